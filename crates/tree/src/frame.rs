//! Frames: the in-between trees of an animation.
//!
//! Both pipelines produce a sequence of frames that share one **union
//! topology** ([`FrameTopology`]): the same nodes, strands and leaves in
//! every frame. Chains that grow exist at zero size before they appear,
//! chains that split are duplicated from the first frame, and wilting chains
//! shrink to zero size instead of disappearing. Only positions, radii and
//! leaf parameters change from frame to frame ([`Frame`]), which is what
//! lets the output stage write one animated glTF with morph targets and a
//! delta stream of positions only.
//!
//! Branch geometry is described by [`Strands`]: polylines of node ids swept
//! into generalised cylinders. A strand's first node is either the root, a
//! node it shares with the strand it grows from (a skeleton junction), or a
//! node the pipeline placed on its parent's axis (a growth location between
//! two parent nodes). Meshing needs nothing else, so node parents are kept
//! only for connectivity checks.

use glam::{Quat, Vec3};

use crate::model::{Bark, LeafMaterial, NodeId, Skeleton, Tree};

/// A decomposition of a skeleton into polylines, each swept as one tube.
///
/// Every branch of the skeleton lies on exactly one strand; consecutive ids
/// of a strand are parent and child.
#[derive(Clone, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct Strands {
    offsets: Vec<u32>,
    nodes: Vec<NodeId>,
}

impl Strands {
    /// Builds strands from node-id polylines.
    pub fn from_polylines<I, P>(polylines: I) -> Strands
    where
        I: IntoIterator<Item = P>,
        P: IntoIterator<Item = NodeId>,
    {
        let mut strands = Strands {
            offsets: vec![0],
            nodes: Vec::new(),
        };
        for p in polylines {
            strands.nodes.extend(p);
            strands.offsets.push(strands.nodes.len() as u32);
        }
        strands
    }

    /// Decomposes a skeleton: at each junction the child that turns least
    /// from the incoming direction (ties: the thicker one) continues the
    /// strand; every other child starts a strand at the junction node.
    pub fn of_skeleton(skeleton: &Skeleton) -> Strands {
        let mut polylines: Vec<Vec<NodeId>> = Vec::new();
        let mut starts: Vec<(NodeId, Option<NodeId>)> = vec![(0, None)];
        while let Some((start, junction)) = starts.pop() {
            let mut line = Vec::new();
            line.extend(junction);
            line.push(start);
            let mut at = start;
            loop {
                let children = skeleton.children(at);
                if children.is_empty() {
                    break;
                }
                let node = skeleton.node(at);
                let incoming = match node.parent {
                    Some(p) => (node.position - skeleton.node(p).position).normalize_or(Vec3::Y),
                    None => Vec3::Y,
                };
                let score = |c: NodeId| {
                    let child = skeleton.node(c);
                    let dir = (child.position - node.position).normalize_or(incoming);
                    (dir.dot(incoming), child.radius)
                };
                let next = *children
                    .iter()
                    .max_by(|&&a, &&b| {
                        score(a)
                            .partial_cmp(&score(b))
                            .unwrap_or(std::cmp::Ordering::Equal)
                    })
                    .expect("children is not empty");
                for &c in children.iter().rev() {
                    if c != next {
                        starts.push((c, Some(at)));
                    }
                }
                line.push(next);
                at = next;
            }
            polylines.push(line);
        }
        Strands::from_polylines(polylines)
    }

    /// Number of strands.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Whether there are no strands.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The node ids of strand `i`.
    pub fn get(&self, i: usize) -> &[NodeId] {
        &self.nodes[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// All strands in order.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = &[NodeId]> + '_ {
        (0..self.len()).map(|i| self.get(i))
    }

    /// Total number of node references over all strands.
    pub fn total_points(&self) -> usize {
        self.nodes.len()
    }
}

/// The fixed part of a leaf in a frame sequence.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FrameLeafTopology {
    /// The node whose branch the leaf rides on in every frame.
    pub node: NodeId,
    /// Leaf materials blended from `materials[0]` (blend 0) to
    /// `materials[1]` (blend 1); the same twice when the leaf keeps its look.
    pub materials: [u32; 2],
}

/// What every frame of a sequence shares.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameTopology {
    /// Parent of each node (`None` for the root).
    pub parents: Vec<Option<NodeId>>,
    /// The polylines swept into branch tubes.
    pub strands: Strands,
    /// Per leaf: its branch and material pair.
    pub leaves: Vec<FrameLeafTopology>,
    /// Leaf materials referenced by [`FrameLeafTopology::materials`].
    pub leaf_materials: Vec<LeafMaterial>,
    /// Bark at blend 0 and at blend 1.
    pub bark: [Bark; 2],
}

impl FrameTopology {
    /// The topology of a single static tree.
    pub fn of_tree(tree: &Tree) -> FrameTopology {
        let skeleton = tree.skeleton();
        FrameTopology {
            parents: skeleton.nodes().iter().map(|n| n.parent).collect(),
            strands: Strands::of_skeleton(skeleton),
            leaves: tree
                .leaves()
                .iter()
                .map(|l| FrameLeafTopology {
                    node: l.branch,
                    materials: [l.material; 2],
                })
                .collect(),
            leaf_materials: tree.materials().leaves.clone(),
            bark: [tree.materials().bark.clone(), tree.materials().bark.clone()],
        }
    }

    /// Number of nodes in every frame.
    pub fn node_count(&self) -> usize {
        self.parents.len()
    }

    /// The strand each node belongs to, as the mesher assigns it: the
    /// strand holding the branch that ends at it, else the first strand
    /// starting there (`None` for a node on no strand).
    pub fn node_owners(&self) -> Vec<Option<u32>> {
        let mut owner = vec![None; self.node_count()];
        for (s, ids) in self.strands.iter().enumerate() {
            for &id in ids.iter().skip(1) {
                owner[id as usize].get_or_insert(s as u32);
            }
        }
        for (s, ids) in self.strands.iter().enumerate() {
            if let Some(&first) = ids.first() {
                owner[first as usize].get_or_insert(s as u32);
            }
        }
        owner
    }

    /// Each strand's parent strand: the owner ([`FrameTopology::node_owners`])
    /// of its first node when another strand owns it (a strand that starts
    /// at its junction), else the owner of that node's parent node (a
    /// strand that starts just past it); `None` for a root strand.
    pub fn strand_parents(&self) -> Vec<Option<u32>> {
        let node_owner = self.node_owners();
        self.strands
            .iter()
            .enumerate()
            .map(|(s, ids)| {
                let first = *ids.first()? as usize;
                let other = |o: &u32| *o != s as u32;
                node_owner[first].filter(other).or_else(|| {
                    let parent = self.parents.get(first).copied().flatten()?;
                    node_owner[parent as usize].filter(other)
                })
            })
            .collect()
    }
}

/// A leaf in one frame.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameLeaf {
    /// World position of the anchor (base of the blade), metres.
    pub anchor: Vec3,
    /// Rotation from the leaf's local frame (blade along +Y, facing +Z).
    pub orientation: Quat,
    /// Blade width, metres (0 for a leaf not grown yet or wilted).
    pub width: f32,
    /// Blade height, metres.
    pub height: f32,
    /// Material blend in [0, 1] between the topology's two materials.
    pub blend: f32,
}

impl FrameLeaf {
    /// The corners of the leaf's quad as the output stage meshes it: the
    /// anchor at the middle of its base edge, `width` across and `height`
    /// up its orientation's x and y axes.
    pub fn corners(&self) -> [Vec3; 4] {
        let across = self.orientation * Vec3::X * (0.5 * self.width.max(0.0));
        let up = self.orientation * Vec3::Y * self.height.max(0.0);
        let a = self.anchor;
        [a - across, a + across, a + across + up, a - across + up]
    }
}

/// How far a sequence moves per frame: the farthest any node or leaf
/// corner moved since the previous frame measured.
#[derive(Clone, Debug, Default)]
pub struct JumpMeter {
    previous: Vec<Vec3>,
    has_previous: bool,
}

impl JumpMeter {
    /// The largest distance a node or a leaf quad's corner of `frame`
    /// moved since the previous frame (0 for the first, or after a change
    /// of topology), in metres; keeps this frame's.
    pub fn jump(&mut self, frame: &Frame) -> f32 {
        let count = frame.positions.len() + 4 * frame.leaves.len();
        let compare = self.has_previous && self.previous.len() == count;
        self.previous.resize(count, Vec3::ZERO);
        // Squared distances: the square root of the largest is the largest
        // root. The nodes, then each leaf's four corners (two rotations),
        // in the order of `Frame::points`, in two plain loops rather than
        // one iterator chaining both.
        let (nodes, corners) = self.previous.split_at_mut(frame.positions.len());
        let mut max2 = 0.0f32;
        let mut keep = |kept: &mut Vec3, p: Vec3| {
            if compare {
                max2 = max2.max(p.distance_squared(*kept));
            }
            *kept = p;
        };
        for (kept, &p) in nodes.iter_mut().zip(&frame.positions) {
            keep(kept, p);
        }
        for (kept, leaf) in corners.chunks_exact_mut(4).zip(&frame.leaves) {
            for (kept, p) in kept.iter_mut().zip(leaf.corners()) {
                keep(kept, p);
            }
        }
        self.has_previous = true;
        max2.sqrt()
    }

    /// Forgets the previous frame (the next jump is 0).
    pub fn reset(&mut self) {
        self.has_previous = false;
    }
}

/// The largest per-frame jump of a sequence ([`JumpMeter::jump`] of each
/// frame) over the median one, frames after the first (which has no
/// predecessor): 1 for uniform motion, large for a spike; 0 when the
/// median frame does not move.
pub fn jump_ratio(max_jump: &[f32]) -> f32 {
    let mut jumps = max_jump.get(1..).unwrap_or_default().to_vec();
    if jumps.is_empty() {
        return 0.0;
    }
    jumps.sort_by(f32::total_cmp);
    let median = jumps[jumps.len() / 2];
    let max = jumps[jumps.len() - 1];
    if median > 0.0 { max / median } else { 0.0 }
}

/// One in-between tree: the varying part of a frame sequence.
/// `Frame::default()` is an empty frame at t = 0, a buffer for a morpher
/// or sketcher to fill.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Frame {
    /// Animation time in [0, 1].
    pub t: f32,
    /// Node positions, metres.
    pub positions: Vec<Vec3>,
    /// Node radii, metres (0 for chains not grown yet or wilted).
    pub radii: Vec<f32>,
    /// Leaves, in topology order.
    pub leaves: Vec<FrameLeaf>,
    /// Bark blend in [0, 1].
    pub bark_blend: f32,
}

/// Why a frame does not fit a topology.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("frame does not fit its topology: {0}")]
pub struct FrameMismatch(pub String);

impl Frame {
    /// Every node, then every leaf quad's corners ([`FrameLeaf::corners`]).
    pub fn points(&self) -> impl Iterator<Item = Vec3> + '_ {
        self.positions
            .iter()
            .copied()
            .chain(self.leaves.iter().flat_map(FrameLeaf::corners))
    }

    /// The frame of a static tree (t = 0).
    pub fn of_tree(tree: &Tree) -> Frame {
        let nodes = tree.skeleton().nodes();
        Frame {
            t: 0.0,
            positions: nodes.iter().map(|n| n.position).collect(),
            radii: nodes.iter().map(|n| n.radius).collect(),
            leaves: tree
                .leaves()
                .iter()
                .map(|l| FrameLeaf {
                    anchor: tree.leaf_anchor(l),
                    orientation: l.orientation,
                    width: l.width,
                    height: l.height,
                    blend: 0.0,
                })
                .collect(),
            bark_blend: 0.0,
        }
    }

    /// Checks counts and numbers against a topology, so encoders can trust
    /// the frame.
    pub fn check(&self, topology: &FrameTopology) -> Result<(), FrameMismatch> {
        let n = topology.node_count();
        if self.positions.len() != n || self.radii.len() != n {
            return Err(FrameMismatch(format!(
                "{} positions and {} radii for {} nodes",
                self.positions.len(),
                self.radii.len(),
                n
            )));
        }
        if self.leaves.len() != topology.leaves.len() {
            return Err(FrameMismatch(format!(
                "{} leaves for {} in the topology",
                self.leaves.len(),
                topology.leaves.len()
            )));
        }
        if let Some(i) = self.positions.iter().position(|p| !p.is_finite()) {
            return Err(FrameMismatch(format!("position {i} is not finite")));
        }
        if let Some(i) = self.radii.iter().position(|r| !r.is_finite() || *r < 0.0) {
            return Err(FrameMismatch(format!(
                "radius {i} is negative or not finite"
            )));
        }
        if let Some(i) = self.leaves.iter().position(|l| {
            !(l.anchor.is_finite()
                && l.orientation.is_finite()
                && l.width.is_finite()
                && l.height.is_finite()
                && l.width >= 0.0
                && l.height >= 0.0
                && (0.0..=1.0).contains(&l.blend))
        }) {
            return Err(FrameMismatch(format!("leaf {i} has an invalid number")));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Limits, Node, TreeParts};

    fn fork() -> Tree {
        let node = |x: f32, y: f32, parent: Option<u32>| Node {
            position: Vec3::new(x, y, 0.0),
            radius: 0.1,
            parent,
        };
        Tree::new(
            TreeParts {
                nodes: vec![
                    node(0.0, 0.0, None),
                    node(0.0, 1.0, Some(0)),
                    node(0.7, 1.7, Some(1)),
                    node(0.05, 2.0, Some(1)),
                    node(0.1, 3.0, Some(3)),
                ],
                ..TreeParts::default()
            },
            &Limits::default(),
        )
        .unwrap()
    }

    #[test]
    fn strands_cover_every_branch_once_and_follow_the_straightest_child() {
        let tree = fork();
        let strands = Strands::of_skeleton(tree.skeleton());
        let lines: Vec<Vec<u32>> = strands.iter().map(<[u32]>::to_vec).collect();
        assert_eq!(lines, vec![vec![0, 1, 3, 4], vec![1, 2]]);
        let mut edges: Vec<(u32, u32)> = lines
            .iter()
            .flat_map(|l| l.windows(2).map(|w| (w[0], w[1])).collect::<Vec<_>>())
            .collect();
        edges.sort_unstable();
        assert_eq!(edges, vec![(0, 1), (1, 2), (1, 3), (3, 4)]);
    }

    #[test]
    fn a_static_frame_fits_its_topology() {
        let tree = fork();
        let topology = FrameTopology::of_tree(&tree);
        let mut frame = Frame::of_tree(&tree);
        assert_eq!(frame.check(&topology), Ok(()));
        frame.radii[2] = -1.0;
        assert!(frame.check(&topology).is_err());
        frame.radii.pop();
        assert!(frame.check(&topology).is_err());
    }
}
