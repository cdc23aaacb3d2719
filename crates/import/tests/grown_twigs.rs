//! Leaves with no wood under them get a grown twig (crate docs, stage 5):
//! after import every leaf hangs within its branch's radius plus half its
//! size from the branch axis, and frame 0 as written has no floating leaf
//! by `treemorph-verify`'s measure.
//!
//! The ignored test measures frame 0 of third-party trees
//! (`tools/third-party-trees`). Modular Tree's welded barks floated up to
//! 5,912 of 10,430 leaves before twigs were grown, and up to 30 after,
//! buried in tubes as wide as the clumps of twigs contraction had merged;
//! with robust radii and a proxy budget that follows the mesh (`contract`)
//! none float. The bar stays at 0.5 % of a tree's leaves; CI's acceptance
//! test (`crates/verify/tests/third_party.rs`) asks for 0 on every frame:
//!
//! ```sh
//! TREEMORPH_THIRD_PARTY_DIR=target/third-party \
//!     cargo test --release -p treemorph-import --test grown_twigs -- --ignored --nocapture
//! ```

mod common;

use glam::{Quat, Vec3};
use treemorph_gltf::frame_glb::{FrameGlbOptions, FrameGlbWriter};
use treemorph_gltf::{BranchMeshMode, ExportOptions, export_glb};
use treemorph_import::{ImportOptions, import};
use treemorph_tree::{
    Frame, FrameTopology, Leaf, LeafMaterial, Limits, Materials, Node, Tree, TreeParts,
};
use treemorph_verify::{MeshView, Plausibility, PlausibilityOptions, Report};

/// Frame 0 of `tree`, meshed and checked as the runner writes it.
fn frame_zero(tree: &Tree) -> Report {
    let topology = FrameTopology::of_tree(tree);
    let frame = Frame::of_tree(tree);
    let mut writer =
        FrameGlbWriter::new(&topology, &frame.radii, &FrameGlbOptions::default()).unwrap();
    writer.write(&frame).unwrap();
    Plausibility::new()
        .check(
            &MeshView::of_frame_meshes(writer.meshes()),
            &PlausibilityOptions::default(),
        )
        .unwrap()
}

/// A trunk with one limb; leaves on the bark, a bunch of five a metre off
/// the trunk and one alone far off the limb.
fn trunk_with_far_leaves() -> (Tree, usize) {
    let node = |x: f32, y: f32, radius: f32, parent: Option<u32>| Node {
        position: Vec3::new(x, y, 0.0),
        radius,
        parent,
    };
    let nodes = vec![
        node(0.0, 0.0, 0.12, None),
        node(0.0, 1.5, 0.1, Some(0)),
        node(0.0, 3.0, 0.07, Some(1)),
        node(0.0, 4.5, 0.04, Some(2)),
        node(1.2, 3.6, 0.03, Some(2)),
    ];
    let leaf = |branch: u32, t: f32, offset: Vec3| Leaf {
        branch,
        t,
        offset,
        width: 0.06,
        height: 0.1,
        orientation: Quat::IDENTITY,
        material: 0,
    };
    let mut leaves = vec![
        leaf(3, 0.5, Vec3::new(0.055, 0.0, 0.0)),
        leaf(3, 0.9, Vec3::new(-0.045, 0.0, 0.0)),
        leaf(4, 0.7, Vec3::new(0.0, 0.0, 0.04)),
    ];
    let near = leaves.len();
    for k in 0..5 {
        let k = k as f32;
        leaves.push(leaf(2, 0.5, Vec3::new(-1.0 - 0.04 * k, 0.03 * k, 0.02 * k)));
    }
    leaves.push(leaf(4, 0.5, Vec3::new(0.0, 0.0, 0.8)));
    let far = leaves.len() - near;
    let tree = Tree::new(
        TreeParts {
            name: "far leaves".into(),
            nodes,
            leaves,
            materials: Materials {
                leaves: vec![LeafMaterial {
                    name: "leaf".into(),
                    color: [0.2, 0.6, 0.2, 1.0],
                    texture: None,
                }],
                ..Materials::default()
            },
            ground_truth: None,
        },
        &Limits::default(),
    )
    .unwrap();
    (tree, far)
}

#[test]
fn far_leaves_grow_twigs_and_hang_on_wood() {
    let (truth, far) = trunk_with_far_leaves();
    // The premise: drawn as they are, the far leaves float.
    assert_eq!(frame_zero(&truth).floating_leaves as usize, far);
    for mode in [BranchMeshMode::TubeSoup, BranchMeshMode::Welded] {
        let glb = export_glb(
            &truth,
            &ExportOptions::default()
                .with_embed_tree(false)
                .with_branch_mode(mode),
        )
        .unwrap();
        let imported = import(
            &glb,
            &ImportOptions::default().with_leaf_materials(["leaf"]),
        )
        .unwrap_or_else(|e| panic!("{mode:?}: {e}"));
        let tree = &imported.tree;
        assert_eq!(tree.leaves().len(), truth.leaves().len(), "{mode:?}");
        // The bunch shares twigs: fewer twigs than far leaves, at least one
        // for the bunch and one for the lone leaf.
        let twigs = imported.report.grown_twigs;
        assert!((2..far).contains(&twigs), "{mode:?}: {twigs} twigs");
        let sk = tree.skeleton();
        for (i, leaf) in tree.leaves().iter().enumerate() {
            let (_, radius) = sk.point_on_branch(leaf.branch, leaf.t);
            let reach = radius + 0.5 * leaf.width.max(leaf.height) + 1e-4;
            assert!(
                leaf.offset.length() <= reach,
                "{mode:?}: leaf {i} is {} from its branch (reach {reach})",
                leaf.offset.length()
            );
        }
        // Every leaf keeps its place.
        let mut anchors: Vec<Vec3> = tree.leaves().iter().map(|l| tree.leaf_anchor(l)).collect();
        for l in truth.leaves() {
            let a = truth.leaf_anchor(l);
            let (k, d) = anchors
                .iter()
                .enumerate()
                .map(|(k, b)| (k, a.distance(*b)))
                .min_by(|x, y| x.1.total_cmp(&y.1))
                .unwrap();
            assert!(d < 1e-3, "{mode:?}: a leaf moved by {d}");
            anchors.swap_remove(k);
        }
        let report = frame_zero(tree);
        assert_eq!(report.leaves as usize, truth.leaves().len(), "{mode:?}");
        assert_eq!(report.floating_leaves, 0, "{mode:?}: {report:?}");
    }
}

#[test]
#[ignore = "needs TREEMORPH_THIRD_PARTY_DIR written by tools/third-party-trees"]
fn third_party_frame_zero_has_no_floating_leaves() {
    let files = common::third_party_files();
    for path in files {
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        let bytes = std::fs::read(&path).unwrap();
        let imported =
            import(&bytes, &ImportOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        let report = frame_zero(&imported.tree);
        eprintln!(
            "{name:14} nodes {:6}  leaves {:6}  grown twigs {:5}  floating {:5}  worst gap {:.3} m",
            imported.tree.skeleton().len(),
            report.leaves,
            imported.report.grown_twigs,
            report.floating_leaves,
            report.worst_leaf_gap
        );
        assert!(
            report.floating_leaves as f32 <= 0.005 * report.leaves as f32,
            "{name}: {} of {} leaves float",
            report.floating_leaves,
            report.leaves
        );
    }
}
