//! Trees from third-party generators (ez-tree and Modular Tree, see
//! `tools/third-party-trees`): no ground truth, so we check what can be
//! checked — one connected tree rooted near its lowest point, the leaf count
//! the generator reports (ez-tree's crossed billboards counted once), a skeleton that stays
//! inside the wood, plausible radii, and an analysis that runs.
//!
//! ```sh
//! npm ci --prefix tools/third-party-trees
//! node tools/third-party-trees/generate.mjs target/third-party
//! TREEMORPH_THIRD_PARTY_DIR=target/third-party \
//!     cargo test -p treemorph-import --test third_party -- --ignored
//! ```

mod common;

use std::num::NonZero;

use glam::Vec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_import::{ImportOptions, SkeletonMethod, import};
use treemorph_verify::geometry::point_triangle_sq;

/// Triangles of the mesh named `branches`.
fn branch_triangles(glb: &[u8]) -> Vec<[Vec3; 3]> {
    let doc = gltf::Gltf::from_slice(glb).unwrap();
    let blob = doc.blob.as_deref().unwrap();
    let mesh = doc.meshes().find(|m| m.name() == Some("branches")).unwrap();
    let mut out = Vec::new();
    for p in mesh.primitives() {
        let reader = p.reader(|_| Some(blob));
        let positions: Vec<Vec3> = reader.read_positions().unwrap().map(Vec3::from).collect();
        let indices: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
        for t in indices.chunks_exact(3) {
            out.push([0, 1, 2].map(|k| positions[t[k] as usize]));
        }
    }
    out
}

fn facts(path: &std::path::Path) -> serde_json::Value {
    let text = std::fs::read_to_string(path.with_extension("json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

#[test]
#[ignore = "needs TREEMORPH_THIRD_PARTY_DIR written by tools/third-party-trees"]
fn third_party_trees_import() {
    let files = common::third_party_files();
    for path in files {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let bytes = std::fs::read(&path).unwrap();
        let facts = facts(&path);
        let imported =
            import(&bytes, &ImportOptions::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
        let tree = &imported.tree;
        let report = &imported.report;
        let sk = tree.skeleton();
        eprintln!(
            "{name}: {} nodes, {} leaves, method {:?}, {} tubes, warnings {:?}",
            sk.len(),
            tree.leaves().len(),
            report.skeleton_method,
            report.tube_components,
            report.warnings
        );
        // ez-tree writes every branch as its own tube; Modular Tree one
        // welded bark, which is contracted.
        let method = if name.starts_with("mt-") {
            SkeletonMethod::Contraction
        } else {
            SkeletonMethod::TubeSoup
        };
        assert_eq!(report.skeleton_method, method, "{name}");
        assert_eq!(report.wood_primitives, 1, "{name}");
        assert_eq!(report.leaf_primitives, 1, "{name}");
        // Leaf count: one per leaf component, crossed quads once.
        assert_eq!(
            tree.leaves().len() as u64,
            facts["leaves"].as_u64().unwrap(),
            "{name}: leaves"
        );
        assert_eq!(report.skipped_leaves, 0, "{name}");
        // One tree (Tree validates connectivity) rooted near its lowest
        // point: at the trunk's base, which a bush's drooping twigs can
        // hang below (the radius checks below see that it is the trunk).
        let root = sk.node(0);
        let lowest = sk
            .nodes()
            .iter()
            .map(|n| n.position.y)
            .fold(f32::MAX, f32::min);
        let height = tree.stats().height;
        assert!(
            root.position.y <= lowest + 0.25 * height,
            "{name}: root is not near the lowest point"
        );
        // The skeleton lies inside the wood: every branch midpoint is about
        // its radius from the wood surface (nearest of the triangles around
        // the nearest triangle centres).
        let wood = branch_triangles(&bytes);
        let centres: Vec<[f32; 3]> = wood
            .iter()
            .map(|t| ((t[0] + t[1] + t[2]) / 3.0).to_array())
            .collect();
        let index: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(&centres);
        let mut inside = 0usize;
        for i in 1..sk.len() as u32 {
            let (p, r) = sk.point_on_branch(i, 0.5);
            let surface = index
                .nearest_n::<SquaredEuclidean>(&p.to_array(), NonZero::new(64).unwrap())
                .iter()
                .map(|n| point_triangle_sq(p, wood[n.item as usize]).sqrt())
                .fold(f32::MAX, f32::min);
            if surface <= 1.5 * r + 1e-4 * height {
                inside += 1;
            }
        }
        let fraction = inside as f32 / (sk.len() - 1) as f32;
        eprintln!("{name}: {fraction:.3} of branches inside the wood");
        // Since the contraction's proxy follows the mesh, welded barks keep
        // their twigs too (0.97–0.99 of branches inside the wood).
        assert!(
            fraction >= 0.95,
            "{name}: only {fraction} of branches inside the wood"
        );
        // Plausible radii: positive, none wider than a tenth of the height,
        // and for tube soups the root thickest (or nearly): a contracted
        // Modular Tree bark can measure its base cap thin (mt-weeping:
        // 0.04 m of 0.45 m; printed).
        let rmax = sk.nodes().iter().map(|n| n.radius).fold(0.0f32, f32::max);
        eprintln!("{name}: root radius {} of largest {rmax}", root.radius);
        assert!(
            rmax <= 0.1 * height,
            "{name}: radius {rmax} for height {height}"
        );
        if method == SkeletonMethod::TubeSoup {
            assert!(
                root.radius >= 0.5 * rmax,
                "{name}: root radius {} of {rmax}",
                root.radius
            );
        }
        // Leaves hang near the wood: anchors within a leaf height of a branch.
        for leaf in tree.leaves() {
            assert!(leaf.offset.length() <= 2.0 * leaf.height.max(leaf.width) + rmax);
        }
        // The analysis runs on it.
        let analysis = Analysis::of(tree, &AnalysisOptions::default())
            .unwrap_or_else(|e| panic!("{name}: analysis: {e}"));
        assert!(!analysis.chains().is_empty());
    }
}
