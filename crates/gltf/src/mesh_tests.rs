use glam::{Quat, Vec3};
use proptest::prelude::*;
use treemorph_tree::{
    Frame, FrameTopology, Leaf, LeafMaterial, Limits, Materials, Node, Strands, Tree, TreeParts,
};

use super::*;
use crate::sample;

fn node(x: f32, y: f32, z: f32, radius: f32, parent: Option<u32>) -> Node {
    Node {
        position: Vec3::new(x, y, z),
        radius,
        parent,
    }
}

/// A trunk of three branches forking at node 2 into a side branch, with
/// three leaves of two materials.
fn fork() -> Tree {
    let leaf = |branch: u32, material: u32| Leaf {
        branch,
        t: 0.5,
        offset: Vec3::new(0.05, 0.0, 0.0),
        width: 0.1,
        height: 0.2,
        orientation: Quat::from_rotation_z(0.3),
        material,
    };
    Tree::new(
        TreeParts {
            name: "fork".into(),
            nodes: vec![
                node(0.0, 0.0, 0.0, 0.2, None),
                node(0.0, 1.0, 0.0, 0.15, Some(0)),
                node(0.1, 2.0, 0.0, 0.12, Some(1)),
                node(0.1, 3.0, 0.2, 0.08, Some(2)),
                node(0.8, 2.6, 0.0, 0.05, Some(2)),
                node(1.4, 3.0, 0.1, 0.03, Some(4)),
            ],
            leaves: vec![leaf(3, 1), leaf(5, 0), leaf(4, 1)],
            materials: Materials {
                leaves: vec![
                    LeafMaterial {
                        name: "ovate".into(),
                        color: [1.0; 4],
                        texture: Some(sample::leaf_texture()),
                    },
                    LeafMaterial {
                        name: "plain".into(),
                        color: [0.2, 0.6, 0.1, 1.0],
                        texture: None,
                    },
                ],
                ..Materials::default()
            },
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap()
}

fn meshers(tree: &Tree) -> (FrameTopology, Frame, BranchMesher, LeafMesher) {
    let topology = FrameTopology::of_tree(tree);
    let frame = Frame::of_tree(tree);
    let options = MeshOptions::default();
    let branches = BranchMesher::new(&topology, &frame.radii, &frame, &options).unwrap();
    let leaves = LeafMesher::new(&topology, &options).unwrap();
    (topology, frame, branches, leaves)
}

/// Everything a valid mesh satisfies whatever the frame.
fn assert_well_formed(mesh: &MeshBuffers) {
    let n = mesh.positions.len();
    assert_eq!(mesh.normals.len(), n);
    assert_eq!(mesh.uvs.len(), n);
    assert_eq!(mesh.indices.len() % 3, 0);
    assert!(mesh.indices.iter().all(|&i| (i as usize) < n));
    assert!(mesh.positions.iter().all(|p| p.is_finite()));
    for (i, normal) in mesh.normals.iter().enumerate() {
        assert!(
            (normal.length() - 1.0).abs() < 1e-4,
            "normal {i} is {normal} (length {})",
            normal.length()
        );
    }
    assert!(
        mesh.uvs
            .iter()
            .all(|uv| uv.is_finite() && (0.0..=1.0).contains(&uv.x) && uv.y >= 0.0)
    );
    let mut covered = 0;
    for g in &mesh.groups {
        assert_eq!(g.first_index, covered);
        assert_eq!(g.index_count % 3, 0);
        covered += g.index_count;
    }
    assert_eq!(covered as usize, mesh.indices.len());
    let bounds = Aabb::of_points(mesh.positions.iter().copied());
    assert_eq!(mesh.bounds, bounds);
}

/// The same frame with every position moved and every radius changed.
fn distorted(frame: &Frame, radius_scale: f32) -> Frame {
    let mut f = frame.clone();
    for (i, p) in f.positions.iter_mut().enumerate() {
        *p += Vec3::new((i as f32).sin(), 0.3 * i as f32, (i as f32 * 0.7).cos()) * 0.2;
    }
    for r in &mut f.radii {
        *r *= radius_scale;
    }
    for l in &mut f.leaves {
        l.width *= radius_scale;
        l.height *= radius_scale;
        l.anchor += Vec3::X;
    }
    f
}

#[test]
fn counts_indices_and_uvs_depend_on_the_topology_only() {
    let tree = sample::sample_tree(200);
    let (_, frame, mut branches, mut leaves) = meshers(&tree);
    let first_b = branches.mesh(&frame).unwrap().clone();
    let first_l = leaves.mesh(&frame).unwrap().clone();
    assert!(first_b.vertex_count() > 0 && first_l.vertex_count() > 0);
    for scale in [0.0, 0.5, 3.0] {
        let other = distorted(&frame, scale);
        let b = branches.mesh(&other).unwrap();
        assert_well_formed(b);
        assert_eq!(b.positions.len(), first_b.positions.len());
        assert_eq!(b.indices, first_b.indices);
        assert_eq!(b.uvs, first_b.uvs);
        assert_eq!(b.groups, first_b.groups);
        assert_ne!(b.positions, first_b.positions);
        let l = leaves.mesh(&other).unwrap();
        assert_well_formed(l);
        assert_eq!(l.positions.len(), first_l.positions.len());
        assert_eq!(l.indices, first_l.indices);
        assert_eq!(l.uvs, first_l.uvs);
    }
    // Meshing the first frame again gives the first mesh again.
    assert_eq!(branches.mesh(&frame).unwrap(), &first_b);
    assert_eq!(leaves.mesh(&frame).unwrap(), &first_l);
}

#[test]
fn static_tree_meshes_are_well_formed() {
    for tree in [fork(), sample::sample_tree(500)] {
        let (_, frame, mut branches, mut leaves) = meshers(&tree);
        assert_well_formed(branches.mesh(&frame).unwrap());
        assert_well_formed(leaves.mesh(&frame).unwrap());
    }
}

/// Rings sit at their node, at the node's radius, perpendicular to the
/// strand; the seam column repeats the first.
#[test]
fn rings_respect_node_radii_and_are_perpendicular_to_the_strand() {
    let tree = fork();
    let (topology, frame, mut branches, _) = meshers(&tree);
    let mesh = branches.mesh(&frame).unwrap().clone();
    for plan in &branches.plans {
        let a = plan.first_node as usize;
        let ids = &branches.nodes[a..a + plan.node_count as usize];
        let stride = plan.sides as usize + 1;
        for (i, &id) in ids.iter().enumerate() {
            let centre = frame.positions[id as usize];
            let expected = BranchMesher::ring_radius(plan, ids, &frame.radii, i);
            let neighbour = if i + 1 < ids.len() {
                ids[i + 1]
            } else {
                ids[i - 1]
            };
            let axis = (frame.positions[neighbour as usize] - centre).normalize();
            let ring = plan.first_vertex as usize + i * stride;
            for j in 0..stride {
                let offset = mesh.positions[ring + j] - centre;
                assert!((offset.length() - expected).abs() < 1e-5);
                assert!((offset.normalize() - mesh.normals[ring + j]).length() < 1e-4);
                // Perpendicular to the tangent, which at the ends is the
                // segment direction.
                if i == 0 || i + 1 == ids.len() {
                    assert!(offset.dot(axis).abs() < 1e-5);
                }
            }
            assert_eq!(mesh.positions[ring], mesh.positions[ring + stride - 1]);
            assert_eq!(mesh.uvs[ring].x, 0.0);
            assert_eq!(mesh.uvs[ring + stride - 1].x, 1.0);
        }
    }
    assert_eq!(branches.tube_count(), topology.strands.len());
}

#[test]
fn child_strands_start_with_their_own_radius() {
    let tree = fork();
    let (topology, frame, mut branches, _) = meshers(&tree);
    let lines: Vec<Vec<u32>> = topology.strands.iter().map(<[u32]>::to_vec).collect();
    assert_eq!(lines, vec![vec![0, 1, 2, 3], vec![2, 4, 5]]);
    let mesh = branches.mesh(&frame).unwrap().clone();
    let child = &branches.plans[1];
    assert!(child.child && !branches.plans[0].child);
    let first_ring = mesh.positions[child.first_vertex as usize];
    // Node 2 (the junction) has radius 0.12; the child's own is 0.05.
    assert!((first_ring.distance(frame.positions[2]) - 0.05).abs() < 1e-6);
    // Only the trunk has a base cap.
    assert_eq!(
        branches.vertex_count(),
        4 * (branches.plans[0].sides as usize + 1) + 2 + 3 * (child.sides as usize + 1) + 1
    );
}

#[test]
fn thick_strands_get_more_sides() {
    let (_, _, branches, _) = meshers(&fork());
    let options = MeshOptions::default();
    assert_eq!(branches.plans[0].sides, options.max_sides);
    let child = branches.plans[1].sides;
    assert!(
        child > options.min_sides && child < options.max_sides,
        "{child}"
    );
}

#[test]
fn faces_point_outwards() {
    let tree = fork();
    let (_, frame, mut branches, mut leaves) = meshers(&tree);
    for mesh in [
        branches.mesh(&frame).unwrap().clone(),
        leaves.mesh(&frame).unwrap().clone(),
    ] {
        for tri in mesh.indices.chunks_exact(3) {
            let [a, b, c] = [0, 1, 2].map(|k| mesh.positions[tri[k] as usize]);
            let face = (b - a).cross(c - a);
            if face.length() < 1e-9 {
                continue;
            }
            let normal = mesh.normals[tri[0] as usize]
                + mesh.normals[tri[1] as usize]
                + mesh.normals[tri[2] as usize];
            assert!(face.dot(normal) > 0.0, "triangle {tri:?} faces inwards");
        }
    }
}

#[test]
fn straight_strands_do_not_twist() {
    let tree = Tree::new(
        TreeParts {
            nodes: (0..6)
                .map(|i| {
                    node(
                        0.3 * i as f32,
                        i as f32,
                        0.1 * i as f32,
                        0.1,
                        (i > 0).then(|| i - 1),
                    )
                })
                .collect(),
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap();
    let (_, frame, mut branches, _) = meshers(&tree);
    let stride = branches.plans[0].sides as usize + 1;
    let mesh = branches.mesh(&frame).unwrap();
    for i in 1..6 {
        assert!((mesh.normals[i * stride] - mesh.normals[0]).length() < 1e-5);
    }
}

#[test]
fn bent_planar_strands_do_not_twist_out_of_their_plane() {
    // A quarter circle: transported reference directions turn with the
    // tangent but never spin about it.
    let k = 12;
    let tree = Tree::new(
        TreeParts {
            nodes: (0..k)
                .map(|i| {
                    let a = std::f32::consts::FRAC_PI_2 * i as f32 / (k - 1) as f32;
                    node(1.0 - a.cos(), a.sin(), 0.0, 0.05, (i > 0).then(|| i - 1))
                })
                .collect(),
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap();
    let (_, frame, mut branches, _) = meshers(&tree);
    let stride = branches.plans[0].sides as usize + 1;
    let mesh = branches.mesh(&frame).unwrap();
    // The curve lies in the z = 0 plane and its first reference direction
    // in the plane; a twist-free frame keeps it there.
    let zs: Vec<f32> = (0..k as usize)
        .map(|i| mesh.normals[i * stride].z)
        .collect();
    for z in &zs {
        assert!((z - zs[0]).abs() < 1e-4, "{zs:?}");
    }
}

/// On a helix (a curve with torsion) each ring's reference direction is the
/// previous one turned only about the bend axis: its twist about the
/// tangent is second order in the bend angle, where a frame re-derived from
/// a fixed axis at every node twists to first order.
#[test]
fn helical_strands_use_rotation_minimising_frames() {
    let k = 40;
    let tree = Tree::new(
        TreeParts {
            nodes: (0..k)
                .map(|i| {
                    let a = 0.15 * i as f32;
                    Node {
                        position: Vec3::new(a.cos(), 0.2 * a, a.sin()),
                        radius: 0.05,
                        parent: (i > 0).then(|| i - 1),
                    }
                })
                .collect(),
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap();
    let (_, frame, mut branches, _) = meshers(&tree);
    let stride = branches.plans[0].sides as usize + 1;
    let mesh = branches.mesh(&frame).unwrap();
    let p = &frame.positions;
    let tangent = |i: usize| (p[(i + 1).min(k as usize - 1)] - p[i.saturating_sub(1)]).normalize();
    for i in 1..k as usize - 2 {
        let (t0, t1) = (tangent(i), tangent(i + 1));
        let (n0, n1) = (mesh.normals[i * stride], mesh.normals[(i + 1) * stride]);
        let twist = n1.dot(t0.cross(n0)).abs();
        let bend = t0.angle_between(t1);
        assert!(
            twist < 0.5 * bend * bend,
            "ring {i}: twist {twist}, bend {bend}"
        );
    }
}

#[test]
fn zero_radii_and_coincident_nodes_give_finite_degenerate_tubes() {
    let tree = sample::sample_tree(120);
    let (_, frame, mut branches, mut leaves) = meshers(&tree);
    let mut collapsed = frame.clone();
    collapsed.radii.fill(0.0);
    for p in collapsed.positions.iter_mut().skip(40) {
        *p = Vec3::new(1.0, 2.0, 3.0);
    }
    for l in &mut collapsed.leaves {
        l.width = 0.0;
        l.height = 0.0;
        l.orientation = Quat::from_xyzw(0.0, 0.0, 0.0, 0.0);
    }
    let mesh = branches.mesh(&collapsed).unwrap();
    assert_well_formed(mesh);
    // Every vertex lies on the skeleton.
    for p in &mesh.positions {
        assert!(collapsed.positions.iter().any(|q| q.distance(*p) < 1e-6));
    }
    let mesh = leaves.mesh(&collapsed).unwrap();
    assert_well_formed(mesh);
    for (quad, leaf) in mesh.positions.chunks_exact(4).zip(&collapsed.leaves) {
        assert!(quad.iter().all(|&p| p == leaf.anchor));
    }
}

#[test]
fn leaf_quads_follow_the_billboard_convention() {
    let tree = fork();
    let (_, frame, _, mut leaves) = meshers(&tree);
    let mesh = leaves.mesh(&frame).unwrap();
    for (i, leaf) in frame.leaves.iter().enumerate() {
        let q = &mesh.positions[4 * i..4 * i + 4];
        let base = (q[0] + q[1]) * 0.5;
        let tip = (q[2] + q[3]) * 0.5;
        assert!(base.distance(leaf.anchor) < 1e-6);
        assert!((tip - base - leaf.orientation * Vec3::Y * leaf.height).length() < 1e-6);
        assert!((q[0].distance(q[1]) - leaf.width).abs() < 1e-6);
        assert!((mesh.normals[4 * i] - leaf.orientation * Vec3::Z).length() < 1e-6);
        assert_eq!(
            mesh.uvs[4 * i].y,
            1.0,
            "base on the image's bottom row (v = 1)"
        );
        assert_eq!(
            mesh.uvs[4 * i + 2].y,
            0.0,
            "tip on the image's top row (v = 0)"
        );
    }
}

#[test]
fn leaves_are_grouped_by_material_in_topology_order() {
    let tree = fork();
    let (_, frame, _, mut leaves) = meshers(&tree);
    let mesh = leaves.mesh(&frame).unwrap();
    assert_eq!(
        mesh.groups,
        vec![
            MeshGroup {
                materials: [0, 0],
                first_index: 0,
                index_count: 6
            },
            MeshGroup {
                materials: [1, 1],
                first_index: 6,
                index_count: 12
            },
        ]
    );
    // Leaf 1 (material 0) first, then leaves 0 and 2.
    assert_eq!(&mesh.indices[..6], &[4, 5, 6, 4, 6, 7]);
    assert_eq!(&mesh.indices[6..9], &[0, 1, 2]);
    assert_eq!(&mesh.indices[12..15], &[8, 9, 10]);
}

#[test]
fn refuses_frames_and_topologies_that_do_not_fit() {
    let tree = fork();
    let (mut topology, frame, mut branches, mut leaves) = meshers(&tree);
    let mut short = frame.clone();
    short.radii.pop();
    assert!(matches!(branches.mesh(&short), Err(MeshError::Frame(_))));
    let mut nan = frame.clone();
    nan.positions[3].x = f32::NAN;
    assert!(matches!(branches.mesh(&nan), Err(MeshError::Frame(_))));
    let mut negative = frame.clone();
    negative.radii[1] = -0.1;
    assert!(matches!(branches.mesh(&negative), Err(MeshError::Frame(_))));
    let mut no_leaves = frame.clone();
    no_leaves.leaves.clear();
    assert!(matches!(leaves.mesh(&no_leaves), Err(MeshError::Frame(_))));
    let mut bad_leaf = frame.clone();
    bad_leaf.leaves[0].width = f32::INFINITY;
    assert!(matches!(leaves.mesh(&bad_leaf), Err(MeshError::Frame(_))));

    assert!(matches!(
        BranchMesher::new(
            &topology,
            &frame.radii[1..],
            &frame,
            &MeshOptions::default()
        ),
        Err(MeshError::Frame(_))
    ));
    for (min, max) in [(2, 8), (6, 5), (4, 65)] {
        let options = MeshOptions {
            min_sides: min,
            max_sides: max,
            ..MeshOptions::default()
        };
        assert!(matches!(
            BranchMesher::new(&topology, &frame.radii, &frame, &options),
            Err(MeshError::InvalidOptions(_))
        ));
    }
    topology.strands = Strands::from_polylines([vec![0, 1, 9]]);
    assert_eq!(
        BranchMesher::new(&topology, &frame.radii, &frame, &MeshOptions::default()).unwrap_err(),
        MeshError::StrandNodeOutOfRange {
            strand: 0,
            node: 9,
            count: 6
        }
    );
}

#[test]
fn a_root_only_tree_has_no_tubes() {
    let tree = Tree::new(
        TreeParts {
            nodes: vec![node(0.0, 0.0, 0.0, 0.1, None)],
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap();
    let (_, frame, mut branches, mut leaves) = meshers(&tree);
    let mesh = branches.mesh(&frame).unwrap();
    assert!(mesh.is_empty() && mesh.positions.is_empty());
    assert!(mesh.bounds.is_empty());
    assert!(leaves.mesh(&frame).unwrap().is_empty());
}

/// A random skeleton (parents before children) with positive radii.
fn arb_tree() -> impl Strategy<Value = Tree> {
    (2usize..30)
        .prop_flat_map(|n| {
            (
                proptest::collection::vec(any::<prop::sample::Index>(), n),
                proptest::collection::vec(prop::array::uniform3(-3.0f32..3.0), n),
                proptest::collection::vec(0.001f32..0.4, n),
            )
        })
        .prop_filter_map("a valid tree", |(parents, positions, radii)| {
            let nodes = (0..positions.len())
                .map(|i| Node {
                    position: Vec3::from_array(positions[i]),
                    radius: radii[i],
                    parent: (i > 0).then(|| parents[i].index(i) as u32),
                })
                .collect();
            Tree::new(
                TreeParts {
                    nodes,
                    ..TreeParts::default()
                },
                &Limits::default(),
            )
            .ok()
        })
}

proptest! {
    #[test]
    fn any_frame_meshes_finitely_with_the_same_layout(
        tree in arb_tree(),
        moves in proptest::collection::vec(prop::array::uniform3(-2.0f32..2.0), 30),
        radii in proptest::collection::vec(prop_oneof![Just(0.0f32), 0.0f32..0.5], 30),
        collapse in any::<bool>(),
    ) {
        let (_, frame, mut branches, _) = meshers(&tree);
        let first = branches.mesh(&frame).unwrap().clone();
        assert_well_formed(&first);
        let mut other = frame.clone();
        for (i, p) in other.positions.iter_mut().enumerate() {
            *p = if collapse && i.is_multiple_of(2) { Vec3::ZERO } else { *p + Vec3::from_array(moves[i]) };
        }
        for (i, r) in other.radii.iter_mut().enumerate() {
            *r = radii[i];
        }
        let mesh = branches.mesh(&other).unwrap();
        assert_well_formed(mesh);
        prop_assert_eq!(mesh.positions.len(), first.positions.len());
        prop_assert_eq!(&mesh.indices, &first.indices);
    }
}
