//! treemorph: the service and command-line tool.
