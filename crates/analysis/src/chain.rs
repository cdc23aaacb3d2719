//! Hybrid orders (Eq. 1–2), chains (Table 1) and their rotation-minimising
//! frames.

use glam::{Mat3, Quat, Vec3};
use serde::Serialize;
use treemorph_tree::geom::{NONE, closest_on_segment};
use treemorph_tree::{NodeId, Skeleton};

use crate::options::AnalysisOptions;
use crate::shape::Lobe;

/// Index of a chain in [`crate::Analysis::chains`].
pub type ChainId = u32;

/// A maximal run of consecutive branches of one hybrid order, with the
/// parameters of the morphing paper's Table 1.
///
/// The polyline starts at the **junction**: the node on the parent chain
/// where this chain grows (the root node for root chains), followed by the
/// chain's own nodes, so a chain of `k` branches has `k + 1` polyline
/// points and its branches are named by `nodes[1..]`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Chain {
    /// This chain's index.
    pub id: ChainId,
    /// Hybrid order (1 for root chains).
    pub order: u32,
    /// The chain it grows on; `None` for root chains.
    pub parent: Option<ChainId>,
    /// Chains growing on this one, by growth location.
    pub children: Vec<ChainId>,
    /// The chain group (BPTT node) holding this chain.
    pub group: u32,
    /// Polyline node ids: the junction, then the chain's own nodes.
    pub nodes: Vec<NodeId>,
    /// Polyline points (node positions), metres.
    pub points: Vec<Vec3>,
    /// Branch radius at each polyline point, metres.
    pub radii: Vec<f32>,
    /// Arc length from the junction to each polyline point, metres.
    pub arc_lengths: Vec<f32>,
    /// Total arc length, metres.
    pub length: f32,
    /// Rotation-minimising frame at each polyline point: rotates the
    /// chain-local axes (x = normal, y = tangent, z = binormal) to world
    /// axes. See [`Chain::frame_at`].
    pub frames: Vec<Quat>,
    /// p: arc-length fraction on the parent chain where this chain starts
    /// (0 for root chains; 1 for children of a symmetric fork).
    pub growth_location: f32,
    /// v: unit direction of the chain's start — from the junction to the
    /// chain point at 10 % of its length, or at its first node when the
    /// first branch is longer. The start, not root→tip, because the morph
    /// matches how a chain leaves its parent, and weeping or curved chains
    /// end far from where they point.
    pub branching_vector: Vec3,
    /// OR: the lowest arc-length fraction where child chains grow; 1 when
    /// none does.
    pub outer_ratio: f32,
    /// IR: the lowest arc-length fraction (of the chain-relative leaf
    /// positions) of the inner lobe's leaves; 1 when the IL is empty.
    pub inner_ratio: f32,
    /// IL: the leaves the lobe clustering gave this chain.
    pub inner_lobe: Lobe,
    /// OL: the IL plus the ILs of every chain in the substructure.
    pub outer_lobe: Lobe,
}

impl Chain {
    /// The junction node (first polyline point).
    pub fn junction(&self) -> NodeId {
        self.nodes[0]
    }

    /// The node ending the chain's first branch (what
    /// [`treemorph_tree::GroundTruthGroup::chains`] lists).
    pub fn first_node(&self) -> NodeId {
        self.nodes[1]
    }

    /// The chain's last node.
    pub fn tip(&self) -> Vec3 {
        *self.points.last().expect("a chain has ≥ 2 points")
    }

    /// Number of branches.
    pub fn branch_count(&self) -> usize {
        self.nodes.len() - 1
    }

    /// Segment index and fraction within it at arc-length fraction `u`.
    fn locate(&self, u: f32) -> (usize, f32) {
        let segs = self.points.len() - 1;
        if self.length <= 0.0 {
            let x = u.clamp(0.0, 1.0) * segs as f32;
            let i = (x.floor() as usize).min(segs - 1);
            return (i, x - i as f32);
        }
        let s = u.clamp(0.0, 1.0) * self.length;
        let i = self.arc_lengths.partition_point(|&a| a <= s).clamp(1, segs) - 1;
        let len = self.arc_lengths[i + 1] - self.arc_lengths[i];
        let f = if len > 0.0 {
            (s - self.arc_lengths[i]) / len
        } else {
            0.0
        };
        (i, f.clamp(0.0, 1.0))
    }

    /// Point and radius at arc-length fraction `u` ∈ [0, 1].
    pub fn point_at(&self, u: f32) -> (Vec3, f32) {
        let (i, f) = self.locate(u);
        (
            self.points[i].lerp(self.points[i + 1], f),
            self.radii[i] + (self.radii[i + 1] - self.radii[i]) * f,
        )
    }

    /// The chain-local frame at arc-length fraction `u`, interpolated
    /// (slerp) between the polyline points' rotation-minimising frames.
    pub fn frame_at(&self, u: f32) -> Quat {
        let (i, f) = self.locate(u);
        self.frames[i].slerp(self.frames[i + 1], f)
    }

    /// Arc-length fraction of a polyline point.
    pub fn param_of_point(&self, index: usize) -> f32 {
        if self.length > 0.0 {
            self.arc_lengths[index] / self.length
        } else {
            index as f32 / (self.points.len() - 1) as f32
        }
    }

    /// Arc-length fraction of the polyline point closest to `p`.
    pub fn project(&self, p: Vec3) -> f32 {
        let mut best = (f32::INFINITY, 0.0);
        for i in 0..self.points.len() - 1 {
            let (a, b) = (self.points[i], self.points[i + 1]);
            let (q, f) = closest_on_segment(p, a, b);
            let d = p.distance_squared(q);
            if d < best.0 {
                let u = if self.length > 0.0 {
                    (self.arc_lengths[i] + f * (b - a).length()) / self.length
                } else {
                    (i as f32 + f) / (self.points.len() - 1) as f32
                };
                best = (d, u);
            }
        }
        best.1
    }
}

/// What the ordering pass knows about each node and chain.
pub(crate) struct Ordering {
    /// Hybrid order of the branch ending at each node (root: 1).
    pub orders: Vec<u32>,
    /// Chain of the branch ending at each node (root: [`NONE`]).
    pub chain_of: Vec<ChainId>,
    /// Index of each node in its chain's polyline (root: 0).
    pub index_in_chain: Vec<u32>,
    /// Chain polylines and facts.
    pub seeds: Vec<ChainSeed>,
}

pub(crate) struct ChainSeed {
    pub nodes: Vec<NodeId>,
    pub order: u32,
    pub parent: Option<ChainId>,
    /// Started at a symmetric (Weibull) fork or at the root: these chains
    /// form a group of their own, never merged with nearby laterals.
    pub at_fork: bool,
}

fn population_std(values: &[f32]) -> (f32, f32) {
    let n = values.len() as f32;
    let mean = values.iter().sum::<f32>() / n;
    let var = values.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / n;
    (mean, var.sqrt())
}

/// Eq. 1–2 from the root to the tips, building chains as it goes.
pub(crate) fn order(skeleton: &Skeleton, options: &AnalysisOptions) -> Ordering {
    let n = skeleton.len();
    let nodes = skeleton.nodes();
    let mut orders = vec![1u32; n];
    let mut chain_of = vec![NONE; n];
    let mut index_in_chain = vec![0u32; n];
    let mut seeds: Vec<ChainSeed> = Vec::new();
    let mut angles = Vec::new();
    let mut radii = Vec::new();

    let start = |seeds: &mut Vec<ChainSeed>,
                 chain_of: &mut [u32],
                 index_in_chain: &mut [u32],
                 orders: &mut [u32],
                 junction: NodeId,
                 child: NodeId,
                 order: u32,
                 parent: Option<ChainId>,
                 at_fork: bool| {
        let id = seeds.len() as ChainId;
        seeds.push(ChainSeed {
            nodes: vec![junction, child],
            order,
            parent,
            at_fork,
        });
        chain_of[child as usize] = id;
        index_in_chain[child as usize] = 1;
        orders[child as usize] = order;
    };

    for id in 0..n as NodeId {
        let children = skeleton.children(id);
        if children.is_empty() {
            continue;
        }
        let node = &nodes[id as usize];
        if id == 0 {
            // Every child of the root starts an order-1 root chain; together
            // they are the root group (one stem, or a multi-stem shrub).
            for &c in children {
                start(
                    &mut seeds,
                    &mut chain_of,
                    &mut index_in_chain,
                    &mut orders,
                    0,
                    c,
                    1,
                    None,
                    true,
                );
            }
            continue;
        }
        let chain = chain_of[id as usize];
        let order = orders[id as usize];
        if let [only] = children {
            let seed = &mut seeds[chain as usize];
            index_in_chain[*only as usize] = seed.nodes.len() as u32;
            seed.nodes.push(*only);
            chain_of[*only as usize] = chain;
            orders[*only as usize] = order;
            continue;
        }
        let parent = node.parent.expect("non-root");
        let incoming = (node.position - nodes[parent as usize].position).normalize_or(Vec3::Y);
        angles.clear();
        radii.clear();
        for &c in children {
            let dir = (nodes[c as usize].position - node.position).normalize_or(incoming);
            angles.push(dir.dot(incoming).clamp(-1.0, 1.0).acos().to_degrees());
            radii.push(nodes[c as usize].radius);
        }
        let (_, sigma_a) = population_std(&angles);
        let (mean_r, sigma_r) = population_std(&radii);
        let weibull =
            sigma_a <= options.weibull_angle && sigma_r <= options.weibull_radius * mean_r;
        // Gravelius continuation: the smallest branching angle; near-ties
        // (within 0.01°) go to the thicker child, then the lower id. None
        // when that turns back more than `continuation_angle`.
        let continuation = if weibull {
            None
        } else {
            let mut best = 0;
            for k in 1..children.len() {
                let (a, b) = (angles[k], angles[best]);
                if a < b - 0.01 || ((a - b).abs() <= 0.01 && radii[k] > radii[best]) {
                    best = k;
                }
            }
            (angles[best] <= options.continuation_angle).then_some(children[best])
        };
        for &c in children {
            if Some(c) == continuation {
                let seed = &mut seeds[chain as usize];
                index_in_chain[c as usize] = seed.nodes.len() as u32;
                seed.nodes.push(c);
                chain_of[c as usize] = chain;
                orders[c as usize] = order;
            } else {
                start(
                    &mut seeds,
                    &mut chain_of,
                    &mut index_in_chain,
                    &mut orders,
                    id,
                    c,
                    order + 1,
                    Some(chain),
                    weibull,
                );
            }
        }
    }
    Ordering {
        orders,
        chain_of,
        index_in_chain,
        seeds,
    }
}

/// Builds the chains' geometry, growth locations, branching vectors, OR and
/// frames. Groups, IR and lobes are filled in later.
pub(crate) fn build_chains(skeleton: &Skeleton, ordering: &Ordering) -> Vec<Chain> {
    let mut chains: Vec<Chain> = Vec::with_capacity(ordering.seeds.len());
    for (id, seed) in ordering.seeds.iter().enumerate() {
        let points: Vec<Vec3> = seed
            .nodes
            .iter()
            .map(|&n| skeleton.node(n).position)
            .collect();
        let radii: Vec<f32> = seed
            .nodes
            .iter()
            .map(|&n| skeleton.node(n).radius)
            .collect();
        let mut arc_lengths = Vec::with_capacity(points.len());
        let mut s = 0.0;
        arc_lengths.push(0.0);
        for w in points.windows(2) {
            s += w[0].distance(w[1]);
            arc_lengths.push(s);
        }
        let mut chain = Chain {
            id: id as ChainId,
            order: seed.order,
            parent: seed.parent,
            children: Vec::new(),
            group: 0,
            nodes: seed.nodes.clone(),
            points,
            radii,
            arc_lengths,
            length: s,
            frames: Vec::new(),
            growth_location: 0.0,
            branching_vector: Vec3::Y,
            outer_ratio: 1.0,
            inner_ratio: 1.0,
            inner_lobe: Lobe::default(),
            outer_lobe: Lobe::default(),
        };
        let reach = if chain.length > 0.0 {
            (chain.arc_lengths[1].max(0.1 * chain.length) / chain.length).min(1.0)
        } else {
            1.0
        };
        let fallback = match seed.parent {
            Some(p) => {
                let parent = &chains[p as usize];
                let j = ordering.index_in_chain[chain.junction() as usize] as usize;
                tangent(&parent.points, j)
            }
            None => Vec3::Y,
        };
        chain.branching_vector = (chain.point_at(reach).0 - chain.points[0]).normalize_or(fallback);
        if let Some(p) = seed.parent {
            let j = ordering.index_in_chain[chain.junction() as usize] as usize;
            let parent = &mut chains[p as usize];
            chain.growth_location = parent.param_of_point(j);
            parent.children.push(id as ChainId);
            parent.outer_ratio = parent.outer_ratio.min(chain.growth_location);
        }
        chain.frames = rotation_minimising_frames(&chain, &chains, ordering);
        chains.push(chain);
    }
    for chain in &mut chains {
        // Sort children by growth location (ties: id) for stable traversal.
        let mut kids = std::mem::take(&mut chain.children);
        kids.sort_by_key(|&c| {
            (
                ordering.index_in_chain[ordering.seeds[c as usize].nodes[0] as usize],
                c,
            )
        });
        chain.children = kids;
    }
    chains
}

/// Unit tangent of a polyline at point `i`: the mean of the adjacent
/// segment directions.
pub(crate) fn tangent(points: &[Vec3], i: usize) -> Vec3 {
    let last = points.len() - 1;
    let inc = if i > 0 {
        (points[i] - points[i - 1]).normalize_or_zero()
    } else {
        Vec3::ZERO
    };
    let out = if i < last {
        (points[i + 1] - points[i]).normalize_or_zero()
    } else {
        Vec3::ZERO
    };
    let t = (inc + out).normalize_or_zero();
    if t != Vec3::ZERO {
        return t;
    }
    // Zero-length segments or a reversal: use whichever direction exists,
    // searching further along the polyline.
    points
        .windows(2)
        .map(|w| (w[1] - w[0]).normalize_or_zero())
        .find(|d| *d != Vec3::ZERO)
        .unwrap_or(Vec3::Y)
}

/// Double-reflection rotation-minimising frames (Wang et al. 2008). The
/// first normal is the parent chain's frame normal at the junction (so a
/// chain's frame is tied to its parent's and a morph can carry children
/// along), projected off the tangent; root chains start from +X.
fn rotation_minimising_frames(chain: &Chain, chains: &[Chain], ordering: &Ordering) -> Vec<Quat> {
    let k = chain.points.len();
    let tangents: Vec<Vec3> = (0..k).map(|i| tangent(&chain.points, i)).collect();
    let (ref_n, ref_b) = match chain.parent {
        Some(p) => {
            let parent = &chains[p as usize];
            let j = ordering.index_in_chain[chain.junction() as usize] as usize;
            let q = parent.frames[j];
            (q * Vec3::X, q * Vec3::Z)
        }
        None => (Vec3::X, Vec3::Z),
    };
    let t0 = tangents[0];
    let mut r = (ref_n - t0 * ref_n.dot(t0)).normalize_or_zero();
    if r.length_squared() < 0.5 {
        r = (ref_b - t0 * ref_b.dot(t0)).normalize_or_zero();
    }
    if r.length_squared() < 0.5 {
        r = t0.any_orthonormal_vector();
    }
    let mut frames = Vec::with_capacity(k);
    frames.push(frame_quat(r, t0));
    for i in 0..k - 1 {
        let v1 = chain.points[i + 1] - chain.points[i];
        let c1 = v1.length_squared();
        let (ti, tn) = (tangents[i], tangents[i + 1]);
        let next = if c1 <= f32::MIN_POSITIVE {
            r
        } else {
            let rl = r - v1 * (2.0 / c1 * v1.dot(r));
            let tl = ti - v1 * (2.0 / c1 * v1.dot(ti));
            let v2 = tn - tl;
            let c2 = v2.length_squared();
            if c2 <= f32::MIN_POSITIVE {
                rl
            } else {
                rl - v2 * (2.0 / c2 * v2.dot(rl))
            }
        };
        let mut nr = (next - tn * next.dot(tn)).normalize_or_zero();
        if nr.length_squared() < 0.5 {
            nr = tn.any_orthonormal_vector();
        }
        r = nr;
        frames.push(frame_quat(r, tn));
    }
    frames
}

fn frame_quat(normal: Vec3, tangent: Vec3) -> Quat {
    Quat::from_mat3(&Mat3::from_cols(normal, tangent, normal.cross(tangent))).normalize()
}
