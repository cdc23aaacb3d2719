//! Wire types shared by the treemorph server, client and CLI (in progress).
