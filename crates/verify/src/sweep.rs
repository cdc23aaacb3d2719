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
use treemorph_tree::grid::{Occupancy, TriangleGrid};

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
    /// Scratch: the questions whose boxes a piece's bounds meet.
    near_piece: Vec<u32>,
}

/// A piece near more questions than this has each triangle look its
/// questions up in the grid, rather than test each of them: a trunk's
/// bounds meet most of a crown's questions.
const PIECE_QUESTIONS: usize = 16;

impl Sweep {
    /// Answers `leaves` and `vertices` (of `pieces` open pieces) over
    /// `triangles`, in a frame within `frame`'s bounds.
    ///
    /// Pieces are read in order, and each piece's triangles in order,
    /// so every question meets its candidate triangles in the same order
    /// however they are found: a piece's triangles are tested against the
    /// few questions its bounds meet (found once per piece), and only a
    /// piece near many looks each triangle's questions up in the grid.
    /// Looking them up for every triangle was most of a sweep's cost.
    pub fn run(
        &mut self,
        frame: (Vec3, Vec3),
        triangles: Triangles<'_>,
        (leaves, vertices, pieces): (&[LeafQuestion<'_>], &[VertexQuestion], usize),
        reach: f32,
    ) -> Found {
        let mut answers = Answers {
            triangles,
            leaves,
            vertices,
            reach2: reach * reach,
            best: std::mem::take(&mut self.best),
            found: Found {
                leaves: vec![None; leaves.len()],
                pieces: vec![None; pieces],
            },
            left: 0,
        };
        if leaves.is_empty() && vertices.is_empty() {
            return answers.found;
        }
        self.ask(frame, leaves, vertices, reach);
        answers.best.clear();
        answers.best.resize(leaves.len(), f32::INFINITY);
        let mut open_pieces = vertices.iter().map(|q| q.rank).collect::<Vec<_>>();
        open_pieces.dedup();
        answers.left = open_pieces.len();
        for piece in 0..triangles.piece_boxes.len() {
            if leaves.is_empty() && answers.left == 0 {
                break;
            }
            self.sweep_piece(piece, &mut answers);
        }
        self.best = std::mem::take(&mut answers.best);
        answers.found
    }

    /// Offers the triangles of `piece` to the questions their bounds meet.
    fn sweep_piece(&mut self, piece: usize, answers: &mut Answers<'_, '_>) {
        let triangles = answers.triangles;
        let (lo, hi) = triangles.piece_boxes[piece];
        if lo.x > hi.x || !self.occupied.any(lo, hi) {
            return;
        }
        let list = triangles.starts[piece] as usize..triangles.starts[piece + 1] as usize;
        let tris = &triangles.by_piece[list];
        self.near_piece.clear();
        let boxes = &self.boxes;
        let near_piece = &mut self.near_piece;
        self.grid.any_near(lo, hi, |q| {
            if meet(boxes[q as usize], (lo, hi)) {
                near_piece.push(q);
            }
            near_piece.len() > PIECE_QUESTIONS
        });
        if self.near_piece.len() > PIECE_QUESTIONS {
            self.sweep_by_grid(tris, answers);
            return;
        }
        for &t in tris {
            let b = triangles.boxes[t as usize];
            for &q in &self.near_piece {
                if meet(self.boxes[q as usize], b) {
                    answers.visit(q, t);
                }
            }
        }
    }

    /// Offers each of `tris` to the questions the grid lists near it.
    fn sweep_by_grid(&mut self, tris: &[u32], answers: &mut Answers<'_, '_>) {
        for &t in tris {
            let (lo, hi) = answers.triangles.boxes[t as usize];
            if !self.occupied.any(lo, hi) {
                continue;
            }
            self.grid.any_near(lo, hi, |q| {
                answers.visit(q, t);
                false
            });
        }
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

/// The answers of a sweep as they are found.
struct Answers<'q, 'p> {
    triangles: Triangles<'q>,
    leaves: &'q [LeafQuestion<'p>],
    vertices: &'q [VertexQuestion],
    reach2: f32,
    best: Vec<f32>,
    found: Found,
    /// Open pieces not answered yet.
    left: usize,
}

impl Answers<'_, '_> {
    /// Offers triangle `t` to question `q` (leaf questions first, then
    /// vertex questions, as [`Sweep::ask`] numbers them).
    fn visit(&mut self, q: u32, t: u32) {
        let (q, n) = (q as usize, self.leaves.len());
        if q < n {
            let surface = (self.triangles.tris, self.triangles.boxes);
            let (best, answer) = (&mut self.best[q], &mut self.found.leaves[q]);
            nearest(surface, &self.leaves[q], t, best, answer);
        } else {
            let v = self.vertices[q - n];
            let answer = &mut self.found.pieces[v.rank as usize];
            if answer.is_none() && near(self.triangles, v, t, self.reach2) {
                *answer = Some((v.vertex, t));
                self.left -= 1;
            }
        }
    }
}

/// Whether two boxes meet (closed bounds).
fn meet(a: (Vec3, Vec3), b: (Vec3, Vec3)) -> bool {
    !(b.0.cmpgt(a.1).any() || b.1.cmplt(a.0).any())
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

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Pieces of small triangles in a 10 m cube (one piece may spread
    /// over all of it, as a trunk's bounds meet most questions).
    #[derive(Debug)]
    struct Scene {
        tris: Vec<[Vec3; 3]>,
        boxes: Vec<(Vec3, Vec3)>,
        piece: Vec<u32>,
        starts: Vec<u32>,
        by_piece: Vec<u32>,
        piece_boxes: Vec<(Vec3, Vec3)>,
    }

    impl Scene {
        fn triangles(&self) -> Triangles<'_> {
            Triangles {
                tris: &self.tris,
                boxes: &self.boxes,
                piece: &self.piece,
                starts: &self.starts,
                by_piece: &self.by_piece,
                piece_boxes: &self.piece_boxes,
            }
        }
    }

    fn point(scale: f32) -> impl Strategy<Value = Vec3> {
        (0.0..scale, 0.0..scale, 0.0..scale).prop_map(|(x, y, z)| Vec3::new(x, y, z))
    }

    fn scene() -> impl Strategy<Value = Scene> {
        let triangle =
            (point(10.0), point(0.6), point(0.6)).prop_map(|(a, d, e)| [a, a + d, a + e]);
        prop::collection::vec(prop::collection::vec(triangle, 0..30), 1..24).prop_map(|pieces| {
            let mut s = Scene {
                tris: Vec::new(),
                boxes: Vec::new(),
                piece: Vec::new(),
                starts: vec![0],
                by_piece: Vec::new(),
                piece_boxes: Vec::new(),
            };
            for (p, tris) in pieces.into_iter().enumerate() {
                let mut bounds = (Vec3::INFINITY, Vec3::NEG_INFINITY);
                for [a, b, c] in tris {
                    let bb = (a.min(b).min(c), a.max(b).max(c));
                    bounds = (bounds.0.min(bb.0), bounds.1.max(bb.1));
                    s.by_piece.push(s.tris.len() as u32);
                    s.tris.push([a, b, c]);
                    s.boxes.push(bb);
                    s.piece.push(p as u32);
                }
                s.piece_boxes.push(bounds);
                s.starts.push(s.tris.len() as u32);
            }
            s
        })
    }

    /// Every question offered every triangle, pieces and triangles in
    /// order: what the sweep must answer.
    fn exhaustive(
        scene: &Scene,
        leaves: &[LeafQuestion<'_>],
        vertices: &[VertexQuestion],
        pieces: usize,
        reach: f32,
    ) -> Found {
        let mut answers = Answers {
            triangles: scene.triangles(),
            leaves,
            vertices,
            reach2: reach * reach,
            best: vec![f32::INFINITY; leaves.len()],
            found: Found {
                leaves: vec![None; leaves.len()],
                pieces: vec![None; pieces],
            },
            left: pieces,
        };
        for &t in &scene.by_piece {
            for q in 0..(leaves.len() + vertices.len()) as u32 {
                answers.visit(q, t);
            }
        }
        answers.found
    }

    proptest! {
        /// The sweep answers as an exhaustive search does, whether a
        /// piece is near a few questions or many (up to 80 leaves).
        #[test]
        fn a_sweep_answers_as_every_triangle_would(
            scene in scene(),
            leaf_points in prop::collection::vec((prop::collection::vec(point(10.0), 1..4), 0.0f32..0.8), 0..80),
            vertex_points in prop::collection::vec((point(10.0), 0u32..24, 1usize..3), 0..12),
            reach in 0.0f32..0.5,
        ) {
            let leaves: Vec<LeafQuestion<'_>> = leaf_points
                .iter()
                .map(|(points, allowed)| LeafQuestion {
                    points,
                    bounds: points.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |b, p| (b.0.min(*p), b.1.max(*p))),
                    allowed: *allowed,
                })
                .collect();
            let mut vertices = Vec::new();
            for (rank, &(at, piece, count)) in vertex_points.iter().enumerate() {
                for k in 0..count {
                    let at = at + Vec3::splat(0.1 * k as f32);
                    vertices.push(VertexQuestion { rank: rank as u32, piece, vertex: k as u32, at });
                }
            }
            let frame = (Vec3::ZERO, Vec3::splat(11.0));
            let asked = (&leaves[..], &vertices[..], vertex_points.len());
            let found = Sweep::default().run(frame, scene.triangles(), asked, reach);
            let want = exhaustive(&scene, &leaves, &vertices, vertex_points.len(), reach);
            prop_assert_eq!(found.leaves, want.leaves);
            // A piece's answer is the first triangle near any of its
            // vertices; which of them a triangle names first follows the
            // grid's order, so any of its vertices within reach will do.
            let triangle = |a: &Option<(u32, u32)>| a.map(|(_, t)| t);
            prop_assert_eq!(
                found.pieces.iter().map(triangle).collect::<Vec<_>>(),
                want.pieces.iter().map(triangle).collect::<Vec<_>>()
            );
            for (rank, answer) in found.pieces.iter().enumerate() {
                if let Some((vertex, t)) = *answer {
                    let v = vertices.iter().find(|v| v.rank == rank as u32 && v.vertex == vertex);
                    prop_assert!(v.is_some_and(|&v| near(scene.triangles(), v, t, reach * reach)));
                }
            }
        }
    }
}
