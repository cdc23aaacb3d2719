//! `treemorph_import::import` on untrusted bytes, as the upload route calls
//! it (with the tree limits applied).
//!
//! The first byte picks how the rest is read, so the fuzzer can mutate the
//! glTF JSON without having to repair the GLB container around it:
//! - even: the bytes as uploaded (GLB, glTF JSON or garbage);
//! - odd: the second byte (scaled) splits the rest into a JSON chunk and a
//!   BIN chunk, wrapped in a well-formed GLB container.
//!
//! Invariant: an error with one of the stable codes and never `internal`,
//! or a valid tree.
#![no_main]

use libfuzzer_sys::fuzz_target;
use treemorph_import::{ImportError, ImportOptions, import};
use treemorph_tree::Limits;

fn options() -> ImportOptions {
    // As `treemorph::files::import_options(&Limits::default())`.
    let limits = Limits::default();
    let mut options = ImportOptions::default();
    options.max_nodes = limits.max_nodes;
    options.max_leaves = limits.max_leaves;
    options.max_texture_side = limits.max_texture_side;
    options
}

fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |n: usize| n.div_ceil(4) * 4;
    let total = 12 + 8 + pad(json.len()) + if bin.is_empty() { 0 } else { 8 + pad(bin.len()) };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(pad(json.len()) as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(json);
    out.resize(out.len() + pad(json.len()) - json.len(), b' ');
    if !bin.is_empty() {
        out.extend_from_slice(&(pad(bin.len()) as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(bin);
        out.resize(out.len() + pad(bin.len()) - bin.len(), 0);
    }
    out
}

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    let bytes = if mode & 1 == 0 {
        rest.to_vec()
    } else {
        let Some((&split, rest)) = rest.split_first() else {
            return;
        };
        let at = rest.len() * usize::from(split) / 255;
        let (json, bin) = rest.split_at(at);
        glb(json, bin)
    };
    match import(&bytes, &options()) {
        Ok(imported) => {
            let tree = imported.tree;
            assert!(tree.skeleton().len() >= 2, "a tree of one node");
        }
        Err(e) => {
            assert!(ImportError::CODES.contains(&e.code()), "unknown code: {e}");
            assert_ne!(e.code(), "internal", "internal error: {e}");
            assert_ne!(e.code(), "invalid_options", "{e}");
        }
    }
});
