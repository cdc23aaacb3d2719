//! The default job without the service: a 60-frame morph of a 5,000-branch
//! maple (seed 1) into a 5,000-branch conifer (seed 2), on trees whose
//! analysis is cached, as a worker runs it (its stored part: the delta
//! stream, `metrics.json` and the plan), and the per-frame measurements
//! that make up most of its frames stage. `benches/job.sh` measures the
//! same job through the service.

use std::collections::HashMap;
use std::sync::Arc;

use treemorph_api::jobs::{JobRequest, MorphRequest, Outputs};
use treemorph_generate::Preset;
use treemorph_gltf::frames::FrameMeshes;
use treemorph_gltf::stream::StreamOptions;
use treemorph_morph::{FrameMeter, MetricsOptions, MorphPlan, Morpher};
use treemorph_tree::Frame;
use treemorph_verify::{CrossingMeter, Hints, MeshView, Plausibility, PlausibilityOptions};

use super::stages::tree;
use super::{Row, measure, thousands};
use crate::pipeline::{
    FrameOutput, InputTree, JobInput, JobSink, JobSpec, Limits, PipelineRunner, Runner, SinkError,
    StoredPlan, frame_instant,
};

/// Frames of the default job.
const FRAMES: u32 = 60;

/// Keeps what a worker would store: the files' size and, for a job's run,
/// the plan.
#[derive(Default)]
pub(super) struct Kept {
    bytes: usize,
    pub(super) plan: Option<Vec<u8>>,
    /// Whether the plan is asked for: a job's run publishes it, a render
    /// of a stored plan does not (the service's render sinks keep none),
    /// so its rows do not time encoding the plan again.
    keeps_plan: bool,
}

impl Kept {
    /// A worker running a job: the plan is kept.
    pub(super) fn run() -> Kept {
        Kept {
            keeps_plan: true,
            ..Kept::default()
        }
    }
}

impl JobSink for Kept {
    fn stage(&mut self, _stage: &'static str, _progress: f32) {}

    fn cancelled(&self) -> bool {
        false
    }

    fn stream_header(&mut self, _bytes: Vec<u8>) -> Result<(), SinkError> {
        Ok(())
    }

    fn frame(&mut self, _frame: FrameOutput) -> Result<(), SinkError> {
        Ok(())
    }

    fn file(&mut self, _name: &str, bytes: Vec<u8>) -> Result<(), SinkError> {
        self.bytes += bytes.len();
        Ok(())
    }

    fn keeps_plan(&self) -> bool {
        self.keeps_plan
    }

    fn plan(&mut self, bytes: Vec<u8>) -> Result<(), SinkError> {
        self.plan = Some(bytes);
        Ok(())
    }
}

/// The default job's trees (analysed) and spec.
fn default_job() -> (HashMap<String, Arc<InputTree>>, JobSpec) {
    default_job_with(Default::default())
}

/// The default job's trees and the spec of its request with `outputs`.
fn default_job_with(outputs: Outputs) -> (HashMap<String, Arc<InputTree>>, JobSpec) {
    let analysed = |preset, seed| {
        let input = InputTree::new(tree(preset, seed, 5_000));
        input.analysis().expect("a generated tree analyses");
        Arc::new(input)
    };
    let trees = HashMap::from([
        ("a".to_owned(), analysed(Preset::Maple, 1)),
        ("b".to_owned(), analysed(Preset::Conifer, 2)),
    ]);
    let request = JobRequest::Morph(MorphRequest {
        source: "a".into(),
        target: "b".into(),
        frames: FRAMES,
        options: Default::default(),
        outputs,
        callback_url: None,
    });
    let spec = JobSpec::parse(&request, &Limits::default()).expect("a valid job");
    (trees, spec)
}

/// Rows: the worker's run, an instant from the stored plan, and the
/// per-frame measurements.
pub(super) fn job_rows(quick: bool, rows: &mut Vec<Row>) {
    let (trees, spec) = default_job();
    let stored = spec.stored_part();
    let input = "maple → conifer".to_owned();
    let size = "5,000/5,000 branches, 60 frames".to_owned();
    let mut kept = Kept::run();
    let timing = measure(quick, || {
        kept = Kept::run();
        let job = JobInput {
            spec: &stored,
            trees: &trees,
            stored_plan: None,
        };
        PipelineRunner::default()
            .run(&job, &mut kept)
            .expect("the default job runs");
    });
    let plan = kept.plan.take().expect("the run published its plan");
    rows.push(Row {
        stage: "default job".into(),
        input: input.clone(),
        size: size.clone(),
        median_ms: timing.0,
        min_ms: timing.1,
        runs: timing.2,
        throughput: format!("{:.0} frames/s", f64::from(FRAMES) * 1e3 / timing.0),
        target_ms: Some(500.0),
        note: format!(
            "plan, stream and metrics.json as a worker runs it; {:.1} MB stream and metrics, {:.1} MB plan",
            kept.bytes as f64 / 1e6,
            plan.len() as f64 / 1e6
        ),
    });
    let timing = time_from_stored_plan(quick, &spec, &plan, |job| {
        let glb = PipelineRunner::default()
            .frame_at(job, 0.375)
            .expect("an instant");
        std::hint::black_box(glb);
    });
    rows.push(stored_plan_row(
        "frame at an instant, stored plan",
        (&input, &size),
        timing,
        (
            50.0,
            "a process that did not run the job: plan read, one GLB (frame.glb?t=)".into(),
        ),
    ));
    rows.push(animation_from_plan(quick, &plan, (&input, &size)));
}

/// `animation.glb` (the default `basis`, float) rendered as the service
/// renders it on its first request: from the stored plan, that output
/// alone, unmeasured.
fn animation_from_plan(quick: bool, plan: &[u8], (input, size): (&str, &str)) -> Row {
    let animated = Outputs {
        glb: false,
        animated: true,
        delta: false,
    };
    let spec = default_job_with(animated).1.unmeasured();
    let mut kept = Kept::default();
    let timing = time_from_stored_plan(quick, &spec, plan, |job| {
        kept = Kept::default();
        PipelineRunner::default()
            .run(job, &mut kept)
            .expect("the animation renders");
    });
    let note = format!(
        "a first request for animation.glb: plan read, 60 frames sampled, a {:.1} MB basis",
        kept.bytes as f64 / 1e6
    );
    stored_plan_row(
        "animation.glb, stored plan",
        (input, size),
        timing,
        (500.0, note),
    )
}

/// Times `render` on the input of a process that did not run the job:
/// no trees, and the plan the job stored.
fn time_from_stored_plan(
    quick: bool,
    spec: &JobSpec,
    plan: &[u8],
    mut render: impl FnMut(&JobInput<'_>),
) -> (f64, f64, usize) {
    measure(quick, || from_stored_plan(spec, plan, &mut render))
}

/// Runs `render` on the input of a process that did not run the job: no
/// trees, and the plan the job stored.
pub(super) fn from_stored_plan<R>(
    spec: &JobSpec,
    plan: &[u8],
    render: impl FnOnce(&JobInput<'_>) -> R,
) -> R {
    let none: HashMap<String, Arc<InputTree>> = HashMap::new();
    let load = || Some(plan.to_vec());
    render(&JobInput {
        spec,
        trees: &none,
        stored_plan: Some(StoredPlan {
            key: "job",
            load: &load,
        }),
    })
}

/// A row of the default job rendered from its stored plan, with its
/// target (ms) and note.
fn stored_plan_row(
    stage: &str,
    (input, size): (&str, &str),
    (median_ms, min_ms, runs): (f64, f64, usize),
    (target, note): (f64, String),
) -> Row {
    Row {
        stage: stage.into(),
        input: input.into(),
        size: size.into(),
        median_ms,
        min_ms,
        runs,
        throughput: String::new(),
        target_ms: Some(target),
        note,
    }
}

/// The output check, the crossings and the construction metrics per frame,
/// each over the default job's whole sequence in order (as a job measures
/// it: the check has the hints of the meshes' writer, and keeps what
/// proved each leaf and piece attached from one frame to the next).
pub(super) fn measurement_rows(quick: bool, rows: &mut Vec<Row>) {
    let (trees, _) = default_job();
    let (input, size) = ("maple → conifer", "5,000/5,000 branches, 60 frames");
    let (a, b) = (&trees["a"], &trees["b"]);
    let options = crate::pipeline::morph_options(&Default::default());
    let plan = MorphPlan::new(
        a.tree(),
        a.analysis().expect("analysed"),
        b.tree(),
        b.analysis().expect("analysed"),
        &options,
    )
    .expect("plan");
    let mut morpher = Morpher::new(&plan);
    let frames: Vec<Frame> = (0..FRAMES)
        .map(|i| {
            let mut frame = Frame::default();
            morpher.morph(frame_instant(i, FRAMES), &mut frame);
            frame
        })
        .collect();
    let radii = treemorph_gltf::frames::max_radii(&frames);
    let mut meshes =
        FrameMeshes::new(plan.topology(), &radii, &StreamOptions::default().mesh).expect("meshes");
    let written: Vec<_> = frames
        .iter()
        .map(|f| {
            let (branches, leaves) = meshes.mesh(f).expect("meshes");
            (branches.clone(), leaves.clone(), meshes.leaves().shape())
        })
        .collect();
    let per_frame = |(median, min, runs): (f64, f64, usize)| {
        let n = f64::from(FRAMES);
        (median / n, min / n, runs)
    };
    let row = |stage: &str, timing: (f64, f64, usize), note: String| Row {
        stage: stage.into(),
        input: input.to_owned(),
        size: size.to_owned(),
        median_ms: timing.0,
        min_ms: timing.1,
        runs: timing.2,
        throughput: String::new(),
        target_ms: None,
        note,
    };
    // The hints a job's check gets from its meshes' writer.
    let hints = Hints::of_tubes(plan.topology(), &meshes.branches().vertex_owners());
    let check = per_frame(measure(quick, || {
        let mut check = Plausibility::new();
        check.set_hints(hints.clone());
        for (branches, leaves, shape) in &written {
            let view = MeshView::of_buffers(branches, leaves, *shape);
            std::hint::black_box(check.check(&view, &PlausibilityOptions::default()))
                .expect("a frame checks");
        }
    }));
    let crossings = per_frame(measure(quick, || {
        let mut meter = CrossingMeter::new();
        for frame in &frames {
            meter.push(&plan.topology().strands, frame);
        }
        std::hint::black_box(meter.crossings());
    }));
    let metrics = per_frame(measure(quick, || {
        let mut meter = FrameMeter::new(&plan, &MetricsOptions::default());
        for frame in &frames {
            std::hint::black_box(meter.measure(frame)).expect("a frame of the plan");
        }
    }));
    let triangles: usize = written.iter().map(|w| w.0.indices.len() / 3).sum();
    rows.extend([
        row(
            "output check per frame",
            check,
            format!(
                "floating leaves and pieces on the written meshes; {} branch triangles a frame",
                thousands(triangles / FRAMES as usize)
            ),
        ),
        row(
            "crossings per frame",
            crossings,
            format!(
                "{} strands' capsules",
                thousands(plan.topology().strands.len())
            ),
        ),
        row(
            "frame metrics per frame",
            metrics,
            "constructed floating parts, MTSW, jumps, growth order, leaf copies".into(),
        ),
    ]);
}
