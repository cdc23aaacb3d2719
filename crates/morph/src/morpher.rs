//! [`Morpher`]: one in-between tree per call, in buffers it keeps.

use glam::{Quat, Vec3};
use rayon::prelude::*;
use treemorph_tree::geom::NONE;
use treemorph_tree::{Frame, FrameLeaf};

use crate::correspondence::Operation;
use crate::plan::{ChainPlan, LeafMode, LeafPlan, MorphPlan, Sample};

/// Chains per rayon task when a level is split across threads.
const CHAINS_PER_TASK: usize = 256;
/// Leaves per rayon task.
const LEAVES_PER_TASK: usize = 2048;

/// The segment `j` of a chain holding union parameter `p`, `u[j] ≤ p ≤
/// u[j + 1]`, searched among segments `lo..=hi` (`u`: the chain's sample
/// parameters, nondecreasing from exactly 0 to exactly 1). A growth
/// location or leaf moves monotonically between its segments at t = 0 and
/// t = 1, which the plan stores, so most lookups need no search at all.
#[inline]
pub(crate) fn segment(u: &[f32], p: f32, lo: usize, hi: usize) -> usize {
    if lo >= hi {
        return lo;
    }
    lo + u[lo + 1..=hi].partition_point(|&x| x <= p)
}

/// The segment holding `p` among all of a chain's segments.
#[inline]
pub(crate) fn locate(u: &[f32], p: f32) -> usize {
    segment(u, p, 0, u.len() - 2)
}

/// Point and frame at union parameter `p` in segment `j` of a chain, given
/// its sample parameters, inverse segment spans, positions and frames:
/// positions linearly, frames by normalised lerp (adjacent sample frames
/// differ by a few degrees at most, where nlerp and slerp agree to well
/// under a microradian). The plan uses this same function on the input
/// chains, so a frame at t = 0 or 1 reproduces the inputs.
#[inline]
pub(crate) fn point_frame(
    u: &[f32],
    inv_span: &[f32],
    x: &[Vec3],
    h: &[Quat],
    j: usize,
    p: f32,
) -> (Vec3, Quat) {
    let f = fraction(u, inv_span, j, p);
    (x[j].lerp(x[j + 1], f), h[j].lerp(h[j + 1], f))
}

/// Where `p` lies in segment `j`, in [0, 1].
#[inline]
pub(crate) fn fraction(u: &[f32], inv_span: &[f32], j: usize, p: f32) -> f32 {
    ((p - u[j]) * inv_span[j]).clamp(0.0, 1.0)
}

/// The interpolation weight of a point at union parameter `u` of a chain
/// carried by `op` at time `t` (§6.1; see the crate docs, *Split and
/// merge*). Continuous in `t` for every `u > 0`, 0 at `t = 0` and 1 at
/// `t = 1`.
#[inline]
pub fn point_weight(op: Operation, slow_down: bool, u: f32, t: f32) -> f32 {
    if !slow_down || t <= 0.0 || t >= 1.0 {
        return t.clamp(0.0, 1.0);
    }
    let base = 1.0 - t; // chn^(1−t) is the part [0, 1 − t]
    match op {
        // b = u / (1 − t) on the base part: b·t there, t on the tip part.
        Operation::Split => t * (u / base).min(1.0),
        // min(1, (2 − b)·t) on the base part, t on the tip part.
        Operation::Merge if u < base => ((2.0 - u / base) * t).min(1.0),
        _ => t,
    }
}

/// `(sin x, cos x)` for `x ∈ [0, π]` (every slerp angle here), inlined:
/// Taylor polynomials of the half angle (degree 11 and 12, error below
/// 1e-7 on [0, π/2]) and the double-angle formulas. Exact at `x = 0`, so a
/// frame at t = 0 is untouched; several times cheaper than a libm call,
/// which was a fifth of a frame.
#[inline]
pub(crate) fn sin_cos(x: f32) -> (f32, f32) {
    let y = 0.5 * x;
    let y2 = y * y;
    let s = y
        * (1.0
            + y2 * (-1.0 / 6.0
                + y2 * (1.0 / 120.0
                    + y2 * (-1.0 / 5040.0 + y2 * (1.0 / 362_880.0 + y2 * (-1.0 / 39_916_800.0))))));
    let c = 1.0
        + y2 * (-0.5
            + y2 * (1.0 / 24.0
                + y2 * (-1.0 / 720.0
                    + y2 * (1.0 / 40320.0
                        + y2 * (-1.0 / 3_628_800.0 + y2 * (1.0 / 479_001_600.0))))));
    (2.0 * s * c, c * c - s * s)
}

#[inline]
fn arc(a: Vec3, perp: Vec3, angle: f32, w: f32) -> Vec3 {
    if angle == 0.0 {
        return a;
    }
    let (s, c) = sin_cos(angle * w);
    a * c + perp * s
}

#[inline]
fn arc_q(a: Quat, perp: Quat, angle: f32, w: f32) -> Quat {
    if angle == 0.0 {
        return a;
    }
    let (s, c) = sin_cos(angle * w);
    a * c + perp * s
}

/// Morphs one chain: its junction on the parent at the interpolated growth
/// location, then segment by segment in the parent's frame there.
#[allow(clippy::too_many_arguments)]
#[inline]
fn morph_chain(
    chain: &ChainPlan,
    samples: &[Sample],
    u: &[f32],
    inv_span: &[f32],
    root: Vec3,
    slow_down: bool,
    t: f32,
    done_pos: &[Vec3],
    done_frames: &[Quat],
    pos: &mut [Vec3],
    rad: &mut [f32],
    frames: &mut [Quat],
) {
    let first = chain.first as usize;
    let k = chain.len as usize;
    let own = &samples[first..first + k];
    let own_u = &u[first..first + k];
    let p = chain.p[0] + (chain.p[1] - chain.p[0]) * t;
    let (junction, anchor) = if chain.parent == NONE {
        (root, Quat::IDENTITY)
    } else {
        let pf = chain.parent_first as usize;
        let pk = chain.parent_len as usize;
        let pu = &u[pf..pf + pk];
        let [lo, hi] = chain.parent_segments;
        point_frame(
            pu,
            &inv_span[pf..pf + pk],
            &done_pos[1 + pf..1 + pf + pk],
            &done_frames[pf..pf + pk],
            segment(pu, p, lo as usize, hi as usize),
            p,
        )
    };
    let op = chain.operation;
    pos[0] = junction;
    for i in 0..k - 1 {
        let s = &own[i];
        let w = point_weight(op, slow_down, own_u[i + 1], t);
        let dir = arc(s.dir, s.dir_perp, s.theta, w);
        let len = s.len[0] + (s.len[1] - s.len[0]) * w;
        pos[i + 1] = pos[i] + anchor * (dir * len);
    }
    for i in 0..k {
        let s = &own[i];
        // The junction sample takes its neighbour's weight: under a split
        // the weight at u = 0 itself would jump at t = 1.
        let w = point_weight(op, slow_down, own_u[i.max(1)], t);
        frames[i] = anchor * arc_q(s.frame, s.frame_perp, s.omega, w);
        rad[i] = (s.radius[0] + (s.radius[1] - s.radius[0]) * w).max(0.0);
    }
    // The junction node sits on the parent's axis: give it the chain's own
    // thickness so its tube does not flare to the parent's girth.
    let w = point_weight(op, slow_down, own_u[1], t);
    let jr = chain.junction_radius;
    rad[0] = (jr[0] + (jr[1] - jr[0]) * w).max(0.0);
}

#[allow(clippy::too_many_arguments)]
fn morph_chains(
    plan: &MorphPlan,
    chains: &[ChainPlan],
    base: usize,
    t: f32,
    done_pos: &[Vec3],
    done_frames: &[Quat],
    pos: &mut [Vec3],
    rad: &mut [f32],
    frames: &mut [Quat],
    parallel: bool,
) {
    if parallel && chains.len() > CHAINS_PER_TASK {
        let mid = chains.len() / 2;
        let split = chains[mid].first as usize - base;
        let (pl, pr) = pos.split_at_mut(split);
        let (rl, rr) = rad.split_at_mut(split);
        let (fl, fr) = frames.split_at_mut(split);
        rayon::join(
            || {
                morph_chains(
                    plan,
                    &chains[..mid],
                    base,
                    t,
                    done_pos,
                    done_frames,
                    pl,
                    rl,
                    fl,
                    true,
                )
            },
            || {
                morph_chains(
                    plan,
                    &chains[mid..],
                    base + split,
                    t,
                    done_pos,
                    done_frames,
                    pr,
                    rr,
                    fr,
                    true,
                )
            },
        );
        return;
    }
    let root = plan.root_at(t);
    for c in chains {
        let off = c.first as usize - base;
        let k = c.len as usize;
        morph_chain(
            c,
            &plan.samples,
            &plan.sample_u,
            &plan.sample_inv_span,
            root,
            plan.slow_down,
            t,
            done_pos,
            done_frames,
            &mut pos[off..off + k],
            &mut rad[off..off + k],
            &mut frames[off..off + k],
        );
    }
}

/// One leaf at time `t`, given the morphed positions (by node) and sample
/// frames.
#[inline]
pub(crate) fn morph_leaf(
    leaf: &LeafPlan,
    plan: &MorphPlan,
    positions: &[Vec3],
    frames: &[Quat],
    t: f32,
) -> FrameLeaf {
    let w = t;
    let (anchor, orientation) = match leaf.mode {
        LeafMode::OnChain => {
            let c = &plan.chain_plans[leaf.host as usize];
            let (f, k) = (c.first as usize, c.len as usize);
            let param = leaf.param[0] + (leaf.param[1] - leaf.param[0]) * w;
            let u = &plan.sample_u[f..f + k];
            let (point, frame) = point_frame(
                u,
                &plan.sample_inv_span[f..f + k],
                &positions[1 + f..1 + f + k],
                &frames[f..f + k],
                segment(
                    u,
                    param,
                    leaf.segments[0] as usize,
                    leaf.segments[1] as usize,
                ),
                param,
            );
            // Both factors are unit quaternions, so the product is one.
            (
                point + frame * leaf.position[0].lerp(leaf.position[1], w),
                frame * arc_q(leaf.orientation, leaf.orientation_perp, leaf.omega, w),
            )
        }
        LeafMode::Linear => (
            leaf.position[0].lerp(leaf.position[1], w),
            arc_q(leaf.orientation, leaf.orientation_perp, leaf.omega, w),
        ),
    };
    FrameLeaf {
        anchor,
        orientation,
        width: (leaf.width[0] + (leaf.width[1] - leaf.width[0]) * w).max(0.0),
        height: (leaf.height[0] + (leaf.height[1] - leaf.height[0]) * w).max(0.0),
        blend: w,
    }
}

/// Produces in-between trees of a [`MorphPlan`]: a reusable context that
/// keeps its buffers between frames, so `morph` allocates nothing once the
/// frame has the topology's size.
///
/// ```no_run
/// # use treemorph_morph::{MorphPlan, Morpher};
/// # fn show(plan: &MorphPlan) {
/// let mut morpher = Morpher::new(plan);
/// let mut frame = morpher.new_frame();
/// for i in 0..=60 {
///     morpher.morph(i as f32 / 60.0, &mut frame);
///     // hand `frame` and `plan.topology()` to a mesher or encoder
/// }
/// # }
/// ```
#[derive(Debug)]
pub struct Morpher<'p> {
    plan: &'p MorphPlan,
    /// Frame (chain-local axes to world) of every union sample.
    frames: Vec<Quat>,
}

impl<'p> Morpher<'p> {
    /// A morpher for `plan`.
    pub fn new(plan: &'p MorphPlan) -> Morpher<'p> {
        Morpher {
            plan,
            frames: vec![Quat::IDENTITY; plan.sample_u.len()],
        }
    }

    /// The plan being played.
    pub fn plan(&self) -> &'p MorphPlan {
        self.plan
    }

    /// A frame of the topology's size (the tree at t = 0).
    pub fn new_frame(&mut self) -> Frame {
        let mut frame = Frame::default();
        self.morph(0.0, &mut frame);
        frame
    }

    /// Writes the in-between tree at time `t` (clamped to [0, 1]; NaN is
    /// taken as 0) into `frame`, resizing it to the topology first if
    /// needed.
    pub fn morph(&mut self, t: f32, frame: &mut Frame) {
        let plan = self.plan;
        let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
        let nodes = plan.topology.node_count();
        frame.t = t;
        frame.bark_blend = t;
        frame.positions.resize(nodes, Vec3::ZERO);
        frame.radii.resize(nodes, 0.0);
        frame.leaves.resize(
            plan.leaf_plans.len(),
            FrameLeaf {
                anchor: Vec3::ZERO,
                orientation: Quat::IDENTITY,
                width: 0.0,
                height: 0.0,
                blend: 0.0,
            },
        );
        frame.positions[0] = plan.root_at(t);
        frame.radii[0] = plan.root_radius[0] + (plan.root_radius[1] - plan.root_radius[0]) * t;

        let parallel = plan.parallel;
        for level in &plan.levels {
            let chains = &plan.chain_plans[level.start as usize..level.end as usize];
            let Some(first) = chains.first() else {
                continue;
            };
            let last = chains.last().expect("non-empty");
            let (a, b) = (first.first as usize, (last.first + last.len) as usize);
            let (done_pos, rest_pos) = frame.positions.split_at_mut(1 + a);
            let (done_frames, rest_frames) = self.frames.split_at_mut(a);
            morph_chains(
                plan,
                chains,
                a,
                t,
                done_pos,
                done_frames,
                &mut rest_pos[..b - a],
                &mut frame.radii[1 + a..1 + b],
                &mut rest_frames[..b - a],
                parallel,
            );
        }

        let positions = &frame.positions;
        let frames = &self.frames;
        if parallel {
            frame
                .leaves
                .par_chunks_mut(LEAVES_PER_TASK)
                .zip(plan.leaf_plans.par_chunks(LEAVES_PER_TASK))
                .for_each(|(out, leaves)| {
                    for (o, l) in out.iter_mut().zip(leaves) {
                        *o = morph_leaf(l, plan, positions, frames, t);
                    }
                });
        } else {
            for (o, l) in frame.leaves.iter_mut().zip(&plan.leaf_plans) {
                *o = morph_leaf(l, plan, positions, frames, t);
            }
        }
    }
}

impl MorphPlan {
    /// The in-between tree at `t` in a new frame (convenience; a
    /// [`Morpher`] reuses its buffers).
    pub fn frame(&self, t: f32) -> Frame {
        let mut morpher = Morpher::new(self);
        let mut frame = morpher.new_frame();
        morpher.morph(t, &mut frame);
        frame
    }
}
