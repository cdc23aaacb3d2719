//! Times [`treemorph_import::import`] on generated 10,000-branch,
//! 5,000-leaf trees exported as GLB without the embedded tree, once as a
//! tube soup and once welded:
//!
//! ```sh
//! cargo run --release -p treemorph-import --example import_bench
//! ```
//!
//! `treemorph bench` can build the same inputs with
//! [`treemorph_import::bench::bench_glb`].

use std::time::Instant;

use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_gltf::mesh::MeshOptions;
use treemorph_gltf::{BranchMeshMode, ExportOptions, export_glb};
use treemorph_import::bench::bench_glb;
use treemorph_import::{ImportOptions, import};

fn main() {
    for preset in [Preset::Eucalyptus, Preset::Maple, Preset::Conifer] {
        let tree = generate(&GenerateOptions::new(preset, 1).with_size(10_000)).unwrap();
        for mode in [BranchMeshMode::TubeSoup, BranchMeshMode::Welded] {
            let glb = bench_glb(&tree, mode, 5_000).unwrap();
            run(&format!("{preset:11} {mode:?}"), &glb);
        }
    }
    // A dense welded mesh (16–48 sides per ring: ~300k vertices), the size
    // third-party tools write.
    let tree = generate(&GenerateOptions::new(Preset::Eucalyptus, 1).with_size(10_000)).unwrap();
    let options = ExportOptions::default()
        .with_embed_tree(false)
        .with_branch_mode(BranchMeshMode::Welded)
        .with_mesh(MeshOptions::default().with_sides(16, 48));
    let dense = export_glb(&tree, &options).unwrap();
    run("eucalyptus  dense welded", &dense);
}

/// Imports `glb` five times and prints the median.
fn run(what: &str, glb: &[u8]) {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..5 {
        let t = Instant::now();
        last = Some(import(glb, &ImportOptions::default()).unwrap());
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let imported = last.unwrap();
    println!(
        "{what}: {:.0} KiB, {} wood vertices → {} nodes, {} leaves; median {:.1} ms (min {:.1}); stages {:?}",
        glb.len() / 1024,
        imported.report.wood_vertices,
        imported.tree.skeleton().len(),
        imported.tree.leaves().len(),
        times[times.len() / 2],
        times[0],
        imported
            .report
            .timings_ms
            .map(|t| (t * 10.0).round() / 10.0),
    );
}
