//! Renders kept in the blob store: [`RenderStore`], the second tier of the
//! render cache (`crate::server::renders`) behind the memory one.
//!
//! # Choices
//! - **Where.** A render of a job's output is stored under the job's
//!   attempt prefix, at `jobs/{id}/{token}/renders/{rest of its key}`, so
//!   deleting or expiring the job removes its renders with every other
//!   blob it owns, on local files and S3 alike, and every API process of a
//!   fleet (and a restarted one) finds a render any of them made.
//! - **Cap.** `--render-store-mb` bounds the bytes of stored renders over
//!   the whole store. Each stored render has a row in the `renders` table
//!   (key, job, bytes, last use); after a store, the least recently used
//!   renders are deleted (blob first, then row) until the total fits. A
//!   served render's last use is updated, so eviction is least recently
//!   *used*, not least recently made. Rows of deleted jobs go at the next
//!   sweep ([`RenderStore::purge_without_job`]).
//! - **Best effort.** The store is a cache: a failed read renders again
//!   and a failed write is logged and served from memory anyway, so a full
//!   or broken blob store never fails a request that can be rendered.
//! - **Crashes.** The blob is written before its row, and read back only
//!   whole (a put is atomic on both stores), so a kill -9 mid-render leaves
//!   nothing, and one between the put and the row leaves a blob that the
//!   job's deletion removes with the rest.

use bytes::Bytes;

use super::{Blobs, Db, now_ms};

/// The blob-store tier of the render cache.
#[derive(Clone, Debug)]
pub struct RenderStore {
    blobs: Blobs,
    db: Db,
    cap: u64,
}

/// The blob key a render of `key` is stored under, and its job; `None`
/// for keys outside a job's attempt prefix (`jobs/{id}/{token}/…`), which
/// are not stored.
pub fn stored_key(key: &str) -> Option<(String, &str)> {
    let mut parts = key.splitn(4, '/');
    match (parts.next(), parts.next(), parts.next(), parts.next()) {
        (Some("jobs"), Some(job), Some(token), Some(rest)) if !rest.is_empty() => {
            Some((format!("jobs/{job}/{token}/renders/{rest}"), job))
        }
        _ => None,
    }
}

impl RenderStore {
    /// A store keeping up to `cap` bytes of renders (0: none).
    pub fn new(blobs: Blobs, db: Db, cap: u64) -> RenderStore {
        RenderStore { blobs, db, cap }
    }

    /// The stored render of `key`, if any (and marks it used).
    pub async fn load(&self, key: &str) -> Option<Bytes> {
        let (stored, _) = stored_key(key)?;
        if self.cap == 0 {
            return None;
        }
        match self.blobs.get(&stored).await {
            Ok(Some(bytes)) => {
                let touched = sqlx::query("UPDATE renders SET used_at = $1 WHERE key = $2")
                    .bind(now_ms())
                    .bind(&stored)
                    .execute(&self.db.writer)
                    .await;
                if let Err(e) = touched {
                    tracing::warn!(key = %stored, error = %e, "could not mark a stored render used");
                }
                Some(bytes)
            }
            Ok(None) => None,
            Err(e) => {
                tracing::warn!(key = %stored, error = %e, "could not read a stored render; rendering again");
                None
            }
        }
    }

    /// Stores the render of `key` and evicts the least recently used
    /// renders beyond the cap; failures are logged, never returned.
    pub async fn save(&self, key: &str, bytes: Bytes) {
        let Some((stored, job)) = stored_key(key) else {
            return;
        };
        if self.cap == 0 || bytes.len() as u64 > self.cap {
            return;
        }
        let len = bytes.len() as i64;
        if let Err(e) = self.blobs.put(&stored, bytes).await {
            tracing::warn!(key = %stored, error = %e, "could not store a render");
            return;
        }
        let recorded = sqlx::query(
            "INSERT INTO renders (key, job_id, bytes, used_at) VALUES ($1, $2, $3, $4) \
             ON CONFLICT (key) DO UPDATE SET bytes = excluded.bytes, used_at = excluded.used_at",
        )
        .bind(&stored)
        .bind(job)
        .bind(len)
        .bind(now_ms())
        .execute(&self.db.writer)
        .await;
        if let Err(e) = recorded {
            tracing::warn!(key = %stored, error = %e, "could not record a stored render");
            return;
        }
        if let Err(e) = self.evict().await {
            tracing::warn!(error = %e, "could not evict stored renders");
        }
    }

    /// Deletes the least recently used renders until the rest fit the cap;
    /// returns how many went.
    pub async fn evict(&self) -> anyhow::Result<u64> {
        let mut evicted = 0;
        loop {
            // PostgreSQL's SUM of BIGINT is NUMERIC: cast it back.
            let (total,): (i64,) =
                sqlx::query_as("SELECT CAST(COALESCE(SUM(bytes), 0) AS BIGINT) FROM renders")
                    .fetch_one(&self.db.pool)
                    .await?;
            if total as u64 <= self.cap {
                return Ok(evicted);
            }
            let oldest: Option<(String, i64)> =
                sqlx::query_as("SELECT key, bytes FROM renders ORDER BY used_at, key LIMIT 1")
                    .fetch_optional(&self.db.pool)
                    .await?;
            let Some((key, _)) = oldest else {
                return Ok(evicted);
            };
            self.blobs.delete(&key).await?;
            sqlx::query("DELETE FROM renders WHERE key = $1")
                .bind(&key)
                .execute(&self.db.writer)
                .await?;
            evicted += 1;
        }
    }

    /// Deletes the rows of renders whose job is gone (their blobs went
    /// with the job); returns how many.
    pub async fn purge_without_job(db: &Db) -> Result<u64, sqlx::Error> {
        Ok(
            sqlx::query("DELETE FROM renders WHERE job_id NOT IN (SELECT id FROM jobs)")
                .execute(&db.writer)
                .await?
                .rows_affected(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_of_a_job_are_stored_under_its_attempt() {
        assert_eq!(
            stored_key("jobs/j1/t1/frames/000003.glb"),
            Some(("jobs/j1/t1/renders/frames/000003.glb".to_owned(), "j1"))
        );
        assert_eq!(
            stored_key("jobs/j1/t1/at/3ec00000"),
            Some(("jobs/j1/t1/renders/at/3ec00000".to_owned(), "j1"))
        );
        assert_eq!(stored_key("trees/x/model.glb"), None);
        assert_eq!(stored_key("jobs/j1/t1"), None);
    }
}
