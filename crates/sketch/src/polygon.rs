//! Small 2D polygon toolkit in normalised device coordinates: areas,
//! convex hulls, containment, arc-length parameterisation, nearest points,
//! simplification and self-intersection tests.
//!
//! Polygons are slices of vertices without a repeated closing vertex;
//! counter-clockwise (CCW) is positive area (y up).

use glam::{DVec2, Vec2};
use treemorph_tree::geom::{closest_on_segment, distance_to_segment};

/// Twice the signed area (positive for CCW), in f64 for robustness.
pub(crate) fn signed_area2(poly: &[Vec2]) -> f64 {
    let n = poly.len();
    if n < 3 {
        return 0.0;
    }
    let mut s = 0.0f64;
    for i in 0..n {
        let a = poly[i].as_dvec2();
        let b = poly[(i + 1) % n].as_dvec2();
        s += a.perp_dot(b);
    }
    s
}

/// Signed area (positive for CCW).
pub(crate) fn signed_area(poly: &[Vec2]) -> f32 {
    (0.5 * signed_area2(poly)) as f32
}

/// Perimeter of a closed polygon.
pub(crate) fn perimeter(poly: &[Vec2]) -> f32 {
    let n = poly.len();
    (0..n).map(|i| poly[i].distance(poly[(i + 1) % n])).sum()
}

/// Axis-aligned bounds `(min, max)`; `None` for an empty slice.
pub(crate) fn bounds(points: &[Vec2]) -> Option<(Vec2, Vec2)> {
    let first = *points.first()?;
    Some(
        points
            .iter()
            .fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p))),
    )
}

/// Length of the diagonal of the bounds (0 when empty).
pub(crate) fn diagonal(points: &[Vec2]) -> f32 {
    bounds(points).map_or(0.0, |(lo, hi)| lo.distance(hi))
}

/// Indices of the 2D convex hull, CCW, without collinear points (Andrew's
/// monotone chain). Fewer than 3 indices when the points span no area.
pub(crate) fn convex_hull(points: &[Vec2]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..points.len())
        .filter(|&i| points[i].is_finite())
        .collect();
    idx.sort_by(|&a, &b| {
        let (p, q) = (points[a], points[b]);
        p.x.total_cmp(&q.x).then(p.y.total_cmp(&q.y))
    });
    idx.dedup_by(|a, b| points[*a] == points[*b]);
    if idx.len() < 3 {
        return idx;
    }
    let cross = |o: usize, a: usize, b: usize| {
        let (o, a, b) = (
            points[o].as_dvec2(),
            points[a].as_dvec2(),
            points[b].as_dvec2(),
        );
        (a - o).perp_dot(b - o)
    };
    let mut hull: Vec<usize> = Vec::with_capacity(2 * idx.len());
    for &i in &idx {
        while hull.len() >= 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], i) <= 0.0 {
            hull.pop();
        }
        hull.push(i);
    }
    let lower = hull.len() + 1;
    for &i in idx.iter().rev().skip(1) {
        while hull.len() >= lower && cross(hull[hull.len() - 2], hull[hull.len() - 1], i) <= 0.0 {
            hull.pop();
        }
        hull.push(i);
    }
    hull.pop();
    hull
}

/// Whether `p` is inside the polygon (even–odd rule; points exactly on the
/// boundary may go either way).
pub(crate) fn contains(poly: &[Vec2], p: Vec2) -> bool {
    let n = poly.len();
    let mut inside = false;
    let mut j = n.wrapping_sub(1);
    for i in 0..n {
        let (a, b) = (poly[i], poly[j]);
        if (a.y > p.y) != (b.y > p.y) {
            let x = a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x);
            if p.x < x {
                inside = !inside;
            }
        }
        j = i;
    }
    inside
}

/// Distance from `p` to the boundary of a closed polygon.
pub(crate) fn distance_to_boundary(poly: &[Vec2], p: Vec2) -> f32 {
    let n = poly.len();
    (0..n)
        .map(|i| distance_to_segment(p, poly[i], poly[(i + 1) % n]))
        .fold(f32::INFINITY, f32::min)
}

/// Cumulative arc lengths of a polyline's vertices; for a closed polygon the
/// extra last entry is the perimeter.
pub(crate) fn cumulative(points: &[Vec2], closed: bool) -> Vec<f32> {
    let n = points.len();
    let segs = if closed { n } else { n.saturating_sub(1) };
    let mut out = Vec::with_capacity(segs + 1);
    let mut s = 0.0;
    out.push(0.0);
    for i in 0..segs {
        s += points[i].distance(points[(i + 1) % n]);
        out.push(s);
    }
    out
}

/// Point at arc length `s` along a polyline with cumulative lengths `cum`
/// (from [`cumulative`]); closed polygons wrap.
pub(crate) fn point_at(points: &[Vec2], cum: &[f32], closed: bool, s: f32) -> Vec2 {
    let n = points.len();
    let total = *cum.last().unwrap_or(&0.0);
    if total <= 0.0 || n == 1 {
        return points[0];
    }
    let s = if closed {
        s.rem_euclid(total)
    } else {
        s.clamp(0.0, total)
    };
    let segs = cum.len() - 1;
    let i = cum.partition_point(|&c| c <= s).clamp(1, segs) - 1;
    let len = cum[i + 1] - cum[i];
    let f = if len > 0.0 { (s - cum[i]) / len } else { 0.0 };
    points[i].lerp(points[(i + 1) % n], f.clamp(0.0, 1.0))
}

/// Nearest point on a polyline (closed or open): `(arc length, distance)`.
pub(crate) fn nearest_arc(points: &[Vec2], cum: &[f32], closed: bool, p: Vec2) -> (f32, f32) {
    let n = points.len();
    let segs = if closed { n } else { n.saturating_sub(1) };
    let mut best = (0.0, f32::INFINITY);
    for i in 0..segs {
        let (a, b) = (points[i], points[(i + 1) % n]);
        let (q, f) = closest_on_segment(p, a, b);
        let d = q.distance(p);
        if d < best.1 {
            best = (cum[i] + f * (cum[i + 1] - cum[i]), d);
        }
    }
    if segs == 0 && n == 1 {
        best = (0.0, points[0].distance(p));
    }
    best
}

/// Douglas–Peucker simplification of an open polyline (endpoints kept).
pub(crate) fn simplify_open(points: &[Vec2], tolerance: f32) -> Vec<Vec2> {
    if points.len() <= 2 {
        return points.to_vec();
    }
    let mut keep = vec![false; points.len()];
    keep[0] = true;
    keep[points.len() - 1] = true;
    let mut stack = vec![(0usize, points.len() - 1)];
    while let Some((a, b)) = stack.pop() {
        if b <= a + 1 {
            continue;
        }
        let (mut far, mut far_d) = (a, -1.0f32);
        for i in a + 1..b {
            let d = distance_to_segment(points[i], points[a], points[b]);
            if d > far_d {
                far_d = d;
                far = i;
            }
        }
        if far_d > tolerance {
            keep[far] = true;
            stack.push((a, far));
            stack.push((far, b));
        }
    }
    points
        .iter()
        .zip(keep)
        .filter_map(|(p, k)| k.then_some(*p))
        .collect()
}

/// Douglas–Peucker simplification of a closed polygon: split at the vertex
/// farthest from vertex 0 and simplify both halves.
pub(crate) fn simplify_closed(points: &[Vec2], tolerance: f32) -> Vec<Vec2> {
    let n = points.len();
    if n <= 4 {
        return points.to_vec();
    }
    let far = (1..n)
        .max_by(|&a, &b| {
            points[a]
                .distance_squared(points[0])
                .total_cmp(&points[b].distance_squared(points[0]))
        })
        .unwrap_or(n / 2);
    let first: Vec<Vec2> = points[..=far].to_vec();
    let mut second: Vec<Vec2> = points[far..].to_vec();
    second.push(points[0]);
    let mut out = simplify_open(&first, tolerance);
    let rest = simplify_open(&second, tolerance);
    out.extend_from_slice(&rest[1..rest.len() - 1]);
    if out.len() < 3 {
        return points.to_vec();
    }
    out
}

fn orient(a: DVec2, b: DVec2, c: DVec2) -> f64 {
    (b - a).perp_dot(c - a)
}

fn on_segment(a: DVec2, b: DVec2, p: DVec2) -> bool {
    p.x >= a.x.min(b.x) && p.x <= a.x.max(b.x) && p.y >= a.y.min(b.y) && p.y <= a.y.max(b.y)
}

/// Whether closed segments `ab` and `cd` share a point.
pub(crate) fn segments_intersect(a: Vec2, b: Vec2, c: Vec2, d: Vec2) -> bool {
    let (a, b, c, d) = (a.as_dvec2(), b.as_dvec2(), c.as_dvec2(), d.as_dvec2());
    let d1 = orient(c, d, a);
    let d2 = orient(c, d, b);
    let d3 = orient(a, b, c);
    let d4 = orient(a, b, d);
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return true;
    }
    (d1 == 0.0 && on_segment(c, d, a))
        || (d2 == 0.0 && on_segment(c, d, b))
        || (d3 == 0.0 && on_segment(a, b, c))
        || (d4 == 0.0 && on_segment(a, b, d))
}

/// The first pair of non-adjacent segments that intersect, as segment
/// indices `(i, j)` with `i < j` (segment `i` runs from point `i` to point
/// `i + 1`, wrapping for closed polygons). Consecutive duplicate points must
/// have been removed. A sweep over x keeps this near O(n log n) for sketches.
pub(crate) fn first_self_intersection(points: &[Vec2], closed: bool) -> Option<(usize, usize)> {
    let n = points.len();
    let segs = if closed { n } else { n.saturating_sub(1) };
    if segs < 2 {
        return None;
    }
    let seg = |i: usize| (points[i], points[(i + 1) % n]);
    let mut order: Vec<usize> = (0..segs).collect();
    let xmin = |i: usize| {
        let (a, b) = seg(i);
        a.x.min(b.x)
    };
    order.sort_by(|&a, &b| xmin(a).total_cmp(&xmin(b)));
    let adjacent = |i: usize, j: usize| {
        let (i, j) = (i.min(j), i.max(j));
        j == i + 1 || (closed && i == 0 && j == segs - 1)
    };
    let mut found: Option<(usize, usize)> = None;
    for (k, &i) in order.iter().enumerate() {
        let (a, b) = seg(i);
        let xmax = a.x.max(b.x);
        let (ylo, yhi) = (a.y.min(b.y), a.y.max(b.y));
        for &j in &order[k + 1..] {
            if xmin(j) > xmax {
                break;
            }
            if adjacent(i, j) {
                // Adjacent segments share a point; they only "intersect" when
                // they fold back onto each other (collinear overlap).
                let (c, d) = seg(j);
                let shared_is_b = (i + 1) % n == j;
                let (p, q, r) = if shared_is_b { (a, b, d) } else { (c, d, b) };
                let (p, q, r) = (p.as_dvec2(), q.as_dvec2(), r.as_dvec2());
                if orient(p, q, r) == 0.0 && (r - q).dot(p - q) > 0.0 {
                    let pair = (i.min(j), i.max(j));
                    found = Some(found.map_or(pair, |f| f.min(pair)));
                }
                continue;
            }
            let (c, d) = seg(j);
            if c.y.max(d.y) < ylo || c.y.min(d.y) > yhi {
                continue;
            }
            if segments_intersect(a, b, c, d) {
                let pair = (i.min(j), i.max(j));
                found = Some(found.map_or(pair, |f| f.min(pair)));
            }
        }
    }
    found
}

/// Removes consecutive duplicate points (and, for closed polygons, a last
/// point equal to the first).
pub(crate) fn dedup(points: &[Vec2], closed: bool) -> Vec<Vec2> {
    let mut out: Vec<Vec2> = Vec::with_capacity(points.len());
    for &p in points {
        if out.last() != Some(&p) {
            out.push(p);
        }
    }
    if closed {
        while out.len() > 1 && out.first() == out.last() {
            out.pop();
        }
    }
    out
}

/// Index of the topmost vertex (largest y; ties: smallest x).
pub(crate) fn topmost(points: &[Vec2]) -> usize {
    let mut best = 0;
    for (i, p) in points.iter().enumerate() {
        let b = points[best];
        if p.y > b.y || (p.y == b.y && p.x < b.x) {
            best = i;
        }
    }
    best
}

/// `n` points evenly spaced by arc length along a closed polygon, starting
/// at vertex 0.
pub(crate) fn resample_closed(points: &[Vec2], n: usize) -> Vec<Vec2> {
    let cum = cumulative(points, true);
    let total = *cum.last().unwrap_or(&0.0);
    (0..n)
        .map(|k| point_at(points, &cum, true, total * k as f32 / n as f32))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square() -> Vec<Vec2> {
        vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(0.0, 1.0),
        ]
    }

    #[test]
    fn area_hull_and_containment() {
        let sq = square();
        assert_eq!(signed_area(&sq), 1.0);
        let mut pts = sq.clone();
        pts.push(Vec2::new(0.5, 0.5));
        pts.push(Vec2::new(0.5, 0.0));
        let hull = convex_hull(&pts);
        assert_eq!(hull.len(), 4);
        let poly: Vec<Vec2> = hull.iter().map(|&i| pts[i]).collect();
        assert!(signed_area(&poly) > 0.0);
        assert!(contains(&sq, Vec2::new(0.3, 0.7)));
        assert!(!contains(&sq, Vec2::new(1.3, 0.7)));
    }

    #[test]
    fn self_intersections_are_found() {
        let bowtie = vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(0.0, 1.0),
        ];
        assert!(first_self_intersection(&bowtie, true).is_some());
        assert_eq!(first_self_intersection(&square(), true), None);
        // Open polyline that crosses itself.
        let z = vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(0.5, -1.0),
        ];
        assert!(first_self_intersection(&z, false).is_some());
        // A spike folding back onto itself.
        let fold = vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(2.0, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(1.0, 1.0),
        ];
        assert!(first_self_intersection(&fold, true).is_some());
    }

    #[test]
    fn arc_length_sampling_and_nearest() {
        let sq = square();
        let cum = cumulative(&sq, true);
        assert_eq!(*cum.last().unwrap(), 4.0);
        assert_eq!(point_at(&sq, &cum, true, 1.5), Vec2::new(1.0, 0.5));
        assert_eq!(point_at(&sq, &cum, true, 4.5), Vec2::new(0.5, 0.0));
        let (s, d) = nearest_arc(&sq, &cum, true, Vec2::new(2.0, 0.5));
        assert!((s - 1.5).abs() < 1e-6 && (d - 1.0).abs() < 1e-6);
        let rs = resample_closed(&sq, 8);
        assert_eq!(rs[2], Vec2::new(1.0, 0.0));
    }

    #[test]
    fn simplification_keeps_corners() {
        let mut pts = Vec::new();
        for i in 0..10 {
            pts.push(Vec2::new(i as f32 / 10.0, 0.0));
        }
        for i in 0..10 {
            pts.push(Vec2::new(1.0, i as f32 / 10.0));
        }
        for i in 0..10 {
            pts.push(Vec2::new(1.0 - i as f32 / 10.0, 1.0));
        }
        for i in 0..10 {
            pts.push(Vec2::new(0.0, 1.0 - i as f32 / 10.0));
        }
        let s = simplify_closed(&pts, 1e-3);
        assert_eq!(s.len(), 4);
        assert!((signed_area(&s) - 1.0).abs() < 1e-6);
    }
}
