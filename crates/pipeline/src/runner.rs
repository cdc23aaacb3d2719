//! The production runner: morph and sketch jobs through the geometry crates.
//!
//! # Floating leaves and branches in `metrics.json`
//! `floating_leaves` and `floating_branches` are measured on the meshes we
//! write (the per-frame GLB's, else the delta stream's, which are the same
//! geometry), by `treemorph-verify`'s output-level check, frame by frame:
//! not on how the frame was built, which cannot see a leaf that hangs in
//! the air because the wood around its node is thinner than assumed. The
//! construction-based counts stay, as `constructed_floating_leaves` and
//! `constructed_floating_branches`.
//!
//! # How natural a sketch stays, in `metrics.json`
//! Measured on every frame written (`treemorph_sketch::SketchMetrics`):
//! `growth` per frame and `max_growth` over the job, the largest growth
//! or shrinking the sketch asks of a chain (`|g − 1|`, `g` its chord now
//! over at rest); `stretch` per frame and `max_stretch` over the job, the
//! largest relative change of a branch segment's length beyond its
//! chain's growth (wilting chains shrink on purpose and are left out in
//! both); and the crown's
//! depth over its width seen from the sketch's camera before and after
//! the job, `crown_depth_width_before` and `crown_depth_width_after` (a
//! crown flattened into a slab facing the camera shows as a falling
//! ratio). The summary carries `max_stretch` and `max_growth`.
//!
//! # How a morph or a sketch moves, in `metrics.json`
//! `max_jump` per frame (the farthest a node or leaf corner moved since
//! the previous frame, over the height) and `jump_ratio`, the largest of
//! those over the median (frames after the first): near 1 for even
//! motion, large where a schedule's window edges make the motion spike.
//! A morph's `growth_out_of_order` per frame counts growing or wilting chains not
//! growing from the tip, and `growth_reversals` those that shrank while
//! growing (or grew while wilting); `coincident_leaves` per frame counts
//! visible leaves drawn on top of another with a different material pair
//! (copies of one leaf, which z-fight). Both kinds count `crossings` per
//! frame: pairs of branch tubes passing through each other that touch at
//! neither end (`treemorph_verify::crossings`), and `sibling_crossings`
//! those of limbs on one parent, with `sibling_pairs` and the largest
//! share of them crossing in a frame (`sibling_crossing_share`). The
//! summary carries the largest of each.
//!
//! Both kinds run from a [`JobSpec`](crate::JobSpec) converted once, and
//! share one sequence driver ([`render`]): it samples the
//! animation at a few instants to fix what must not change from frame to
//! frame (tube side counts from the largest radius each node reaches, the
//! quantisation grid from the bounds), then computes every frame once and
//! feeds it to each requested encoder in turn — the delta stream (header
//! published before frame 0, so clients start playing at once), the
//! per-frame GLB, the animated GLB's keyframes and the metrics.

use std::sync::{Arc, OnceLock};
use std::time::Instant;

use serde_json::{Value, json};
use treemorph_analysis::Analysis;
use treemorph_api::delta::EncoderOptions;
use treemorph_gltf::animated::keyframe_indices;
use treemorph_gltf::basis::{AnimationBuilder, BasisReport};
use treemorph_gltf::frame_glb::{FrameGlbOptions, FrameGlbWriter};
use treemorph_gltf::frames::{EncodeError, FrameMeshes, max_radii};
use treemorph_gltf::mesh::{LeafShape, MeshBuffers};
use treemorph_gltf::stream::{DeltaStreamWriter, StreamOptions};
use treemorph_morph::{FrameMeter, MetricsOptions, MorphPlan, Morpher};
use treemorph_sketch::{SketchMetrics, SketchPlan, Sketcher};
use treemorph_tree::{Aabb, Frame, FrameTopology, JumpMeter, jump_ratio};
use treemorph_verify::{CrossingMeter, Hints, MeshView, Plausibility, PlausibilityOptions, Report};

use crate::plans::{PlanOf, Planned, Plans, Prepared, Writers};
use crate::{
    FrameOutput, InputTree, JobError, JobInput, JobOutcome, JobSink, JobSpec, MorphSpec,
    RenderSpec, Runner, SinkError, SketchSpec, StreamPart, stage,
};

/// Instants sampled before encoding to bound radii and positions.
const PROBES: [f32; 5] = [0.0, 0.25, 0.5, 0.75, 1.0];

/// Runs morph and sketch jobs, and renders their instants on request
/// from the plans it keeps (`plans`).
#[derive(Debug, Default)]
pub struct PipelineRunner {
    plans: Plans,
}

/// Milliseconds since `started`, for the debug timings of a job's stages.
fn ms_since(started: Instant) -> f64 {
    started.elapsed().as_secs_f64() * 1e3
}

fn stored(e: SinkError) -> JobError {
    JobError::unavailable(e.to_string())
}

fn encode(e: EncodeError) -> JobError {
    JobError::from_domain(&e, "encoding frames: ")
}

/// The input trees of a job, in the order its spec names them.
fn spec_trees(input: &JobInput<'_>) -> Result<Vec<Arc<InputTree>>, JobError> {
    let ids = match input.spec {
        JobSpec::Morph(m) => vec![&m.source, &m.target],
        JobSpec::Sketch(s) => vec![&s.tree],
    };
    ids.into_iter().map(|id| input.trees.tree(id)).collect()
}

impl Runner for PipelineRunner {
    /// Plans are deterministic, so every output renders again byte for
    /// byte (`frames_render_again_byte_for_byte` in the tests).
    fn renders_on_request(&self) -> bool {
        true
    }

    /// Starts from a kept or stored plan when there is one (a re-sampled
    /// output of a job costs its frames, not a plan), else plans; keeps
    /// the plan (`plans`), so instants asked of the job next are quick,
    /// and publishes it when the sink keeps plans.
    fn run(&self, input: &JobInput<'_>, sink: &mut dyn JobSink) -> Result<JobOutcome, JobError> {
        let prepared = self.prepared(input, Some(&mut *sink))?;
        // A plan kept from an earlier job is published before the frames,
        // so it is written beside them rather than at the job's end; a
        // new one once its probes are sampled, after the frames.
        let mut unpublished = sink.keeps_plan();
        if unpublished && let Some(bytes) = prepared.stored_bytes() {
            sink.plan(bytes.to_vec()).map_err(stored)?;
            unpublished = false;
        }
        let kept = (&prepared.probed, &prepared.writers);
        let outcome = match (&prepared.plan, input.spec) {
            (Planned::Morph(plan), JobSpec::Morph(m)) => run_morph(m, plan, kept, sink)?,
            (Planned::Sketch(plan), JobSpec::Sketch(s)) => run_sketch(s, plan, kept, sink)?,
            _ => return Err(JobError::internal("a kept plan of another kind of job")),
        };
        if unpublished {
            let bytes = prepared
                .stored_bytes()
                .ok_or_else(|| JobError::internal("the plan's probes were never sampled"))?;
            sink.plan(bytes.to_vec()).map_err(stored)?;
        }
        Ok(outcome)
    }

    fn frame_at(&self, input: &JobInput<'_>, t: f32) -> Result<Vec<u8>, JobError> {
        self.render_instant(input, t, InstantFormat::Glb)
    }

    fn stream_at(
        &self,
        input: &JobInput<'_>,
        t: f32,
        part: StreamPart,
    ) -> Result<Vec<u8>, JobError> {
        self.render_instant(input, t, InstantFormat::Stream(part))
    }
}

impl PipelineRunner {
    /// One instant of a job, from its kept plan or a new one (plans are
    /// deterministic) and the same probes as the whole job (so tube side
    /// counts and the stream's bounds match its frames).
    fn render_instant(
        &self,
        input: &JobInput<'_>,
        t: f32,
        format: InstantFormat,
    ) -> Result<Vec<u8>, JobError> {
        let t = crate::check_instant(t)?;
        let prepared = self.prepared(input, None)?;
        let kept = (&prepared.probed, &prepared.writers);
        match &prepared.plan {
            Planned::Morph(plan) => {
                let mut morpher = Morpher::new(plan);
                let eval = |t, frame: &mut Frame| morpher.morph(t, frame);
                instant(plan.topology(), eval, kept, t, format)
            }
            Planned::Sketch(plan) => {
                let mut sketcher = Sketcher::new(plan);
                let eval = |t, frame: &mut Frame| sketcher.deform(t, frame);
                instant(plan.topology(), eval, kept, t, format)
            }
        }
    }

    /// The job's plan: kept in memory, else stored with the job
    /// ([`JobInput::stored_plan`]), else a new one from its trees; kept.
    /// A run passes its sink, for the stages and cancellation of planning.
    fn prepared(
        &self,
        input: &JobInput<'_>,
        sink: Option<&mut dyn JobSink>,
    ) -> Result<Arc<Prepared>, JobError> {
        let spec = input.spec;
        if let Some(stored) = input.stored_plan {
            let of = PlanOf::Key(stored.key);
            if let Some(kept) = self.plans.get(spec, of) {
                return Ok(kept);
            }
            if let Some(read) = read_stored(stored.load) {
                return Ok(self
                    .plans
                    .insert(spec.clone(), of, read.plan, Some(read.probed)));
            }
            // Not run yet (or its stored plan is unreadable): another job
            // of the same trees and options, planned here, has its plan.
            let trees = spec_trees(input)?;
            if let Some(kept) = self.plans.get(spec, PlanOf::Trees(&trees)) {
                return Ok(kept);
            }
            let plan = new_plan(spec, &trees, sink)?;
            let of = PlanOf::Both(stored.key, &trees);
            return Ok(self.plans.insert(spec.clone(), of, plan, None));
        }
        let trees = spec_trees(input)?;
        if let Some(kept) = self.plans.get(spec, PlanOf::Trees(&trees)) {
            return Ok(kept);
        }
        let plan = new_plan(spec, &trees, sink)?;
        Ok(self
            .plans
            .insert(spec.clone(), PlanOf::Trees(&trees), plan, None))
    }
}

/// The stored plan `load` reads, if it reads one this build renders.
fn read_stored(load: &crate::PlanLoader<'_>) -> Option<crate::stored::StoredPlan> {
    let started = Instant::now();
    let bytes = load()?;
    match crate::stored::read(&bytes) {
        Ok(stored) => {
            tracing::debug!(
                ms = ms_since(started),
                bytes = bytes.len(),
                "stored plan read"
            );
            Some(stored)
        }
        Err(e) => {
            tracing::warn!(error = %e, "planning again: the stored plan cannot be used");
            None
        }
    }
}

/// Analyses a job's trees (side by side when neither is analysed yet)
/// and plans it, reporting stages to `sink` when a run passes one.
fn new_plan(
    spec: &JobSpec,
    trees: &[Arc<InputTree>],
    mut sink: Option<&mut dyn JobSink>,
) -> Result<Planned, JobError> {
    if let Some(sink) = sink.as_deref_mut() {
        sink.stage(stage::ANALYSING, 0.02);
    }
    let analyses = match spec {
        JobSpec::Morph(_) => {
            let (a, b) = rayon::join(|| analyse(&trees[0]), || analyse(&trees[1]));
            vec![a?, b?]
        }
        JobSpec::Sketch(_) => vec![analyse(&trees[0])?],
    };
    if let Some(sink) = sink {
        if sink.cancelled() {
            return Err(JobError::cancelled());
        }
        sink.stage(stage::PLANNING, 0.08);
    }
    Ok(match spec {
        JobSpec::Morph(m) => Planned::Morph(plan_morph(
            m,
            &trees[0],
            analyses[0],
            &trees[1],
            analyses[1],
        )?),
        JobSpec::Sketch(s) => Planned::Sketch(plan_sketch(s, &trees[0], analyses[0])?),
    })
}

/// What a single instant is rendered as.
#[derive(Clone, Copy, Debug)]
enum InstantFormat {
    /// The per-frame GLB.
    Glb,
    /// A delta stream of the one frame, or its frame record.
    Stream(StreamPart),
}

fn plan_morph(
    spec: &MorphSpec,
    source: &InputTree,
    a: &Analysis,
    target: &InputTree,
    b: &Analysis,
) -> Result<MorphPlan, JobError> {
    let started = Instant::now();
    let plan = MorphPlan::new(source.tree(), a, target.tree(), b, &spec.options)
        .map_err(|e| JobError::from_domain(&e, ""))?;
    tracing::debug!(ms = ms_since(started), "morph planned");
    Ok(plan)
}

fn plan_sketch(
    spec: &SketchSpec,
    input: &InputTree,
    analysis: &Analysis,
) -> Result<SketchPlan, JobError> {
    SketchPlan::new(
        input.tree(),
        analysis,
        &spec.view,
        &spec.sketch,
        &spec.options,
    )
    .map_err(|e| JobError::from_domain(&e, ""))
}

/// One instant of a sequence as the job's encoders write it: after the
/// same probes [`render`] samples, and with the bark's texture coordinates
/// fixed by the frame at t = 0, as the job's first frame fixes them.
fn instant(
    topology: &FrameTopology,
    mut eval: impl FnMut(f32, &mut Frame),
    (probed, writers): (&OnceLock<Probed>, &Writers),
    t: f32,
    format: InstantFormat,
) -> Result<Vec<u8>, JobError> {
    let mut frame = Frame::default();
    let probed = probed.get_or_init(|| probe(&mut eval, &mut frame));
    eval(t, &mut frame);
    let mut first = || {
        let mut first = Frame::default();
        eval(0.0, &mut first);
        first
    };
    match format {
        InstantFormat::Glb => {
            let mut writer = match writers.glb.take() {
                Some(kept) => kept,
                None => instant_glb_writer(topology, probed, &first())?,
            };
            let glb = writer.write(&frame).map_err(encode)?;
            writers.glb.keep(writer);
            Ok(glb)
        }
        InstantFormat::Stream(part) => {
            let mut out = Vec::new();
            let mut writer = match writers.stream.take() {
                Some(mut kept) => {
                    kept.restart(&mut out).map_err(encode)?;
                    kept
                }
                None => instant_stream_writer(topology, probed, &first(), &mut out)?,
            };
            let header = out.len();
            writer.write_frame(&frame, &mut out).map_err(encode)?;
            if part == StreamPart::Whole {
                writer.finish(&mut out).map_err(encode)?;
            }
            writers.stream.keep(writer);
            if part == StreamPart::Frame {
                out.drain(..header);
            }
            Ok(out)
        }
    }
}

/// A frame GLB writer for the instants of a sequence whose first frame is
/// `first`.
fn instant_glb_writer(
    topology: &FrameTopology,
    probed: &Probed,
    first: &Frame,
) -> Result<FrameGlbWriter, JobError> {
    let options = FrameGlbOptions::default();
    let mut writer = FrameGlbWriter::new(topology, &probed.radii, &options).map_err(encode)?;
    writer.set_uv_frame(first).map_err(encode)?;
    Ok(writer)
}

/// A one-frame stream writer for the instants of a sequence whose first
/// frame is `first`, its header written to `out`.
fn instant_stream_writer(
    topology: &FrameTopology,
    probed: &Probed,
    first: &Frame,
    out: &mut Vec<u8>,
) -> Result<DeltaStreamWriter, JobError> {
    // One instant at a time, fetched while the user waits: bytes matter
    // more than the millisecond zstd takes.
    let options = StreamOptions::default()
        .with_frame_count(1)
        .with_encoder(EncoderOptions::default());
    let mut writer =
        DeltaStreamWriter::new(topology, &probed.radii, probed.bounds, &options).map_err(encode)?;
    writer.write_header(first, out).map_err(encode)?;
    Ok(writer)
}

fn analyse(input: &InputTree) -> Result<&Analysis, JobError> {
    input
        .analysis()
        .map_err(|e| JobError::from_domain(&e, &format!("tree {:?}: ", input.tree().name())))
}

fn run_morph(
    spec: &MorphSpec,
    plan: &MorphPlan,
    kept: (&OnceLock<Probed>, &Writers),
    sink: &mut dyn JobSink,
) -> Result<JobOutcome, JobError> {
    let mut morpher = Morpher::new(plan);
    let mut meter = FrameMeter::new(plan, &MetricsOptions::default());
    let mut series = MorphSeries::with_capacity(spec.render.frames as usize);
    let mut crossings = CrossingMeter::new();
    let mut measure_error = None;
    let outcome = render(
        (plan.topology(), kept),
        &spec.render,
        |t, frame| morpher.morph(t, frame),
        |frame| {
            let ((), measured) = rayon::join(
                || crossings.push(&plan.topology().strands, frame),
                || meter.measure(frame),
            );
            measured
        },
        |written, measured| match measured {
            Ok(m) => series.push(&m, written),
            Err(e) => measure_error = Some(e),
        },
        sink,
    )?;
    if let Some(e) = measure_error {
        return Err(JobError::internal(format_args!("measuring frames: {e}")));
    }
    let (metrics, summary) = if spec.render.measured {
        series.into_json(
            spec.render.frames,
            plan.endpoint_error(),
            (&crossings, plan.topology()),
        )
    } else {
        unmeasured(spec.render.frames)
    };
    finish(outcome, metrics, summary, sink)
}

/// The metrics of an [unmeasured](crate::JobSpec::unmeasured) run: the
/// frame count, and that nothing was measured.
fn unmeasured(frames: u32) -> (Value, Value) {
    let summary = json!({"frames": frames, "measured": false});
    (summary.clone(), summary)
}

#[derive(Default)]
struct MorphSeries {
    t: Vec<f32>,
    written: WrittenSeries,
    constructed_floating_branches: Vec<u32>,
    constructed_floating_leaves: Vec<u32>,
    mtsw: Vec<f32>,
    max_jump: Vec<f32>,
    growth_out_of_order: Vec<u32>,
    growth_reversals: Vec<u32>,
    coincident_leaves: Vec<u32>,
}

impl MorphSeries {
    fn with_capacity(n: usize) -> MorphSeries {
        MorphSeries {
            t: Vec::with_capacity(n),
            written: WrittenSeries::with_capacity(n),
            constructed_floating_branches: Vec::with_capacity(n),
            constructed_floating_leaves: Vec::with_capacity(n),
            mtsw: Vec::with_capacity(n),
            max_jump: Vec::with_capacity(n),
            growth_out_of_order: Vec::with_capacity(n),
            growth_reversals: Vec::with_capacity(n),
            coincident_leaves: Vec::with_capacity(n),
        }
    }

    fn push(&mut self, m: &treemorph_morph::FrameMetrics, written: &Report) {
        self.t.push(m.t);
        self.written.push(written);
        self.constructed_floating_branches.push(m.floating_branches);
        self.constructed_floating_leaves.push(m.floating_leaves);
        self.mtsw.push(m.mtsw);
        self.max_jump.push(m.max_jump);
        self.growth_out_of_order.push(m.growth_out_of_order);
        self.growth_reversals.push(m.growth_reversals);
        self.coincident_leaves.push(m.coincident_leaves);
    }

    /// `metrics.json` and the job's summary metrics.
    fn into_json(
        self,
        frames: u32,
        endpoint: treemorph_morph::EndpointError,
        crossings: (&CrossingMeter, &FrameTopology),
    ) -> (Value, Value) {
        let max = |v: &[u32]| v.iter().copied().max().unwrap_or(0);
        let mut summary = json!({
            "max_jump": self.max_jump.iter().copied().fold(0.0f32, f32::max),
            "jump_ratio": jump_ratio(&self.max_jump),
            "growth_out_of_order": max(&self.growth_out_of_order),
            "growth_reversals": max(&self.growth_reversals),
            "coincident_leaves": max(&self.coincident_leaves),
            "endpoint_error": {"source": endpoint.source, "target": endpoint.target},
        });
        let mut metrics = json!({
            "kind": "morph",
            "frames": frames,
            "t": self.t,
            "constructed_floating_branches": self.constructed_floating_branches,
            "constructed_floating_leaves": self.constructed_floating_leaves,
            "mtsw": self.mtsw,
            "max_jump": self.max_jump,
            "jump_ratio": jump_ratio(&self.max_jump),
            "growth_out_of_order": self.growth_out_of_order,
            "growth_reversals": self.growth_reversals,
            "coincident_leaves": self.coincident_leaves,
            "endpoint_error": {"source": endpoint.source, "target": endpoint.target},
        });
        self.written
            .write_into(crossings, &mut metrics, &mut summary);
        (metrics, summary)
    }
}

fn run_sketch(
    spec: &SketchSpec,
    plan: &SketchPlan,
    kept: (&OnceLock<Probed>, &Writers),
    sink: &mut dyn JobSink,
) -> Result<JobOutcome, JobError> {
    let mut sketcher = Sketcher::new(plan);
    let mut meter = SketchMetrics::new(plan);
    let mut series = SketchSeries::with_capacity(spec.render.frames as usize, plan.height());
    let (mut crossings, mut jumps) = (CrossingMeter::new(), JumpMeter::default());
    let outcome = render(
        (plan.topology(), kept),
        &spec.render,
        |t, frame| sketcher.deform(t, frame),
        |frame| {
            let ((), measured) = rayon::join(
                || crossings.push(&plan.topology().strands, frame),
                || (meter.measure(frame), jumps.jump(frame)),
            );
            measured
        },
        |written, measured| series.push(measured, written),
        sink,
    )?;
    let (metrics, summary) = if spec.render.measured {
        series
            .into_json(spec.render.frames, (&crossings, plan.topology()))
            .ok_or_else(|| JobError::internal("no frame was measured"))?
    } else {
        unmeasured(spec.render.frames)
    };
    finish(outcome, metrics, summary, sink)
}

#[derive(Default)]
struct SketchSeries {
    frechet: Vec<f32>,
    stretch: Vec<f32>,
    growth: Vec<f32>,
    /// The tree's height (jumps are fractions of it).
    height: f32,
    max_jump: Vec<f32>,
    first_depth_width: Option<f32>,
    written: WrittenSeries,
    constructed_floating_branches: Vec<usize>,
    constructed_floating_leaves: Vec<usize>,
    last: Option<treemorph_sketch::FrameMetrics>,
}

impl SketchSeries {
    fn with_capacity(n: usize, height: f32) -> SketchSeries {
        SketchSeries {
            height: height.max(f32::MIN_POSITIVE),
            frechet: Vec::with_capacity(n),
            stretch: Vec::with_capacity(n),
            growth: Vec::with_capacity(n),
            max_jump: Vec::with_capacity(n),
            first_depth_width: None,
            written: WrittenSeries::with_capacity(n),
            constructed_floating_branches: Vec::with_capacity(n),
            constructed_floating_leaves: Vec::with_capacity(n),
            last: None,
        }
    }

    fn push(&mut self, (m, jump): (treemorph_sketch::FrameMetrics, f32), written: &Report) {
        self.frechet.push(m.frechet_normalised);
        self.max_jump.push(jump / self.height);
        self.stretch.push(m.max_stretch);
        self.growth.push(m.max_growth);
        self.first_depth_width.get_or_insert(m.crown_depth_width);
        self.written.push(written);
        self.constructed_floating_branches.push(m.floating_branches);
        self.constructed_floating_leaves.push(m.floating_leaves);
        self.last = Some(m);
    }

    /// `metrics.json` and the job's summary metrics; `None` when no frame
    /// was measured.
    fn into_json(
        self,
        frames: u32,
        crossings: (&CrossingMeter, &FrameTopology),
    ) -> Option<(Value, Value)> {
        let last = self.last?;
        let max_stretch = self.stretch.iter().copied().fold(0.0f32, f32::max);
        let max_growth = self.growth.iter().copied().fold(0.0f32, f32::max);
        let before = self.first_depth_width.unwrap_or(last.crown_depth_width);
        let mut summary = json!({
            "final_iou": last.iou,
            "final_frechet": last.frechet_normalised,
            "max_stretch": max_stretch,
            "max_growth": max_growth,
            "jump_ratio": jump_ratio(&self.max_jump),
        });
        let mut metrics = json!({
            "kind": "sketch",
            "frames": frames,
            "frechet": self.frechet,
            "final_iou": last.iou,
            "final_frechet": last.frechet_normalised,
            "stretch": self.stretch,
            "max_stretch": max_stretch,
            "growth": self.growth,
            "max_growth": max_growth,
            "max_jump": self.max_jump,
            "jump_ratio": jump_ratio(&self.max_jump),
            "crown_depth_width_before": before,
            "crown_depth_width_after": last.crown_depth_width,
            "constructed_floating_branches": self.constructed_floating_branches,
            "constructed_floating_leaves": self.constructed_floating_leaves,
        });
        self.written
            .write_into(crossings, &mut metrics, &mut summary);
        Some((metrics, summary))
    }
}

/// The output-level counts of every frame as written (`treemorph-verify`).
#[derive(Default)]
struct WrittenSeries {
    floating_branches: Vec<u32>,
    floating_leaves: Vec<u32>,
}

impl WrittenSeries {
    fn with_capacity(n: usize) -> WrittenSeries {
        WrittenSeries {
            floating_branches: Vec::with_capacity(n),
            floating_leaves: Vec::with_capacity(n),
        }
    }

    fn push(&mut self, report: &Report) {
        self.floating_branches.push(report.floating_branches);
        self.floating_leaves.push(report.floating_leaves);
    }

    /// Adds the per-frame counts and the crossings of the frames' branch
    /// tubes to `metrics.json` and their maxima to the summary, under the
    /// names both have always had (`crossings` is new). Of the crossings,
    /// those between limbs of one parent (`sibling_crossings`) are also
    /// given as a share of all such pairs of the topology
    /// (`sibling_crossing_share`, the most in a frame), the figure the
    /// matching's crossing cost answers for on any tree.
    fn write_into(
        self,
        (meter, topology): (&CrossingMeter, &FrameTopology),
        metrics: &mut Value,
        summary: &mut Value,
    ) {
        let max = |v: &[u32]| v.iter().max().copied().unwrap_or(0);
        let siblings = meter.sibling_crossings(&topology.strand_parents());
        let share = siblings.share();
        summary["sibling_crossing_share"] = share.into();
        metrics["sibling_crossings"] = siblings.per_frame.into();
        metrics["sibling_pairs"] = siblings.pairs.into();
        metrics["sibling_crossing_share"] = share.into();
        let crossings = meter.crossings();
        summary["floating_branches"] = max(&self.floating_branches).into();
        summary["floating_leaves"] = max(&self.floating_leaves).into();
        summary["crossings"] = max(&crossings).into();
        metrics["floating_branches"] = self.floating_branches.into();
        metrics["floating_leaves"] = self.floating_leaves.into();
        metrics["crossings"] = crossings.into();
    }
}

/// The output-level plausibility check of each frame as written
/// (`treemorph-verify`).
///
/// It runs on the second core while the next frame is computed, encoded
/// and published ([`render`]): it is the most expensive step of a frame
/// (more than half of a 5,000-branch morph's frame time), and a job
/// succeeds sooner when it overlaps the rest. So the positions and indices
/// just written are copied ([`NextGeometry::take`]) and measured later
/// ([`Checker::check`]). The copy goes to a second buffer while the check
/// reads the first, and the two swap after each frame: the copy (the
/// positions, 3.4 MB a frame on the default morph's 284,000 vertices; the
/// indices only once, [`copy_geometry`]) is then part of the frame's
/// parallel work, beside the construction metrics, instead of a serial
/// step between frames.
struct OutputCheck {
    checker: Checker,
    next: NextGeometry,
}

/// Checks the geometry of one frame.
struct Checker {
    check: Plausibility,
    options: PlausibilityOptions,
    geometry: Geometry,
}

/// What the check reads of a frame's written meshes.
struct Geometry {
    /// Positions and indices only.
    branches: MeshBuffers,
    leaves: MeshBuffers,
    shape: LeafShape,
}

/// Where the next frame's geometry is copied while the last is checked.
struct NextGeometry {
    /// Meshes of its own, for jobs that write neither per-frame GLBs nor
    /// the stream (only the animated GLB): the per-frame GLB's geometry.
    own: Option<FrameMeshes>,
    geometry: Geometry,
}

impl OutputCheck {
    /// The check of a job's frames, in `kept`'s context when a job of the
    /// plan left one ([`Plausibility::start_sequence`]).
    fn new(
        topology: &FrameTopology,
        probed: &Probed,
        encoders: &Encoders,
        kept: Option<Plausibility>,
    ) -> Result<OutputCheck, JobError> {
        let mesh = FrameGlbOptions::default().mesh;
        let own = (encoders.glb.is_none() && encoders.stream.is_none())
            .then(|| FrameMeshes::new(topology, &probed.radii, &mesh))
            .transpose()
            .map_err(encode)?;
        let geometry = || Geometry {
            branches: MeshBuffers::default(),
            leaves: MeshBuffers::default(),
            shape: mesh.leaf_shape,
        };
        let hints = checked_meshes(encoders, own.as_ref())
            .map(|meshes| Hints::of_tubes(topology, &meshes.branches().vertex_owners()))
            .unwrap_or_default();
        let mut check = kept.unwrap_or_default();
        check.start_sequence(hints);
        Ok(OutputCheck {
            checker: Checker {
                check,
                options: PlausibilityOptions::default(),
                geometry: geometry(),
            },
            next: NextGeometry {
                own,
                geometry: geometry(),
            },
        })
    }

    /// Makes the last copy the one to check.
    fn swap(&mut self) {
        std::mem::swap(&mut self.checker.geometry, &mut self.next.geometry);
    }
}

/// The meshes the output check reads: the per-frame GLB's, else the
/// stream's, else the check's `own`.
fn checked_meshes<'a>(
    encoders: &'a Encoders,
    own: Option<&'a FrameMeshes>,
) -> Option<&'a FrameMeshes> {
    match (&encoders.glb, &encoders.stream) {
        (Some(glb), _) => Some(glb.meshes()),
        (None, Some(stream)) => Some(stream.meshes()),
        (None, None) => own,
    }
}

impl NextGeometry {
    /// Copies the meshes `encoders` just wrote for `frame` (or meshes the
    /// frame, when no encoder does).
    fn take(&mut self, frame: &Frame, encoders: &Encoders) -> Result<(), JobError> {
        if let Some(own) = &mut self.own {
            own.mesh(frame).map_err(encode)?;
        }
        let meshes = checked_meshes(encoders, self.own.as_ref())
            .ok_or_else(|| JobError::internal("no meshes to check"))?;
        let to = &mut self.geometry;
        copy_geometry(&mut to.branches, meshes.branches().buffers());
        copy_geometry(&mut to.leaves, meshes.leaves().buffers());
        to.shape = meshes.leaves().shape();
        Ok(())
    }
}

impl Checker {
    /// Checks the geometry swapped in last ([`OutputCheck::swap`]).
    fn check(&mut self) -> Result<Report, JobError> {
        let g = &self.geometry;
        let view = MeshView::of_buffers(&g.branches, &g.leaves, g.shape);
        self.check
            .check(&view, &self.options)
            .map_err(|e| JobError::internal(format_args!("checking a frame: {e}")))
    }
}

/// Copies what the check reads (positions and indices), reusing `to`'s
/// allocations. A mesher's indices are fixed when it is made (the gltf
/// crate's meshers overwrite only positions, normals and bounds per
/// frame), and `to` always copies the same mesher, so its indices are
/// copied once: copying them every frame was 3.7 MB a frame on the
/// default morph, about 1.5 % of a job's CPU.
fn copy_geometry(to: &mut MeshBuffers, from: &MeshBuffers) {
    to.positions.clone_from(&from.positions);
    if to.indices.len() != from.indices.len() {
        to.indices.clone_from(&from.indices);
    }
    debug_assert_eq!(to.indices, from.indices, "a mesher's indices changed");
}

/// What [`render`] produced besides what it published.
struct Rendered {
    frames: u32,
    files: Vec<String>,
    /// What the basis animation reached, when one was written.
    animation: Option<BasisReport>,
}

/// Publishes `metrics.json` and reports the run.
fn finish(
    rendered: Rendered,
    mut metrics: Value,
    summary: Value,
    sink: &mut dyn JobSink,
) -> Result<JobOutcome, JobError> {
    if let Some(report) = &rendered.animation {
        add_animation_metrics(&mut metrics, report);
    }
    let bytes = serde_json::to_vec_pretty(&metrics).map_err(JobError::internal)?;
    sink.file("metrics.json", bytes).map_err(stored)?;
    let mut files = rendered.files;
    files.push("metrics.json".into());
    sink.stage(stage::FINISHING, 1.0);
    let outcome = JobOutcome {
        frames: rendered.frames,
        metrics: summary,
        files,
    };
    Ok(outcome)
}

/// The basis or skinned animation's figures in `metrics.json`: its morph
/// target count, its largest vertex error as a fraction of the tree's
/// height, whether that is within the budget, how many targets carry
/// normals and the normals' largest mean error in degrees, and a
/// skeleton's joint count.
fn add_animation_metrics(metrics: &mut Value, report: &BasisReport) {
    metrics["animation_targets"] = report.targets.into();
    metrics["animation_max_error"] = f64::from(report.max_error).into();
    metrics["animation_within_budget"] = report.within_budget.into();
    metrics["animation_normal_targets"] = report.normal_targets.into();
    metrics["animation_normal_error_degrees"] = f64::from(report.normal_error_degrees).into();
    if report.joints > 0 {
        metrics["animation_joints"] = report.joints.into();
    }
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

/// What must hold for the whole sequence: tube radii per node and the
/// bounds of every frame.
#[derive(serde::Serialize, serde::Deserialize)]
pub(crate) struct Probed {
    radii: Vec<f32>,
    bounds: Aabb,
}

/// Side counts and the quantisation grid must hold for the whole
/// sequence, so they come from a few probes before the first frame.
fn probe(eval: &mut impl FnMut(f32, &mut Frame), frame: &mut Frame) -> Probed {
    let started = Instant::now();
    let mut probes = Vec::with_capacity(PROBES.len());
    for &t in &PROBES {
        eval(t, frame);
        probes.push(frame.clone());
    }
    let radii = max_radii(&probes);
    let bounds = probes
        .iter()
        .map(frame_bounds)
        .fold(Aabb::EMPTY, Aabb::union);
    tracing::debug!(ms = ms_since(started), "probes sampled");
    Probed { radii, bounds }
}

/// The encoders a job's outputs ask for.
struct Encoders {
    stream: Option<DeltaStreamWriter>,
    /// Whether `stream` was kept from a job of the plan and restarts after
    /// its header before the first frame ([`Writers`]).
    restart: bool,
    glb: Option<FrameGlbWriter>,
}

/// The animated GLB's builder and the frames that become its keyframes.
/// A keyframe is kept as a copy and added to the builder while the next
/// frame is computed ([`render`]): meshing a keyframe took longer than
/// evaluating a frame, and ran after it on the default morph (60 frames:
/// 160 ms of meshing, 70 ms of evaluation).
#[derive(Default)]
struct Keyframes {
    animated: Option<AnimationBuilder>,
    /// Frame indices that become keyframes of the animated GLB.
    picks: Vec<usize>,
    next_pick: usize,
    /// The last keyframe kept and not added yet.
    waiting: Option<Frame>,
}

impl Keyframes {
    /// Keeps a copy of frame `i` when it is a keyframe.
    fn keep(&mut self, i: u32, frame: &Frame) {
        if self.animated.is_some() && self.picks.get(self.next_pick) == Some(&(i as usize)) {
            self.waiting = Some(frame.clone());
            self.next_pick += 1;
        }
    }

    /// Adds the keyframe kept last, if any, to the animated GLB.
    fn add_waiting(&mut self) -> Result<(), JobError> {
        if let (Some(builder), Some(frame)) = (&mut self.animated, self.waiting.take()) {
            builder.push(&frame).map_err(encode)?;
        }
        Ok(())
    }
}

impl Encoders {
    /// The per-frame encoders and, apart (their work runs beside the
    /// next frame's), the animated GLB's keyframes.
    fn new(
        topology: &FrameTopology,
        render: &RenderSpec,
        probed: &Probed,
        writers: &Writers,
    ) -> Result<(Encoders, Keyframes), JobError> {
        let outputs = &render.outputs;
        let kept = outputs
            .delta
            .then(|| writers.job_stream.take())
            .flatten()
            .filter(|(frames, _)| *frames == render.frames);
        let restart = kept.is_some();
        let stream = match kept {
            Some((_, writer)) => Some(writer),
            None => outputs
                .delta
                .then(|| {
                    let options = StreamOptions::default().with_frame_count(render.frames);
                    DeltaStreamWriter::new(topology, &probed.radii, probed.bounds, &options)
                })
                .transpose()
                .map_err(encode)?,
        };
        let glb = outputs
            .glb
            .then(|| FrameGlbWriter::new(topology, &probed.radii, &FrameGlbOptions::default()))
            .transpose()
            .map_err(encode)?;
        let picks = keyframe_indices(render.frames as usize, render.keyframes as usize);
        let animated = outputs
            .animated
            .then(|| {
                let options = render
                    .animation
                    .default_options()
                    .with_keyframes(picks.len())
                    .with_encoding(render.encoding)
                    .with_skeleton_joints(render.skeleton_joints as usize);
                AnimationBuilder::new(
                    render.animation,
                    topology,
                    &probed.radii,
                    probed.bounds,
                    &options,
                )
            })
            .transpose()
            .map_err(encode)?;
        let keyframes = Keyframes {
            animated,
            picks,
            ..Keyframes::default()
        };
        let encoders = Encoders {
            stream,
            restart,
            glb,
        };
        Ok((encoders, keyframes))
    }

    /// Keeps the stream writer of a job that ended well for the next job
    /// of the plan with as many `frames` ([`Writers`]).
    fn keep(self, frames: u32, writers: &Writers) {
        if let Some(stream) = self.stream {
            writers.job_stream.keep((frames, stream));
        }
    }

    /// Encodes frame `i` as a stream record (into `record`; returns the
    /// length of the header at its start, which only frame 0 carries) and
    /// as a GLB. The two are independent encodings of the same frame, so
    /// they are made side by side: on an idle core this halves the time to
    /// publish a frame (the first frame's record carries the stream header,
    /// as slow to build as the GLB).
    fn encode(
        &mut self,
        i: u32,
        frame: &Frame,
        record: &mut Vec<u8>,
    ) -> Result<(Option<usize>, Option<Vec<u8>>), JobError> {
        let (stream, glb) = (&mut self.stream, &mut self.glb);
        let restart = std::mem::take(&mut self.restart);
        let (header, glb_bytes) = rayon::join(
            || -> Result<Option<usize>, EncodeError> {
                let Some(stream) = stream else {
                    return Ok(None);
                };
                record.clear();
                if restart {
                    stream.restart(record)?;
                }
                stream.write_frame(frame, record)?;
                Ok(Some(if i == 0 {
                    stream.header_bytes().map_or(0, <[u8]>::len)
                } else {
                    0
                }))
            },
            || glb.as_mut().map(|w| w.write(frame)).transpose(),
        );
        Ok((header.map_err(encode)?, glb_bytes.map_err(encode)?))
    }

    /// Publishes the whole-sequence files, the animated GLB from
    /// `keyframes`.
    fn finish(
        &mut self,
        whole_stream: WholeStream,
        keyframes: Keyframes,
        sink: &mut dyn JobSink,
    ) -> Result<(Vec<String>, Option<BasisReport>), JobError> {
        let mut files = Vec::new();
        let mut report = None;
        if let Some(stream) = &mut self.stream {
            whole_stream.finish(stream, sink)?;
            files.push("stream.tmd".into());
        }
        if let Some(builder) = keyframes.animated {
            sink.stage(stage::FINISHING, 0.96);
            let (bytes, basis) = builder.finish().map_err(encode)?;
            sink.file("animation.glb", bytes).map_err(stored)?;
            files.push("animation.glb".into());
            report = basis;
        }
        Ok((files, report))
    }
}

/// Computes the spec's frames with `eval`, publishes them through `sink`
/// in every requested format (with the plan's `probes`, sampled by its
/// first job or render and kept with it: 8.7 ms of a repeated default
/// job's start went to sampling them again; and with the stream writer
/// and check context a job of the plan kept in `writers`), and measures
/// each unless the spec is
/// [unmeasured](crate::JobSpec::unmeasured): `construct` right after the
/// frame is computed (what its construction says), then `measure` with
/// that and the output-level check of the frame as written. Frame `i`'s
/// check and `measure` run while frame `i + 1` is evaluated, then
/// constructed-measured and encoded side by side ([`OutputCheck`]), so
/// `measure` sees frame `i` once frame `i + 1` is computed, and the last
/// frame after the loop; the metrics are the same, in the same order.
/// The frame's own work is split in tasks (the construction metrics and
/// the crossings apart, beside the encoding) so that the core that ends
/// the check first takes what is left: on the default morph the check
/// took 8.5 ms a frame, and evaluating, constructing and encoding 12.6 ms
/// one after the other.
fn render<M: Send>(
    (topology, (probes, writers)): (&FrameTopology, (&OnceLock<Probed>, &Writers)),
    spec: &RenderSpec,
    mut eval: impl FnMut(f32, &mut Frame) + Send,
    mut construct: impl FnMut(&Frame) -> M + Send,
    mut measure: impl FnMut(&Report, M) + Send,
    sink: &mut dyn JobSink,
) -> Result<Rendered, JobError> {
    let frames = spec.frames;
    let mut frame = Frame::default();
    let probed = probes.get_or_init(|| probe(&mut eval, &mut frame));
    let (mut encoders, mut keyframes) = Encoders::new(topology, spec, probed, writers)?;
    let mut output_check = spec
        .measured
        .then(|| OutputCheck::new(topology, probed, &encoders, writers.checker.take()))
        .transpose()?;
    let mut whole_stream = WholeStream::Unasked;
    let mut record = Vec::new();
    // The last frame computed, published while the next one is.
    let mut unpublished: Option<Unpublished> = None;
    // What `construct` said of the frame whose copy waits for its check
    // (see `OutputCheck`).
    let mut waiting = None;
    for i in 0..frames {
        if sink.cancelled() {
            return Err(JobError::cancelled());
        }
        let t = crate::frame_instant(i, frames);
        let started = Instant::now();
        let measuring = output_check.is_some();
        let (checker, next) = match &mut output_check {
            Some(c) => (Some(&mut c.checker), Some(&mut c.next)),
            None => (None, None),
        };
        let mut computed = None;
        // The sink stays on this thread (it need not be `Send`); the frame
        // is computed on the pool meanwhile.
        rayon::in_place_scope(|scope| {
            scope.spawn(|_| {
                computed = Some(rayon::join(
                    || {
                        let (checked, added) = rayon::join(
                            || match (checker, waiting.take()) {
                                (Some(check), Some(m)) => {
                                    check.check().map(|report| measure(&report, m))
                                }
                                _ => Ok(()),
                            },
                            || keyframes.add_waiting(),
                        );
                        checked.and(added)
                    },
                    || {
                        eval(t, &mut frame);
                        let eval_ms = ms_since(started);
                        let (constructed, encoded) = rayon::join(
                            || measuring.then(|| construct(&frame)),
                            || encode_and_copy(&mut encoders, next, (i, &frame), &mut record),
                        );
                        encoded.map(|out| (out, eval_ms, constructed))
                    },
                ));
            });
            match unpublished.take() {
                Some(last) => last.publish(&mut whole_stream, sink),
                None => Ok(()),
            }
        })?;
        let (measured, encoded) = computed.expect("the scope waits for the frame");
        measured?;
        let ((header, glb), eval_ms, constructed) = encoded?;
        let encoded_ms = ms_since(started);
        let done = Unpublished {
            index: i,
            t,
            header,
            glb,
            record: std::mem::take(&mut record),
        };
        // Frame 0 too is published while the next frame is computed: the
        // pool sat idle for the 10 ms its publishing took (the stream
        // header and the record, two commits).
        unpublished = Some(done);
        if let Some(check) = &mut output_check {
            check.swap();
            waiting = constructed;
        }
        keyframes.keep(i, &frame);
        tracing::debug!(frame = i, eval_ms, encoded_ms, "frame computed");
        sink.stage(stage::FRAMES, 0.1 + 0.85 * (i + 1) as f32 / frames as f32);
    }
    if let Some(last) = unpublished {
        last.publish(&mut whole_stream, sink)?;
    }
    if let Some(check) = &mut output_check
        && let Some(m) = waiting
    {
        let report = check.checker.check()?;
        measure(&report, m);
    }
    keyframes.add_waiting()?;
    let (files, animation) = encoders.finish(whole_stream, keyframes, sink)?;
    encoders.keep(spec.frames, writers);
    if let Some(check) = output_check {
        writers.checker.keep(check.checker.check);
    }
    Ok(Rendered {
        frames,
        files,
        animation,
    })
}

/// A frame computed and encoded, waiting to be published: [`render`]
/// publishes each frame while it computes the next, so the sink's writes
/// and database commits (about 1.5 ms a frame on local storage) overlap
/// the work rather than follow it.
struct Unpublished {
    index: u32,
    t: f32,
    /// The stream header's length at the start of `record` (`None`: no
    /// stream is written).
    header: Option<usize>,
    glb: Option<Vec<u8>>,
    record: Vec<u8>,
}

impl Unpublished {
    /// Publishes the frame: the stream header first for frame 0
    /// ([`publish_header`]), then the frame, then its record in the whole
    /// stream.
    fn publish(
        self,
        whole_stream: &mut WholeStream,
        sink: &mut dyn JobSink,
    ) -> Result<(), JobError> {
        let delta = publish_header(self.index, self.header, &self.record, sink)?;
        sink.frame(FrameOutput {
            index: self.index,
            t: self.t,
            glb: self.glb,
            delta,
        })
        .map_err(stored)?;
        // The whole stream's copy after the frame is out: written to a
        // file as it comes, frame 0's (with the header, a few MB) delayed
        // the first frame's event by about 10 ms.
        if self.header.is_some() {
            whole_stream.add(&self.record, sink)?;
        }
        Ok(())
    }
}

/// Encodes frame `i` (see [`Encoders::encode`]), then copies what the
/// output check reads of it into `next`.
fn encode_and_copy(
    encoders: &mut Encoders,
    next: Option<&mut NextGeometry>,
    (i, frame): (u32, &Frame),
    record: &mut Vec<u8>,
) -> Result<(Option<usize>, Option<Vec<u8>>), JobError> {
    let encoded = encoders.encode(i, frame, record)?;
    if let Some(next) = next {
        next.take(frame, encoders)?;
    }
    Ok(encoded)
}

/// Publishes the stream header before frame 0 and returns the frame's
/// delta: the record less the header; empty when the stream was not
/// requested.
fn publish_header(
    i: u32,
    header: Option<usize>,
    record: &[u8],
    sink: &mut dyn JobSink,
) -> Result<Vec<u8>, JobError> {
    let Some(header) = header else {
        return Ok(Vec::new());
    };
    if i == 0 {
        if header == 0 {
            return Err(JobError::internal("the delta stream wrote no header"));
        }
        sink.stream_header(record[..header].to_vec())
            .map_err(stored)?;
    }
    Ok(record[header..].to_vec())
}

/// `stream.tmd` as the frames are published: handed to the sink in parts
/// when it takes them ([`JobSink::stream_part`]; asked with the first
/// record), else kept here and published whole at the end.
enum WholeStream {
    Unasked,
    Parts,
    Kept(Vec<u8>),
}

impl WholeStream {
    /// Adds the next record (the first with the header before it).
    fn add(&mut self, record: &[u8], sink: &mut dyn JobSink) -> Result<(), JobError> {
        match self {
            WholeStream::Unasked => {
                *self = if sink.stream_part(record, false).map_err(stored)? {
                    WholeStream::Parts
                } else {
                    WholeStream::Kept(record.to_vec())
                };
            }
            WholeStream::Parts => {
                if !sink.stream_part(record, false).map_err(stored)? {
                    return Err(JobError::internal("the sink stopped taking stream parts"));
                }
            }
            WholeStream::Kept(bytes) => bytes.extend_from_slice(record),
        }
        Ok(())
    }

    /// Ends the stream (`stream`'s end record) and publishes it.
    fn finish(
        self,
        stream: &mut DeltaStreamWriter,
        sink: &mut dyn JobSink,
    ) -> Result<(), JobError> {
        let parts = matches!(self, WholeStream::Parts);
        let mut bytes = match self {
            WholeStream::Kept(bytes) => bytes,
            WholeStream::Parts | WholeStream::Unasked => Vec::new(),
        };
        stream.finish(&mut bytes).map_err(encode)?;
        if !parts {
            return sink.file("stream.tmd", bytes).map_err(stored);
        }
        if !sink.stream_part(&bytes, true).map_err(stored)? {
            return Err(JobError::internal("the sink stopped taking stream parts"));
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "runner_tests.rs"]
mod tests;
