//! Export of trees from the real generator (`treemorph-generate`).

use std::time::Instant;

use gltf::Gltf;
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_gltf::{ExportOptions, export_glb, read_embedded_tree};
use treemorph_tree::Limits;

#[test]
fn generated_maple_exports_and_reads_back_exactly() {
    let tree = generate(&GenerateOptions::new(Preset::Maple, 1)).unwrap();
    let glb = export_glb(&tree, &ExportOptions::default()).unwrap();
    let gltf = Gltf::from_slice(&glb).unwrap();
    let names: Vec<_> = gltf.nodes().map(|n| n.name().unwrap().to_owned()).collect();
    assert_eq!(names, ["branches", "leaves"]);
    assert!(gltf.nodes().all(|n| n.mesh().is_some()));
    let leaves = gltf.meshes().find(|m| m.name() == Some("leaves")).unwrap();
    assert_eq!(leaves.primitives().count(), {
        let mut used: Vec<u32> = tree.leaves().iter().map(|l| l.material).collect();
        used.sort_unstable();
        used.dedup();
        used.len()
    });
    assert_eq!(read_embedded_tree(&glb, &Limits::default()), Ok(Some(tree)));
}

#[test]
fn every_preset_exports() {
    for &preset in Preset::ALL {
        let tree = generate(&GenerateOptions::new(preset, 7).with_size(500)).unwrap();
        let glb = export_glb(&tree, &ExportOptions::default()).unwrap();
        Gltf::from_slice(&glb).unwrap();
    }
}

/// `cargo test --release -p treemorph-gltf --test generated -- --ignored --nocapture`
#[test]
#[ignore = "timing; run in release with --nocapture"]
fn generated_20k_timing() {
    for &preset in &[Preset::Maple, Preset::Conifer] {
        let options = GenerateOptions::new(preset, 1).with_size(20_000);
        let (mut generate_ms, mut export_ms) = (f64::MAX, f64::MAX);
        let mut size = 0;
        let mut stats = None;
        for _ in 0..5 {
            let start = Instant::now();
            let tree = generate(&options).unwrap();
            generate_ms = generate_ms.min(start.elapsed().as_secs_f64() * 1e3);
            let start = Instant::now();
            let glb = export_glb(&tree, &ExportOptions::default()).unwrap();
            export_ms = export_ms.min(start.elapsed().as_secs_f64() * 1e3);
            size = glb.len();
            stats = Some(tree.stats());
        }
        let stats = stats.unwrap();
        println!(
            "{preset:?}: {} branches, {} leaves: generate {generate_ms:.1} ms, \
             export_glb {export_ms:.1} ms, GLB {size} bytes",
            stats.branches, stats.leaves
        );
    }
}
