//! `treemorph_tree::json::from_slice`: the upload route's parser for our
//! tree format.
//!
//! Invariants: never a panic; a tree that parses writes back
//! (`json::to_vec`) to a document that parses to the same tree.
#![no_main]

use libfuzzer_sys::fuzz_target;
use treemorph_tree::{Limits, json};

fuzz_target!(|data: &[u8]| {
    let limits = Limits::default();
    if let Ok(tree) = json::from_slice(data, &limits) {
        let written = json::to_vec(&tree);
        let again = json::from_slice(&written, &limits)
            .unwrap_or_else(|e| panic!("a parsed tree does not read back: {e}"));
        assert!(again == tree, "the tree changed on a write/read round trip");
    }
});
