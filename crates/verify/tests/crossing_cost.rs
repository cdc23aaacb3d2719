//! The morph's crossing cost (`treemorph_morph`'s `crossing.rs`) measured
//! where it matters: the crossings of the frames themselves, by
//! [`CrossingMeter`], with the cost on (default) and off.

use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_morph::{MorphOptions, MorphPlan, Morpher};
use treemorph_verify::CrossingMeter;

/// Pairs of sibling branches touching mid-morph, summed over the frames,
/// and the most in one frame.
fn crossings(a: (Preset, u64), b: (Preset, u64), size: u32, options: &MorphOptions) -> (u32, u32) {
    let tree = |(p, seed)| generate(&GenerateOptions::new(p, seed).with_size(size)).unwrap();
    let (s, t) = (tree(a), tree(b));
    let analyse = |x| Analysis::of(x, &AnalysisOptions::default()).unwrap();
    let plan = MorphPlan::new(&s, &analyse(&s), &t, &analyse(&t), options).unwrap();
    let mut morpher = Morpher::new(&plan);
    let mut frame = morpher.new_frame();
    let mut meter = CrossingMeter::new();
    for i in 0..=24 {
        morpher.morph(i as f32 / 24.0, &mut frame);
        meter.push(&plan.topology().strands, &frame);
    }
    let per_frame = meter.crossings();
    (
        per_frame.iter().sum(),
        per_frame.iter().copied().max().unwrap_or(0),
    )
}

#[test]
fn the_crossing_cost_lowers_the_crossings_of_the_written_frames() {
    let mut off = MorphOptions::default();
    off.group_weights.crossing = 0.0;
    let pair = ((Preset::Conifer, 2), (Preset::Willow, 3));
    let without = crossings(pair.0, pair.1, 1500, &off);
    let with = crossings(pair.0, pair.1, 1500, &MorphOptions::default());
    eprintln!(
        "conifer → willow, 1,500 branches: crossings (sum, most in a frame) {without:?} without the cost, {with:?} with it"
    );
    assert!(
        with.0 < without.0 && with.1 < without.1,
        "{with:?} against {without:?}"
    );
}
