//! The morph's crossing cost (`treemorph_morph`'s `crossing.rs`), its
//! routing round siblings (`routing.rs`) and its untangling
//! (`untangling.rs`) measured where they matter: the crossings of the frames
//! themselves, by [`CrossingMeter`], with each on (default) and off. The
//! cost and the routing are measured with untangling off, which sheds
//! whatever crossings they leave.

use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_morph::{MorphOptions, MorphPlan, Morpher};
use treemorph_verify::CrossingMeter;

/// Pairs of branches touching mid-morph, summed over the frames of a
/// 25-frame job (instants `i / 24`), and the most in one frame; then the
/// same of pairs of siblings.
fn measure(
    a: (Preset, u64),
    b: (Preset, u64),
    size: u32,
    options: &MorphOptions,
) -> ((u32, u32), (u32, u32)) {
    measure_at(a, b, size, options, 25)
}

/// [`measure`] on the frames of a job of `frames` (at least 2) frames.
fn measure_at(
    a: (Preset, u64),
    b: (Preset, u64),
    size: u32,
    options: &MorphOptions,
    frames: u32,
) -> ((u32, u32), (u32, u32)) {
    assert!(frames >= 2, "a job has at least its two ends");
    let tree = |(p, seed)| generate(&GenerateOptions::new(p, seed).with_size(size)).unwrap();
    let (s, t) = (tree(a), tree(b));
    let analyse = |x| Analysis::of(x, &AnalysisOptions::default()).unwrap();
    let plan = MorphPlan::new(&s, &analyse(&s), &t, &analyse(&t), options).unwrap();
    let mut morpher = Morpher::new(&plan);
    let mut frame = morpher.new_frame();
    let mut meter = CrossingMeter::new();
    for i in 0..frames {
        morpher.morph(i as f32 / (frames - 1) as f32, &mut frame);
        meter.push(&plan.topology().strands, &frame);
    }
    let sum_and_most = |per_frame: &[u32]| {
        (
            per_frame.iter().sum(),
            per_frame.iter().copied().max().unwrap_or(0),
        )
    };
    let siblings = meter.sibling_crossings(&plan.topology().strand_parents());
    (
        sum_and_most(&meter.crossings()),
        sum_and_most(&siblings.per_frame),
    )
}

/// [`measure`]'s crossings of all pairs.
fn crossings(a: (Preset, u64), b: (Preset, u64), size: u32, options: &MorphOptions) -> (u32, u32) {
    measure(a, b, size, options).0
}

#[test]
fn the_crossing_cost_lowers_the_crossings_of_the_written_frames() {
    let on = MorphOptions::default().with_untangle(false);
    let mut off = on.clone();
    off.group_weights.crossing = 0.0;
    let pair = ((Preset::Conifer, 2), (Preset::Willow, 3));
    let without = crossings(pair.0, pair.1, 1500, &off);
    let with = crossings(pair.0, pair.1, 1500, &on);
    eprintln!(
        "conifer → willow, 1,500 branches: crossings (sum, most in a frame) {without:?} without the cost, {with:?} with it"
    );
    assert!(
        with.0 < without.0 && with.1 < without.1,
        "{with:?} against {without:?}"
    );
}

/// Routing (and the junction lift) measured on the written frames of the
/// pair whose trunk carries a hundred limbs that pass each other; the
/// other preset pairs are printed (at 1,500 branches they move by a
/// crossing or two either way).
#[test]
fn routing_round_siblings_lowers_their_crossings_in_the_written_frames() {
    let on = MorphOptions::default().with_untangle(false);
    let off = on.clone().with_route_round(false);
    for (a, b) in [
        ((Preset::Maple, 1), (Preset::Conifer, 2)),
        ((Preset::Willow, 3), (Preset::Eucalyptus, 4)),
        ((Preset::Eucalyptus, 4), (Preset::Shrub, 5)),
        ((Preset::Shrub, 5), (Preset::Maple, 1)),
    ] {
        let without = measure(a, b, 1500, &off);
        let with = measure(a, b, 1500, &on);
        eprintln!("{a:?} → {b:?}: (all, siblings) {without:?} without routing, {with:?} with it");
    }
    let pair = ((Preset::Conifer, 2), (Preset::Willow, 3));
    let without = measure(pair.0, pair.1, 1500, &off);
    let with = measure(pair.0, pair.1, 1500, &on);
    eprintln!("conifer → willow: (all, siblings) {without:?} without routing, {with:?} with it");
    assert!(with.0.0 < without.0.0, "{with:?} against {without:?}");
    assert!(
        with.1.0 < without.1.0 && with.1.1 < without.1.1,
        "{with:?} against {without:?}"
    );
}

/// Untangling on the five preset pairs at 1,500 branches: no crossing in
/// any frame of jobs of 25 and of 97 frames (instants `i / 24` and
/// `i / 96` of the final pace, not the `k / 64` the planner plays, and on
/// the final pace, which refines the rounds' coarse one where the motion
/// is concentrated), where the tangled plans have some in each.
#[test]
fn untangling_sheds_the_crossings_of_the_written_frames() {
    let off = MorphOptions::default().with_untangle(false);
    for (a, b) in [
        ((Preset::Maple, 1), (Preset::Conifer, 2)),
        ((Preset::Conifer, 2), (Preset::Willow, 3)),
        ((Preset::Willow, 3), (Preset::Eucalyptus, 4)),
        ((Preset::Eucalyptus, 4), (Preset::Shrub, 5)),
        ((Preset::Shrub, 5), (Preset::Maple, 1)),
    ] {
        let without = crossings(a, b, 1500, &off);
        let with = [25, 97].map(|n| measure_at(a, b, 1500, &MorphOptions::default(), n).0);
        eprintln!(
            "{a:?} → {b:?}: crossings (sum, most in a frame) {without:?} tangled, {with:?} untangled (25, 97 frames)"
        );
        assert!(without.1 > 0, "{a:?} → {b:?} had nothing to untangle");
        assert_eq!(with, [(0, 0); 2], "{a:?} → {b:?}");
    }
}
