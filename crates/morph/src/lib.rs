//! treemorph morph stage (in progress).
