//! Plan and frame times at the morphing paper's Table 2 sizes (~4.5k/4.5k
//! and ~5k/20k chains), release build:
//!
//! ```text
//! cargo run --release -p treemorph-morph --example timing
//! ```
//!
//! Generation and analysis are not timed (they are other stages). A frame
//! is the skeleton and the leaves (`Morpher::morph`); meshing is timed by
//! the output stage.

use std::time::Instant;

use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_morph::{FrameMeter, MetricsOptions, MorphOptions, MorphPlan, Morpher};

/// Median and fastest of `runs` runs of `f`, in milliseconds.
fn measure(runs: usize, mut f: impl FnMut()) -> (f64, f64) {
    let mut times: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    times.sort_by(f64::total_cmp);
    (times[runs / 2], times[0])
}

fn main() {
    let cases = [
        (
            "4.5k/4.5k",
            (Preset::Eucalyptus, 1, 15_000),
            (Preset::Conifer, 2, 15_000),
        ),
        (
            "5k/20k",
            (Preset::Eucalyptus, 1, 15_000),
            (Preset::Shrub, 2, 70_000),
        ),
    ];
    for (name, a, b) in cases {
        let ta = generate(&GenerateOptions::new(a.0, a.1).with_size(a.2)).unwrap();
        let tb = generate(&GenerateOptions::new(b.0, b.1).with_size(b.2)).unwrap();
        let aa = Analysis::of(&ta, &AnalysisOptions::default()).unwrap();
        let ab = Analysis::of(&tb, &AnalysisOptions::default()).unwrap();
        let options = MorphOptions::default();
        let (plan_median, plan_min) = measure(11, || {
            std::hint::black_box(MorphPlan::new(&ta, &aa, &tb, &ab, &options).unwrap());
        });
        let plan = MorphPlan::new(&ta, &aa, &tb, &ab, &options).unwrap();
        let mut morpher = Morpher::new(&plan);
        let mut frame = morpher.new_frame();
        let mut i = 0;
        let (frame_median, frame_min) = measure(241, || {
            morpher.morph((i % 121) as f32 / 120.0, &mut frame);
            i += 1;
        });
        let mut meter = FrameMeter::new(&plan, &MetricsOptions::default());
        let (meter_median, _) = measure(11, || {
            std::hint::black_box(meter.measure(&frame).unwrap());
        });
        println!(
            "{name}: {} {} → {} {} branches | chains {} / {} | leaves {} / {} | \
             union nodes {} leaves {} | plan {plan_median:.1} ms (min {plan_min:.1}) | \
             frame {frame_median:.2} ms (min {frame_min:.2}) | metrics {meter_median:.2} ms",
            a.0,
            a.2,
            b.0,
            b.2,
            aa.chains().len(),
            ab.chains().len(),
            ta.leaves().len(),
            tb.leaves().len(),
            plan.topology().node_count(),
            plan.topology().leaves.len(),
        );
    }
}
