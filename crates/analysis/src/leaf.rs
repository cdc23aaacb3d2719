//! Leaves as the paper's septuples (§4.3), relative to chains.

use glam::{Quat, Vec3};
use serde::Serialize;
use treemorph_tree::Tree;

use crate::chain::{Chain, ChainId, Ordering};

/// A leaf expressed relative to its IL chain: ⟨chain, position, width,
/// height, orientation, texture⟩ (§4.3), plus the chain it grows on.
///
/// Reconstruct the anchor with `chain.point_at(param).0 +
/// chain.frame_at(param) * offset` and the world orientation with
/// `chain.frame_at(param) * orientation`; the morph does exactly that on
/// the in-between chain.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LeafPlacement {
    /// The chain holding the branch the leaf grows on (from the ordering).
    pub grows_on: ChainId,
    /// Arc-length fraction of the leaf's branch point along `grows_on`.
    pub grows_on_param: f32,
    /// The chain whose inner lobe holds the leaf (from the clustering).
    pub inner_lobe: ChainId,
    /// Arc-length fraction along the IL chain: the leaf's own branch point
    /// when the IL chain is the one it grows on, otherwise the closest
    /// point of the IL chain to the anchor.
    pub param: f32,
    /// From the IL chain's point at `param` to the anchor, in that chain's
    /// local frame there (metres).
    pub offset: Vec3,
    /// Blade width, metres.
    pub width: f32,
    /// Blade height, metres.
    pub height: f32,
    /// Leaf orientation relative to the IL chain's local frame at `param`.
    pub orientation: Quat,
    /// Index into the tree's leaf materials.
    pub material: u32,
}

pub(crate) fn place(
    tree: &Tree,
    ordering: &Ordering,
    chains: &[Chain],
    il: &[ChainId],
) -> Vec<LeafPlacement> {
    tree.leaves()
        .iter()
        .zip(il)
        .map(|(leaf, &il)| {
            let grows_on = ordering.chain_of[leaf.branch as usize];
            let g = &chains[grows_on as usize];
            let j = ordering.index_in_chain[leaf.branch as usize] as usize;
            let grows_on_param = if g.length > 0.0 {
                (g.arc_lengths[j - 1] + leaf.t * (g.arc_lengths[j] - g.arc_lengths[j - 1]))
                    / g.length
            } else {
                (j as f32 - 1.0 + leaf.t) / g.branch_count() as f32
            };
            let anchor = tree.leaf_anchor(leaf);
            let c = &chains[il as usize];
            let param = if il == grows_on {
                grows_on_param
            } else {
                c.project(anchor)
            };
            let frame = c.frame_at(param);
            let inv = frame.inverse();
            LeafPlacement {
                grows_on,
                grows_on_param,
                inner_lobe: il,
                param,
                offset: inv * (anchor - c.point_at(param).0),
                width: leaf.width,
                height: leaf.height,
                orientation: (inv * leaf.orientation).normalize(),
                material: leaf.material,
            }
        })
        .collect()
}
