//! Timings, printed rather than asserted:
//! `cargo test --release -p treemorph-sketch --test it -- --ignored --nocapture timing`.

use std::time::Instant;

use treemorph_generate::Preset;
use treemorph_sketch::{SketchMetrics, SketchOptions, SketchPlan, Sketcher};

use crate::{example, make};

#[test]
#[ignore = "timing; run in release with --nocapture"]
fn timing() {
    let file = example("heart");
    let options = SketchOptions::default().with_fit(file.fit);
    for size in [5_000u32, 20_000] {
        for &preset in Preset::ALL {
            let f = make(preset, 1, size);
            // Plan: best of 3.
            let mut plan_ms = f64::INFINITY;
            let mut plan = None;
            for _ in 0..3 {
                let t0 = Instant::now();
                let p = SketchPlan::new(&f.tree, &f.analysis, &file.view, &file.sketch, &options)
                    .unwrap();
                plan_ms = plan_ms.min(t0.elapsed().as_secs_f64() * 1e3);
                plan = Some(p);
            }
            let plan = plan.unwrap();
            let mut sketcher = Sketcher::new(&plan);
            let mut frame = sketcher.frame(0.0);
            let frames = 60;
            let t0 = Instant::now();
            for i in 0..=frames {
                sketcher.deform(i as f32 / frames as f32, &mut frame);
            }
            let frame_ms = t0.elapsed().as_secs_f64() * 1e3 / (frames + 1) as f64;
            let mut metrics = SketchMetrics::new(&plan);
            let t0 = Instant::now();
            let m = metrics.measure(&frame);
            let metrics_ms = t0.elapsed().as_secs_f64() * 1e3;
            let t0 = Instant::now();
            sketcher.deform_lobes(0.5).unwrap();
            let lobes_first_ms = t0.elapsed().as_secs_f64() * 1e3;
            let t0 = Instant::now();
            sketcher.deform_lobes(0.7).unwrap();
            let lobes_ms = t0.elapsed().as_secs_f64() * 1e3;
            println!(
                "{preset:12} {:6} branches {:6} leaves {:5} cages: plan {plan_ms:7.1} ms, frame {frame_ms:6.2} ms, metrics {metrics_ms:5.1} ms, lobes {lobes_first_ms:6.1} ms first / {lobes_ms:5.1} ms, IoU {:.3}",
                f.tree.skeleton().branch_count(),
                f.tree.leaves().len(),
                plan.cages().len(),
                m.iou,
            );
        }
    }
}

/// Final IoU of every preset × sketch × seed, both methods:
/// `cargo test --release -p treemorph-sketch --test it -- --ignored --nocapture iou_table`.
#[test]
#[ignore = "report; run in release with --nocapture"]
fn iou_table() {
    use treemorph_sketch::Method;
    for seed in 1..=3u64 {
        for &preset in Preset::ALL {
            let f = make(preset, seed, 5_000);
            let mut row = format!("seed {seed} {preset:12}");
            for sketch in ["heart", "diamond", "star", "crescent"] {
                let file = example(sketch);
                for method in [Method::Multiscale, Method::SingleCage] {
                    let options = SketchOptions::default()
                        .with_fit(file.fit)
                        .with_method(method);
                    let plan =
                        SketchPlan::new(&f.tree, &f.analysis, &file.view, &file.sketch, &options)
                            .unwrap();
                    let frame = Sketcher::new(&plan).frame(1.0);
                    let m = SketchMetrics::new(&plan).measure(&frame);
                    row += &format!(" {sketch}/{method:?}={:.3}", m.iou);
                }
            }
            println!("{row}");
        }
    }
}
