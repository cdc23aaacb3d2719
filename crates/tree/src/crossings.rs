//! Crossing branches: pairs of branch pieces whose tubes pass through each
//! other in a frame but at neither end of its sequence.
//!
//! A **piece** is a strand of the frame topology: one tube of the branch
//! mesh, as the mesher sweeps it. Its tube lies within the union of its
//! segments' **capsules** — segment `(a, b)` with the larger of its two
//! radii — since the tube's rings are polygons inscribed in circles of
//! those radii. Two pieces **touch** in a frame when capsules of theirs
//! overlap (segment distance below the sum of the radii); segments of no
//! radius are not drawn and touch nothing. A child's tube starts inside
//! its parent's, so neighbours touch at both ends of a sequence; a pair
//! that touches in a frame and at neither end (t = 0 and t = 1, frames of
//! the same topology) is a **crossing**: limbs passing through each other
//! mid-animation.
//!
//! Capsules rather than the written triangles: the exact triangle test of
//! the plausibility check costs tens of milliseconds per frame on a
//! 5,000-branch tree, the capsules a few, and they bound the tubes (a
//! capsule pair may touch where the polygonal tubes just miss, by at most
//! the polygon's sagitta). The broad phase is the spatial hash the
//! plausibility check uses for triangles ([`TriangleGrid`]), over the
//! capsules' bounds: a collision crate would bring a physics engine.
//!
//! Between two frames, [`CrossingMeter::passing_pairs`] finds the pairs
//! that touch at any instant of a straight motion from one to the other
//! (the `swept` module): what a finer sampling of the motion would show.

use crate::{Frame, Strands};
use glam::Vec3;

use crate::geom::segment_segment_sq;
use crate::grid::TriangleGrid;

mod swept;

/// Pairs of pieces touching per frame of a sequence, and the crossings
/// they make (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct CrossingMeter {
    /// Per frame measured: the touching piece pairs, sorted.
    frames: Vec<Vec<(u32, u32)>>,
    capsules: Vec<Capsule>,
    /// The capsules' bounds and a spatial hash of them, rebuilt per frame
    /// in buffers kept between frames.
    boxes: Vec<(Vec3, Vec3)>,
    grid: TriangleGrid,
    /// The segments swept between two frames ([`CrossingMeter::passing_pairs`]).
    swept: Vec<swept::Swept>,
}

/// One drawn segment of a piece, with the larger of its radii.
#[derive(Clone, Copy, Debug)]
struct Capsule {
    a: Vec3,
    b: Vec3,
    r: f32,
    piece: u32,
    nodes: (u32, u32),
}

impl CrossingMeter {
    /// A meter with no frame measured.
    pub fn new() -> CrossingMeter {
        CrossingMeter::default()
    }

    /// Measures the next frame of the sequence (`strands` its topology's).
    pub fn push(&mut self, strands: &Strands, frame: &Frame) {
        let pairs = self.touching_pairs(strands, frame);
        self.push_touching(pairs);
    }

    /// Measures the next frame of the sequence from its touching pairs,
    /// as [`CrossingMeter::touching_pairs`] gave them (on this meter or
    /// another): frames measured in parallel, then joined in order.
    pub fn push_touching(&mut self, pairs: Vec<(u32, u32)>) {
        self.frames.push(pairs);
    }

    /// The sorted piece pairs touching in `frame`, without measuring it as
    /// part of the sequence: for callers that measure frames in parallel,
    /// one meter (its buffers) per thread.
    pub fn touching_pairs(&mut self, strands: &Strands, frame: &Frame) -> Vec<(u32, u32)> {
        self.collect(strands, frame);
        self.touching()
    }

    /// Per frame measured: how many piece pairs touch in it and in
    /// neither the first nor the last frame measured.
    pub fn crossings(&self) -> Vec<u32> {
        (0..self.frames.len())
            .map(|i| self.crossing_pairs(i).count() as u32)
            .collect()
    }

    /// The piece pairs (strand indices, lower first) of frame `i` touching
    /// in it and in neither the first nor the last frame measured.
    pub fn crossing_pairs(&self, i: usize) -> impl Iterator<Item = (u32, u32)> + '_ {
        let none: &[(u32, u32)] = &[];
        let first = self.frames.first().map_or(none, Vec::as_slice);
        let last = self.frames.last().map_or(none, Vec::as_slice);
        // All three lists are sorted: one merge, with a cursor in each end
        // frame's list, rather than two binary searches per pair, which
        // took 8-12 ms at the end of the default 60-frame job (its
        // metrics.json is built after the last frame, on one core).
        let (mut f, mut l) = (0, 0);
        self.frames
            .get(i)
            .map_or(none, Vec::as_slice)
            .iter()
            .copied()
            .filter(move |p| {
                while first.get(f).is_some_and(|q| q < p) {
                    f += 1;
                }
                while last.get(l).is_some_and(|q| q < p) {
                    l += 1;
                }
                first.get(f) != Some(p) && last.get(l) != Some(p)
            })
    }

    /// The crossings ([`CrossingMeter::crossing_pairs`]) between two
    /// pieces of one parent piece, `parents` giving each piece's parent
    /// piece (as [`crate::FrameTopology::strand_parents`] does):
    /// limbs of one branch passing through each other, which the morph's
    /// matching is meant to avoid, apart from limbs of one subtree
    /// swinging through another's.
    pub fn sibling_crossings(&self, parents: &[Option<u32>]) -> SiblingCrossings {
        let parent = |piece: u32| parents.get(piece as usize).copied().flatten();
        let per_frame = (0..self.frames.len())
            .map(|i| {
                self.crossing_pairs(i)
                    .filter(|&(a, b)| parent(a).is_some() && parent(a) == parent(b))
                    .count() as u32
            })
            .collect();
        SiblingCrossings {
            per_frame,
            pairs: sibling_pairs(parents),
        }
    }

    /// The frame's drawn segments as capsules.
    fn collect(&mut self, strands: &Strands, frame: &Frame) {
        self.capsules.clear();
        let (pos, radii) = (&frame.positions, &frame.radii);
        for (piece, nodes) in strands.iter().enumerate() {
            for w in nodes.windows(2) {
                let (i, j) = (w[0] as usize, w[1] as usize);
                let r = radii[i].max(radii[j]);
                if r > 0.0 && r.is_finite() && pos[i].is_finite() && pos[j].is_finite() {
                    self.capsules.push(Capsule {
                        a: pos[i],
                        b: pos[j],
                        r,
                        piece: piece as u32,
                        nodes: (w[0], w[1]),
                    });
                }
            }
        }
    }

    /// The sorted pairs of pieces with overlapping capsules: every pair of
    /// capsules whose bounds meet ([`TriangleGrid::for_each_overlap`]).
    fn touching(&mut self) -> Vec<(u32, u32)> {
        self.boxes.clear();
        self.boxes.extend(self.capsules.iter().map(|c| {
            let r = Vec3::splat(c.r);
            (c.a.min(c.b) - r, c.a.max(c.b) + r)
        }));
        self.grid.build(&self.boxes, cell_size(&self.capsules));
        let mut pairs = Vec::new();
        let capsules = &self.capsules;
        self.grid.for_each_overlap(&self.boxes, |i, j| {
            if let Some(pair) = overlap(&capsules[i as usize], &capsules[j as usize]) {
                pairs.push(pair);
            }
        });
        pairs.sort_unstable();
        pairs.dedup();
        pairs
    }
}

/// Crossings between limbs of one parent ([`CrossingMeter::sibling_crossings`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SiblingCrossings {
    /// Per frame measured: how many pairs of limbs on one parent cross.
    pub per_frame: Vec<u32>,
    /// How many pairs of pieces share a parent piece: what the counts are
    /// a share of. Pieces drawn at one end of the sequence only (growing
    /// or wilting) count too.
    pub pairs: u64,
}

impl SiblingCrossings {
    /// The most in one frame.
    pub fn most(&self) -> u32 {
        self.per_frame.iter().copied().max().unwrap_or(0)
    }

    /// [`SiblingCrossings::most`] as a share of
    /// [`SiblingCrossings::pairs`] (0 without pairs).
    pub fn share(&self) -> f64 {
        if self.pairs == 0 {
            0.0
        } else {
            f64::from(self.most()) / self.pairs as f64
        }
    }
}

/// How many pairs of pieces share a parent piece.
fn sibling_pairs(parents: &[Option<u32>]) -> u64 {
    let mut children = vec![0u64; parents.len()];
    for p in parents.iter().flatten() {
        if let Some(n) = children.get_mut(*p as usize) {
            *n += 1;
        }
    }
    children.iter().map(|n| n * n.saturating_sub(1) / 2).sum()
}

/// The piece pair of two overlapping capsules of different pieces that
/// share no node (a child's first segment starts on its parent's node).
fn overlap(p: &Capsule, q: &Capsule) -> Option<(u32, u32)> {
    if p.piece == q.piece {
        return None;
    }
    let shared = [p.nodes.0, p.nodes.1]
        .iter()
        .any(|n| *n == q.nodes.0 || *n == q.nodes.1);
    let reach = p.r + q.r;
    (!shared && segment_segment_sq(p.a, p.b, q.a, q.b) < reach * reach)
        .then(|| (p.piece.min(q.piece), p.piece.max(q.piece)))
}

/// A grid cell twice as large as a typical capsule (the mean segment
/// length plus diameter), so most capsules cover one to eight cells: the
/// pairing costs a bucket's entries squared, the build a capsule's cells.
/// On the default morph's frames, 2,439 strands, per frame: 1.62 ms at
/// twice the mean, 2.02 ms at the mean, 3.65 ms at half, 1.95 ms at three
/// times (`treemorph bench --filter "crossings per frame"`).
fn cell_size(capsules: &[Capsule]) -> f32 {
    cell_size_of(capsules.iter().map(|c| c.a.distance(c.b) + 2.0 * c.r))
}

/// Twice the mean of `extents` (1 for none or a degenerate mean).
fn cell_size_of(extents: impl ExactSizeIterator<Item = f32>) -> f32 {
    let n = extents.len().max(1) as f32;
    let mean = extents.sum::<f32>() / n;
    if mean > 0.0 && mean.is_finite() {
        2.0 * mean
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Sorted, deduplicated piece pairs among a few pieces, so frames
    /// share many.
    fn pairs() -> impl Strategy<Value = Vec<(u32, u32)>> {
        prop::collection::vec((0u32..12, 0u32..12), 0..60).prop_map(|mut v| {
            v.retain(|(a, b)| a < b);
            v.sort_unstable();
            v.dedup();
            v
        })
    }

    proptest! {
        /// The merge keeps exactly the pairs of a frame found in neither
        /// end frame's list.
        #[test]
        fn crossing_pairs_are_those_in_neither_end_frame(frames in prop::collection::vec(pairs(), 0..6)) {
            let meter = CrossingMeter { frames: frames.clone(), ..CrossingMeter::default() };
            for (i, frame) in frames.iter().enumerate() {
                let (first, last) = (&frames[0], &frames[frames.len() - 1]);
                let expected: Vec<_> = frame
                    .iter()
                    .copied()
                    .filter(|p| !first.contains(p) && !last.contains(p))
                    .collect();
                prop_assert_eq!(meter.crossing_pairs(i).collect::<Vec<_>>(), expected);
            }
            prop_assert_eq!(meter.crossing_pairs(frames.len()).count(), 0);
        }
    }

    /// A frame of `positions`, every node of radius `radius` (also for
    /// the `swept` tests).
    pub(super) fn frame(positions: Vec<Vec3>, radius: f32) -> Frame {
        Frame {
            radii: vec![radius; positions.len()],
            positions,
            ..Frame::default()
        }
    }

    #[test]
    fn sibling_crossings_count_pieces_of_one_parent() {
        // A trunk (piece 0) with a limb at each of its two upper nodes;
        // the upper limb swings down through the lower one and back.
        let strands = Strands::from_polylines([vec![0u32, 1, 2], vec![1, 3], vec![2, 4]]);
        let at = |z: f32| {
            frame(
                vec![
                    Vec3::ZERO,
                    Vec3::new(0.0, 1.0, 0.0),
                    Vec3::new(0.0, 2.0, 0.0),
                    Vec3::new(1.0, 2.0, 0.0),
                    Vec3::new(1.0, 1.0, z),
                ],
                0.02,
            )
        };
        let mut meter = CrossingMeter::new();
        for z in [1.0, 0.0, 1.0] {
            meter.push(&strands, &at(z));
        }
        assert_eq!(meter.crossings(), [0, 1, 0]);
        let siblings = [None, Some(0), Some(0)];
        assert_eq!(meter.sibling_crossings(&siblings).per_frame, [0, 1, 0]);
        assert_eq!(
            meter.sibling_crossings(&[None, Some(0), None]).per_frame,
            [0, 0, 0]
        );
        assert_eq!(sibling_pairs(&siblings), 1);
        assert_eq!(
            sibling_pairs(&[None, Some(0), Some(0), Some(0), Some(1)]),
            3
        );
    }

    #[test]
    fn a_pair_touching_only_in_between_is_a_crossing() {
        // Two sticks from the ground: apart, crossed, apart again.
        let strands = Strands::from_polylines([vec![0u32, 1], vec![2, 3]]);
        let at = |x: f32| {
            frame(
                vec![
                    Vec3::ZERO,
                    Vec3::new(x, 1.0, 0.0),
                    Vec3::new(1.0, 0.0, 0.0),
                    Vec3::new(1.0 - x, 1.0, 0.0),
                ],
                0.01,
            )
        };
        let mut meter = CrossingMeter::new();
        for x in [0.0, 1.0, 0.0] {
            meter.push(&strands, &at(x));
        }
        assert_eq!(meter.crossings(), vec![0, 1, 0]);
    }

    #[test]
    fn neighbours_touching_at_the_ends_and_undrawn_pieces_do_not_cross() {
        // A child from its parent's node, and a twig of no radius
        // through the parent.
        let strands = Strands::from_polylines([vec![0u32, 1, 2], vec![1, 3], vec![4, 5]]);
        let mut f = frame(
            vec![
                Vec3::ZERO,
                Vec3::Y,
                Vec3::Y * 2.0,
                Vec3::new(1.0, 1.5, 0.0),
                Vec3::new(-1.0, 0.5, 0.0),
                Vec3::new(1.0, 0.5, 0.0),
            ],
            0.05,
        );
        f.radii[4] = 0.0;
        f.radii[5] = 0.0;
        let mut meter = CrossingMeter::new();
        for _ in 0..3 {
            meter.push(&strands, &f);
        }
        assert_eq!(meter.crossings(), vec![0, 0, 0]);
        assert!(meter.frames[1].is_empty(), "{:?}", meter.frames[1]);
    }
}
