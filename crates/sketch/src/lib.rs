//! treemorph sketch stage (in progress).
