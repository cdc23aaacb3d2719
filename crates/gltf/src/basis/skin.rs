//! The skeleton of a `skinned` animation: joints that follow the branch
//! hierarchy, their transforms at every sample, and what they leave to
//! morph targets.
//!
//! - **Joints.** Every strand (chain) of the topology starts as a joint,
//!   child of the joint of the strand it branches from. While there are
//!   more than the cap, the joint whose parent's motion carries it best
//!   merges into its parent (a joint always holds a connected piece of
//!   the hierarchy). What a merge costs is measured on the samples: the
//!   farthest any of the joint's vertices, at any sample, is from where
//!   its parent joint's motion carries it ([`merge`]). A twig that turns
//!   with its branch merges early, whatever its size; a strand that
//!   wilts while its parent grows, or swings its own way, keeps its
//!   joint. Merging the lightest joints first instead (what
//!   this did before) merged such strands at the cost of their full
//!   extent: on the default morph, 1,024 joints were then 16.5 % of the
//!   height off, worse than 256. Strands without geometry never get a
//!   joint of their own. Joint 0 is a still root (`tree`) above every
//!   other, so the skin has one common root.
//! - **A joint's motion is its top strand's.** A joint follows the bark
//!   of the strand at its top: the strand the merges were measured
//!   against, and the one whose motion its children most resemble. A
//!   least-squares fit to all of a merged joint's vertices let the strands
//!   merged into it pull it off its own bark; a growing subtree's folded
//!   twigs and leaves pulled its scale to nothing while its limb had
//!   grown half-way. The leaves stay out of the fit as well: they unfold
//!   after their twig has grown.
//! - **Bind pose.** A joint is bound where its top strand's bark is
//!   spread widest: at the sample where it is grown (a growing chain's
//!   first samples hold it collapsed at its junction, which no transform
//!   can unfold). The file's vertex positions are each vertex at its
//!   joint's bind sample. Bark often stands still for many samples while
//!   its leaves fold or unfold (leaves fold before their twig retracts
//!   and unfold after it has grown), so several samples spread the bark
//!   equally widely. [`Bind::Bark`] takes the first of them (rounding
//!   picks which), [`Bind::Open`] the one where all the joint's
//!   vertices spread widest: its leaves open. Neither is better on every
//!   morph (with 4 residual targets, default morph at 256 joints: 3.60 %
//!   of the height against 1.86 %; ash-large → mt-weeping 7.43 % against
//!   8.81 %), so the
//!   caller makes both (the second only when the first misses the budget)
//!   and keeps the one a player shows nearer the samples. Both share the
//!   joints: the merge costs are measured with each strand bound where its
//!   bark spreads widest.
//! - **Transforms.** At every sample a joint's transform is the
//!   similarity (uniform scale, rotation, translation) that carries its
//!   top strand's bind bark closest to where it is, by least squares. So
//!   growth and wilt scale joints from (nearly) zero, and a morph's
//!   turning chains turn their joints. Scales are kept at or above
//!   [`MIN_SCALE`] so that a child's transform relative to a collapsed
//!   parent stays finite; a joint at that scale draws a speck.
//! - **Residual.** What a joint's similarity cannot express (bending
//!   within a merged joint, tip-first growth, leaf outline changes) is the
//!   vertex's offset from its bind position in the joint's own frame;
//!   the caller spans those offsets with a few morph targets, applied
//!   before skinning as glTF does.
//!
//! The rotation of a joint is extracted by the iterative method of
//! Müller et al. 2016 ("A robust method to extract the rotational part of
//! deformations"), warm-started from the previous sample: each fit is a
//! 3 × 3 problem, thousands per animation, where a general SVD call
//! costs more than the fit. Written here because no crate offers it.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use glam::{DMat3, DQuat, DVec3, Mat4, Quat, Vec3};
use rayon::prelude::*;
use treemorph_tree::{FrameTopology, NodeId};

use super::motion::Columns;

/// The smallest joint scale stored.
pub(crate) const MIN_SCALE: f64 = 1e-3;

/// The joints and which joint moves each vertex.
#[derive(Clone, Debug)]
pub(crate) struct Rig {
    /// Per vertex (branch vertices, then leaf vertices): its joint.
    pub(crate) vertex_joint: Vec<u32>,
    /// Per joint: its parent (joint 0, the still root, has none); parents
    /// come before their children.
    pub(crate) parents: Vec<Option<usize>>,
    /// Per joint: the strand at its top (none for the root).
    pub(crate) top_strands: Vec<Option<u32>>,
    /// Per joint: the vertices its motion follows, its top strand's
    /// ([`strand_anchors`]: its bark, else its leaves); all the joint's
    /// vertices where the top strand has none (the still root, or a top
    /// strand without geometry).
    pub(crate) anchors: Vec<Vec<u32>>,
}

impl Rig {
    /// The joints of `topology` for meshes whose branch vertices belong to
    /// `owners` (strand, node), followed by `leaf_vertices` leaf vertices,
    /// `per_leaf` per leaf; at most `cap` joints besides the root (0: one
    /// per strand with geometry), merged where the `samples` show a
    /// strand moving most nearly as its parent joint moves.
    pub(crate) fn new(
        topology: &FrameTopology,
        owners: &[(u32, NodeId)],
        (per_leaf, leaf_vertices): (usize, usize),
        samples: &Samples,
        cap: usize,
    ) -> Rig {
        let strands = topology.strands.len();
        let node_owner = topology.node_owners();
        let parents = topology.strand_parents();
        let vertex_strand: Vec<Option<u32>> = owners
            .iter()
            .map(|&(s, _)| Some(s))
            .chain((0..leaf_vertices).map(|v| {
                let leaf = topology.leaves.get(v / per_leaf.max(1))?;
                node_owner.get(leaf.node as usize).copied().flatten()
            }))
            .collect();
        let mut weights = vec![0u64; strands];
        for s in vertex_strand.iter().flatten() {
            weights[*s as usize] += 1;
        }
        let members = strand_members(&vertex_strand, strands);
        let anchors = strand_anchors(&members, &vertex_strand[..owners.len()]);
        let with_vertices = weights.iter().filter(|&&w| w > 0).count();
        let top = if cap == 0 || with_vertices <= cap {
            // Only the joints without vertices merge: no cost to measure.
            merge(&parents, &weights, |_, _| 0.0, cap)
        } else {
            let motion = StrandMotion::of(&members, &anchors, samples);
            merge(&parents, &weights, |s, t| motion.error(samples, s, t), cap)
        };
        let (joint_of, joint_parents, top_strands) = order_joints(&parents, &top, &weights);
        let vertex_joint: Vec<u32> = vertex_strand
            .iter()
            .map(|s| s.map_or(0, |s| joint_of[top[s as usize] as usize] as u32))
            .collect();
        let anchors = joint_members(&vertex_joint, joint_parents.len())
            .into_iter()
            .zip(&top_strands)
            .map(|(all, top)| match top {
                Some(s) if !anchors[*s as usize].is_empty() => anchors[*s as usize].clone(),
                _ => all,
            })
            .collect();
        Rig {
            vertex_joint,
            parents: joint_parents,
            top_strands,
            anchors,
        }
    }

    pub(crate) fn joint_count(&self) -> usize {
        self.parents.len()
    }

    /// Each joint's vertices.
    pub(crate) fn members(&self) -> Vec<Vec<u32>> {
        joint_members(&self.vertex_joint, self.joint_count())
    }
}

/// The top strand of each strand's joint after merging the cheapest
/// joints into their parents until at most `cap` with vertices remain
/// (0: no cap). Merging a joint into its parent costs `error(s, t)` of
/// its worst strand `s`, `t` the parent joint's top strand; joints
/// without vertices cost nothing, so they merge first.
fn merge(
    parents: &[Option<u32>],
    weights: &[u64],
    error: impl Fn(usize, usize) -> f32 + Sync,
    cap: usize,
) -> Vec<u32> {
    let mut m = Merging::new(parents, weights, &error);
    let mut count = weights.iter().filter(|&&w| w > 0).count();
    while let Some(Reverse((c, s))) = m.heap.pop() {
        let s = s as usize;
        if m.top[s] != s as u32 {
            continue;
        }
        let now = m.cost(s).to_bits();
        if now != c {
            m.heap.push(Reverse((now, s as u32)));
            continue;
        }
        let w = m.weight[s];
        if w > 0 && (cap == 0 || count <= cap) {
            break;
        }
        let Some(parent) = parents[s] else { continue };
        let into = find(&mut m.top, parent as usize);
        if w > 0 && m.weight[into] > 0 {
            count -= 1;
        }
        m.join(s, into);
    }
    (0..parents.len())
        .map(|s| find(&mut m.top, s) as u32)
        .collect()
}

/// The joints while they merge, each named by its top strand: its
/// strands, vertex count, child joints and the cost last measured of
/// merging it into its parent joint; the heap of those costs
/// (`f32` bits, which order as the non-negative costs do).
struct Merging<'a, E> {
    parents: &'a [Option<u32>],
    error: &'a E,
    top: Vec<u32>,
    strands: Vec<Vec<u32>>,
    weight: Vec<u64>,
    children: Vec<Vec<u32>>,
    /// Per top strand: the parent joint's top strand and the cost, as
    /// last measured.
    cached_cost: Vec<Option<(usize, f32)>>,
    heap: BinaryHeap<Reverse<(u32, u32)>>,
}

impl<'a, E: Fn(usize, usize) -> f32 + Sync> Merging<'a, E> {
    /// One joint per strand, each strand's cost measured (in parallel:
    /// the merges that follow measure only the joints they change).
    fn new(parents: &'a [Option<u32>], weights: &[u64], error: &'a E) -> Self {
        let n = parents.len();
        let cached_cost = (0..n)
            .into_par_iter()
            .map(|s| match parents[s] {
                Some(p) if weights[s] > 0 => Some((p as usize, error(s, p as usize))),
                _ => None,
            })
            .collect();
        let mut children = vec![Vec::new(); n];
        for (s, p) in parents.iter().enumerate() {
            if let Some(p) = p {
                children[*p as usize].push(s as u32);
            }
        }
        let mut m = Merging {
            parents,
            error,
            top: (0..n as u32).collect(),
            strands: (0..n as u32).map(|s| vec![s]).collect(),
            weight: weights.to_vec(),
            children,
            cached_cost,
            heap: BinaryHeap::new(),
        };
        for s in (0..n).filter(|&s| parents[s].is_some()) {
            m.push(s);
        }
        m
    }

    /// Queues the joint of top strand `s` at its cost now.
    fn push(&mut self, s: usize) {
        let c = self.cost(s);
        debug_assert!(c >= 0.0, "a merge cost is a distance: {c}");
        self.heap.push(Reverse((c.to_bits(), s as u32)));
    }

    /// What merging the joint of top strand `s` into its parent joint costs.
    fn cost(&mut self, s: usize) -> f32 {
        let Some(parent) = self.parents[s] else {
            return f32::INFINITY;
        };
        if self.weight[s] == 0 {
            return 0.0;
        }
        let into = find(&mut self.top, parent as usize);
        if let Some((i, c)) = self.cached_cost[s]
            && i == into
        {
            return c;
        }
        let c = self.strands[s]
            .iter()
            .map(|&x| (self.error)(x as usize, into))
            .fold(0.0, f32::max);
        self.cached_cost[s] = Some((into, c));
        c
    }

    /// Merges the joint of top strand `s` into that of `into`. `into`'s
    /// cached cost grows by the moved strands' where its parent joint
    /// stays; `s`'s child joints, now `into`'s, are measured against it
    /// and queued again (their queued costs were against `s`).
    fn join(&mut self, s: usize, into: usize) {
        self.top[s] = into as u32;
        let moved = std::mem::take(&mut self.strands[s]);
        if let Some(above) = self.parents[into]
            && let Some((i, c)) = self.cached_cost[into]
            && i == find(&mut self.top, above as usize)
        {
            let more = moved
                .iter()
                .map(|&x| (self.error)(x as usize, i))
                .fold(0.0, f32::max);
            self.cached_cost[into] = Some((i, c.max(more)));
        }
        self.strands[into].extend(moved);
        self.weight[into] += self.weight[s];
        self.weight[s] = 0;
        let children = std::mem::take(&mut self.children[s]);
        for &c in &children {
            if self.top[c as usize] == c {
                self.push(c as usize);
            }
        }
        self.children[into].extend(children);
        if self.parents[into].is_some() {
            self.push(into);
        }
    }
}

/// Each of `joints` joints' vertices, by `vertex_joint`.
fn joint_members(vertex_joint: &[u32], joints: usize) -> Vec<Vec<u32>> {
    let mut out = vec![Vec::new(); joints];
    for (v, &j) in vertex_joint.iter().enumerate() {
        out[j as usize].push(v as u32);
    }
    out
}

/// Per strand, the vertices its motion follows: its bark (the vertices
/// `bark_strand` names), else its `members` (a strand of leaves only).
/// The leaves stay out where there is bark: they unfold after their twig
/// has grown, and while folded they would pull a growing twig's scale to
/// nothing.
fn strand_anchors(members: &[Vec<u32>], bark_strand: &[Option<u32>]) -> Vec<Vec<u32>> {
    let bark = strand_members(bark_strand, members.len());
    bark.into_iter()
        .zip(members)
        .map(|(b, m)| if b.is_empty() { m.clone() } else { b })
        .collect()
}

/// Each strand's vertices (`vertex_strand`'s indices).
fn strand_members(vertex_strand: &[Option<u32>], strands: usize) -> Vec<Vec<u32>> {
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); strands];
    for (v, s) in vertex_strand.iter().enumerate() {
        if let Some(s) = s {
            members[*s as usize].push(v as u32);
        }
    }
    members
}

/// Each strand's own motion: the similarity that carries its anchors
/// ([`strand_anchors`]) from the sample where they spread widest to each
/// sample, as [`Rig`] moves a joint with that strand at its top.
struct StrandMotion<'a> {
    members: &'a [Vec<u32>],
    binds: Vec<usize>,
    fits: Vec<Vec<Similarity>>,
}

impl<'a> StrandMotion<'a> {
    /// The motion of strands of `members` vertices that follow `anchors`.
    fn of(members: &'a [Vec<u32>], anchors: &[Vec<u32>], samples: &Samples) -> Self {
        let binds = bind_samples(anchors, samples);
        let mut bind = vec![Vec3::ZERO; samples.base.len()];
        for (vs, &f) in anchors.iter().zip(&binds) {
            for &v in vs {
                bind[v as usize] = samples.position(f, v as usize);
            }
        }
        let fits = fit_joints(anchors, &bind, samples);
        StrandMotion {
            members,
            binds,
            fits,
        }
    }

    /// The farthest any vertex of strand `s` is, at any sample, from
    /// where strand `t`'s motion carries it from `t`'s bind sample: what
    /// `s` would be off if it were bound to `t`'s joint.
    fn error(&self, samples: &Samples, s: usize, t: usize) -> f32 {
        let b = self.binds[t];
        let members = &self.members[s];
        let at_bind: Vec<DVec3> = members
            .iter()
            .map(|&v| samples.position(b, v as usize).as_dvec3())
            .collect();
        let mut worst = 0f64;
        for (f, fit) in self.fits[t].iter().enumerate() {
            for (&v, &p) in members.iter().zip(&at_bind) {
                let d = fit
                    .apply(p)
                    .distance_squared(samples.position(f, v as usize).as_dvec3());
                worst = worst.max(d);
            }
        }
        worst.sqrt() as f32
    }
}

/// The representative (top strand) of `s`'s joint, compressing the path.
fn find(top: &mut [u32], s: usize) -> usize {
    let mut r = s;
    while top[r] as usize != r {
        r = top[r] as usize;
    }
    let mut c = s;
    while top[c] as usize != r {
        let next = top[c] as usize;
        top[c] = r as u32;
        c = next;
    }
    r
}

/// Joint indices for the top strands that hold vertices, parents first
/// (joint 0 the still root), with each joint's parent and top strand.
#[allow(clippy::type_complexity)]
fn order_joints(
    parents: &[Option<u32>],
    top: &[u32],
    weights: &[u64],
) -> (Vec<usize>, Vec<Option<usize>>, Vec<Option<u32>>) {
    let n = parents.len();
    let mut total = vec![0u64; n];
    for (s, &t) in top.iter().enumerate() {
        total[t as usize] += weights[s];
    }
    let mut children: Vec<Vec<u32>> = vec![Vec::new(); n];
    let mut roots = Vec::new();
    for s in 0..n {
        if top[s] as usize != s {
            continue;
        }
        // The joint above a top strand: its parent strand's joint.
        match parents[s] {
            Some(p) => children[top[p as usize] as usize].push(s as u32),
            None => roots.push(s as u32),
        }
    }
    let mut joint_of = vec![0usize; n];
    let mut joint_parents = vec![None];
    let mut top_strands = vec![None];
    let mut stack: Vec<(u32, usize)> = roots.iter().rev().map(|&r| (r, 0)).collect();
    while let Some((s, above)) = stack.pop() {
        let mut here = above;
        if total[s as usize] > 0 {
            here = joint_parents.len();
            joint_parents.push(Some(above));
            top_strands.push(Some(s));
        }
        joint_of[s as usize] = here;
        stack.extend(children[s as usize].iter().rev().map(|&c| (c, here)));
    }
    (joint_of, joint_parents, top_strands)
}

/// A similarity: `x ↦ s · R x + t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Similarity {
    pub(crate) scale: f64,
    pub(crate) rotation: DQuat,
    pub(crate) translation: DVec3,
}

impl Similarity {
    const IDENTITY: Similarity = Similarity {
        scale: 1.0,
        rotation: DQuat::IDENTITY,
        translation: DVec3::ZERO,
    };

    fn apply(&self, p: DVec3) -> DVec3 {
        self.scale * (self.rotation * p) + self.translation
    }

    fn inverse(&self) -> Similarity {
        let r = self.rotation.inverse();
        Similarity {
            scale: 1.0 / self.scale,
            rotation: r,
            translation: -(r * self.translation) / self.scale,
        }
    }

    /// `self ∘ other`.
    fn then_after(&self, other: &Similarity) -> Similarity {
        Similarity {
            scale: self.scale * other.scale,
            rotation: (self.rotation * other.rotation).normalize(),
            translation: self.apply(other.translation),
        }
    }
}

/// The samples' positions and normals: the base plus each column.
pub(crate) struct Samples<'a> {
    pub(crate) base: &'a [Vec3],
    pub(crate) base_normals: &'a [Vec3],
    pub(crate) displacements: &'a Columns,
    pub(crate) normal_changes: &'a Columns,
}

impl Samples<'_> {
    pub(crate) fn count(&self) -> usize {
        self.displacements.count()
    }

    pub(crate) fn position(&self, f: usize, v: usize) -> Vec3 {
        self.base[v] + self.displacements.vertex(f, v)
    }

    pub(crate) fn normal(&self, f: usize, v: usize) -> Vec3 {
        self.base_normals[v] + self.normal_changes.vertex(f, v)
    }
}

/// Which of the samples where a joint's bark spreads (nearly) widest
/// binds it (see the module docs, *Bind pose*).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Bind {
    /// The first sample where the bark it follows spreads widest.
    Bark,
    /// Of the samples where that bark spreads within [`OPEN_TIE`] of its
    /// widest, the one where all the joint's vertices spread widest (the
    /// bark's own choice when none of them spreads at all).
    Open,
}

/// How near its widest a joint's bark must spread ([`spread`], a sum of
/// squared distances: 0.99 is about 0.5 % in length) for [`Bind::Open`]
/// to bind it there: still bark spreads the same up to rounding, and on
/// the default morph any share from 0.95 to 0.999 picks the same samples.
const OPEN_TIE: f64 = 0.99;

/// Each joint's bind sample: where the vertices it follows (`anchors`,
/// per joint) are spread widest.
pub(crate) fn bind_samples(anchors: &[Vec<u32>], samples: &Samples) -> Vec<usize> {
    anchors
        .par_iter()
        .map(|vs| widest(&spreads(vs, samples), |_| true).unwrap_or(0))
        .collect()
}

/// Each joint's bind sample as `bind` chooses it, `members` its vertices
/// and `anchors` those it follows.
pub(crate) fn bind_samples_by(
    bind: Bind,
    anchors: &[Vec<u32>],
    members: &[Vec<u32>],
    samples: &Samples,
) -> Vec<usize> {
    if bind == Bind::Bark {
        return bind_samples(anchors, samples);
    }
    anchors
        .par_iter()
        .zip(members)
        .map(|(vs, all)| {
            let bark = spreads(vs, samples);
            let own = widest(&bark, |_| true).unwrap_or(0);
            let most = bark[own];
            widest(&spreads(all, samples), |f| bark[f] >= OPEN_TIE * most).unwrap_or(own)
        })
        .collect()
}

/// Per sample, how widely `vertices` spread ([`spread`]).
fn spreads(vertices: &[u32], samples: &Samples) -> Vec<f64> {
    (0..samples.count())
        .map(|f| spread(vertices.iter().map(|&v| samples.position(f, v as usize))))
        .collect()
}

/// The first sample `f` with `among(f)` of the largest `values[f]`, if
/// any is at least 0 (a spread of `NaN` is none).
fn widest(values: &[f64], among: impl Fn(usize) -> bool) -> Option<usize> {
    (0..values.len())
        .filter(|&f| among(f))
        .fold(None, |best: Option<usize>, f| match best {
            Some(b) if values[f] <= values[b] => Some(b),
            _ if values[f] >= 0.0 => Some(f),
            _ => best,
        })
}

/// `Σ |p − mean|²`.
fn spread(points: impl Iterator<Item = Vec3> + Clone) -> f64 {
    let (sum, n) = points
        .clone()
        .fold((DVec3::ZERO, 0usize), |(s, n), p| (s + p.as_dvec3(), n + 1));
    if n == 0 {
        return 0.0;
    }
    let mean = sum / n as f64;
    points.map(|p| (p.as_dvec3() - mean).length_squared()).sum()
}

/// Each joint's similarity at each sample (`[joint][sample]`), carrying
/// the `bind` positions of the vertices it follows (`anchors`, per joint)
/// to the samples' as closely as any does.
pub(crate) fn fit_joints(
    anchors: &[Vec<u32>],
    bind: &[Vec3],
    samples: &Samples,
) -> Vec<Vec<Similarity>> {
    anchors
        .par_iter()
        .map(|vs| {
            let p: Vec<DVec3> = vs.iter().map(|&v| bind[v as usize].as_dvec3()).collect();
            let mut rotation = DQuat::IDENTITY;
            let fits: Vec<Result<Similarity, (DVec3, DVec3)>> = (0..samples.count())
                .map(|f| {
                    let q = vs
                        .iter()
                        .map(|&v| samples.position(f, v as usize).as_dvec3());
                    let fit = fit(&p, q, rotation, if f == 0 { 40 } else { 12 });
                    if let Ok(s) = fit {
                        rotation = s.rotation;
                    }
                    fit
                })
                .collect();
            fill_degenerate(&fits)
        })
        .collect()
}

/// The similarity carrying `p` closest to `q` (least squares), its
/// rotation iterated from `start`, its scale at least [`MIN_SCALE`] (the
/// centroids still map onto each other). Without extent to turn, `q`'s
/// centre (the point it collapsed into) and `p`'s.
fn fit(
    p: &[DVec3],
    q: impl Iterator<Item = DVec3> + Clone,
    start: DQuat,
    iterations: usize,
) -> Result<Similarity, (DVec3, DVec3)> {
    if p.is_empty() {
        return Ok(Similarity::IDENTITY);
    }
    let n = p.len() as f64;
    let mp = p.iter().copied().sum::<DVec3>() / n;
    let mq = q.clone().sum::<DVec3>() / n;
    let mut a = DMat3::ZERO;
    let (mut pp, mut qq) = (0.0, 0.0);
    for (pi, qi) in p.iter().zip(q) {
        let (dp, dq) = (*pi - mp, qi - mq);
        a += DMat3::from_cols(dq * dp.x, dq * dp.y, dq * dp.z);
        pp += dp.length_squared();
        qq += dq.length_squared();
    }
    if pp <= 1e-18 {
        // A joint of one point moves by translation only.
        return Ok(Similarity {
            scale: 1.0,
            rotation: start,
            translation: mq - start * mp,
        });
    }
    if qq <= 1e-14 * pp {
        return Err((mq, mp));
    }
    let rotation = polar_rotation(&a, start, iterations);
    let r = DMat3::from_quat(rotation);
    let scale = ((r.x_axis.dot(a.x_axis) + r.y_axis.dot(a.y_axis) + r.z_axis.dot(a.z_axis)) / pp)
        .max(MIN_SCALE);
    Ok(Similarity {
        scale,
        rotation,
        translation: mq - scale * (rotation * mp),
    })
}

/// The rotation `R` maximising `tr(Rᵀ A)` (Müller et al. 2016), from
/// `start`.
fn polar_rotation(a: &DMat3, start: DQuat, iterations: usize) -> DQuat {
    let mut q = start;
    for _ in 0..iterations {
        let r = DMat3::from_quat(q);
        let dot = r.x_axis.dot(a.x_axis) + r.y_axis.dot(a.y_axis) + r.z_axis.dot(a.z_axis);
        let omega =
            (r.x_axis.cross(a.x_axis) + r.y_axis.cross(a.y_axis) + r.z_axis.cross(a.z_axis))
                / (dot.abs() + 1e-12);
        let w = omega.length();
        if w < 1e-12 {
            break;
        }
        q = (DQuat::from_axis_angle(omega / w, w) * q).normalize();
    }
    q
}

/// Samples at which a joint has no extent (collapsed into its junction)
/// take the smallest scale at the point it collapsed into, with the
/// nearest fitted sample's rotation: the joint shrinks to that point
/// without spinning.
fn fill_degenerate(fits: &[Result<Similarity, (DVec3, DVec3)>]) -> Vec<Similarity> {
    let known: Vec<usize> = (0..fits.len()).filter(|&i| fits[i].is_ok()).collect();
    (0..fits.len())
        .map(|i| match fits[i] {
            Ok(s) => s,
            Err((centre, bind_centre)) => {
                let rotation = known
                    .iter()
                    .min_by_key(|&&k| k.abs_diff(i))
                    .and_then(|&k| fits[k].ok())
                    .map_or(DQuat::IDENTITY, |s| s.rotation);
                Similarity {
                    scale: MIN_SCALE,
                    rotation,
                    translation: centre - MIN_SCALE * (rotation * bind_centre),
                }
            }
        })
        .collect()
}

/// A joint's pose as a glTF node stores it (relative to its parent).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Local {
    pub(crate) translation: Vec3,
    pub(crate) rotation: Quat,
    pub(crate) scale: f32,
}

impl Local {
    pub(crate) fn matrix(&self) -> Mat4 {
        Mat4::from_scale_rotation_translation(
            Vec3::splat(self.scale),
            self.rotation,
            self.translation,
        )
    }
}

/// The skeleton's animation: each joint's origin in the bind pose and
/// its local pose at every sample.
pub(crate) struct Poses {
    /// Per joint: where its node sits in the bind pose (world).
    pub(crate) origins: Vec<Vec3>,
    /// `[joint][sample]`, relative to the parent joint (the root's is the
    /// identity).
    pub(crate) locals: Vec<Vec<Local>>,
}

/// The joints' local poses from their fits: each joint's node sits at
/// `origins[j]` in the bind pose (the inverse bind matrix takes it back
/// there), so its world transform at a sample is `fit ∘ translate(origin)`.
pub(crate) fn poses(rig: &Rig, origins: Vec<Vec3>, mut fits: Vec<Vec<Similarity>>) -> Poses {
    for joint in &mut fits {
        for k in 1..joint.len() {
            if joint[k].rotation.dot(joint[k - 1].rotation) < 0.0 {
                joint[k].rotation = -joint[k].rotation;
            }
        }
    }
    let worlds: Vec<Vec<Similarity>> = fits
        .iter()
        .zip(&origins)
        .map(|(joint, o)| {
            let at = Similarity {
                translation: o.as_dvec3(),
                ..Similarity::IDENTITY
            };
            joint.iter().map(|s| s.then_after(&at)).collect()
        })
        .collect();
    let locals = (0..rig.joint_count())
        .map(|j| match rig.parents[j] {
            None => vec![local_of(&Similarity::IDENTITY); fits[j].len()],
            Some(0) => worlds[j].iter().map(local_of).collect(),
            Some(p) => worlds[j]
                .iter()
                .zip(&worlds[p])
                .map(|(w, pw)| local_of(&pw.inverse().then_after(w)))
                .collect(),
        })
        .map(|mut l: Vec<Local>| {
            for k in 1..l.len() {
                if l[k].rotation.dot(l[k - 1].rotation) < 0.0 {
                    l[k].rotation = -l[k].rotation;
                }
            }
            l
        })
        .collect();
    Poses { origins, locals }
}

fn local_of(s: &Similarity) -> Local {
    Local {
        translation: s.translation.as_vec3(),
        rotation: s.rotation.as_quat().normalize(),
        scale: s.scale as f32,
    }
}

impl Poses {
    /// Each joint's world matrix at sample `f`, composed from the stored
    /// locals in `f32` as a player composes them, times its inverse bind
    /// matrix: the matrix that carries a bind position to the sample.
    pub(crate) fn skinning(&self, rig: &Rig, f: usize) -> Vec<Mat4> {
        let mut world: Vec<Mat4> = Vec::with_capacity(rig.joint_count());
        for j in 0..rig.joint_count() {
            let local = self.locals[j][f].matrix();
            let w = match rig.parents[j] {
                None => local,
                Some(p) => world[p] * local,
            };
            world.push(w);
        }
        world
            .iter()
            .zip(&self.origins)
            .map(|(w, o)| *w * Mat4::from_translation(-*o))
            .collect()
    }
}

/// The residual of every sample (planar columns, like the samples): each
/// vertex's offset from its bind position in its joint's fitted frame,
/// and its normal's turn likewise, at every scale. A nearly collapsed
/// joint's residual is its offset divided by that scale, but the targets
/// are fitted to the error as shown (`weighted`), where the scale weighs
/// it back down. Leaving out the samples below scale 0.05 (as this did
/// before that fit) told the fit that nothing was to be done there: a
/// strand merged into a wilting joint that moved its own way stayed
/// metres off. Default morph, 16 targets: 1.08 % of the height → 0.76 %;
/// six third-party pairs 2.8–9.4 % → 0.6–2.4 %.
pub(crate) fn residuals(
    rig: &Rig,
    fits: &[Vec<Similarity>],
    bind: &[Vec3],
    bind_normals: &[Vec3],
    samples: &Samples,
) -> (Columns, Columns) {
    let rows = 3 * bind.len();
    let count = samples.count();
    let columns: Vec<(Vec<f32>, Vec<f32>)> = (0..count)
        .into_par_iter()
        .map(|f| {
            let inverses: Vec<Similarity> = fits.iter().map(|j| j[f].inverse()).collect();
            let n = bind.len();
            let (mut pos, mut nrm) = (vec![0f32; rows], vec![0f32; rows]);
            for v in 0..n {
                let inv = &inverses[rig.vertex_joint[v] as usize];
                let d = inv.apply(samples.position(f, v).as_dvec3()).as_vec3() - bind[v];
                let dn =
                    (inv.rotation * samples.normal(f, v).as_dvec3()).as_vec3() - bind_normals[v];
                for a in 0..3 {
                    pos[a * n + v] = d[a];
                    nrm[a * n + v] = dn[a];
                }
            }
            (pos, nrm)
        })
        .collect();
    let mut d = Columns::new(rows, count);
    let mut nd = Columns::new(rows, count);
    for (p, n) in columns {
        d.data.extend(p);
        nd.data.extend(n);
    }
    (d, nd)
}

#[cfg(test)]
#[path = "skin_tests.rs"]
mod tests;
