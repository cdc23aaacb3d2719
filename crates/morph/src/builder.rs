//! Building a [`MorphPlan`]: union chains from the correspondence, their
//! samples, the side data of both inputs at every sample, the slerp
//! coefficients a frame evaluates, and the leaves' local placements.

use std::ops::Range;

use glam::{DQuat, Quat, Vec3};
use rayon::prelude::*;
use treemorph_analysis::{Analysis, ChainId};
use treemorph_tree::geom::NONE;
use treemorph_tree::{Frame, FrameLeafTopology, FrameTopology, NodeId, Strands, Tree};

use crate::correspondence::{Correspondence, Excluded, Input, LeafMatch, Operation, correspond};
use crate::error::{MorphError, Side};
use crate::morpher::{Morpher, fraction, locate};
use crate::options::{LeafMorph, MorphOptions, ScheduleKind};
use crate::plan::{
    ChainPlan, EndpointError, LeafMode, LeafPlan, MorphPlan, NodeOrigin, Sample, UnionChain,
};
use crate::staging::{Timed, coarse_pace, pace, refined_pace, schedule, separate_copies};

/// The chain data the plan reads, copied from the analysis in one
/// sequential pass into concatenated arrays: the build visits chains in
/// union order, and the analysis keeps each chain in a large struct with
/// five separate heap vectors, which made cache misses the build's main
/// cost.
struct ChainArrays {
    offsets: Vec<u32>,
    points: Vec<Vec3>,
    radii: Vec<f32>,
    frames: Vec<Quat>,
    params: Vec<f32>,
    nodes: Vec<NodeId>,
    growth: Vec<f32>,
    parent: Vec<Option<ChainId>>,
}

/// One chain of a [`ChainArrays`].
#[derive(Clone, Copy)]
struct ChainView<'a> {
    points: &'a [Vec3],
    radii: &'a [f32],
    frames: &'a [Quat],
    params: &'a [f32],
    nodes: &'a [NodeId],
    growth: f32,
}

impl ChainArrays {
    fn of(analysis: &Analysis) -> ChainArrays {
        let chains = analysis.chains();
        let total: usize = chains.iter().map(|c| c.points.len()).sum();
        let mut a = ChainArrays {
            offsets: Vec::with_capacity(chains.len() + 1),
            points: Vec::with_capacity(total),
            radii: Vec::with_capacity(total),
            frames: Vec::with_capacity(total),
            params: Vec::with_capacity(total),
            nodes: Vec::with_capacity(total),
            growth: chains.iter().map(|c| c.growth_location).collect(),
            parent: chains.iter().map(|c| c.parent).collect(),
        };
        a.offsets.push(0);
        for c in chains {
            a.points.extend_from_slice(&c.points);
            a.radii.extend_from_slice(&c.radii);
            a.frames.extend_from_slice(&c.frames);
            a.nodes.extend_from_slice(&c.nodes);
            a.params
                .extend((0..c.points.len()).map(|i| c.param_of_point(i)));
            a.offsets.push(a.points.len() as u32);
        }
        a
    }

    /// Number of chains.
    fn len(&self) -> usize {
        self.growth.len()
    }

    fn get(&self, c: ChainId) -> ChainView<'_> {
        let r = self.offsets[c as usize] as usize..self.offsets[c as usize + 1] as usize;
        ChainView {
            points: &self.points[r.clone()],
            radii: &self.radii[r.clone()],
            frames: &self.frames[r.clone()],
            params: &self.params[r.clone()],
            nodes: &self.nodes[r],
            growth: self.growth[c as usize],
        }
    }
}

/// Side data of one union sample.
#[derive(Clone, Copy)]
struct SideSample {
    x: Vec3,
    r: f32,
    h: Quat,
}

/// Samples of one side of a union chain: at every union parameter, the
/// chain's own node when there is one (so inputs are reproduced exactly),
/// else the point on the polyline segment it falls in, with the frame
/// nlerped between the segment's node frames (any continuous frame will
/// do: leaves and children are expressed relative to these very frames).
fn side_samples(chain: ChainView, u: &[f32], origin: &[Option<u32>], out: &mut Vec<SideSample>) {
    out.clear();
    let mut k = 0usize; // the node at or before the current sample
    for (&p, o) in u.iter().zip(origin) {
        if let Some(o) = o {
            k = *o as usize;
            out.push(SideSample {
                x: chain.points[k],
                r: chain.radii[k],
                h: chain.frames[k],
            });
            continue;
        }
        let k1 = (k + 1).min(chain.points.len() - 1);
        let (a, b) = (chain.params[k], chain.params[k1]);
        let f = if b > a {
            ((p - a) / (b - a)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        // The first segment starts at the junction, whose radius is the
        // parent's; the chain's own tube starts at min(r₀, r₁) (as meshers
        // draw it), so extra samples there taper from that.
        let r0 = if k == 0 {
            chain.radii[0].min(chain.radii[1])
        } else {
            chain.radii[k]
        };
        out.push(SideSample {
            x: chain.points[k].lerp(chain.points[k1], f),
            r: r0 + (chain.radii[k1] - r0) * f,
            h: chain.frames[k].lerp(chain.frames[k1], f),
        });
    }
}

/// Union parameters of a chain: the merge of both sides' node parameters,
/// with, per sample, the source and target polyline index it reproduces.
#[derive(Default)]
struct Params {
    u: Vec<f32>,
    origin: [Vec<Option<u32>>; 2],
}

fn union_params(source: Option<ChainView>, target: Option<ChainView>, out: &mut Params) {
    out.u.clear();
    out.origin[0].clear();
    out.origin[1].clear();
    let len = |c: Option<ChainView>| c.map_or(0, |c| c.points.len());
    let (na, nb) = (len(source), len(target));
    let param = |c: Option<ChainView>, i: usize| c.expect("in range").params[i];
    let (mut i, mut j) = (0, 0);
    while i < na || j < nb {
        let (a, b) = (
            (i < na).then(|| param(source, i)),
            (j < nb).then(|| param(target, j)),
        );
        let take_a = a.is_some_and(|a| b.is_none_or(|b| a <= b));
        let take_b = b.is_some_and(|b| a.is_none_or(|a| b <= a));
        out.u
            .push(if take_a { a } else { b }.expect("one side remains"));
        out.origin[0].push(take_a.then_some(i as u32));
        out.origin[1].push(take_b.then_some(j as u32));
        i += usize::from(take_a);
        j += usize::from(take_b);
    }
    // Parameters must run from exactly 0 to exactly 1 for `locate`.
    if let Some(f) = out.u.first_mut() {
        *f = 0.0;
    }
    if let Some(l) = out.u.last_mut() {
        *l = 1.0;
    }
}

/// `a cos(wθ) + a⊥ sin(wθ)` coefficients for unit vectors `a → b`, so
/// that `w = 1` gives `b`. In f64 with `atan2`: an f32 `acos` near 1 is only
/// good to ~3e-4 rad, which would show at t = 1.
fn arc_coefficients(a: Vec3, b: Vec3, hint: Vec3) -> (Vec3, f32) {
    let (a, b) = (a.as_dvec3(), b.as_dvec3());
    let c = a.dot(b);
    let perp = b - a * c;
    let n = perp.length();
    if n > 1e-9 {
        return ((perp / n).as_vec3(), n.atan2(c) as f32);
    }
    if c > 0.0 {
        return (Vec3::ZERO, 0.0);
    }
    // Antiparallel: turn through the hint's direction.
    let hint = hint.as_dvec3();
    let h = hint - a * hint.dot(a);
    let perp = if h.length_squared() > 1e-12 {
        h.normalize()
    } else {
        a.any_orthonormal_vector()
    };
    (perp.as_vec3(), std::f32::consts::PI)
}

/// The same for unit quaternions (shortest arc; `b` is negated when needed).
fn arc_coefficients_q(a: Quat, b: Quat) -> (Quat, f32) {
    let (a, mut b) = (a.as_dquat(), b.as_dquat());
    if a.dot(b) < 0.0 {
        b = -b;
    }
    arc_coefficients_q_to(a, b)
}

/// The coefficients of the arc from `a` to `b` as given (not negated).
fn arc_coefficients_q_to(a: DQuat, b: DQuat) -> (Quat, f32) {
    let d = a.dot(b);
    let perp = b - a * d;
    let n = perp.length();
    if n <= 1e-12 {
        return (Quat::from_xyzw(0.0, 0.0, 0.0, 0.0), 0.0);
    }
    ((perp * (1.0 / n)).as_quat(), n.atan2(d) as f32)
}

/// [`arc_coefficients_q`] for the frames of a chain's samples, taken
/// base to tip: the first sample's arc is the shortest, and each next
/// sample's runs to whichever of `b` and `−b` (one rotation, two arcs)
/// keeps its half-way frame nearest `follow`, the previous sample's
/// half-way frame (returned for the next). Shortest arcs chosen sample by
/// sample part ways where a chain's frames turn by about 180° between
/// the trees (on bush-1 → mt-bushy, a trunk whose source and target
/// frames differ by a half turn about its axis): two neighbours turn
/// opposite ways, their frames half way differ by a half turn, and the
/// normalised lerp between them (a junction's anchor, a leaf's frame)
/// flips as the sign of their dot product does, so a limb jumped a
/// third of the tree's height in one frame. The ends are the same
/// rotations either way.
fn frame_arc(a: Quat, b: Quat, follow: Option<DQuat>) -> ((Quat, f32), DQuat) {
    let (da, db) = (a.as_dquat(), b.as_dquat());
    let (near, far) = (da + db, da - db);
    let to_b = match follow {
        Some(m) if near.length() > 1e-6 && far.length() > 1e-6 => {
            near.normalize().dot(m).abs() >= far.normalize().dot(m).abs()
        }
        _ => da.dot(db) >= 0.0,
    };
    let (b, mid) = if to_b { (db, near) } else { (-db, far) };
    (arc_coefficients_q_to(da, b), mid.normalize())
}

/// One side's chain-local data relative to its anchor frame.
#[derive(Default)]
struct Local {
    dirs: Vec<Vec3>,
    lens: Vec<f32>,
    frames: Vec<Quat>,
}

impl Local {
    fn set(&mut self, samples: &[SideSample], anchor: Quat) {
        let inv = anchor.inverse();
        self.frames.clear();
        self.frames
            .extend(samples.iter().map(|s| (inv * s.h).normalize()));
        self.dirs.clear();
        self.lens.clear();
        for i in 0..samples.len() {
            let fallback = self.frames[i] * Vec3::Y;
            if i + 1 < samples.len() {
                let d = inv * (samples[i + 1].x - samples[i].x);
                let len = d.length();
                self.lens.push(len);
                self.dirs.push(if len > 1e-12 { d / len } else { fallback });
            } else {
                self.lens.push(0.0);
                self.dirs.push(fallback);
            }
        }
    }
}

/// A union chain before its samples are laid out.
#[derive(Clone, Copy)]
struct Proto {
    operation: Operation,
    source: Option<ChainId>,
    target: Option<ChainId>,
    /// Parent union chain, or [`NONE`].
    parent: u32,
    /// Depth in the union chain tree (set when the chains are ordered).
    level: u32,
}

impl Proto {
    fn new(operation: Operation, source: Option<ChainId>, target: Option<ChainId>) -> Proto {
        Proto {
            operation,
            source,
            target,
            parent: NONE,
            level: 0,
        }
    }
}

/// What the plan needs of one input leaf, gathered in one sequential pass
/// (the leaf loop visits leaves in correspondence order, and scattered
/// reads from several big arrays cost more than the work).
struct LeafFacts {
    inner_lobe: ChainId,
    param: f32,
    offset_len: f32,
    anchor: Vec3,
    orientation: Quat,
    width: f32,
    height: f32,
    /// Index into the union's leaf materials.
    material: u32,
}

fn leaf_facts(input: &Input, material_offset: u32) -> Vec<LeafFacts> {
    input
        .tree
        .leaves()
        .par_iter()
        .zip(input.analysis.leaves())
        .with_min_len(1024)
        .map(|(leaf, placement)| LeafFacts {
            inner_lobe: placement.inner_lobe,
            param: placement.param,
            offset_len: placement.offset.length(),
            anchor: input.tree.leaf_anchor(leaf),
            orientation: leaf.orientation,
            width: leaf.width,
            height: leaf.height,
            material: leaf.material + material_offset,
        })
        .collect()
}

/// The union chain of the pair (source, target), if they are matched.
fn pair_of(pairs_of: &[Vec<(ChainId, u32)>], source: ChainId, target: ChainId) -> Option<u32> {
    pairs_of[source as usize]
        .iter()
        .find(|p| p.0 == target)
        .map(|p| p.1)
}

fn internal(msg: impl Into<String>) -> MorphError {
    MorphError::Internal(msg.into())
}

/// Both inputs at one union sample: position and frame of the source (0)
/// and target (1) polylines (what children and leaves are placed on).
#[derive(Clone, Copy)]
struct SideData {
    x: [Vec3; 2],
    h: [Quat; 2],
}

impl Default for SideData {
    fn default() -> SideData {
        SideData {
            x: [Vec3::ZERO; 2],
            h: [Quat::IDENTITY; 2],
        }
    }
}

impl Default for Sample {
    fn default() -> Sample {
        Sample {
            frame: Quat::IDENTITY,
            frame_perp: Quat::IDENTITY,
            dir: Vec3::Y,
            dir_perp: Vec3::ZERO,
            theta: 0.0,
            omega: 0.0,
            len: [0.0; 2],
            radius: [0.0; 2],
        }
    }
}

/// [`point_frame`] on one side of built samples, with the same arithmetic,
/// so the plan and the morpher agree to the last bit.
fn side_point_frame(
    u: &[f32],
    inv_span: &[f32],
    b: &[SideData],
    sd: usize,
    p: f32,
) -> (Vec3, Quat) {
    let j = locate(u, p);
    let f = fraction(u, inv_span, j, p);
    (
        b[j].x[sd].lerp(b[j + 1].x[sd], f),
        b[j].h[sd].lerp(b[j + 1].h[sd], f),
    )
}

struct BuildContext<'a> {
    arrays: &'a [ChainArrays; 2],
    sample_u: &'a [f32],
    sample_inv_span: &'a [f32],
    origins: &'a [Vec<Option<u32>>; 2],
}

/// Scratch buffers of one build task.
#[derive(Default)]
struct Scratch {
    side: Vec<SideSample>,
    radii: Vec<[f32; 2]>,
    locals: [Local; 2],
}

/// Chains per rayon task in pass 2.
const BUILD_CHAINS_PER_TASK: usize = 128;

/// Pass 2 for a run of chains of one level whose samples start at `base`:
/// `done` holds the side data of every earlier sample (the parents'),
/// `out` and `samples` these chains' side data and samples.
fn build_chains(
    cx: &BuildContext,
    plans: &[ChainPlan],
    sides: &[[Option<ChainId>; 2]],
    done: &[SideData],
    out: &mut [SideData],
    samples: &mut [Sample],
    base: usize,
) -> Result<(), MorphError> {
    if plans.len() > BUILD_CHAINS_PER_TASK {
        let mid = plans.len() / 2;
        let split = plans[mid].first as usize - base;
        let (lo, hi) = out.split_at_mut(split);
        let (slo, shi) = samples.split_at_mut(split);
        let (a, b) = rayon::join(
            || build_chains(cx, &plans[..mid], &sides[..mid], done, lo, slo, base),
            || {
                build_chains(
                    cx,
                    &plans[mid..],
                    &sides[mid..],
                    done,
                    hi,
                    shi,
                    base + split,
                )
            },
        );
        return a.and(b);
    }
    let mut scratch = Scratch::default();
    for (c, side) in plans.iter().zip(sides) {
        let r = c.first as usize - base..c.first as usize - base + c.len as usize;
        build_chain(
            cx,
            c,
            *side,
            done,
            &mut out[r.clone()],
            &mut samples[r],
            &mut scratch,
        )?;
    }
    Ok(())
}

fn build_chain(
    cx: &BuildContext,
    c: &ChainPlan,
    side: [Option<ChainId>; 2],
    done: &[SideData],
    out: &mut [SideData],
    samples: &mut [Sample],
    scratch: &mut Scratch,
) -> Result<(), MorphError> {
    let r = c.first as usize..(c.first + c.len) as usize;
    let u = &cx.sample_u[r.clone()];
    let mut has = [false; 2];
    scratch.radii.clear();
    scratch.radii.resize(u.len(), [0.0; 2]);
    for sd in 0..2 {
        let Some(id) = side[sd] else { continue };
        let chain = cx.arrays[sd].get(id);
        side_samples(chain, u, &cx.origins[sd][r.clone()], &mut scratch.side);
        let anchor = if c.parent == NONE {
            Quat::IDENTITY
        } else {
            let pr = c.parent_first as usize..(c.parent_first + c.parent_len) as usize;
            side_point_frame(
                &cx.sample_u[pr.clone()],
                &cx.sample_inv_span[pr.clone()],
                &done[pr],
                sd,
                c.p[sd],
            )
            .1
        };
        scratch.locals[sd].set(&scratch.side, anchor);
        has[sd] = true;
        for ((o, x), r) in out.iter_mut().zip(&scratch.side).zip(&mut scratch.radii) {
            o.x[sd] = x.x;
            o.h[sd] = x.h;
            r[sd] = x.r;
        }
    }
    let (a, b) = match has {
        [true, true] => (&scratch.locals[0], &scratch.locals[1]),
        [true, false] => (&scratch.locals[0], &scratch.locals[0]),
        [false, true] => (&scratch.locals[1], &scratch.locals[1]),
        [false, false] => return Err(internal("a union chain has no side")),
    };
    let mut follow = None;
    for (j, (o, radius)) in samples.iter_mut().zip(&scratch.radii).enumerate() {
        let (dir_perp, theta) = arc_coefficients(a.dirs[j], b.dirs[j], a.frames[j] * Vec3::X);
        let ((frame_perp, omega), mid) = frame_arc(a.frames[j], b.frames[j], follow);
        follow = Some(mid);
        *o = Sample {
            dir: a.dirs[j],
            dir_perp,
            theta,
            len: [
                if has[0] { a.lens[j] } else { 0.0 },
                if has[1] { b.lens[j] } else { 0.0 },
            ],
            frame: a.frames[j],
            frame_perp,
            omega,
            radius: [
                if has[0] { radius[0] } else { 0.0 },
                if has[1] { radius[1] } else { 0.0 },
            ],
        };
    }
    Ok(())
}

/// Height of a tree for normalisation: the stats height, else the largest
/// extent, else 1 m.
fn tree_height(tree: &Tree) -> f32 {
    let stats = tree.stats();
    if stats.height > 1e-6 && stats.height.is_finite() {
        return stats.height;
    }
    let [lo, hi] = stats.bounds;
    let extent = (0..3).map(|i| hi[i] - lo[i]).fold(0.0f32, f32::max);
    if extent > 1e-6 && extent.is_finite() {
        extent
    } else {
        1.0
    }
}

/// Checks that `analysis` was made from `tree`.
fn check_analysis(tree: &Tree, analysis: &Analysis, side: Side) -> Result<(), MorphError> {
    let mismatch = |reason: String| MorphError::AnalysisMismatch { side, reason };
    let skeleton = tree.skeleton();
    if analysis.orders().len() != skeleton.len() {
        return Err(mismatch(format!(
            "{} node orders for {} nodes",
            analysis.orders().len(),
            skeleton.len()
        )));
    }
    if analysis.leaves().len() != tree.leaves().len() {
        return Err(mismatch(format!(
            "{} leaf placements for {} leaves",
            analysis.leaves().len(),
            tree.leaves().len()
        )));
    }
    if analysis.chains().is_empty() || analysis.groups().is_empty() {
        return Err(mismatch("the analysis has no chains".into()));
    }
    let chains = analysis.chains().len() as ChainId;
    for c in analysis.chains() {
        if c.nodes.len() < 2
            || c.points.len() != c.nodes.len()
            || c.radii.len() != c.nodes.len()
            || c.frames.len() != c.nodes.len()
            || c.arc_lengths.len() != c.nodes.len()
        {
            return Err(mismatch(format!("chain {} is malformed", c.id)));
        }
        if c.parent.is_some_and(|p| p >= c.id) || c.children.iter().any(|&k| k >= chains) {
            return Err(mismatch(format!(
                "chain {} has a bad parent or child",
                c.id
            )));
        }
        for (&n, &p) in c.nodes.iter().zip(&c.points) {
            if n as usize >= skeleton.len() || skeleton.node(n).position != p {
                return Err(mismatch(format!(
                    "chain {} names node {n}, which is not at {p}",
                    c.id
                )));
            }
        }
    }
    for (i, l) in analysis.leaves().iter().enumerate() {
        if l.inner_lobe >= chains {
            return Err(mismatch(format!("leaf {i} has no inner lobe chain")));
        }
    }
    Ok(())
}

impl MorphPlan {
    /// Matches `source` with `target` (§5) and builds the union topology and
    /// interpolation data (§6). Each analysis must come from its tree.
    pub fn new(
        source: &Tree,
        source_analysis: &Analysis,
        target: &Tree,
        target_analysis: &Analysis,
        options: &MorphOptions,
    ) -> Result<MorphPlan, MorphError> {
        options.validate()?;
        check_analysis(source, source_analysis, Side::Source)?;
        check_analysis(target, target_analysis, Side::Target)?;
        let heights = [tree_height(source), tree_height(target)];
        let inputs = [
            Input::new(source, source_analysis, heights[0]),
            Input::new(target, target_analysis, heights[1]),
        ];
        let mut plan = plan_excluding(&inputs, options, heights, &Excluded::default())?;
        if options.schedule.kind == ScheduleKind::Staged {
            if options.untangle {
                plan = untangled(plan, &inputs, options, heights)?;
            } else {
                plan.schedule.pace = pace(&plan, options.schedule.easing);
            }
        }
        plan.endpoint = plan.measure_endpoints(source, target);
        Ok(plan)
    }

    fn measure_endpoints(&self, source: &Tree, target: &Tree) -> EndpointError {
        let mut morpher = Morpher::new(self);
        let mut frame = Frame::default();
        let mut junctions = vec![false; self.topology.node_count()];
        for c in &self.chains {
            junctions[c.nodes.start as usize] = true;
        }
        let mut errors = [0.0f32; 2];
        for (side, tree) in [source, target].into_iter().enumerate() {
            morpher.morph(side as f32, &mut frame);
            let nodes = tree.skeleton();
            let mut worst = 0.0f32;
            for (i, o) in self.node_origins.iter().enumerate() {
                let origin = if side == 0 { o.source } else { o.target };
                if let Some(n) = origin {
                    let node = nodes.node(n);
                    worst = worst.max(frame.positions[i].distance(node.position));
                    if !junctions[i] {
                        worst = worst.max((frame.radii[i] - node.radius).abs());
                    }
                }
            }
            for (i, m) in self.correspondence.leaves.iter().enumerate() {
                let origin = if side == 0 { m.source } else { m.target };
                if let Some(l) = origin {
                    let leaf = &tree.leaves()[l as usize];
                    let f = &frame.leaves[i];
                    worst = worst
                        .max(f.anchor.distance(tree.leaf_anchor(leaf)))
                        .max((f.width - leaf.width).abs())
                        .max((f.height - leaf.height).abs());
                }
            }
            errors[side] = worst / self.heights[side];
        }
        EndpointError {
            source: errors[0],
            target: errors[1],
        }
    }
}

/// `plan` with its crossing blends shed and regrown (see `untangling`).
/// Each round's plan is paced on its own motion before it is played: the
/// sweep between two instants takes every node on a straight line, which
/// is the motion to within its bow only where the instants are close,
/// and an even pace keeps them close everywhere (on the first plan's pace
/// a later plan's bursts fell between far instants, and a twig passing
/// the trunk in one was missed). The rounds' paces are coarse (no
/// refinement of concentrated motion); the plan that comes out is paced
/// in full, as [`pace`] paces it.
fn untangled(
    mut plan: MorphPlan,
    inputs: &[Input; 2],
    options: &MorphOptions,
    heights: [f32; 2],
) -> Result<MorphPlan, MorphError> {
    let easing = options.schedule.easing;
    let mut excluded = Excluded::default();
    let mut concentrated;
    (plan.schedule.pace, concentrated) = coarse_pace(&plan, easing);
    for _ in 0..crate::untangling::ROUNDS {
        let shed = crate::untangling::to_shed(&plan);
        if shed.is_empty() {
            break;
        }
        for (side, c) in shed {
            excluded.add(side, c, inputs[side].analysis.chains().len());
        }
        plan = plan_excluding(inputs, options, heights, &excluded)?;
        (plan.schedule.pace, concentrated) = coarse_pace(&plan, easing);
    }
    if concentrated {
        // The pace measures the motion as the plan plays it: unpaced.
        plan.schedule.pace = None;
        plan.schedule.pace = refined_pace(&plan, easing);
    }
    Ok(plan)
}

/// Matches and builds the plan with `excluded` chains left out of the
/// matching, then routes a staged one; the caller paces it and measures
/// its endpoint error.
fn plan_excluding(
    [source, target]: &[Input; 2],
    options: &MorphOptions,
    heights: [f32; 2],
    excluded: &Excluded,
) -> Result<MorphPlan, MorphError> {
    let mut correspondence = correspond(source, target, options, excluded);
    // The random-leaf baseline keeps its copies: it is the paper's
    // Figure 11 as published.
    if options.schedule.kind == ScheduleKind::Staged && options.leaf_morph == LeafMorph::OnChains {
        separate_copies(&mut correspondence.leaves);
    }
    let mut plan = build(source, target, correspondence, options, heights)?;
    if options.schedule.kind == ScheduleKind::Staged && options.route_round {
        crate::routing::route(&mut plan);
    }
    Ok(plan)
}

/// Builds the plan of `source` → `target` from their correspondence (§6);
/// the caller measures its endpoint error.
pub(crate) fn build(
    source: &Input,
    target: &Input,
    correspondence: Correspondence,
    options: &MorphOptions,
    heights: [f32; 2],
) -> Result<MorphPlan, MorphError> {
    let arrays = [
        ChainArrays::of(source.analysis),
        ChainArrays::of(target.analysis),
    ];
    let union = UnionChains::of(&correspondence, &arrays)?;
    let layout = ChainLayout::of(&union, &arrays)?;
    let (side_data, samples) = sample_sides(&arrays, &layout)?;
    let leaves = LeafPlanner {
        union: &union,
        layout: &layout,
        side_data: &side_data,
        samples: &samples,
        facts: [
            leaf_facts(source, 0),
            leaf_facts(target, source.tree.materials().leaves.len() as u32),
        ],
        linear: matches!(options.leaf_morph, LeafMorph::RandomLinear { .. }),
        buds: options.schedule.kind == ScheduleKind::Staged,
    }
    .plan_all(&correspondence.leaves)?;
    let mut leaf_materials = source.tree.materials().leaves.clone();
    leaf_materials.extend(target.tree.materials().leaves.iter().cloned());
    let ChainLayout {
        chain_plans,
        chains,
        sample_u,
        sample_inv_span,
        node_origins,
        parents,
        levels,
        ..
    } = layout;
    let topology = FrameTopology {
        parents,
        strands: Strands::from_polylines(chains.iter().map(|c| c.nodes.clone())),
        leaves: leaves.topology,
        leaf_materials,
        bark: [
            source.tree.materials().bark.clone(),
            target.tree.materials().bark.clone(),
        ],
    };
    let parallel = topology.node_count() + leaves.plans.len() > options.parallel_threshold;
    let (source_root, target_root) = (
        source.tree.skeleton().node(0),
        target.tree.skeleton().node(0),
    );
    let schedule = schedule(
        &options.schedule,
        &Timed {
            chain_plans: &chain_plans,
            chains: &chains,
            samples: &samples,
            sample_u: &sample_u,
            sample_inv_span: &sample_inv_span,
            leaf_plans: &leaves.plans,
            leaf_matches: &correspondence.leaves,
        },
    );
    Ok(MorphPlan {
        topology,
        correspondence,
        chains,
        node_origins,
        chain_plans,
        levels,
        samples,
        sample_u,
        sample_inv_span,
        leaf_plans: leaves.plans,
        leaf_hosts: leaves.hosts,
        leaf_offset_len: leaves.offset_lens,
        root: [source_root.position, target_root.position],
        root_radius: [source_root.radius, target_root.radius],
        slow_down: options.slow_down,
        schedule,
        parallel,
        heights,
        endpoint: EndpointError::default(),
    })
}

/// The union chains, parents first (by level), and which union chain
/// stands for each input chain.
struct UnionChains {
    /// In parent-first order; `parent` indexes this order.
    protos: Vec<Proto>,
    /// Union chain of each matched pair, per source chain (a handful each).
    pairs_of: Vec<Vec<(ChainId, u32)>>,
    /// Per source chain (0) and target chain (1): the union chain that
    /// carries its children and leaves.
    primary: [Vec<u32>; 2],
}

impl UnionChains {
    fn of(
        correspondence: &Correspondence,
        arrays: &[ChainArrays; 2],
    ) -> Result<UnionChains, MorphError> {
        let mut union = UnionChains::unordered(correspondence, arrays)?;
        union.link_parents(arrays)?;
        union.order_by_level()?;
        Ok(union)
    }

    /// Pairs, then wilting and growing chains, in correspondence order.
    fn unordered(
        correspondence: &Correspondence,
        arrays: &[ChainArrays; 2],
    ) -> Result<UnionChains, MorphError> {
        let mut protos: Vec<Proto> = Vec::new();
        let mut pairs_of: Vec<Vec<(ChainId, u32)>> = vec![Vec::new(); arrays[0].len()];
        let mut primary_src = vec![NONE; arrays[0].len()];
        let mut primary_tgt = vec![NONE; arrays[1].len()];
        for m in &correspondence.chains {
            let idx = protos.len() as u32;
            protos.push(Proto::new(m.operation, Some(m.source), Some(m.target)));
            pairs_of[m.source as usize].push((m.target, idx));
            let (s_primary, t_primary) = match m.operation {
                Operation::Split => (m.primary, true),
                Operation::Merge => (true, m.primary),
                _ => (true, true),
            };
            if s_primary || primary_src[m.source as usize] == NONE {
                primary_src[m.source as usize] = idx;
            }
            if t_primary || primary_tgt[m.target as usize] == NONE {
                primary_tgt[m.target as usize] = idx;
            }
        }
        for &c in &correspondence.wilting_chains {
            primary_src[c as usize] = protos.len() as u32;
            protos.push(Proto::new(Operation::Wilt, Some(c), None));
        }
        for &c in &correspondence.growing_chains {
            primary_tgt[c as usize] = protos.len() as u32;
            protos.push(Proto::new(Operation::Grow, None, Some(c)));
        }
        if primary_src.contains(&NONE) || primary_tgt.contains(&NONE) {
            return Err(internal("a chain has no union chain"));
        }
        Ok(UnionChains {
            protos,
            pairs_of,
            primary: [primary_src, primary_tgt],
        })
    }

    /// A union chain's parent: the union chain of its inputs' parents.
    fn link_parents(&mut self, arrays: &[ChainArrays; 2]) -> Result<(), MorphError> {
        let [primary_src, primary_tgt] = &self.primary;
        for p in &mut self.protos {
            let ps = p.source.and_then(|c| arrays[0].parent[c as usize]);
            let pt = p.target.and_then(|c| arrays[1].parent[c as usize]);
            p.parent = match (p.operation, ps, pt) {
                (Operation::Wilt, Some(ps), _) => primary_src[ps as usize],
                (Operation::Grow, _, Some(pt)) => primary_tgt[pt as usize],
                (Operation::Wilt | Operation::Grow, None, None) => NONE,
                (_, None, None) => NONE,
                (_, Some(ps), Some(pt)) => pair_of(&self.pairs_of, ps, pt)
                    .ok_or_else(|| internal("a matched chain's parents are not matched"))?,
                _ => return Err(internal("a root chain is matched with a non-root chain")),
            };
        }
        Ok(())
    }

    /// Sorts the chains parent-first by level (stable within a level) and
    /// renumbers every reference to them.
    fn order_by_level(&mut self) -> Result<(), MorphError> {
        let depth = chain_depths(&self.protos)?;
        let mut order: Vec<u32> = (0..self.protos.len() as u32).collect();
        order.sort_by_key(|&i| (depth[i as usize], i));
        let mut rank = vec![0u32; self.protos.len()];
        for (r, &i) in order.iter().enumerate() {
            rank[i as usize] = r as u32;
        }
        let remap = |i: u32| if i == NONE { NONE } else { rank[i as usize] };
        for p in self.primary.iter_mut().flatten() {
            *p = remap(*p);
        }
        for v in self.pairs_of.iter_mut().flatten() {
            v.1 = remap(v.1);
        }
        self.protos = order
            .iter()
            .map(|&i| {
                let p = &self.protos[i as usize];
                Proto {
                    parent: remap(p.parent),
                    level: depth[i as usize],
                    ..*p
                }
            })
            .collect();
        Ok(())
    }
}

/// Depth of every union chain in the union chain tree (roots: 0).
fn chain_depths(protos: &[Proto]) -> Result<Vec<u32>, MorphError> {
    let mut depth = vec![NONE; protos.len()];
    for i in 0..protos.len() {
        let mut chain = vec![i];
        while let Some(&c) = chain.last() {
            let p = protos[c].parent;
            if p == NONE {
                depth[c] = 0;
                break;
            }
            if depth[p as usize] != NONE {
                depth[c] = depth[p as usize] + 1;
                break;
            }
            if chain.len() > protos.len() {
                return Err(internal("the union chains form a cycle"));
            }
            chain.push(p as usize);
        }
        while let Some(c) = chain.pop() {
            if depth[c] == NONE {
                let p = protos[c].parent as usize;
                depth[c] = depth[p] + 1;
            }
        }
    }
    Ok(depth)
}

/// Pass 1, sequential and cheap: sample parameters, node numbering and
/// chain records, parents first.
struct ChainLayout {
    chain_plans: Vec<ChainPlan>,
    chains: Vec<UnionChain>,
    /// Per union chain: its source and target chain.
    sides: Vec<[Option<ChainId>; 2]>,
    sample_u: Vec<f32>,
    sample_inv_span: Vec<f32>,
    /// Per sample and side: the input node it is, if any.
    origins: [Vec<Option<u32>>; 2],
    node_origins: Vec<NodeOrigin>,
    parents: Vec<Option<NodeId>>,
    levels: Vec<Range<u32>>,
}

impl ChainLayout {
    fn of(union: &UnionChains, arrays: &[ChainArrays; 2]) -> Result<ChainLayout, MorphError> {
        let protos = &union.protos;
        let bound: usize = protos
            .iter()
            .map(|p| {
                p.source.map_or(0, |c| arrays[0].get(c).points.len())
                    + p.target.map_or(0, |c| arrays[1].get(c).points.len())
            })
            .sum();
        let mut node_origins = Vec::with_capacity(bound + 1);
        node_origins.push(NodeOrigin {
            source: Some(0),
            target: Some(0),
        });
        let mut parents: Vec<Option<NodeId>> = Vec::with_capacity(bound + 1);
        parents.push(None);
        let mut layout = ChainLayout {
            chain_plans: Vec::with_capacity(protos.len()),
            chains: Vec::with_capacity(protos.len()),
            sides: Vec::with_capacity(protos.len()),
            sample_u: Vec::with_capacity(bound),
            sample_inv_span: Vec::with_capacity(bound),
            origins: [Vec::with_capacity(bound), Vec::with_capacity(bound)],
            node_origins,
            parents,
            levels: Vec::new(),
        };
        let mut params = Params::default();
        for proto in protos {
            let cs = proto.source.map(|c| arrays[0].get(c));
            let ct = proto.target.map(|c| arrays[1].get(c));
            union_params(cs, ct, &mut params);
            layout.push_chain(proto, [cs, ct], &params)?;
        }
        layout.levels = level_ranges(&layout.chains);
        Ok(layout)
    }

    /// Appends one union chain (its parent already laid out) with the
    /// sample parameters `params`.
    fn push_chain(
        &mut self,
        proto: &Proto,
        [cs, ct]: [Option<ChainView>; 2],
        params: &Params,
    ) -> Result<(), MorphError> {
        let u = &params.u;
        let first = self.sample_u.len() as u32;
        let k = u.len();
        if first as usize + k + 1 > u32::MAX as usize {
            return Err(MorphError::TooLarge(format!(
                "more than {} union nodes",
                u32::MAX
            )));
        }
        let parent = proto.parent;
        let parent_plan = (parent != NONE).then(|| self.chain_plans[parent as usize]);
        let p = [cs.map_or(0.0, |c| c.growth), ct.map_or(0.0, |c| c.growth)];
        let p = match proto.operation {
            Operation::Wilt => [p[0], p[0]],
            Operation::Grow => [p[1], p[1]],
            _ => p,
        };
        self.push_samples(params);
        let node0 = 1 + first;
        self.push_nodes(node0, parent_plan, p, [cs, ct], params);
        self.chain_plans.push(ChainPlan {
            operation: proto.operation,
            first,
            len: k as u32,
            parent,
            parent_first: parent_plan.map_or(0, |pp| pp.first),
            parent_len: parent_plan.map_or(0, |pp| pp.len),
            p,
            parent_segments: match parent_plan {
                None => [0, 0],
                Some(pp) => {
                    let pu = &self.sample_u[pp.first as usize..(pp.first + pp.len) as usize];
                    let (a, b) = (locate(pu, p[0]) as u32, locate(pu, p[1]) as u32);
                    [a.min(b), a.max(b)]
                }
            },
            junction_radius: [
                cs.map_or(0.0, |c| c.radii[0].min(c.radii[1])),
                ct.map_or(0.0, |c| c.radii[0].min(c.radii[1])),
            ],
            detour: Vec3::ZERO,
            lift: 0.0,
        });
        self.sides.push([proto.source, proto.target]);
        self.chains.push(UnionChain {
            operation: proto.operation,
            source: proto.source,
            target: proto.target,
            parent: (parent != NONE).then_some(parent),
            level: proto.level,
            nodes: node0..node0 + k as u32,
        });
        Ok(())
    }

    /// A chain's sample parameters, inverse spans and input origins.
    fn push_samples(&mut self, params: &Params) {
        let u = &params.u;
        self.sample_u.extend_from_slice(u);
        self.sample_inv_span.extend(u.windows(2).map(|w| {
            if w[1] > w[0] {
                1.0 / (w[1] - w[0])
            } else {
                0.0
            }
        }));
        self.sample_inv_span.push(0.0);
        self.origins[0].extend_from_slice(&params.origin[0]);
        self.origins[1].extend_from_slice(&params.origin[1]);
    }

    /// A chain's nodes from `node0` on: the junction (on the parent at the
    /// nearer growth location, or the root), then one per sample.
    fn push_nodes(
        &mut self,
        node0: u32,
        parent_plan: Option<ChainPlan>,
        p: [f32; 2],
        [cs, ct]: [Option<ChainView>; 2],
        params: &Params,
    ) {
        let (os, ot) = (&params.origin[0], &params.origin[1]);
        let k = params.u.len();
        let junction_parent = match parent_plan {
            None => 0,
            Some(pp) => {
                let (f, n) = (pp.first as usize, pp.len as usize);
                let j = locate(&self.sample_u[f..f + n], p[0].min(p[1]));
                1 + pp.first + j as u32
            }
        };
        self.parents.push(Some(junction_parent));
        for j in 1..k as u32 {
            self.parents.push(Some(node0 + j - 1));
        }
        for j in 0..k {
            self.node_origins.push(NodeOrigin {
                source: cs.zip(os[j]).map(|(c, o)| c.nodes[o as usize]),
                target: ct.zip(ot[j]).map(|(c, o)| c.nodes[o as usize]),
            });
        }
    }
}

/// The range of union chains on each level (`chains` sorted by level).
fn level_ranges(chains: &[UnionChain]) -> Vec<Range<u32>> {
    let mut levels: Vec<Range<u32>> = Vec::new();
    for (i, c) in chains.iter().enumerate() {
        let l = c.level as usize;
        if levels.len() <= l {
            levels.push(i as u32..i as u32);
        }
        levels[l].end = i as u32 + 1;
    }
    levels
}

/// Pass 2, level by level with rayon: each side's samples, the anchor
/// frame (the parent's frame at the growth location, exactly as the
/// morpher will compute it) and the slerp coefficients.
fn sample_sides(
    arrays: &[ChainArrays; 2],
    layout: &ChainLayout,
) -> Result<(Vec<SideData>, Vec<Sample>), MorphError> {
    let chain_plans = &layout.chain_plans;
    let mut side_data = vec![SideData::default(); layout.sample_u.len()];
    let mut samples = vec![Sample::default(); layout.sample_u.len()];
    let cx = BuildContext {
        arrays,
        sample_u: &layout.sample_u,
        sample_inv_span: &layout.sample_inv_span,
        origins: &layout.origins,
    };
    for level in &layout.levels {
        let r = level.start as usize..level.end as usize;
        let Some(first) = chain_plans.get(r.start) else {
            continue;
        };
        let last = &chain_plans[r.end - 1];
        let (a, b) = (first.first as usize, (last.first + last.len) as usize);
        let (done, rest) = side_data.split_at_mut(a);
        build_chains(
            &cx,
            &chain_plans[r.clone()],
            &layout.sides[r],
            done,
            &mut rest[..b - a],
            &mut samples[a..b],
            a,
        )?;
    }
    Ok((side_data, samples))
}

/// One planned leaf: its plan, its topology, its hosts at t = 0 and 1 and
/// its offset lengths there.
type Planned = (LeafPlan, FrameLeafTopology, [u32; 2], [f32; 2]);

/// Every leaf's [`Planned`] parts, in correspondence order.
struct PlannedLeaves {
    plans: Vec<LeafPlan>,
    topology: Vec<FrameLeafTopology>,
    hosts: Vec<[u32; 2]>,
    offset_lens: Vec<[f32; 2]>,
}

/// Places the leaves on the laid-out union chains.
struct LeafPlanner<'a> {
    union: &'a UnionChains,
    layout: &'a ChainLayout,
    side_data: &'a [SideData],
    samples: &'a [Sample],
    /// The source's and the target's leaves.
    facts: [Vec<LeafFacts>; 2],
    /// Whether leaves move in straight lines (`LeafMorph::RandomLinear`)
    /// rather than ride on their chains.
    linear: bool,
    /// Whether a leaf that grows or wilts (a staged schedule) opens from
    /// the bark as a bud: its offset starts (or ends) on the wood's radius
    /// there, so a leaf just starting to unfold neither hangs off the bark
    /// nor hides in the wood. On a chain growing from its tip the morpher
    /// then scales the offset with the wood as it is at the time.
    buds: bool,
}

impl LeafPlanner<'_> {
    /// Plans every leaf of `matches` (grouped by star, hence by host), in
    /// parallel.
    fn plan_all(&self, matches: &[LeafMatch]) -> Result<PlannedLeaves, MorphError> {
        // Filled in place (a vector of tuples would be one more big temporary).
        let n = matches.len();
        let mut out = PlannedLeaves {
            plans: vec![
                LeafPlan {
                    mode: LeafMode::OnChain,
                    host: 0,
                    param: [0.0; 2],
                    segments: [0; 2],
                    position: [Vec3::ZERO; 2],
                    orientation: Quat::IDENTITY,
                    orientation_perp: Quat::IDENTITY,
                    omega: 0.0,
                    width: [0.0; 2],
                    height: [0.0; 2],
                };
                n
            ],
            topology: vec![
                FrameLeafTopology {
                    node: 0,
                    materials: [0; 2],
                };
                n
            ],
            hosts: vec![[0u32; 2]; n],
            offset_lens: vec![[0.0f32; 2]; n],
        };
        out.plans
            .par_iter_mut()
            .zip(out.topology.par_iter_mut())
            .zip(out.hosts.par_iter_mut())
            .zip(out.offset_lens.par_iter_mut())
            .zip(matches.par_iter())
            .with_min_len(1024)
            .try_for_each(|((((plan, topology), hosts), lens), m)| {
                (*plan, *topology, *hosts, *lens) = self.plan(m)?;
                Ok::<(), MorphError>(())
            })?;
        Ok(out)
    }

    /// The samples of union chain `host`: parameters, inverse spans and
    /// side data.
    fn host_samples(&self, host: u32) -> (&[f32], &[f32], &[SideData]) {
        let c = &self.layout.chain_plans[host as usize];
        let r = c.first as usize..(c.first + c.len) as usize;
        (
            &self.layout.sample_u[r.clone()],
            &self.layout.sample_inv_span[r.clone()],
            &self.side_data[r],
        )
    }

    /// A leaf relative to a union chain's side: local offset and local
    /// orientation, exactly as the morpher reconstructs them.
    fn place(&self, side: usize, leaf: &LeafFacts, host: u32) -> (Vec3, Quat) {
        let (u, inv_span, data) = self.host_samples(host);
        let (point, frame) = side_point_frame(u, inv_span, data, side, leaf.param);
        let inv = frame.inverse();
        (
            inv * (leaf.anchor - point),
            (inv * leaf.orientation).normalize(),
        )
    }

    /// Where a leaf placed at `offset` with `orientation` (in `host`'s
    /// frame on `side` at `param`) has its bud: on the bark, at the same
    /// height along the chain, towards the leaf (the chain frame's y axis
    /// is the tangent), or towards the blade's normal when the leaf sits
    /// on the axis, as imported cards often do.
    fn bud(&self, (offset, orientation): (Vec3, Quat), host: u32, side: usize, param: f32) -> Vec3 {
        let c = &self.layout.chain_plans[host as usize];
        let r = c.first as usize..(c.first + c.len) as usize;
        let (u, inv_span) = (
            &self.layout.sample_u[r.clone()],
            &self.layout.sample_inv_span[r.clone()],
        );
        let s = &self.samples[r];
        let j = locate(u, param);
        let at = fraction(u, inv_span, j, param);
        let radius = s[j].radius[side] + (s[j + 1].radius[side] - s[j].radius[side]) * at;
        let radial = |v: Vec3| Vec3::new(v.x, 0.0, v.z).try_normalize();
        let out = radial(offset)
            .or_else(|| radial(orientation * Vec3::Z))
            .unwrap_or(Vec3::X);
        out * radius + Vec3::Y * offset.y
    }

    /// The union chains a leaf is on at t = 0 and 1.
    fn hosts(&self, a: Option<&LeafFacts>, b: Option<&LeafFacts>) -> Result<[u32; 2], MorphError> {
        let [primary_src, primary_tgt] = &self.union.primary;
        Ok(match (a, b) {
            (Some(a), Some(b)) if !self.linear => {
                let h = pair_of(&self.union.pairs_of, a.inner_lobe, b.inner_lobe)
                    .ok_or_else(|| internal("matched leaves on unmatched chains"))?;
                [h, h]
            }
            (Some(a), Some(b)) => [
                primary_src[a.inner_lobe as usize],
                primary_tgt[b.inner_lobe as usize],
            ],
            (Some(a), None) => [primary_src[a.inner_lobe as usize]; 2],
            (None, Some(b)) => [primary_tgt[b.inner_lobe as usize]; 2],
            (None, None) => return Err(internal("an empty leaf match")),
        })
    }

    fn plan(&self, m: &LeafMatch) -> Result<Planned, MorphError> {
        let a = m.source.map(|l| &self.facts[0][l as usize]);
        let b = m.target.map(|l| &self.facts[1][l as usize]);
        let hosts = self.hosts(a, b)?;
        // The side that exists stands in for the missing one, at size 0.
        let (fa, fb) = match (a, b) {
            (Some(a), Some(b)) => (a, b),
            (Some(a), None) => (a, a),
            (None, Some(b)) => (b, b),
            (None, None) => return Err(internal("an empty leaf match")),
        };
        let size = |x: Option<&LeafFacts>| x.map_or([0.0, 0.0], |x| [x.width, x.height]);
        let sizes = [size(a), size(b)];
        let (plan, lens) = if self.linear {
            linear_plan(fa, fb, hosts[0], sizes)
        } else {
            self.on_chain_plan(a, b, [fa, fb], hosts[0], sizes)?
        };
        let topology = self.riding_branch(&plan, hosts[0], [fa.material, fb.material]);
        Ok((plan, topology, hosts, lens))
    }

    /// The plan of a leaf carried by its host chain (the paper), and its
    /// offset lengths at t = 0 and 1.
    fn on_chain_plan(
        &self,
        a: Option<&LeafFacts>,
        b: Option<&LeafFacts>,
        [fa, fb]: [&LeafFacts; 2],
        host: u32,
        [size_a, size_b]: [[f32; 2]; 2],
    ) -> Result<(LeafPlan, [f32; 2]), MorphError> {
        let hc = &self.layout.chain_plans[host as usize];
        let pa = a.map(|x| self.place(0, x, host));
        let pb = b.map(|x| self.place(1, x, host));
        let (la, lb) = match (pa, pb) {
            (Some(x), Some(y)) => (x, y),
            (Some(x), None) => (x, x),
            (None, Some(y)) => (y, y),
            (None, None) => return Err(internal("an empty leaf match")),
        };
        let (orientation_perp, omega) = arc_coefficients_q(la.1, lb.1);
        // A leaf that grows or wilts keeps its place; on a chain that
        // grows or wilts its offset from the axis scales with the chain.
        let mut offset = [la.0, lb.0];
        if hc.operation == Operation::Grow {
            offset[0] = Vec3::ZERO;
        }
        if hc.operation == Operation::Wilt {
            offset[1] = Vec3::ZERO;
        }
        if self.buds && a.is_none() {
            offset[0] = self.bud((offset[1], lb.1), host, 1, fb.param);
        }
        if self.buds && b.is_none() {
            offset[1] = self.bud((offset[0], la.1), host, 0, fa.param);
        }
        let lens = [offset[0].length(), offset[1].length()];
        let hu = &self.layout.sample_u[hc.first as usize..(hc.first + hc.len) as usize];
        let (j0, j1) = (locate(hu, fa.param) as u32, locate(hu, fb.param) as u32);
        let plan = LeafPlan {
            mode: LeafMode::OnChain,
            host,
            param: [fa.param, fb.param],
            segments: [j0.min(j1), j0.max(j1)],
            position: offset,
            orientation: la.1,
            orientation_perp,
            omega,
            width: [size_a[0], size_b[0]],
            height: [size_a[1], size_b[1]],
        };
        Ok((plan, lens))
    }

    /// The branch the leaf rides on: the host's segment holding its
    /// mid-morph parameter.
    fn riding_branch(&self, plan: &LeafPlan, host: u32, materials: [u32; 2]) -> FrameLeafTopology {
        let c = &self.layout.chain_plans[host as usize];
        let r = c.first as usize..(c.first + c.len) as usize;
        let mid = match plan.mode {
            LeafMode::OnChain => 0.5 * (plan.param[0] + plan.param[1]),
            LeafMode::Linear => plan.param[0],
        };
        let j = locate(&self.layout.sample_u[r], mid);
        FrameLeafTopology {
            node: 1 + c.first + j as u32 + 1,
            materials,
        }
    }
}

/// The plan of a leaf moving in a straight line
/// (`LeafMorph::RandomLinear`), and its offset lengths at t = 0 and 1.
fn linear_plan(
    fa: &LeafFacts,
    fb: &LeafFacts,
    host: u32,
    [size_a, size_b]: [[f32; 2]; 2],
) -> (LeafPlan, [f32; 2]) {
    let (orientation_perp, omega) = arc_coefficients_q(fa.orientation, fb.orientation);
    let plan = LeafPlan {
        mode: LeafMode::Linear,
        host,
        param: [fa.param, fb.param],
        segments: [0, 0],
        position: [fa.anchor, fb.anchor],
        orientation: fa.orientation,
        orientation_perp,
        omega,
        width: [size_a[0], size_b[0]],
        height: [size_a[1], size_b[1]],
    };
    (plan, [fa.offset_len, fb.offset_len])
}

#[cfg(test)]
mod frame_arc_tests {
    use std::f32::consts::PI;

    use glam::Quat;

    use super::{arc_coefficients_q, frame_arc};
    use crate::morpher::arc_q;

    /// The frame an arc's coefficients give at weight `w`, as the morpher
    /// evaluates it.
    fn at(a: Quat, (perp, omega): (Quat, f32), w: f32) -> Quat {
        arc_q(a, perp, omega, w)
    }

    /// A chain's samples whose frames turn by 170°, 178°, 186° and 194°
    /// about its axis between the trees: the shortest arcs of the last two
    /// turn the other way (−174°, −166°), so half way the second and
    /// third sample's frames are a half turn apart. Following the previous
    /// sample's arc keeps neighbours within their 8° step all along.
    #[test]
    fn neighbouring_sample_frames_turn_the_same_way() {
        let a: Vec<Quat> = (0..4)
            .map(|j| Quat::from_rotation_x(0.02 * j as f32))
            .collect();
        let b: Vec<Quat> = (0..4)
            .map(|j| Quat::from_rotation_y((170.0 + 8.0 * j as f32).to_radians()) * a[j])
            .collect();
        let mut follow = None;
        let arcs: Vec<(Quat, f32)> = (0..4)
            .map(|j| {
                let (arc, mid) = frame_arc(a[j], b[j], follow);
                follow = Some(mid);
                arc
            })
            .collect();
        let shortest: Vec<(Quat, f32)> = (0..4).map(|j| arc_coefficients_q(a[j], b[j])).collect();
        let widest = |arcs: &[(Quat, f32)], w: f32| {
            (1..4)
                .map(|j| at(a[j - 1], arcs[j - 1], w).angle_between(at(a[j], arcs[j], w)))
                .fold(0.0f32, f32::max)
        };
        assert!(
            widest(&shortest, 0.5) > 0.9 * PI,
            "the shortest arcs part ways"
        );
        for w in [0.1f32, 0.25, 0.5, 0.75, 0.9] {
            let widest = widest(&arcs, w);
            assert!(widest < 10f32.to_radians(), "{widest} rad apart at {w}");
        }
        for j in 0..4 {
            assert!(at(a[j], arcs[j], 0.0).angle_between(a[j]) < 2e-3);
            assert!(
                at(a[j], arcs[j], 1.0).angle_between(b[j]) < 2e-3,
                "sample {j} ends as b"
            );
        }
    }
}
