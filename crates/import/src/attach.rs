//! Leaf attachment: each leaf to the nearest skeleton segment.
//!
//! A kd-tree (kiddo) over points sampled along every branch gives the
//! branches near a leaf's anchor; the exact closest point on those decides
//! the branch and the parameter `t`, and the offset is the anchor minus that
//! point. A leaf whose base is unknown (no texture coordinates) is tried
//! from both ends and keeps the end nearer the skeleton.

use glam::Vec3;
use treemorph_tree::{Leaf, Node};

use crate::leaves::LeafGeometry;
use crate::skeleton::{SegmentIndex, closest_on_segment};

/// Attaches `leaves` to the skeleton `nodes` (canonical order, at least two
/// nodes).
pub(crate) fn attach(nodes: &[Node], leaves: &[LeafGeometry]) -> Vec<Leaf> {
    let points: Vec<Vec3> = nodes.iter().map(|n| n.position).collect();
    let segments: Vec<(u32, u32)> = nodes
        .iter()
        .enumerate()
        .filter_map(|(i, n)| n.parent.map(|p| (p, i as u32)))
        .collect();
    let mut lengths: Vec<f32> = segments
        .iter()
        .map(|&(a, b)| points[a as usize].distance(points[b as usize]))
        .collect();
    let total: f32 = lengths.iter().sum();
    let mid = lengths.len() / 2;
    let median = *lengths.select_nth_unstable_by(mid, f32::total_cmp).1;
    let step = (0.5 * median).max(total / 400_000.0).max(1e-6);
    let index = SegmentIndex::new(&points, &segments, step);
    let nearest = |p: Vec3| {
        let mut best: Option<(f32, u32, f32)> = None;
        for seg in index.near(p, 12) {
            let (a, b) = segments[seg as usize];
            let (s, d) = closest_on_segment(p, points[a as usize], points[b as usize]);
            if best.is_none_or(|x| d < x.0) {
                best = Some((d, seg, s));
            }
        }
        best
    };
    leaves
        .iter()
        .filter_map(|leaf| {
            let mut leaf = *leaf;
            let mut hit = nearest(leaf.anchor)?;
            if leaf.base_unknown {
                let other = leaf.flipped();
                if let Some(h) = nearest(other.anchor)
                    && h.0 < hit.0
                {
                    leaf = other;
                    hit = h;
                }
            }
            let (_, seg, s) = hit;
            let (a, b) = segments[seg as usize];
            let point = points[a as usize].lerp(points[b as usize], s);
            Some(Leaf {
                branch: b,
                t: s,
                offset: leaf.anchor - point,
                width: leaf.width,
                height: leaf.height,
                orientation: leaf.orientation,
                material: leaf.material,
            })
        })
        .collect()
}
