//! [`Morpher`]: one in-between tree per call, in buffers it keeps.

use glam::{Quat, Vec3};
use rayon::prelude::*;
use treemorph_tree::geom::NONE;
use treemorph_tree::{Frame, FrameLeaf};

use crate::correspondence::Operation;
use crate::plan::{ChainPlan, LeafMode, LeafPlan, MorphPlan, Sample};
use crate::schedule::{ChainState, Paced};

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
pub(crate) fn arc_q(a: Quat, perp: Quat, angle: f32, w: f32) -> Quat {
    if angle == 0.0 {
        return a;
    }
    let (s, c) = sin_cos(angle * w);
    a * c + perp * s
}

/// A chain's junction at some instant: where it is and its frame (on the
/// parent at the interpolated growth location, or the root), and the ball
/// about it that lies inside its ancestors' tubes ([`Seal`]) when asked
/// for.
struct Junction {
    at: Vec3,
    anchor: Quat,
    ball: Option<Seal>,
}

/// The chain's [`Junction`] at `w`, with its ball when `sealing` (a root
/// chain has none): the parent's radius there, or the ball the parent is
/// sealed in when it is. One search for the parent's segment serves both.
#[inline]
fn junction(
    chain: &ChainPlan,
    (u, inv_span): (&[f32], &[f32]),
    root: Vec3,
    w: f32,
    done: Done,
    sealing: bool,
) -> Junction {
    if chain.parent == NONE {
        return Junction {
            at: root,
            anchor: Quat::IDENTITY,
            ball: None,
        };
    }
    let p = chain.p[0] + (chain.p[1] - chain.p[0]) * w;
    let pf = chain.parent_first as usize;
    let pk = chain.parent_len as usize;
    let (pu, span) = (&u[pf..pf + pk], &inv_span[pf..pf + pk]);
    let [lo, hi] = chain.parent_segments;
    let j = segment(pu, p, lo as usize, hi as usize);
    let pos = &done.pos[1 + pf..1 + pf + pk];
    let (at, anchor) = point_frame(pu, span, pos, &done.frames[pf..pf + pk], j, p);
    let ball = sealing.then(|| {
        let parent_sealed = done.seals[chain.parent as usize];
        if parent_sealed.1 > 0.0 {
            return parent_sealed;
        }
        let (r, f) = (&done.rad[1 + pf..1 + pf + pk], fraction(pu, span, j, p));
        (at, r[j] + (r[j + 1] - r[j]) * f)
    });
    Junction { at, anchor, ball }
}

/// What the levels above a chain's wrote: positions and radii by node,
/// frames by sample, seals by union chain.
#[derive(Clone, Copy)]
struct Done<'a> {
    pos: &'a [Vec3],
    rad: &'a [f32],
    frames: &'a [Quat],
    seals: &'a [Seal],
}

/// The ball a chain lies sealed in, inside an ancestor's tube, when it is
/// not drawn for that ([`undraw_if_sealed`]): centre and radius, radius 0
/// when it is not sealed.
type Seal = (Vec3, f32);

/// Undraws a chain (radius 0) whose tube lies inside `ball`, the ball
/// about its junction inside its ancestors' tubes ([`Junction`]), and
/// marks it sealed in it (so that its children are measured against the
/// same ball); marks it unsealed otherwise. A twig retracted
/// into a thick limb, or a stub whose junction slides up a thick trunk,
/// would otherwise be a tube sealed in the limb, where it passes through
/// the stubs of its siblings and cousins and floats on no surface.
#[inline]
fn undraw_if_sealed(ball: Option<Seal>, out: ChainOut) {
    let ChainOut {
        pos, rad, seals, ..
    } = out;
    let inside = ball.filter(|&(centre, radius)| {
        let mut nodes = pos.iter().zip(rad.iter());
        radius > 0.0 && nodes.all(|(p, r)| p.distance(centre) + r <= radius)
    });
    seals[0] = match inside {
        Some(ball) => {
            rad.fill(0.0);
            ball
        }
        None => (Vec3::ZERO, 0.0),
    };
}

/// The output slices of one chain (or of a run of chains): positions,
/// radii and frames of its nodes, and its seal.
struct ChainOut<'a> {
    pos: &'a mut [Vec3],
    rad: &'a mut [f32],
    frames: &'a mut [Quat],
    seals: &'a mut [Seal],
}

impl ChainOut<'_> {
    /// The same slices, for a call that does not take them over.
    fn reborrow(&mut self) -> ChainOut<'_> {
        ChainOut {
            pos: &mut *self.pos,
            rad: &mut *self.rad,
            frames: &mut *self.frames,
            seals: &mut *self.seals,
        }
    }
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
    (slow_down, reshape, inner): (bool, f32, bool),
    state: ChainState,
    done: Done,
    mut out: ChainOut,
) {
    let first = chain.first as usize;
    let k = chain.len as usize;
    let own = &samples[first..first + k];
    let own_u = &u[first..first + k];
    match state {
        ChainState::Blend(w) => {
            // The ends are the inputs', sealed stubs and all: sealing
            // only `inner`.
            let Junction { at, anchor, ball } =
                junction(chain, (u, inv_span), root, w, done, inner);
            blend_chain(
                chain,
                own,
                own_u,
                (slow_down, w),
                (at, anchor),
                out.reborrow(),
            );
            undraw_if_sealed(ball, out);
        }
        ChainState::Reach(reach) => {
            let Junction { at, anchor, ball } =
                junction(chain, (u, inv_span), root, 0.0, done, inner);
            let side = usize::from(chain.operation == Operation::Grow);
            let jr = chain.junction_radius[side];
            // A wilting chain that a sibling's junction passes stands off
            // the axis on the reshape's clock, while the sibling moves.
            let leaves = arc(own[0].dir, own[0].dir_perp, own[0].theta, side as f32);
            let at = at + anchor * lifted(chain.lift, leaves, reshape);
            tip_first(own, side, (reach, jr), (at, anchor), out.reborrow());
            undraw_if_sealed(ball, out);
        }
    }
}

/// A chain interpolated with weight `w` (the paper's morph, split, merge
/// and scaling growth).
#[inline]
fn blend_chain(
    chain: &ChainPlan,
    own: &[Sample],
    own_u: &[f32],
    (slow_down, w): (bool, f32),
    (junction, anchor): (Vec3, Quat),
    out: ChainOut,
) {
    let ChainOut {
        pos, rad, frames, ..
    } = out;
    let k = own.len();
    let op = chain.operation;
    // The lifted junction turns with the chain: routing models the detour
    // as a turn of all of it about the junction on the parent's axis.
    let anchor = anchor * detour_turn(chain.detour, w);
    let leaves = arc(own[0].dir, own[0].dir_perp, own[0].theta, w);
    pos[0] = junction + anchor * lifted(chain.lift, leaves, w);
    for i in 0..k - 1 {
        let s = &own[i];
        let wi = point_weight(op, slow_down, own_u[i + 1], w);
        let dir = arc(s.dir, s.dir_perp, s.theta, wi);
        let len = s.len[0] + (s.len[1] - s.len[0]) * wi;
        pos[i + 1] = pos[i] + anchor * (dir * len);
    }
    for i in 0..k {
        let s = &own[i];
        // The junction sample takes its neighbour's weight: under a split
        // the weight at u = 0 itself would jump at t = 1.
        let wi = point_weight(op, slow_down, own_u[i.max(1)], w);
        frames[i] = anchor * arc_q(s.frame, s.frame_perp, s.omega, wi);
        rad[i] = (s.radius[0] + (s.radius[1] - s.radius[0]) * wi).max(0.0);
    }
    // The junction node sits on the parent's axis: give it the chain's own
    // thickness so its tube does not flare to the parent's girth.
    let wi = point_weight(op, slow_down, own_u[1], w);
    let jr = chain.junction_radius;
    rad[0] = (jr[0] + (jr[1] - jr[0]) * wi).max(0.0);
}

/// The turn of a chain blended with weight `w` by its detour, in its
/// anchor frame: none at either end (`4w(1 − w)` is exactly 0 there), all
/// of it half way.
#[inline]
pub(crate) fn detour_turn(detour: Vec3, w: f32) -> Quat {
    if detour == Vec3::ZERO || w <= 0.0 || w >= 1.0 {
        return Quat::IDENTITY;
    }
    Quat::from_scaled_axis(detour * (4.0 * w * (1.0 - w)))
}

/// How far the part of a chain's first direction square to its parent
/// must reach for its junction to stand off the axis by its whole lift
/// (the sine of 30°).
const LIFT_FULL: f32 = 0.5;

/// Where a chain's junction node stands off its parent's axis at `w`, in
/// its anchor frame before any detour: `4w(1 − w)` of its lift, square to
/// the parent (the anchor's y axis) towards `out`, where the chain's first
/// segment leaves it; less when that leaves within 30° of the parent's
/// axis, in proportion to its part square to the parent (a direction
/// normalised there would whip round the parent as the chain swings past
/// its axis). A blended chain's `out` is taken at `w`, which differs from
/// the drawn one only under a split's or merge's slow-down; see
/// `routing`.
#[inline]
fn lifted(lift: f32, out: Vec3, w: f32) -> Vec3 {
    if lift == 0.0 || w <= 0.0 || w >= 1.0 {
        return Vec3::ZERO;
    }
    let across = Vec3::new(out.x, 0.0, out.z);
    across / across.length().max(LIFT_FULL) * (lift * 4.0 * w * (1.0 - w))
}

/// A growing or wilting chain grown `reach` metres from its junction along
/// its shape on `side` (see `schedule`, *Tip-first growth*): segments
/// fill base first, nodes not yet reached wait at the tip, and radii are
/// the full chain's radii as far behind its tip as the node is behind the
/// growing tip. The junction keeps at most `jr`.
#[inline]
fn tip_first(
    own: &[Sample],
    side: usize,
    (reach, jr): (f32, f32),
    (junction, anchor): (Vec3, Quat),
    out: ChainOut,
) {
    let ChainOut {
        pos, rad, frames, ..
    } = out;
    let k = own.len();
    let w = side as f32;
    pos[0] = junction;
    let mut c = 0.0f32;
    for i in 0..k - 1 {
        let s = &own[i];
        let grown = (reach - c).clamp(0.0, s.len[side]);
        pos[i + 1] = pos[i] + anchor * (arc(s.dir, s.dir_perp, s.theta, w) * grown);
        c += s.len[side];
    }
    for (f, s) in frames.iter_mut().zip(own) {
        *f = anchor * arc_q(s.frame, s.frame_perp, s.omega, w);
    }
    let length = c;
    if reach >= length {
        for (r, s) in rad.iter_mut().zip(own) {
            *r = s.radius[side];
        }
        rad[0] = jr;
    } else if reach <= 0.0 {
        rad.fill(0.0);
    } else {
        pipe_radii(own, side, length - reach, reach, rad);
        rad[0] = rad[0].min(jr);
    }
}

/// Radii of a chain grown `reach` metres: node `i`, `c_i` metres out,
/// takes the full chain's radius at `min(c_i, reach) + shift`, `shift` the
/// length still to grow, and never more than its own full radius. Without
/// that bound a chain thinner at its base than further out (imported
/// twigs often are) swelled at the base while it grew or retracted, and
/// a retracting twig's base reached a sibling it never touched at rest.
fn pipe_radii(own: &[Sample], side: usize, shift: f32, reach: f32, rad: &mut [f32]) {
    let k = own.len();
    let (mut j, mut cj, mut c) = (0usize, 0.0f32, 0.0f32);
    for i in 0..k {
        let x = c.min(reach) + shift;
        while j + 2 < k && cj + own[j].len[side] < x {
            cj += own[j].len[side];
            j += 1;
        }
        let l = own[j].len[side];
        let f = if l > 0.0 {
            ((x - cj) / l).clamp(0.0, 1.0)
        } else {
            1.0
        };
        let (a, b) = (own[j].radius[side], own[j + 1].radius[side]);
        rad[i] = (a + (b - a) * f).clamp(0.0, own[i].radius[side].max(0.0));
        if i + 1 < k {
            c += own[i].len[side];
        }
    }
}

/// Chains `index..index + chains.len()` of one level of the union chain
/// tree at time `t`, written into `out` (their nodes, from sample `base`
/// on), halved across rayon tasks when `parallel`.
#[allow(clippy::too_many_arguments)]
fn morph_chains(
    plan: &MorphPlan,
    chains: &[ChainPlan],
    index: usize,
    base: usize,
    t: Paced,
    done: Done,
    out: ChainOut,
    parallel: bool,
) {
    let ChainOut {
        pos,
        rad,
        frames,
        seals,
    } = out;
    if parallel && chains.len() > CHAINS_PER_TASK {
        let mid = chains.len() / 2;
        let split = chains[mid].first as usize - base;
        let (pl, pr) = pos.split_at_mut(split);
        let (rl, rr) = rad.split_at_mut(split);
        let (fl, fr) = frames.split_at_mut(split);
        let (sl, sr) = seals.split_at_mut(mid);
        let (left, right) = (&chains[..mid], &chains[mid..]);
        rayon::join(
            || {
                let out = ChainOut {
                    pos: pl,
                    rad: rl,
                    frames: fl,
                    seals: sl,
                };
                morph_chains(plan, left, index, base, t, done, out, true)
            },
            || {
                let out = ChainOut {
                    pos: pr,
                    rad: rr,
                    frames: fr,
                    seals: sr,
                };
                morph_chains(plan, right, index + mid, base + split, t, done, out, true)
            },
        );
        return;
    }
    let root = plan.root_at(t);
    let reshape = plan.schedule.overall(t);
    for (i, c) in chains.iter().enumerate() {
        let off = c.first as usize - base;
        let k = c.len as usize;
        morph_chain(
            c,
            &plan.samples,
            &plan.sample_u,
            &plan.sample_inv_span,
            root,
            (plan.slow_down, reshape, t.inner()),
            plan.schedule.chain(index + i, t),
            done,
            ChainOut {
                pos: &mut pos[off..off + k],
                rad: &mut rad[off..off + k],
                frames: &mut frames[off..off + k],
                seals: std::slice::from_mut(&mut seals[i]),
            },
        );
    }
}

/// One leaf with weight `w` (its schedule's at some t), given the morphed
/// positions (by node) and sample frames.
#[inline]
pub(crate) fn morph_leaf(
    leaf: &LeafPlan,
    plan: &MorphPlan,
    (positions, radii): (&[Vec3], &[f32]),
    frames: &[Quat],
    w: f32,
) -> FrameLeaf {
    let (anchor, orientation) = match leaf.mode {
        LeafMode::OnChain => {
            let c = &plan.chain_plans[leaf.host as usize];
            let (f, k) = (c.first as usize, c.len as usize);
            let param = leaf.param[0] + (leaf.param[1] - leaf.param[0]) * w;
            let u = &plan.sample_u[f..f + k];
            let inv_span = &plan.sample_inv_span[f..f + k];
            let [lo, hi] = leaf.segments;
            let j = segment(u, param, lo as usize, hi as usize);
            let (point, frame) = point_frame(
                u,
                inv_span,
                &positions[1 + f..1 + f + k],
                &frames[f..f + k],
                j,
                param,
            );
            let offset = leaf.position[0].lerp(leaf.position[1], w);
            let thickness = if plan.schedule.tip_first(leaf.host as usize) {
                let side = usize::from(c.operation == Operation::Grow);
                let at = fraction(u, inv_span, j, param);
                let now = radii[1 + f + j] + (radii[2 + f + j] - radii[1 + f + j]) * at;
                // As the morpher writes it grown: the junction node has the
                // junction radius.
                let full_at = |i: usize| match i {
                    0 => c.junction_radius[side],
                    _ => plan.samples[f + i].radius[side],
                };
                let full = full_at(j) + (full_at(j + 1) - full_at(j)) * at;
                if full > 0.0 {
                    (now / full).min(1.0)
                } else {
                    1.0
                }
            } else {
                1.0
            };
            // Both factors are unit quaternions, so the product is one. On
            // a chain still growing from its tip the wood is thinner than
            // it will be: the leaf keeps to the bark as it is now.
            (
                point + frame * (offset * thickness),
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
    /// The ball every union chain lies sealed in, if any ([`Seal`]).
    seals: Vec<Seal>,
}

impl<'p> Morpher<'p> {
    /// A morpher for `plan`.
    pub fn new(plan: &'p MorphPlan) -> Morpher<'p> {
        Morpher {
            plan,
            frames: vec![Quat::IDENTITY; plan.sample_u.len()],
            seals: vec![(Vec3::ZERO, 0.0); plan.chain_plans.len()],
        }
    }

    /// The plan being played.
    pub fn plan(&self) -> &'p MorphPlan {
        self.plan
    }

    /// The junction and anchor frame (the parent's frame there) of every
    /// union chain in `frame`, the frame this morpher wrote last.
    pub(crate) fn anchors(&self, frame: &Frame) -> Vec<(Vec3, Quat)> {
        let plan = self.plan;
        let t = plan.schedule.paced(frame.t);
        let root = plan.root_at(t);
        let (u, inv_span) = (&plan.sample_u, &plan.sample_inv_span);
        let done = Done {
            pos: &frame.positions,
            rad: &frame.radii,
            frames: &self.frames,
            seals: &self.seals,
        };
        (plan.chain_plans.iter().enumerate())
            .map(|(i, c)| {
                let w = match plan.schedule.chain(i, t) {
                    ChainState::Blend(w) => w,
                    ChainState::Reach(_) => 0.0,
                };
                let j = junction(c, (u, inv_span), root, w, done, false);
                (j.at, j.anchor)
            })
            .collect()
    }

    /// A frame of the topology's size (the tree at t = 0).
    pub fn new_frame(&mut self) -> Frame {
        let mut frame = Frame::default();
        self.morph(0.0, &mut frame);
        frame
    }

    /// The branches of [`Morpher::morph`] alone: positions, radii and bark
    /// blend, the leaves left as they were; returns `t` paced.
    pub(crate) fn morph_branches(&mut self, t: f32, frame: &mut Frame) -> Paced {
        let plan = self.plan;
        let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
        let nodes = plan.topology.node_count();
        frame.t = t;
        let t = plan.schedule.paced(t);
        frame.bark_blend = plan.schedule.overall(t);
        frame.positions.resize(nodes, Vec3::ZERO);
        frame.radii.resize(nodes, 0.0);
        frame.positions[0] = plan.root_at(t);
        let root_w = plan.schedule.overall(t);
        frame.radii[0] = plan.root_radius[0] + (plan.root_radius[1] - plan.root_radius[0]) * root_w;

        let parallel = plan.parallel;
        for level in &plan.levels {
            let chains = &plan.chain_plans[level.start as usize..level.end as usize];
            let Some(first) = chains.first() else {
                continue;
            };
            let last = chains.last().expect("non-empty");
            let (a, b) = (first.first as usize, (last.first + last.len) as usize);
            let (done_pos, rest_pos) = frame.positions.split_at_mut(1 + a);
            let (done_rad, rest_rad) = frame.radii.split_at_mut(1 + a);
            let (done_frames, rest_frames) = self.frames.split_at_mut(a);
            let (done_seals, rest_seals) = self.seals.split_at_mut(level.start as usize);
            let done = Done {
                pos: done_pos,
                rad: done_rad,
                frames: done_frames,
                seals: done_seals,
            };
            let out = ChainOut {
                pos: &mut rest_pos[..b - a],
                rad: &mut rest_rad[..b - a],
                frames: &mut rest_frames[..b - a],
                seals: &mut rest_seals[..chains.len()],
            };
            let index = level.start as usize;
            morph_chains(plan, chains, index, a, t, done, out, parallel);
        }
        t
    }

    /// Writes the in-between tree at time `t` (clamped to [0, 1]; NaN is
    /// taken as 0) into `frame`, resizing it to the topology first if
    /// needed.
    pub fn morph(&mut self, t: f32, frame: &mut Frame) {
        let t = self.morph_branches(t, frame);
        let plan = self.plan;
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
        let positions = &frame.positions;
        let radii = &frame.radii;
        let frames = &self.frames;
        if plan.parallel {
            frame
                .leaves
                .par_chunks_mut(LEAVES_PER_TASK)
                .zip(plan.leaf_plans.par_chunks(LEAVES_PER_TASK))
                .enumerate()
                .for_each(|(chunk, (out, leaves))| {
                    let first = chunk * LEAVES_PER_TASK;
                    for (i, (o, l)) in out.iter_mut().zip(leaves).enumerate() {
                        let w = plan.schedule.leaf(first + i, t);
                        *o = morph_leaf(l, plan, (positions, radii), frames, w);
                    }
                });
        } else {
            for (i, (o, l)) in frame.leaves.iter_mut().zip(&plan.leaf_plans).enumerate() {
                *o = morph_leaf(
                    l,
                    plan,
                    (positions, radii),
                    frames,
                    plan.schedule.leaf(i, t),
                );
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
