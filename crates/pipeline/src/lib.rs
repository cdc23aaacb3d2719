//! Jobs without the service: a request converted once into a [`JobSpec`],
//! its input trees in, frames and files out through a [`JobSink`].
//!
//! This crate is synchronous and knows nothing of HTTP, databases or async
//! runtimes; the service (`treemorph serve`), the command line, the
//! benchmarks and the fuzz targets all call it.
//!
//! - [`JobSpec::parse`] converts a wire request (`treemorph_api::jobs`)
//!   into validated domain options, once; the spec is kept for the run.
//! - [`ErrorCoded`] is the one table from every domain error to its stable
//!   code; [`JobError`] is a job's failure as clients read it.
//! - The seam between the service's queue (which owns persistence, leases
//!   and streaming) and the geometry (which owns morphing, sketching,
//!   meshing and encoding) is the [`Runner`] trait: the queue calls
//!   [`Runner::check`] when a job is posted (so bad parameters get a 422 at
//!   once) and [`Runner::run`] on a blocking thread when a worker has
//!   claimed the job. A runner reports progress, publishes outputs through
//!   the sink as soon as each exists (the delta stream's header first, then
//!   one record per frame, so clients can play before the job ends) and
//!   polls [`JobSink::cancelled`] between frames.

use std::collections::HashMap;
use std::sync::{Arc, OnceLock};

use treemorph_analysis::{Analysis, AnalysisError, AnalysisOptions};
use treemorph_api::jobs::JobRequest;
use treemorph_tree::Tree;

mod error;
mod plans;
mod runner;
mod spec;
mod stored;

pub use error::{ErrorCoded, INTERNAL_MESSAGE, JobError};
pub use runner::PipelineRunner;
pub use spec::{
    DEFAULT_BASIS_SAMPLES, DEFAULT_KEYFRAMES, JobSpec, Limits, MIN_FRAMES, MorphSpec, RenderSpec,
    SketchSpec, SpecError, morph_options, sketch_options, view, wire_view,
};
pub use stored::{FORMAT as PLAN_FORMAT, ReadError as PlanReadError};

/// The stages a job goes through, in order; reported in `GET /v1/jobs/{id}`
/// and the SSE stream.
pub mod stage {
    /// Reading the input trees.
    pub const LOADING: &str = "loading";
    /// Skeleton-lobe analysis of the inputs.
    pub const ANALYSING: &str = "analysing";
    /// Building the morph or sketch plan (correspondences, cages).
    pub const PLANNING: &str = "planning";
    /// Computing, meshing and encoding frames.
    pub const FRAMES: &str = "frames";
    /// Writing the whole-sequence files (animated GLB, complete stream).
    pub const FINISHING: &str = "finishing";
}

/// One frame's outputs.
#[derive(Debug)]
pub struct FrameOutput {
    /// 0-based frame index.
    pub index: u32,
    /// Animation time in [0, 1].
    pub t: f32,
    /// The frame as a GLB, when per-frame GLBs were requested.
    pub glb: Option<Vec<u8>>,
    /// The frame's record of the delta stream.
    pub delta: Vec<u8>,
}

/// Why publishing an output failed (storage trouble; the job is retried).
#[derive(Debug, thiserror::Error)]
#[error("could not store {what}: {reason}")]
pub struct SinkError {
    /// What was being stored.
    pub what: String,
    /// The cause.
    pub reason: String,
}

/// Where a running job sends progress and outputs.
pub trait JobSink {
    /// Reports the current stage and the job's overall progress in [0, 1].
    fn stage(&mut self, stage: &'static str, progress: f32);
    /// Whether the job was cancelled; runners check between frames.
    fn cancelled(&self) -> bool;
    /// Publishes the delta stream's header (before any frame).
    fn stream_header(&mut self, bytes: Vec<u8>) -> Result<(), SinkError>;
    /// Publishes one frame (in index order).
    fn frame(&mut self, frame: FrameOutput) -> Result<(), SinkError>;
    /// Publishes a whole-sequence file: `animation.glb`, `stream.tmd`,
    /// `metrics.json`.
    fn file(&mut self, name: &str, bytes: Vec<u8>) -> Result<(), SinkError>;
    /// Takes the next bytes of `stream.tmd` as the job makes them: the
    /// header with frame 0's record, each later record, then (`last`) the
    /// end record, after which the file is published as
    /// [`JobSink::file`] publishes it. Returns `false` when the sink
    /// takes the file whole instead (the default): the runner then keeps
    /// the bytes and passes them to `file` at the end. A sink that writes
    /// the file as the frames come spares the job's end the copy of the
    /// whole stream (17 MB on the default job).
    fn stream_part(&mut self, bytes: &[u8], last: bool) -> Result<bool, SinkError> {
        let _ = (bytes, last);
        Ok(false)
    }
    /// The queue attempt this sink publishes for (`None` outside the queue,
    /// e.g. the command line). Runners need not care; the test runner
    /// stamps it into its outputs so the scale-out test can prove which
    /// attempt every served byte came from.
    fn attempt(&self) -> Option<Attempt<'_>> {
        None
    }
    /// Whether this sink keeps the job's plan ([`JobSink::plan`]); runners
    /// encode it only then.
    fn keeps_plan(&self) -> bool {
        false
    }
    /// Publishes the job's plan, a versioned binary (see
    /// [`PlanReadError`] for what reading it may meet): outputs rendered on
    /// request later start from it ([`JobInput::stored_plan`]) instead of
    /// planning again. Called once before the job ends: before its first
    /// frame when the plan was kept from an earlier job, else after its
    /// last.
    fn plan(&mut self, bytes: Vec<u8>) -> Result<(), SinkError> {
        let _ = bytes;
        Ok(())
    }
}

/// One attempt of a queued job (see [`crate::jobs::queue`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Attempt<'a> {
    /// The job's id.
    pub job: &'a str,
    /// The attempt's number (the job's `attempt` counter after the claim).
    pub number: u32,
    /// The attempt's lease token: unique per claim, it fences the
    /// attempt's writes and names the blob prefix of its outputs.
    pub token: &'a str,
}

/// What a finished job reports.
#[derive(Debug, Clone, PartialEq)]
pub struct JobOutcome {
    /// Frames produced.
    pub frames: u32,
    /// Summary metrics (the `result.metrics` object of the job).
    pub metrics: serde_json::Value,
    /// Names of the files published with [`JobSink::file`].
    pub files: Vec<String>,
}

/// An input tree with its skeleton-lobe analysis, computed at most once.
///
/// A stored tree never changes (a new upload gets a new id), so one
/// analysis serves every job that names the tree: the service keeps these
/// in its tree cache (`crate::jobs::tree_cache`), seeded by the upload that
/// analysed the tree already, and a job on a cached tree starts planning at
/// once instead of parsing and analysing both trees again.
#[derive(Debug)]
pub struct InputTree {
    tree: Tree,
    analysis: OnceLock<Analysis>,
}

impl InputTree {
    /// A tree whose analysis is computed on first use.
    pub fn new(tree: Tree) -> InputTree {
        InputTree {
            tree,
            analysis: OnceLock::new(),
        }
    }

    /// A tree with its analysis already computed (with the default
    /// options, the only ones jobs use).
    pub fn with_analysis(tree: Tree, analysis: Analysis) -> InputTree {
        InputTree {
            tree,
            analysis: OnceLock::from(analysis),
        }
    }

    /// The tree.
    pub fn tree(&self) -> &Tree {
        &self.tree
    }

    /// Whether the analysis has been computed.
    pub fn is_analysed(&self) -> bool {
        self.analysis.get().is_some()
    }

    /// The tree's analysis with the default options, computed on the first
    /// call. Two threads racing here may both compute it; one result is
    /// kept (they are equal), which is cheaper than holding a lock across
    /// tens of milliseconds of work. Errors are not kept: the stored trees
    /// were analysed when uploaded, so an error here is exceptional.
    pub fn analysis(&self) -> Result<&Analysis, AnalysisError> {
        if let Some(a) = self.analysis.get() {
            return Ok(a);
        }
        let computed = Analysis::of(&self.tree, &AnalysisOptions::default())?;
        Ok(self.analysis.get_or_init(|| computed))
    }
}

impl From<Tree> for InputTree {
    fn from(tree: Tree) -> InputTree {
        InputTree::new(tree)
    }
}

/// A claimed job: its spec, where its input trees come from and, for a
/// job that ran before, the plan it stored.
pub struct JobInput<'a> {
    /// The job, converted and validated once.
    pub spec: &'a JobSpec,
    /// The trees the request names, by id; a runner asks only for those it
    /// needs (none when it starts from a kept or stored plan).
    pub trees: &'a dyn TreeSource,
    /// The plan the job's run published ([`JobSink::plan`]), if the caller
    /// knows of one: rendering from it needs no trees.
    pub stored_plan: Option<StoredPlan<'a>>,
}

impl std::fmt::Debug for JobInput<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("JobInput")
            .field("spec", self.spec)
            .field("stored_plan", &self.stored_plan.map(|s| s.key))
            .finish_non_exhaustive()
    }
}

/// Where a job's input trees come from: a map of loaded trees, or a
/// source that loads each on first use (the service's renders, which
/// need no tree at all when the job's plan is stored).
pub trait TreeSource: Sync {
    /// The input tree `id`; `tree_not_found` when it is not there.
    fn tree(&self, id: &str) -> Result<Arc<InputTree>, JobError>;
}

impl TreeSource for HashMap<String, Arc<InputTree>> {
    fn tree(&self, id: &str) -> Result<Arc<InputTree>, JobError> {
        self.get(id).cloned().ok_or_else(|| {
            JobError::invalid(
                treemorph_api::ErrorCode::TreeNotFound,
                format!("tree {id} was not loaded"),
            )
        })
    }
}

/// A job's plan as its run published it ([`JobSink::plan`]).
#[derive(Clone, Copy)]
pub struct StoredPlan<'a> {
    /// What names this plan and no other for as long as it exists (the
    /// service gives the attempt that ran the job: its trees and request
    /// never change). A runner keeps plans in memory under it, so a
    /// render of a job whose plan is kept neither loads the plan nor
    /// asks for trees; the run of the job passes it too, and leaves its
    /// plan there.
    pub key: &'a str,
    /// Reads the stored bytes: `None` when there are none or they cannot
    /// be read (the runner then plans again from the trees). Called only
    /// when no plan is kept under `key`.
    pub load: &'a PlanLoader<'a>,
}

/// Reads a job's stored plan ([`StoredPlan::load`]).
pub type PlanLoader<'a> = dyn Fn() -> Option<Vec<u8>> + Sync + 'a;

/// Runs jobs. Implementations are synchronous and CPU-bound; the queue calls
/// them on a blocking thread.
pub trait Runner: Send + Sync + 'static {
    /// Converts and checks a request before it is queued (cheap: trees are
    /// not loaded); the worker calls it again on the stored request and
    /// runs the spec it returns.
    fn check(&self, request: &JobRequest, limits: &Limits) -> Result<JobSpec, JobError> {
        Ok(JobSpec::parse(request, limits)?)
    }
    /// Runs a job to the end, publishing outputs through `sink`.
    fn run(&self, input: &JobInput<'_>, sink: &mut dyn JobSink) -> Result<JobOutcome, JobError>;
    /// Whether this runner renders any output of a job it ran again on
    /// request, byte for byte: per-frame GLBs with [`Runner::frame_at`] at
    /// [`frame_instant`], whole-sequence files with [`Runner::run`] of the
    /// same spec. The service then stores only a job's
    /// [`JobSpec::stored_part`] and renders the rest when asked.
    fn renders_on_request(&self) -> bool {
        false
    }
    /// The job's frame at instant `t` in [0, 1] as a GLB: at
    /// [`frame_instant`]`(i, n)` the same bytes as the job's per-frame GLB
    /// `i`. Runners that cannot render single instants refuse with
    /// `invalid_job`.
    fn frame_at(&self, input: &JobInput<'_>, t: f32) -> Result<Vec<u8>, JobError> {
        let _ = (input, t);
        Err(JobError::invalid(
            treemorph_api::ErrorCode::InvalidJob,
            "this runner renders no single instants",
        ))
    }
    /// The job's frame at instant `t` in [0, 1] as a delta stream of that
    /// one frame, based on the job's frame 0: the header is the job's own
    /// stream header but for its frame count (1), and the frame record
    /// decodes against either. So [`StreamPart::Frame`], the record alone,
    /// is what a player that holds the job's stream needs to show the
    /// instant in its own meshes; at [`frame_instant`]`(i, n)` it decodes
    /// to the positions of the job's frame `i`. Runners that cannot render
    /// single instants refuse with `invalid_job`.
    fn stream_at(
        &self,
        input: &JobInput<'_>,
        t: f32,
        part: StreamPart,
    ) -> Result<Vec<u8>, JobError> {
        let _ = (input, t, part);
        Err(JobError::invalid(
            treemorph_api::ErrorCode::InvalidJob,
            "this runner renders no single instants as a stream",
        ))
    }
}

/// What of a one-instant delta stream [`Runner::stream_at`] renders.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StreamPart {
    /// A stream on its own: header, the frame record, end record.
    Whole,
    /// The frame record alone, for a client holding the job's own stream
    /// header.
    Frame,
}

/// The version of what this build renders from a request and its trees.
/// A job records the version that ran it; outputs rendered on request
/// later must be the bytes the job would have written, so a process whose
/// version differs refuses to render them (410 `plan_outdated`) instead
/// of serving different bytes under the same name and ETag.
///
/// Bump it with every change that alters any output byte of a job for the
/// same request and trees (geometry, meshing, encoding, metrics).
///
/// - 1: the first plan-first jobs.
/// - 2: `animation.glb` is a motion basis by default (`options.animation`).
/// - 3: morphs are staged by default (`options.schedule`).
/// - 4: sketches turn about their joints and are staged by default;
///   their `metrics.json` has `max_jump` and `jump_ratio`.
/// - 5: a morph's group matching swaps partners to uncross sibling limbs
///   (`group_weights.crossing`).
/// - 6: a sketch's foliage fit balances its crown against the outline;
///   plans are stored (`plan.bin`).
/// - 7: a basis or skinned `animation.glb` has quad leaves
///   (`treemorph_gltf::animated::ANIMATED_MESH`).
/// - 8: a staged morph routes limbs round the siblings they would pass
///   through, and lifts sliding junctions off their parent's axis (the
///   plan's chains carry `detour` and `lift`).
/// - 9: a growing or wilting chain's radius never exceeds its own full
///   radius at that node (twigs thinner at the base than further out no
///   longer swell there).
/// - 10: a skinned animation fits its residual at every joint scale, with
///   up to 16 targets.
/// - 11: a staged morph sheds and regrows the blends that still pass
///   through other branches (`treemorph_morph::MorphOptions::untangle`).
/// - 12: untangling sweeps the motion between the instants it plays, paces
///   each round anew, sheds until nothing crosses, and sheds no ancestor
///   for a pair of which neither chain blends; a chain that fits inside
///   its parent's tube mid-morph is not drawn.
pub const RENDER_VERSION: u32 = 12;

/// The instant of frame `i` of `frames` (both ends included): `i / (frames
/// − 1)`, computed the one way every frame and every render on request
/// computes it, so a frame rendered later has the same bits of `t`.
pub fn frame_instant(i: u32, frames: u32) -> f32 {
    i as f32 / frames.saturating_sub(1).max(1) as f32
}

/// Checks an instant of a job's timeline: finite and in [0, 1]
/// (`invalid_request` otherwise, naming the value).
pub fn check_instant(t: f32) -> Result<f32, JobError> {
    if t.is_finite() && (0.0..=1.0).contains(&t) {
        Ok(t)
    } else {
        Err(JobError::invalid(
            treemorph_api::ErrorCode::InvalidRequest,
            format!("t must be a number in [0, 1], not {t}"),
        ))
    }
}

/// The runner `treemorph serve` uses: morph and sketch jobs through the
/// geometry crates.
pub fn default_runner() -> Arc<dyn Runner> {
    Arc::new(PipelineRunner::default())
}
