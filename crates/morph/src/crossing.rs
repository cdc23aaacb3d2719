//! Crossing cost in the matching. §5 matches on summaries, with no
//! penalty for paths that cross, and limbs swing through each other
//! mid-morph. The pairs that do are siblings on one parent from
//! **different** chain groups: on the five preset pairs (default morphs,
//! 5,000 branches), not one crossing pair of siblings came from the same
//! matched pair of groups. So the cost belongs to the matching of a star's
//! child groups: after its minimum-weight matching, [`uncross`] swaps the
//! partners of two matched groups where that removes more crossings, times
//! [`GroupCostWeights::crossing`], than it adds group cost, and adds no
//! more than one crossing's worth (without that bound, a swap that cleared
//! many crossings traded a limb for a far partner, and ash → aspen's
//! largest move in a frame went from 3.8 % to 12 % of the height). A pair of
//! groups moves as the union chains its chains' own matching would make
//! (`group_swing` in `correspondence`, the same greedy matching). Only
//! one-to-one stars are searched: there all child groups hang on one
//! parent on each side, so their motions compare in its frame.
//!
//! # The motion model
//! The morph turns each segment of a chain about its junction, in the
//! parent's frame there, from its source direction to its target direction
//! (a slerp), while its length changes linearly and its junction slides
//! along the parent. The model keeps exactly that and drops the detail: a
//! chain is four segments (its polyline at 0, ¼, ½, ¾ and all of its arc
//! length) in its parent's local frame (x normal, y tangent, z binormal),
//! each turning by slerp with linearly changing length, and the junction
//! moves along the parent's tangent by its growth location times the
//! parent's length. Positions are in units of the tree's height, so a
//! source and a target chain compare by where they are in their crowns.
//! Siblings share the parent, so the parent's own motion moves them
//! together and is left out; so do the staged schedule's windows.
//!
//! # Touching
//! As the output-level meter (`treemorph_verify::CrossingMeter`) counts
//! them: two union chains cross when capsules of their segments (radius:
//! the chain's base radius, interpolated) overlap at an instant between
//! the ends and at neither end; nine samples of t. Against that meter on
//! the written meshes of the default maple → conifer, willow → eucalyptus
//! and conifer → willow morphs, the model's sibling crossings were 87–95 %
//! right (61 of 65, 52 of 55, 167 of 191) and found 55–87 % of the
//! meter's; a two-segment pass-through test found only 13–38 %.
//!
//! Hand-written: tens of lines of segment geometry on top of
//! [`segment_segment_sq`]; no crate offers moving-segment contact.
//!
//! [`GroupCostWeights::crossing`]: crate::GroupCostWeights::crossing

use std::collections::HashMap;

use glam::{Quat, Vec3};
use treemorph_analysis::ChainId;
use treemorph_tree::geom::segment_segment_sq;

use crate::assignment::FORBIDDEN;
use crate::correspondence::Input;

/// Samples of t in [0, 1], ends included.
const SAMPLES: usize = 9;

/// Passes of pairwise swaps over one star.
const PASSES: usize = 3;

/// Stars with more matched groups than this keep their matching (the swap
/// search is cubic in the pairs).
const MAX_PAIRS: usize = 256;

/// Where a chain is, relative to its parent at its junction: the junction's
/// distance along the parent, the chain's [`PARTS`] segments as vectors in
/// the parent's local frame, and its base radius, in units of the tree's
/// height.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Pose {
    along: f32,
    parts: [Vec3; PARTS],
    radius: f32,
}

/// Segments a chain is cut into.
const PARTS: usize = 4;

impl Pose {
    /// The pose of `chain` of `input`'s tree.
    pub fn of(input: &Input, chain: ChainId) -> Pose {
        let c = input.analysis.chain(chain);
        let (along, frame) = match c.parent {
            Some(p) => {
                let parent = input.analysis.chain(p);
                let u = c.growth_location;
                (u * parent.length, parent.frame_at(u))
            }
            None => (0.0, Quat::IDENTITY),
        };
        let to_local = frame.inverse();
        let scale = input.inv_height;
        let points: [Vec3; PARTS + 1] =
            std::array::from_fn(|k| c.point_at(k as f32 / PARTS as f32).0);
        Pose {
            along: along * scale,
            parts: std::array::from_fn(|k| to_local * (points[k + 1] - points[k]) * scale),
            radius: c.radii.get(1).copied().unwrap_or(0.0) * scale,
        }
    }
}

/// The segments of a union chain going from pose `a` to pose `b`, at `t`.
fn segments(a: &Pose, b: &Pose, t: f32) -> [[Vec3; 2]; PARTS] {
    let mut at = Vec3::new(0.0, a.along + (b.along - a.along) * t, 0.0);
    std::array::from_fn(|k| {
        let (x, y) = (a.parts[k], b.parts[k]);
        let len = x.length() + (y.length() - x.length()) * t;
        let next = at + turn(x, y, t) * len;
        let seg = [at, next];
        at = next;
        seg
    })
}

/// A union chain's segments at every sample of t, with their radius and
/// bounds, computed once: the swap search compares each with many.
#[derive(Clone, Debug)]
pub(crate) struct Track {
    at: [[[Vec3; 2]; PARTS]; SAMPLES],
    radius: [f32; SAMPLES],
    lo: Vec3,
    hi: Vec3,
}

impl Track {
    /// The union chain going from pose `a` to pose `b`.
    pub fn new(a: &Pose, b: &Pose) -> Track {
        let time = |k: usize| k as f32 / (SAMPLES - 1) as f32;
        let at: [[[Vec3; 2]; PARTS]; SAMPLES] = std::array::from_fn(|k| segments(a, b, time(k)));
        let radius = std::array::from_fn(|k| a.radius + (b.radius - a.radius) * time(k));
        let points = at.iter().flatten().flatten();
        let r = a.radius.max(b.radius);
        let lo = points.clone().fold(Vec3::INFINITY, |m, p| m.min(*p)) - Vec3::splat(r);
        let hi = points.fold(Vec3::NEG_INFINITY, |m, p| m.max(*p)) + Vec3::splat(r);
        Track { at, radius, lo, hi }
    }

    /// Whether the two touch (capsules of their base radii overlap) between
    /// their ends but at neither end.
    pub fn touches(&self, other: &Track) -> bool {
        if self.lo.cmpgt(other.hi).any() || other.lo.cmpgt(self.hi).any() {
            return false;
        }
        let touch = |k: usize| {
            let r = self.radius[k] + other.radius[k];
            self.at[k].iter().any(|x| {
                other.at[k]
                    .iter()
                    .any(|y| segment_segment_sq(x[0], x[1], y[0], y[1]) < r * r)
            })
        };
        !touch(0) && !touch(SAMPLES - 1) && (1..SAMPLES - 1).any(touch)
    }
}

/// The unit direction a fraction `t` of the way along the great circle
/// from `x` to `y` (either may be zero: then the other's direction).
fn turn(x: Vec3, y: Vec3, t: f32) -> Vec3 {
    let (u, v) = (x.normalize_or_zero(), y.normalize_or_zero());
    match (u == Vec3::ZERO, v == Vec3::ZERO) {
        (true, true) => Vec3::ZERO,
        (true, false) => v,
        (false, true) => u,
        (false, false) => Quat::IDENTITY
            .slerp(Quat::from_rotation_arc(u, v), t)
            .mul_vec3(u),
    }
}

/// The union chains a matched pair of groups makes.
pub(crate) type Swing = Vec<Track>;

/// A star's child groups: the matching's costs and, for any pair of
/// groups, the union chains their chains' matching would make.
pub(crate) struct Swings<'a> {
    /// Row-major `rows × cols` costs ([`FORBIDDEN`] or more: never).
    pub cost: &'a [f64],
    pub cols: usize,
    /// Cost of one crossing.
    pub weight: f64,
    /// The union chains of source group `i` matched with target group `j`.
    pub swing: &'a dyn Fn(usize, usize) -> Swing,
}

impl Swings<'_> {
    fn cost(&self, i: usize, j: usize) -> f64 {
        self.cost[i * self.cols + j]
    }
}

/// Swaps partners of matched rows, pair by pair, while a swap saves more
/// in crossings than it adds in cost (see the module docs).
pub(crate) fn uncross(swings: &Swings, matching: &mut [Option<usize>]) {
    let matched = matching.iter().filter(|m| m.is_some()).count();
    if !(2..=MAX_PAIRS).contains(&matched) || swings.weight <= 0.0 {
        return;
    }
    let mut search = Search {
        swings,
        tracks: HashMap::new(),
        crossings: HashMap::new(),
    };
    for _ in 0..PASSES {
        let mut swapped = false;
        for a in 0..matching.len() {
            for b in a + 1..matching.len() {
                if search.gain(matching, a, b) > 0.0 {
                    matching.swap(a, b); // rows a and b trade partners
                    swapped = true;
                }
            }
        }
        if !swapped {
            break;
        }
    }
}

/// A matched pair of groups: source row, target column.
type Pair = (usize, usize);

/// The swap search's memory: the union chains of every pair of groups
/// looked at, and the crossings between every two such pairs.
struct Search<'a, 'b> {
    swings: &'a Swings<'b>,
    tracks: HashMap<Pair, Vec<Track>>,
    crossings: HashMap<(Pair, Pair), usize>,
}

impl Search<'_, '_> {
    /// Crossings between the union chains of pairs `p` and `q`.
    fn between(&mut self, p: Pair, q: Pair) -> usize {
        let key = (p.min(q), p.max(q));
        if let Some(&n) = self.crossings.get(&key) {
            return n;
        }
        for x in [p, q] {
            if !self.tracks.contains_key(&x) {
                let tracks = (self.swings.swing)(x.0, x.1);
                self.tracks.insert(x, tracks);
            }
        }
        let (a, b) = (&self.tracks[&p], &self.tracks[&q]);
        let n = a
            .iter()
            .map(|x| b.iter().filter(|y| x.touches(y)).count())
            .sum();
        self.crossings.insert(key, n);
        n
    }

    /// Crossings of pairs `p` and `q` with each other and with the matched
    /// pairs of rows other than `skip`.
    fn total(
        &mut self,
        matching: &[Option<usize>],
        (p, q): (Pair, Pair),
        skip: [usize; 2],
    ) -> usize {
        let mut n = self.between(p, q);
        for (k, m) in matching.iter().enumerate() {
            if let Some(l) = m
                && !skip.contains(&k)
            {
                n += self.between(p, (k, *l)) + self.between(q, (k, *l));
            }
        }
        n
    }

    /// What swapping the partners of rows `a` and `b` saves: crossings
    /// removed times the weight, less the cost added (0 when they do not
    /// cross, a swap is forbidden, or it adds more than one crossing's
    /// worth: trading a limb for a far partner makes it jump).
    fn gain(&mut self, matching: &[Option<usize>], a: usize, b: usize) -> f64 {
        let (Some(ja), Some(jb)) = (matching[a], matching[b]) else {
            return 0.0;
        };
        let s = self.swings;
        let (ca, cb) = (s.cost(a, jb), s.cost(b, ja));
        if ca >= FORBIDDEN || cb >= FORBIDDEN || self.between((a, ja), (b, jb)) == 0 {
            return 0.0;
        }
        let before = self.total(matching, ((a, ja), (b, jb)), [a, b]);
        let after = self.total(matching, ((a, jb), (b, ja)), [a, b]);
        let added = ca + cb - s.cost(a, ja) - s.cost(b, jb);
        if added > s.weight {
            return 0.0; // a partner that far moves a limb farther than it saves
        }
        (before as f64 - after as f64) * s.weight - added
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A straight chain at `along` on its parent, `len` long along `dir`.
    fn pose(along: f32, dir: Vec3, len: f32) -> Pose {
        Pose {
            along,
            parts: [dir.normalize() * len / PARTS as f32; PARTS],
            radius: 0.005,
        }
    }

    fn touch(a: (Pose, Pose), b: (Pose, Pose)) -> bool {
        Track::new(&a.0, &a.1).touches(&Track::new(&b.0, &b.1))
    }

    #[test]
    fn a_limb_swinging_through_a_sibling_touches_it() {
        let still = pose(0.5, Vec3::X, 0.3);
        // Just above it, sloping down: from one side of it, through it (by
        // way of +x), to the other side.
        let from = pose(0.52, Vec3::new(0.2, -0.1, 1.0), 0.3);
        let to = pose(0.52, Vec3::new(0.2, -0.1, -1.0), 0.3);
        assert!(touch((still, still), (from, to)));
        assert!(touch((from, to), (still, still)), "not symmetric");
        assert!(!touch((still, still), (from, from)), "a still pair touched");
    }

    #[test]
    fn contacts_at_either_end_are_not_crossings() {
        let a = pose(0.5, Vec3::X, 0.3);
        let b = pose(0.5, Vec3::Z, 0.3);
        // Same junction: touching at both ends, whatever happens between.
        assert!(!touch((a, b), (b, a)));
        // Far apart on the parent: never touching.
        let high = pose(0.9, Vec3::X, 0.3);
        assert!(!touch((a, b), (high, high)));
    }
}
