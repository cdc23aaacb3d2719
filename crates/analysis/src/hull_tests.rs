use std::collections::HashMap;

use glam::Vec3;
use proptest::prelude::*;

use super::*;

/// Every edge appears exactly once in each direction (closed, consistently
/// oriented 2-manifold) and V − E + F = 2.
fn assert_closed_sphere(h: &Hull) {
    let mut edges: HashMap<(u32, u32), u32> = HashMap::new();
    for t in &h.triangles {
        for k in 0..3 {
            *edges.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
        }
    }
    for (&(a, b), &n) in &edges {
        assert_eq!(n, 1, "directed edge {a}->{b} used {n} times");
        assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}->{b} has no twin");
    }
    let v = h.vertices.len() as i64;
    let e = edges.len() as i64 / 2;
    let f = h.triangles.len() as i64;
    assert_eq!(v - e + f, 2, "Euler characteristic");
    assert!(
        h.volume() > 0.0,
        "outward orientation gives positive volume"
    );
}

fn cube_points() -> Vec<Vec3> {
    let mut pts = Vec::new();
    for x in [0.0, 1.0] {
        for y in [0.0, 1.0] {
            for z in [0.0, 1.0] {
                pts.push(Vec3::new(x, y, z));
            }
        }
    }
    pts.push(Vec3::splat(0.5));
    pts.push(Vec3::new(0.2, 0.7, 0.4));
    pts
}

#[test]
fn convex_hull_of_a_cube_has_its_corners_and_unit_volume() {
    let h = Hull::convex(&cube_points(), 0.01);
    assert_closed_sphere(&h);
    assert_eq!(h.vertices.len(), 8, "interior points are dropped");
    assert!((h.volume() - 1.0).abs() < 1e-5);
    assert!(h.contains(Vec3::splat(0.5), 0.0));
    assert!(!h.contains(Vec3::new(1.2, 0.5, 0.5), 1e-3));
}

#[test]
fn empty_points_give_an_empty_hull() {
    let h = Hull::convex(&[], 0.1);
    assert!(h.is_empty());
    assert!(Hull::radial(&[], 0.1, 4, 8).is_empty());
}

#[test]
fn degenerate_sets_are_inflated_into_closed_shapes() {
    let single = [Vec3::new(1.0, 2.0, 3.0)];
    let line = [Vec3::ZERO, Vec3::X, Vec3::X * 2.0];
    let plane = [
        Vec3::ZERO,
        Vec3::X,
        Vec3::Z,
        Vec3::new(1.0, 0.0, 1.0),
        Vec3::new(0.5, 0.0, 0.3),
    ];
    for pts in [&single[..], &line[..], &plane[..]] {
        let h = Hull::convex(pts, 0.05);
        assert_closed_sphere(&h);
        for &p in pts {
            assert!(h.contains(p, 1e-5), "{p} inside");
        }
    }
    let h = Hull::convex(&single, 0.05);
    assert!(
        (h.volume() - 4.0 / 3.0 * 0.05f32.powi(3)).abs() < 1e-6,
        "octahedron of radius 0.05"
    );
}

#[test]
fn radial_hull_is_closed_and_tighter_than_convex_on_a_dumbbell() {
    // Two sub-crowns joined by a thin stem of points: the convex hull is a
    // capsule, the radial hull pinches at the waist.
    let mut pts = Vec::new();
    for i in 0..400 {
        let f = i as f32;
        let d =
            Vec3::new((f * 0.61).sin(), (f * 1.37).cos(), (f * 0.29).sin()).normalize_or(Vec3::X);
        let side = if i % 2 == 0 { 1.0 } else { -1.0 };
        pts.push(Vec3::new(side, 0.0, 0.0) + d * 0.4 * ((i % 7) as f32 / 6.0));
    }
    for i in 0..=20 {
        pts.push(Vec3::new(-1.0 + i as f32 * 0.1, 0.0, 0.0));
    }
    let convex = Hull::convex(&pts, 0.01);
    let radial = Hull::radial(&pts, 0.01, 8, 16);
    assert_closed_sphere(&radial);
    for &p in &pts {
        assert!(radial.contains(p, 1e-4), "{p} inside the radial hull");
        assert!(convex.contains(p, 1e-4), "{p} inside the convex hull");
    }
    assert!(
        radial.volume() < convex.volume(),
        "{} < {}",
        radial.volume(),
        convex.volume()
    );
}

#[test]
fn hausdorff_of_identical_hulls_is_zero_and_of_shifted_is_the_shift() {
    let a = Hull::convex(&cube_points(), 0.01);
    let mut b = a.clone();
    for v in &mut b.vertices {
        *v += Vec3::new(0.0, 3.0, 0.0);
    }
    assert_eq!(a.hausdorff(&a), 0.0);
    // Each shifted corner's nearest original corner is 2 m away (top face
    // of the cube), the worst is 3 m.
    assert!((a.hausdorff(&b) - 3.0).abs() < 1e-5, "{}", a.hausdorff(&b));
    assert_eq!(a.hausdorff(&Hull::default()), f32::INFINITY);
    assert_eq!(Hull::default().hausdorff(&Hull::default()), 0.0);
}

#[test]
fn hausdorff_with_a_kdtree_matches_brute_force() {
    let pts: Vec<Vec3> = (0..400)
        .map(|i| {
            let f = i as f32;
            Vec3::new((f * 0.37).sin(), (f * 0.91).cos(), (f * 0.13).sin() * 2.0)
        })
        .collect();
    let qs: Vec<Vec3> = pts.iter().map(|p| *p * 1.3 + Vec3::X * 0.2).collect();
    let fast = directed_hausdorff(&pts, &qs);
    let slow = pts
        .iter()
        .map(|p| {
            qs.iter()
                .map(|q| p.distance(*q))
                .fold(f32::INFINITY, f32::min)
        })
        .fold(0.0f32, f32::max);
    assert!((fast - slow).abs() < 1e-5, "{fast} vs {slow}");
}

fn point_cloud() -> impl Strategy<Value = Vec<Vec3>> {
    prop::collection::vec(
        (-10.0f32..10.0, -10.0f32..10.0, -10.0f32..10.0).prop_map(|(x, y, z)| Vec3::new(x, y, z)),
        1..200,
    )
}

proptest! {
    #[test]
    fn convex_hull_is_closed_and_contains_its_points(pts in point_cloud()) {
        let h = Hull::convex(&pts, 0.05);
        assert_closed_sphere(&h);
        for &p in &pts {
            prop_assert!(h.contains(p, 1e-3), "{} outside", p);
        }
        // Convexity: every vertex is behind every face plane.
        for t in &h.triangles {
            let [a, b, c] = t.map(|i| h.vertices[i as usize]);
            let n = (b - a).cross(c - a).normalize_or_zero();
            for v in &h.vertices {
                prop_assert!(n.dot(*v - a) <= 1e-3);
            }
        }
    }

    #[test]
    fn coplanar_grids_are_handled(n in 1usize..30, y in -5.0f32..5.0) {
        let pts: Vec<Vec3> = (0..n).map(|i| Vec3::new((i % 5) as f32, y, (i / 5) as f32)).collect();
        let h = Hull::convex(&pts, 0.1);
        assert_closed_sphere(&h);
        for &p in &pts {
            prop_assert!(h.contains(p, 1e-3));
        }
    }

    #[test]
    fn radial_hull_contains_its_points(pts in point_cloud()) {
        let h = Hull::radial(&pts, 0.05, 6, 12);
        assert_closed_sphere(&h);
        for &p in &pts {
            prop_assert!(h.contains(p, 1e-3), "{} outside", p);
        }
    }
}
