//! The worker pool: N claim loops, a reclaimer of expired leases and the
//! webhook deliverer, plus graceful shutdown.
//!
//! Each worker claims one job at a time (see [`super::queue`]) and runs it
//! on a thread of its own at job priority. Beside the attempt runs a *watcher* task that,
//! every `--poll-ms`, reads the job's row (fenced by the token): it renews
//! the lease every third of its duration, raises the cancellation flag when
//! a client cancelled the job from any process, and notices a lost lease.
//! The runner polls the flag between frames, so a cancellation reaches it
//! within one frame of the watcher's poll (at once when the cancelling
//! request was served by this process: the [`super::Hub`] sets the flag
//! directly).
//!
//! # Plan first
//! When the runner renders outputs again on request
//! ([`crate::pipeline::Runner::renders_on_request`]), a job runs only its
//! stored part: the delta stream and the metrics. Per-frame GLBs and the
//! animated GLB are rendered from the job's request and trees when first
//! asked for (`crate::server::jobs`), so a job stores about 1/60 of what
//! it would and succeeds as soon as its frames are computed.
//!
//! # Shutdown
//! [`Pool::shutdown`] stops claiming, lets in-flight attempts run for the
//! grace period, then raises their release flag: runners stop at the next
//! frame and the workers put the jobs back in the queue without counting
//! the attempt. An attempt whose runner ignores the flag is released
//! directly after a further few seconds (its late writes are fenced).

use std::collections::HashMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::watch;
use tokio::task::JoinSet;
use treemorph_api::ErrorCode;
use treemorph_api::jobs::{JobRequest, JobStatus};
use treemorph_tree::Limits;

use super::queue::{self, Claim, End, JobRow, Lease, StoredResult};
use super::sink::{BlobSink, Flags};
use super::{Services, backoff_ms};
use crate::pipeline::{InputTree, JobError, JobInput, JobOutcome, JobSpec, StoredPlan};
use crate::store::now_ms;

/// In-flight attempts of this process: job id → (token, flags).
type InFlight = Arc<Mutex<HashMap<String, (String, Arc<Flags>)>>>;

/// The running worker pool of a process.
#[derive(Debug)]
pub struct Pool {
    stop: watch::Sender<bool>,
    workers: JoinSet<()>,
    background: JoinSet<()>,
    in_flight: InFlight,
    db: crate::store::Db,
}

impl Pool {
    /// Starts `services.settings.worker_count()` workers, the lease
    /// reclaimer (which first runs at once, so jobs of a crashed process
    /// resume) and the webhook deliverer.
    pub fn start(services: Services) -> Pool {
        if services.settings.worker_count() > 0 && !super::priority::lower_rayon_pool() {
            tracing::debug!("the rayon pool existed already; its threads keep their priority");
        }
        let (stop, stop_rx) = watch::channel(false);
        let in_flight: InFlight = Arc::default();
        let mut workers = JoinSet::new();
        let host = std::env::var("HOSTNAME").unwrap_or_else(|_| "local".into());
        for n in 0..services.settings.worker_count() {
            let name = format!("{host}-{}-{n}", std::process::id());
            workers.spawn(worker_loop(
                services.clone(),
                name,
                stop_rx.clone(),
                in_flight.clone(),
            ));
        }
        let mut background = JoinSet::new();
        background.spawn(reclaim_loop(services.clone()));
        background.spawn(super::webhooks::deliver_loop(services.clone()));
        Pool {
            stop,
            workers,
            background,
            in_flight,
            db: services.db.clone(),
        }
    }

    /// Stops claiming, waits up to `grace` for in-flight jobs, then releases
    /// what is still running back to the queue.
    pub async fn shutdown(mut self, grace: Duration) {
        let _ = self.stop.send(true);
        let n = self.in_flight.lock().expect("in-flight lock").len();
        tracing::info!(
            in_flight = n,
            grace_secs = grace.as_secs(),
            "workers draining"
        );
        if tokio::time::timeout(grace, all_done(&mut self.workers))
            .await
            .is_err()
        {
            let jobs: Vec<String> = {
                let map = self.in_flight.lock().expect("in-flight lock");
                for (_, flags) in map.values() {
                    flags.release.store(true, Ordering::SeqCst);
                }
                map.keys().cloned().collect()
            };
            tracing::info!(?jobs, "grace period over: releasing in-flight jobs");
            if tokio::time::timeout(Duration::from_secs(5), all_done(&mut self.workers))
                .await
                .is_err()
            {
                let left: Vec<(String, String)> = self
                    .in_flight
                    .lock()
                    .expect("in-flight lock")
                    .iter()
                    .map(|(id, (token, _))| (id.clone(), token.clone()))
                    .collect();
                for (id, token) in left {
                    match queue::release(&self.db, &id, &token).await {
                        Ok(_) => {
                            tracing::warn!(job = %id, "released a job whose runner ignored the stop flag")
                        }
                        Err(e) => {
                            tracing::error!(job = %id, error = %e, "could not release a job; its lease will expire")
                        }
                    }
                }
                self.workers.abort_all();
            }
        }
        self.background.abort_all();
        while self.background.join_next().await.is_some() {}
    }
}

async fn all_done(workers: &mut JoinSet<()>) {
    while workers.join_next().await.is_some() {}
}

async fn reclaim_loop(services: Services) {
    let every = (services.settings.lease() / 2).max(Duration::from_millis(500));
    loop {
        match queue::reclaim_expired(&services.db, services.settings.max_attempts).await {
            Ok(0) => {}
            Ok(n) => {
                tracing::info!(jobs = n, "reclaimed expired leases");
                services.hub.work.notify_one();
            }
            Err(e) => tracing::warn!(error = %e, "reclaiming expired leases failed"),
        }
        tokio::time::sleep(every).await;
    }
}

async fn worker_loop(
    services: Services,
    name: String,
    mut stop: watch::Receiver<bool>,
    in_flight: InFlight,
) {
    let lease_ms = services.settings.lease().as_millis() as i64;
    loop {
        if *stop.borrow() {
            break;
        }
        match queue::claim(&services.db, &name, lease_ms).await {
            Ok(Some(claim)) => run_attempt(&services, claim, &in_flight).await,
            Ok(None) => {
                tokio::select! {
                    _ = services.hub.work.notified() => {}
                    _ = tokio::time::sleep(services.settings.poll()) => {}
                    _ = stop.changed() => {}
                }
            }
            Err(e) => {
                tracing::warn!(worker = %name, error = %e, "claiming a job failed");
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
        }
    }
}

/// What running an attempt produced.
enum Ran {
    Finished(Result<JobOutcome, JobError>, Box<BlobSink>),
    Panicked(String),
    /// Could not start (trees missing or unreadable).
    NotStarted(JobError),
}

async fn run_attempt(services: &Services, claim: Claim, in_flight: &InFlight) {
    let Claim { row, token } = claim;
    let id = row.id.clone();
    tracing::info!(job = %id, attempt = row.attempt, kind = row.kind.as_str(), "job claimed");
    let flags = Arc::new(Flags::default());
    in_flight
        .lock()
        .expect("in-flight lock")
        .insert(id.clone(), (token.clone(), flags.clone()));
    services.hub.register(&id, flags.cancel.clone());
    services.hub.changed(&id);
    services.metrics.jobs_in_flight.inc();
    let started = Instant::now();

    let watcher = tokio::spawn(watch_lease(
        services.clone(),
        id.clone(),
        token.clone(),
        flags.clone(),
    ));
    let cleanup = {
        let (blobs, id, token) = (services.blobs.clone(), id.clone(), token.clone());
        tokio::spawn(async move { delete_superseded(&blobs, &id, &token).await })
    };

    let ran = execute(services, &row, &token, flags.clone()).await;
    watcher.abort();
    let _ = cleanup.await;
    services.hub.unregister(&id);
    let outcome = settle(services, &row, &token, &flags, ran).await;
    in_flight.lock().expect("in-flight lock").remove(&id);
    services.metrics.jobs_in_flight.dec();
    services
        .metrics
        .observe_job(row.kind.as_str(), outcome, started.elapsed());
    services.hub.changed(&id);
}

/// Deletes the outputs of earlier attempts of a job (never served: the row
/// names this attempt now).
async fn delete_superseded(blobs: &crate::store::Blobs, id: &str, token: &str) {
    match blobs.children(&format!("jobs/{id}")).await {
        Ok(tokens) => {
            for old in tokens.iter().filter(|t| *t != token) {
                if let Err(e) = blobs.delete_prefix(&queue::attempt_prefix(id, old)).await {
                    tracing::warn!(job = %id, error = %e, "could not delete a superseded attempt's outputs");
                }
            }
        }
        Err(e) => tracing::warn!(job = %id, error = %e, "could not list earlier attempts"),
    }
}

/// Records what the ended attempt's outputs take in the blob store, for
/// the per-key quota; a failure only leaves the job counted as 0 bytes.
/// Deletes a succeeded job's per-frame stream records: they served live
/// viewers while the job ran, and `stream.tmd` holds the same bytes whole
/// (live viewers switch to it at the success: `crate::server::stream`);
/// storing both would double the largest output a job keeps. A job that
/// asked for no stream has empty records, which serve nobody.
async fn drop_stream_records(services: &Services, row: &JobRow, token: &str) {
    if row.status != JobStatus::Succeeded {
        return;
    }
    let records = queue::stream_records_prefix(&queue::attempt_prefix(&row.id, token));
    if let Err(e) = services.blobs.delete_prefix(&records).await {
        tracing::warn!(job = %row.id, error = %e, "could not delete the stream records");
    }
}

async fn record_usage(services: &Services, id: &str, token: &str) {
    let prefix = queue::attempt_prefix(id, token);
    let recorded = match services.blobs.usage(&prefix).await {
        Ok((_, bytes)) => queue::record_stored_bytes(&services.db, id, bytes)
            .await
            .map_err(anyhow::Error::from),
        Err(e) => Err(e.into()),
    };
    if let Err(e) = recorded {
        tracing::warn!(job = %id, error = %e, "could not record the job's stored bytes");
    }
}

async fn watch_lease(services: Services, id: String, token: String, flags: Arc<Flags>) {
    let lease = services.settings.lease();
    let lease_ms = lease.as_millis() as i64;
    let renew_every = lease / 3;
    let mut last_renew = Instant::now();
    loop {
        tokio::time::sleep(services.settings.poll().min(renew_every)).await;
        let state = if last_renew.elapsed() >= renew_every {
            last_renew = Instant::now();
            queue::renew(&services.db, &id, &token, lease_ms).await
        } else {
            queue::peek(&services.db, &id, &token).await
        };
        match state {
            Ok(Lease::Held { cancel_requested }) => {
                if cancel_requested {
                    flags.cancel.store(true, Ordering::SeqCst);
                }
            }
            Ok(Lease::Lost) => {
                tracing::warn!(job = %id, "lease lost; this attempt stops");
                flags.lost.store(true, Ordering::SeqCst);
                return;
            }
            Err(e) => tracing::warn!(job = %id, error = %e, "lease heartbeat failed"),
        }
    }
}

/// A job's input trees, from the tree cache or the blob store.
pub(crate) async fn load_trees(
    services: &Services,
    spec: &JobSpec,
) -> Result<HashMap<String, Arc<InputTree>>, JobError> {
    let mut ids = spec.tree_ids();
    ids.dedup();
    // The trees of a morph are read and parsed side by side.
    let loaded = futures_util::future::join_all(ids.iter().map(|id| load_tree(services, id))).await;
    ids.iter()
        .zip(loaded)
        .map(|(id, tree)| Ok(((*id).to_owned(), tree?)))
        .collect()
}

/// One input tree: from the tree cache, or read from the blob store,
/// parsed and cached (the runner then analyses it in place, so the next
/// job on it finds the analysis too).
pub(crate) async fn load_tree(services: &Services, id: &str) -> Result<Arc<InputTree>, JobError> {
    if let Some(cached) = services.trees.get(id) {
        services.metrics.observe_tree_cache(true);
        return Ok(cached);
    }
    services.metrics.observe_tree_cache(false);
    let key = format!("{}/tree.json", crate::store::trees::blob_prefix(id));
    let bytes = match services.blobs.get(&key).await {
        Ok(Some(b)) => b,
        Ok(None) => {
            return Err(JobError {
                code: ErrorCode::TreeNotFound,
                message: format!("tree {id} no longer exists"),
                retryable: false,
            });
        }
        Err(e) => {
            tracing::warn!(tree = %id, error = %e, "loading a tree failed");
            return Err(JobError {
                code: ErrorCode::Unavailable,
                message: "the blob store is unavailable".into(),
                retryable: true,
            });
        }
    };
    let json_bytes = bytes.len() as u64;
    let tree = tokio::task::spawn_blocking(move || {
        treemorph_tree::json::from_slice(&bytes, &Limits::default())
    })
    .await
    .map_err(|e| JobError {
        code: ErrorCode::Internal,
        message: format!("loading the tree failed: {e}"),
        retryable: false,
    })?
    .map_err(|e| JobError {
        code: ErrorCode::Internal,
        message: format!("stored tree {id} is unreadable: {e}"),
        retryable: false,
    })?;
    let tree = Arc::new(InputTree::new(tree));
    services.trees.insert(id, tree.clone(), json_bytes);
    Ok(tree)
}

/// The stored request of a claimed job, converted once into the spec the
/// run uses.
///
/// The frame cap is an admission rule of the process that accepted the
/// job: a worker started with a lower `--max-frames` still runs what was
/// accepted, so it checks everything but that cap.
/// The spec of a stored job, converted again from its stored request.
pub(crate) fn claimed_spec(services: &Services, row: &JobRow) -> Result<JobSpec, JobError> {
    let request: JobRequest = serde_json::from_str(&row.request)
        .map_err(|e| JobError::internal(format_args!("stored request is unreadable: {e}")))?;
    services.runner.check(
        &request,
        &crate::pipeline::Limits::default().with_max_frames(u32::MAX),
    )
}

async fn execute(services: &Services, row: &JobRow, token: &str, flags: Arc<Flags>) -> Ran {
    let spec = match claimed_spec(services, row) {
        Ok(spec) => spec,
        Err(e) => return Ran::NotStarted(e),
    };
    let trees = match load_trees(services, &spec).await {
        Ok(t) => t,
        Err(e) => return Ran::NotStarted(e),
    };
    let mut sink = Box::new(BlobSink::new(
        tokio::runtime::Handle::current(),
        services.db.clone(),
        services.blobs.clone(),
        services.hub.clone(),
        services.metrics.clone(),
        row.kind.as_str(),
        &row.id,
        row.attempt,
        token,
        flags,
    ));
    let runner = services.runner.clone();
    let requested = *spec.outputs();
    let plan_first = runner.renders_on_request();
    let spec = if plan_first { spec.stored_part() } else { spec };
    // A thread of its own at job priority (see `super::priority`), not the
    // runtime's blocking pool, whose threads also serve file reads for
    // requests and would keep the lowered priority.
    let plan_key = queue::plan_key(&queue::attempt_prefix(&row.id, token));
    let (done, joined) = tokio::sync::oneshot::channel();
    let work = move || {
        super::priority::lower_this_thread();
        // The run's plan is kept under its attempt, where renders of the
        // job look first: there is nothing stored to load yet.
        let none = || None;
        let input = JobInput {
            spec: &spec,
            trees: &trees,
            stored_plan: Some(StoredPlan {
                key: &plan_key,
                load: &none,
            }),
        };
        let result = catch_unwind(AssertUnwindSafe(|| runner.run(&input, sink.as_mut())));
        let succeeded = matches!(result, Ok(Ok(_)));
        if plan_first && succeeded {
            sink.offer_rendered(&requested);
        }
        // Whatever the outcome, the outputs clients may already have seen
        // become durable before the attempt's end is recorded (but for a
        // success's stream records, which its end drops). A job that
        // succeeded but whose outputs cannot be synced is retried.
        let result = match (result, sink.sync_outputs(succeeded)) {
            (Ok(Ok(_)), Err(e)) => Ok(Err(JobError {
                code: ErrorCode::Unavailable,
                message: e.to_string(),
                retryable: true,
            })),
            (result, _) => result,
        };
        sink.close_stage();
        let _ = done.send((result, sink));
    };
    if let Err(e) = std::thread::Builder::new()
        .name(format!("job-{}", row.id))
        .spawn(work)
    {
        return Ran::NotStarted(JobError {
            code: ErrorCode::Unavailable,
            message: format!("could not start a job thread: {e}"),
            retryable: true,
        });
    }
    match joined.await {
        Ok((Ok(result), sink)) => Ran::Finished(result, sink),
        Ok((Err(payload), _)) => Ran::Panicked(panic_message(payload.as_ref())),
        // The thread ended without an answer: a panic outside the runner
        // (in the sink's sync or stage bookkeeping).
        Err(_) => Ran::Panicked("the job thread stopped without a result".into()),
    }
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_owned()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "non-string panic payload".into()
    }
}

/// Records the attempt's end; returns the outcome label for metrics.
async fn settle(
    services: &Services,
    row: &JobRow,
    token: &str,
    flags: &Flags,
    ran: Ran,
) -> &'static str {
    let db = &services.db;
    let id = row.id.as_str();
    if flags.lost.load(Ordering::SeqCst) {
        tracing::warn!(job = %id, attempt = row.attempt, "attempt superseded; its outcome is dropped");
        return "superseded";
    }
    let (end, label) = match ran {
        Ran::Finished(Ok(outcome), sink) => (
            End::Succeeded(StoredResult {
                frames: outcome.frames,
                metrics: outcome.metrics,
                files: sink.files().to_vec(),
                frame_glbs: sink.frame_glbs(),
                render_version: crate::pipeline::RENDER_VERSION,
            }),
            "succeeded",
        ),
        Ran::Panicked(message) => {
            tracing::error!(job = %id, panic = %message, "the runner panicked; the job fails");
            (
                End::Failed {
                    code: ErrorCode::Internal,
                    message: "the job failed unexpectedly (internal error)".into(),
                },
                "failed",
            )
        }
        Ran::Finished(Err(e), _) | Ran::NotStarted(e) => {
            if flags.cancel.load(Ordering::SeqCst) {
                (
                    End::Cancelled {
                        code: ErrorCode::Cancelled,
                        message: "cancelled by the client".into(),
                    },
                    "cancelled",
                )
            } else if flags.release.load(Ordering::SeqCst) {
                match queue::release(db, id, token).await {
                    Ok(true) => tracing::info!(job = %id, "released back to the queue"),
                    Ok(false) => tracing::warn!(job = %id, "release fenced: lease already lost"),
                    Err(e) => {
                        tracing::error!(job = %id, error = %e, "release failed; the lease will expire")
                    }
                }
                return "released";
            } else if (e.retryable || flags.storage_error.load(Ordering::SeqCst))
                && row.attempt < services.settings.max_attempts
            {
                let delay = backoff_ms(row.attempt, 500, 60_000);
                tracing::warn!(job = %id, attempt = row.attempt, delay_ms = delay, error = %e, "transient failure; retrying");
                match queue::retry_later(db, id, token, now_ms() + delay as i64, &e.message).await {
                    Ok(_) => {}
                    Err(err) => {
                        tracing::error!(job = %id, error = %err, "could not requeue; the lease will expire")
                    }
                }
                return "retried";
            } else {
                let (code, message) = (e.code, e.message);
                tracing::info!(job = %id, code = %code, "job failed");
                (End::Failed { code, message }, "failed")
            }
        }
    };
    match queue::finish(db, id, token, end).await {
        Ok(Some(row)) => {
            tracing::info!(job = %id, status = row.status.as_str(), "job ended");
            drop_stream_records(services, &row, token).await;
            record_usage(services, id, token).await;
            if row.callback_url.is_some() {
                services.hub.webhooks.notify_one();
            }
        }
        Ok(None) => tracing::warn!(job = %id, "finishing fenced: the lease was lost"),
        Err(e) => {
            tracing::error!(job = %id, error = %e, "could not record the job's end; the lease will expire and the job rerun")
        }
    }
    label
}
