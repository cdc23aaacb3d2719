//! **Test only**: a small deterministic [`Runner`] for testing the queue,
//! streaming and crash recovery without the geometry pipelines.
//!
//! It emits a real delta stream (a one-triangle mesh that moves with `t`)
//! so clients can decode it, fake frame GLBs (`glTF` + the frame index),
//! and the three whole-sequence files. Its behaviour is configurable per
//! request through [`TestBehaviour`] (a delay per frame, failures, panics),
//! and the real binary selects it with the hidden `--test-runner slow:MS`
//! flag (`TREEMORPH_TEST_RUNNER`), used by the kill -9 and SIGTERM tests.
//!
//! # Tracing attempts (`slow:MS,trace=DIR`)
//! With a trace directory the runner appends one JSON line per attempt
//! start and end ([`TraceEvent`]) to `DIR/attempts-{pid}.jsonl`, and stamps
//! the attempt's token into every output: after the 8 bytes of a frame or
//! animation GLB, as `"attempt"` in `metrics.json` and as the name of the
//! stream header's material (`attempt:{token}`). The scale-out test reads
//! both to prove that no attempt ran twice at once and that every served
//! byte comes from the attempt the job's row publishes.

use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use serde::{Deserialize, Serialize};

use treemorph_api::ErrorCode;
use treemorph_api::delta::{
    Encoder, EncoderOptions, Grid, Material, MaterialGroup, Mesh, StreamHeader,
};
use treemorph_api::jobs::JobRequest;

use crate::pipeline::{
    FrameOutput, JobError, JobInput, JobOutcome, JobSink, JobSpec, Limits, Runner, StreamPart,
    stage,
};

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

type Decide = dyn Fn(&JobSpec) -> TestBehaviour + Send + Sync;

/// The test runner.
pub struct TestRunner {
    decide: Arc<Decide>,
    runs: AtomicU32,
    instants: AtomicU32,
    flaky_runs: AtomicU32,
    checks_reject_frames: Option<u32>,
    trace: Option<PathBuf>,
    plan_first: bool,
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
    pub fn new(decide: impl Fn(&JobSpec) -> TestBehaviour + Send + Sync + 'static) -> TestRunner {
        TestRunner {
            decide: Arc::new(decide),
            runs: AtomicU32::new(0),
            instants: AtomicU32::new(0),
            flaky_runs: AtomicU32::new(0),
            checks_reject_frames: None,
            trace: None,
            plan_first: false,
        }
    }

    /// A runner that emits frames with `delay` before each.
    pub fn slow(delay: Duration) -> TestRunner {
        TestRunner::new(move |_| TestBehaviour::Frames(delay))
    }

    /// How many single instants were rendered ([`Runner::frame_at`]).
    pub fn instants(&self) -> u32 {
        self.instants.load(Ordering::SeqCst)
    }

    /// Makes [`Runner::check`] reject requests for exactly `frames` frames
    /// with `invalid_job` (to test the 422 path of `POST /v1/jobs`).
    pub fn rejecting_frames(mut self, frames: u32) -> TestRunner {
        self.checks_reject_frames = Some(frames);
        self
    }

    /// Makes the runner claim [`Runner::renders_on_request`], so the
    /// service stores only a job's stream and metrics and renders frames
    /// ([`instant_glb`]) and the animated GLB when asked, as with the
    /// production runner. Without it, jobs store every output, as jobs
    /// stored by earlier versions did.
    pub fn plan_first(mut self) -> TestRunner {
        self.plan_first = true;
        self
    }

    /// Records attempts in `dir` and stamps outputs with the attempt's
    /// token (see the module docs).
    pub fn tracing_to(mut self, dir: impl Into<PathBuf>) -> TestRunner {
        self.trace = Some(dir.into());
        self
    }

    /// Parses `--test-runner`: `slow:MS` (or `fast`), optionally followed
    /// by `,trace=DIR`.
    pub fn from_spec(spec: &str) -> Result<TestRunner, String> {
        let (base, trace) = match spec.split_once(',') {
            Some((base, option)) => match option.split_once('=') {
                Some(("trace", dir)) if !dir.is_empty() => (base, Some(dir)),
                _ => return Err(format!("unknown test runner option {option:?}")),
            },
            None => (spec, None),
        };
        let runner = match base.split_once(':') {
            Some(("slow", ms)) => {
                let ms: u64 = ms.parse().map_err(|_| format!("bad delay in {spec:?}"))?;
                TestRunner::slow(Duration::from_millis(ms))
            }
            None if base == "fast" => TestRunner::slow(Duration::ZERO),
            _ => {
                return Err(format!(
                    "unknown test runner {spec:?}; expected slow:MS or fast[,trace=DIR]"
                ));
            }
        };
        Ok(match trace {
            Some(dir) => runner.tracing_to(dir),
            None => runner,
        })
    }

    fn record(&self, event: &TraceEvent) {
        let Some(dir) = &self.trace else { return };
        let mut line = serde_json::to_vec(event).expect("trace event serialises");
        line.push(b'\n');
        // One write per line on an O_APPEND file: lines of concurrent
        // attempts never interleave.
        let written = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(dir.join(format!("attempts-{}.jsonl", std::process::id())))
            .and_then(|mut f| f.write_all(&line));
        if let Err(e) = written {
            tracing::error!(error = %e, dir = %dir.display(), "writing the test runner's trace failed");
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

/// The attempt token stamped into a fake GLB (`None` when unstamped).
pub fn stamped_token(glb: &[u8]) -> Option<&str> {
    glb.get(8..)
        .filter(|t| !t.is_empty())
        .and_then(|t| std::str::from_utf8(t).ok())
}

/// The attempt token stamped into a stream header (`None` when
/// unstamped).
pub fn stamped_header_token(header: &StreamHeader) -> Option<&str> {
    header
        .materials
        .first()
        .and_then(|m| m.name.strip_prefix("attempt:"))
}

/// One line of the runner's trace (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TraceEvent {
    /// `start` or `end`.
    pub ev: String,
    /// The job's id.
    pub job: String,
    /// The attempt's number.
    pub attempt: u32,
    /// The attempt's token.
    pub token: String,
    /// The worker process.
    pub pid: u32,
    /// When, in milliseconds since the Unix epoch.
    pub at_ms: i64,
    /// How the run ended (`end` only): `ok`, `stopped` (cancelled, lease
    /// lost or shutting down) or `error:{code}`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outcome: Option<String>,
}

/// Reads every trace file in `dir` (a line cut short by `kill -9` is
/// skipped).
pub fn read_trace(dir: &std::path::Path) -> std::io::Result<Vec<TraceEvent>> {
    let mut events = Vec::new();
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        if path.extension().is_some_and(|e| e == "jsonl") {
            let text = std::fs::read_to_string(&path)?;
            events.extend(
                text.lines()
                    .filter_map(|l| serde_json::from_str::<TraceEvent>(l).ok()),
            );
        }
    }
    events.sort_by_key(|e| e.at_ms);
    Ok(events)
}

fn internal(e: impl std::fmt::Display) -> JobError {
    JobError::internal(e)
}

/// The fake GLB the test runner renders at instant `t`: the magic and the
/// bits of `t`.
pub fn instant_glb(t: f32) -> Vec<u8> {
    let mut v = b"glTF".to_vec();
    v.extend_from_slice(&t.to_bits().to_le_bytes());
    v.extend_from_slice(b"instant");
    v
}

/// What [`TestRunner`] renders as a delta stream at instant `t`: not a
/// stream, but bytes that name the instant.
pub fn instant_stream(t: f32) -> Vec<u8> {
    let mut v = b"TMD\0".to_vec();
    v.extend_from_slice(&t.to_bits().to_le_bytes());
    v.extend_from_slice(b"instant");
    v
}

impl Runner for TestRunner {
    fn renders_on_request(&self) -> bool {
        self.plan_first
    }

    /// Takes as long as one of the job's frames.
    fn frame_at(&self, input: &JobInput<'_>, t: f32) -> Result<Vec<u8>, JobError> {
        let t = crate::pipeline::check_instant(t)?;
        self.instants.fetch_add(1, Ordering::SeqCst);
        if let TestBehaviour::Frames(delay) = (self.decide)(input.spec) {
            std::thread::sleep(delay);
        }
        Ok(instant_glb(t))
    }

    /// As [`TestRunner::frame_at`], counted with it.
    fn stream_at(
        &self,
        input: &JobInput<'_>,
        t: f32,
        part: StreamPart,
    ) -> Result<Vec<u8>, JobError> {
        let mut bytes = self.frame_at(input, t).map(|_| instant_stream(t))?;
        if part == StreamPart::Frame {
            bytes.extend_from_slice(b" frame");
        }
        Ok(bytes)
    }

    fn check(&self, request: &JobRequest, limits: &Limits) -> Result<JobSpec, JobError> {
        // The same conversion as production, so tests of the HTTP layer see
        // the same refusals.
        let spec = JobSpec::parse(request, limits)?;
        if Some(spec.frames()) == self.checks_reject_frames {
            return Err(JobError::invalid(
                ErrorCode::InvalidJob,
                format!("the test runner rejects {} frames", spec.frames()),
            ));
        }
        Ok(spec)
    }

    fn run(&self, input: &JobInput<'_>, sink: &mut dyn JobSink) -> Result<JobOutcome, JobError> {
        self.runs.fetch_add(1, Ordering::SeqCst);
        let traced = match (&self.trace, sink.attempt()) {
            (Some(_), Some(a)) => Some(TraceEvent {
                ev: "start".into(),
                job: a.job.to_owned(),
                attempt: a.number,
                token: a.token.to_owned(),
                pid: std::process::id(),
                at_ms: crate::store::now_ms(),
                outcome: None,
            }),
            _ => None,
        };
        let Some(mut event) = traced else {
            return self.run_stamped(input, sink, None);
        };
        self.record(&event);
        let result = self.run_stamped(input, sink, Some(&event.token));
        event.ev = "end".into();
        event.at_ms = crate::store::now_ms();
        event.outcome = Some(match &result {
            Ok(_) => "ok".into(),
            Err(_) if sink.cancelled() => "stopped".into(),
            Err(e) => format!("error:{}", e.code),
        });
        self.record(&event);
        result
    }
}

impl TestRunner {
    /// [`Runner::run`], with outputs stamped with `token` when given.
    fn run_stamped(
        &self,
        input: &JobInput<'_>,
        sink: &mut dyn JobSink,
        token: Option<&str>,
    ) -> Result<JobOutcome, JobError> {
        let stamp = |mut glb: Vec<u8>| {
            glb.extend_from_slice(token.unwrap_or_default().as_bytes());
            glb
        };
        let spec = input.spec;
        let frames = spec.frames();
        let (delay, stubborn) = match (self.decide)(spec) {
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
        let panic_after_first = (self.decide)(spec) == TestBehaviour::Panic;
        for id in spec.tree_ids() {
            if input.trees.tree(id).is_err() {
                return Err(internal(format!("tree {id} was not loaded")));
            }
        }
        sink.stage(stage::ANALYSING, 0.05);
        sink.stage(stage::PLANNING, 0.1);
        let mut header = header(frames);
        if let Some(token) = token {
            header.materials[0].name = format!("attempt:{token}");
        }
        let mut encoder = Encoder::new(header, &EncoderOptions::default()).map_err(internal)?;
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
                glb: spec.outputs().glb.then(|| stamp(frame_glb(n))),
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
        let mut metrics = serde_json::json!({"frames": frames, "runner": "test"});
        if let Some(token) = token {
            metrics["attempt"] = token.into();
        }
        let mut files = vec![];
        if spec.outputs().animated {
            sink.file("animation.glb", stamp(frame_glb(u32::MAX)))
                .map_err(|e| internal(&e))?;
            files.push("animation.glb".to_owned());
        }
        if spec.outputs().delta {
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

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use treemorph_api::delta::{DecoderOptions, decode_all};
    use treemorph_api::jobs::{MorphRequest, Outputs};

    use super::*;
    use crate::pipeline::{Attempt, SinkError};

    /// Keeps what the runner publishes; claims to be attempt 2 of job `j`.
    #[derive(Default)]
    struct Sink {
        stream: Vec<u8>,
        glbs: Vec<Vec<u8>>,
        files: HashMap<String, Vec<u8>>,
    }

    impl JobSink for Sink {
        fn stage(&mut self, _: &'static str, _: f32) {}
        fn cancelled(&self) -> bool {
            false
        }
        fn stream_header(&mut self, bytes: Vec<u8>) -> Result<(), SinkError> {
            self.stream = bytes;
            Ok(())
        }
        fn frame(&mut self, frame: FrameOutput) -> Result<(), SinkError> {
            self.stream.extend_from_slice(&frame.delta);
            self.glbs.extend(frame.glb);
            Ok(())
        }
        fn file(&mut self, name: &str, bytes: Vec<u8>) -> Result<(), SinkError> {
            self.files.insert(name.to_owned(), bytes);
            Ok(())
        }
        fn attempt(&self) -> Option<Attempt<'_>> {
            Some(Attempt {
                job: "j",
                number: 2,
                token: "tok",
            })
        }
    }

    fn run(runner: &TestRunner) -> Sink {
        let request = JobRequest::Morph(MorphRequest {
            source: "a".into(),
            target: "b".into(),
            frames: 3,
            options: Default::default(),
            outputs: Outputs::default(),
            callback_url: None,
        });
        let tree = Arc::new(crate::pipeline::InputTree::new(
            treemorph_generate::generate(
                &treemorph_generate::GenerateOptions::new(treemorph_generate::Preset::Maple, 1)
                    .with_size(60),
            )
            .unwrap(),
        ));
        let trees = HashMap::from([("a".to_owned(), tree.clone()), ("b".to_owned(), tree)]);
        let mut sink = Sink::default();
        let spec = runner
            .check(&request, &crate::pipeline::Limits::default())
            .unwrap();
        let input = JobInput {
            spec: &spec,
            trees: &trees,
            stored_plan: None,
        };
        runner.run(&input, &mut sink).unwrap();
        sink
    }

    #[test]
    fn specs_parse() {
        assert!(TestRunner::from_spec("slow:5").unwrap().trace.is_none());
        assert!(TestRunner::from_spec("fast").is_ok());
        let traced = TestRunner::from_spec("slow:5,trace=/tmp/x").unwrap();
        assert_eq!(traced.trace, Some(PathBuf::from("/tmp/x")));
        for bad in [
            "slow",
            "slow:x",
            "quick:1",
            "slow:1,trace=",
            "slow:1,speed=2",
        ] {
            assert!(TestRunner::from_spec(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn untraced_outputs_are_unstamped() {
        let sink = run(&TestRunner::slow(Duration::ZERO));
        assert_eq!(sink.glbs[1], frame_glb(1));
        assert_eq!(stamped_token(&sink.glbs[1]), None);
        let (header, frames) =
            decode_all(&sink.files["stream.tmd"], &DecoderOptions::default()).unwrap();
        assert_eq!(frames.len(), 3);
        assert_eq!(stamped_header_token(&header), None);
    }

    #[test]
    fn traced_runs_record_start_and_end_and_stamp_every_output() {
        let dir = tempfile::tempdir().unwrap();
        let sink = run(&TestRunner::slow(Duration::ZERO).tracing_to(dir.path()));
        for glb in sink.glbs.iter().chain([&sink.files["animation.glb"]]) {
            assert_eq!(stamped_token(glb), Some("tok"));
        }
        let metrics: serde_json::Value =
            serde_json::from_slice(&sink.files["metrics.json"]).unwrap();
        assert_eq!(metrics["attempt"], "tok");
        let (header, frames) =
            decode_all(&sink.files["stream.tmd"], &DecoderOptions::default()).unwrap();
        assert_eq!(frames.len(), 3);
        assert_eq!(stamped_header_token(&header), Some("tok"));
        assert!(sink.files["stream.tmd"].starts_with(&sink.stream));

        let events = read_trace(dir.path()).unwrap();
        assert_eq!(events.len(), 2, "{events:?}");
        assert_eq!(
            (events[0].ev.as_str(), events[1].ev.as_str()),
            ("start", "end")
        );
        for e in &events {
            assert_eq!(
                (e.job.as_str(), e.attempt, e.token.as_str()),
                ("j", 2, "tok")
            );
            assert_eq!(e.pid, std::process::id());
        }
        assert_eq!(events[0].outcome, None);
        assert_eq!(events[1].outcome.as_deref(), Some("ok"));
        assert!(events[0].at_ms <= events[1].at_ms);
    }

    #[test]
    fn a_line_cut_short_is_skipped() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("attempts-1.jsonl"),
            "{\"ev\":\"start\",\"job\":\"j\",\"attempt\":1,\"token\":\"t\",\"pid\":1,\"at_ms\":5}\n{\"ev\":\"end\",\"jo",
        )
        .unwrap();
        let events = read_trace(dir.path()).unwrap();
        assert_eq!(events.len(), 1);
        assert_eq!(events[0].token, "t");
    }
}
