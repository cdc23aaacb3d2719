//! Whole sequences re-sampled on request: `animation.glb?keyframes=K` and
//! `stream?frames=N` for a job that succeeded.
//!
//! # Choices
//! - The job's stored request is run again with the new frame or keyframe
//!   count and only the one output asked for, through the same
//!   [`crate::pipeline::JobSpec`] conversion as a posted job, so a bad
//!   count gets the same 422 `invalid_request` naming the field, and the
//!   frames are the same functions of `t` as the job's own (plans are
//!   deterministic). The job's metrics are not recomputed into it.
//! - The run happens on the blocking pool, never in a worker slot, and its
//!   file is kept in the render cache ([`super::renders`]) under the job's
//!   attempt and the count, which also names its ETag: a repeated request
//!   is served from memory or answered 304 without a run.
//! - A job whose trees are gone answers 410 `plan_outdated`.
//! - A re-sampled delta stream is sent as it renders the first time it is
//!   asked for ([`super::streamed`]); the animated GLB, whose file is only
//!   written once every frame is in, is sent whole.

use std::collections::HashMap;
use std::sync::Arc;

use axum::http::HeaderMap;
use axum::response::Response;
use bytes::Bytes;
use serde_json::{Value, json};
use treemorph_api::ErrorCode;
use treemorph_api::jobs::JobRequest;

use super::streamed::{Live, LiveSink};
use super::{AppState, blob, streamed};
use crate::error::ApiError;
use crate::jobs::queue::JobRow;
use crate::pipeline::{
    FrameOutput, InputTree, JobError, JobInput, JobSink, JobSpec, Runner, SinkError, StoredPlan,
    TreeSource,
};

/// What to re-sample.
#[derive(Clone, Copy, Debug)]
pub enum Resample {
    /// The animated GLB with the job's own keyframes (a plan-first job's
    /// `animation.glb`).
    Animation,
    /// The animated GLB with this many keyframes.
    Keyframes(u32),
    /// The delta stream with this many frames.
    Frames(u32),
}

impl Resample {
    /// The file the run produces.
    fn file(self) -> &'static str {
        match self {
            Resample::Animation | Resample::Keyframes(_) => "animation.glb",
            Resample::Frames(_) => "stream.tmd",
        }
    }

    /// The cache key (and ETag source) under the job's attempt prefix, for
    /// the run of `spec`: the job's own animation shares the key of its
    /// keyframe count.
    pub fn key(self, prefix: &str, spec: &JobSpec) -> String {
        match self {
            Resample::Animation => format!("{prefix}/keyframes/{}", spec.render().keyframes),
            Resample::Keyframes(k) => format!("{prefix}/keyframes/{k}"),
            Resample::Frames(n) => format!("{prefix}/frames-resampled/{n}"),
        }
    }

    /// Refuses a count outside what a job may ask for (422
    /// `invalid_request` naming the query parameter): keyframes from 2 to
    /// the job's frames, frames from the least a job has to the server's
    /// limit.
    fn check(self, job_frames: u32, max_frames: u32) -> Result<(), ApiError> {
        let (name, value, range) = match self {
            Resample::Animation => return Ok(()),
            Resample::Keyframes(k) => ("keyframes", k, 2..=job_frames),
            Resample::Frames(n) => ("frames", n, crate::pipeline::MIN_FRAMES..=max_frames),
        };
        if range.contains(&value) {
            return Ok(());
        }
        Err(ApiError::invalid(format!(
            "{name} is {value}; it must be from {} to {}",
            range.start(),
            range.end()
        )))
    }

    /// The stored request with the new count and only this output.
    fn request(self, stored: &str) -> Result<JobRequest, ApiError> {
        let mut request: Value = serde_json::from_str(stored).map_err(ApiError::internal)?;
        match self {
            Resample::Animation => {
                request["outputs"] = json!({"glb": false, "animated": true, "delta": false});
            }
            Resample::Keyframes(k) => {
                request["options"]["keyframes"] = json!(k);
                request["outputs"] = json!({"glb": false, "animated": true, "delta": false});
            }
            Resample::Frames(n) => {
                request["frames"] = json!(n);
                request["outputs"] = json!({"glb": false, "animated": false, "delta": true});
            }
        }
        serde_json::from_value(request).map_err(ApiError::internal)
    }
}

/// Collects the whole-sequence files of a run.
#[derive(Default)]
struct Files(HashMap<String, Vec<u8>>);

impl JobSink for Files {
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

    fn file(&mut self, name: &str, bytes: Vec<u8>) -> Result<(), SinkError> {
        self.0.insert(name.to_owned(), bytes);
        Ok(())
    }
}

/// 410 `plan_outdated`: the job cannot be run again.
pub fn outdated(e: JobError) -> ApiError {
    ApiError::new(
        ErrorCode::PlanOutdated,
        format!(
            "this job can no longer render new outputs ({}); post the same request again to re-run it",
            e.message
        ),
    )
}

/// Refuses to render for a job that a process of another
/// [`crate::pipeline::RENDER_VERSION`] ran (410 `plan_outdated`): its
/// renders would not be the bytes it wrote. A job still running has no
/// recorded version yet; it renders.
pub fn check_version(row: &JobRow) -> Result<(), ApiError> {
    let current = crate::pipeline::RENDER_VERSION;
    match &row.result {
        Some(result) if result.render_version != current => Err(ApiError::new(
            ErrorCode::PlanOutdated,
            format!(
                "this job was run by another version of the renderer (version {}; this server renders version {current}), so its outputs cannot be rendered again; post the same request again to re-run it",
                result.render_version
            ),
        )),
        _ => Ok(()),
    }
}

/// The run that re-samples the succeeded job `row`, whose outputs live
/// under `prefix`: its render-cache key (the ETag's source) and its spec,
/// the stored request converted once with the new count and one output.
pub fn prepare(
    state: &AppState,
    row: &JobRow,
    prefix: &str,
    what: Resample,
) -> Result<(String, JobSpec), ApiError> {
    what.check(row.frames, state.settings().max_frames)?;
    let request = what.request(&row.request)?;
    // Unmeasured: the job's own metrics are stored; these would be thrown
    // away.
    let spec = state
        .services
        .runner
        .check(&request, &state.settings().limits())?
        .unmeasured();
    Ok((what.key(prefix, &spec), spec))
}

/// The re-sampled file under `key` ([`prepare`]), from the render cache or
/// run now.
pub async fn file(
    state: &AppState,
    row: &JobRow,
    key: &str,
    spec: JobSpec,
    what: Resample,
) -> Result<Bytes, ApiError> {
    check_version(row)?;
    state
        .renders
        .get_or_render(key, run(state, row, spec, what))
        .await
}

/// Serves the re-sampled delta stream under `key` ([`prepare`]): from the
/// render cache, or as it renders ([`super::streamed`]), joining a render
/// of the same key in progress.
pub async fn streamed(
    state: &AppState,
    row: &JobRow,
    key: &str,
    spec: JobSpec,
    headers: &HeaderMap,
) -> Result<Response, ApiError> {
    check_version(row)?;
    let media = treemorph_api::delta::MEDIA_TYPE;
    if let Some(bytes) = state.renders.cached(key).await {
        return Ok(blob::serve_bytes(key, media, headers, bytes));
    }
    let (live, started) = state.renders.live(key);
    if started {
        let run = render_live(
            state.clone(),
            row.clone(),
            key.to_owned(),
            spec,
            live.clone(),
        );
        tokio::spawn(run);
    }
    live.started().await?;
    Ok(streamed::response(key, media, live))
}

/// Runs the re-sample whose pieces go to `live`, then ends it (into the
/// cache when complete).
async fn render_live(state: AppState, row: JobRow, key: String, spec: JobSpec, live: Arc<Live>) {
    let feed = live.clone();
    let whole = on_inputs(&state, &row, spec, move |runner, input| {
        let mut sink = LiveSink::new(feed);
        runner.run(input, &mut sink)?;
        Ok(sink.into_whole())
    })
    .await
    .and_then(|whole| {
        whole
            .map(Bytes::from)
            .ok_or_else(|| ApiError::internal("the run wrote no stream.tmd"))
    });
    if let Err(e) = &whole {
        tracing::warn!(key, code = ?e.code, error = %e.message, "a streamed re-sample failed");
    }
    state.renders.finish_live(&key, &live, whole);
}

async fn run(
    state: &AppState,
    row: &JobRow,
    spec: JobSpec,
    what: Resample,
) -> Result<Vec<u8>, ApiError> {
    let mut files = on_inputs(state, row, spec, |runner, input| {
        let mut files = Files::default();
        runner.run(input, &mut files).map(|_| files)
    })
    .await?;
    files
        .0
        .remove(what.file())
        .ok_or_else(|| ApiError::internal(format!("the run wrote no {}", what.file())))
}

/// Runs `work` on `spec` on the blocking pool (never in a worker slot: a
/// render does not hold up the job queue), with the plan `row`'s run
/// stored and, should the runner need them (no plan kept or stored), its
/// input trees, loaded then.
pub async fn on_inputs<T: Send + 'static>(
    state: &AppState,
    row: &JobRow,
    spec: JobSpec,
    work: impl FnOnce(&dyn Runner, &JobInput<'_>) -> Result<T, JobError> + Send + 'static,
) -> Result<T, ApiError> {
    let runner = state.services.runner.clone();
    let services = state.services.clone();
    let prefix = row.published_prefix();
    let rt = tokio::runtime::Handle::current();
    let done = tokio::task::spawn_blocking(move || {
        let trees = LazyTrees {
            rt: &rt,
            services: &services,
        };
        let key = prefix.as_deref().map(crate::jobs::queue::plan_key);
        // Read only when the runner asks: a kept plan costs no read.
        let load = || stored_plan(&rt, &services.blobs, key.as_deref()?);
        let input = JobInput {
            spec: &spec,
            trees: &trees,
            stored_plan: key.as_deref().map(|key| StoredPlan { key, load: &load }),
        };
        work(runner.as_ref(), &input)
    })
    .await
    .map_err(ApiError::internal)?;
    done.map_err(|e| match e.code {
        ErrorCode::TreeNotFound => outdated(e),
        ErrorCode::Unavailable => ApiError::unavailable(e.message),
        _ => ApiError::from(e),
    })
}

/// A job's input trees, each loaded (from the tree cache or the blob
/// store) when the runner first asks for it, on the blocking thread the
/// render runs on.
struct LazyTrees<'a> {
    rt: &'a tokio::runtime::Handle,
    services: &'a crate::jobs::Services,
}

impl TreeSource for LazyTrees<'_> {
    fn tree(&self, id: &str) -> Result<Arc<InputTree>, JobError> {
        self.rt
            .block_on(crate::jobs::worker::load_tree(self.services, id))
    }
}

/// The stored plan under `key`, read on a blocking thread; `None` when
/// there is none (jobs run before plans were stored) or it cannot be read
/// (logged: the runner plans again).
fn stored_plan(
    rt: &tokio::runtime::Handle,
    blobs: &crate::store::Blobs,
    key: &str,
) -> Option<Vec<u8>> {
    match rt.block_on(blobs.get(key)) {
        Ok(bytes) => bytes.map(Vec::from),
        Err(e) => {
            tracing::warn!(key, error = %e, "the stored plan cannot be read; planning again");
            None
        }
    }
}
