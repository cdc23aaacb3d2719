//! `treemorph morph` and `treemorph sketch`: run a job locally and write its
//! outputs to a directory.
//!
//! `DIR/frame_NNNN.glb` (one per frame), `DIR/animation.glb` (morph
//! targets), `DIR/frames.tmd` (the binary delta stream) and
//! `DIR/metrics.json`; `--format` picks which of the first three.
//! `--at T` writes only the frame at instant `T` in [0, 1],
//! `DIR/frame_at_T.glb` (`T` with four decimals): at `T = i / (frames −
//! 1)` the same bytes as `frame_NNNN.glb` of frame `i`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, anyhow};
use indicatif::ProgressBar;
use treemorph_api::jobs::{JobRequest, MorphJobOptions, SketchJobOptions};
use treemorph_tree::Limits;

use super::job_args::{Format, morph_request, read_sketch_file, sketch_request};
use super::{EXIT_INVALID_INPUT, EXIT_USAGE, Failure, progress};
use crate::files::{load_tree, write_atomic};
use crate::pipeline::{
    FrameOutput, InputTree, JobError, JobInput, JobSink, SinkError, default_runner, stage,
};

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
    /// Write only the frame at this instant in [0, 1], as
    /// `DIR/frame_at_T.glb`.
    #[arg(long, value_name = "T")]
    at: Option<f32>,
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
    #[command(flatten)]
    options: MorphJobOptions,
}

/// Arguments of `treemorph sketch`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  treemorph sketch maple.glb --sketch examples/sketches/heart.json -o out/\n\n\
SKETCH.json holds {\"view\": {\"eye\": [x,y,z], \"target\": [x,y,z], \"up\": [x,y,z], \
\"fov_deg\": f, \"aspect\": w/h}, \"points\": [[x, y], ...], \"closed\": true, \"fit\": \"crown\"}; \
points are normalised device coordinates of that camera (x, y in [-1, 1], y up)."
)]
pub struct SketchArgs {
    /// The tree (GLB, glTF or treemorph JSON).
    tree: PathBuf,
    /// The sketch file.
    #[arg(long)]
    sketch: PathBuf,
    #[command(flatten)]
    common: Common,
    #[command(flatten)]
    options: SketchJobOptions,
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
        ErrorCode::InvalidJob | ErrorCode::InvalidRequest => EXIT_USAGE,
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
    let spec = runner
        .check(&request, &crate::pipeline::Limits::default())
        .map_err(job_failure)?;
    std::fs::create_dir_all(&common.output)
        .with_context(|| format!("creating {}", common.output.display()))?;
    let input = JobInput {
        spec: &spec,
        trees: &trees,
        stored_plan: None,
    };
    if let Some(t) = common.at {
        return write_instant(runner.as_ref(), &input, t, &common.output);
    }
    let bar = progress::bar(u64::from(common.frames), stage::LOADING);
    let mut sink = DirSink {
        dir: common.output.clone(),
        bar: bar.clone(),
        frames: common.frames,
    };
    let outcome = runner.run(&input, &mut sink).map_err(job_failure)?;
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

/// `--at T`: the one frame at instant `t`.
fn write_instant(
    runner: &dyn crate::pipeline::Runner,
    input: &JobInput<'_>,
    t: f32,
    dir: &Path,
) -> Result<(), Failure> {
    let glb = runner.frame_at(input, t).map_err(job_failure)?;
    let path = dir.join(format!("frame_at_{t:.4}.glb"));
    write_atomic(&path, &glb).with_context(|| format!("writing {}", path.display()))?;
    println!("{}", path.display());
    Ok(())
}

pub(super) fn morph(args: &MorphArgs) -> Result<(), Failure> {
    let source = load(&args.source)?;
    let target = load(&args.target)?;
    let request = morph_request(
        ("source".into(), "target".into()),
        args.common.frames,
        &args.options,
        &args.common.format,
        None,
    );
    let trees = HashMap::from([("source".to_owned(), source), ("target".to_owned(), target)]);
    run_job(request, trees, &args.common)
}

pub(super) fn sketch(args: &SketchArgs) -> Result<(), Failure> {
    let tree = load(&args.tree)?;
    let file = read_sketch_file(&args.sketch)?;
    let request = sketch_request(
        "tree".into(),
        file,
        args.common.frames,
        &args.options,
        &args.common.format,
        None,
    );
    let trees = HashMap::from([("tree".to_owned(), tree)]);
    run_job(request, trees, &args.common)
}
