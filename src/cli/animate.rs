//! `treemorph morph` and `treemorph sketch`: run a job locally and write its
//! outputs to a directory.
//!
//! `DIR/frame_NNNN.glb` (one per frame), `DIR/animation.glb` (morph
//! targets), `DIR/frames.tmd` (the binary delta stream) and
//! `DIR/metrics.json`; `--format` picks which of the first three.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, anyhow};
use indicatif::ProgressBar;
use treemorph_api::jobs::{
    AnimationEncoding, JobRequest, LeafAssignment, Matching, MorphJobOptions, MorphRequest,
    Outputs, SketchFit, SketchInput, SketchJobOptions, SketchMethod, SketchRequest, View,
};
use treemorph_tree::Limits;

use super::{EXIT_INVALID_INPUT, EXIT_USAGE, Failure, progress};
use crate::files::{load_tree, write_atomic};
use crate::pipeline::{
    FrameOutput, InputTree, JobError, JobInput, JobSink, SinkError, default_runner, stage,
};

/// Which outputs to write.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// One GLB per frame.
    Glb,
    /// One animated GLB (morph targets).
    Animated,
    /// The binary delta stream.
    Delta,
    /// All of the above.
    All,
}

fn outputs(formats: &[Format]) -> Outputs {
    let all = formats.is_empty() || formats.contains(&Format::All);
    Outputs {
        glb: all || formats.contains(&Format::Glb),
        animated: all || formats.contains(&Format::Animated),
        delta: all || formats.contains(&Format::Delta),
    }
}

/// Arguments both commands share.
#[derive(Debug, clap::Args)]
pub struct Common {
    /// Number of frames (2–600).
    #[arg(long, default_value_t = 60)]
    frames: u32,
    /// Output directory (created if missing).
    #[arg(short, long)]
    output: PathBuf,
    /// What to write (repeatable or comma-separated; default all).
    #[arg(long, value_enum, value_delimiter = ',')]
    format: Vec<Format>,
    /// Keyframes of animation.glb (2..=frames; default 24 or frames).
    #[arg(long)]
    keyframes: Option<u32>,
    /// How animation.glb stores its morph targets: float (core glTF, plays
    /// everywhere), quantized (KHR_mesh_quantization, about half the size)
    /// or meshopt (EXT_meshopt_compression, about a sixth).
    #[arg(long, value_enum, default_value_t = EncodingArg::Float)]
    animation_encoding: EncodingArg,
}

/// `--animation-encoding` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum EncodingArg {
    /// 32-bit floats.
    Float,
    /// KHR_mesh_quantization.
    Quantized,
    /// EXT_meshopt_compression.
    Meshopt,
}

impl From<EncodingArg> for AnimationEncoding {
    fn from(e: EncodingArg) -> AnimationEncoding {
        match e {
            EncodingArg::Float => AnimationEncoding::Float,
            EncodingArg::Quantized => AnimationEncoding::Quantized,
            EncodingArg::Meshopt => AnimationEncoding::Meshopt,
        }
    }
}

/// Arguments of `treemorph morph`.
#[derive(Debug, clap::Args)]
#[command(after_help = "Example:\n  treemorph morph eucalyptus.glb shrub.glb --frames 48 -o out/")]
pub struct MorphArgs {
    /// Source tree (GLB, glTF or treemorph JSON).
    source: PathBuf,
    /// Target tree.
    target: PathBuf,
    #[command(flatten)]
    common: Common,
    /// Chain matching: one-to-many (splits and merges; default) or
    /// one-to-one (the blending baseline: extra stems grow instead).
    #[arg(long, value_enum, default_value_t = MatchingArg::OneToMany)]
    matching: MatchingArg,
    /// Leaf matching: greedy on chains (default) or random with straight-line
    /// positions (the baseline that leaves leaves floating).
    #[arg(long, value_enum, default_value_t = LeavesArg::Greedy)]
    leaves: LeavesArg,
    /// Let split and merge copies part all along their length at once
    /// instead of from the tips first (turns the paper's slow-down
    /// coefficient off).
    #[arg(long)]
    no_slow_down: bool,
}

/// `--matching` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum MatchingArg {
    /// Splits and merges.
    OneToMany,
    /// One-to-one or one-to-none only.
    OneToOne,
}

/// `--leaves` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LeavesArg {
    /// Greedy matching on matched chains.
    Greedy,
    /// Random matching, straight-line positions.
    Random,
}

/// Arguments of `treemorph sketch`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  treemorph sketch maple.glb --sketch examples/sketches/heart.json -o out/\n\n\
SKETCH.json holds {\"view\": {\"eye\": [x,y,z], \"target\": [x,y,z], \"up\": [x,y,z], \
\"fov_deg\": f}, \"points\": [[x, y], ...], \"closed\": true, \"fit\": \"crown\"}; points are \
normalised device coordinates of that camera (x, y in [-1, 1], y up)."
)]
pub struct SketchArgs {
    /// The tree (GLB, glTF or treemorph JSON).
    tree: PathBuf,
    /// The sketch file.
    #[arg(long)]
    sketch: PathBuf,
    #[command(flatten)]
    common: Common,
    /// Deformation: the multiscale cage tree (default) or one global cage
    /// (the baseline).
    #[arg(long, value_enum, default_value_t = MethodArg::Multiscale)]
    method: MethodArg,
}

/// `--method` values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum MethodArg {
    /// Self-adaptive multiscale cages with pruning.
    Multiscale,
    /// A single global cage.
    SingleCage,
}

/// Writes a job's outputs under a directory.
struct DirSink {
    dir: PathBuf,
    bar: ProgressBar,
    frames: u32,
}

impl DirSink {
    fn put(&self, name: &str, bytes: &[u8]) -> Result<(), SinkError> {
        write_atomic(&self.dir.join(name), bytes).map_err(|e| SinkError {
            what: name.to_owned(),
            reason: e.to_string(),
        })
    }
}

impl JobSink for DirSink {
    fn stage(&mut self, stage: &'static str, _progress: f32) {
        self.bar.set_message(stage);
    }

    fn cancelled(&self) -> bool {
        false
    }

    fn stream_header(&mut self, _bytes: Vec<u8>) -> Result<(), SinkError> {
        // The complete stream arrives as `stream.tmd` at the end.
        Ok(())
    }

    fn frame(&mut self, frame: FrameOutput) -> Result<(), SinkError> {
        if let Some(glb) = &frame.glb {
            self.put(&format!("frame_{:04}.glb", frame.index), glb)?;
        }
        self.bar.set_position(u64::from(frame.index) + 1);
        Ok(())
    }

    fn file(&mut self, name: &str, bytes: Vec<u8>) -> Result<(), SinkError> {
        // The CLI's documented name for the delta stream.
        let name = if name == "stream.tmd" {
            "frames.tmd"
        } else {
            name
        };
        self.put(name, &bytes)
    }
}

fn load(path: &Path) -> Result<Arc<InputTree>, Failure> {
    let (tree, _) = load_tree(path, &Limits::default()).map_err(Failure::invalid_input)?;
    Ok(Arc::new(InputTree::new(tree)))
}

fn job_failure(e: JobError) -> Failure {
    use treemorph_api::ErrorCode;
    let code = match e.code {
        ErrorCode::InvalidJob => EXIT_USAGE,
        ErrorCode::InvalidSketch
        | ErrorCode::InvalidTree
        | ErrorCode::IncompatibleTrees
        | ErrorCode::TreeNotFound => EXIT_INVALID_INPUT,
        _ => super::EXIT_FAILURE,
    };
    Failure {
        code,
        error: anyhow!("{} ({})", e.message, e.code),
    }
}

fn run_job(
    request: JobRequest,
    trees: HashMap<String, Arc<InputTree>>,
    common: &Common,
) -> Result<(), Failure> {
    let runner = default_runner();
    runner.check(&request).map_err(job_failure)?;
    std::fs::create_dir_all(&common.output)
        .with_context(|| format!("creating {}", common.output.display()))?;
    let bar = progress::bar(u64::from(common.frames), stage::LOADING);
    let mut sink = DirSink {
        dir: common.output.clone(),
        bar: bar.clone(),
        frames: common.frames,
    };
    let outcome = runner
        .run(
            &JobInput {
                request: &request,
                trees: &trees,
            },
            &mut sink,
        )
        .map_err(job_failure)?;
    bar.finish_and_clear();
    eprintln!(
        "wrote {} frames to {} ({}); metrics: {}",
        sink.frames,
        common.output.display(),
        outcome.files.join(", "),
        outcome.metrics
    );
    Ok(())
}

pub(super) fn morph(args: &MorphArgs) -> Result<(), Failure> {
    let source = load(&args.source)?;
    let target = load(&args.target)?;
    let request = JobRequest::Morph(MorphRequest {
        source: "source".into(),
        target: "target".into(),
        frames: args.common.frames,
        options: MorphJobOptions {
            matching: match args.matching {
                MatchingArg::OneToMany => Matching::OneToMany,
                MatchingArg::OneToOne => Matching::OneToOne,
            },
            leaves: match args.leaves {
                LeavesArg::Greedy => LeafAssignment::Greedy,
                LeavesArg::Random => LeafAssignment::Random,
            },
            slow_down: args.no_slow_down.then_some(false),
            keyframes: args.common.keyframes,
            animation_encoding: args.common.animation_encoding.into(),
        },
        outputs: outputs(&args.common.format),
        callback_url: None,
    });
    let trees = HashMap::from([("source".to_owned(), source), ("target".to_owned(), target)]);
    run_job(request, trees, &args.common)
}

/// A sketch file as the wire types of a sketch request.
pub(super) struct SketchFile {
    /// The camera.
    pub view: View,
    /// The polyline.
    pub sketch: SketchInput,
    /// `Some(Crown)` when the file asks for the crown fit.
    pub fit: Option<SketchFit>,
}

/// Reads a sketch file (`treemorph_sketch::parse_sketch_file`); a missing
/// or invalid file is the caller's invalid input.
pub(super) fn read_sketch_file(path: &Path) -> Result<SketchFile, Failure> {
    let bytes = std::fs::read(path)
        .with_context(|| format!("cannot read {}", path.display()))
        .map_err(Failure::invalid_input)?;
    let file = treemorph_sketch::parse_sketch_file(&bytes)
        .map_err(|e| Failure::invalid_input(anyhow!("{}: {e}", path.display())))?;
    Ok(SketchFile {
        view: View {
            eye: file.view.eye.to_array(),
            target: file.view.target.to_array(),
            up: file.view.up.to_array(),
            fov_deg: file.view.fov_deg,
            ortho_height: file.view.ortho_height,
        },
        sketch: SketchInput {
            points: file.sketch.points.iter().map(|p| p.to_array()).collect(),
            closed: file.sketch.closed,
        },
        fit: match file.fit {
            treemorph_sketch::Fit::Crown => Some(SketchFit::Crown),
            _ => None,
        },
    })
}

impl From<MethodArg> for SketchMethod {
    fn from(m: MethodArg) -> SketchMethod {
        match m {
            MethodArg::Multiscale => SketchMethod::Multiscale,
            MethodArg::SingleCage => SketchMethod::SingleCage,
        }
    }
}

pub(super) fn sketch(args: &SketchArgs) -> Result<(), Failure> {
    let tree = load(&args.tree)?;
    let file = read_sketch_file(&args.sketch)?;
    let request = JobRequest::Sketch(SketchRequest {
        tree: "tree".into(),
        view: file.view,
        sketch: file.sketch,
        frames: args.common.frames,
        options: SketchJobOptions {
            method: args.method.into(),
            fit: file.fit,
            keyframes: args.common.keyframes,
            animation_encoding: args.common.animation_encoding.into(),
        },
        outputs: outputs(&args.common.format),
        callback_url: None,
    });
    let trees = HashMap::from([("tree".to_owned(), tree)]);
    run_job(request, trees, &args.common)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_map_to_outputs() {
        let all = Outputs {
            glb: true,
            animated: true,
            delta: true,
        };
        assert_eq!(outputs(&[]), all);
        assert_eq!(outputs(&[Format::All]), all);
        assert_eq!(
            outputs(&[Format::Glb, Format::Delta]),
            Outputs {
                glb: true,
                animated: false,
                delta: true
            }
        );
    }
}
