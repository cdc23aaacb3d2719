//! treemorph analysis stage (in progress).
