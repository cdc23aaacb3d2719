//! Tube skeletons: the axis of one open or capped tube from its rings.
//!
//! A breadth-first search over the mesh edges, started from one end of the
//! tube, reaches the tube's rings one after the other: with the usual ring
//! layout every vertex of ring `i + 1` is one edge from ring `i`, so the
//! search's levels *are* the rings, whatever the triangulation of the
//! quads. The search starts from a whole boundary loop (an open tube end)
//! when there is one. A closed tube starts from an apex or a cap centre:
//! candidates are the vertex farthest from the centroid and the two ends of
//! a surface double sweep, and the one whose levels are the tightest rings
//! (smallest mean distance to their centroids) wins. (The farthest vertex
//! along the surface alone can be a rim vertex across the last ring, and
//! counting edges instead of length picks mid-tube vertices on short, thick
//! tubes.) Each level's centroid is an axis
//! point and its mean distance to the centroid the radius there;
//! single-vertex levels at either end (apex, cap centre) are dropped.
//!
//! A component is a tube only if every level is one connected ring; a
//! component that branches (a level falls apart into several pieces) is
//! left to mesh contraction.

use glam::Vec3;
use treemorph_tree::geom::NONE;

use crate::mesh::{Adjacency, Edges, Mesh, UnionFind};
use crate::skeleton::Piece;

/// The axis polyline of `mesh` if it is a simple tube.
pub(crate) fn tube_piece(mesh: &Mesh) -> Option<Piece> {
    let n = mesh.len();
    if n < 3 {
        return None;
    }
    let edges = Edges::of(mesh);
    let adj = Adjacency::of_edges(n, edges.list.iter().copied());
    let boundary = Adjacency::of_edges(
        n,
        edges
            .list
            .iter()
            .zip(&edges.uses)
            .filter(|(_, u)| **u == 1)
            .map(|(e, _)| *e),
    );
    let candidates: Vec<Vec<u32>> =
        match (0..n as u32).find(|&v| !boundary.neighbours(v).is_empty()) {
            // An open end: its whole boundary loop.
            Some(start) => {
                let mut seen = vec![start];
                let mut on = vec![false; n];
                on[start as usize] = true;
                let mut i = 0;
                while i < seen.len() {
                    for &w in boundary.neighbours(seen[i]) {
                        if !std::mem::replace(&mut on[w as usize], true) {
                            seen.push(w);
                        }
                    }
                    i += 1;
                }
                vec![seen]
            }
            // Closed: an apex or a cap centre. The vertex farthest from the
            // centroid is one when the tube is straight-ish; the surface double
            // sweep finds one when it bends. The candidate whose levels are the
            // tightest rings wins.
            None => {
                let centroid = mesh.positions.iter().sum::<Vec3>() / n as f32;
                let euclid = (0..n as u32)
                    .max_by(|&a, &b| {
                        let d = |v: u32| mesh.positions[v as usize].distance_squared(centroid);
                        d(a).total_cmp(&d(b))
                    })
                    .unwrap_or(0);
                let a = farthest(mesh, &adj, 0);
                let b = farthest(mesh, &adj, a);
                vec![vec![euclid], vec![a], vec![b]]
            }
        };
    candidates
        .iter()
        .filter_map(|sources| rings(mesh, &adj, &edges, sources))
        .min_by(|x, y| x.0.total_cmp(&y.0))
        .map(|(_, piece)| piece)
}

/// The ring centroids of the breadth-first levels from `sources`, and the
/// mean ring radius (small for true rings); `None` when a level is not one
/// connected ring.
fn rings(mesh: &Mesh, adj: &Adjacency, edges: &Edges, sources: &[u32]) -> Option<(f32, Piece)> {
    let n = mesh.len();
    let mut level = vec![NONE; n];
    let mut queue = Vec::with_capacity(n);
    bfs(adj, sources, &mut level, &mut queue);
    if level.contains(&NONE) {
        return None;
    }
    let levels = *level.iter().max()? as usize + 1;

    // Every level must be one connected ring.
    let mut uf = UnionFind::new(n);
    for &(a, b) in &edges.list {
        if level[a as usize] == level[b as usize] {
            uf.union(a, b);
        }
    }
    let mut root_of_level = vec![NONE; levels];
    let mut sum = vec![Vec3::ZERO; levels];
    let mut count = vec![0u32; levels];
    for v in 0..n as u32 {
        let l = level[v as usize] as usize;
        let r = uf.find(v);
        if root_of_level[l] == NONE {
            root_of_level[l] = r;
        } else if root_of_level[l] != r {
            return None;
        }
        sum[l] += mesh.positions[v as usize];
        count[l] += 1;
    }
    let centres: Vec<Vec3> = sum
        .iter()
        .zip(&count)
        .map(|(s, &c)| *s / c as f32)
        .collect();
    let mut radius = vec![0.0f32; levels];
    for (p, &l) in mesh.positions.iter().zip(&level) {
        radius[l as usize] += p.distance(centres[l as usize]);
    }
    for (r, &c) in radius.iter_mut().zip(&count) {
        *r /= c as f32;
    }
    let mut first = 0;
    let mut last = levels;
    if count[0] == 1 && levels > 2 {
        first = 1;
    }
    if count[levels - 1] == 1 && last - first > 2 {
        last -= 1;
    }
    let mut piece = Piece::default();
    for l in first..last {
        let p = centres[l];
        // Rings that coincide (zero-length segments) add nothing.
        if let Some(&prev) = piece.points.last()
            && prev.distance(p) <= 1e-6
        {
            continue;
        }
        piece.points.push(p);
        piece.radii.push(radius[l]);
    }
    if piece.points.len() < 2 {
        return None;
    }
    piece.edges = (1..piece.points.len() as u32).map(|i| (i - 1, i)).collect();
    let score = radius
        .iter()
        .zip(&count)
        .map(|(r, &c)| r * c as f32)
        .sum::<f32>()
        / n as f32;
    Some((score, piece))
}

/// The vertex farthest from `start` along mesh edges (Dijkstra).
fn farthest(mesh: &Mesh, adj: &Adjacency, start: u32) -> u32 {
    use std::cmp::Reverse;
    use std::collections::BinaryHeap;
    let mut dist = vec![f32::INFINITY; mesh.len()];
    let mut heap = BinaryHeap::new();
    dist[start as usize] = 0.0;
    heap.push(Reverse((0u32, start)));
    let mut far = (0.0f32, start);
    while let Some(Reverse((d, v))) = heap.pop() {
        let d = f32::from_bits(d);
        if d > dist[v as usize] {
            continue;
        }
        if d > far.0 {
            far = (d, v);
        }
        for &w in adj.neighbours(v) {
            let nd = d + mesh.positions[v as usize].distance(mesh.positions[w as usize]);
            if nd < dist[w as usize] {
                dist[w as usize] = nd;
                heap.push(Reverse((nd.to_bits(), w)));
            }
        }
    }
    far.1
}

/// Breadth-first levels from `sources`; returns the last vertex reached.
fn bfs(adj: &Adjacency, sources: &[u32], level: &mut [u32], queue: &mut Vec<u32>) -> u32 {
    queue.clear();
    for &s in sources {
        if level[s as usize] == NONE {
            level[s as usize] = 0;
            queue.push(s);
        }
    }
    let mut head = 0;
    while head < queue.len() {
        let v = queue[head];
        head += 1;
        let next = level[v as usize] + 1;
        for &w in adj.neighbours(v) {
            if level[w as usize] == NONE {
                level[w as usize] = next;
                queue.push(w);
            }
        }
    }
    queue.last().copied().unwrap_or(sources[0])
}
