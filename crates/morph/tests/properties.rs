//! Invariants of every morph, over random generated pairs (proptest): the
//! end frames are the inputs, no branch or leaf ever floats, the topology
//! is fixed, numbers are finite, and the motion is continuous.

use proptest::prelude::*;
use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_morph::{FrameMeter, MetricsOptions, MorphOptions, MorphPlan, Morpher};
use treemorph_tree::Tree;

fn analysed(preset: Preset, seed: u64, size: u32) -> (Tree, Analysis) {
    let tree = generate(&GenerateOptions::new(preset, seed).with_size(size)).unwrap();
    let analysis = Analysis::of(&tree, &AnalysisOptions::default()).unwrap();
    (tree, analysis)
}

/// The largest per-frame jump of a `frames`-frame sequence.
fn max_jump(plan: &MorphPlan, frames: usize) -> f32 {
    let mut morpher = Morpher::new(plan);
    let mut frame = morpher.new_frame();
    let mut meter = FrameMeter::new(plan, &MetricsOptions::default());
    let mut worst = 0.0f32;
    for i in 0..=frames {
        morpher.morph(i as f32 / frames as f32, &mut frame);
        worst = worst.max(meter.measure(&frame).unwrap().max_jump);
    }
    worst
}

fn preset() -> impl Strategy<Value = Preset> {
    proptest::sample::select(Preset::ALL.to_vec())
}

fn options() -> impl Strategy<Value = MorphOptions> {
    prop_oneof![
        3 => Just(MorphOptions::default()),
        1 => Just(MorphOptions::one_to_one()),
        1 => any::<bool>().prop_map(|slow_down| {
            let mut o = MorphOptions::default();
            o.slow_down = slow_down;
            o.parallel_threshold = 0; // exercise the rayon path on small trees
            o
        }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn every_frame_is_a_connected_plausible_tree(
        a in preset(), b in preset(),
        sa in 0u64..1000, sb in 0u64..1000,
        na in 50u32..300, nb in 50u32..300,
        options in options(),
    ) {
        let (ta, aa) = analysed(a, sa, na);
        let (tb, ab) = analysed(b, sb, nb);
        let plan = MorphPlan::new(&ta, &aa, &tb, &ab, &options).unwrap();
        let topology = plan.topology();
        let (nodes, leaves) = (topology.node_count(), topology.leaves.len());

        // The morph starts and ends exactly at its inputs.
        let e = plan.endpoint_error();
        prop_assert!(e.source < 1e-5 && e.target < 1e-5, "{a}→{b}: {e:?}");

        let mut morpher = Morpher::new(&plan);
        let mut frame = morpher.new_frame();
        let mut meter = FrameMeter::new(&plan, &MetricsOptions::default());
        for i in 0..=60 {
            let t = i as f32 / 60.0;
            morpher.morph(t, &mut frame);
            prop_assert_eq!(frame.positions.len(), nodes);
            prop_assert_eq!(frame.leaves.len(), leaves);
            // Finite numbers, radii ≥ 0, leaf sizes ≥ 0, blends in [0, 1].
            prop_assert_eq!(frame.check(topology), Ok(()));
            let m = meter.measure(&frame).unwrap();
            prop_assert_eq!(m.floating_branches, 0, "{}→{} at t = {}", a, b, t);
            prop_assert_eq!(m.floating_leaves, 0, "{}→{} at t = {}", a, b, t);
            prop_assert!((0.0..=1.0).contains(&m.mtsw));
            // Continuous motion: nothing crosses a tenth of the tree in
            // one of 60 frames.
            prop_assert!(m.max_jump < 0.1, "{}→{} jumps {} at t = {}", a, b, m.max_jump, t);
        }
    }

    #[test]
    fn motion_is_continuous(
        a in preset(), b in preset(),
        sa in 0u64..1000, sb in 0u64..1000,
        options in options(),
    ) {
        let (ta, aa) = analysed(a, sa, 150);
        let (tb, ab) = analysed(b, sb, 150);
        let plan = MorphPlan::new(&ta, &aa, &tb, &ab, &options).unwrap();
        // Halving the time step about halves the largest step of a
        // continuous motion; a jump would not shrink. A staged morph is
        // paced to even speed, so its largest step is a short burst (a
        // leaf unfolding) that halves less exactly: 0.7, not 0.6.
        let (j60, j120) = (max_jump(&plan, 60), max_jump(&plan, 120));
        prop_assert!(j120 <= 0.7 * j60 + 1e-6, "{}→{}: {} at 60 frames, {} at 120", a, b, j60, j120);
    }
}
