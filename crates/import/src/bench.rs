//! Inputs for `treemorph bench`: the GLB files the import benchmark reads.

use treemorph_gltf::{BranchMeshMode, ExportError, ExportOptions, export_glb};
use treemorph_tree::{Limits, Tree, TreeParts};

/// `tree` with at most `max_leaves` leaves (evenly thinned), exported as a
/// GLB without the embedded tree, branches meshed as `mode` — what a
/// third-party tool would write. The benchmark imports it with
/// [`import`](crate::import).
pub fn bench_glb(
    tree: &Tree,
    mode: BranchMeshMode,
    max_leaves: usize,
) -> Result<Vec<u8>, ExportError> {
    let thinned;
    let tree = if tree.leaves().len() > max_leaves {
        let mut parts: TreeParts = tree.clone().into_parts();
        let n = parts.leaves.len();
        parts.leaves = (0..max_leaves)
            .map(|i| parts.leaves[i * n / max_leaves])
            .collect();
        thinned = Tree::new(parts, &Limits::default())
            .map_err(|e| ExportError::Internal(format!("thinning leaves: {e}")))?;
        &thinned
    } else {
        tree
    };
    export_glb(
        tree,
        &ExportOptions::default()
            .with_embed_tree(false)
            .with_branch_mode(mode),
    )
}
