//! [`Lobe`]: a leaf cluster and the closed shape around it.
//!
//! Its own module because chains and chain groups carry lobes while the
//! lobe computation reads chains and groups: the type sits below both.

use glam::Vec3;
use serde::Serialize;

use crate::hull::Hull;

/// A leaf cluster and its closed shape.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Lobe {
    /// Leaf indices (into [`Tree::leaves`](treemorph_tree::Tree::leaves)),
    /// ascending.
    pub leaves: Vec<u32>,
    /// Closed shape around the leaves' blade points; empty when `leaves` is.
    pub hull: Hull,
    /// Centroid of the leaves' blade points (for an empty lobe: the chain's
    /// tip, or the mean tip of a group's chains), metres.
    pub center: Vec3,
    /// Largest distance from `center` to a hull vertex (0 when empty),
    /// metres.
    pub radius: f32,
}

impl Lobe {
    /// Whether the lobe holds no leaves.
    pub fn is_empty(&self) -> bool {
        self.leaves.is_empty()
    }
}
