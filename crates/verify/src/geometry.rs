//! Exact distances between points, segments and triangles (Ericson,
//! *Real-Time Collision Detection*, §5.1.5, §5.1.9 and §5.3.6), all as
//! squared distances so the hot loops take no square root.

use glam::Vec3;

/// Squared distance from `p` to the closest point of triangle `[a, b, c]`
/// (Ericson 5.1.5: Voronoi regions of vertices, edges and face). Exact for
/// degenerate triangles too (they reduce to segments or points).
pub fn point_triangle_sq(p: Vec3, [a, b, c]: [Vec3; 3]) -> f32 {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return p.distance_squared(a);
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return p.distance_squared(b);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return p.distance_squared(a + ab * (d1 / (d1 - d3)));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return p.distance_squared(c);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return p.distance_squared(a + ac * (d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return p.distance_squared(b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))));
    }
    let sum = va + vb + vc;
    if sum.abs() <= f32::MIN_POSITIVE {
        // A degenerate triangle whose regions tests all failed through
        // rounding: it is its edges.
        return segment_point_sq(p, a, b)
            .min(segment_point_sq(p, b, c))
            .min(segment_point_sq(p, c, a));
    }
    let denom = 1.0 / sum;
    p.distance_squared(a + ab * (vb * denom) + ac * (vc * denom))
}

/// Squared distance from `p` to segment `ab`.
pub fn segment_point_sq(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let ab = b - a;
    let len2 = ab.length_squared();
    let t = if len2 > 0.0 {
        ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    p.distance_squared(a + ab * t)
}

pub use treemorph_tree::geom::segment_segment_sq;

/// Whether segment `pq` crosses triangle `[a, b, c]` (Ericson 5.3.6, both
/// faces). Parallel and coplanar segments answer `false`: where they touch
/// the triangle, an endpoint or an edge distance is zero instead.
fn segment_crosses_triangle(p: Vec3, q: Vec3, [a, b, c]: [Vec3; 3]) -> bool {
    let (ab, ac) = (b - a, c - a);
    let n = ab.cross(ac);
    let (mut p, mut q) = (p, q);
    let mut d = (p - q).dot(n);
    if d.abs() <= f32::MIN_POSITIVE {
        return false;
    }
    // Ericson's test is one-sided: run the segment toward the back face.
    if d < 0.0 {
        std::mem::swap(&mut p, &mut q);
        d = -d;
    }
    let (qp, ap) = (p - q, p - a);
    let t = ap.dot(n);
    if t < 0.0 || t > d {
        return false;
    }
    let e = qp.cross(ap);
    let v = ac.dot(e);
    if v < 0.0 || v > d {
        return false;
    }
    let w = -ab.dot(e);
    w >= 0.0 && v + w <= d
}

/// Squared distance between segment `pq` and triangle `t`: zero when it
/// crosses the triangle, else the nearest of its endpoints to the triangle
/// and of the segment to the triangle's edges (the closest pair of a
/// segment and a triangle that do not meet always involves one of those).
pub fn segment_triangle_sq(p: Vec3, q: Vec3, t: [Vec3; 3]) -> f32 {
    if segment_crosses_triangle(p, q, t) {
        return 0.0;
    }
    let [a, b, c] = t;
    point_triangle_sq(p, t)
        .min(point_triangle_sq(q, t))
        .min(segment_segment_sq(p, q, a, b))
        .min(segment_segment_sq(p, q, b, c))
        .min(segment_segment_sq(p, q, c, a))
}

/// Squared distance between two triangles: the nearest of each one's edges
/// to the other (when two triangles meet, an edge of one crosses the
/// other; when they do not, the closest pair is vertex–face or edge–edge).
pub fn triangle_triangle_sq(s: [Vec3; 3], t: [Vec3; 3]) -> f32 {
    let mut best = f32::INFINITY;
    for (x, y) in [(s, t), (t, s)] {
        for k in 0..3 {
            best = best.min(segment_triangle_sq(x[k], x[(k + 1) % 3], y));
            if best == 0.0 {
                return 0.0;
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: [Vec3; 3] = [Vec3::ZERO, Vec3::X, Vec3::Y];

    #[test]
    fn point_regions() {
        assert_eq!(point_triangle_sq(Vec3::new(0.2, 0.2, 2.0), T), 4.0);
        assert_eq!(point_triangle_sq(Vec3::new(-1.0, -1.0, 0.0), T), 2.0);
        assert!((point_triangle_sq(Vec3::new(0.5, -1.0, 0.0), T) - 1.0).abs() < 1e-6);
        assert!((point_triangle_sq(Vec3::new(1.0, 1.0, 0.0), T) - 0.5).abs() < 1e-6);
        // Degenerate triangle: a segment.
        let line = [Vec3::ZERO, Vec3::X, Vec3::X * 2.0];
        assert!((point_triangle_sq(Vec3::new(1.0, 1.0, 0.0), line) - 1.0).abs() < 1e-6);
    }

    #[test]
    fn segments() {
        let d = segment_segment_sq(
            Vec3::ZERO,
            Vec3::X,
            Vec3::new(0.5, 1.0, -1.0),
            Vec3::new(0.5, 1.0, 1.0),
        );
        assert!((d - 1.0).abs() < 1e-6);
        // Crossing the face: zero, both directions of travel.
        let (p, q) = (Vec3::new(0.2, 0.2, -1.0), Vec3::new(0.2, 0.2, 1.0));
        assert_eq!(segment_triangle_sq(p, q, T), 0.0);
        assert_eq!(segment_triangle_sq(q, p, T), 0.0);
        // Passing beside it: the edge distance.
        let (p, q) = (Vec3::new(2.0, 0.0, -1.0), Vec3::new(2.0, 0.0, 1.0));
        assert!((segment_triangle_sq(p, q, T) - 1.0).abs() < 1e-6);
        // Stopping short of it: the endpoint distance.
        let (p, q) = (Vec3::new(0.2, 0.2, -1.0), Vec3::new(0.2, 0.2, -0.5));
        assert!((segment_triangle_sq(p, q, T) - 0.25).abs() < 1e-6);
    }

    #[test]
    fn triangles() {
        // One pierces the other through its middle: no edge of the pierced
        // triangle touches the piercing one.
        let big = [
            Vec3::new(-5.0, -5.0, 0.0),
            Vec3::new(5.0, -5.0, 0.0),
            Vec3::new(0.0, 5.0, 0.0),
        ];
        let spike = [
            Vec3::new(0.0, 0.0, -1.0),
            Vec3::new(0.1, 0.0, 1.0),
            Vec3::new(-0.1, 0.0, 1.0),
        ];
        assert_eq!(triangle_triangle_sq(big, spike), 0.0);
        assert_eq!(triangle_triangle_sq(spike, big), 0.0);
        let lifted = spike.map(|v| v + Vec3::Z * 3.0);
        assert!((triangle_triangle_sq(big, lifted) - 4.0).abs() < 1e-5);
    }
}
