//! Time per frame of the plausibility check on the frames of a default
//! job (a 5,000-branch maple → conifer morph, a morph with random linear
//! leaves — many floating leaves — and a sketch into a cone), meshed as
//! the runner does, and the fast check's reports against the exhaustive
//! reference's.
//!
//! ```sh
//! cargo test --release -p treemorph-verify --test frame_timing -- --ignored --nocapture
//! ```
//!
//! `FRAME_TIMING_ONLY=morph` (or `random`, `sketch`) runs one sequence;
//! `FRAME_TIMING_FAST_ONLY=1` times the fast check alone (for profiling).

mod support;

use std::time::Instant;

use glam::Vec2;
use support::write_frames;
use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_morph::{MorphOptions, MorphPlan, Morpher};
use treemorph_sketch::{Fit, Sketch, SketchOptions, SketchPlan, Sketcher, View};
use treemorph_tree::{Frame, FrameTopology};
use treemorph_verify::{Plausibility, PlausibilityOptions, Report};

/// Frames per sequence.
const FRAMES: u32 = 9;

fn timed(f: impl FnOnce() -> Report) -> (Report, f64) {
    let started = Instant::now();
    let report = f();
    (report, started.elapsed().as_secs_f64() * 1e3)
}

/// Writes every frame of a sequence as the runner does, checks each with
/// the fast check (one context for the sequence, as a job would, and a
/// fresh one: "cold") and the reference, asserts equal reports and prints
/// the times.
fn run(name: &str, topology: &FrameTopology, eval: impl FnMut(f32, &mut Frame)) {
    if std::env::var("FRAME_TIMING_ONLY").is_ok_and(|only| only != name) {
        return;
    }
    let (mut fast, mut reference) = (Plausibility::new(), Plausibility::new());
    let options = PlausibilityOptions::default();
    let (mut fast_sum, mut cold_sum, mut ref_sum) = (0.0, 0.0, 0.0);
    write_frames(topology, FRAMES, eval, |frame, view| {
        let t = frame.t;
        let (a, fast_ms) = timed(|| fast.check(&view, &options).unwrap());
        fast_sum += fast_ms;
        if std::env::var_os("FRAME_TIMING_FAST_ONLY").is_some() {
            // For profiling the fast check alone.
            return;
        }
        let (c, cold_ms) = timed(|| Plausibility::of(&view, &options).unwrap());
        let (b, ref_ms) = timed(|| reference.check_reference(&view, &options).unwrap());
        assert_eq!(a, c, "{name} t={t}");
        assert_eq!(
            (
                a.leaves,
                a.floating_leaves,
                a.branch_pieces,
                a.floating_branches
            ),
            (
                b.leaves,
                b.floating_leaves,
                b.branch_pieces,
                b.floating_branches
            ),
            "{name} t={t}"
        );
        assert_eq!(a, b, "{name} t={t}");
        cold_sum += cold_ms;
        ref_sum += ref_ms;
        eprintln!(
            "{name:>8} t={t:.3}: {:>7} tris {:>6} pieces {:>5} leaves {:>5} floating leaves {:>3} floating pieces: \
             fast {fast_ms:8.2} ms, cold {cold_ms:8.2} ms, reference {ref_ms:8.2} ms",
            view.branch_indices.len() / 3,
            a.branch_pieces,
            a.leaves,
            a.floating_leaves,
            a.floating_branches,
        );
    });
    let n = FRAMES as f64;
    eprintln!(
        "{name:>8} mean ms per frame: fast {:.2}, cold {:.2}, reference {:.2}",
        fast_sum / n,
        cold_sum / n,
        ref_sum / n
    );
}

#[test]
#[ignore = "timing; run in release with --nocapture"]
fn default_job_frames() {
    let tree = |preset, seed| {
        let tree = generate(&GenerateOptions::new(preset, seed).with_size(5000)).unwrap();
        let analysis = Analysis::of(&tree, &AnalysisOptions::default()).unwrap();
        (tree, analysis)
    };
    let (maple, maple_a) = tree(Preset::Maple, 1);
    let (conifer, conifer_a) = tree(Preset::Conifer, 2);
    for (name, options) in [
        ("morph", MorphOptions::default()),
        ("random", MorphOptions::random_leaves(7)),
    ] {
        let plan = MorphPlan::new(&maple, &maple_a, &conifer, &conifer_a, &options).unwrap();
        let mut morpher = Morpher::new(&plan);
        run(name, plan.topology(), |t, f| morpher.morph(t, f));
    }
    let height = maple.stats().height;
    let cone = Sketch {
        points: vec![
            Vec2::new(-0.45, -0.3),
            Vec2::new(0.45, -0.3),
            Vec2::new(0.0, 0.75),
        ],
        closed: true,
    };
    let plan = SketchPlan::new(
        &maple,
        &maple_a,
        &View::front(height),
        &cone,
        &SketchOptions::default().with_fit(Fit::Crown),
    )
    .unwrap();
    let mut sketcher = Sketcher::new(&plan);
    run("sketch", plan.topology(), |t, f| sketcher.deform(t, f));
}
