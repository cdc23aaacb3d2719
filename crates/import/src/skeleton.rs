//! Assembling skeleton pieces into one rooted tree.
//!
//! Every wood component gives a [`Piece`]: a small tree of axis points with
//! radii (a polyline for a tube, a branching tree for a contracted welded
//! mesh). Pieces are joined like this:
//!
//! 1. **Root.** Among the pieces' ends (points with at most one neighbour)
//!    that lie within 2 % of the tree's height above its lowest point, the
//!    thickest is the root: the lowest, thickest point.
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

use crate::error::ImportError;

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

/// Closest point to `p` on segment `a`–`b`: parameter and distance.
pub(crate) fn closest_on_segment(p: Vec3, a: Vec3, b: Vec3) -> (f32, f32) {
    let ab = b - a;
    let len2 = ab.length_squared();
    let s = if len2 > 0.0 {
        ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (s, p.distance(a + ab * s))
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
    let is_end = |v: usize| degree[v] <= 1;
    let (ymin, ymax) = pos.iter().fold((f32::MAX, f32::MIN), |(lo, hi), p| {
        (lo.min(p.y), hi.max(p.y))
    });
    let band = ymin + 0.02 * (ymax - ymin);
    let root = (0..n)
        .filter(|&v| is_end(v) && pos[v].y <= band)
        .max_by(|&a, &b| {
            rad[a]
                .total_cmp(&rad[b])
                .then(pos[b].y.total_cmp(&pos[a].y))
        })
        .or_else(|| (0..n).min_by(|&a, &b| pos[a].y.total_cmp(&pos[b].y)))
        .ok_or_else(|| ImportError::Internal("no root candidate".into()))?;

    let mut attached = vec![false; pieces.len()];
    let root_piece = piece_of[root] as usize;
    attached[root_piece] = true;
    let mut joins: Vec<Candidate> = Vec::new();
    if pieces.len() > 1 {
        let lengths: Vec<f32> = segments
            .iter()
            .map(|&(a, b)| pos[a as usize].distance(pos[b as usize]))
            .collect();
        let total: f32 = lengths.iter().sum();
        let mut sorted = lengths.clone();
        let mid = sorted.len() / 2;
        let median = if sorted.is_empty() {
            1.0
        } else {
            *sorted.select_nth_unstable_by(mid, f32::total_cmp).1
        };
        let step = (0.5 * median).max(total / 400_000.0).max(1e-6);
        let index = SegmentIndex::new(&pos, &segments, step);

        // Candidates per target piece.
        let mut by_target: Vec<Vec<Candidate>> = vec![Vec::new(); pieces.len()];
        for end in (0..n).filter(|&v| is_end(v)) {
            let piece = piece_of[end];
            if piece as usize == root_piece {
                continue;
            }
            let mut best: Vec<Candidate> = Vec::new();
            for seg in index.near(pos[end], 32) {
                let target = seg_piece[seg as usize];
                if target == piece {
                    continue;
                }
                let (a, b) = segments[seg as usize];
                let (s, dist) = closest_on_segment(pos[end], pos[a as usize], pos[b as usize]);
                let c = Candidate {
                    dist,
                    piece,
                    end: end as u32,
                    target_piece: target,
                    segment: seg,
                    s,
                };
                match best.iter_mut().find(|x| x.target_piece == target) {
                    Some(x) if x.dist > dist => *x = c,
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
        let mut heap: BinaryHeap<Reverse<(u32, u32, u32)>> = BinaryHeap::new();
        let push = |heap: &mut BinaryHeap<Reverse<(u32, u32, u32)>>,
                    by: &Vec<Vec<Candidate>>,
                    t: usize| {
            for (i, c) in by[t].iter().enumerate() {
                heap.push(Reverse((c.dist.to_bits(), t as u32, i as u32)));
            }
        };
        push(&mut heap, &by_target, root_piece);
        let mut remaining = pieces.len() - 1;
        while remaining > 0 {
            while let Some(Reverse((_, t, i))) = heap.pop() {
                let c = by_target[t as usize][i as usize];
                if attached[c.piece as usize] {
                    continue;
                }
                attached[c.piece as usize] = true;
                remaining -= 1;
                joins.push(c);
                push(&mut heap, &by_target, c.piece as usize);
            }
            if remaining == 0 {
                break;
            }
            // Leftovers: attach the one nearest to the attached pieces.
            let attached_segments: Vec<u32> = (0..segments.len() as u32)
                .filter(|&s| attached[seg_piece[s as usize] as usize])
                .collect();
            let sub: Vec<(u32, u32)> = attached_segments
                .iter()
                .map(|&s| segments[s as usize])
                .collect();
            let sub_index = SegmentIndex::new(&pos, &sub, step);
            let mut best: Option<Candidate> = None;
            for end in (0..n).filter(|&v| is_end(v) && !attached[piece_of[v] as usize]) {
                for local in sub_index.near(pos[end], 8) {
                    let seg = attached_segments[local as usize];
                    let (a, b) = segments[seg as usize];
                    let (s, dist) = closest_on_segment(pos[end], pos[a as usize], pos[b as usize]);
                    if best.is_none_or(|x| dist < x.dist) {
                        best = Some(Candidate {
                            dist,
                            piece: piece_of[end],
                            end: end as u32,
                            target_piece: seg_piece[seg as usize],
                            segment: seg,
                            s,
                        });
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
                for v in (0..n).filter(|&v| !attached[piece_of[v] as usize]) {
                    for &seg in &attached_segments {
                        let (a, b) = segments[seg as usize];
                        let (s, dist) =
                            closest_on_segment(pos[v], pos[a as usize], pos[b as usize]);
                        if dist.is_finite() && best.is_none_or(|x| dist < x.dist) {
                            best = Some(Candidate {
                                dist,
                                piece: piece_of[v],
                                end: v as u32,
                                target_piece: seg_piece[seg as usize],
                                segment: seg,
                                s,
                            });
                        }
                    }
                }
            }
            let Some(c) = best else {
                return Err(ImportError::InvalidTree(
                    "the branch mesh falls apart into pieces that cannot be joined into one skeleton"
                        .into(),
                ));
            };
            attached[c.piece as usize] = true;
            remaining -= 1;
            joins.push(c);
            push(&mut heap, &by_target, c.piece as usize);
        }
    }

    // Joins: snap or split, then merge or connect.
    let mut alias: Vec<u32> = (0..n as u32).collect();
    let mut splits: Vec<Vec<(f32, u32)>> = vec![Vec::new(); segments.len()];
    let mut extra: Vec<(u32, u32)> = Vec::new();
    let mut big_gaps = 0usize;
    for c in &joins {
        let (a, b) = segments[c.segment as usize];
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
        if c.dist > rad[end] + r + 0.05 * (ymax - ymin) {
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
    let resolve = |mut v: u32, alias: &[u32]| {
        while alias[v as usize] != v {
            v = alias[v as usize];
        }
        v
    };
    let mut edges: Vec<(u32, u32)> = Vec::with_capacity(segments.len() + extra.len() + 8);
    for (i, &(a, b)) in segments.iter().enumerate() {
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
    let total = pos.len();
    let edges: Vec<(u32, u32)> = edges
        .into_iter()
        .map(|(a, b)| (resolve(a, &alias), resolve(b, &alias)))
        .filter(|(a, b)| a != b)
        .collect();
    let root = resolve(root as u32, &alias);
    let adj = crate::mesh::Adjacency::of_edges(total, edges.iter().copied());

    // Breadth-first from the root; nodes too close to their parent are
    // merged into it.
    let mut id = vec![u32::MAX; total];
    let mut nodes: Vec<Node> = Vec::new();
    let mut stack = vec![(root, None::<u32>)];
    id[root as usize] = 0;
    nodes.push(Node {
        position: pos[root as usize],
        radius: rad[root as usize],
        parent: None,
    });
    let mut queue_head = 0;
    let mut queue = vec![root];
    stack.clear();
    while queue_head < queue.len() {
        let v = queue[queue_head];
        queue_head += 1;
        let vid = id[v as usize];
        for &w in adj.neighbours(v) {
            if id[w as usize] != u32::MAX {
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
            resolve(v as u32, &alias) == v as u32
                && adj.neighbours(v as u32).len() + usize::from(v as u32 == root) > 0
        })
        .count();
    if reached < live {
        return Err(ImportError::Internal(format!(
            "the assembled skeleton reaches {reached} of {live} points"
        )));
    }
    let rmax = nodes.iter().map(|n| n.radius).fold(0.0f32, f32::max);
    let floor = (1e-3 * rmax).max(1e-5);
    for node in &mut nodes {
        if node.radius.is_nan() || node.radius < floor {
            node.radius = floor;
        }
    }
    Ok(nodes)
}

#[cfg(test)]
#[path = "skeleton_tests.rs"]
mod tests;
