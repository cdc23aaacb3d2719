//! Routing swings round their siblings. The crossing cost in the matching
//! (`crossing`) picks partners whose limbs need not meet; a limb that must
//! still swing through a sibling to reach its partner is **routed round**
//! it here: its path bows out of the way and comes back. Staged schedules
//! only ([`MorphOptions::route_round`](crate::MorphOptions::route_round));
//! `linear` keeps the paper's paths.
//!
//! # The detour
//! A blended union chain (a morph, split or merge copy; not one growing or
//! wilting from its tip, which never swings) may carry a
//! [`detour`](crate::plan::ChainPlan::detour): a rotation about its
//! junction, in its anchor frame, applied with `4w(1 − w)` of its angle
//! (`w` its blend weight). So the ends are exactly the inputs, the path
//! bows out by the whole angle half way through the chain's window, and
//! the turn is smooth inside it (its rate is 0 where the eased weight's
//! is). Its children and leaves hang on it and follow.
//!
//! # The lift
//! A union chain's junction node sits on its parent's axis, so two limbs
//! whose junctions slide past each other along the parent (their order
//! along it differs between the trees) touch there, however far apart
//! round the parent they are: on conifer → willow every remaining sibling
//! crossing was such a pair. Mid-blend the junction of a chain that passes
//! a sibling therefore stands off the axis towards where the chain leaves
//! the parent: by `4w(1 − w)` of its
//! [`lift`](crate::plan::ChainPlan::lift), less for a chain leaving within
//! 30° of the parent's axis (so it stays near the axis instead of whipping
//! round it). The lift
//! is as much as keeps the chain's base within [`LIFT_DEPTH`] of the
//! parent's radius (its thinnest between the junction's two ends), so the
//! base stays inside the bark and shows no gap, and limbs on different
//! sides of a trunk pass each other apart; thick limbs on thin parents
//! (most third-party trees) get none. The lift is part of the chain: a
//! detour turns it too. A wilting limb whose junction a sibling's passes
//! is lifted as well (on conifer → willow a third of the passing pairs
//! were a merging limb and a wilting one), on the reshape phase's clock,
//! which the passing sibling's window lies in, towards where it leaves
//! the parent at t = 0; it retracts into its lifted junction. Growing
//! limbs keep their junctions on the axis: they grow from it.
//!
//! # The choice
//! The star of every union chain (its children; the root chains form one
//! more) is checked for crossings as the output-level meter counts them
//! (`treemorph_verify::CrossingMeter`): two children cross when capsules of
//! their segments (radius: the larger of the segment's end radii; none
//! when both are 0) overlap at an inner instant and at neither end, here
//! at [`SAMPLES`] instants of the plan's own frames (its schedule's windows
//! and easing and the lifts included; before the pace, which only
//! reparametrises time for all chains alike, so it changes which
//! instants are sampled, not which pairs touch). Each blended child in a crossing,
//! those in the most first, tries turns of [`ANGLES`] either way about two
//! axes square to its mid-swing chord: one bows the swing out of its
//! plane, the other leads or lags it in the plane (for a chain that does
//! not swing, any two such axes). It keeps the turn that leaves it the
//! fewest crossings with its siblings, the smaller angle on a tie, when
//! that is fewer than it has; [`PASSES`] passes over the star. 33 samples
//! rather than 17 or 25: a limb passing a sibling in less than 1/32 of the
//! morph was missed, and a detour chosen at 17 samples could add crossings
//! the 60 frames of a job then show (conifer → willow, 5,000 branches:
//! most sibling crossings in a frame 61 at 17 samples, 63 at 25, 57 at 33
//! and at 49).
//!
//! Only siblings are compared: the crossing figure of issue 19 for trees
//! from other tools is between limbs of one parent. A star turns whole
//! with its parent's detour, so each star is routed on its own (in
//! parallel) and the parents' detours do not change their children's
//! crossings.
//!
//! Hand-written: a few dozen lines of capsule tests on top of
//! [`segment_segment_sq`]; no crate plans paths among moving segments.

use std::cmp::Reverse;

use glam::{Quat, Vec3};
use rayon::prelude::*;
use treemorph_tree::Frame;
use treemorph_tree::geom::{NONE, segment_segment_sq};

use crate::correspondence::Operation;
use crate::morpher::{Morpher, detour_turn};
use crate::plan::MorphPlan;
use crate::schedule::ChainState;

/// Instants sampled, ends included.
pub(crate) const SAMPLES: usize = 33;

/// The turns tried, radians.
pub(crate) const ANGLES: [f32; 2] = [0.2, 0.4];

/// Passes over a star.
const PASSES: usize = 2;

/// Stars with more children than this are left as they are: a star's
/// crossings are sought among all pairs of its children, and the largest
/// star of the preset and third-party trees has 104.
const MAX_CHILDREN: usize = 1024;

/// Lifts the junctions of `plan`'s blended chains that pass a sibling,
/// then gives those that cross a sibling the detour that clears most of
/// their crossings (see the module docs).
pub(crate) fn route(plan: &mut MorphPlan) {
    let stars = stars(plan);
    lift_junctions(plan, &stars);
    let sampled = Sampled::of(plan);
    let detours: Vec<(u32, Vec3)> = stars
        .par_iter()
        .flat_map_iter(|kids| Star::new(plan, &sampled, kids).route())
        .collect();
    for (chain, detour) in detours {
        plan.chain_plans[chain as usize].detour = detour;
    }
}

/// How deep in its parent a lifted junction's chain stays: its base ring
/// within this fraction of the parent's radius from the axis.
const LIFT_DEPTH: f32 = 0.85;

/// Gives every blended or wilting chain on a parent whose junction passes
/// a sibling's along it (or is passed by one) its lift: as far off the
/// parent's axis as keeps its base inside the parent's thinnest point
/// between its junction's two ends. A chain that passes no sibling keeps
/// its junction on the axis (a tree morphed into itself stands still).
fn lift_junctions(plan: &mut MorphPlan, stars: &[Vec<u32>]) {
    let passing: Vec<u32> = stars
        .iter()
        .flat_map(|kids| passing_siblings(plan, kids))
        .collect();
    for i in passing {
        let c = plan.chain_plans[i as usize];
        let [lo, hi] = c.parent_segments;
        let parent = (c.parent_first + lo) as usize..=(c.parent_first + hi + 1) as usize;
        // The parent's first node is drawn with its own junction radius.
        let base = (lo == 0).then(|| plan.chain_plans[c.parent as usize].junction_radius);
        let thinnest = (plan.samples[parent].iter())
            .flat_map(|s| s.radius)
            .chain(base.into_iter().flatten())
            .fold(f32::INFINITY, f32::min);
        let base = plan.samples[c.first as usize + 1].radius;
        let own = c
            .junction_radius
            .into_iter()
            .chain(base)
            .fold(0.0, f32::max);
        plan.chain_plans[i as usize].lift = (LIFT_DEPTH * thinnest - own).max(0.0);
    }
}

/// The blended and wilting children of one parent whose growth location
/// passes a sibling's: the two are in one order along the parent at t = 0
/// and in the other at t = 1. A growing or wilting sibling counts too, drawn or
/// not when the junction passes it: a needless lift costs a little motion
/// inside the bark, a missing one a crossing.
fn passing_siblings<'a>(plan: &'a MorphPlan, kids: &'a [u32]) -> impl Iterator<Item = u32> + 'a {
    let p = |k: u32| plan.chain_plans[k as usize].p;
    kids.iter().copied().filter(move |&k| {
        let c = &plan.chain_plans[k as usize];
        let tip_first = plan.schedule.tip_first(k as usize);
        c.parent != NONE
            && (!tip_first || c.operation == Operation::Wilt)
            && kids.iter().any(|&o| {
                let (a, b) = (p(k), p(o));
                (a[0] - b[0]) * (a[1] - b[1]) < 0.0
            })
    })
}

/// The instant of sample `k`.
fn instant(k: usize) -> f32 {
    k as f32 / (SAMPLES - 1) as f32
}

/// The plan's branches at the sampled instants, with every union chain's
/// junction and anchor frame there.
struct Sampled {
    frames: Vec<Frame>,
    /// `[sample][chain]`.
    anchors: Vec<Vec<(Vec3, Quat)>>,
}

impl Sampled {
    fn of(plan: &MorphPlan) -> Sampled {
        let (frames, anchors) = (0..SAMPLES)
            .into_par_iter()
            .map(|k| {
                let mut morpher = Morpher::new(plan);
                let mut frame = Frame::default();
                morpher.morph_branches(instant(k), &mut frame);
                let anchors = morpher.anchors(&frame);
                (frame, anchors)
            })
            .unzip();
        Sampled { frames, anchors }
    }
}

/// The children of every union chain, and the root chains, where there
/// are two or more.
fn stars(plan: &MorphPlan) -> Vec<Vec<u32>> {
    let n = plan.chain_plans.len();
    let mut kids: Vec<Vec<u32>> = vec![Vec::new(); n + 1];
    for (i, c) in plan.chain_plans.iter().enumerate() {
        let parent = if c.parent == NONE {
            n
        } else {
            c.parent as usize
        };
        kids[parent].push(i as u32);
    }
    kids.retain(|k| (2..=MAX_CHILDREN).contains(&k.len()));
    kids
}

/// A segment drawn at a sample: its ends and radius.
#[derive(Clone, Copy, Debug)]
struct Capsule {
    a: Vec3,
    b: Vec3,
    r: f32,
}

impl Capsule {
    /// The capsule's bounds.
    fn bounds(&self) -> (Vec3, Vec3) {
        let pad = Vec3::splat(self.r);
        (self.a.min(self.b) - pad, self.a.max(self.b) + pad)
    }

    /// Whether the bounds `(lo, hi)` miss this capsule's.
    fn misses(&self, (lo, hi): (Vec3, Vec3)) -> bool {
        let (own_lo, own_hi) = self.bounds();
        own_lo.cmpgt(hi).any() || lo.cmpgt(own_hi).any()
    }

    fn overlaps(&self, other: &Capsule) -> bool {
        if self.misses(other.bounds()) {
            return false;
        }
        let reach = self.r + other.r;
        segment_segment_sq(self.a, self.b, other.a, other.b) < reach * reach
    }
}

/// One union chain's drawn segments at every sample.
#[derive(Clone, Debug)]
struct Track {
    capsules: Vec<Capsule>,
    /// Sample `k`'s capsules are `starts[k]..starts[k + 1]`.
    starts: [u32; SAMPLES + 1],
    bounds: [(Vec3, Vec3); SAMPLES],
}

impl Track {
    /// Chain `chain` of `plan` at the samples, turned by `detour`.
    fn of(plan: &MorphPlan, sampled: &Sampled, chain: u32, detour: Vec3) -> Track {
        let nodes = plan.chains[chain as usize].nodes.clone();
        let (first, last) = (nodes.start as usize, nodes.end as usize);
        let mut capsules = Vec::with_capacity(SAMPLES * (last - first));
        let mut starts = [0u32; SAMPLES + 1];
        let mut bounds = [(Vec3::INFINITY, Vec3::NEG_INFINITY); SAMPLES];
        for (k, frame) in sampled.frames.iter().enumerate() {
            let turn = turn_at(plan, sampled, (chain, k), detour);
            let at = |n: usize| {
                let p = frame.positions[n];
                turn.map_or(p, |(j, r)| j + r * (p - j))
            };
            for n in first..last - 1 {
                let r = frame.radii[n].max(frame.radii[n + 1]);
                if r > 0.0 && r.is_finite() {
                    let capsule = Capsule {
                        a: at(n),
                        b: at(n + 1),
                        r,
                    };
                    let (lo, hi) = capsule.bounds();
                    bounds[k] = (bounds[k].0.min(lo), bounds[k].1.max(hi));
                    capsules.push(capsule);
                }
            }
            starts[k + 1] = capsules.len() as u32;
        }
        Track {
            capsules,
            starts,
            bounds,
        }
    }

    fn at(&self, k: usize) -> &[Capsule] {
        &self.capsules[self.starts[k] as usize..self.starts[k + 1] as usize]
    }

    /// Whether capsules of the two overlap at sample `k`.
    fn touch(&self, other: &Track, k: usize) -> bool {
        let (ours, theirs) = (self.bounds[k], other.bounds[k]);
        if ours.0.cmpgt(theirs.1).any() || theirs.0.cmpgt(ours.1).any() {
            return false;
        }
        self.at(k)
            .iter()
            .filter(|c| !c.misses(theirs))
            .any(|c| other.at(k).iter().any(|d| c.overlaps(d)))
    }

    /// Whether the two touch at an inner sample and at neither end.
    fn crosses(&self, other: &Track) -> bool {
        !self.touch(other, 0)
            && !self.touch(other, SAMPLES - 1)
            && (1..SAMPLES - 1).any(|k| self.touch(other, k))
    }
}

/// The world turn (about the junction) that `detour` makes of `chain` at
/// sample `k`, if any.
fn turn_at(
    plan: &MorphPlan,
    sampled: &Sampled,
    (chain, k): (u32, usize),
    detour: Vec3,
) -> Option<(Vec3, Quat)> {
    if detour == Vec3::ZERO {
        return None;
    }
    let t = plan.schedule.paced(instant(k));
    let ChainState::Blend(w) = plan.schedule.chain(chain as usize, t) else {
        return None;
    };
    if w <= 0.0 || w >= 1.0 {
        return None;
    }
    let (junction, anchor) = sampled.anchors[k][chain as usize];
    Some((junction, anchor * detour_turn(detour, w) * anchor.inverse()))
}

/// The detours a blended chain tries, smaller angles first (none for a
/// chain of no length).
fn candidates(plan: &MorphPlan, chain: u32) -> Vec<Vec3> {
    let c = &plan.chain_plans[chain as usize];
    let own = &plan.samples[c.first as usize..(c.first + c.len) as usize];
    let (mut from, mut to) = (Vec3::ZERO, Vec3::ZERO);
    for s in &own[..own.len() - 1] {
        from += s.dir * s.len[0];
        to += (s.dir * s.theta.cos() + s.dir_perp * s.theta.sin()) * s.len[1];
    }
    let mid = (from.normalize_or_zero() + to.normalize_or_zero()).normalize_or_zero();
    if mid == Vec3::ZERO {
        return Vec::new();
    }
    let normal = from.cross(to).normalize_or_zero();
    let side = if normal == Vec3::ZERO {
        mid.any_orthonormal_vector()
    } else {
        mid.cross(normal).normalize()
    };
    let lead = mid.cross(side);
    ANGLES
        .iter()
        .flat_map(|&a| [side * a, -side * a, lead * a, -lead * a])
        .collect()
}

/// One star's children, their tracks and which pairs cross.
struct Star<'a> {
    plan: &'a MorphPlan,
    sampled: &'a Sampled,
    kids: &'a [u32],
    tracks: Vec<Track>,
    /// Row-major `n × n`.
    cross: Vec<bool>,
}

impl<'a> Star<'a> {
    fn new(plan: &'a MorphPlan, sampled: &'a Sampled, kids: &'a [u32]) -> Star<'a> {
        let tracks: Vec<Track> = (kids.iter())
            .map(|&c| Track::of(plan, sampled, c, Vec3::ZERO))
            .collect();
        let n = kids.len();
        let mut cross = vec![false; n * n];
        for i in 0..n {
            for j in i + 1..n {
                let c = tracks[i].crosses(&tracks[j]);
                cross[i * n + j] = c;
                cross[j * n + i] = c;
            }
        }
        Star {
            plan,
            sampled,
            kids,
            tracks,
            cross,
        }
    }

    fn count(&self, i: usize) -> usize {
        let n = self.kids.len();
        self.cross[i * n..(i + 1) * n]
            .iter()
            .filter(|&&c| c)
            .count()
    }

    /// The detours chosen (see the module docs), by chain.
    fn route(mut self) -> Vec<(u32, Vec3)> {
        let n = self.kids.len();
        let mut detours = vec![Vec3::ZERO; n];
        for _ in 0..PASSES {
            let mut order: Vec<usize> = (0..n)
                .filter(|&i| {
                    self.count(i) > 0 && !self.plan.schedule.tip_first(self.kids[i] as usize)
                })
                .collect();
            order.sort_by_key(|&i| (Reverse(self.count(i)), i));
            let mut changed = false;
            for i in order {
                if let Some((detour, track, row)) = self.better(i) {
                    detours[i] = detour;
                    self.tracks[i] = track;
                    for (j, c) in row.into_iter().enumerate() {
                        self.cross[i * n + j] = c;
                        self.cross[j * n + i] = c;
                    }
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        (self.kids.iter().copied().zip(detours))
            .filter(|(_, d)| *d != Vec3::ZERO)
            .collect()
    }

    /// The detour of child `i` with the fewest crossings, its track and
    /// crossings, if fewer than it has now.
    fn better(&self, i: usize) -> Option<(Vec3, Track, Vec<bool>)> {
        let mut fewest = self.count(i);
        let mut best = None;
        for detour in candidates(self.plan, self.kids[i]) {
            if fewest == 0 {
                break;
            }
            let track = Track::of(self.plan, self.sampled, self.kids[i], detour);
            let row: Vec<bool> = (0..self.kids.len())
                .map(|j| j != i && track.crosses(&self.tracks[j]))
                .collect();
            let count = row.iter().filter(|&&c| c).count();
            if count < fewest {
                fewest = count;
                best = Some((detour, track, row));
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use treemorph_analysis::{Analysis, AnalysisOptions};
    use treemorph_generate::{GenerateOptions, Preset, generate};

    use super::*;
    use crate::MorphOptions;

    /// Conifer → willow at 1,500 branches: many limbs on one trunk, with
    /// whorls that pass each other.
    fn conifer_to_willow(options: &MorphOptions) -> MorphPlan {
        conifer_to_willow_at(1500, options)
    }

    fn conifer_to_willow_at(size: u32, options: &MorphOptions) -> MorphPlan {
        let tree = |preset, seed| {
            let t = generate(&GenerateOptions::new(preset, seed).with_size(size)).unwrap();
            let a = Analysis::of(&t, &AnalysisOptions::default()).unwrap();
            (t, a)
        };
        let (a, b) = (tree(Preset::Conifer, 2), tree(Preset::Willow, 3));
        MorphPlan::new(&a.0, &a.1, &b.0, &b.1, options).unwrap()
    }

    fn blended_limbs(plan: &MorphPlan) -> Vec<usize> {
        (0..plan.chain_plans.len())
            .filter(|&i| plan.chain_plans[i].parent != NONE && !plan.schedule.tip_first(i))
            .collect()
    }

    /// Sibling pairs crossing at the samples, over all stars.
    fn model_crossings(plan: &MorphPlan) -> usize {
        let sampled = Sampled::of(plan);
        let stars = stars(plan);
        (stars.iter())
            .map(|kids| {
                let star = Star::new(plan, &sampled, kids);
                (0..kids.len()).map(|i| star.count(i)).sum::<usize>() / 2
            })
            .sum()
    }

    #[test]
    fn detours_and_lifts_move_chains_whole_and_keep_the_ends() {
        let plain = conifer_to_willow(&MorphOptions::default().with_route_round(false));
        let mut moved = plain.clone();
        let limbs = blended_limbs(&plain);
        assert!(limbs.len() > 20, "{}", limbs.len());
        for &i in &limbs {
            moved.chain_plans[i].detour = Vec3::new(0.3, -0.2, 0.1);
            moved.chain_plans[i].lift = 0.05;
        }
        for t in [0.0, 1.0] {
            let (a, b) = (plain.frame(t), moved.frame(t));
            assert_eq!(a.positions, b.positions, "t = {t}");
            assert_eq!(a.radii, b.radii, "t = {t}");
            assert_eq!(a.leaves, b.leaves, "t = {t}");
        }
        let (a, b) = (plain.frame(0.5), moved.frame(0.5));
        let most = (a.positions.iter().zip(&b.positions))
            .map(|(p, q)| p.distance(*q))
            .fold(0.0, f32::max);
        assert!(most > 0.05, "nothing moved: {most}");
        assert_eq!(a.radii, b.radii);
        for c in plain.chains() {
            for n in c.nodes.start as usize..c.nodes.end as usize - 1 {
                let length = |f: &Frame| f.positions[n].distance(f.positions[n + 1]);
                let (x, y) = (length(&a), length(&b));
                assert!((x - y).abs() <= 1e-4 * x.max(1e-2), "{x} against {y}");
            }
        }
    }

    /// What routing predicts of a detour is what the morpher draws, lift
    /// and all.
    #[test]
    fn a_detour_tried_is_the_detour_drawn() {
        let mut plain = conifer_to_willow(&MorphOptions::default().with_route_round(false));
        let limb = blended_limbs(&plain)[3] as u32;
        plain.chain_plans[limb as usize].lift = 0.05;
        let detour = Vec3::new(0.0, 0.35, -0.2);
        let tried = Track::of(&plain, &Sampled::of(&plain), limb, detour);
        let mut moved = plain.clone();
        moved.chain_plans[limb as usize].detour = detour;
        let drawn = Track::of(&moved, &Sampled::of(&moved), limb, Vec3::ZERO);
        assert_eq!(tried.starts, drawn.starts);
        let apart = (tried.capsules.iter().zip(&drawn.capsules))
            .map(|(p, q)| p.a.distance(q.a).max(p.b.distance(q.b)))
            .fold(0.0, f32::max);
        assert!(apart < 1e-4, "{apart} m apart");
        let still = Track::of(&plain, &Sampled::of(&plain), limb, Vec3::ZERO);
        let turned = (tried.capsules.iter().zip(&still.capsules))
            .map(|(p, q)| p.b.distance(q.b))
            .fold(0.0, f32::max);
        assert!(turned > 0.05, "the detour moved nothing: {turned}");
    }

    /// A lifted junction's base ring stays inside its parent's tube in
    /// the drawn frames: no gap at the bark while it slides (5,000
    /// branches: at 1,500 the conifer's limbs are too thick for their
    /// trunk to lift).
    #[test]
    fn lifted_bases_stay_inside_their_parents() {
        let plan = conifer_to_willow_at(5000, &MorphOptions::default());
        let lifted: Vec<usize> = (0..plan.chain_plans.len())
            .filter(|&i| plan.chain_plans[i].lift > 0.0)
            .collect();
        let wilting = |&i: &usize| plan.chain_plans[i].operation == Operation::Wilt;
        assert!(lifted.iter().any(wilting), "no wilting limb lifted");
        assert!(!lifted.iter().all(wilting), "no blended limb lifted");
        let mut morpher = Morpher::new(&plan);
        let mut frame = Frame::default();
        let mut farthest = 0.0f32;
        for k in 1..24 {
            morpher.morph(k as f32 / 24.0, &mut frame);
            for &i in &lifted {
                let (gap, girth) = off_axis(&plan, &frame, i);
                let r = frame.radii[plan.chains[i].nodes.start as usize];
                assert!(
                    gap + r <= girth * 1.001,
                    "chain {i}: its base {gap} m off the axis with radius {r} m, the parent's {girth} m"
                );
                farthest = farthest.max(gap);
            }
        }
        assert!(
            farthest > 0.01,
            "no junction left its parent's axis: {farthest} m"
        );
    }

    /// How far chain `i`'s junction node is from its parent's axis, and
    /// the parent's radius at the point of the axis nearest it (its
    /// segment's radii interpolated).
    fn off_axis(plan: &MorphPlan, frame: &Frame, i: usize) -> (f32, f32) {
        let p = frame.positions[plan.chains[i].nodes.start as usize];
        let parent = plan.chains[plan.chain_plans[i].parent as usize]
            .nodes
            .clone();
        (parent.start as usize..parent.end as usize - 1)
            .map(|n| {
                let (a, b) = (frame.positions[n], frame.positions[n + 1]);
                let f = ((p - a).dot(b - a) / (b - a).length_squared().max(1e-12)).clamp(0.0, 1.0);
                let girth = frame.radii[n] + (frame.radii[n + 1] - frame.radii[n]) * f;
                (p.distance(a + (b - a) * f), girth)
            })
            .min_by(|x, y| x.0.total_cmp(&y.0))
            .expect("a parent has a segment")
    }

    #[test]
    fn routing_lowers_the_crossings_between_siblings() {
        // Untangling sheds what routing leaves crossing: compare routing
        // alone.
        let tangled = MorphOptions::default().with_untangle(false);
        let plain = conifer_to_willow(&tangled.clone().with_route_round(false));
        let routed = conifer_to_willow(&tangled);
        let (before, after) = (model_crossings(&plain), model_crossings(&routed));
        assert!(after < before, "{after} against {before}");
        assert!(routed.chain_plans.iter().any(|c| c.detour != Vec3::ZERO));
    }
}
