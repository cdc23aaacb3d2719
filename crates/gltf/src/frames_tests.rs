use glam::{Quat, Vec2, Vec3};
use proptest::prelude::*;
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_tree::{Aabb, Frame};

use super::*;
use crate::bench::Sway;
use crate::contour::LeafContour;
use crate::mesh::{LeafShape, MeshBuffers, bounds_of};

fn contour(points: u32) -> MeshOptions {
    MeshOptions {
        leaf_shape: LeafShape::Contour { points },
        ..MeshOptions::default()
    }
}

fn maple_sway() -> Sway {
    let tree = generate(&GenerateOptions::new(Preset::Maple, 5).with_size(3000)).unwrap();
    Sway::new(&tree, 5)
}

fn mesh_with_threads(
    threads: usize,
    sway: &Sway,
    options: &MeshOptions,
) -> (MeshBuffers, MeshBuffers) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| {
        let mut meshes =
            FrameMeshes::new(sway.topology(), sway.reference_radii(), options).unwrap();
        meshes.set_uv_frame(&sway.frame(0)).unwrap();
        let (b, l) = meshes.mesh(&sway.frame(3)).unwrap();
        (b.clone(), l.clone())
    })
}

#[test]
fn parallel_meshing_does_not_depend_on_the_thread_count() {
    let sway = maple_sway();
    for options in [MeshOptions::default(), contour(24)] {
        let one = mesh_with_threads(1, &sway, &options);
        for threads in [2, 5] {
            assert!(
                mesh_with_threads(threads, &sway, &options) == one,
                "{threads} threads"
            );
        }
        // Several batches of strands and of leaves were meshed.
        assert!(one.0.positions.len() > 16_384, "{}", one.0.positions.len());
        assert!(sway.topology().leaves.len() > 2 * 2048);
    }
}

#[test]
fn bounds_are_the_exact_extremes() {
    let sway = maple_sway();
    let mut meshes =
        FrameMeshes::new(sway.topology(), sway.reference_radii(), &contour(12)).unwrap();
    let (b, l) = meshes.mesh(&sway.frame(2)).unwrap();
    for mesh in [b, l] {
        let naive = Aabb::of_points(mesh.positions.iter().copied());
        assert_eq!(mesh.bounds, naive);
    }
    for n in 0..9 {
        let points: Vec<Vec3> = (0..n)
            .map(|i| Vec3::new(i as f32, -(i as f32), (i % 3) as f32))
            .collect();
        assert_eq!(
            bounds_of(&points),
            Aabb::of_points(points.iter().copied()),
            "{n} points"
        );
    }
}

#[test]
fn contour_leaves_morph_between_their_materials_outlines() {
    let sway = maple_sway();
    let topology = sway.topology();
    let mut meshes = FrameMeshes::new(topology, sway.reference_radii(), &contour(16)).unwrap();
    let contours: Vec<LeafContour> = meshes.leaves().contours().to_vec();
    assert_eq!(contours.len(), topology.leaf_materials.len());
    let mut frame = sway.frame(0);
    for (i, leaf) in frame.leaves.iter_mut().enumerate() {
        leaf.blend = (i % 3) as f32 * 0.5;
        leaf.orientation = Quat::from_rotation_y(0.3 * i as f32);
    }
    let (_, l) = meshes.mesh(&frame).unwrap();
    assert_eq!(l.vertex_count(), 17 * topology.leaves.len());
    assert_eq!(l.indices.len(), 3 * 16 * topology.leaves.len());
    for (i, (leaf, top)) in frame.leaves.iter().zip(&topology.leaves).enumerate() {
        let [a, b] = top.materials.map(|m| &contours[m as usize]);
        let mut fan = vec![Vec2::ZERO; 17];
        a.lerp_fan(b, leaf.blend, &mut fan);
        let q = leaf.orientation;
        for (k, p) in fan.iter().enumerate() {
            let want = leaf.anchor + q * Vec3::new(p.x * leaf.width, p.y * leaf.height, 0.0);
            let got = l.positions[i * 17 + k];
            assert!(
                got.abs_diff_eq(want, 1e-5),
                "leaf {i} vertex {k}: {got} vs {want}"
            );
            assert!(l.normals[i * 17 + k].abs_diff_eq(q * Vec3::Z, 1e-5));
            // UVs are the first material's outline in every frame.
            assert_eq!(l.uvs[i * 17 + k], LeafContour::uv(a.fan().nth(k).unwrap()));
        }
    }
    // Every fan triangle faces the leaf's normal (counter-clockwise seen
    // from its front), at every blend.
    for tri in l.indices.chunks_exact(3) {
        let [p0, p1, p2] = [0, 1, 2].map(|k| l.positions[tri[k] as usize]);
        let n = l.normals[tri[0] as usize];
        assert!((p1 - p0).cross(p2 - p0).dot(n) > 0.0, "{tri:?}");
    }
}

#[test]
fn reference_radii_are_the_maximum_over_a_sequence() {
    let sway = maple_sway();
    let frames: Vec<Frame> = (0..3)
        .map(|i| {
            let mut f = sway.frame(i);
            f.radii[1] = i as f32;
            f.radii[2] = f32::NAN;
            f
        })
        .collect();
    let r = max_radii(&frames);
    assert_eq!(r.len(), frames[0].radii.len());
    assert_eq!(r[1], 2.0);
    assert_eq!(r[2], 0.0);
    assert_eq!(r[0], frames[0].radii[0]);
    assert!(max_radii(&[]).is_empty());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Whatever the leaves do — zero size, any blend, sloppy rotations —
    /// contour meshes stay finite with the topology's layout.
    #[test]
    fn any_leaves_mesh_finitely(
        seed in 0u64..1000,
        scale in prop::sample::select(vec![0.0f32, 1e-6, 1.0, 1e3]),
        blend in prop::sample::select(vec![0.0f32, 0.3, 1.0, f32::NAN]),
        w in -1.0f32..1.0,
    ) {
        let tree = generate(&GenerateOptions::new(Preset::Shrub, seed).with_size(60)).unwrap();
        let sway = Sway::new(&tree, 2);
        let mut meshes = FrameMeshes::new(sway.topology(), sway.reference_radii(), &contour(8)).unwrap();
        let mut frame = sway.frame(1);
        for leaf in &mut frame.leaves {
            leaf.width *= scale;
            leaf.height *= scale;
            leaf.blend = blend;
            leaf.orientation = Quat::from_xyzw(w, 0.0, 0.0, 0.0);
        }
        let n = meshes.leaves().vertex_count();
        let (_, l) = meshes.mesh(&frame).unwrap();
        prop_assert_eq!(l.positions.len(), n);
        prop_assert!(l.positions.iter().all(|p| p.is_finite()));
        prop_assert!(l.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-4));
    }
}
