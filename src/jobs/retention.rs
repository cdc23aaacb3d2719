//! Retention: deleting ended jobs (on a client's `DELETE` and after
//! `--result-ttl`) with every blob they own, and sweeping what crashes
//! leave behind.
//!
//! # Choices
//! - **Row first, blobs second.** A job's row goes in one statement that
//!   only matches an ended job ([`queue::delete_ended`]); its blobs
//!   (`jobs/{id}/…`, every attempt) go next. A crash in between leaves
//!   blobs without a row, which the orphan sweep removes; the opposite
//!   order could leave a row whose outputs are gone.
//! - **Expiry counts from the end** (`updated_at` of an ended job, which
//!   no later write touches), not from creation: a job that queued for a
//!   day still keeps its results for the whole TTL.
//! - **Trees are not expired.** They are the users' assets, deleted only
//!   on request (`DELETE /v1/trees/{id}`), which is refused while a job
//!   that still exists uses the tree: a job renders frames at new instants
//!   from its trees. Once its jobs are deleted or expired, a tree can go.
//! - **Webhook records** of deliveries that are done go with their job
//!   (or at the next sweep); a pending one stays until it is delivered or
//!   given up, so a deleted job's end is still announced.
//! - **Orphans** are blob prefixes (`jobs/{id}`, `trees/{id}`) whose row
//!   does not exist, and upload spool files. Blobs are written before
//!   the row that names them, so a prefix without a row may be an upload
//!   or job in flight: only prefixes whose newest object is older than
//!   twice the request timeout go (an upload's blobs are stored within
//!   the request timeout that bounds the work after its body; a job's
//!   row exists before its first blob). The same age rule has always
//!   applied to spool files, whose writes refresh their age while the
//!   body keeps arriving.
//! - **Every process sweeps**, at start and every `--sweep-secs`. Sweeps
//!   are idempotent, so several processes sweeping one store only repeat
//!   each other's listing.

use std::collections::HashSet;
use std::time::Duration;

use sqlx::Row;

use super::{Services, queue};
use crate::store::{Blobs, Db, now_ms, trees::blob_prefix};

/// Jobs expired per database round trip.
const EXPIRE_BATCH: u32 = 100;
/// Ids looked up per query when sweeping orphans.
const LOOKUP_BATCH: usize = 100;

/// What one sweep removed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Swept {
    /// Ended jobs past `--result-ttl`.
    pub expired_jobs: u64,
    /// Blob prefixes without a row (`jobs/{id}`, `trees/{id}`).
    pub orphan_prefixes: u64,
    /// Upload spool files.
    pub spool_files: u64,
    /// Records of done webhook deliveries whose job is gone.
    pub webhook_records: u64,
    /// Records of stored renders whose job is gone.
    pub render_records: u64,
}

/// Deletes every blob a job owns. Failures are logged: the orphan sweep
/// retries them, since the row is gone already.
pub async fn delete_job_blobs(blobs: &Blobs, id: &str) {
    if let Err(e) = blobs.delete_prefix(&queue::job_prefix(id)).await {
        tracing::warn!(job = %id, error = %e, "deleting a job's blobs failed; the orphan sweep retries");
    }
}

/// Runs [`sweep`] at start and every `--sweep-secs` until the process
/// ends.
pub async fn sweep_loop(services: Services) {
    let every = Duration::from_secs(services.settings.sweep_secs.max(1));
    loop {
        match sweep(&services).await {
            Ok(swept) if swept != Swept::default() => tracing::info!(?swept, "swept"),
            Ok(_) => {}
            Err(e) => tracing::warn!(error = %e, "sweep failed; retrying at the next one"),
        }
        tokio::time::sleep(every).await;
    }
}

/// Expires ended jobs past `--result-ttl` and removes orphans once.
pub async fn sweep(services: &Services) -> anyhow::Result<Swept> {
    let settings = &services.settings;
    let grace = orphan_grace(settings.request_timeout);
    let spool = settings.data_dir.join("tmp");
    let spool_files = tokio::task::spawn_blocking(move || sweep_spool(&spool, grace)).await?;
    let expired_jobs = match settings.result_ttl.0 {
        Some(ttl) => expire(services, now_ms() - ttl.as_millis() as i64).await?,
        None => 0,
    };
    let orphan_prefixes = sweep_orphans(&services.db, &services.blobs, grace).await?;
    let webhook_records = super::webhooks::purge_done_without_job(&services.db).await?;
    let render_records =
        crate::store::renders::RenderStore::purge_without_job(&services.db).await?;
    Ok(Swept {
        expired_jobs,
        orphan_prefixes,
        spool_files,
        webhook_records,
        render_records,
    })
}

/// How old a spool file or a row-less blob prefix must be to be an orphan
/// rather than a request in flight: twice the request timeout.
pub fn orphan_grace(request_timeout_secs: u64) -> Duration {
    Duration::from_secs(request_timeout_secs.max(1) * 2)
}

/// Deletes the ended jobs that ended before `ended_before` (ms) and their
/// blobs; returns how many went.
async fn expire(services: &Services, ended_before: i64) -> anyhow::Result<u64> {
    let mut expired = 0;
    loop {
        let ids = queue::ended_before(&services.db, ended_before, EXPIRE_BATCH).await?;
        for id in &ids {
            if queue::delete_ended(&services.db, None, id, ended_before).await? {
                delete_job_blobs(&services.blobs, id).await;
                services.hub.changed(id);
                expired += 1;
            }
        }
        if ids.len() < EXPIRE_BATCH as usize {
            return Ok(expired);
        }
    }
}

/// Removes the `jobs/{id}` and `trees/{id}` prefixes that have no row
/// and were last written more than `grace` ago.
async fn sweep_orphans(db: &Db, blobs: &Blobs, grace: Duration) -> anyhow::Result<u64> {
    let written_before = now_ms() - grace.as_millis() as i64;
    let mut removed = 0;
    for table in ["jobs", "trees"] {
        let ids = blobs.children(table).await?;
        for batch in ids.chunks(LOOKUP_BATCH) {
            let rows = existing(db, table, batch).await?;
            for id in batch.iter().filter(|id| !rows.contains(*id)) {
                let prefix = match table {
                    "jobs" => queue::job_prefix(id),
                    _ => blob_prefix(id),
                };
                if blobs
                    .last_modified(&prefix)
                    .await?
                    .is_some_and(|at| at < written_before)
                {
                    blobs.delete_prefix(&prefix).await?;
                    tracing::info!(prefix, "removed blobs without a row");
                    removed += 1;
                }
            }
        }
    }
    Ok(removed)
}

/// Which of `ids` have a row in `table` (`jobs` or `trees`).
async fn existing(db: &Db, table: &str, ids: &[String]) -> Result<HashSet<String>, sqlx::Error> {
    if ids.is_empty() {
        return Ok(HashSet::new());
    }
    let placeholders: Vec<String> = (1..=ids.len()).map(|i| format!("${i}")).collect();
    let sql = format!(
        "SELECT id FROM {table} WHERE id IN ({})",
        placeholders.join(", ")
    );
    // The table is one of our two names and the ids are bound.
    let mut query = sqlx::query(sqlx::AssertSqlSafe(sql));
    for id in ids {
        query = query.bind(id);
    }
    let rows = query.fetch_all(&db.pool).await?;
    rows.iter().map(|r| r.try_get::<String, _>("id")).collect()
}

/// Removes upload spool files under `dir` older than `max_age` (a crash,
/// kill -9, leaves them behind); returns how many went. A live upload's
/// file is younger: every write refreshes it, and a body may pause for no
/// longer than the header timeout.
pub fn sweep_spool(dir: &std::path::Path, max_age: Duration) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for entry in entries.flatten() {
        let old = entry
            .metadata()
            .and_then(|m| m.modified())
            .ok()
            .and_then(|t| t.elapsed().ok())
            .is_some_and(|age| age > max_age);
        if old && entry.file_type().is_ok_and(|t| t.is_file()) {
            removed += u64::from(std::fs::remove_file(entry.path()).is_ok());
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, SystemTime};

    /// Regression: spool files of uploads cut off by kill -9 stayed in
    /// `DATA/tmp` forever.
    #[test]
    fn stale_spool_files_go_and_fresh_ones_stay() {
        let dir = tempfile::tempdir().unwrap();
        let stale = dir.path().join(".tmpstale");
        let fresh = dir.path().join(".tmpfresh");
        std::fs::write(&stale, b"x").unwrap();
        std::fs::write(&fresh, b"x").unwrap();
        std::fs::File::options()
            .write(true)
            .open(&stale)
            .unwrap()
            .set_modified(SystemTime::now() - Duration::from_secs(3600))
            .unwrap();
        assert_eq!(super::sweep_spool(dir.path(), Duration::from_secs(60)), 1);
        assert!(!stale.exists());
        assert!(fresh.exists());
    }
}
