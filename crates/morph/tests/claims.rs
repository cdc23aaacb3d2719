//! The paper's claims (§7), reproduced on generated pairs, and every
//! preset pair morphing cleanly.

use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_morph::{
    FrameMeter, MetricsOptions, MorphOptions, MorphPlan, Morpher, Operation, ScheduleOptions,
};
use treemorph_tree::Tree;

fn analysed(preset: Preset, seed: u64, size: u32) -> (Tree, Analysis) {
    let tree = generate(&GenerateOptions::new(preset, seed).with_size(size)).unwrap();
    let analysis = Analysis::of(&tree, &AnalysisOptions::default()).unwrap();
    (tree, analysis)
}

/// Metrics of every frame of a `frames`-frame sequence.
fn run(plan: &MorphPlan, frames: usize) -> Vec<treemorph_morph::FrameMetrics> {
    let mut morpher = Morpher::new(plan);
    let mut frame = morpher.new_frame();
    let mut meter = FrameMeter::new(plan, &MetricsOptions::default());
    (0..=frames)
        .map(|i| {
            morpher.morph(i as f32 / frames as f32, &mut frame);
            meter.measure(&frame).unwrap()
        })
        .collect()
}

/// Figure 11: leaves matched at random and lerped in world space float
/// away from the branches; ours stay on them.
#[test]
fn random_leaf_matching_floats_leaves_where_ours_does_not() {
    for (a, b) in [
        (Preset::Eucalyptus, Preset::Maple),
        (Preset::Conifer, Preset::Willow),
    ] {
        let (ta, aa) = analysed(a, 1, 400);
        let (tb, ab) = analysed(b, 2, 400);
        let ours = MorphPlan::new(&ta, &aa, &tb, &ab, &MorphOptions::default()).unwrap();
        let base = MorphPlan::new(&ta, &aa, &tb, &ab, &MorphOptions::random_leaves(7)).unwrap();
        let (mo, mb) = (run(&ours, 30), run(&base, 30));
        assert!(
            mo.iter().all(|m| m.floating_leaves == 0),
            "{a}→{b}: ours floats"
        );
        // Both end frames are the inputs, so nothing floats there…
        assert_eq!(mb[0].floating_leaves, 0);
        assert_eq!(mb[30].floating_leaves, 0);
        // …but mid-morph most random leaves hang in the air.
        let mid = mb[15].floating_leaves as usize;
        let leaves = base.topology().leaves.len();
        assert!(mid * 2 > leaves, "{a}→{b}: only {mid} of {leaves} float");
        // The skeleton is the same morph in both.
        assert!(mb.iter().all(|m| m.floating_branches == 0));
    }
}

/// Figure 10: from a single trunk to a multi-stem shrub, one-to-one
/// matching grows the extra stems and the main-trunk support weight drops
/// steeply when they become main stems; splitting shifts it smoothly.
#[test]
fn splitting_shifts_the_trunk_weight_more_smoothly_than_growing_stems() {
    for seed in 0..3 {
        let (ta, aa) = analysed(Preset::Eucalyptus, seed, 1000);
        let (tb, ab) = analysed(Preset::Shrub, seed + 100, 1000);
        // The paper's clock: the claim is about the matching, not timing.
        let linear = MorphOptions::default().with_schedule(ScheduleOptions::linear());
        let ours = MorphPlan::new(&ta, &aa, &tb, &ab, &linear).unwrap();
        let one_to_one = MorphOptions::one_to_one().with_schedule(ScheduleOptions::linear());
        let base = MorphPlan::new(&ta, &aa, &tb, &ab, &one_to_one).unwrap();
        let roots = |p: &MorphPlan, op| {
            p.chains()
                .iter()
                .filter(|c| c.parent.is_none() && c.operation == op)
                .count()
        };
        assert!(roots(&ours, Operation::Split) >= 3);
        assert!(roots(&base, Operation::Grow) >= 2);
        let curve = |p: &MorphPlan| run(p, 60).iter().map(|m| m.mtsw).collect::<Vec<f32>>();
        let (a, b) = (curve(&ours), curve(&base));
        // Same tree at both ends, so the same MTSW there.
        assert!((a[0] - b[0]).abs() < 1e-3 && (a[60] - b[60]).abs() < 0.05);
        let steepest = |c: &[f32]| {
            c.windows(2)
                .map(|w| (w[1] - w[0]).abs())
                .fold(0.0f32, f32::max)
        };
        let (sa, sb) = (steepest(&a), steepest(&b));
        assert!(sa < 0.5 * sb, "seed {seed}: ours {sa}, one-to-one {sb}");
    }
}

/// Every preset pair (6 × 6) morphs without error at a small size.
#[test]
fn every_preset_pair_morphs() {
    let trees: Vec<(Preset, Tree, Analysis)> = Preset::ALL
        .iter()
        .map(|&p| {
            let (t, a) = analysed(p, 5, 120);
            (p, t, a)
        })
        .collect();
    for (p, ta, aa) in &trees {
        for (q, tb, ab) in &trees {
            let plan = MorphPlan::new(ta, aa, tb, ab, &MorphOptions::default())
                .unwrap_or_else(|e| panic!("{p}→{q}: {e}"));
            for m in run(&plan, 8) {
                assert_eq!(m.floating_branches, 0, "{p}→{q} at {}", m.t);
                assert_eq!(m.floating_leaves, 0, "{p}→{q} at {}", m.t);
            }
            let e = plan.endpoint_error();
            assert!(e.source < 1e-5 && e.target < 1e-5, "{p}→{q}: {e:?}");
        }
    }
}
