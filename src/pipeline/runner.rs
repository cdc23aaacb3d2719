//! The production runner: morph and sketch jobs through the geometry crates.
//!
//! Both kinds share one sequence driver ([`render`]): it samples the
//! animation at a few instants to fix what must not change from frame to
//! frame (tube side counts from the largest radius each node reaches, the
//! quantisation grid from the bounds), then computes every frame once and
//! feeds it to each requested encoder in turn — the delta stream (header
//! published before frame 0, so clients start playing at once), the
//! per-frame GLB, the animated GLB's keyframes and the metrics.

use std::time::Instant;

use serde_json::{Value, json};
use treemorph_analysis::Analysis;
use treemorph_api::ErrorCode;
use treemorph_api::jobs::{
    AnimationEncoding, JobRequest, LeafAssignment, Matching, MorphRequest, Outputs, SketchRequest,
};
use treemorph_gltf::animated::{
    AnimatedEncoding, AnimatedGlbBuilder, AnimatedOptions, keyframe_indices,
};
use treemorph_gltf::frame_glb::{FrameGlbOptions, FrameGlbWriter};
use treemorph_gltf::frames::{EncodeError, max_radii};
use treemorph_gltf::stream::{DeltaStreamWriter, StreamOptions};
use treemorph_morph::{FrameMeter, MetricsOptions, MorphOptions, MorphPlan, Morpher};
use treemorph_sketch::{Fit, Method, SketchMetrics, SketchOptions, SketchPlan, Sketcher};
use treemorph_tree::glam::{Vec2, Vec3};
use treemorph_tree::{Aabb, Frame, FrameTopology};

use super::{
    FrameOutput, InputTree, JobError, JobInput, JobOutcome, JobSink, Runner, SinkError, stage,
};

/// Fewest and most frames a job may ask for.
pub const FRAMES_RANGE: std::ops::RangeInclusive<u32> = 2..=600;
/// Keyframes of the animated GLB when the request names none.
pub const DEFAULT_KEYFRAMES: u32 = 24;
/// Instants sampled before encoding to bound radii and positions.
const PROBES: [f32; 5] = [0.0, 0.25, 0.5, 0.75, 1.0];

/// Runs morph and sketch jobs.
#[derive(Debug, Default)]
pub struct PipelineRunner {}

/// Milliseconds since `started`, for the debug timings of a job's stages.
fn ms_since(started: Instant) -> f64 {
    started.elapsed().as_secs_f64() * 1e3
}

fn invalid(code: ErrorCode, message: impl Into<String>) -> JobError {
    JobError {
        code,
        message: message.into(),
        retryable: false,
    }
}

fn internal(message: impl std::fmt::Display) -> JobError {
    JobError {
        code: ErrorCode::Internal,
        message: message.to_string(),
        retryable: false,
    }
}

fn cancelled() -> JobError {
    invalid(ErrorCode::Cancelled, "the job was cancelled")
}

fn stored(e: SinkError) -> JobError {
    JobError {
        code: ErrorCode::Unavailable,
        message: e.to_string(),
        retryable: true,
    }
}

fn encode(e: EncodeError) -> JobError {
    internal(format!("encoding frames: {e}"))
}

fn check_common(frames: u32, keyframes: Option<u32>) -> Result<(), JobError> {
    if !FRAMES_RANGE.contains(&frames) {
        return Err(invalid(
            ErrorCode::InvalidJob,
            format!(
                "frames is {frames}; it must be from {} to {}",
                FRAMES_RANGE.start(),
                FRAMES_RANGE.end()
            ),
        ));
    }
    if let Some(k) = keyframes
        && !(2..=frames).contains(&k)
    {
        return Err(invalid(
            ErrorCode::InvalidJob,
            format!("options.keyframes is {k}; it must be from 2 to frames ({frames})"),
        ));
    }
    Ok(())
}

/// The morph pipeline's options for a request.
pub fn morph_options(request: &MorphRequest) -> Result<MorphOptions, JobError> {
    let mut options = match request.options.matching {
        Matching::OneToMany => MorphOptions::default(),
        Matching::OneToOne => MorphOptions::one_to_one(),
    };
    if request.options.leaves == LeafAssignment::Random {
        // A fixed seed: the same request always gives the same animation.
        let one_to_one = request.options.matching == Matching::OneToOne;
        options = MorphOptions::random_leaves(0);
        if one_to_one {
            options.chain_matching = MorphOptions::one_to_one().chain_matching;
        }
    }
    if let Some(slow_down) = request.options.slow_down {
        options.slow_down = slow_down;
    }
    options
        .validate()
        .map_err(|e| invalid(ErrorCode::InvalidJob, format!("options: {e}")))?;
    Ok(options)
}

/// The sketch pipeline's view, sketch and options for a request.
pub fn sketch_inputs(
    request: &SketchRequest,
) -> Result<
    (
        treemorph_sketch::View,
        treemorph_sketch::Sketch,
        SketchOptions,
    ),
    JobError,
> {
    let v = &request.view;
    let mut view = treemorph_sketch::View::perspective(
        Vec3::from_array(v.eye),
        Vec3::from_array(v.target),
        Vec3::from_array(v.up),
        v.fov_deg.unwrap_or(f32::NAN),
    );
    view.fov_deg = v.fov_deg;
    view.ortho_height = v.ortho_height;
    let sketch = treemorph_sketch::Sketch {
        points: request
            .sketch
            .points
            .iter()
            .map(|p| Vec2::from_array(*p))
            .collect(),
        closed: request.sketch.closed,
    };
    let bad = |e: treemorph_sketch::SketchError| invalid(ErrorCode::InvalidSketch, e.to_string());
    view.camera().map_err(bad)?;
    sketch.validate().map_err(bad)?;
    let method = match request.options.method {
        treemorph_api::jobs::SketchMethod::Multiscale => Method::Multiscale,
        treemorph_api::jobs::SketchMethod::SingleCage => Method::SingleCage,
    };
    let fit = match request.options.fit {
        Some(treemorph_api::jobs::SketchFit::Crown) => Fit::Crown,
        None => Fit::None,
    };
    let options = SketchOptions::default().with_method(method).with_fit(fit);
    options.validate().map_err(bad)?;
    Ok((view, sketch, options))
}

/// Checks everything about a request that needs no tree: frame and
/// keyframe counts, morph options, the sketch's camera and polyline. Every
/// runner (the test runner too) applies it, so `POST /v1/jobs` refuses the
/// same requests whichever runner a process was started with.
pub fn check_request(request: &JobRequest) -> Result<(), JobError> {
    match request {
        JobRequest::Morph(r) => {
            check_common(r.frames, r.options.keyframes)?;
            morph_options(r).map(drop)
        }
        JobRequest::Sketch(r) => {
            check_common(r.frames, r.options.keyframes)?;
            sketch_inputs(r).map(drop)
        }
    }
}

impl Runner for PipelineRunner {
    fn check(&self, request: &JobRequest) -> Result<(), JobError> {
        check_request(request)
    }

    fn run(&self, input: &JobInput<'_>, sink: &mut dyn JobSink) -> Result<JobOutcome, JobError> {
        self.check(input.request)?;
        let tree = |id: &str| -> Result<&InputTree, JobError> {
            input.trees.get(id).map(|t| &**t).ok_or_else(|| {
                invalid(ErrorCode::TreeNotFound, format!("tree {id} was not loaded"))
            })
        };
        match input.request {
            JobRequest::Morph(r) => run_morph(r, tree(&r.source)?, tree(&r.target)?, sink),
            JobRequest::Sketch(r) => run_sketch(r, tree(&r.tree)?, sink),
        }
    }
}

fn analyse(input: &InputTree) -> Result<&Analysis, JobError> {
    input.analysis().map_err(|e| {
        invalid(
            ErrorCode::InvalidTree,
            format!("tree {:?}: {e}", input.tree().name()),
        )
    })
}

fn run_morph(
    request: &MorphRequest,
    source_input: &InputTree,
    target_input: &InputTree,
    sink: &mut dyn JobSink,
) -> Result<JobOutcome, JobError> {
    let options = morph_options(request)?;
    sink.stage(stage::ANALYSING, 0.02);
    // Trees the cache has not analysed yet are analysed side by side.
    let (a, b) = rayon::join(|| analyse(source_input), || analyse(target_input));
    let (a, b) = (a?, b?);
    let (source, target) = (source_input.tree(), target_input.tree());
    if sink.cancelled() {
        return Err(cancelled());
    }
    sink.stage(stage::PLANNING, 0.08);
    let started = Instant::now();
    let plan = MorphPlan::new(source, a, target, b, &options)
        .map_err(|e| invalid(ErrorCode::IncompatibleTrees, e.to_string()))?;
    tracing::debug!(ms = ms_since(started), "morph planned");
    let mut morpher = Morpher::new(&plan);
    let mut meter = FrameMeter::new(&plan, &MetricsOptions::default());
    let n = request.frames as usize;
    let mut series = MorphSeries::with_capacity(n);
    let mut measure_error = None;
    let outcome = render(
        plan.topology(),
        request.frames,
        &request.outputs,
        Animation {
            keyframes: request.options.keyframes,
            encoding: request.options.animation_encoding,
        },
        |t, frame| morpher.morph(t, frame),
        |frame| match meter.measure(frame) {
            Ok(m) => series.push(&m),
            Err(e) => measure_error = Some(e.to_string()),
        },
        sink,
    )?;
    if let Some(e) = measure_error {
        return Err(internal(format!("measuring frames: {e}")));
    }
    let endpoint = plan.endpoint_error();
    let metrics = json!({
        "kind": "morph",
        "frames": n,
        "t": series.t,
        "floating_branches": series.floating_branches,
        "floating_leaves": series.floating_leaves,
        "mtsw": series.mtsw,
        "max_jump": series.max_jump,
        "endpoint_error": {"source": endpoint.source, "target": endpoint.target},
    });
    let summary = json!({
        "floating_branches": series.floating_branches.iter().max().copied().unwrap_or(0),
        "floating_leaves": series.floating_leaves.iter().max().copied().unwrap_or(0),
        "max_jump": series.max_jump.iter().copied().fold(0.0f32, f32::max),
        "endpoint_error": {"source": endpoint.source, "target": endpoint.target},
    });
    finish(outcome, metrics, summary, sink)
}

#[derive(Default)]
struct MorphSeries {
    t: Vec<f32>,
    floating_branches: Vec<u32>,
    floating_leaves: Vec<u32>,
    mtsw: Vec<f32>,
    max_jump: Vec<f32>,
}

impl MorphSeries {
    fn with_capacity(n: usize) -> MorphSeries {
        MorphSeries {
            t: Vec::with_capacity(n),
            floating_branches: Vec::with_capacity(n),
            floating_leaves: Vec::with_capacity(n),
            mtsw: Vec::with_capacity(n),
            max_jump: Vec::with_capacity(n),
        }
    }

    fn push(&mut self, m: &treemorph_morph::FrameMetrics) {
        self.t.push(m.t);
        self.floating_branches.push(m.floating_branches);
        self.floating_leaves.push(m.floating_leaves);
        self.mtsw.push(m.mtsw);
        self.max_jump.push(m.max_jump);
    }
}

fn run_sketch(
    request: &SketchRequest,
    input: &InputTree,
    sink: &mut dyn JobSink,
) -> Result<JobOutcome, JobError> {
    let (view, sketch, options) = sketch_inputs(request)?;
    sink.stage(stage::ANALYSING, 0.02);
    let analysis = analyse(input)?;
    let tree = input.tree();
    if sink.cancelled() {
        return Err(cancelled());
    }
    sink.stage(stage::PLANNING, 0.08);
    let plan = SketchPlan::new(tree, analysis, &view, &sketch, &options)
        .map_err(|e| invalid(ErrorCode::InvalidSketch, e.to_string()))?;
    let mut sketcher = Sketcher::new(&plan);
    let mut meter = SketchMetrics::new(&plan);
    let n = request.frames as usize;
    let mut frechet = Vec::with_capacity(n);
    let mut floating_branches = Vec::with_capacity(n);
    let mut floating_leaves = Vec::with_capacity(n);
    let mut last = None;
    let outcome = render(
        plan.topology(),
        request.frames,
        &request.outputs,
        Animation {
            keyframes: request.options.keyframes,
            encoding: request.options.animation_encoding,
        },
        |t, frame| sketcher.deform(t, frame),
        |frame| {
            let m = meter.measure(frame);
            frechet.push(m.frechet_normalised);
            floating_branches.push(m.floating_branches);
            floating_leaves.push(m.floating_leaves);
            last = Some(m);
        },
        sink,
    )?;
    let last = last.ok_or_else(|| internal("no frame was measured"))?;
    let metrics = json!({
        "kind": "sketch",
        "frames": n,
        "frechet": frechet,
        "final_iou": last.iou,
        "final_frechet": last.frechet_normalised,
        "floating_branches": floating_branches,
        "floating_leaves": floating_leaves,
    });
    let summary = json!({
        "final_iou": last.iou,
        "final_frechet": last.frechet_normalised,
        "floating_branches": floating_branches.iter().max().copied().unwrap_or(0),
        "floating_leaves": floating_leaves.iter().max().copied().unwrap_or(0),
    });
    finish(outcome, metrics, summary, sink)
}

/// What [`render`] produced besides what it published.
struct Rendered {
    frames: u32,
    files: Vec<String>,
}

fn finish(
    rendered: Rendered,
    metrics: Value,
    summary: Value,
    sink: &mut dyn JobSink,
) -> Result<JobOutcome, JobError> {
    let bytes = serde_json::to_vec_pretty(&metrics).map_err(internal)?;
    sink.file("metrics.json", bytes).map_err(stored)?;
    let mut files = rendered.files;
    files.push("metrics.json".into());
    sink.stage(stage::FINISHING, 1.0);
    Ok(JobOutcome {
        frames: rendered.frames,
        metrics: summary,
        files,
    })
}

/// Bounds of every node (with its radius) and leaf (with its size) of a
/// frame.
fn frame_bounds(frame: &Frame) -> Aabb {
    let mut b = Aabb::EMPTY;
    for (p, r) in frame.positions.iter().zip(&frame.radii) {
        b = b.union(Aabb::of_points([*p]).inflated(*r));
    }
    for leaf in &frame.leaves {
        b = b.union(Aabb::of_points([leaf.anchor]).inflated(leaf.width.max(leaf.height)));
    }
    b
}

/// How `animation.glb` is written.
struct Animation {
    keyframes: Option<u32>,
    encoding: AnimationEncoding,
}

/// Computes `frames` frames with `eval`, measures each with `measure` and
/// publishes them through `sink` in every requested format.
fn render(
    topology: &FrameTopology,
    frames: u32,
    outputs: &Outputs,
    animation: Animation,
    mut eval: impl FnMut(f32, &mut Frame),
    mut measure: impl FnMut(&Frame),
    sink: &mut dyn JobSink,
) -> Result<Rendered, JobError> {
    let time = |i: u32| i as f32 / (frames - 1) as f32;
    let mut frame = Frame {
        t: 0.0,
        positions: Vec::new(),
        radii: Vec::new(),
        leaves: Vec::new(),
        bark_blend: 0.0,
    };
    // Side counts and the quantisation grid must hold for the whole
    // sequence, so they come from a few probes before the first frame.
    let started = Instant::now();
    let mut probes = Vec::with_capacity(PROBES.len());
    for &t in &PROBES {
        eval(t, &mut frame);
        probes.push(frame.clone());
    }
    let radii = max_radii(&probes);
    let bounds = probes
        .iter()
        .map(frame_bounds)
        .fold(Aabb::EMPTY, Aabb::union);
    drop(probes);
    tracing::debug!(ms = ms_since(started), "probes sampled");

    let mut stream = if outputs.delta {
        let options = StreamOptions::default().with_frame_count(frames);
        Some(DeltaStreamWriter::new(topology, &radii, bounds, &options).map_err(encode)?)
    } else {
        None
    };
    let mut glb = if outputs.glb {
        Some(FrameGlbWriter::new(topology, &radii, &FrameGlbOptions::default()).map_err(encode)?)
    } else {
        None
    };
    let picks = keyframe_indices(
        frames as usize,
        animation.keyframes.unwrap_or(DEFAULT_KEYFRAMES).min(frames) as usize,
    );
    let mut animated = if outputs.animated {
        let encoding = match animation.encoding {
            AnimationEncoding::Float => AnimatedEncoding::Float,
            AnimationEncoding::Quantized => AnimatedEncoding::Quantized,
            AnimationEncoding::Meshopt => AnimatedEncoding::Meshopt,
        };
        let options = AnimatedOptions::default()
            .with_keyframes(picks.len())
            .with_encoding(encoding);
        Some(AnimatedGlbBuilder::new(topology, &radii, bounds, &options).map_err(encode)?)
    } else {
        None
    };

    let mut whole_stream = Vec::new();
    let mut record = Vec::new();
    let mut next_pick = 0;
    for i in 0..frames {
        if sink.cancelled() {
            return Err(cancelled());
        }
        let t = time(i);
        let started = Instant::now();
        eval(t, &mut frame);
        let eval_ms = ms_since(started);
        // The stream record and the GLB are independent encodings of the
        // same frame, so they are made side by side: on an idle core this
        // halves the time to publish a frame (the first frame's record
        // carries the stream header, as slow to build as the GLB).
        let (header, glb_bytes) = rayon::join(
            || -> Result<Option<usize>, EncodeError> {
                let Some(stream) = &mut stream else {
                    return Ok(None);
                };
                record.clear();
                stream.write_frame(&frame, &mut record)?;
                Ok(Some(if i == 0 {
                    stream.header_bytes().map_or(0, <[u8]>::len)
                } else {
                    0
                }))
            },
            || glb.as_mut().map(|w| w.write(&frame)).transpose(),
        );
        let (header, glb_bytes) = (header.map_err(encode)?, glb_bytes.map_err(encode)?);
        let encoded_ms = ms_since(started);
        let mut delta = Vec::new();
        if let Some(header) = header {
            if i == 0 {
                if header == 0 {
                    return Err(internal("the delta stream wrote no header"));
                }
                sink.stream_header(record[..header].to_vec())
                    .map_err(stored)?;
            }
            whole_stream.extend_from_slice(&record);
            delta = record[header..].to_vec();
        }
        sink.frame(FrameOutput {
            index: i,
            t,
            glb: glb_bytes,
            delta,
        })
        .map_err(stored)?;
        let published_ms = ms_since(started);
        // Metrics and the animated GLB's keyframes wait until the frame is
        // out: clients see it sooner.
        measure(&frame);
        if let Some(builder) = &mut animated
            && picks.get(next_pick) == Some(&(i as usize))
        {
            builder.push(&frame).map_err(encode)?;
            next_pick += 1;
        }
        tracing::debug!(
            frame = i,
            eval_ms,
            encoded_ms,
            published_ms,
            "frame published"
        );
        sink.stage(stage::FRAMES, 0.1 + 0.85 * (i + 1) as f32 / frames as f32);
    }

    let mut files = Vec::new();
    if let Some(stream) = &mut stream {
        stream.finish(&mut whole_stream).map_err(encode)?;
        sink.file("stream.tmd", whole_stream).map_err(stored)?;
        files.push("stream.tmd".into());
    }
    if let Some(builder) = animated {
        sink.stage(stage::FINISHING, 0.96);
        let bytes = builder.finish().map_err(encode)?;
        sink.file("animation.glb", bytes).map_err(stored)?;
        files.push("animation.glb".into());
    }
    Ok(Rendered { frames, files })
}

#[cfg(test)]
#[path = "runner_tests.rs"]
mod tests;
