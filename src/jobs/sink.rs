//! [`BlobSink`]: where a running pipeline publishes progress and outputs.
//!
//! The runner calls the sink on its job thread; the sink drives the async
//! database (and S3) with `Handle::block_on` and writes local blobs on the
//! job thread itself, at job priority ([`Blobs::put_deferred_here`]); the
//! large outputs of a job's end are written on a thread of their own at the
//! same priority while the job thread goes on ([`BlobSink::put_behind`]);
//! on the local store `stream.tmd` is written as the frames come
//! ([`JobSink::stream_part`]).
//! Every output is written to the blob store
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
use crate::store::{BlobError, BlobWriter, Blobs, Db};
use crate::telemetry::Metrics;

/// Outputs of a job's end at least this large are written beside the job
/// thread ([`BlobSink::put_behind`]); smaller ones cost less than a thread.
const PUT_BEHIND_BYTES: usize = 1 << 20;

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
    /// Puts of the job's end still writing (see [`BlobSink::put_behind`]):
    /// what each is and the thread writing it.
    pending: Vec<(String, std::thread::JoinHandle<Result<(), BlobError>>)>,
    /// `stream.tmd` as it is written, on the local store
    /// ([`JobSink::stream_part`]).
    stream_file: Option<BlobWriter>,
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
            pending: Vec::new(),
            stream_file: None,
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
        self.join_pending()?;
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
        self.holds_lease(what)?;
        self.blobs
            .put_deferred_here(&self.rt, &key, bytes)
            .map_err(|e| self.storage(what, e))?;
        self.written.push(key);
        Ok(())
    }

    /// [`BlobSink::put`] on a thread of its own (at job priority, as the
    /// job thread writes), for a large output that no client reads before
    /// the job ends (`file`, `plan`): the job thread goes on to its next
    /// output while this one is copied into the page cache, and
    /// [`BlobSink::sync_outputs`] waits for it before syncing. On the
    /// default job, writing the 17 MB `stream.tmd` took about 37 ms of its
    /// end, beside which `metrics.json` is built and the plan encoded.
    fn put_behind(&mut self, what: &str, key: String, bytes: Vec<u8>) -> Result<(), SinkError> {
        if bytes.len() < PUT_BEHIND_BYTES {
            return self.put(what, key, bytes);
        }
        self.holds_lease(what)?;
        let (blobs, rt, at) = (self.blobs.clone(), self.rt.clone(), key.clone());
        let writer = std::thread::Builder::new()
            .name(format!("put-{}", self.job))
            .spawn(move || {
                super::priority::lower_this_thread();
                blobs.put_deferred_here(&rt, &at, bytes)?;
                // Written back here rather than by the sync at the job's
                // end, which waited for the plan's 2.8 MB on the default
                // job after its last frame.
                blobs.write_back_here(&at);
                Ok(())
            })
            .map_err(|e| self.storage(what, e))?;
        self.pending.push((what.to_owned(), writer));
        self.written.push(key);
        Ok(())
    }

    /// Waits for every put left writing ([`BlobSink::put_behind`]); the
    /// first failure is reported once all have ended.
    fn join_pending(&mut self) -> Result<(), SinkError> {
        let mut first = Ok(());
        for (what, writer) in std::mem::take(&mut self.pending) {
            let ended = match writer.join() {
                Ok(put) => put.map_err(|e| self.storage(&what, e)),
                Err(_) => Err(self.storage(&what, "the thread writing it panicked")),
            };
            first = first.and(ended);
        }
        first
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

    /// Fails with [`BlobSink::lost`] once the attempt has lost its lease:
    /// nothing more of it is written.
    fn holds_lease(&self, what: &str) -> Result<(), SinkError> {
        if self.flags.lost.load(Ordering::SeqCst) {
            return Err(self.lost(what));
        }
        Ok(())
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
        self.put_behind(name, file_key(&self.prefix, name), bytes)?;
        if !self.files.iter().any(|f| f == name) {
            self.files.push(name.to_owned());
        }
        Ok(())
    }

    /// On the local store `stream.tmd` is written as the frames come, by
    /// the job thread beside the frames' work ([`BlobWriter`]); on S3 it
    /// is put whole at the end. Written whole, its 17 MB took 35-50 ms of
    /// the default job's end on this store.
    fn stream_part(&mut self, bytes: &[u8], last: bool) -> Result<bool, SinkError> {
        const NAME: &str = "stream.tmd";
        let key = file_key(&self.prefix, NAME);
        let mut writer = match self.stream_file.take() {
            Some(w) => w,
            None => {
                self.holds_lease(NAME)?;
                match self.blobs.writer(&key) {
                    Ok(Some(w)) => w,
                    Ok(None) => return Ok(false),
                    Err(e) => return Err(self.storage(NAME, e)),
                }
            }
        };
        writer.append(bytes).map_err(|e| self.storage(NAME, e))?;
        if !last {
            self.stream_file = Some(writer);
            return Ok(true);
        }
        self.holds_lease(NAME)?;
        writer.finish().map_err(|e| self.storage(NAME, e))?;
        self.written.push(key);
        if !self.files.iter().any(|f| f == NAME) {
            self.files.push(NAME.to_owned());
        }
        Ok(true)
    }

    fn keeps_plan(&self) -> bool {
        true
    }

    fn plan(&mut self, bytes: Vec<u8>) -> Result<(), SinkError> {
        self.put_behind("plan", plan_key(&self.prefix), bytes)
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

    /// A sink of job `job` (token `token`) over a local store in `dir`.
    fn sink(rt: &tokio::runtime::Runtime, dir: &std::path::Path) -> BlobSink {
        let db = rt
            .block_on(Db::connect("sqlite::memory:"))
            .expect("an in-memory database");
        BlobSink::new(
            rt.handle().clone(),
            db,
            Blobs::local(dir).expect("a local store"),
            Arc::new(Hub::default()),
            Arc::new(Metrics::default()),
            "morph",
            "job",
            1,
            "token",
            Arc::new(Flags::default()),
        )
    }

    #[test]
    fn outputs_written_behind_the_job_are_whole_once_synced() {
        let rt = tokio::runtime::Runtime::new().expect("a runtime");
        let dir = tempfile::tempdir().expect("a directory");
        let mut sink = sink(&rt, dir.path());
        let stream: Vec<u8> = (0..3 * PUT_BEHIND_BYTES).map(|i| (i % 251) as u8).collect();
        sink.file("stream.tmd", stream.clone()).expect("queued");
        sink.file("metrics.json", b"{}".to_vec()).expect("written");
        sink.plan(vec![7; PUT_BEHIND_BYTES]).expect("queued");
        assert_eq!(sink.pending.len(), 2, "the two large outputs go behind");
        sink.sync_outputs(true).expect("synced");
        let prefix = queue::attempt_prefix("job", "token");
        let read = |key: String| std::fs::read(dir.path().join(key)).expect("stored");
        assert_eq!(read(file_key(&prefix, "stream.tmd")), stream);
        assert_eq!(read(file_key(&prefix, "metrics.json")), b"{}");
        assert_eq!(read(plan_key(&prefix)), vec![7; PUT_BEHIND_BYTES]);
    }

    #[test]
    fn a_put_behind_the_job_that_fails_fails_the_sync() {
        // The attempt's directory is a file: no blob can be written under it.
        let rt = tokio::runtime::Runtime::new().expect("a runtime");
        let dir = tempfile::tempdir().expect("a directory");
        std::fs::create_dir_all(dir.path().join("jobs/job")).expect("a directory");
        std::fs::write(dir.path().join("jobs/job/token"), b"in the way").expect("a file");
        let mut sink = sink(&rt, dir.path());
        sink.file("stream.tmd", vec![0; PUT_BEHIND_BYTES])
            .expect("queued: the failure shows at the sync");
        let err = sink.sync_outputs(true).expect_err("the put failed");
        assert_eq!(err.what, "stream.tmd");
        assert!(sink.flags.storage_error.load(Ordering::SeqCst));
    }

    /// Every file under `dir`, relative to it.
    fn files_under(dir: &std::path::Path) -> Vec<String> {
        let mut out = Vec::new();
        let mut todo = vec![dir.to_owned()];
        while let Some(d) = todo.pop() {
            for entry in std::fs::read_dir(&d).expect("a directory").flatten() {
                let path = entry.path();
                if path.is_dir() {
                    todo.push(path);
                } else {
                    let rel = path.strip_prefix(dir).expect("under dir");
                    out.push(rel.to_string_lossy().into_owned());
                }
            }
        }
        out.sort();
        out
    }

    #[test]
    fn a_stream_written_in_parts_appears_whole_at_its_key() {
        let rt = tokio::runtime::Runtime::new().expect("a runtime");
        let dir = tempfile::tempdir().expect("a directory");
        let mut sink = sink(&rt, dir.path());
        let prefix = queue::attempt_prefix("job", "token");
        let key = file_key(&prefix, "stream.tmd");
        assert!(sink.stream_part(b"header+0;", false).expect("taken"));
        assert!(sink.stream_part(b"1;", false).expect("taken"));
        assert!(
            !dir.path().join(&key).exists(),
            "no blob before the stream ends"
        );
        assert!(sink.stream_part(b"end", true).expect("taken"));
        sink.sync_outputs(true).expect("synced");
        assert_eq!(
            std::fs::read(dir.path().join(&key)).expect("stored"),
            b"header+0;1;end"
        );
        assert_eq!(files_under(dir.path()), vec![key]);
        assert_eq!(sink.files(), ["stream.tmd"]);
    }

    #[test]
    fn a_stream_written_back_as_it_comes_is_whole() {
        // Parts of several megabytes start their write-back behind the
        // job: the file still ends whole, in order, at its key.
        let rt = tokio::runtime::Runtime::new().expect("a runtime");
        let dir = tempfile::tempdir().expect("a directory");
        let mut sink = sink(&rt, dir.path());
        let key = file_key(&queue::attempt_prefix("job", "token"), "stream.tmd");
        let parts: Vec<Vec<u8>> = (0..5u8).map(|k| vec![k; 3 << 20]).collect();
        for (k, part) in parts.iter().enumerate() {
            assert!(sink.stream_part(part, k == 4).expect("taken"));
        }
        sink.sync_outputs(true).expect("synced");
        let stored = std::fs::read(dir.path().join(&key)).expect("stored");
        assert!(stored == parts.concat(), "{} bytes", stored.len());
        assert_eq!(files_under(dir.path()), vec![key]);
    }

    #[test]
    fn a_stream_left_unfinished_leaves_no_file() {
        // A run that fails between frames drops its sink with the stream
        // half written: the partial file goes with it.
        let rt = tokio::runtime::Runtime::new().expect("a runtime");
        let dir = tempfile::tempdir().expect("a directory");
        let mut sink = sink(&rt, dir.path());
        assert!(sink.stream_part(b"header+0;", false).expect("taken"));
        assert_eq!(files_under(dir.path()).len(), 1, "the partial file");
        drop(sink);
        assert!(files_under(dir.path()).is_empty());
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
