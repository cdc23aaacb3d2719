//! 2D mean value coordinates (Floater 2003; Hormann & Floater 2006, *Mean
//! value coordinates for arbitrary planar polygons*).
//!
//! For a point `x` and a closed polygon `v_0 … v_{n-1}`, with
//! `s_i = v_i − x`, `r_i = |s_i|` and `α_i` the signed angle between `s_i`
//! and `s_{i+1}`, the unnormalised weights are
//! `w_i = (tan(α_{i−1}/2) + tan(α_i/2)) / r_i` and the coordinates are
//! `λ_i = w_i / Σ w_j`. They reproduce linear functions
//! (`Σ λ_i v_i = x`, `Σ λ_i = 1`) everywhere the sum is non-zero, inside and
//! outside the polygon, which is what lets a cage carry the points it
//! encloses.
//!
//! Robustness choices:
//! - `tan(α/2)` is evaluated as `(r_i r_{i+1} − D_i) / (2A_i)` when the angle
//!   is obtuse and as `2A_i / (r_i r_{i+1} + D_i)` otherwise (`A_i` the signed
//!   triangle area, `D_i` the dot product), so neither form divides by a
//!   vanishing quantity except on the boundary itself;
//! - a point on a vertex (within `1e-9` of the cage size) gets that vertex's
//!   unit weight; a point on an edge gets the edge's linear interpolation
//!   weights — MVC's continuous limit there;
//! - in the rare exterior spots where `Σ w` vanishes (only possible outside
//!   a non-convex cage) the point is carried by its nearest boundary point's
//!   weights, i.e. it moves rigidly with the nearest edge. Our rest cages are
//!   convex silhouettes, so this never happens for them.
//!
//! All arithmetic is in `f64`.

use glam::{DVec2, Vec2};
use treemorph_tree::geom::closest_on_segment;

/// Writes the mean value coordinates of `p` with respect to `cage` into
/// `out` (`out.len() == cage.len()`). The cage needs ≥ 3 vertices.
pub(crate) fn coordinates(cage: &[Vec2], p: Vec2, out: &mut [f32]) {
    SCRATCH.with_borrow_mut(|scratch| coordinates_with(cage, p, out, scratch));
}

/// Per-thread buffers of [`coordinates`]: the plan computes coordinates
/// for every node and cage vertex, tens of thousands of calls, which
/// allocated four vectors each.
#[derive(Default)]
struct Scratch {
    s: Vec<DVec2>,
    r: Vec<f64>,
    tans: Vec<f64>,
    w: Vec<f64>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::default();
}

fn coordinates_with(cage: &[Vec2], p: Vec2, out: &mut [f32], scratch: &mut Scratch) {
    let n = cage.len();
    debug_assert_eq!(out.len(), n);
    let x = p.as_dvec2();
    let scale = cage
        .iter()
        .map(|v| v.as_dvec2().distance(x))
        .fold(0.0f64, f64::max)
        .max(1e-30);
    let eps = 1e-9 * scale;
    let Scratch { s, r, tans, w } = scratch;
    s.clear();
    r.clear();
    tans.clear();
    w.clear();
    for v in cage {
        let si = v.as_dvec2() - x;
        let ri = si.length();
        s.push(si);
        r.push(ri);
    }
    out.fill(0.0);
    // On a vertex.
    if let Some(i) = (0..n).find(|&i| r[i] <= eps) {
        out[i] = 1.0;
        return;
    }
    // tan(α_i / 2) for each edge i → i+1; on an edge, interpolate.
    for i in 0..n {
        let j = (i + 1) % n;
        let a = s[i].perp_dot(s[j]); // 2 × signed area
        let d = s[i].dot(s[j]);
        let rr = r[i] * r[j];
        if a.abs() <= eps * (r[i] + r[j]) && d < 0.0 {
            let f = r[i] / (r[i] + r[j]);
            out[i] = (1.0 - f) as f32;
            out[j] = f as f32;
            return;
        }
        let t = if d < 0.0 { (rr - d) / a } else { a / (rr + d) };
        tans.push(t);
    }
    let mut sum = 0.0;
    let mut abs_sum = 0.0;
    for i in 0..n {
        let prev = tans[(i + n - 1) % n];
        let wi = (prev + tans[i]) / r[i];
        sum += wi;
        abs_sum += wi.abs();
        w.push(wi);
    }
    if sum.abs() <= 1e-9 * abs_sum || !sum.is_finite() {
        nearest_boundary(cage, x, out);
        return;
    }
    for i in 0..n {
        out[i] = (w[i] / sum) as f32;
    }
}

/// Linear-interpolation weights of the boundary point nearest to `x`.
fn nearest_boundary(cage: &[Vec2], x: DVec2, out: &mut [f32]) {
    let n = cage.len();
    let mut best = (f64::INFINITY, 0usize, 0.0f64);
    for i in 0..n {
        let a = cage[i].as_dvec2();
        let b = cage[(i + 1) % n].as_dvec2();
        let (q, f) = closest_on_segment(x, a, b);
        let d = q.distance_squared(x);
        if d < best.0 {
            best = (d, i, f);
        }
    }
    out.fill(0.0);
    let (_, i, f) = best;
    out[i] = (1.0 - f) as f32;
    out[(i + 1) % n] += f as f32;
}

/// `Σ λ_i v_i`.
pub(crate) fn apply(weights: &[f32], values: &[Vec2]) -> Vec2 {
    weights
        .iter()
        .zip(values)
        .fold(Vec2::ZERO, |acc, (&w, &v)| acc + v * w)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn hexagon() -> Vec<Vec2> {
        (0..6)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / 6.0;
                Vec2::new(a.cos() * 2.0 + 0.3, a.sin() * 1.5 - 0.2)
            })
            .collect()
    }

    fn star() -> Vec<Vec2> {
        (0..10)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / 10.0;
                let r = if i % 2 == 0 { 1.0 } else { 0.45 };
                Vec2::new(a.cos() * r, a.sin() * r)
            })
            .collect()
    }

    #[test]
    fn cage_vertices_get_unit_weights() {
        for cage in [hexagon(), star()] {
            let mut w = vec![0.0; cage.len()];
            for (i, &v) in cage.iter().enumerate() {
                coordinates(&cage, v, &mut w);
                for (k, &wk) in w.iter().enumerate() {
                    assert_eq!(wk, if k == i { 1.0 } else { 0.0 });
                }
            }
        }
    }

    #[test]
    fn edge_points_interpolate_their_edge() {
        let cage = hexagon();
        let mut w = vec![0.0; 6];
        let p = cage[2].lerp(cage[3], 0.25);
        coordinates(&cage, p, &mut w);
        assert!((w[2] - 0.75).abs() < 1e-5 && (w[3] - 0.25).abs() < 1e-5);
        assert!((apply(&w, &cage) - p).length() < 1e-5);
    }

    proptest! {
        #[test]
        fn reproduces_linear_functions(x in -3.0f32..3.0, y in -3.0f32..3.0, use_star in any::<bool>()) {
            let cage = if use_star { star() } else { hexagon() };
            let p = Vec2::new(x, y);
            let mut w = vec![0.0; cage.len()];
            coordinates(&cage, p, &mut w);
            let sum: f32 = w.iter().sum();
            prop_assert!((sum - 1.0).abs() < 1e-4, "sum {}", sum);
            // A linear function f(v) = 2x − 3y + 1 is reproduced too.
            let f = |v: Vec2| 2.0 * v.x - 3.0 * v.y + 1.0;
            let fp: f32 = w.iter().zip(&cage).map(|(&wi, &v)| wi * f(v)).sum();
            // Exterior points far from a cage have large, cancelling weights.
            let tol = 1e-3 * (1.0 + w.iter().map(|v| v.abs()).sum::<f32>());
            prop_assert!((apply(&w, &cage) - p).length() < tol);
            prop_assert!((fp - f(p)).abs() < 5.0 * tol);
        }

        #[test]
        fn interior_weights_of_a_convex_cage_are_positive(u in 0.01f32..0.99, v in 0.01f32..0.99) {
            let cage = hexagon();
            // Points inside: convex combination of the centre and a vertex.
            let c = cage.iter().copied().sum::<Vec2>() / 6.0;
            let k = ((u * 6.0) as usize).min(5);
            let p = c.lerp(cage[k].lerp(cage[(k + 1) % 6], v), u);
            let mut w = vec![0.0; 6];
            coordinates(&cage, p, &mut w);
            prop_assert!(w.iter().all(|&x| x >= 0.0));
        }
    }
}
