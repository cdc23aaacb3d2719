//! Validation and canonicalisation of [`TreeParts`] into a [`Tree`].

use std::fmt;

use glam::Vec3;
use thiserror::Error;

use crate::model::{GroundTruth, Leaf, Node, NodeId, Skeleton, Tree, TreeParts};
use crate::texture::DEFAULT_MAX_TEXTURE_SIDE;

/// Size limits applied when a tree is built. Every field is a count; the
/// defaults accept the largest trees the papers use with room to spare.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct Limits {
    /// Most skeleton nodes (default 1,000,000).
    pub max_nodes: usize,
    /// Most leaves (default 500,000).
    pub max_leaves: usize,
    /// Most leaf materials (default 64).
    pub max_leaf_materials: usize,
    /// Longest texture side in pixels (default 4,096).
    pub max_texture_side: u32,
    /// Most pixels of all textures together, bark and leaves (default
    /// 4 × 4,096², i.e. 256 MiB decoded). Encoders decode every texture
    /// of a tree at once, so without a total a small upload of
    /// well-compressed large images could hold gigabytes.
    pub max_texture_pixels: u64,
    /// Longest tree name in bytes (default 256).
    pub max_name_len: usize,
}

impl Default for Limits {
    fn default() -> Limits {
        Limits {
            max_nodes: 1_000_000,
            max_leaves: 500_000,
            max_leaf_materials: 64,
            max_texture_side: DEFAULT_MAX_TEXTURE_SIDE,
            max_texture_pixels: 4 * 4096 * 4096,
            max_name_len: 256,
        }
    }
}

impl Limits {
    /// Limits with the given node and leaf maxima and defaults otherwise.
    pub fn with_sizes(max_nodes: usize, max_leaves: usize) -> Limits {
        Limits {
            max_nodes,
            max_leaves,
            ..Limits::default()
        }
    }
}

/// What a size limit counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SizeKind {
    /// Skeleton nodes.
    Nodes,
    /// Leaves.
    Leaves,
    /// Leaf materials.
    LeafMaterials,
    /// Bytes of the tree's name.
    NameBytes,
}

impl fmt::Display for SizeKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SizeKind::Nodes => "nodes",
            SizeKind::Leaves => "leaves",
            SizeKind::LeafMaterials => "leaf materials",
            SizeKind::NameBytes => "bytes of name",
        })
    }
}

/// A numeric field that must be finite.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Field {
    /// `nodes[i].position`.
    NodePosition,
    /// `nodes[i].radius`.
    NodeRadius,
    /// `leaves[i].t`.
    LeafT,
    /// `leaves[i].offset`.
    LeafOffset,
    /// `leaves[i].width`.
    LeafWidth,
    /// `leaves[i].height`.
    LeafHeight,
    /// `leaves[i].orientation`.
    LeafOrientation,
    /// `materials.bark.color`.
    BarkColor,
    /// `materials.leaves[i].color`.
    LeafColor,
}

impl Field {
    /// The field's path in the JSON tree format, with the index filled in.
    pub fn at(self, index: usize) -> String {
        match self {
            Field::NodePosition => format!("nodes[{index}].position"),
            Field::NodeRadius => format!("nodes[{index}].radius"),
            Field::LeafT => format!("leaves[{index}].t"),
            Field::LeafOffset => format!("leaves[{index}].offset"),
            Field::LeafWidth => format!("leaves[{index}].width"),
            Field::LeafHeight => format!("leaves[{index}].height"),
            Field::LeafOrientation => format!("leaves[{index}].orientation"),
            Field::BarkColor => "materials.bark.color".to_owned(),
            Field::LeafColor => format!("materials.leaves[{index}].color"),
        }
    }
}

/// Why a tree was refused. Indices refer to the input's order.
#[derive(Clone, Debug, Error, PartialEq)]
// Exhaustive on purpose: the service's error-code table
// (`treemorph_pipeline::ErrorCoded`) must name a code for every variant.
pub enum InvalidTree {
    /// The skeleton has no nodes.
    #[error("the skeleton has no nodes")]
    Empty,
    /// No node is a root: every node has a parent, so the parents form a cycle.
    #[error("no node is a root (every node has a parent); node {node} is on a cycle")]
    NoRoot {
        /// A node on a cycle.
        node: usize,
    },
    /// More than one node has no parent.
    #[error("nodes {first} and {second} both have no parent; a tree has exactly one root")]
    SeveralRoots {
        /// The first root.
        first: usize,
        /// Another root.
        second: usize,
    },
    /// A parent index names no node.
    #[error("node {node} names parent {parent}, but there are only {count} nodes")]
    DanglingParent {
        /// The node.
        node: usize,
        /// Its parent index.
        parent: u64,
        /// Number of nodes.
        count: usize,
    },
    /// Following parents from this node never reaches the root.
    #[error("node {node} is on a cycle of parents and never reaches the root")]
    Cycle {
        /// A node on the cycle.
        node: usize,
    },
    /// A NaN or infinite number.
    #[error("{} is not a finite number", field.at(*index))]
    NonFinite {
        /// The field.
        field: Field,
        /// Index of the node, leaf or material.
        index: usize,
    },
    /// A radius that is zero or negative.
    #[error("nodes[{node}].radius is {radius}; radii must be greater than zero")]
    NonPositiveRadius {
        /// The node.
        node: usize,
        /// Its radius.
        radius: f32,
    },
    /// A branch whose two ends coincide, so it has no direction.
    #[error("branch to node {node} has zero length (it sits on its parent {parent})")]
    ZeroLengthBranch {
        /// The node.
        node: usize,
        /// Its parent.
        parent: usize,
    },
    /// A leaf names a branch that does not exist.
    #[error("leaves[{leaf}] grows on branch {branch}, but there are only {count} nodes")]
    LeafOnMissingBranch {
        /// The leaf.
        leaf: usize,
        /// Its branch.
        branch: u64,
        /// Number of nodes.
        count: usize,
    },
    /// A leaf names the root node, which ends no branch.
    #[error("leaves[{leaf}] grows on node {branch}, the root, which carries no branch")]
    LeafOnRoot {
        /// The leaf.
        leaf: usize,
        /// The root's index.
        branch: usize,
    },
    /// A leaf's parameter is outside [0, 1].
    #[error("leaves[{leaf}].t is {t}; it must be within [0, 1]")]
    LeafParameterOutOfRange {
        /// The leaf.
        leaf: usize,
        /// Its parameter.
        t: f32,
    },
    /// A leaf with zero or negative width or height.
    #[error("leaves[{leaf}] is {width}×{height}; width and height must be greater than zero")]
    NonPositiveLeafSize {
        /// The leaf.
        leaf: usize,
        /// Its width.
        width: f32,
        /// Its height.
        height: f32,
    },
    /// A leaf orientation that is not a unit quaternion.
    #[error("leaves[{leaf}].orientation has length {length}; it must be a unit quaternion")]
    NonUnitOrientation {
        /// The leaf.
        leaf: usize,
        /// The quaternion's length.
        length: f32,
    },
    /// A leaf names a material that does not exist.
    #[error("leaves[{leaf}] uses material {material}, but there are only {count} leaf materials")]
    MissingMaterial {
        /// The leaf.
        leaf: usize,
        /// Its material index.
        material: u32,
        /// Number of leaf materials.
        count: usize,
    },
    /// A colour component outside [0, 1].
    #[error("{} has a component outside [0, 1]", field.at(*index))]
    ColorOutOfRange {
        /// The field.
        field: Field,
        /// Index of the material.
        index: usize,
    },
    /// A texture could not be read or is too large.
    #[error("texture of {material}: {reason}")]
    InvalidTexture {
        /// Which material (`"bark"` or `"leaves[i]"`).
        material: String,
        /// What is wrong.
        reason: String,
    },
    /// More of something than the limits allow.
    #[error("the tree has {count} {kind}; at most {limit} are allowed")]
    TooLarge {
        /// What was counted.
        kind: SizeKind,
        /// How many there are.
        count: usize,
        /// The limit.
        limit: usize,
    },
    /// Ground truth that does not fit the skeleton.
    #[error("ground truth does not fit the skeleton: {reason}")]
    GroundTruthMismatch {
        /// What is wrong.
        reason: String,
    },
}

/// Quaternions further than this from unit length are refused.
const UNIT_TOLERANCE: f32 = 1e-3;

/// Branches shorter than this (metres) have no usable direction.
pub(crate) const MIN_BRANCH_LENGTH: f32 = 1e-6;

fn finite3(v: Vec3) -> bool {
    v.is_finite()
}

impl Tree {
    /// Validates `parts` against `limits` and builds the tree.
    ///
    /// Nodes are put in canonical order (root first, parents before
    /// children); when the input already is in that order it is kept as is,
    /// so a tree written by treemorph reads back identical. Leaf branches and
    /// ground truth are renumbered with the nodes.
    pub fn new(parts: TreeParts, limits: &Limits) -> Result<Tree, InvalidTree> {
        build(parts, limits)
    }
}

fn build(parts: TreeParts, limits: &Limits) -> Result<Tree, InvalidTree> {
    let TreeParts {
        name,
        nodes,
        leaves,
        materials,
        ground_truth,
    } = parts;
    check_size(SizeKind::NameBytes, name.len(), limits.max_name_len)?;
    check_size(SizeKind::Nodes, nodes.len(), limits.max_nodes)?;
    check_size(SizeKind::Leaves, leaves.len(), limits.max_leaves)?;
    check_size(
        SizeKind::LeafMaterials,
        materials.leaves.len(),
        limits.max_leaf_materials,
    )?;
    if nodes.is_empty() {
        return Err(InvalidTree::Empty);
    }
    let n = nodes.len();

    // Structure first: numbers are only meaningful on a well-formed skeleton,
    // and the structural errors are the ones users most need to see.
    let mut root = None;
    for (i, node) in nodes.iter().enumerate() {
        match node.parent {
            None => match root {
                None => root = Some(i),
                Some(first) => return Err(InvalidTree::SeveralRoots { first, second: i }),
            },
            Some(p) if p as usize >= n => {
                return Err(InvalidTree::DanglingParent {
                    node: i,
                    parent: u64::from(p),
                    count: n,
                });
            }
            Some(_) => {}
        }
    }
    let Some(root) = root else {
        return Err(InvalidTree::NoRoot {
            node: node_on_cycle(&nodes, 0),
        });
    };
    let order = canonical_order(&nodes, root)?;

    for (i, node) in nodes.iter().enumerate() {
        if !finite3(node.position) {
            return Err(InvalidTree::NonFinite {
                field: Field::NodePosition,
                index: i,
            });
        }
        if !node.radius.is_finite() {
            return Err(InvalidTree::NonFinite {
                field: Field::NodeRadius,
                index: i,
            });
        }
        if node.radius <= 0.0 {
            return Err(InvalidTree::NonPositiveRadius {
                node: i,
                radius: node.radius,
            });
        }
        if let Some(p) = node.parent
            && nodes[p as usize].position.distance(node.position) < MIN_BRANCH_LENGTH
        {
            return Err(InvalidTree::ZeroLengthBranch {
                node: i,
                parent: p as usize,
            });
        }
    }

    check_color(materials.bark.color, Field::BarkColor, 0)?;
    let mut pixels = 0u64;
    if let Some(t) = &materials.bark.texture {
        check_texture(t, "bark", limits, &mut pixels)?;
    }
    for (i, m) in materials.leaves.iter().enumerate() {
        check_color(m.color, Field::LeafColor, i)?;
        if let Some(t) = &m.texture {
            check_texture(t, &format!("leaves[{i}]"), limits, &mut pixels)?;
        }
    }

    for (i, leaf) in leaves.iter().enumerate() {
        check_leaf(i, leaf, n, root, materials.leaves.len())?;
    }

    if let Some(gt) = &ground_truth {
        check_ground_truth(gt, n)?;
    }

    // Renumber only when the input is not already canonical, so that our own
    // files read back bit-identical.
    let identity = order.iter().enumerate().all(|(i, &o)| i == o as usize);
    let (nodes, leaves, ground_truth) = if identity {
        (nodes, leaves, ground_truth)
    } else {
        renumber(nodes, leaves, ground_truth, &order)
    };
    Ok(Tree::from_valid(
        name,
        Skeleton::from_canonical(nodes),
        leaves,
        materials,
        ground_truth,
    ))
}

fn check_size(kind: SizeKind, count: usize, limit: usize) -> Result<(), InvalidTree> {
    if count > limit {
        Err(InvalidTree::TooLarge { kind, count, limit })
    } else {
        Ok(())
    }
}

fn check_color(color: [f32; 4], field: Field, index: usize) -> Result<(), InvalidTree> {
    if color.iter().any(|c| !c.is_finite()) {
        return Err(InvalidTree::NonFinite { field, index });
    }
    if color.iter().any(|c| !(0.0..=1.0).contains(c)) {
        return Err(InvalidTree::ColorOutOfRange { field, index });
    }
    Ok(())
}

/// Checks one texture's size and adds its pixels to the running `total`.
fn check_texture(
    texture: &crate::Texture,
    material: &str,
    limits: &Limits,
    total: &mut u64,
) -> Result<(), InvalidTree> {
    let side = texture.width().max(texture.height());
    if side > limits.max_texture_side {
        return Err(InvalidTree::InvalidTexture {
            material: material.to_owned(),
            reason: format!(
                "the image is {}×{} pixels; at most {} pixels per side are allowed",
                texture.width(),
                texture.height(),
                limits.max_texture_side
            ),
        });
    }
    *total += u64::from(texture.width()) * u64::from(texture.height());
    if *total > limits.max_texture_pixels {
        return Err(InvalidTree::InvalidTexture {
            material: material.to_owned(),
            reason: format!(
                "the textures up to this one have {total} pixels; at most {} are allowed in all",
                limits.max_texture_pixels
            ),
        });
    }
    Ok(())
}

fn check_leaf(
    i: usize,
    leaf: &Leaf,
    n: usize,
    root: usize,
    materials: usize,
) -> Result<(), InvalidTree> {
    if leaf.branch as usize >= n {
        return Err(InvalidTree::LeafOnMissingBranch {
            leaf: i,
            branch: u64::from(leaf.branch),
            count: n,
        });
    }
    if leaf.branch as usize == root {
        return Err(InvalidTree::LeafOnRoot {
            leaf: i,
            branch: root,
        });
    }
    let non_finite = |field| Err(InvalidTree::NonFinite { field, index: i });
    if !leaf.t.is_finite() {
        return non_finite(Field::LeafT);
    }
    if !finite3(leaf.offset) {
        return non_finite(Field::LeafOffset);
    }
    if !leaf.width.is_finite() {
        return non_finite(Field::LeafWidth);
    }
    if !leaf.height.is_finite() {
        return non_finite(Field::LeafHeight);
    }
    if !leaf.orientation.is_finite() {
        return non_finite(Field::LeafOrientation);
    }
    if !(0.0..=1.0).contains(&leaf.t) {
        return Err(InvalidTree::LeafParameterOutOfRange { leaf: i, t: leaf.t });
    }
    if leaf.width <= 0.0 || leaf.height <= 0.0 {
        return Err(InvalidTree::NonPositiveLeafSize {
            leaf: i,
            width: leaf.width,
            height: leaf.height,
        });
    }
    let length = leaf.orientation.length();
    if (length - 1.0).abs() > UNIT_TOLERANCE {
        return Err(InvalidTree::NonUnitOrientation { leaf: i, length });
    }
    if leaf.material as usize >= materials {
        return Err(InvalidTree::MissingMaterial {
            leaf: i,
            material: leaf.material,
            count: materials,
        });
    }
    Ok(())
}

fn check_ground_truth(gt: &GroundTruth, n: usize) -> Result<(), InvalidTree> {
    let mismatch = |reason: String| Err(InvalidTree::GroundTruthMismatch { reason });
    if gt.orders.len() != n {
        return mismatch(format!(
            "{} orders for {} nodes; there must be one per node",
            gt.orders.len(),
            n
        ));
    }
    if let Some(i) = gt.orders.iter().position(|&o| o == 0) {
        return mismatch(format!("orders[{i}] is 0; orders start at 1"));
    }
    for (g, group) in gt.groups.iter().enumerate() {
        if group.chains.is_empty() {
            return mismatch(format!("groups[{g}] has no chains"));
        }
        if let Some(&c) = group.chains.iter().find(|&&c| c as usize >= n) {
            return mismatch(format!("groups[{g}] names node {c}, which does not exist"));
        }
    }
    Ok(())
}

/// Walks parents from `start` until a node repeats, returning one on the cycle.
fn node_on_cycle(nodes: &[Node], start: usize) -> usize {
    // Floyd's tortoise and hare: no allocation, ends on any parent cycle.
    let step = |i: usize| nodes[i].parent.map_or(i, |p| p as usize);
    let (mut slow, mut fast) = (step(start), step(step(start)));
    while slow != fast {
        slow = step(slow);
        fast = step(step(fast));
    }
    // Return the smallest index on the cycle so errors are deterministic.
    let mut best = slow;
    let mut i = step(slow);
    while i != slow {
        best = best.min(i);
        i = step(i);
    }
    best
}

/// A parents-before-children order from `root`: identity when the input
/// already satisfies it, else a depth-first preorder.
fn canonical_order(nodes: &[Node], root: usize) -> Result<Vec<NodeId>, InvalidTree> {
    let n = nodes.len();
    let already = root == 0
        && nodes
            .iter()
            .enumerate()
            .all(|(i, node)| node.parent.is_none_or(|p| (p as usize) < i));
    if already {
        return Ok((0..n as NodeId).collect());
    }
    let mut counts = vec![0u32; n + 1];
    for node in nodes {
        if let Some(p) = node.parent {
            counts[p as usize + 1] += 1;
        }
    }
    for i in 0..n {
        counts[i + 1] += counts[i];
    }
    let mut fill = counts.clone();
    let mut children = vec![0u32; n - 1];
    for (i, node) in nodes.iter().enumerate() {
        if let Some(p) = node.parent {
            children[fill[p as usize] as usize] = i as u32;
            fill[p as usize] += 1;
        }
    }
    let mut order = Vec::with_capacity(n);
    let mut stack = vec![root as u32];
    while let Some(i) = stack.pop() {
        order.push(i);
        let (a, b) = (counts[i as usize] as usize, counts[i as usize + 1] as usize);
        // Reverse so that children come out in increasing index order.
        stack.extend(children[a..b].iter().rev());
    }
    if order.len() < n {
        let mut reached = vec![false; n];
        for &i in &order {
            reached[i as usize] = true;
        }
        let start = reached.iter().position(|r| !r).unwrap_or(0);
        return Err(InvalidTree::Cycle {
            node: node_on_cycle(nodes, start),
        });
    }
    Ok(order)
}

fn renumber(
    nodes: Vec<Node>,
    leaves: Vec<Leaf>,
    ground_truth: Option<GroundTruth>,
    order: &[NodeId],
) -> (Vec<Node>, Vec<Leaf>, Option<GroundTruth>) {
    let mut new_id = vec![0u32; nodes.len()];
    for (new, &old) in order.iter().enumerate() {
        new_id[old as usize] = new as u32;
    }
    let nodes = order
        .iter()
        .map(|&old| {
            let node = nodes[old as usize];
            Node {
                parent: node.parent.map(|p| new_id[p as usize]),
                ..node
            }
        })
        .collect();
    let leaves = leaves
        .into_iter()
        .map(|leaf| Leaf {
            branch: new_id[leaf.branch as usize],
            ..leaf
        })
        .collect();
    let ground_truth = ground_truth.map(|gt| GroundTruth {
        orders: order.iter().map(|&old| gt.orders[old as usize]).collect(),
        groups: gt
            .groups
            .into_iter()
            .map(|mut g| {
                for c in &mut g.chains {
                    *c = new_id[*c as usize];
                }
                g
            })
            .collect(),
    });
    (nodes, leaves, ground_truth)
}

#[cfg(test)]
#[path = "validate_tests.rs"]
mod tests;
