use glam::Vec3;
use treemorph_gltf::{BranchMesher, MeshOptions};
use treemorph_tree::{Frame, FrameTopology, Limits, Node as TreeNode, Tree, TreeParts};

use super::*;
use crate::mesh::{Mesh, split};
use crate::tube::tube_piece;

fn node(x: f32, y: f32, z: f32, radius: f32, parent: Option<u32>) -> TreeNode {
    TreeNode {
        position: Vec3::new(x, y, z),
        radius,
        parent,
    }
}

/// A trunk with a fork and a lateral, meshed as a tube soup.
fn forked() -> Tree {
    Tree::new(
        TreeParts {
            nodes: vec![
                node(0.0, 0.0, 0.0, 0.2, None),
                node(0.0, 1.0, 0.0, 0.15, Some(0)),
                node(0.1, 2.0, 0.0, 0.12, Some(1)),
                node(0.1, 3.0, 0.2, 0.08, Some(2)),
                node(0.8, 2.6, 0.0, 0.05, Some(2)),
                node(-0.6, 1.5, 0.1, 0.04, Some(1)),
            ],
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap()
}

fn soup(tree: &Tree, sides: u32) -> Mesh {
    let topology = FrameTopology::of_tree(tree);
    let frame = Frame::of_tree(tree);
    let options = MeshOptions::default().with_sides(sides, sides.max(12));
    let mut mesher = BranchMesher::new(&topology, &frame.radii, &frame, &options).unwrap();
    let b = mesher.mesh(&frame).unwrap();
    let tris: Vec<[u32; 3]> = b
        .indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    Mesh::weld(&b.positions, &tris).0
}

#[test]
fn tube_axes_are_the_ring_centres() {
    let tree = forked();
    let mesh = soup(&tree, 4);
    let parts = split(&mesh);
    assert_eq!(parts.len(), 3, "one tube per strand");
    for (part, _) in &parts {
        let piece = tube_piece(part).expect("a tube");
        for (p, r) in piece.points.iter().zip(&piece.radii) {
            let hit = tree.skeleton().nodes().iter().any(|n| {
                n.position.distance(*p) < 1e-5 && (n.radius - r).abs() < 1e-3
                    || n.position.distance(*p) < 1e-5
            });
            assert!(hit, "ring centre {p} is not a node");
        }
    }
}

#[test]
fn tube_soups_assemble_into_the_original_skeleton() {
    let tree = forked();
    let mesh = soup(&tree, 6);
    let pieces: Vec<Piece> = split(&mesh)
        .iter()
        .map(|(m, _)| tube_piece(m).unwrap())
        .collect();
    let mut warnings = Vec::new();
    let nodes = assemble(&pieces, &mut warnings).unwrap();
    assert!(warnings.is_empty(), "{warnings:?}");
    assert_eq!(nodes.len(), tree.skeleton().len());
    assert!(nodes[0].position.length() < 1e-5);
    assert!(nodes[0].parent.is_none());
    for n in &nodes {
        let t = tree
            .skeleton()
            .nodes()
            .iter()
            .find(|t| t.position.distance(n.position) < 1e-5)
            .expect("every node is an original node");
        if let (Some(p), Some(tp)) = (n.parent, t.parent) {
            assert!(
                nodes[p as usize]
                    .position
                    .distance(tree.skeleton().node(tp).position)
                    < 1e-5
            );
        }
    }
}

#[test]
fn separate_parts_are_joined_with_a_warning() {
    let trunk = Piece {
        points: vec![Vec3::ZERO, Vec3::Y * 2.0],
        radii: vec![0.1, 0.08],
        edges: vec![(0, 1)],
    };
    // A branch starting inside the trunk, and a far stick.
    let branch = Piece {
        points: vec![Vec3::new(0.05, 1.0, 0.0), Vec3::new(1.0, 1.5, 0.0)],
        radii: vec![0.03, 0.02],
        edges: vec![(0, 1)],
    };
    let stick = Piece {
        points: vec![Vec3::new(5.0, 1.0, 0.0), Vec3::new(5.0, 2.0, 0.0)],
        radii: vec![0.02, 0.02],
        edges: vec![(0, 1)],
    };
    let mut warnings = Vec::new();
    let nodes = assemble(&[branch, stick, trunk], &mut warnings).unwrap();
    assert_eq!(nodes[0].position, Vec3::ZERO, "root: lowest, thickest end");
    assert_eq!(warnings.len(), 1);
    // Trunk split at the branch base: 2 + 1 split + branch 2 + stick 2.
    assert_eq!(nodes.len(), 7);
    let parts = TreeParts {
        nodes,
        ..TreeParts::default()
    };
    assert!(Tree::new(parts, &Limits::default()).is_ok());
}

#[test]
fn closest_points_on_segments() {
    let (s, d) = closest_on_segment(Vec3::new(0.5, 1.0, 0.0), Vec3::ZERO, Vec3::X);
    assert_eq!((s, d), (0.5, 1.0));
    let (s, d) = closest_on_segment(Vec3::new(-1.0, 0.0, 0.0), Vec3::ZERO, Vec3::X);
    assert_eq!((s, d), (0.0, 1.0));
    let (s, _) = closest_on_segment(Vec3::ONE, Vec3::ONE, Vec3::ONE);
    assert_eq!(s, 0.0);
}

/// Regression: a bush from ez-tree whose drooping twigs hang lower than
/// its trunk's base was rooted at a twig tip (root radius 0.001 m against
/// a 0.58 m trunk): only the ends within 2 % of the height above the
/// lowest point were considered, and only twig tips lay there. The root
/// is the thick base of the trunk.
#[test]
fn a_twig_hanging_below_the_trunk_base_is_not_the_root() {
    let trunk = Piece {
        points: vec![Vec3::ZERO, Vec3::Y * 2.0],
        radii: vec![0.3, 0.2],
        edges: vec![(0, 1)],
    };
    // A drooping branch from the trunk's top, its tip 0.2 m below the base.
    let droop = Piece {
        points: vec![
            Vec3::new(0.05, 1.9, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(1.5, -0.2, 0.0),
        ],
        radii: vec![0.05, 0.02, 0.001],
        edges: vec![(0, 1), (1, 2)],
    };
    let nodes = assemble(&[droop, trunk], &mut Vec::new()).unwrap();
    assert_eq!(nodes[0].position, Vec3::ZERO, "root: the trunk's base");
}

/// Regression: a contracted welded bark whose trunk base is a junction
/// (its cap contracted to a point with two neighbours), not an end, has no
/// end on the ground; the root fell to the thickest end in the lowest
/// quarter, a limb's stub 5 m up a 15 m Modular Tree broadleaf, instead of
/// the lowest point. With no end on the ground the lowest point is the
/// root, as before the drooping-twig rule.
#[test]
fn a_trunk_base_that_is_a_junction_stays_the_root() {
    let trunk = Piece {
        points: vec![Vec3::ZERO, Vec3::Y, Vec3::new(0.3, 0.1, 0.0), Vec3::Y * 3.0],
        radii: vec![0.3, 0.25, 0.1, 0.05],
        edges: vec![(0, 1), (0, 2), (1, 3)],
    };
    let nodes = assemble(&[trunk], &mut Vec::new()).unwrap();
    assert_eq!(nodes[0].position, Vec3::ZERO, "root: the trunk's base");
}
