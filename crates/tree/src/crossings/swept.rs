//! Touching between two frames: the piece pairs whose capsules meet at
//! some instant while every node moves on a straight line from its place
//! in one frame to its place in the next, and every radius changes
//! linearly.
//!
//! Frames show instants; a twig that passes through another between two
//! of them is seen by no frame of that sampling but by a finer one (a
//! job's frame count is the caller's). Between two close instants of a
//! smooth motion the straight line is the motion to within its curvature
//! (a node turning by θ about a joint leaves its chord by at most
//! `r (1 − cos θ/2)`), so this is what any finer sampling of the motion
//! shows, up to that bow.
//!
//! **How.** A capsule's gap to another, `g(s)` (segment distance less the
//! two radii), changes with `s` at most as fast as a point of one moves
//! against a point of the other, plus the radii's changes: a point's move
//! is a blend of its segment's two end moves, so the relative move is a
//! blend of the four differences of end moves and no longer than the
//! longest of them (`relative_rate`). On an interval
//! whose ends have gaps `g₀`, `g₁`, the gap is therefore at least
//! `(g₀ + g₁ − L·h) / 2`; where that is positive the pair cannot touch,
//! elsewhere the interval is halved, down to 1/2^[`DEPTH`] of the step.
//! Most pairs are cleared by the first bound. The broad phase is the
//! meter's spatial hash over each capsule's box swept over the step.
//!
//! Hand-written: continuous collision tests in crates come with a physics
//! engine (parry's time of impact is for rigid shapes, and a twig's two
//! ends move independently).

use glam::Vec3;

use super::{CrossingMeter, cell_size_of};
use crate::geom::segment_segment_sq;
use crate::{Frame, Strands};

/// Halvings of the step at most: a pass shorter than 1/256 of the step
/// between two frames, which is less than a job's frame count could
/// show, is not looked for.
const DEPTH: u32 = 8;

/// One segment of a piece over the step: its ends and largest radius in
/// the two frames.
#[derive(Clone, Copy, Debug)]
pub(super) struct Swept {
    from: [Vec3; 2],
    to: [Vec3; 2],
    r: [f32; 2],
    piece: u32,
    nodes: (u32, u32),
}

impl Swept {
    /// The segment and its radius at `s` of the step.
    fn at(&self, s: f32) -> (Vec3, Vec3, f32) {
        (
            self.from[0].lerp(self.to[0], s),
            self.from[1].lerp(self.to[1], s),
            self.r[0] + (self.r[1] - self.r[0]) * s,
        )
    }

    /// How far its ends and radius move over the step.
    fn moves(&self) -> ([Vec3; 2], f32) {
        (
            [self.to[0] - self.from[0], self.to[1] - self.from[1]],
            self.r[1] - self.r[0],
        )
    }

    /// Its box over the step.
    fn bounds(&self) -> (Vec3, Vec3) {
        let r = Vec3::splat(self.r[0].max(self.r[1]));
        let lo = self.from[0]
            .min(self.from[1])
            .min(self.to[0].min(self.to[1]));
        let hi = self.from[0]
            .max(self.from[1])
            .max(self.to[0].max(self.to[1]));
        (lo - r, hi + r)
    }
}

impl CrossingMeter {
    /// The sorted piece pairs whose capsules touch at some instant of the
    /// straight motion from `from` to `to`, two frames of `strands`'s
    /// topology (see the module docs), the frames' own touching pairs
    /// included, apart from those in `known` (sorted): pairs the caller
    /// already knows to touch (as a sequence's end frames' pairs, which
    /// make no crossing), whose near capsules would cost the most to
    /// follow through the step. A segment is swept when it is drawn (has a
    /// radius) in at least one of the two frames.
    pub fn passing_pairs(
        &mut self,
        strands: &Strands,
        [from, to]: [&Frame; 2],
        known: &[(u32, u32)],
    ) -> Vec<(u32, u32)> {
        self.collect_swept(strands, from, to);
        self.boxes.clear();
        self.boxes.extend(self.swept.iter().map(Swept::bounds));
        let cell = cell_size_of(self.boxes.iter().map(|(lo, hi)| (hi - lo).max_element()));
        self.grid.build(&self.boxes, cell);
        let mut pairs = Vec::new();
        let swept = &self.swept;
        self.grid.for_each_overlap(&self.boxes, |i, j| {
            if let Some(pair) = passing(&swept[i as usize], &swept[j as usize], known) {
                pairs.push(pair);
            }
        });
        pairs.sort_unstable();
        pairs.dedup();
        pairs
    }

    /// The segments drawn in either frame, swept over the step.
    fn collect_swept(&mut self, strands: &Strands, from: &Frame, to: &Frame) {
        self.swept.clear();
        let radius = |f: &Frame, i: usize, j: usize| {
            let r = f.radii[i].max(f.radii[j]);
            if r.is_finite() { r.max(0.0) } else { 0.0 }
        };
        let finite = |f: &Frame, i: usize| f.positions[i].is_finite();
        for (piece, nodes) in strands.iter().enumerate() {
            for w in nodes.windows(2) {
                let (i, j) = (w[0] as usize, w[1] as usize);
                let r = [radius(from, i, j), radius(to, i, j)];
                let placed = [i, j].iter().all(|&n| finite(from, n) && finite(to, n));
                if placed && (r[0] > 0.0 || r[1] > 0.0) {
                    self.swept.push(Swept {
                        from: [from.positions[i], from.positions[j]],
                        to: [to.positions[i], to.positions[j]],
                        r,
                        piece: piece as u32,
                        nodes: (w[0], w[1]),
                    });
                }
            }
        }
    }
}

/// The piece pair of two swept segments of different pieces that share no
/// node, is not `known`, and touches at some instant of the step.
fn passing(p: &Swept, q: &Swept, known: &[(u32, u32)]) -> Option<(u32, u32)> {
    if p.piece == q.piece {
        return None;
    }
    let pair = (p.piece.min(q.piece), p.piece.max(q.piece));
    let shared = [p.nodes.0, p.nodes.1]
        .iter()
        .any(|n| *n == q.nodes.0 || *n == q.nodes.1);
    if shared {
        return None;
    }
    let rate = relative_rate(p, q);
    // The cheap tests first: the list lookup misses the cache.
    let near = !apart(p, q, 0, rate) && !apart(p, q, 1, rate);
    (near && known.binary_search(&pair).is_err() && touch_in_step(p, q, rate)).then_some(pair)
}

/// Whether the two capsules meet at some instant of the step, their gap
/// changing at most by `rate` over it ([`relative_rate`]).
fn touch_in_step(p: &Swept, q: &Swept, rate: f32) -> bool {
    let gap = |s: f32| {
        let ((a, b, r), (c, d, t)) = (p.at(s), q.at(s));
        segment_segment_sq(a, b, c, d).sqrt() - (r + t)
    };
    let (g0, g1) = (gap(0.0), gap(1.0));
    let interval = Interval { gap: &gap, rate };
    g0 < 0.0 || g1 < 0.0 || interval.touches(0.0, 1.0, g0, g1, DEPTH)
}

/// Whether the capsules' bounding spheres in frame `end` (0 or 1) are
/// further apart than the gap can close over the whole step: a cheap
/// test that clears most pairs of neighbouring twigs that move alike.
fn apart(p: &Swept, q: &Swept, end: usize, rate: f32) -> bool {
    let [(a, b), (c, d)] = [p, q].map(|x| {
        if end == 0 {
            (x.from[0], x.from[1])
        } else {
            (x.to[0], x.to[1])
        }
    });
    let reach = 0.5 * (a.distance(b) + c.distance(d)) + p.r[end] + q.r[end];
    (0.5 * (a + b)).distance(0.5 * (c + d)) - reach > rate
}

/// How fast (per whole step) the gap between two swept capsules can
/// change: the fastest relative move of a point of one against a point of
/// the other, plus the radii's changes. A point's move is a blend of its
/// segment's two end moves, so their difference is a blend of the four
/// differences of end moves, and no longer than the longest of them. Two
/// twigs carried by one limb move alike, and their gap hardly changes.
fn relative_rate(p: &Swept, q: &Swept) -> f32 {
    let ((mp, rp), (mq, rq)) = (p.moves(), q.moves());
    let ends = mp
        .iter()
        .flat_map(|a| mq.iter().map(move |b| a.distance_squared(*b)))
        .fold(0.0, f32::max);
    ends.sqrt() + rp.abs() + rq.abs()
}

/// The gap of a capsule pair over a step and the bound on its change.
struct Interval<'a, G: Fn(f32) -> f32> {
    gap: &'a G,
    rate: f32,
}

impl<G: Fn(f32) -> f32> Interval<'_, G> {
    /// Whether the gap falls below 0 inside `[s0, s1]`, whose ends have
    /// gaps `g0`, `g1` (both positive).
    fn touches(&self, s0: f32, s1: f32, g0: f32, g1: f32, depth: u32) -> bool {
        if g0 + g1 - self.rate * (s1 - s0) > 0.0 || depth == 0 {
            return false;
        }
        let m = 0.5 * (s0 + s1);
        let gm = (self.gap)(m);
        gm < 0.0 || self.touches(s0, m, g0, gm, depth - 1) || self.touches(m, s1, gm, g1, depth - 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::crossings::tests::frame;

    /// A leaning stick whose tip swings from behind an upright one to in
    /// front of it: apart in both frames, through it in between.
    fn swinging(z: f32) -> Frame {
        frame(
            vec![
                Vec3::ZERO,
                Vec3::new(1.0, 1.0, z),
                Vec3::new(0.5, 0.5, 0.0),
                Vec3::new(0.5, 1.5, 0.0),
            ],
            0.01,
        )
    }

    #[test]
    fn a_pass_between_two_frames_is_found() {
        let strands = Strands::from_polylines([vec![0u32, 1], vec![2, 3]]);
        let mut meter = CrossingMeter::new();
        let (a, b) = (swinging(-1.0), swinging(1.0));
        assert!(meter.touching_pairs(&strands, &a).is_empty());
        assert!(meter.touching_pairs(&strands, &b).is_empty());
        assert_eq!(meter.passing_pairs(&strands, [&a, &b], &[]), [(0, 1)]);
    }

    #[test]
    fn pieces_that_stay_apart_do_not_pass() {
        // Both sticks lean right by the same amount: parallel throughout.
        let strands = Strands::from_polylines([vec![0u32, 1], vec![2, 3]]);
        let lean = |x: f32| {
            frame(
                vec![
                    Vec3::ZERO,
                    Vec3::new(x, 1.0, 0.0),
                    Vec3::new(1.0, 0.0, 0.0),
                    Vec3::new(1.0 + x, 1.0, 0.0),
                ],
                0.01,
            )
        };
        let mut meter = CrossingMeter::new();
        assert!(
            meter
                .passing_pairs(&strands, [&lean(-0.5), &lean(0.5)], &[])
                .is_empty()
        );
    }

    /// A near miss: the gap shrinks to a hair in mid-step and opens again;
    /// the bound must not call it a touch, and a slightly larger radius
    /// must.
    #[test]
    fn a_near_miss_is_told_from_a_graze() {
        let strands = Strands::from_polylines([vec![0u32, 1], vec![2, 3]]);
        // Piece 1 sweeps past piece 0's tip in z, 0.05 above it, at 5/8
        // of the step.
        let at = |z: f32, radius: f32| {
            frame(
                vec![
                    Vec3::ZERO,
                    Vec3::Y,
                    Vec3::new(-1.0, 1.05, z),
                    Vec3::new(1.0, 1.05, z),
                ],
                radius,
            )
        };
        let mut meter = CrossingMeter::new();
        let pass =
            |m: &mut CrossingMeter, r| m.passing_pairs(&strands, [&at(-1.0, r), &at(0.6, r)], &[]);
        assert!(pass(&mut meter, 0.02).is_empty());
        assert_eq!(pass(&mut meter, 0.03), [(0, 1)]);
    }

    /// Proptest's view of the bound: whatever the motion, a pair found
    /// touching at one of 65 even instants of the straight motion (ends
    /// included) is a passing pair.
    mod sampled {
        use super::*;
        use proptest::prelude::*;

        fn point() -> impl Strategy<Value = Vec3> {
            (-1.0f32..1.0, -1.0f32..1.0, -1.0f32..1.0).prop_map(|(x, y, z)| Vec3::new(x, y, z))
        }

        proptest! {
            #[test]
            fn every_sampled_touch_is_found(
                from in prop::collection::vec(point(), 4),
                to in prop::collection::vec(point(), 4),
                r in 0.01f32..0.2,
            ) {
                let strands = Strands::from_polylines([vec![0u32, 1], vec![2, 3]]);
                let (a, b) = (frame(from, r), frame(to, r));
                let mut meter = CrossingMeter::new();
                let passing = meter.passing_pairs(&strands, [&a, &b], &[]);
                let sampled = (0..=64).any(|k| {
                    let s = k as f32 / 64.0;
                    let mid = Frame {
                        positions: a.positions.iter().zip(&b.positions).map(|(p, q)| p.lerp(*q, s)).collect(),
                        radii: a.radii.clone(),
                        ..Frame::default()
                    };
                    !meter.touching_pairs(&strands, &mid).is_empty()
                });
                prop_assert!(!sampled || passing == [(0, 1)], "{passing:?}");
            }
        }
    }
}
