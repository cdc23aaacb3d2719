//! Jobs: the durable queue ([`queue`], its claim benchmark in [`bench`]),
//! the worker pool ([`worker`]), the sink through which a running pipeline
//! publishes outputs ([`sink`]) and webhook delivery ([`webhooks`]).
//!
//! # How a job runs
//! 1. `POST /v1/jobs` validates the request (trees exist, frame count,
//!    callback URL, [`crate::pipeline::Runner::check`]) and inserts a
//!    `queued` row. That commit is the acknowledgement: from then on the job
//!    survives any crash.
//! 2. A worker claims it (a lease with a fresh attempt token, see
//!    [`queue`]), loads the trees it names from the blob store, and runs the
//!    [`crate::pipeline::Runner`] on a thread of its own (the pipeline's CPU
//!    work fans out on the rayon pool and never blocks the async runtime;
//!    both run at a lower CPU priority than the runtime, see [`priority`]).
//!    A panic is caught and fails the job with `internal`; the worker lives
//!    on.
//! 3. Outputs are published through the [`sink::BlobSink`]: blob first,
//!    then a fenced row update that makes it visible (publish by commit).
//! 4. The job ends with one fenced update (`succeeded`/`failed`/
//!    `cancelled`) that also schedules its webhook, or goes back to the
//!    queue: after a transient failure with exponential backoff and jitter
//!    (until `--max-attempts`), or on shutdown without counting the attempt.
//!
//! # Who hears about changes
//! Everything a client can observe is in the database, so API processes
//! that run no workers (`--role api`) see progress by polling it (every
//! `--poll-ms`). When the worker is in the same process, the [`Hub`]'s
//! broadcast channel wakes subscribers at once — a fast path, never the only
//! path. Cancellation likewise reaches a worker in another process through
//! the row (`cancel_requested`, read by the job's watcher every poll) and a
//! worker in this process directly through the [`Hub`].

pub mod bench;
pub mod priority;
pub mod queue;
pub mod retention;
pub mod sink;
pub mod testing;
pub mod tree_cache;
pub mod webhooks;
pub mod worker;

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use tokio::sync::{Notify, broadcast};

/// In-process signals between the API and the workers of one process.
#[derive(Debug)]
pub struct Hub {
    /// Woken when a job is queued (idle workers claim at once instead of at
    /// their next poll).
    pub work: Notify,
    /// Woken when a webhook delivery is scheduled.
    pub webhooks: Notify,
    /// The id of every job that changed (progress, frame, end).
    pub changes: broadcast::Sender<Arc<str>>,
    running: Mutex<HashMap<String, Arc<AtomicBool>>>,
}

impl Default for Hub {
    fn default() -> Self {
        Hub {
            work: Notify::new(),
            webhooks: Notify::new(),
            changes: broadcast::channel(1024).0,
            running: Mutex::new(HashMap::new()),
        }
    }
}

impl Hub {
    /// Announces that job `id` changed.
    pub fn changed(&self, id: &str) {
        let _ = self.changes.send(Arc::from(id));
    }

    /// Registers a job running in this process; `flag` is set when a client
    /// cancels it here.
    pub fn register(&self, id: &str, flag: Arc<AtomicBool>) {
        self.running
            .lock()
            .expect("hub lock")
            .insert(id.to_owned(), flag);
    }

    /// Forgets a job that stopped running here.
    pub fn unregister(&self, id: &str) {
        self.running.lock().expect("hub lock").remove(id);
    }

    /// Signals a cancellation to the job if it runs in this process.
    pub fn cancel(&self, id: &str) {
        if let Some(flag) = self.running.lock().expect("hub lock").get(id) {
            flag.store(true, Ordering::SeqCst);
        }
    }
}

/// Everything the workers (and the API) share.
#[derive(Clone)]
pub struct Services {
    /// Settings.
    pub settings: Arc<crate::config::Settings>,
    /// Metadata database.
    pub db: crate::store::Db,
    /// Blob store.
    pub blobs: crate::store::Blobs,
    /// In-process signals.
    pub hub: Arc<Hub>,
    /// The pipeline.
    pub runner: Arc<dyn crate::pipeline::Runner>,
    /// Parsed and analysed input trees, by id.
    pub trees: Arc<tree_cache::TreeCache>,
    /// Prometheus metrics.
    pub metrics: Arc<crate::telemetry::Metrics>,
    /// The webhook signing key (decoded `whsec_` secret).
    pub webhook_key: Arc<Vec<u8>>,
}

impl std::fmt::Debug for Services {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Services")
            .field("db", &self.db)
            .finish_non_exhaustive()
    }
}

/// Exponential backoff with full jitter: a random delay in
/// `[base·2^(n-1) / 2, base·2^(n-1)]`, capped at `cap_ms`.
pub fn backoff_ms(attempt: u32, base_ms: u64, cap_ms: u64) -> u64 {
    let exp = base_ms.saturating_mul(1u64 << attempt.saturating_sub(1).min(20));
    let top = exp.min(cap_ms).max(1);
    let low = top / 2;
    low + crate::store::random_u64() % (top - low + 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_grows_and_is_capped() {
        for attempt in 1..30 {
            let d = backoff_ms(attempt, 100, 10_000);
            let top = (100u64 << (attempt - 1).min(20)).min(10_000);
            assert!(d >= top / 2 && d <= top, "attempt {attempt}: {d}");
        }
    }

    #[test]
    fn hub_cancels_only_registered_jobs() {
        let hub = Hub::default();
        let flag = Arc::new(AtomicBool::new(false));
        hub.register("a", flag.clone());
        hub.cancel("b");
        assert!(!flag.load(Ordering::SeqCst));
        hub.cancel("a");
        assert!(flag.load(Ordering::SeqCst));
        hub.unregister("a");
    }
}
