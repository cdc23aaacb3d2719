//! Integration tests of the sketch pipeline on generated trees.

mod acceptance;
mod figure12;
mod properties;
mod timing;
mod validation;

use std::sync::OnceLock;

use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_sketch::{SketchFile, parse_sketch_file};
use treemorph_tree::Tree;

/// A generated tree and its analysis.
pub struct Fixture {
    /// The tree.
    pub tree: Tree,
    /// Its analysis (default options).
    pub analysis: Analysis,
}

/// The default-size tree of `preset` (seed 1, what `treemorph generate`
/// makes by default), generated and analysed once per test binary.
pub fn fixture(preset: Preset) -> &'static Fixture {
    static CACHE: OnceLock<Vec<OnceLock<Fixture>>> = OnceLock::new();
    let cache = CACHE.get_or_init(|| Preset::ALL.iter().map(|_| OnceLock::new()).collect());
    let i = Preset::ALL.iter().position(|&p| p == preset).unwrap();
    cache[i].get_or_init(|| make(preset, 1, GenerateOptions::DEFAULT_SIZE))
}

/// A tree of `size` branches and its analysis.
pub fn make(preset: Preset, seed: u64, size: u32) -> Fixture {
    let tree = generate(&GenerateOptions::new(preset, seed).with_size(size)).unwrap();
    let analysis = Analysis::of(&tree, &AnalysisOptions::default()).unwrap();
    Fixture { tree, analysis }
}

/// One of the example sketch files in `examples/sketches/`.
pub fn example(name: &str) -> SketchFile {
    let bytes: &[u8] = match name {
        "heart" => include_bytes!("../../../../examples/sketches/heart.json"),
        "diamond" => include_bytes!("../../../../examples/sketches/diamond.json"),
        "star" => include_bytes!("../../../../examples/sketches/star.json"),
        "crescent" => include_bytes!("../../../../examples/sketches/crescent.json"),
        "oversketch" => include_bytes!("../../../../examples/sketches/oversketch.json"),
        other => panic!("no example sketch {other}"),
    };
    parse_sketch_file(bytes).unwrap()
}

/// Plans are shared between threads (the service renders frames on a
/// worker pool); sketchers move to them.
#[test]
fn plans_are_send_and_sync() {
    fn shared<T: Send + Sync>() {}
    fn movable<T: Send>() {}
    shared::<treemorph_sketch::SketchPlan>();
    movable::<treemorph_sketch::Sketcher<'static>>();
    movable::<treemorph_sketch::SketchMetrics<'static>>();
}
