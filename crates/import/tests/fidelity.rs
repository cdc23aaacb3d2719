//! Measured fidelity: generated trees exported as GLB without our extras
//! (tube soup and welded), imported back, compared with the originals.

mod common;

use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_gltf::{BranchMeshMode, ExportOptions, export_glb};
use treemorph_import::{ImportOptions, SkeletonMethod, import};
use treemorph_tree::Tree;

struct Figures {
    coverage: f32,
    chains: (usize, usize),
    leaves: (usize, usize),
    right_chain: f32,
}

fn round_trip(preset: Preset, seed: u64, size: u32, mode: BranchMeshMode) -> (Tree, Tree, Figures) {
    let truth = generate(&GenerateOptions::new(preset, seed).with_size(size)).unwrap();
    let glb = export_glb(
        &truth,
        &ExportOptions::default()
            .with_embed_tree(false)
            .with_branch_mode(mode),
    )
    .unwrap();
    let imported = import(&glb, &ImportOptions::default()).unwrap();
    let expected = match mode {
        BranchMeshMode::Welded => SkeletonMethod::Contraction,
        _ => SkeletonMethod::TubeSoup,
    };
    assert_eq!(imported.report.skeleton_method, expected, "{preset}");
    let recovered = imported.tree;
    let height = truth.stats().height;
    let figures = Figures {
        coverage: common::coverage(&truth, &recovered, 1e-3 * height),
        chains: (common::chains(&truth), common::chains(&recovered)),
        leaves: (truth.leaves().len(), recovered.leaves().len()),
        right_chain: common::leaves_on_right_chain(&truth, &recovered),
    };
    eprintln!(
        "{preset:12} {mode:?}: coverage {:.3}, chains {} → {}, leaves {} → {}, right chain {:.3}, nodes {} → {}",
        figures.coverage,
        figures.chains.0,
        figures.chains.1,
        figures.leaves.0,
        figures.leaves.1,
        figures.right_chain,
        truth.skeleton().len(),
        recovered.skeleton().len()
    );
    (truth, recovered, figures)
}

fn check(f: &Figures, what: &str) {
    assert!(f.coverage >= 0.95, "{what}: coverage {}", f.coverage);
    let (a, b) = f.chains;
    assert!(
        (b as f32 - a as f32).abs() <= 0.1 * a as f32,
        "{what}: chains {a} → {b}"
    );
    assert_eq!(f.leaves.0, f.leaves.1, "{what}: leaf count");
    assert!(
        f.right_chain >= 0.9,
        "{what}: right chain {}",
        f.right_chain
    );
}

#[test]
fn tube_soup_exports_are_recovered() {
    for (seed, size) in [(7, 1500), (11, 4000)] {
        for &preset in Preset::ALL {
            let (_, _, f) = round_trip(preset, seed, size, BranchMeshMode::TubeSoup);
            check(&f, &format!("{preset} {seed} tube soup"));
        }
    }
}

#[test]
fn welded_exports_are_recovered() {
    for (seed, size) in [(7, 1500), (11, 4000)] {
        for &preset in Preset::ALL {
            let (_, _, f) = round_trip(preset, seed, size, BranchMeshMode::Welded);
            check(&f, &format!("{preset} {seed} welded"));
        }
    }
}

#[test]
fn embedded_trees_are_used_as_is_unless_ignored() {
    let truth = generate(&GenerateOptions::new(Preset::Shrub, 3).with_size(300)).unwrap();
    let glb = export_glb(&truth, &ExportOptions::default()).unwrap();
    let imported = import(&glb, &ImportOptions::default()).unwrap();
    assert_eq!(imported.report.skeleton_method, SkeletonMethod::Embedded);
    assert_eq!(imported.tree, truth);
    let rebuilt = import(
        &glb,
        &ImportOptions::default().with_ignore_embedded_tree(true),
    )
    .unwrap();
    assert_eq!(rebuilt.report.skeleton_method, SkeletonMethod::TubeSoup);
    assert_eq!(rebuilt.tree.leaves().len(), truth.leaves().len());
    assert!(rebuilt.tree.ground_truth().is_none());
}

#[test]
fn name_overrides_decide_wood_and_leaves() {
    let truth = generate(&GenerateOptions::new(Preset::Maple, 2).with_size(200)).unwrap();
    let glb = export_glb(&truth, &ExportOptions::default().with_embed_tree(false)).unwrap();
    // Calling the bark foliage leaves no wood.
    let err = import(
        &glb,
        &ImportOptions::default().with_leaf_materials(["bark"]),
    )
    .unwrap_err();
    assert_eq!(err.code(), "invalid_tree");
    // Calling the leaves wood turns them into skeleton pieces.
    let all_wood = import(&glb, &ImportOptions::default().with_wood_materials(["*"])).unwrap();
    assert_eq!(all_wood.tree.leaves().len(), 0);
    assert_eq!(all_wood.report.leaf_primitives, 0);
}
