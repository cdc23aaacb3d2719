//! One pass over a frame's visible triangles that settles what last
//! frame's proofs left open ([`Sweep`]).
//!
//! Most leaves and pieces of a frame are settled by what proved them
//! attached on the frame before (see [`crate::Plausibility`]); the few
//! hundred left open — leaves just unfolded, pieces just grown, proofs a
//! morph moved apart — would each need a range query, and a table of all
//! the frame's triangles to ask it of costs more than all of them. So the
//! questions go into a small grid of their own (each question's box: a
//! leaf's bounds grown by its allowed distance, a piece vertex's point
//! grown by the reach), a coarse bitmap marks where they are, and the
//! triangles are read once: a piece's bounds, then a triangle's, that
//! meet no marked cell are passed over at once, and every other triangle
//! visits the questions whose boxes its own meets. Every triangle within
//! reach of a question's geometry has bounds within reach of it, so the
//! answers are those of an exhaustive search.
//!
//! - A **leaf** question keeps the *nearest* triangle within its allowed
//!   distance of a vertex of the leaf: the proof then names the leaf's own
//!   twig, which it keeps while it moves, rather than the first neighbour
//!   within reach, which drifts away.
//! - A **vertex** question (one of a piece's first vertices, which for a
//!   tube are its base ring) asks for any triangle of another piece within
//!   the reach: a sufficient test that most child tubes pass inside their
//!   parent; a piece none of whose vertices passes goes to the exhaustive
//!   triangle–triangle search.

use glam::Vec3;

use crate::geometry::point_triangle_sq;
use crate::grid::{Occupancy, TriangleGrid};

/// A frame's visible triangles, as the check lists them.
#[derive(Clone, Copy)]
pub(crate) struct Triangles<'a> {
    pub tris: &'a [[Vec3; 3]],
    pub boxes: &'a [(Vec3, Vec3)],
    pub piece: &'a [u32],
    /// Visible triangles by piece: `by_piece[starts[p]..starts[p + 1]]`.
    pub starts: &'a [u32],
    pub by_piece: &'a [u32],
    /// Each piece's bounds (empty boxes for pieces with nothing visible).
    pub piece_boxes: &'a [(Vec3, Vec3)],
}

/// An open leaf: its vertices and bounds, and its allowed distance.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LeafQuestion<'a> {
    pub points: &'a [Vec3],
    pub bounds: (Vec3, Vec3),
    pub allowed: f32,
}

/// An open piece's vertex: the piece (by its rank among the open pieces,
/// and its index) and the vertex (its index and position).
#[derive(Clone, Copy, Debug)]
pub(crate) struct VertexQuestion {
    pub rank: u32,
    pub piece: u32,
    pub vertex: u32,
    pub at: Vec3,
}

/// What a sweep found: per leaf question, the rank of its nearest vertex
/// and the visible triangle; per open piece, a vertex and a visible
/// triangle of another piece within reach.
#[derive(Debug, Default)]
pub(crate) struct Found {
    pub leaves: Vec<Option<(u32, u32)>>,
    pub pieces: Vec<Option<(u32, u32)>>,
}

/// The reusable buffers of a sweep.
#[derive(Clone, Debug, Default)]
pub(crate) struct Sweep {
    boxes: Vec<(Vec3, Vec3)>,
    grid: TriangleGrid,
    occupied: Occupancy,
    /// Squared distance of each leaf question's best triangle so far.
    best: Vec<f32>,
}

impl Sweep {
    /// Answers `leaves` and `vertices` (of `pieces` open pieces) over
    /// `triangles`, in a frame within `frame`'s bounds.
    pub fn run(
        &mut self,
        frame: (Vec3, Vec3),
        triangles: Triangles<'_>,
        (leaves, vertices, pieces): (&[LeafQuestion<'_>], &[VertexQuestion], usize),
        reach: f32,
    ) -> Found {
        let mut found = Found {
            leaves: vec![None; leaves.len()],
            pieces: vec![None; pieces],
        };
        if leaves.is_empty() && vertices.is_empty() {
            return found;
        }
        self.ask(frame, leaves, vertices, reach);
        self.best.clear();
        self.best.resize(leaves.len(), f32::INFINITY);
        let mut open_pieces = vertices.iter().map(|q| q.rank).collect::<Vec<_>>();
        open_pieces.dedup();
        let mut left = open_pieces.len();
        let reach2 = reach * reach;
        for piece in 0..triangles.piece_boxes.len() {
            if leaves.is_empty() && left == 0 {
                break;
            }
            let (lo, hi) = triangles.piece_boxes[piece];
            if lo.x > hi.x || !self.occupied.any(lo, hi) {
                continue;
            }
            let list = triangles.starts[piece] as usize..triangles.starts[piece + 1] as usize;
            for &t in &triangles.by_piece[list] {
                let (lo, hi) = triangles.boxes[t as usize];
                if !self.occupied.any(lo, hi) {
                    continue;
                }
                let (best, n) = (&mut self.best, leaves.len());
                self.grid.any_near(lo, hi, |q| {
                    let q = q as usize;
                    if q < n {
                        let surface = (triangles.tris, triangles.boxes);
                        nearest(surface, &leaves[q], t, &mut best[q], &mut found.leaves[q]);
                    } else {
                        let v = vertices[q - n];
                        let answer = &mut found.pieces[v.rank as usize];
                        if answer.is_none() && near(triangles, v, t, reach2) {
                            *answer = Some((v.vertex, t));
                            left -= 1;
                        }
                    }
                    false
                });
            }
        }
        found
    }

    /// Puts the questions' boxes (leaves first) into the grid and the map.
    fn ask(
        &mut self,
        frame: (Vec3, Vec3),
        leaves: &[LeafQuestion<'_>],
        vertices: &[VertexQuestion],
        reach: f32,
    ) {
        self.boxes.clear();
        self.boxes.extend(leaves.iter().map(|q| {
            let a = Vec3::splat(q.allowed);
            (q.bounds.0 - a, q.bounds.1 + a)
        }));
        let r = Vec3::splat(reach);
        self.boxes
            .extend(vertices.iter().map(|q| (q.at - r, q.at + r)));
        self.grid.build(&self.boxes, typical_side(&self.boxes));
        self.occupied.reset(frame.0, frame.1);
        for &(lo, hi) in &self.boxes {
            self.occupied.mark(lo, hi);
        }
    }
}

/// Keeps triangle `t` (of `tris`, with bounds `boxes`) as the leaf's
/// answer if a vertex of the leaf lies within its allowed distance of it
/// and nearer than the best so far.
pub(crate) fn nearest(
    (tris, boxes): (&[[Vec3; 3]], &[(Vec3, Vec3)]),
    leaf: &LeafQuestion<'_>,
    t: u32,
    best: &mut f32,
    answer: &mut Option<(u32, u32)>,
) {
    let within2 = (leaf.allowed * leaf.allowed).min(*best);
    let b = boxes[t as usize];
    if box_gap_sq(leaf.bounds, b) > within2 {
        return;
    }
    let tri = tris[t as usize];
    for (k, &p) in leaf.points.iter().enumerate() {
        if box_gap_sq((p, p), b) > within2 {
            continue;
        }
        let d2 = point_triangle_sq(p, tri);
        if d2 <= within2 && (answer.is_none() || d2 < *best) {
            *best = d2;
            *answer = Some((k as u32, t));
        }
    }
}

/// Whether the vertex question's point lies within the reach of triangle
/// `t` of another piece.
fn near(triangles: Triangles<'_>, v: VertexQuestion, t: u32, reach2: f32) -> bool {
    triangles.piece[t as usize] != v.piece
        && box_gap_sq((v.at, v.at), triangles.boxes[t as usize]) <= reach2
        && point_triangle_sq(v.at, triangles.tris[t as usize]) <= reach2
}

/// A grid cell for `boxes`: the median of their largest sides, so most
/// cover a cell or two (positive, whatever the boxes).
fn typical_side(boxes: &[(Vec3, Vec3)]) -> f32 {
    let mut sides: Vec<f32> = boxes
        .iter()
        .map(|(lo, hi)| (*hi - *lo).max_element())
        .collect();
    let mid = sides.len() / 2;
    let side = if sides.is_empty() {
        0.0
    } else {
        *sides.select_nth_unstable_by(mid, f32::total_cmp).1
    };
    if side.is_finite() && side > 0.0 {
        side
    } else {
        1.0
    }
}

/// Squared gap between two boxes (0 when they meet).
pub(crate) fn box_gap_sq((alo, ahi): (Vec3, Vec3), (blo, bhi): (Vec3, Vec3)) -> f32 {
    let d = (blo - ahi).max(alo - bhi).max(Vec3::ZERO);
    d.length_squared()
}
