//! Writes the synthetic sample tree as a GLB and prints how long it took.
//!
//! ```text
//! cargo run --release -p treemorph-gltf --example write_sample -- OUT.glb [BRANCHES] [--no-embed]
//! ```
//!
//! BRANCHES defaults to 20,000. Validate the result with
//! `node tools/gltf-validate/validate.mjs OUT.glb`.

use std::time::Instant;

use treemorph_gltf::{ExportOptions, export_glb, sample::sample_tree};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let out = args
        .next()
        .ok_or("usage: write_sample OUT.glb [BRANCHES] [--no-embed]")?;
    let mut branches = 20_000;
    let mut options = ExportOptions::default();
    for arg in args {
        if arg == "--no-embed" {
            options = options.with_embed_tree(false);
        } else {
            branches = arg.parse()?;
        }
    }
    let start = Instant::now();
    let tree = sample_tree(branches);
    let built = start.elapsed();
    let start = Instant::now();
    let glb = export_glb(&tree, &options)?;
    let exported = start.elapsed();
    std::fs::write(&out, &glb)?;
    let stats = tree.stats();
    println!(
        "{out}: {} branches, {} leaves, {} bytes; tree built in {:.1} ms, export_glb {:.1} ms",
        stats.branches,
        stats.leaves,
        glb.len(),
        built.as_secs_f64() * 1e3,
        exported.as_secs_f64() * 1e3
    );
    Ok(())
}
