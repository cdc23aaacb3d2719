//! [`JobSpec`]: a job request converted once into the validated domain
//! options the pipelines run with.
//!
//! The wire types of `treemorph_api::jobs` are the contract with clients
//! (JSON, the OpenAPI document, and the command line, which derives its
//! flags from the same structs); the domain options of the morph, sketch
//! and glTF crates are what the algorithms read. [`JobSpec::parse`] is the
//! one mapping between them. The service calls it when a job is posted (so
//! a bad request is refused before it is queued) and the worker calls it
//! once more on the stored request when it claims the job (the worker may
//! be another process, and the stored text is the durable record); within
//! one process and one run, a request is converted exactly once and the
//! spec is kept for the whole run. The command line, the benchmarks and
//! the `job_json` fuzz target call the same function, so the fuzzer fuzzes
//! the code the service runs.

use treemorph_api::jobs::{
    AnimationEncoding, JobKind, JobRequest, LeafAssignment, Matching, MorphJobOptions,
    MorphRequest, Outputs, ScheduleKind, SketchFit, SketchJobOptions, SketchMethod, SketchRequest,
};
use treemorph_gltf::animated::{AnimatedEncoding, DEFAULT_SKELETON_JOINTS};
use treemorph_gltf::basis::AnimationKind;
use treemorph_morph::{ChainMatching, LeafMorph, MorphError, MorphOptions};
use treemorph_sketch::{Fit, Method, Sketch, SketchError, SketchOptions, View};
use treemorph_tree::glam::{Vec2, Vec3};
use treemorph_tree::timing::ScheduleOptions;

/// Fewest frames a job may ask for: both ends of the animation.
pub const MIN_FRAMES: u32 = 2;
/// Keyframes of the animated GLB when the request names none.
pub const DEFAULT_KEYFRAMES: u32 = 24;
/// Frames a basis animation samples when the job does not say (all of
/// them for shorter jobs).
pub const DEFAULT_BASIS_SAMPLES: u32 = 120;
/// Seed of the random leaf assignment: fixed, so the same request always
/// gives the same animation.
const RANDOM_LEAVES_SEED: u64 = 0;
/// Most joints a skinned animation may ask for: glTF's 16-bit joint
/// indices, less the root.
pub const MAX_SKELETON_JOINTS: u32 = 65_534;

/// Limits a process applies to requests (the service's settings; the
/// command line uses the defaults).
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct Limits {
    /// Most frames a job may ask for (default 600, the service's
    /// `--max-frames` default).
    pub max_frames: u32,
}

impl Default for Limits {
    fn default() -> Limits {
        Limits { max_frames: 600 }
    }
}

impl Limits {
    /// These limits with another frame cap.
    pub fn with_max_frames(self, max_frames: u32) -> Limits {
        Limits { max_frames }
    }
}

/// Why a request cannot become a [`JobSpec`]; every variant is the caller's
/// mistake and names the field.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SpecError {
    /// `frames` is outside [`MIN_FRAMES`]`..=`[`Limits::max_frames`].
    #[error("frames is {frames}; it must be from {MIN_FRAMES} to {max}")]
    Frames {
        /// The value asked for.
        frames: u32,
        /// The process's limit.
        max: u32,
    },
    /// `options.skeleton_joints` is above [`MAX_SKELETON_JOINTS`].
    #[error(
        "options.skeleton_joints is {joints}; it must be at most {MAX_SKELETON_JOINTS} (0: one joint per chain)"
    )]
    SkeletonJoints {
        /// The joint cap asked for.
        joints: u32,
    },
    /// `options.keyframes` is outside `2..=frames`.
    #[error("options.keyframes is {keyframes}; it must be from 2 to frames ({frames})")]
    Keyframes {
        /// The value asked for.
        keyframes: u32,
        /// The job's frame count.
        frames: u32,
    },
    /// The morph options do not validate.
    #[error("options: {0}")]
    MorphOptions(MorphError),
    /// A sketch's `stagger` or `easing` is out of range.
    #[error("options: invalid sketch option `{option}`: {reason}")]
    Schedule {
        /// The option's field path (e.g. `schedule.stagger`).
        option: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// The camera, the polyline or the sketch options do not validate.
    #[error(transparent)]
    Sketch(SketchError),
}

/// How a job's frames are rendered and which outputs it writes.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderSpec {
    /// Frames, both ends included.
    pub frames: u32,
    /// Which outputs to write.
    pub outputs: Outputs,
    /// Keyframes of the animated GLB (resolved: at most `frames`): its
    /// morph targets, or for a basis the frames its weights sample.
    pub keyframes: u32,
    /// How the animated GLB stores its morph targets.
    pub encoding: AnimatedEncoding,
    /// What the animated GLB's morph targets are.
    pub animation: AnimationKind,
    /// Most joints of a skinned animation besides its root (0: one per
    /// chain).
    pub skeleton_joints: u32,
    /// Whether the run measures its frames: the output-level check and
    /// the per-frame series of `metrics.json`. Always true for a parsed
    /// request; renders on request turn it off ([`JobSpec::unmeasured`]).
    pub measured: bool,
}

/// A morph job, validated.
#[derive(Clone, Debug, PartialEq)]
pub struct MorphSpec {
    /// Id of the tree at t = 0.
    pub source: String,
    /// Id of the tree at t = 1.
    pub target: String,
    /// The morph pipeline's options.
    pub options: MorphOptions,
    /// Frames and outputs.
    pub render: RenderSpec,
}

/// A sketch job, validated.
#[derive(Clone, Debug, PartialEq)]
pub struct SketchSpec {
    /// Id of the tree to animate.
    pub tree: String,
    /// The camera the sketch was drawn from (its camera builds).
    pub view: View,
    /// The drawn polyline (validated).
    pub sketch: Sketch,
    /// The sketch pipeline's options.
    pub options: SketchOptions,
    /// Frames and outputs.
    pub render: RenderSpec,
}

/// A job request converted once into validated domain options.
#[derive(Clone, Debug, PartialEq)]
pub enum JobSpec {
    /// Morph one tree into another.
    Morph(MorphSpec),
    /// Animate a tree into a sketched crown.
    Sketch(SketchSpec),
}

impl JobSpec {
    /// Converts and validates `request` under `limits`; the error names the
    /// first field that is wrong.
    pub fn parse(request: &JobRequest, limits: &Limits) -> Result<JobSpec, SpecError> {
        let render = render_spec(request, limits)?;
        match request {
            JobRequest::Morph(r) => morph_spec(r, render).map(JobSpec::Morph),
            JobRequest::Sketch(r) => sketch_spec(r, render).map(JobSpec::Sketch),
        }
    }

    /// `morph` or `sketch`.
    pub fn kind(&self) -> JobKind {
        match self {
            JobSpec::Morph(_) => JobKind::Morph,
            JobSpec::Sketch(_) => JobKind::Sketch,
        }
    }

    /// Frames and outputs.
    pub fn render(&self) -> &RenderSpec {
        match self {
            JobSpec::Morph(m) => &m.render,
            JobSpec::Sketch(s) => &s.render,
        }
    }

    /// Frames, both ends included.
    pub fn frames(&self) -> u32 {
        self.render().frames
    }

    /// Which outputs the job writes.
    pub fn outputs(&self) -> &Outputs {
        &self.render().outputs
    }

    /// The spec a plan-first run executes: the same job without the
    /// outputs that are rendered on request instead of stored (the
    /// per-frame GLBs and the animated GLB; see [`Runner::renders_on_request`]).
    /// The delta stream and the metrics stay: the viewer plays the stream
    /// while the job runs, and the metrics are measured on the frames.
    ///
    /// [`Runner::renders_on_request`]: crate::Runner::renders_on_request
    pub fn stored_part(&self) -> JobSpec {
        let mut spec = self.clone();
        let outputs = &mut spec.render_mut().outputs;
        outputs.glb = false;
        outputs.animated = false;
        spec
    }

    /// The same job without measuring its frames: for a render on
    /// request, whose metrics nobody reads (the job's own are stored).
    /// Every output byte but `metrics.json` stays the same; the
    /// output-level check and the metrics' per-frame series are most of a
    /// frame's cost.
    pub fn unmeasured(&self) -> JobSpec {
        let mut spec = self.clone();
        spec.render_mut().measured = false;
        spec
    }

    fn render_mut(&mut self) -> &mut RenderSpec {
        match self {
            JobSpec::Morph(m) => &mut m.render,
            JobSpec::Sketch(s) => &mut s.render,
        }
    }

    /// The ids of the trees the job reads.
    pub fn tree_ids(&self) -> Vec<&str> {
        match self {
            JobSpec::Morph(m) => vec![m.source.as_str(), m.target.as_str()],
            JobSpec::Sketch(s) => vec![s.tree.as_str()],
        }
    }
}

fn morph_spec(r: &MorphRequest, render: RenderSpec) -> Result<MorphSpec, SpecError> {
    let options = morph_options(&r.options);
    options.validate().map_err(SpecError::MorphOptions)?;
    Ok(MorphSpec {
        source: r.source.clone(),
        target: r.target.clone(),
        options,
        render,
    })
}

/// The morph pipeline's options for the wire options: the one place a
/// morph job option reaches the pipeline.
pub fn morph_options(o: &MorphJobOptions) -> MorphOptions {
    let mut options = MorphOptions::default()
        .with_chain_matching(chain_matching(o.matching))
        .with_leaf_morph(leaf_morph(o.leaves));
    if let Some(slow_down) = o.slow_down {
        options = options.with_slow_down(slow_down);
    }
    if let Some(untangle) = o.untangle {
        options = options.with_untangle(untangle);
    }
    options.schedule = schedule(o.schedule, o.stagger, o.easing);
    options
}

/// The schedule options for the wire's `schedule`, `stagger` and
/// `easing` (a morph's and a sketch's alike).
fn schedule(kind: ScheduleKind, stagger: Option<f32>, easing: Option<f32>) -> ScheduleOptions {
    let mut schedule = ScheduleOptions::default();
    schedule.kind = match kind {
        ScheduleKind::Staged => treemorph_tree::timing::ScheduleKind::Staged,
        ScheduleKind::Linear => treemorph_tree::timing::ScheduleKind::Linear,
    };
    if let Some(stagger) = stagger {
        schedule.stagger = stagger;
    }
    if let Some(easing) = easing {
        schedule.easing = easing;
    }
    schedule
}

fn chain_matching(m: Matching) -> ChainMatching {
    match m {
        Matching::OneToMany => ChainMatching::OneToMany,
        Matching::OneToOne => ChainMatching::OneToOne,
    }
}

fn leaf_morph(l: LeafAssignment) -> LeafMorph {
    match l {
        LeafAssignment::Greedy => LeafMorph::OnChains,
        LeafAssignment::Random => LeafMorph::RandomLinear {
            seed: RANDOM_LEAVES_SEED,
        },
    }
}

fn sketch_spec(r: &SketchRequest, render: RenderSpec) -> Result<SketchSpec, SpecError> {
    let view = view(&r.view);
    view.camera().map_err(SpecError::Sketch)?;
    let sketch = Sketch {
        points: r
            .sketch
            .points
            .iter()
            .map(|p| Vec2::from_array(*p))
            .collect(),
        closed: r.sketch.closed,
    };
    sketch.validate().map_err(SpecError::Sketch)?;
    let options = sketch_options(&r.options);
    if let Some((option, reason)) = options.schedule.invalid_field() {
        return Err(SpecError::Schedule { option, reason });
    }
    options.validate().map_err(SpecError::Sketch)?;
    Ok(SketchSpec {
        tree: r.tree.clone(),
        view,
        sketch,
        options,
        render,
    })
}

/// The domain camera for a wire camera, field by field (nothing is
/// defaulted on the way: `aspect` absent on the wire is the domain's 1).
pub fn view(v: &treemorph_api::jobs::View) -> View {
    View {
        eye: Vec3::from_array(v.eye),
        target: Vec3::from_array(v.target),
        up: Vec3::from_array(v.up),
        fov_deg: v.fov_deg,
        ortho_height: v.ortho_height,
        aspect: v.aspect.unwrap_or(1.0),
    }
}

/// The wire camera for a domain camera (a sketch file's, on the command
/// line): the inverse of [`view`], field by field, so a camera survives
/// the round trip whole.
pub fn wire_view(v: &View) -> treemorph_api::jobs::View {
    treemorph_api::jobs::View {
        eye: v.eye.to_array(),
        target: v.target.to_array(),
        up: v.up.to_array(),
        fov_deg: v.fov_deg,
        ortho_height: v.ortho_height,
        aspect: (v.aspect != 1.0).then_some(v.aspect),
    }
}

/// The sketch pipeline's options for the wire options.
pub fn sketch_options(o: &SketchJobOptions) -> SketchOptions {
    let method = match o.method {
        SketchMethod::Multiscale => Method::Multiscale,
        SketchMethod::SingleCage => Method::SingleCage,
    };
    let fit = match o.fit {
        Some(SketchFit::Crown) => Fit::Crown,
        None => Fit::None,
    };
    SketchOptions::default()
        .with_method(method)
        .with_fit(fit)
        .with_schedule(schedule(o.schedule, o.stagger, o.easing))
}

fn render_spec(request: &JobRequest, limits: &Limits) -> Result<RenderSpec, SpecError> {
    let (frames, outputs) = (request.frames(), *request.outputs());
    let (keyframes, encoding, animation, joints) = match request {
        JobRequest::Morph(r) => (
            r.options.keyframes,
            r.options.animation_encoding,
            r.options.animation,
            r.options.skeleton_joints,
        ),
        JobRequest::Sketch(r) => (
            r.options.keyframes,
            r.options.animation_encoding,
            r.options.animation,
            r.options.skeleton_joints,
        ),
    };
    let animation = match animation {
        treemorph_api::jobs::AnimationKind::Basis => AnimationKind::Basis,
        treemorph_api::jobs::AnimationKind::Keyframes => AnimationKind::Keyframes,
        treemorph_api::jobs::AnimationKind::Skinned => AnimationKind::Skinned,
    };
    let skeleton_joints = joints.unwrap_or(DEFAULT_SKELETON_JOINTS as u32);
    if skeleton_joints > MAX_SKELETON_JOINTS {
        return Err(SpecError::SkeletonJoints {
            joints: skeleton_joints,
        });
    }
    // A basis samples every frame unless told otherwise (its size does not
    // grow with the samples), up to DEFAULT_BASIS_SAMPLES: its builder
    // keeps every sample's displacements.
    let default_keyframes = match animation {
        AnimationKind::Keyframes => DEFAULT_KEYFRAMES,
        _ => DEFAULT_BASIS_SAMPLES,
    };
    if !(MIN_FRAMES..=limits.max_frames).contains(&frames) {
        return Err(SpecError::Frames {
            frames,
            max: limits.max_frames,
        });
    }
    if let Some(k) = keyframes
        && !(2..=frames).contains(&k)
    {
        return Err(SpecError::Keyframes {
            keyframes: k,
            frames,
        });
    }
    Ok(RenderSpec {
        frames,
        outputs,
        keyframes: keyframes.unwrap_or(default_keyframes).min(frames),
        encoding: match encoding {
            AnimationEncoding::Float => AnimatedEncoding::Float,
            AnimationEncoding::Quantized => AnimatedEncoding::Quantized,
            AnimationEncoding::Meshopt => AnimatedEncoding::Meshopt,
        },
        animation,
        skeleton_joints,
        measured: true,
    })
}

#[cfg(test)]
#[path = "spec_tests.rs"]
mod tests;
