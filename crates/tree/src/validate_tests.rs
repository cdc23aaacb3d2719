use glam::{Quat, Vec3};

use super::*;
use crate::model::{GroundTruthGroup, LeafMaterial};
use crate::{BranchingPattern, Texture};

fn node(y: f32, parent: Option<u32>) -> Node {
    Node {
        position: Vec3::new(0.0, y, 0.0),
        radius: 0.1,
        parent,
    }
}

fn leaf(branch: u32) -> Leaf {
    Leaf {
        branch,
        t: 0.5,
        offset: Vec3::X * 0.1,
        width: 0.05,
        height: 0.1,
        orientation: Quat::IDENTITY,
        material: 0,
    }
}

/// A valid three-node stick with one leaf and one leaf material.
fn parts() -> TreeParts {
    TreeParts {
        name: "stick".into(),
        nodes: vec![node(0.0, None), node(1.0, Some(0)), node(2.0, Some(1))],
        leaves: vec![leaf(2)],
        materials: crate::Materials {
            leaves: vec![LeafMaterial {
                name: "plain".into(),
                color: [1.0; 4],
                texture: None,
            }],
            ..Default::default()
        },
        ground_truth: None,
    }
}

fn build_with(f: impl FnOnce(&mut TreeParts)) -> Result<Tree, InvalidTree> {
    let mut p = parts();
    f(&mut p);
    Tree::new(p, &Limits::default())
}

#[test]
fn accepts_a_valid_tree() {
    let tree = build_with(|_| {}).unwrap();
    assert_eq!(tree.skeleton().len(), 3);
    assert_eq!(tree.skeleton().children(0), &[1]);
    assert_eq!(tree.leaves().len(), 1);
}

#[test]
fn refuses_an_empty_skeleton() {
    assert_eq!(
        build_with(|p| {
            p.nodes.clear();
            p.leaves.clear();
        }),
        Err(InvalidTree::Empty)
    );
}

#[test]
fn refuses_several_roots() {
    assert_eq!(
        build_with(|p| p.nodes[2].parent = None),
        Err(InvalidTree::SeveralRoots {
            first: 0,
            second: 2
        })
    );
}

#[test]
fn refuses_a_skeleton_without_root() {
    assert_eq!(
        build_with(|p| p.nodes[0].parent = Some(2)),
        Err(InvalidTree::NoRoot { node: 0 })
    );
}

#[test]
fn refuses_cycles_detached_from_the_root() {
    let result = build_with(|p| {
        p.nodes.push(node(3.0, Some(4)));
        p.nodes.push(node(4.0, Some(3)));
    });
    assert_eq!(result, Err(InvalidTree::Cycle { node: 3 }));
    assert_eq!(
        build_with(|p| p.nodes[2].parent = Some(2)),
        Err(InvalidTree::Cycle { node: 2 })
    );
}

#[test]
fn refuses_dangling_parents() {
    assert_eq!(
        build_with(|p| p.nodes[1].parent = Some(7)),
        Err(InvalidTree::DanglingParent {
            node: 1,
            parent: 7,
            count: 3
        })
    );
}

#[test]
fn refuses_non_finite_numbers() {
    assert_eq!(
        build_with(|p| p.nodes[1].position.x = f32::NAN),
        Err(InvalidTree::NonFinite {
            field: Field::NodePosition,
            index: 1
        })
    );
    assert_eq!(
        build_with(|p| p.nodes[2].radius = f32::INFINITY),
        Err(InvalidTree::NonFinite {
            field: Field::NodeRadius,
            index: 2
        })
    );
    type Corrupt = fn(&mut Leaf);
    let cases: [(Field, Corrupt); 5] = [
        (Field::LeafT, |l| l.t = f32::NAN),
        (Field::LeafOffset, |l| l.offset.z = f32::NEG_INFINITY),
        (Field::LeafWidth, |l| l.width = f32::NAN),
        (Field::LeafHeight, |l| l.height = f32::INFINITY),
        (Field::LeafOrientation, |l| l.orientation.w = f32::NAN),
    ];
    for (field, corrupt) in cases {
        assert_eq!(
            build_with(|p| corrupt(&mut p.leaves[0])),
            Err(InvalidTree::NonFinite { field, index: 0 }),
            "{field:?}"
        );
    }
    assert_eq!(
        build_with(|p| p.materials.bark.color[1] = f32::NAN),
        Err(InvalidTree::NonFinite {
            field: Field::BarkColor,
            index: 0
        })
    );
    assert_eq!(
        build_with(|p| p.materials.leaves[0].color[3] = f32::NAN),
        Err(InvalidTree::NonFinite {
            field: Field::LeafColor,
            index: 0
        })
    );
}

#[test]
fn refuses_zero_and_negative_radii() {
    assert_eq!(
        build_with(|p| p.nodes[1].radius = 0.0),
        Err(InvalidTree::NonPositiveRadius {
            node: 1,
            radius: 0.0
        })
    );
    assert_eq!(
        build_with(|p| p.nodes[0].radius = -0.5),
        Err(InvalidTree::NonPositiveRadius {
            node: 0,
            radius: -0.5
        })
    );
}

#[test]
fn refuses_zero_length_branches() {
    assert_eq!(
        build_with(|p| p.nodes[2].position = p.nodes[1].position),
        Err(InvalidTree::ZeroLengthBranch { node: 2, parent: 1 })
    );
}

#[test]
fn refuses_leaves_on_missing_branches_and_on_the_root() {
    assert_eq!(
        build_with(|p| p.leaves[0].branch = 3),
        Err(InvalidTree::LeafOnMissingBranch {
            leaf: 0,
            branch: 3,
            count: 3
        })
    );
    assert_eq!(
        build_with(|p| p.leaves[0].branch = 0),
        Err(InvalidTree::LeafOnRoot { leaf: 0, branch: 0 })
    );
}

#[test]
fn refuses_bad_leaf_parameters() {
    assert_eq!(
        build_with(|p| p.leaves[0].t = 1.5),
        Err(InvalidTree::LeafParameterOutOfRange { leaf: 0, t: 1.5 })
    );
    assert_eq!(
        build_with(|p| p.leaves[0].width = 0.0),
        Err(InvalidTree::NonPositiveLeafSize {
            leaf: 0,
            width: 0.0,
            height: 0.1
        })
    );
    assert_eq!(
        build_with(|p| p.leaves[0].orientation = Quat::from_xyzw(0.0, 0.0, 0.0, 2.0)),
        Err(InvalidTree::NonUnitOrientation {
            leaf: 0,
            length: 2.0
        })
    );
    assert_eq!(
        build_with(|p| p.leaves[0].material = 1),
        Err(InvalidTree::MissingMaterial {
            leaf: 0,
            material: 1,
            count: 1
        })
    );
}

#[test]
fn refuses_colours_outside_the_unit_range() {
    assert_eq!(
        build_with(|p| p.materials.bark.color[0] = 1.5),
        Err(InvalidTree::ColorOutOfRange {
            field: Field::BarkColor,
            index: 0
        })
    );
}

#[test]
fn refuses_sizes_over_the_limits() {
    let limits = Limits::with_sizes(2, 10);
    assert_eq!(
        Tree::new(parts(), &limits),
        Err(InvalidTree::TooLarge {
            kind: SizeKind::Nodes,
            count: 3,
            limit: 2
        })
    );
    let limits = Limits::with_sizes(10, 0);
    assert_eq!(
        Tree::new(parts(), &limits),
        Err(InvalidTree::TooLarge {
            kind: SizeKind::Leaves,
            count: 1,
            limit: 0
        })
    );
    let limits = Limits {
        max_leaf_materials: 0,
        ..Limits::default()
    };
    assert_eq!(
        Tree::new(parts(), &limits),
        Err(InvalidTree::TooLarge {
            kind: SizeKind::LeafMaterials,
            count: 1,
            limit: 0
        })
    );
    assert_eq!(
        build_with(|p| p.name = "x".repeat(300)),
        Err(InvalidTree::TooLarge {
            kind: SizeKind::NameBytes,
            count: 300,
            limit: 256
        })
    );
}

#[test]
fn refuses_textures_over_the_side_limit() {
    let image = crate::RgbaImage::new(16, 4, vec![255; 16 * 4 * 4]).unwrap();
    let texture = Texture::from_rgba(&image);
    let mut p = parts();
    p.materials.bark.texture = Some(texture);
    let limits = Limits {
        max_texture_side: 8,
        ..Limits::default()
    };
    assert!(matches!(
        Tree::new(p, &limits),
        Err(InvalidTree::InvalidTexture { material, .. }) if material == "bark"
    ));
}

/// Regression (hostile uploads): 64 leaf materials of 4096² each passed
/// the per-side limit, and a job decoding them all held 4 GiB of pixels
/// for a 5 MiB upload of all-zero PNGs.
#[test]
fn refuses_textures_over_the_total_pixel_budget() {
    let image = crate::RgbaImage::new(8, 8, vec![255; 8 * 8 * 4]).unwrap();
    let texture = Texture::from_rgba(&image);
    let material = |name: &str| crate::LeafMaterial {
        name: name.into(),
        color: [1.0; 4],
        texture: Some(texture.clone()),
    };
    let mut p = parts();
    p.materials.bark.texture = Some(texture.clone());
    p.materials.leaves = vec![material("a"), material("b")];
    let limits = Limits {
        max_texture_pixels: 3 * 64,
        ..Limits::default()
    };
    assert!(Tree::new(p.clone(), &limits).is_ok());
    p.materials.leaves.push(material("c"));
    assert!(matches!(
        Tree::new(p, &limits),
        Err(InvalidTree::InvalidTexture { material, .. }) if material == "leaves[2]"
    ));
    assert_eq!(Limits::default().max_texture_pixels, 4 * 4096 * 4096);
}

#[test]
fn refuses_ground_truth_that_does_not_fit() {
    let gt = |orders: Vec<u32>, chains: Vec<u32>| {
        Some(GroundTruth {
            orders,
            groups: vec![GroundTruthGroup {
                chains,
                pattern: BranchingPattern::Alternate,
            }],
        })
    };
    assert!(build_with(|p| p.ground_truth = gt(vec![1, 1, 1], vec![1])).is_ok());
    for bad in [
        gt(vec![1, 1], vec![1]),
        gt(vec![1, 0, 1], vec![1]),
        gt(vec![1, 1, 1], vec![9]),
        gt(vec![1, 1, 1], vec![]),
    ] {
        assert!(matches!(
            build_with(|p| p.ground_truth = bad),
            Err(InvalidTree::GroundTruthMismatch { .. })
        ));
    }
}

#[test]
fn canonicalises_node_order_and_renumbers_references() {
    // Root last, children before parents.
    let p = TreeParts {
        nodes: vec![node(2.0, Some(1)), node(1.0, Some(2)), node(0.0, None)],
        leaves: vec![leaf(0)],
        ground_truth: Some(GroundTruth {
            orders: vec![3, 2, 1],
            groups: vec![GroundTruthGroup {
                chains: vec![1],
                pattern: BranchingPattern::Alternate,
            }],
        }),
        ..parts()
    };
    let tree = Tree::new(p, &Limits::default()).unwrap();
    let ys: Vec<f32> = tree
        .skeleton()
        .nodes()
        .iter()
        .map(|n| n.position.y)
        .collect();
    assert_eq!(ys, vec![0.0, 1.0, 2.0]);
    assert_eq!(tree.skeleton().node(2).parent, Some(1));
    assert_eq!(tree.leaves()[0].branch, 2);
    let gt = tree.ground_truth().unwrap();
    assert_eq!(gt.orders, vec![1, 2, 3]);
    assert_eq!(gt.groups[0].chains, vec![1]);
}

#[test]
fn keeps_canonical_input_unchanged() {
    let p = parts();
    let tree = Tree::new(p.clone(), &Limits::default()).unwrap();
    assert_eq!(tree.into_parts(), p);
}

#[test]
fn error_messages_name_the_problem() {
    let e = build_with(|p| p.leaves[0].offset.y = f32::NAN).unwrap_err();
    assert_eq!(e.to_string(), "leaves[0].offset is not a finite number");
    let e = build_with(|p| p.nodes[1].parent = Some(7)).unwrap_err();
    assert_eq!(
        e.to_string(),
        "node 1 names parent 7, but there are only 3 nodes"
    );
}

mod properties {
    use proptest::prelude::*;

    use super::*;

    /// Random trees given as parent choices: node i's parent is some j < i.
    fn arb_parents() -> impl Strategy<Value = Vec<u32>> {
        (1usize..60).prop_flat_map(|n| (1..n).map(|i| (0..i as u32).boxed()).collect::<Vec<_>>())
    }

    proptest! {
        /// Shuffling node order never changes the tree that comes out, up to
        /// renumbering: same node count, same multiset of positions, every
        /// parent before its child.
        #[test]
        fn any_node_order_is_canonicalised(parents in arb_parents(), seed in any::<u64>()) {
            let n = parents.len() + 1;
            let mut nodes: Vec<Node> = (0..n)
                .map(|i| Node {
                    position: Vec3::new(i as f32, (i * i) as f32 * 0.01, 0.0),
                    radius: 0.1,
                    parent: if i == 0 { None } else { Some(parents[i - 1]) },
                })
                .collect();
            // A deterministic permutation from the seed.
            let mut perm: Vec<usize> = (0..n).collect();
            let mut s = seed;
            for i in (1..n).rev() {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                perm.swap(i, (s >> 33) as usize % (i + 1));
            }
            let mut inverse = vec![0; n];
            for (new, &old) in perm.iter().enumerate() {
                inverse[old] = new;
            }
            let shuffled: Vec<Node> = perm
                .iter()
                .map(|&old| Node {
                    parent: nodes[old].parent.map(|p| inverse[p as usize] as u32),
                    ..nodes[old]
                })
                .collect();
            let tree = Tree::new(
                TreeParts { nodes: shuffled, ..TreeParts::default() },
                &Limits::default(),
            ).unwrap();
            let skeleton = tree.skeleton();
            prop_assert_eq!(skeleton.len(), n);
            prop_assert!(skeleton.node(0).parent.is_none());
            for (i, node) in skeleton.nodes().iter().enumerate().skip(1) {
                prop_assert!((node.parent.unwrap() as usize) < i);
            }
            let key = |v: Vec3| (v.x.to_bits(), v.y.to_bits());
            let mut a: Vec<_> = skeleton.nodes().iter().map(|n| key(n.position)).collect();
            let mut b: Vec<_> = nodes.iter_mut().map(|n| key(n.position)).collect();
            a.sort_unstable();
            b.sort_unstable();
            prop_assert_eq!(a, b);
        }
    }
}
