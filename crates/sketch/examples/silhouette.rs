//! Prints the crown silhouette of a generated tree (seed 1, default size)
//! in the view of a sketch file, as NDC points — the outline an open
//! oversketch has to start and end near:
//!
//! `cargo run -p treemorph-sketch --example silhouette -- maple examples/sketches/oversketch.json`
use glam::Vec2;
use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_sketch::{Sketch, SketchOptions, SketchPlan, parse_sketch_file};

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [preset, path] = &args[..] else {
        eprintln!("usage: silhouette PRESET SKETCH.json");
        std::process::exit(2);
    };
    let preset: Preset = preset.parse().expect("a preset name");
    let file = parse_sketch_file(&std::fs::read(path).expect("a sketch file")).expect("valid");
    let tree = generate(&GenerateOptions::new(preset, 1)).expect("generated");
    let analysis = Analysis::of(&tree, &AnalysisOptions::default()).expect("analysed");
    // Any sketch overlapping the crown will do: we only want the silhouette.
    let sketch = Sketch {
        points: vec![
            Vec2::new(-1.0, -1.0),
            Vec2::new(1.0, -1.0),
            Vec2::new(0.0, 1.0),
        ],
        closed: true,
    };
    let options = SketchOptions::default().with_fit(treemorph_sketch::Fit::Crown);
    let plan = SketchPlan::new(&tree, &analysis, &file.view, &sketch, &options).expect("planned");
    for p in plan.crown_silhouette() {
        println!("[{:.4}, {:.4}],", p.x, p.y);
    }
}
