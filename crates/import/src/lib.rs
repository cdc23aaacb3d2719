//! treemorph import stage (in progress).
