use glam::{Quat, Vec3};
use serde::{Deserialize, Serialize};

use crate::bounds::Aabb;
use crate::texture::Texture;

/// Index of a node in [`Skeleton::nodes`]; also names the branch that ends at
/// that node.
pub type NodeId = u32;

/// A skeleton point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Node {
    /// Position in metres, Y up.
    pub position: Vec3,
    /// Branch radius at this point in metres (> 0).
    pub radius: f32,
    /// The parent node; `None` only for the root.
    pub parent: Option<NodeId>,
}

/// A rooted tree of nodes, stored parents-before-children with the root at
/// index 0, together with a child index.
#[derive(Clone, Debug, PartialEq)]
pub struct Skeleton {
    nodes: Vec<Node>,
    child_offsets: Vec<u32>,
    child_list: Vec<NodeId>,
}

impl Skeleton {
    /// Builds the child index; callers guarantee the canonical order.
    pub(crate) fn from_canonical(nodes: Vec<Node>) -> Skeleton {
        let n = nodes.len();
        let mut counts = vec![0u32; n + 1];
        for node in &nodes {
            if let Some(p) = node.parent {
                counts[p as usize + 1] += 1;
            }
        }
        for i in 0..n {
            counts[i + 1] += counts[i];
        }
        let mut fill = counts.clone();
        let mut child_list = vec![0; n.saturating_sub(1)];
        for (i, node) in nodes.iter().enumerate() {
            if let Some(p) = node.parent {
                let slot = &mut fill[p as usize];
                child_list[*slot as usize] = i as NodeId;
                *slot += 1;
            }
        }
        Skeleton {
            nodes,
            child_offsets: counts,
            child_list,
        }
    }

    /// All nodes; index 0 is the root and every parent precedes its children.
    pub fn nodes(&self) -> &[Node] {
        &self.nodes
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// Always false: a valid skeleton has a root.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Number of branches (edges): one per non-root node.
    pub fn branch_count(&self) -> usize {
        self.nodes.len().saturating_sub(1)
    }

    /// One node.
    pub fn node(&self, id: NodeId) -> &Node {
        &self.nodes[id as usize]
    }

    /// Children of a node, in increasing id order.
    pub fn children(&self, id: NodeId) -> &[NodeId] {
        let a = self.child_offsets[id as usize] as usize;
        let b = self.child_offsets[id as usize + 1] as usize;
        &self.child_list[a..b]
    }

    /// The branch ending at `id` as (start, end) points; `None` for the root.
    pub fn branch(&self, id: NodeId) -> Option<(Vec3, Vec3)> {
        let node = self.node(id);
        node.parent
            .map(|p| (self.nodes[p as usize].position, node.position))
    }

    /// Point on branch `id` at parameter `t` (0 at the parent, 1 at the node)
    /// with the linearly interpolated radius; the root node itself for the
    /// root.
    pub fn point_on_branch(&self, id: NodeId, t: f32) -> (Vec3, f32) {
        let node = self.node(id);
        match node.parent {
            Some(p) => {
                let parent = &self.nodes[p as usize];
                (
                    parent.position.lerp(node.position, t),
                    parent.radius + (node.radius - parent.radius) * t,
                )
            }
            None => (node.position, node.radius),
        }
    }

    /// Number of nodes on the longest root-to-tip path.
    pub fn depth(&self) -> usize {
        let mut depth = vec![0u32; self.nodes.len()];
        let mut best = 0;
        for (i, node) in self.nodes.iter().enumerate() {
            let d = node.parent.map_or(1, |p| depth[p as usize] + 1);
            depth[i] = d;
            best = best.max(d);
        }
        best as usize
    }

    /// Total length of all branches in metres.
    pub fn total_length(&self) -> f32 {
        (1..self.nodes.len() as NodeId)
            .filter_map(|i| self.branch(i))
            .map(|(a, b)| a.distance(b))
            .sum()
    }
}

/// A billboard leaf: the papers' septuple ⟨chain, position, width, height,
/// orientation, texture⟩, stored relative to the branch it grows on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Leaf {
    /// The branch the leaf grows on (its child node; never the root).
    pub branch: NodeId,
    /// Parametric position along the branch: 0 at the parent node, 1 at the
    /// branch's node.
    pub t: f32,
    /// From the branch axis point at `t` to the leaf's anchor, in metres
    /// (world axes). Its length is usually the branch radius there.
    pub offset: Vec3,
    /// Blade width in metres (> 0).
    pub width: f32,
    /// Blade height, base to tip, in metres (> 0).
    pub height: f32,
    /// Rotation from the leaf's local frame (blade along +Y, facing +Z) to
    /// world axes; a unit quaternion.
    pub orientation: Quat,
    /// Index into [`Materials::leaves`].
    pub material: u32,
}

/// Bark appearance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Bark {
    /// Base colour, linear RGBA in [0, 1] (multiplied with the texture).
    pub color: [f32; 4],
    /// Optional bark texture; its `u` runs around the branch, `v` along it.
    pub texture: Option<Texture>,
}

impl Default for Bark {
    fn default() -> Bark {
        Bark {
            color: [0.23, 0.16, 0.1, 1.0],
            texture: None,
        }
    }
}

/// A leaf material: a texture whose alpha channel cuts out the blade.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LeafMaterial {
    /// Human-readable name (e.g. `"ovate"`).
    pub name: String,
    /// Colour multiplier, linear RGBA in [0, 1].
    pub color: [f32; 4],
    /// The blade texture (PNG with alpha); `None` draws a solid quad.
    pub texture: Option<Texture>,
}

/// Bark and leaf materials.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct Materials {
    /// The bark of every branch.
    pub bark: Bark,
    /// Leaf materials, indexed by [`Leaf::material`].
    pub leaves: Vec<LeafMaterial>,
}

/// The arrangement of chains of one order growing at one location (morphing
/// paper Eq. 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, PartialOrd, Ord)]
#[serde(rename_all = "snake_case")]
pub enum BranchingPattern {
    /// Exactly one chain grows at the location.
    Alternate,
    /// Two chains, about 180° apart around the parent.
    Opposite,
    /// Three or more chains (or two that are not opposite).
    Whorled,
}

impl BranchingPattern {
    /// All patterns, in histogram order.
    pub const ALL: [BranchingPattern; 3] = [
        BranchingPattern::Alternate,
        BranchingPattern::Opposite,
        BranchingPattern::Whorled,
    ];

    /// The snake_case name used in JSON.
    pub fn as_str(self) -> &'static str {
        match self {
            BranchingPattern::Alternate => "alternate",
            BranchingPattern::Opposite => "opposite",
            BranchingPattern::Whorled => "whorled",
        }
    }
}

/// One chain group the generator meant to create.
#[derive(Clone, Debug, PartialEq)]
pub struct GroundTruthGroup {
    /// For each chain of the group, the node that ends its first branch.
    pub chains: Vec<NodeId>,
    /// The intended pattern.
    pub pattern: BranchingPattern,
}

/// What a procedural generator intended, so analyses can be tested against
/// it rather than against themselves.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct GroundTruth {
    /// Intended hybrid order of the branch ending at each node (index =
    /// node id); the root's entry is 1.
    pub orders: Vec<u32>,
    /// Every intended chain group, including the root group.
    pub groups: Vec<GroundTruthGroup>,
}

/// The unvalidated parts of a tree, in any node order.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct TreeParts {
    /// Free-form name.
    pub name: String,
    /// Skeleton nodes; exactly one has no parent.
    pub nodes: Vec<Node>,
    /// Leaves.
    pub leaves: Vec<Leaf>,
    /// Materials.
    pub materials: Materials,
    /// Optional generator ground truth.
    pub ground_truth: Option<GroundTruth>,
}

/// A valid tree: one rooted skeleton, leaves on existing branches, finite
/// numbers, positive radii and sizes within [`Limits`](crate::Limits).
#[derive(Clone, Debug, PartialEq)]
pub struct Tree {
    name: String,
    skeleton: Skeleton,
    leaves: Vec<Leaf>,
    materials: Materials,
    ground_truth: Option<GroundTruth>,
}

/// Summary figures of a tree.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TreeStats {
    /// Skeleton nodes.
    pub nodes: usize,
    /// Branches (skeleton edges).
    pub branches: usize,
    /// Leaves.
    pub leaves: usize,
    /// Bounds of the skeleton and leaf anchors, `[min, max]`, metres.
    pub bounds: [[f32; 3]; 2],
    /// Height above the root, metres.
    pub height: f32,
    /// Nodes on the longest root-to-tip path.
    pub depth: usize,
    /// Total branch length, metres.
    pub total_length: f32,
}

// `Tree::new` lives in validate.rs: the model is the lower module, the
// rules that build a valid tree sit on top of it.
impl Tree {
    pub(crate) fn from_valid(
        name: String,
        skeleton: Skeleton,
        leaves: Vec<Leaf>,
        materials: Materials,
        ground_truth: Option<GroundTruth>,
    ) -> Tree {
        Tree {
            name,
            skeleton,
            leaves,
            materials,
            ground_truth,
        }
    }

    /// The tree's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Renames the tree.
    pub fn set_name(&mut self, name: impl Into<String>) {
        self.name = name.into();
    }

    /// The skeleton.
    pub fn skeleton(&self) -> &Skeleton {
        &self.skeleton
    }

    /// The leaves.
    pub fn leaves(&self) -> &[Leaf] {
        &self.leaves
    }

    /// The materials.
    pub fn materials(&self) -> &Materials {
        &self.materials
    }

    /// Generator ground truth, when the tree came from a generator.
    pub fn ground_truth(&self) -> Option<&GroundTruth> {
        self.ground_truth.as_ref()
    }

    /// Drops the ground truth (e.g. before an export meant to look like a
    /// third-party file).
    pub fn without_ground_truth(mut self) -> Tree {
        self.ground_truth = None;
        self
    }

    /// Gives the parts back (in canonical order).
    pub fn into_parts(self) -> TreeParts {
        TreeParts {
            name: self.name,
            nodes: self.skeleton.nodes,
            leaves: self.leaves,
            materials: self.materials,
            ground_truth: self.ground_truth,
        }
    }

    /// World position of a leaf's anchor (branch axis point plus offset).
    pub fn leaf_anchor(&self, leaf: &Leaf) -> Vec3 {
        self.skeleton.point_on_branch(leaf.branch, leaf.t).0 + leaf.offset
    }

    /// Bounds of every branch (as spheres of its radius) and every leaf blade.
    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for node in self.skeleton.nodes() {
            b = b.union(Aabb::of_points([node.position]).inflated(node.radius));
        }
        for leaf in &self.leaves {
            let anchor = self.leaf_anchor(leaf);
            let tip = anchor + leaf.orientation * Vec3::new(0.0, leaf.height, 0.0);
            b = b.with_point(anchor).with_point(tip);
        }
        b
    }

    /// Summary figures.
    pub fn stats(&self) -> TreeStats {
        let bounds = self.bounds();
        let root_y = self.skeleton.node(0).position.y;
        TreeStats {
            nodes: self.skeleton.len(),
            branches: self.skeleton.branch_count(),
            leaves: self.leaves.len(),
            bounds: [bounds.min.to_array(), bounds.max.to_array()],
            height: (bounds.max.y - root_y).max(0.0),
            depth: self.skeleton.depth(),
            total_length: self.skeleton.total_length(),
        }
    }
}
