//! [`BlobSink`]: where a running pipeline publishes progress and outputs.
//!
//! The runner calls the sink on its job thread; the sink drives the async
//! database (and S3) with `Handle::block_on` and writes local blobs on the
//! job thread itself, at job priority ([`Blobs::put_deferred_here`]). Every output is written to the blob store
//! under the attempt's prefix **first**, and only then made visible by a
//! row update fenced by the attempt token (`frames_ready = n + 1`,
//! `header_ready = 1`). When a fenced update matches nothing, the attempt
//! has lost its lease: the sink reports it (`cancelled()` turns true, every
//! later publish fails) and the worker drops the attempt's outcome.
//!
//! Blobs are written with [`Blobs::put_deferred`] (visible at once, safe
//! against a killed process) and made durable together by
//! [`BlobSink::sync_outputs`] before the commit that ends the attempt (see
//! [`crate::store::blobs`] for why, and the window it leaves) — all but a
//! succeeded job's stream records, which its end drops.
//!
//! Progress updates are throttled (a stage change is written at once, mere
//! progress at most every 100 ms) so a fast pipeline does not turn into a
//! stream of fsyncs.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use tokio::runtime::Handle;

use super::Hub;
use super::queue::{self, file_key, frame_delta_key, frame_glb_key, header_key, plan_key};
use crate::pipeline::{Attempt, FrameOutput, JobSink, SinkError};
use crate::store::{Blobs, Db};
use crate::telemetry::Metrics;

/// Files a runner may publish with [`JobSink::file`].
pub const FILES: [&str; 3] = ["animation.glb", "stream.tmd", "metrics.json"];

/// Flags shared between a running attempt, its watcher and the worker.
#[derive(Debug, Default)]
pub struct Flags {
    /// A client cancelled the job.
    pub cancel: Arc<AtomicBool>,
    /// The process is shutting down and the grace period is over: stop and
    /// release the job.
    pub release: AtomicBool,
    /// The lease was lost to another attempt (or a reclaim).
    pub lost: AtomicBool,
    /// Publishing failed because of the blob store or the database (a
    /// transient fault: the attempt is retried).
    pub storage_error: AtomicBool,
}

impl Flags {
    /// Whether the runner should stop.
    pub fn should_stop(&self) -> bool {
        self.cancel.load(Ordering::SeqCst)
            || self.release.load(Ordering::SeqCst)
            || self.lost.load(Ordering::SeqCst)
    }
}

/// The sink of one attempt.
pub struct BlobSink {
    rt: Handle,
    db: Db,
    blobs: Blobs,
    hub: Arc<Hub>,
    metrics: Arc<Metrics>,
    kind: &'static str,
    job: String,
    attempt: u32,
    token: String,
    prefix: String,
    flags: Arc<Flags>,
    stage: &'static str,
    stage_started: Instant,
    progress: f32,
    last_write: Instant,
    frames_ready: u32,
    header: bool,
    frame_glbs: bool,
    files: Vec<String>,
    /// Every blob written, to be synced at the end.
    written: Vec<String>,
}

impl std::fmt::Debug for BlobSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BlobSink")
            .field("job", &self.job)
            .field("frames_ready", &self.frames_ready)
            .finish_non_exhaustive()
    }
}

impl BlobSink {
    /// A sink for the attempt `token` (number `attempt`) of job `job`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        rt: Handle,
        db: Db,
        blobs: Blobs,
        hub: Arc<Hub>,
        metrics: Arc<Metrics>,
        kind: &'static str,
        job: &str,
        attempt: u32,
        token: &str,
        flags: Arc<Flags>,
    ) -> BlobSink {
        BlobSink {
            rt,
            db,
            blobs,
            hub,
            metrics,
            kind,
            job: job.to_owned(),
            attempt,
            token: token.to_owned(),
            prefix: queue::attempt_prefix(job, token),
            flags,
            stage: crate::pipeline::stage::LOADING,
            stage_started: Instant::now(),
            progress: 0.0,
            last_write: Instant::now() - Duration::from_secs(1),
            frames_ready: 0,
            header: false,
            frame_glbs: false,
            files: Vec::new(),
            written: Vec::new(),
        }
    }

    /// Makes the blobs this attempt wrote durable. The worker calls it
    /// before recording the attempt's end, so the outputs of an ended job
    /// survive power loss; a failure counts as a storage fault (the
    /// attempt is retried).
    ///
    /// When the run `succeeded`, its stream records are left out
    /// ([`durable_keys`]): the job's end drops them, and from then on
    /// the stream is served from `stream.tmd`, so syncing them (an fsync
    /// per frame: about 80 ms of the default job's 115 ms sync) would
    /// only delay the success.
    pub fn sync_outputs(&mut self, succeeded: bool) -> Result<(), SinkError> {
        let keys = durable_keys(std::mem::take(&mut self.written), &self.prefix, succeeded);
        self.blobs
            .sync_here(&keys)
            .map_err(|e| self.storage(&format!("{} outputs", keys.len()), e))
    }

    /// Frames published.
    pub fn frames_ready(&self) -> u32 {
        self.frames_ready
    }

    /// Whether any frame carried a GLB.
    pub fn frame_glbs(&self) -> bool {
        self.frame_glbs
    }

    /// Offers the outputs of `requested` that a plan-first run left out
    /// ([`crate::pipeline::JobSpec::stored_part`]): they are rendered on
    /// request, and the job lists them as if stored (`files`,
    /// `frame_glbs`), so its links and routes stay as they were.
    pub fn offer_rendered(&mut self, requested: &treemorph_api::jobs::Outputs) {
        if requested.glb {
            self.frame_glbs = true;
        }
        if requested.animated && !self.files.iter().any(|f| f == "animation.glb") {
            self.files.push("animation.glb".to_owned());
        }
    }

    /// Files published (or offered, [`BlobSink::offer_rendered`]).
    pub fn files(&self) -> &[String] {
        &self.files
    }

    /// Records the time spent in the current stage (at a stage change and
    /// at the end of the job).
    pub fn close_stage(&mut self) {
        self.metrics
            .observe_stage(self.kind, self.stage, self.stage_started.elapsed());
        self.stage_started = Instant::now();
    }

    fn put(&mut self, what: &str, key: String, bytes: Vec<u8>) -> Result<(), SinkError> {
        if self.flags.lost.load(Ordering::SeqCst) {
            return Err(self.lost(what));
        }
        self.blobs
            .put_deferred_here(&self.rt, &key, bytes)
            .map_err(|e| self.storage(what, e))?;
        self.written.push(key);
        Ok(())
    }

    fn commit(&self, what: &str, result: Result<bool, sqlx::Error>) -> Result<(), SinkError> {
        match result {
            Ok(true) => {
                self.hub.changed(&self.job);
                Ok(())
            }
            Ok(false) => {
                self.flags.lost.store(true, Ordering::SeqCst);
                Err(self.lost(what))
            }
            Err(e) => Err(self.storage(what, e)),
        }
    }

    fn lost(&self, what: &str) -> SinkError {
        SinkError {
            what: what.to_owned(),
            reason: "this attempt lost its lease to a newer one".into(),
        }
    }

    fn storage(&self, what: &str, e: impl std::fmt::Display) -> SinkError {
        self.flags.storage_error.store(true, Ordering::SeqCst);
        tracing::warn!(job = %self.job, what, error = %e, "publishing an output failed");
        SinkError {
            what: what.to_owned(),
            reason: e.to_string(),
        }
    }
}

impl JobSink for BlobSink {
    fn stage(&mut self, stage: &'static str, progress: f32) {
        let changed = stage != self.stage;
        if changed {
            self.close_stage();
            self.stage = stage;
        }
        self.progress = progress.clamp(0.0, 1.0);
        if changed || self.last_write.elapsed() >= Duration::from_millis(100) {
            self.last_write = Instant::now();
            let r = self.rt.block_on(queue::set_progress(
                &self.db,
                &self.job,
                &self.token,
                stage,
                f64::from(self.progress),
            ));
            // Progress is advisory: a failed write is not worth failing the
            // job over, but a lost lease must stop it.
            match r {
                Ok(false) => self.flags.lost.store(true, Ordering::SeqCst),
                Ok(true) => self.hub.changed(&self.job),
                Err(e) => tracing::warn!(job = %self.job, error = %e, "progress update failed"),
            }
        }
    }

    fn cancelled(&self) -> bool {
        self.flags.should_stop()
    }

    fn stream_header(&mut self, bytes: Vec<u8>) -> Result<(), SinkError> {
        if self.header {
            return Err(SinkError {
                what: "stream header".into(),
                reason: "published twice".into(),
            });
        }
        self.put("stream header", header_key(&self.prefix), bytes)?;
        let r = self
            .rt
            .block_on(queue::publish_header(&self.db, &self.job, &self.token));
        self.commit("stream header", r)?;
        self.header = true;
        Ok(())
    }

    fn frame(&mut self, frame: FrameOutput) -> Result<(), SinkError> {
        let what = format!("frame {}", frame.index);
        if frame.index != self.frames_ready {
            return Err(SinkError {
                what,
                reason: format!(
                    "frames must be published in order; expected {}",
                    self.frames_ready
                ),
            });
        }
        // Both blobs first; the row update below publishes them together.
        if let Some(glb) = frame.glb {
            self.put(&what, frame_glb_key(&self.prefix, frame.index), glb)?;
            self.frame_glbs = true;
        }
        self.put(
            &what,
            frame_delta_key(&self.prefix, frame.index),
            frame.delta,
        )?;
        let r = self.rt.block_on(queue::publish_frames(
            &self.db,
            &self.job,
            &self.token,
            frame.index + 1,
            f64::from(self.progress),
        ));
        self.commit(&what, r)?;
        self.frames_ready = frame.index + 1;
        Ok(())
    }

    fn file(&mut self, name: &str, bytes: Vec<u8>) -> Result<(), SinkError> {
        if !FILES.contains(&name) {
            return Err(SinkError {
                what: name.to_owned(),
                reason: format!("unknown output file; expected one of {FILES:?}"),
            });
        }
        self.put(name, file_key(&self.prefix, name), bytes)?;
        if !self.files.iter().any(|f| f == name) {
            self.files.push(name.to_owned());
        }
        Ok(())
    }

    fn keeps_plan(&self) -> bool {
        true
    }

    fn plan(&mut self, bytes: Vec<u8>) -> Result<(), SinkError> {
        self.put("plan", plan_key(&self.prefix), bytes)
    }

    fn attempt(&self) -> Option<Attempt<'_>> {
        Some(Attempt {
            job: &self.job,
            number: self.attempt,
            token: &self.token,
        })
    }
}

/// The keys of `written` (under the attempt `prefix`) that must outlive a
/// power loss: all of them, except, after a run that `succeeded`, its
/// stream records, which nothing reads once the job has succeeded
/// (`crate::server::stream` serves `stream.tmd` then).
fn durable_keys(written: Vec<String>, prefix: &str, succeeded: bool) -> Vec<String> {
    if !succeeded {
        return written;
    }
    let records = format!("{}/", queue::stream_records_prefix(prefix));
    written
        .into_iter()
        .filter(|key| !key.starts_with(&records))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn written(prefix: &str) -> Vec<String> {
        vec![
            header_key(prefix),
            frame_delta_key(prefix, 0),
            frame_glb_key(prefix, 0),
            file_key(prefix, "stream.tmd"),
            file_key(prefix, "metrics.json"),
            plan_key(prefix),
        ]
    }

    #[test]
    fn a_succeeded_run_syncs_everything_but_its_stream_records() {
        let prefix = queue::attempt_prefix("job", "token");
        let kept = durable_keys(written(&prefix), &prefix, true);
        assert_eq!(kept, written(&prefix)[2..].to_vec());
    }

    #[test]
    fn a_failed_run_syncs_its_stream_records_too() {
        // Clients of a failed or cancelled job are still served the
        // records published before it ended.
        let prefix = queue::attempt_prefix("job", "token");
        assert_eq!(
            durable_keys(written(&prefix), &prefix, false),
            written(&prefix)
        );
    }
}
