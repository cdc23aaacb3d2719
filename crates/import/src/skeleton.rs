//! Assembling skeleton pieces into one rooted tree.
//!
//! Every wood component gives a [`Piece`]: a small tree of axis points with
//! radii (a polyline for a tube, a branching tree for a contracted welded
//! mesh). Pieces are joined like this:
//!
//! 1. **Root.** Among the pieces' ends (points with at most one neighbour)
//!    that lie within 2 % of the tree's height above its lowest point, the
//!    thickest is the root: the lowest, thickest point. Drooping twigs can
//!    hang lower than the trunk's base (an ez-tree bush's do), so when an
//!    end in the lowest quarter of the tree is more than 4 × as thick, it
//!    is the root instead: a trunk's base, not a twig's tip. With no end
//!    near the ground (a contracted bark's base cap can be a junction),
//!    the lowest point is the root.
//! 2. **Candidates.** For each end of every other piece, the nearest points
//!    on up to four other pieces (a kd-tree over points sampled along every
//!    segment, then the exact point–segment distance).
//! 3. **Prim's growth.** Starting from the root's piece, the closest
//!    candidate whose target piece is already attached attaches its piece by
//!    that end (so an end that lies inside another tube — a branch base —
//!    wins over a free tip). Pieces left over (their candidates only name
//!    each other) are attached to the nearest attached piece directly.
//! 4. **Joins.** The attachment point snaps to the target segment's nearer
//!    node when it is within a tenth of the segment or a quarter of the
//!    local radius of it, else it splits the segment; the attaching end is
//!    merged into that point when they (nearly) coincide — a tube soup
//!    child's first ring centre lies on its parent's axis — and joined to it
//!    by a short branch otherwise.
//!
//! The result is always one connected tree. Gaps larger than the attaching
//! end's radius plus the target's radius are reported as warnings: the file
//! probably holds a separate object.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::num::NonZero;

use glam::Vec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use treemorph_tree::Node;
use treemorph_tree::geom::{self, NONE};

use crate::error::ImportError;

/// Ends this high above the lowest point (fraction of the height) are on
/// the ground.
const GROUND: f32 = 0.02;

/// Ends this high above the lowest point (fraction of the height) may be a
/// trunk's base above drooping twigs.
const LOW: f32 = 0.25;

/// An end on the ground thinner than this fraction of the thickest low end
/// is a twig's tip.
const THIN: f32 = 0.25;

/// A piece of skeleton: points with radii and the edges of a tree over
/// them.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Piece {
    pub points: Vec<Vec3>,
    pub radii: Vec<f32>,
    pub edges: Vec<(u32, u32)>,
}

/// Nodes closer than this (metres) are merged: the tree model refuses
/// shorter branches.
const MIN_BRANCH: f32 = 1e-5;

/// Closest point to `p` on segment `a`–`b`: parameter and distance (what
/// joins and leaf attachment compare).
pub(crate) fn closest_on_segment(p: Vec3, a: Vec3, b: Vec3) -> (f32, f32) {
    let (q, s) = geom::closest_on_segment(p, a, b);
    (s, p.distance(q))
}

/// Points sampled along segments, for nearest-segment queries.
pub(crate) struct SegmentIndex {
    tree: Option<ImmutableKdTree<f32, 3>>,
    /// Segment of each sample.
    segment: Vec<u32>,
}

impl SegmentIndex {
    /// Samples every segment `(a, b)` of `segments` at most `step` apart
    /// (both ends included).
    pub(crate) fn new(points: &[Vec3], segments: &[(u32, u32)], step: f32) -> SegmentIndex {
        let mut samples = Vec::with_capacity(segments.len() * 3);
        let mut segment = Vec::with_capacity(segments.len() * 3);
        for (i, &(a, b)) in segments.iter().enumerate() {
            let (pa, pb) = (points[a as usize], points[b as usize]);
            let k = ((pa.distance(pb) / step).ceil() as usize).clamp(1, 1000);
            for j in 0..=k {
                samples.push(pa.lerp(pb, j as f32 / k as f32).to_array());
                segment.push(i as u32);
            }
        }
        let tree = (!samples.is_empty()).then(|| ImmutableKdTree::new_from_slice(&samples));
        SegmentIndex { tree, segment }
    }

    /// Segments of the `k` samples nearest to `p` (with repeats).
    pub(crate) fn near(&self, p: Vec3, k: usize) -> Vec<u32> {
        let Some(tree) = &self.tree else {
            return Vec::new();
        };
        let k = NonZero::new(k.max(1)).unwrap_or(NonZero::<usize>::MIN);
        tree.nearest_n::<SquaredEuclidean>(&p.to_array(), k)
            .into_iter()
            .map(|n| self.segment[n.item as usize])
            .collect()
    }
}

#[derive(Clone, Copy, Debug)]
struct Candidate {
    dist: f32,
    piece: u32,
    /// Global id of the attaching end.
    end: u32,
    target_piece: u32,
    /// Global segment id and parameter on it.
    segment: u32,
    s: f32,
}

/// Joins `pieces` into one tree; returns nodes in canonical order (root
/// first, parents before children).
pub(crate) fn assemble(
    pieces: &[Piece],
    warnings: &mut Vec<String>,
) -> Result<Vec<Node>, ImportError> {
    let mut soup = Soup::of(pieces)?;
    let root = soup.root()?;
    let joins = soup.attach_pieces(pieces.len(), root)?;
    let joined = soup.join(&joins, root, warnings);
    let mut nodes = soup.breadth_first(&joined)?;
    floor_radii(&mut nodes);
    Ok(nodes)
}

/// Every piece's points and segments in one numbering (step 1–3 work on
/// it; step 4 appends the split points).
struct Soup {
    pos: Vec<Vec3>,
    rad: Vec<f32>,
    piece_of: Vec<u32>,
    segments: Vec<(u32, u32)>,
    seg_piece: Vec<u32>,
    /// Neighbours of each of the pieces' own points (before any join).
    degree: Vec<u32>,
    /// Lowest and highest point, metres.
    ymin: f32,
    ymax: f32,
}

impl Soup {
    fn of(pieces: &[Piece]) -> Result<Soup, ImportError> {
        let mut pos: Vec<Vec3> = Vec::new();
        let mut rad: Vec<f32> = Vec::new();
        let mut piece_of: Vec<u32> = Vec::new();
        let mut segments: Vec<(u32, u32)> = Vec::new();
        let mut seg_piece: Vec<u32> = Vec::new();
        for (k, p) in pieces.iter().enumerate() {
            let base = pos.len() as u32;
            pos.extend_from_slice(&p.points);
            rad.extend_from_slice(&p.radii);
            piece_of.extend(std::iter::repeat_n(k as u32, p.points.len()));
            for &(a, b) in &p.edges {
                segments.push((base + a, base + b));
                seg_piece.push(k as u32);
            }
        }
        let n = pos.len();
        if n == 0 {
            return Err(ImportError::InvalidTree(
                "the branch meshes give no skeleton points".into(),
            ));
        }
        let mut degree = vec![0u32; n];
        for &(a, b) in &segments {
            degree[a as usize] += 1;
            degree[b as usize] += 1;
        }
        let (ymin, ymax) = pos.iter().fold((f32::MAX, f32::MIN), |(lo, hi), p| {
            (lo.min(p.y), hi.max(p.y))
        });
        Ok(Soup {
            pos,
            rad,
            piece_of,
            segments,
            seg_piece,
            degree,
            ymin,
            ymax,
        })
    }

    /// Points of the pieces themselves (split points come after them).
    fn own_points(&self) -> usize {
        self.degree.len()
    }

    fn is_end(&self, v: usize) -> bool {
        self.degree[v] <= 1
    }

    /// Step 1: the thickest end near the ground — unless a much thicker end
    /// lies in the lowest quarter of the tree (see the module docs) — else,
    /// with no end near the ground, the lowest point.
    fn root(&self) -> Result<usize, ImportError> {
        let height = self.ymax - self.ymin;
        let ground = self.thickest_end_below(self.ymin + GROUND * height);
        let low = self.thickest_end_below(self.ymin + LOW * height);
        let root = match (ground, low) {
            (Some(g), Some(l)) if self.rad[g] < THIN * self.rad[l] => Some(l),
            (g, _) => g,
        };
        root.or_else(|| {
            (0..self.own_points()).min_by(|&a, &b| self.pos[a].y.total_cmp(&self.pos[b].y))
        })
        .ok_or_else(|| ImportError::Internal("no root candidate".into()))
    }

    /// The thickest end no higher than `y` (the lower of equals).
    fn thickest_end_below(&self, y: f32) -> Option<usize> {
        let (pos, rad) = (&self.pos, &self.rad);
        (0..self.own_points())
            .filter(|&v| self.is_end(v) && pos[v].y <= y)
            .max_by(|&a, &b| {
                rad[a]
                    .total_cmp(&rad[b])
                    .then(pos[b].y.total_cmp(&pos[a].y))
            })
    }

    /// A candidate joining `end` to global segment `seg`.
    fn candidate(&self, end: usize, seg: u32) -> Candidate {
        let (a, b) = self.segments[seg as usize];
        let (s, dist) =
            closest_on_segment(self.pos[end], self.pos[a as usize], self.pos[b as usize]);
        Candidate {
            dist,
            piece: self.piece_of[end],
            end: end as u32,
            target_piece: self.seg_piece[seg as usize],
            segment: seg,
            s,
        }
    }

    /// Spacing of the samples of a [`SegmentIndex`]: half the median
    /// segment, coarse enough to keep the index under ~400,000 samples.
    fn sample_step(&self) -> f32 {
        let lengths: Vec<f32> = self
            .segments
            .iter()
            .map(|&(a, b)| self.pos[a as usize].distance(self.pos[b as usize]))
            .collect();
        let total: f32 = lengths.iter().sum();
        let mut sorted = lengths.clone();
        let mid = sorted.len() / 2;
        let median = if sorted.is_empty() {
            1.0
        } else {
            *sorted.select_nth_unstable_by(mid, f32::total_cmp).1
        };
        (0.5 * median).max(total / 400_000.0).max(1e-6)
    }

    /// Steps 2–3: the join of every piece but the root's, in the order
    /// Prim's growth attaches them.
    fn attach_pieces(&self, pieces: usize, root: usize) -> Result<Vec<Candidate>, ImportError> {
        let mut attached = vec![false; pieces];
        let root_piece = self.piece_of[root] as usize;
        attached[root_piece] = true;
        let mut joins: Vec<Candidate> = Vec::new();
        if pieces == 1 {
            return Ok(joins);
        }
        let step = self.sample_step();
        let by_target = self.candidates(
            pieces,
            root_piece,
            &SegmentIndex::new(&self.pos, &self.segments, step),
        );
        let mut heap: BinaryHeap<Reverse<(u32, u32, u32)>> = BinaryHeap::new();
        let push = |heap: &mut BinaryHeap<Reverse<(u32, u32, u32)>>, t: usize| {
            for (i, c) in by_target[t].iter().enumerate() {
                heap.push(Reverse((c.dist.to_bits(), t as u32, i as u32)));
            }
        };
        push(&mut heap, root_piece);
        let mut remaining = pieces - 1;
        while remaining > 0 {
            while let Some(Reverse((_, t, i))) = heap.pop() {
                let c = by_target[t as usize][i as usize];
                if attached[c.piece as usize] {
                    continue;
                }
                attached[c.piece as usize] = true;
                remaining -= 1;
                joins.push(c);
                push(&mut heap, c.piece as usize);
            }
            if remaining == 0 {
                break;
            }
            let Some(c) = self.nearest_leftover(&attached, step) else {
                return Err(ImportError::InvalidTree(
                    "the branch mesh falls apart into pieces that cannot be joined into one skeleton"
                        .into(),
                ));
            };
            attached[c.piece as usize] = true;
            remaining -= 1;
            joins.push(c);
            push(&mut heap, c.piece as usize);
        }
        Ok(joins)
    }

    /// Step 2: per target piece, the candidates naming it — for every end
    /// outside the root's piece, the nearest point on up to four other
    /// pieces.
    fn candidates(
        &self,
        pieces: usize,
        root_piece: usize,
        index: &SegmentIndex,
    ) -> Vec<Vec<Candidate>> {
        let mut by_target: Vec<Vec<Candidate>> = vec![Vec::new(); pieces];
        for end in (0..self.own_points()).filter(|&v| self.is_end(v)) {
            let piece = self.piece_of[end];
            if piece as usize == root_piece {
                continue;
            }
            let mut best: Vec<Candidate> = Vec::new();
            for seg in index.near(self.pos[end], 32) {
                let target = self.seg_piece[seg as usize];
                if target == piece {
                    continue;
                }
                let c = self.candidate(end, seg);
                match best.iter_mut().find(|x| x.target_piece == target) {
                    Some(x) if x.dist > c.dist => *x = c,
                    Some(_) => {}
                    None => best.push(c),
                }
            }
            best.sort_by(|x, y| x.dist.total_cmp(&y.dist));
            best.truncate(4);
            for c in best {
                by_target[c.target_piece as usize].push(c);
            }
        }
        by_target
    }

    /// The leftover piece nearest to the attached ones, and its join, for
    /// when Prim's growth runs out of candidates.
    fn nearest_leftover(&self, attached: &[bool], step: f32) -> Option<Candidate> {
        let attached_segments: Vec<u32> = (0..self.segments.len() as u32)
            .filter(|&s| attached[self.seg_piece[s as usize] as usize])
            .collect();
        let sub: Vec<(u32, u32)> = attached_segments
            .iter()
            .map(|&s| self.segments[s as usize])
            .collect();
        let sub_index = SegmentIndex::new(&self.pos, &sub, step);
        let leftover = |v: usize| !attached[self.piece_of[v] as usize];
        let mut best: Option<Candidate> = None;
        for end in (0..self.own_points()).filter(|&v| self.is_end(v) && leftover(v)) {
            for local in sub_index.near(self.pos[end], 8) {
                let c = self.candidate(end, attached_segments[local as usize]);
                if best.is_none_or(|x| c.dist < x.dist) {
                    best = Some(c);
                }
            }
        }
        if best.is_none() {
            // The grid search found nothing near: the leftover pieces
            // are far away (hostile coordinates) or closed loops with
            // no end (found by fuzzing). Try every vertex of them
            // against every attached segment; only hostile files get
            // here, so the quadratic cost is bounded by the size
            // limits and paid by them alone.
            for v in (0..self.own_points()).filter(|&v| leftover(v)) {
                for &seg in &attached_segments {
                    let c = self.candidate(v, seg);
                    if c.dist.is_finite() && best.is_none_or(|x| c.dist < x.dist) {
                        best = Some(c);
                    }
                }
            }
        }
        best
    }

    /// Step 4: snaps or splits at every join and merges or connects the
    /// attaching ends.
    fn join(&mut self, joins: &[Candidate], root: usize, warnings: &mut Vec<String>) -> Joined {
        let n = self.own_points();
        let mut alias: Vec<u32> = (0..n as u32).collect();
        let mut splits: Vec<Vec<(f32, u32)>> = vec![Vec::new(); self.segments.len()];
        let mut extra: Vec<(u32, u32)> = Vec::new();
        let mut big_gaps = 0usize;
        for c in joins {
            let (pos, rad) = (&mut self.pos, &mut self.rad);
            let (a, b) = self.segments[c.segment as usize];
            let (pa, pb) = (pos[a as usize], pos[b as usize]);
            let len = pa.distance(pb);
            let r = rad[a as usize] + (rad[b as usize] - rad[a as usize]) * c.s;
            let snap = (0.1 * len).max(0.25 * r).min(0.5 * len);
            let target = if c.s * len <= snap {
                a
            } else if (1.0 - c.s) * len <= snap {
                b
            } else {
                let id = pos.len() as u32;
                pos.push(pa.lerp(pb, c.s));
                rad.push(r);
                alias.push(id);
                splits[c.segment as usize].push((c.s, id));
                id
            };
            let end = c.end as usize;
            let gap = pos[end].distance(pos[target as usize]);
            if c.dist > rad[end] + r + 0.05 * (self.ymax - self.ymin) {
                big_gaps += 1;
            }
            if gap <= MIN_BRANCH.max(0.1 * rad[end].min(r)) {
                alias[end] = target;
            } else {
                extra.push((target, end as u32));
            }
        }
        if big_gaps > 0 {
            warnings.push(format!(
                "{big_gaps} separate wood parts were joined to the tree across gaps wider than their thickness"
            ));
        }
        let mut edges: Vec<(u32, u32)> = Vec::with_capacity(self.segments.len() + extra.len() + 8);
        for (i, &(a, b)) in self.segments.iter().enumerate() {
            let mut list = std::mem::take(&mut splits[i]);
            list.sort_by(|x, y| x.0.total_cmp(&y.0));
            let mut prev = a;
            for (_, id) in list {
                edges.push((prev, id));
                prev = id;
            }
            edges.push((prev, b));
        }
        edges.extend(extra);
        let edges: Vec<(u32, u32)> = edges
            .into_iter()
            .map(|(a, b)| (resolve(a, &alias), resolve(b, &alias)))
            .filter(|(a, b)| a != b)
            .collect();
        Joined {
            edges,
            root: resolve(root as u32, &alias),
            alias,
        }
    }

    /// Nodes breadth-first from the root; nodes too close to their parent
    /// are merged into it. Fails when a point is left unreached (a bug: the
    /// joins connect every piece).
    fn breadth_first(&self, joined: &Joined) -> Result<Vec<Node>, ImportError> {
        let (pos, rad, root) = (&self.pos, &self.rad, joined.root);
        let total = pos.len();
        let adj = crate::mesh::Adjacency::of_edges(total, joined.edges.iter().copied());
        let mut id = vec![NONE; total];
        let mut nodes: Vec<Node> = Vec::new();
        id[root as usize] = 0;
        nodes.push(Node {
            position: pos[root as usize],
            radius: rad[root as usize],
            parent: None,
        });
        let mut queue_head = 0;
        let mut queue = vec![root];
        while queue_head < queue.len() {
            let v = queue[queue_head];
            queue_head += 1;
            let vid = id[v as usize];
            for &w in adj.neighbours(v) {
                if id[w as usize] != NONE {
                    continue;
                }
                let parent_pos = nodes[vid as usize].position;
                if pos[w as usize].distance(parent_pos) < MIN_BRANCH {
                    id[w as usize] = vid;
                } else {
                    id[w as usize] = nodes.len() as u32;
                    nodes.push(Node {
                        position: pos[w as usize],
                        radius: rad[w as usize],
                        parent: Some(vid),
                    });
                }
                queue.push(w);
            }
        }
        let reached = queue.len();
        let live = (0..total)
            .filter(|&v| {
                resolve(v as u32, &joined.alias) == v as u32
                    && adj.neighbours(v as u32).len() + usize::from(v as u32 == root) > 0
            })
            .count();
        if reached < live {
            return Err(ImportError::Internal(format!(
                "the assembled skeleton reaches {reached} of {live} points"
            )));
        }
        Ok(nodes)
    }
}

/// The joined tree of step 4, merged points resolved.
struct Joined {
    edges: Vec<(u32, u32)>,
    root: u32,
    /// Per point, the point it was merged into (itself when kept).
    alias: Vec<u32>,
}

/// Raises every radius to at least a thousandth of the thickest (and 10 µm):
/// the tree model refuses radii that are not positive, and a contracted
/// mesh can leave zero or NaN radii at its tips.
fn floor_radii(nodes: &mut [Node]) {
    let rmax = nodes.iter().map(|n| n.radius).fold(0.0f32, f32::max);
    let floor = (1e-3 * rmax).max(1e-5);
    for node in nodes {
        if node.radius.is_nan() || node.radius < floor {
            node.radius = floor;
        }
    }
}

/// The point `v` was merged into.
fn resolve(mut v: u32, alias: &[u32]) -> u32 {
    while alias[v as usize] != v {
        v = alias[v as usize];
    }
    v
}

#[cfg(test)]
#[path = "skeleton_tests.rs"]
mod tests;
