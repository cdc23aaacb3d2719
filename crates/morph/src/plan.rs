//! [`MorphPlan`]: correspondences turned into a union topology and the
//! per-sample data every frame interpolates.

use std::ops::Range;

use glam::{Quat, Vec3};
use serde::Serialize;
use treemorph_analysis::ChainId;
use treemorph_tree::{FrameTopology, NodeId};

use crate::correspondence::{Correspondence, LeafMatch, Operation};
use crate::schedule::{Paced, Schedule};

/// A chain of the union topology: one matched pair (or one copy of a split
/// or merge), or one growing or wilting chain. Its nodes are a contiguous
/// range: first its **junction node** (on the parent chain's axis at the
/// interpolated growth location; at the root for root chains), then one
/// node per sample.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct UnionChain {
    /// How the chain goes from source to target.
    pub operation: Operation,
    /// The source chain (`None` when it grows).
    pub source: Option<ChainId>,
    /// The target chain (`None` when it wilts).
    pub target: Option<ChainId>,
    /// The union chain it grows on; `None` for root chains.
    pub parent: Option<u32>,
    /// Depth in the union chain tree (root chains: 0).
    pub level: u32,
    /// Its nodes: the junction node, then the samples. This is also its
    /// strand.
    pub nodes: Range<NodeId>,
}

/// Which input nodes a union node reproduces exactly at t = 0 and t = 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct NodeOrigin {
    /// The source node it sits on at t = 0 (`None` for a sample added from
    /// the target polyline, or a growing chain).
    pub source: Option<NodeId>,
    /// The target node it sits on at t = 1.
    pub target: Option<NodeId>,
}

/// How far the morph's end frames are from its inputs (see
/// [`FrameMetrics::endpoint_error`](crate::FrameMetrics)).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct EndpointError {
    /// The frame at t = 0 against the source tree: the largest difference
    /// of a node position, a node radius (junction nodes excepted), a leaf
    /// anchor, width or height, over the source tree's height.
    pub source: f32,
    /// The frame at t = 1 against the target tree, over its height.
    pub target: f32,
}

/// A union chain as the morpher needs it.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub(crate) struct ChainPlan {
    pub operation: Operation,
    /// First sample (its node is `1 + first`).
    pub first: u32,
    /// Number of samples (≥ 2).
    pub len: u32,
    /// Parent union chain, or [`NONE`](treemorph_tree::geom::NONE) for a
    /// root chain.
    pub parent: u32,
    pub parent_first: u32,
    pub parent_len: u32,
    /// Growth location on the parent (union parameter) at t = 0 and 1.
    pub p: [f32; 2],
    /// The parent's segments holding `p` at t = 0 and 1, in order.
    pub parent_segments: [u32; 2],
    /// Radius of the junction node at t = 0 and 1: the side chain's
    /// `min(r_junction, r_first_node)`, independent of the resampling.
    pub junction_radius: [f32; 2],
    /// A turn about the junction, in the anchor frame (axis times angle,
    /// radians), that the chain makes mid-blend to clear its siblings:
    /// applied with `4w(1 − w)` of its angle (see `routing`).
    pub detour: Vec3,
    /// How far, metres, the junction node stands off the parent's axis
    /// half way through the blend (see `routing`).
    pub lift: f32,
}

/// Per-sample data: the segment to the next sample and the frame at the
/// sample, each in the chain's anchor frame (the parent's frame at the
/// growth location), precomputed for slerp as `a cos(wθ) + a⊥ sin(wθ)`.
/// Quaternions first: 80 bytes, no padding.
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub(crate) struct Sample {
    pub frame: Quat,
    pub frame_perp: Quat,
    pub dir: Vec3,
    pub dir_perp: Vec3,
    pub theta: f32,
    pub omega: f32,
    /// Segment length at t = 0 and 1.
    pub len: [f32; 2],
    /// Radius at t = 0 and 1.
    pub radius: [f32; 2],
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub(crate) enum LeafMode {
    /// The paper: carried by the host chain.
    OnChain,
    /// Baseline: world anchors and orientations interpolated.
    Linear,
}

/// What a frame needs of a leaf (kept small: frames stream through it).
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub(crate) struct LeafPlan {
    pub mode: LeafMode,
    /// The union chain carrying the leaf ([`LeafMode::OnChain`]).
    pub host: u32,
    /// Parameter along the host at t = 0 and 1.
    pub param: [f32; 2],
    /// The host's segments holding `param` at t = 0 and 1, in order.
    pub segments: [u32; 2],
    /// [`LeafMode::OnChain`]: the offset from the host's axis in its frame
    /// at t = 0 and 1 (lerped: it never leaves the bark by more than the
    /// lerped offset length). [`LeafMode::Linear`]: world anchors.
    pub position: [Vec3; 2],
    /// Orientation (relative to the host frame, or world for
    /// [`LeafMode::Linear`]) precomputed for slerp.
    pub orientation: Quat,
    pub orientation_perp: Quat,
    pub omega: f32,
    pub width: [f32; 2],
    pub height: [f32; 2],
}

/// Everything needed to produce the in-between tree at any t: the
/// correspondence, the union topology, and per-sample and per-leaf data.
/// Build it once with [`MorphPlan::new`], then play it with a
/// [`Morpher`](crate::Morpher).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct MorphPlan {
    pub(crate) topology: FrameTopology,
    pub(crate) correspondence: Correspondence,
    pub(crate) chains: Vec<UnionChain>,
    pub(crate) node_origins: Vec<NodeOrigin>,
    pub(crate) chain_plans: Vec<ChainPlan>,
    pub(crate) levels: Vec<Range<u32>>,
    pub(crate) samples: Vec<Sample>,
    pub(crate) sample_u: Vec<f32>,
    pub(crate) sample_inv_span: Vec<f32>,
    pub(crate) leaf_plans: Vec<LeafPlan>,
    /// Per leaf, the union chains it belongs to at t = 0 and 1 (the same
    /// twice for [`LeafMode::OnChain`]; for metrics).
    pub(crate) leaf_hosts: Vec<[u32; 2]>,
    /// Per leaf, its offset length from the axis at t = 0 and 1 (metrics).
    pub(crate) leaf_offset_len: Vec<[f32; 2]>,
    pub(crate) root: [Vec3; 2],
    pub(crate) root_radius: [f32; 2],
    pub(crate) slow_down: bool,
    pub(crate) schedule: Schedule,
    pub(crate) parallel: bool,
    pub(crate) heights: [f32; 2],
    pub(crate) endpoint: EndpointError,
}

impl MorphPlan {
    /// The union topology every frame shares.
    pub fn topology(&self) -> &FrameTopology {
        &self.topology
    }

    /// The correspondences the plan was built from.
    pub fn correspondence(&self) -> &Correspondence {
        &self.correspondence
    }

    /// The union chains, parents first (by level); chain `i` is strand `i`.
    pub fn chains(&self) -> &[UnionChain] {
        &self.chains
    }

    /// Per union node, the input nodes it reproduces at t = 0 and t = 1.
    pub fn node_origins(&self) -> &[NodeOrigin] {
        &self.node_origins
    }

    /// Per union leaf (in topology order), the input leaves it comes from
    /// and goes to.
    pub fn leaf_origins(&self) -> &[LeafMatch] {
        &self.correspondence.leaves
    }

    /// Heights of the source and target trees, metres (bounds above the
    /// root; see the crate docs).
    pub fn heights(&self) -> [f32; 2] {
        self.heights
    }

    /// The scale metrics are relative to: the larger of the two heights,
    /// metres.
    pub fn height(&self) -> f32 {
        self.heights[0].max(self.heights[1])
    }

    /// How exactly the frames at t = 0 and t = 1 reproduce the inputs
    /// (measured once when the plan is built).
    pub fn endpoint_error(&self) -> EndpointError {
        self.endpoint
    }

    /// The root node at time `t` (it moves with the reshape phase).
    pub(crate) fn root_at(&self, t: Paced) -> Vec3 {
        self.root[0].lerp(self.root[1], self.schedule.overall(t))
    }

    /// Union parameter of a chain's growth location at time `t`.
    pub(crate) fn growth_at(&self, chain: usize, t: Paced) -> f32 {
        let p = self.chain_plans[chain].p;
        p[0] + (p[1] - p[0]) * self.schedule.chain_weight(chain, t)
    }
}
