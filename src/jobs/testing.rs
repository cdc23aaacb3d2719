//! **Test only**: a small deterministic [`Runner`] for testing the queue,
//! streaming and crash recovery without the geometry pipelines.
//!
//! It emits a real delta stream (a one-triangle mesh that moves with `t`)
//! so clients can decode it, fake frame GLBs (`glTF` + the frame index),
//! and the three whole-sequence files. Its behaviour is configurable per
//! request through [`TestBehaviour`] (a delay per frame, failures, panics),
//! and the real binary selects it with the hidden `--test-runner slow:MS`
//! flag (`TREEMORPH_TEST_RUNNER`), used by the kill -9 and SIGTERM tests.

use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use treemorph_api::ErrorCode;
use treemorph_api::delta::{
    Encoder, EncoderOptions, Grid, Material, MaterialGroup, Mesh, StreamHeader,
};
use treemorph_api::jobs::JobRequest;

use crate::pipeline::{FrameOutput, JobError, JobInput, JobOutcome, JobSink, Runner, stage};

/// What the test runner does for a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TestBehaviour {
    /// Emit every frame, sleeping this long before each.
    Frames(Duration),
    /// Fail at once with this code (not retryable).
    Fail(ErrorCode),
    /// Fail retryably on the first `n` runs that get this behaviour, then
    /// emit frames.
    Flaky(u32),
    /// Panic after publishing the first frame.
    Panic,
    /// Ignore cancellation and the stop flag (sleeps this long per frame).
    Stubborn(Duration),
}

type Decide = dyn Fn(&JobRequest) -> TestBehaviour + Send + Sync;

/// The test runner.
pub struct TestRunner {
    decide: Arc<Decide>,
    runs: AtomicU32,
    flaky_runs: AtomicU32,
    checks_reject_frames: Option<u32>,
}

impl std::fmt::Debug for TestRunner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TestRunner")
            .field("runs", &self.runs)
            .finish_non_exhaustive()
    }
}

impl TestRunner {
    /// A runner that decides per request.
    pub fn new(
        decide: impl Fn(&JobRequest) -> TestBehaviour + Send + Sync + 'static,
    ) -> TestRunner {
        TestRunner {
            decide: Arc::new(decide),
            runs: AtomicU32::new(0),
            flaky_runs: AtomicU32::new(0),
            checks_reject_frames: None,
        }
    }

    /// A runner that emits frames with `delay` before each.
    pub fn slow(delay: Duration) -> TestRunner {
        TestRunner::new(move |_| TestBehaviour::Frames(delay))
    }

    /// Makes [`Runner::check`] reject requests for exactly `frames` frames
    /// with `invalid_job` (to test the 422 path of `POST /v1/jobs`).
    pub fn rejecting_frames(mut self, frames: u32) -> TestRunner {
        self.checks_reject_frames = Some(frames);
        self
    }

    /// Parses `--test-runner`: `slow:MS` (or `fast`).
    pub fn from_spec(spec: &str) -> Result<TestRunner, String> {
        match spec.split_once(':') {
            Some(("slow", ms)) => {
                let ms: u64 = ms.parse().map_err(|_| format!("bad delay in {spec:?}"))?;
                Ok(TestRunner::slow(Duration::from_millis(ms)))
            }
            None if spec == "fast" => Ok(TestRunner::slow(Duration::ZERO)),
            _ => Err(format!(
                "unknown test runner {spec:?}; expected slow:MS or fast"
            )),
        }
    }

    /// How many times [`Runner::run`] was called.
    pub fn runs(&self) -> u32 {
        self.runs.load(Ordering::SeqCst)
    }
}

/// The stream header of the synthetic animation (one triangle).
pub fn header(frames: u32) -> StreamHeader {
    let bounds = [[-1.0, 0.0, -1.0], [1.0, 2.0, 1.0]];
    StreamHeader {
        bounds,
        grid: Grid::for_bounds(bounds, 0.001),
        frame_count: frames,
        textures: vec![],
        materials: vec![Material::default()],
        meshes: vec![Mesh {
            name: "branches".into(),
            indices: vec![0, 1, 2],
            uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
            groups: vec![MaterialGroup {
                first: 0,
                count: 3,
                material: 0,
                fade_to: None,
            }],
            base_positions: triangle(0.0).to_vec(),
        }],
    }
}

/// The triangle at time `t`.
pub fn triangle(t: f32) -> [[f32; 3]; 3] {
    [[0.0, 0.0, 0.0], [1.0, t, 0.0], [0.0, 1.0 + t, 0.5 * t]]
}

/// The fake GLB of frame `n`.
pub fn frame_glb(n: u32) -> Vec<u8> {
    let mut v = b"glTF".to_vec();
    v.extend_from_slice(&n.to_le_bytes());
    v
}

fn internal(e: impl std::fmt::Display) -> JobError {
    JobError {
        code: ErrorCode::Internal,
        message: e.to_string(),
        retryable: false,
    }
}

impl Runner for TestRunner {
    fn check(&self, request: &JobRequest) -> Result<(), JobError> {
        if Some(request.frames()) == self.checks_reject_frames {
            return Err(JobError {
                code: ErrorCode::InvalidJob,
                message: format!("the test runner rejects {} frames", request.frames()),
                retryable: false,
            });
        }
        Ok(())
    }

    fn run(&self, input: &JobInput<'_>, sink: &mut dyn JobSink) -> Result<JobOutcome, JobError> {
        self.runs.fetch_add(1, Ordering::SeqCst);
        let request = input.request;
        let frames = request.frames();
        let (delay, stubborn) = match (self.decide)(request) {
            TestBehaviour::Frames(d) => (d, false),
            TestBehaviour::Stubborn(d) => (d, true),
            TestBehaviour::Fail(code) => {
                return Err(JobError {
                    code,
                    message: "the test runner was told to fail".into(),
                    retryable: false,
                });
            }
            TestBehaviour::Flaky(n) if self.flaky_runs.fetch_add(1, Ordering::SeqCst) < n => {
                return Err(JobError {
                    code: ErrorCode::Unavailable,
                    message: "a transient test failure".into(),
                    retryable: true,
                });
            }
            TestBehaviour::Flaky(_) => (Duration::ZERO, false),
            TestBehaviour::Panic => (Duration::ZERO, false),
        };
        let panic_after_first = (self.decide)(request) == TestBehaviour::Panic;
        for id in request.tree_ids() {
            if !input.trees.contains_key(id) {
                return Err(internal(format!("tree {id} was not loaded")));
            }
        }
        sink.stage(stage::ANALYSING, 0.05);
        sink.stage(stage::PLANNING, 0.1);
        let mut encoder =
            Encoder::new(header(frames), &EncoderOptions::default()).map_err(internal)?;
        let mut stream = encoder.header_bytes().to_vec();
        sink.stream_header(stream.clone())
            .map_err(|e| internal(&e))?;
        for n in 0..frames {
            if !delay.is_zero() {
                std::thread::sleep(delay);
            }
            if !stubborn && sink.cancelled() {
                return Err(JobError {
                    code: ErrorCode::Cancelled,
                    message: "cancelled".into(),
                    retryable: false,
                });
            }
            let t = n as f32 / (frames - 1).max(1) as f32;
            let before = stream.len();
            encoder
                .encode_frame(n, t, &[&triangle(t)], t, &mut stream)
                .map_err(internal)?;
            sink.stage(stage::FRAMES, 0.1 + 0.85 * (n + 1) as f32 / frames as f32);
            sink.frame(FrameOutput {
                index: n,
                t,
                glb: request.outputs().glb.then(|| frame_glb(n)),
                delta: stream[before..].to_vec(),
            })
            .map_err(|e| JobError {
                code: ErrorCode::Unavailable,
                message: e.to_string(),
                retryable: true,
            })?;
            if panic_after_first {
                panic!("the test runner was told to panic");
            }
        }
        sink.stage(stage::FINISHING, 0.97);
        encoder.finish(&mut stream).map_err(internal)?;
        let metrics = serde_json::json!({"frames": frames, "runner": "test"});
        let mut files = vec![];
        if request.outputs().animated {
            sink.file("animation.glb", frame_glb(u32::MAX))
                .map_err(|e| internal(&e))?;
            files.push("animation.glb".to_owned());
        }
        if request.outputs().delta {
            sink.file("stream.tmd", stream).map_err(|e| internal(&e))?;
            files.push("stream.tmd".to_owned());
        }
        sink.file("metrics.json", serde_json::to_vec(&metrics).expect("json"))
            .map_err(|e| internal(&e))?;
        files.push("metrics.json".to_owned());
        Ok(JobOutcome {
            frames,
            metrics,
            files,
        })
    }
}
