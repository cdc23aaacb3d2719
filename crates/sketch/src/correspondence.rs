//! The crown correspondence (§5.1, "screen-space arc-length
//! parameterisation"): matching points of the crown silhouette S0 and the
//! sketched crown S1, so the crown cage can move from one to the other.
//!
//! - **Closed sketch**: S1 is the sketch. Both polygons are counter-clockwise
//!   and parameterised by normalised arc length from their topmost vertex;
//!   the sketch's parameter is then shifted by the cyclic offset that
//!   minimises the sum of squared distances between 128 uniform samples of
//!   the two curves, each centred on its mean and scaled by its bounding-box
//!   diagonal (so the alignment depends on shape, not on where or how big
//!   the sketch is drawn). A topmost-point start alone is fragile: a heart
//!   has two tops.
//! - **Open sketch**: its ends snap to the nearest silhouette points `a`,
//!   `b`; of the two silhouette arcs between them, the one closer to the
//!   stroke (mean distance of 32 stroke samples) is replaced by
//!   `a → stroke → b`; the other is kept and maps to itself.
//!
//! The sample set is the union of both curves' corners (by parameter) and
//! `crown_samples` uniform parameters, so neither a silhouette corner nor a
//! sketch corner (a heart's cusp, a star's tips) is cut off; samples closer
//! than a fifth of the uniform spacing merge, keeping silhouette corners
//! exact. The source samples all lie on S0, so the crown cage at rest is
//! still the convex silhouette.

use glam::Vec2;

use crate::error::{SketchEnd, SketchError};
use crate::polygon;

/// Corresponding samples of the crown silhouette and the sketched crown.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Correspondence {
    /// Samples on the crown silhouette S0, CCW: the crown cage at rest.
    pub source: Vec<Vec2>,
    /// The matching samples on the sketched crown S1 (also its polygon).
    pub target: Vec<Vec2>,
    /// For each sample, the S0 vertex it sits on, if any.
    pub source_vertex: Vec<Option<u32>>,
}

/// A curve parameterised by normalised arc length.
struct Curve<'a> {
    points: &'a [Vec2],
    cum: Vec<f32>,
    closed: bool,
}

impl<'a> Curve<'a> {
    fn new(points: &'a [Vec2], closed: bool) -> Curve<'a> {
        Curve {
            points,
            cum: polygon::cumulative(points, closed),
            closed,
        }
    }

    fn length(&self) -> f32 {
        *self.cum.last().unwrap_or(&0.0)
    }

    /// Normalised parameter of vertex `i`.
    fn param(&self, i: usize) -> f32 {
        let l = self.length();
        if l > 0.0 { self.cum[i] / l } else { 0.0 }
    }

    fn at(&self, u: f32) -> Vec2 {
        polygon::point_at(self.points, &self.cum, self.closed, u * self.length())
    }
}

/// A merged, sorted parameter list in [0, 1) (closed) or [0, 1] (open),
/// tagged with the source vertex each entry sits on.
fn merge_params(
    source: impl Iterator<Item = (f32, u32)>,
    others: impl Iterator<Item = f32>,
    gap: f32,
    closed: bool,
) -> Vec<(f32, Option<u32>)> {
    let mut all: Vec<(f32, Option<u32>)> = source.map(|(u, i)| (u, Some(i))).collect();
    all.extend(others.map(|u| (u, None)));
    all.retain(|(u, _)| u.is_finite());
    all.sort_by(|a, b| a.0.total_cmp(&b.0).then(b.1.is_some().cmp(&a.1.is_some())));
    let mut out: Vec<(f32, Option<u32>)> = Vec::with_capacity(all.len());
    for (u, tag) in all {
        match out.last_mut() {
            Some(last) if u - last.0 < gap => match (last.1, tag) {
                (None, Some(_)) => *last = (u, tag),
                (Some(_), Some(_)) => out.push((u, tag)),
                _ => {}
            },
            _ => out.push((u, tag)),
        }
    }
    if closed {
        // Wrap-around: an untagged entry too close to 1 (= 0) goes.
        while out.len() > 1 {
            let last = out[out.len() - 1];
            if 1.0 - last.0 < gap && last.1.is_none() {
                out.pop();
            } else {
                break;
            }
        }
    }
    out
}

/// Rotates a closed polygon to start at its topmost vertex; returns the
/// rotated copy and the original index of each vertex.
fn from_top(poly: &[Vec2]) -> (Vec<Vec2>, Vec<u32>) {
    let top = polygon::topmost(poly);
    let n = poly.len();
    let idx: Vec<u32> = (0..n).map(|k| ((top + k) % n) as u32).collect();
    (idx.iter().map(|&i| poly[i as usize]).collect(), idx)
}

/// Correspondence for a closed sketch `s1` (CCW) replacing the silhouette
/// `s0` (CCW).
pub(crate) fn closed(s0: &[Vec2], s1: &[Vec2], uniform: usize) -> Correspondence {
    let (p0, idx0) = from_top(s0);
    let (p1, _) = from_top(s1);
    let c0 = Curve::new(&p0, true);
    let c1 = Curve::new(&p1, true);

    // Cyclic alignment of the normalised shapes.
    const M: usize = 128;
    let normalised = |c: &Curve<'_>| -> Vec<Vec2> {
        let pts: Vec<Vec2> = (0..M).map(|k| c.at(k as f32 / M as f32)).collect();
        let mean = pts.iter().copied().sum::<Vec2>() / M as f32;
        let size = polygon::diagonal(&pts).max(1e-12);
        pts.iter().map(|&p| (p - mean) / size).collect()
    };
    let a = normalised(&c0);
    let b = normalised(&c1);
    let mut best = (f32::INFINITY, 0usize);
    for shift in 0..M {
        let cost: f32 = (0..M)
            .map(|k| a[k].distance_squared(b[(k + shift) % M]))
            .sum();
        if cost < best.0 {
            best = (cost, shift);
        }
    }
    let delta = best.1 as f32 / M as f32;

    let gap = 0.2 / uniform as f32;
    let params = merge_params(
        (0..p0.len()).map(|i| (c0.param(i), idx0[i])),
        (0..p1.len())
            .map(|j| (c1.param(j) - delta).rem_euclid(1.0))
            .chain((0..uniform).map(|k| k as f32 / uniform as f32)),
        gap,
        true,
    );
    let mut out = Correspondence {
        source: Vec::with_capacity(params.len()),
        target: Vec::with_capacity(params.len()),
        source_vertex: Vec::with_capacity(params.len()),
    };
    for (u, tag) in params {
        let src = match tag {
            Some(i) => s0[i as usize],
            None => c0.at(u),
        };
        out.source.push(src);
        out.target.push(c1.at((u + delta).rem_euclid(1.0)));
        out.source_vertex.push(tag);
    }
    out
}

/// The CCW arc of closed polygon `poly` from arc length `s` to `e`
/// (wrapping), as points: the point at `s`, the vertices strictly between,
/// the point at `e`; with the vertex index of each point.
fn arc(poly: &[Vec2], cum: &[f32], s: f32, e: f32) -> (Vec<Vec2>, Vec<Option<u32>>) {
    let total = *cum.last().unwrap_or(&0.0);
    let n = poly.len();
    let len = (e - s).rem_euclid(total);
    let mut pts = vec![polygon::point_at(poly, cum, true, s)];
    let mut tags = vec![None];
    // Vertices whose offset from s lies in (0, len).
    let mut verts: Vec<(f32, usize)> = (0..n)
        .map(|i| ((cum[i] - s).rem_euclid(total), i))
        .filter(|&(o, _)| o > 1e-7 * total && o < len - 1e-7 * total)
        .collect();
    verts.sort_by(|a, b| a.0.total_cmp(&b.0));
    for (_, i) in verts {
        pts.push(poly[i]);
        tags.push(Some(i as u32));
    }
    pts.push(polygon::point_at(poly, cum, true, e));
    tags.push(None);
    (pts, tags)
}

fn mean_distance(samples: &[Vec2], line: &[Vec2]) -> f32 {
    let cum = polygon::cumulative(line, false);
    samples
        .iter()
        .map(|&p| polygon::nearest_arc(line, &cum, false, p).1)
        .sum::<f32>()
        / samples.len().max(1) as f32
}

/// Correspondence for an open sketch `stroke` oversketching part of `s0`.
/// `limit` is the largest accepted distance from an end to `s0`.
pub(crate) fn open(
    s0: &[Vec2],
    stroke: &[Vec2],
    uniform: usize,
    limit: f32,
) -> Result<Correspondence, SketchError> {
    let cum = polygon::cumulative(s0, true);
    let total = *cum.last().unwrap_or(&0.0);
    let first = stroke[0];
    let last = stroke[stroke.len() - 1];
    let (sa, da) = polygon::nearest_arc(s0, &cum, true, first);
    let (sb, db) = polygon::nearest_arc(s0, &cum, true, last);
    for (end, distance) in [(SketchEnd::Start, da), (SketchEnd::End, db)] {
        if distance > limit {
            return Err(SketchError::OpenSketchTooFar {
                end,
                distance,
                limit,
            });
        }
    }
    if (sb - sa).abs() <= 1e-6 * total || (total - (sb - sa).abs()) <= 1e-6 * total {
        return Err(SketchError::OpenSketchEndsCoincide);
    }
    let stroke_curve = Curve::new(stroke, false);
    let probes: Vec<Vec2> = (0..32).map(|k| stroke_curve.at(k as f32 / 31.0)).collect();
    let (arc1, tags1) = arc(s0, &cum, sa, sb);
    let (arc2, tags2) = arc(s0, &cum, sb, sa);
    // The replaced arc R runs CCW from p to q; the new part N from p to q.
    let (replaced, replaced_tags, kept, kept_tags, new_part) =
        if mean_distance(&probes, &arc1) <= mean_distance(&probes, &arc2) {
            let mut n = vec![arc1[0]];
            n.extend_from_slice(stroke);
            n.push(arc1[arc1.len() - 1]);
            (arc1, tags1, arc2, tags2, n)
        } else {
            let mut n = vec![arc2[0]];
            n.extend(stroke.iter().rev());
            n.push(arc2[arc2.len() - 1]);
            (arc2, tags2, arc1, tags1, n)
        };
    let new_part = polygon::dedup(&new_part, false);

    // The sketched crown: N (p → q) then the kept arc's interior (q → p).
    let mut sketched = new_part.clone();
    sketched.extend_from_slice(&kept[1..kept.len() - 1]);
    let sketched = polygon::dedup(&sketched, true);
    if sketched.len() < 3
        || polygon::first_self_intersection(&sketched, true).is_some()
        || polygon::signed_area(&sketched) <= 0.0
    {
        return Err(SketchError::SplicedCrownSelfIntersecting);
    }

    let rc = Curve::new(&replaced, false);
    let nc = Curve::new(&new_part, false);
    let share = (rc.length() / total.max(1e-12)).clamp(0.0, 1.0);
    let count = ((uniform as f32 * share).ceil() as usize).max(8);
    let gap = 0.2 / count as f32;
    let params = merge_params(
        (0..replaced.len()).filter_map(|i| replaced_tags[i].map(|t| (rc.param(i), t))),
        (0..new_part.len())
            .map(|j| nc.param(j))
            .chain((0..count).map(|k| k as f32 / count as f32)),
        gap,
        false,
    );
    let mut out = Correspondence {
        source: Vec::new(),
        target: Vec::new(),
        source_vertex: Vec::new(),
    };
    for (u, tag) in params {
        if u >= 1.0 {
            continue; // q is the kept arc's first point
        }
        let src = match tag {
            Some(i) => s0[i as usize],
            None => rc.at(u),
        };
        out.source.push(src);
        out.target.push(nc.at(u));
        out.source_vertex.push(tag);
    }
    // The kept arc maps to itself: q, its vertices, up to (not including) p.
    for (k, &p) in kept[..kept.len() - 1].iter().enumerate() {
        out.source.push(p);
        out.target.push(p);
        out.source_vertex.push(kept_tags[k]);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn circle(n: usize, r: f32, c: Vec2) -> Vec<Vec2> {
        (0..n)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / n as f32;
                c + Vec2::new(a.cos(), a.sin()) * r
            })
            .collect()
    }

    #[test]
    fn closed_correspondence_keeps_corners_and_aligns() {
        let s0 = circle(24, 1.0, Vec2::ZERO);
        // A square, drawn starting from a different corner and offset.
        let s1 = vec![
            Vec2::new(2.0, -1.0),
            Vec2::new(4.0, -1.0),
            Vec2::new(4.0, 1.0),
            Vec2::new(2.0, 1.0),
        ];
        let c = closed(&s0, &s1, 64);
        assert_eq!(c.source.len(), c.target.len());
        // Every silhouette vertex and every sketch corner is a sample.
        for v in &s0 {
            assert!(c.source.contains(v));
        }
        for v in &s1 {
            assert!(c.target.iter().any(|t| t.distance(*v) < 1e-5));
        }
        assert!(polygon::signed_area(&c.source) > 0.0);
        assert!(polygon::signed_area(&c.target) > 0.0);
        // Aligned: the top of the circle maps to the top edge of the square.
        let top = c
            .source
            .iter()
            .position(|p| p.distance(Vec2::new(0.0, 1.0)) < 1e-5)
            .unwrap();
        assert!((c.target[top].y - 1.0).abs() < 1e-3, "{:?}", c.target[top]);
        assert!((c.target[top].x - 3.0).abs() < 0.3, "{:?}", c.target[top]);
    }

    #[test]
    fn open_correspondence_replaces_the_overdrawn_arc() {
        let s0 = circle(32, 1.0, Vec2::ZERO);
        // Push the top of the circle up into a point.
        let stroke = vec![
            Vec2::new(-0.7, 0.72),
            Vec2::new(0.0, 1.6),
            Vec2::new(0.7, 0.72),
        ];
        let c = open(&s0, &stroke, 64, 0.2).unwrap();
        let moved = c
            .source
            .iter()
            .zip(&c.target)
            .filter(|(s, t)| s.distance(**t) > 1e-4)
            .count();
        assert!(moved > 0);
        // The bottom is kept.
        for (s, t) in c.source.iter().zip(&c.target) {
            if s.y < 0.0 {
                assert_eq!(s, t);
            }
        }
        assert!(
            c.target
                .iter()
                .any(|t| t.distance(Vec2::new(0.0, 1.6)) < 1e-5)
        );
        assert!(polygon::signed_area(&c.target) > polygon::signed_area(&c.source));
        // Too far away.
        let far = vec![
            Vec2::new(-0.7, 1.5),
            Vec2::new(0.0, 1.6),
            Vec2::new(0.7, 0.72),
        ];
        assert!(matches!(
            open(&s0, &far, 64, 0.2),
            Err(SketchError::OpenSketchTooFar {
                end: SketchEnd::Start,
                ..
            })
        ));
    }
}
