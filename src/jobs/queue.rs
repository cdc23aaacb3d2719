//! The durable job queue: the `jobs` table and every state change of a job.
//!
//! # Lease protocol
//! - **Claim.** A worker claims the oldest due `queued` job with one
//!   statement, `UPDATE jobs SET status = 'running', attempt = attempt + 1,
//!   lease_token = <fresh random token>, lease_expires_at = now + lease …
//!   WHERE id = (SELECT id … WHERE status = 'queued' AND run_after <= now
//!   ORDER BY created_at LIMIT 1 [FOR UPDATE SKIP LOCKED]) AND status =
//!   'queued' RETURNING *`. On SQLite the statement holds the database's
//!   write lock, so two workers can never claim the same row; on PostgreSQL
//!   `SKIP LOCKED` lets concurrent claimers pass over each other's rows and
//!   the repeated `status = 'queued'` makes a lost race claim nothing.
//! - **Fencing.** The token is the attempt's identity. *Every* later write
//!   of the attempt — heartbeat, progress, frame publication, completion,
//!   failure, retry, release — has `WHERE id = $1 AND lease_token = $2`, and
//!   a write that matches no row tells the worker it has lost the job. A
//!   worker that stalled past its lease and wakes up after another worker
//!   re-claimed the job can therefore never overwrite the newer attempt.
//! - **Heartbeat.** The running worker renews `lease_expires_at` every
//!   third of the lease; the same round trip reads `cancel_requested`.
//! - **Reclaim.** Any worker process (at start and then periodically)
//!   returns `running` jobs whose lease expired to `queued` — or, when their
//!   attempts are used up, fails them, so a job that kills its worker every
//!   time cannot loop forever. A crash therefore loses no job.
//! - **Release.** On shutdown a job that could not finish in the grace
//!   period goes back to `queued` with its attempt *not* counted
//!   (`attempt - 1`), since the job did nothing wrong.
//!
//! # Publish by commit
//! Outputs are blobs under `jobs/{id}/{lease_token}/…`, written *before*
//! the row change that makes them visible: `header_ready` and the
//! `frames_ready` counter (both fenced by the token) for streamed frames,
//! `status = 'succeeded'` with the result for the whole-sequence files. The
//! claim sets `published_token` to the new attempt's token and resets the
//! counters, so readers only ever look under the attempt the row names, and
//! only at what it says is complete; a superseded attempt's blobs are never
//! served and are deleted by the next attempt.

use serde::{Deserialize, Serialize};
use sqlx::any::AnyRow;
use sqlx::{Any, Row, Transaction};
use treemorph_api::ErrorCode;
use treemorph_api::jobs::{JobErrorInfo, JobInfo, JobKind, JobLinks, JobResult, JobStatus};

use crate::store::{Backend, Db, now_ms, rfc3339};

/// A row of the `jobs` table.
#[derive(Clone, Debug, PartialEq)]
pub struct JobRow {
    /// Id.
    pub id: String,
    /// Owner (API key fingerprint).
    pub owner: String,
    /// Kind.
    pub kind: JobKind,
    /// The request as JSON.
    pub request: String,
    /// Frames requested.
    pub frames: u32,
    /// Status.
    pub status: JobStatus,
    /// Current stage.
    pub stage: Option<String>,
    /// Progress in [0, 1].
    pub progress: f64,
    /// Attempts started.
    pub attempt: u32,
    /// The current attempt's token while running.
    pub lease_token: Option<String>,
    /// Whether a cancellation is pending.
    pub cancel_requested: bool,
    /// The attempt whose outputs are served.
    pub published_token: Option<String>,
    /// Whether the delta stream's header is published.
    pub header_ready: bool,
    /// Frames published.
    pub frames_ready: u32,
    /// The stored result (succeeded jobs).
    pub result: Option<StoredResult>,
    /// Error code (failed and cancelled jobs).
    pub error_code: Option<String>,
    /// Error message.
    pub error_message: Option<String>,
    /// Hash of the request (idempotency).
    pub request_hash: String,
    /// Webhook URL.
    pub callback_url: Option<String>,
    /// Created, ms.
    pub created_at: i64,
    /// Last change, ms.
    pub updated_at: i64,
}

/// What a succeeded job stores in its `result` column.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StoredResult {
    /// Frames produced.
    pub frames: u32,
    /// The pipeline's metrics.
    pub metrics: serde_json::Value,
    /// Whole-sequence files published.
    pub files: Vec<String>,
    /// Whether per-frame GLBs were published (or are offered, rendered
    /// on request).
    pub frame_glbs: bool,
    /// The [`crate::pipeline::RENDER_VERSION`] of the process that ran the
    /// job (1 for jobs stored before versions were recorded).
    #[serde(default = "first_render_version")]
    pub render_version: u32,
}

fn first_render_version() -> u32 {
    1
}

fn decode_err(e: impl std::fmt::Display) -> sqlx::Error {
    sqlx::Error::Decode(e.to_string().into())
}

/// Progress as clients read it (the job document and SSE): clamped to
/// [0, 1] and rounded to 4 decimals, because it is stored as a float the
/// runner computed in `f32`, and `0.07999999821186066` helps nobody.
pub fn rounded_progress(stored: f64) -> f64 {
    (stored.clamp(0.0, 1.0) * 1e4).round() / 1e4
}

impl JobRow {
    fn from_row(row: &AnyRow) -> Result<JobRow, sqlx::Error> {
        let kind: String = row.try_get("kind")?;
        let status: String = row.try_get("status")?;
        let result: Option<String> = row.try_get("result")?;
        Ok(JobRow {
            id: row.try_get("id")?,
            owner: row.try_get("owner")?,
            kind: match kind.as_str() {
                "morph" => JobKind::Morph,
                "sketch" => JobKind::Sketch,
                other => return Err(decode_err(format!("unknown job kind {other}"))),
            },
            request: row.try_get("request")?,
            frames: row.try_get::<i64, _>("frames")? as u32,
            status: JobStatus::parse(&status)
                .ok_or_else(|| decode_err(format!("unknown job status {status}")))?,
            stage: row.try_get("stage")?,
            progress: rounded_progress(row.try_get("progress")?),
            attempt: row.try_get::<i64, _>("attempt")? as u32,
            lease_token: row.try_get("lease_token")?,
            cancel_requested: row.try_get::<i64, _>("cancel_requested")? != 0,
            published_token: row.try_get("published_token")?,
            header_ready: row.try_get::<i64, _>("header_ready")? != 0,
            frames_ready: row.try_get::<i64, _>("frames_ready")? as u32,
            result: result
                .map(|r| serde_json::from_str(&r).map_err(decode_err))
                .transpose()?,
            error_code: row.try_get("error_code")?,
            error_message: row.try_get("error_message")?,
            request_hash: row.try_get("request_hash")?,
            callback_url: row.try_get("callback_url")?,
            created_at: row.try_get("created_at")?,
            updated_at: row.try_get("updated_at")?,
        })
    }

    /// The wire document.
    pub fn info(&self) -> JobInfo {
        let id = &self.id;
        JobInfo {
            id: id.clone(),
            kind: self.kind,
            status: self.status,
            progress: self.progress as f32,
            stage: self.stage.clone(),
            attempt: self.attempt,
            frames: self.frames,
            frames_ready: self.frames_ready,
            cancel_requested: self.cancel_requested && !self.status.is_terminal(),
            created_at: rfc3339(self.created_at),
            updated_at: rfc3339(self.updated_at),
            error: self.error_code.as_ref().map(|code| JobErrorInfo {
                code: ErrorCode::parse(code).unwrap_or(ErrorCode::Internal),
                message: self.error_message.clone().unwrap_or_default(),
            }),
            result: match (&self.result, self.status) {
                (Some(r), JobStatus::Succeeded) => Some(JobResult {
                    frames: r.frames,
                    metrics: r.metrics.clone(),
                    links: JobLinks {
                        animation: r
                            .files
                            .iter()
                            .any(|f| f == "animation.glb")
                            .then(|| format!("/v1/jobs/{id}/animation.glb")),
                        stream: r
                            .files
                            .iter()
                            .any(|f| f == "stream.tmd")
                            .then(|| format!("/v1/jobs/{id}/stream")),
                        metrics: format!("/v1/jobs/{id}/metrics.json"),
                        frames: r
                            .frame_glbs
                            .then(|| format!("/v1/jobs/{id}/frames/{{n}}.glb")),
                        frame_at: Some(format!("/v1/jobs/{id}/frame.glb?t={{t}}")),
                        stream_at: Some(format!("/v1/jobs/{id}/stream?t={{t}}")),
                    },
                }),
                _ => None,
            },
        }
    }

    /// The outputs the job's request asked for (all, as the default, if
    /// the stored request cannot be read).
    pub fn requested_outputs(&self) -> treemorph_api::jobs::Outputs {
        serde_json::from_str::<treemorph_api::jobs::JobRequest>(&self.request)
            .map(|r| *r.outputs())
            .unwrap_or_default()
    }

    /// The blob prefix of the published attempt's outputs.
    pub fn published_prefix(&self) -> Option<String> {
        self.published_token
            .as_ref()
            .map(|t| attempt_prefix(&self.id, t))
    }
}

/// The blob prefix of everything a job owns: every attempt's outputs.
pub fn job_prefix(job: &str) -> String {
    format!("jobs/{job}")
}

/// The blob prefix of one attempt's outputs.
pub fn attempt_prefix(job: &str, token: &str) -> String {
    format!("jobs/{job}/{token}")
}

/// Blob key of frame `n`'s GLB under an attempt prefix.
pub fn frame_glb_key(prefix: &str, n: u32) -> String {
    format!("{prefix}/frames/{n:06}.glb")
}

/// The blob prefix of an attempt's stream records (its header and frame
/// records, [`header_key`] and [`frame_delta_key`]): they serve live
/// viewers while the job runs, and a succeeded job drops them.
pub fn stream_records_prefix(prefix: &str) -> String {
    format!("{prefix}/stream")
}

/// Blob key of frame `n`'s delta record under an attempt prefix.
pub fn frame_delta_key(prefix: &str, n: u32) -> String {
    format!("{}/{n:06}.rec", stream_records_prefix(prefix))
}

/// Blob key of the delta stream header under an attempt prefix.
pub fn header_key(prefix: &str) -> String {
    format!("{}/header.rec", stream_records_prefix(prefix))
}

/// Blob key of the job's stored plan under an attempt prefix
/// ([`crate::pipeline::JobSink::plan`]): not an output clients download,
/// but it lives and dies with them.
pub fn plan_key(prefix: &str) -> String {
    format!("{prefix}/plan.bin")
}

/// Blob key of a whole-sequence file under an attempt prefix.
pub fn file_key(prefix: &str, name: &str) -> String {
    format!("{prefix}/files/{name}")
}

/// A job to insert.
#[derive(Clone, Debug)]
pub struct NewJob {
    /// Id.
    pub id: String,
    /// Owner.
    pub owner: String,
    /// Kind.
    pub kind: JobKind,
    /// Request JSON.
    pub request: String,
    /// First tree.
    pub tree_a: String,
    /// Second tree (morph target).
    pub tree_b: Option<String>,
    /// Frames requested.
    pub frames: u32,
    /// Idempotency key.
    pub idempotency_key: Option<String>,
    /// Hash of the request.
    pub request_hash: String,
    /// Webhook URL.
    pub callback_url: Option<String>,
}

/// What [`create`] did.
#[derive(Debug)]
pub enum Created {
    /// A new job.
    New(JobRow),
    /// The job an earlier request with the same idempotency key created.
    Existing(JobRow),
    /// The idempotency key was used with a different request.
    KeyReused,
}

/// Inserts a job, honouring its idempotency key: concurrent requests with
/// the same key race on the unique index `(owner, idempotency_key)`; the
/// loser's insert does nothing and it returns the winner's job.
pub async fn create(db: &Db, job: &NewJob) -> Result<Created, sqlx::Error> {
    let now = now_ms();
    let row = sqlx::query(
        "INSERT INTO jobs (id, owner, kind, request, tree_a, tree_b, frames, status, run_after, \
           request_hash, idempotency_key, callback_url, created_at, updated_at) \
         VALUES ($1, $2, $3, $4, $5, $6, $7, 'queued', $8, $9, $10, $11, $8, $8) \
         ON CONFLICT DO NOTHING RETURNING *",
    )
    .bind(&job.id)
    .bind(&job.owner)
    .bind(job.kind.as_str())
    .bind(&job.request)
    .bind(&job.tree_a)
    .bind(&job.tree_b)
    .bind(i64::from(job.frames))
    .bind(now)
    .bind(&job.request_hash)
    .bind(&job.idempotency_key)
    .bind(&job.callback_url)
    .fetch_optional(&db.writer)
    .await?;
    if let Some(row) = row {
        return Ok(Created::New(JobRow::from_row(&row)?));
    }
    let Some(key) = &job.idempotency_key else {
        return Err(sqlx::Error::Protocol(
            "job insert conflicted without a key".into(),
        ));
    };
    replay(db, &job.owner, Some(key), &job.request_hash)
        .await?
        .ok_or_else(|| sqlx::Error::Protocol("job insert conflicted on a missing key".into()))
}

/// What a request with idempotency key `key` and request hash `hash` gets
/// from a job the key already created: that job when the request is the
/// same, [`Created::KeyReused`] when it differs; `None` when the key
/// created no job (or there is no key). The one place the idempotency
/// decision is made: `POST /v1/jobs` asks before queueing (so a retry
/// succeeds even when the queue has filled up since), and [`create`] when
/// a concurrent request won the insert.
pub async fn replay(
    db: &Db,
    owner: &str,
    key: Option<&str>,
    hash: &str,
) -> Result<Option<Created>, sqlx::Error> {
    let Some(key) = key else { return Ok(None) };
    let existing = sqlx::query("SELECT * FROM jobs WHERE owner = $1 AND idempotency_key = $2")
        .bind(owner)
        .bind(key)
        .fetch_optional(&db.pool)
        .await?
        .map(|r| JobRow::from_row(&r))
        .transpose()?;
    Ok(existing.map(|existing| {
        if existing.request_hash == hash {
            Created::Existing(existing)
        } else {
            Created::KeyReused
        }
    }))
}

/// The job `id` of `owner`.
pub async fn get(db: &Db, owner: &str, id: &str) -> Result<Option<JobRow>, sqlx::Error> {
    sqlx::query("SELECT * FROM jobs WHERE id = $1 AND owner = $2")
        .bind(id)
        .bind(owner)
        .fetch_optional(&db.pool)
        .await?
        .map(|r| JobRow::from_row(&r))
        .transpose()
}

/// The job `id`, whoever owns it (workers).
pub async fn get_any(db: &Db, id: &str) -> Result<Option<JobRow>, sqlx::Error> {
    sqlx::query("SELECT * FROM jobs WHERE id = $1")
        .bind(id)
        .fetch_optional(&db.pool)
        .await?
        .map(|r| JobRow::from_row(&r))
        .transpose()
}

/// A page of `owner`'s jobs, newest first (`limit + 1` rows, see
/// [`Db::list_trees`]).
pub async fn list(
    db: &Db,
    owner: &str,
    status: Option<JobStatus>,
    after: Option<(i64, String)>,
    limit: u32,
) -> Result<Vec<JobRow>, sqlx::Error> {
    let mut sql = String::from("SELECT * FROM jobs WHERE owner = $1");
    let mut n = 1;
    if status.is_some() {
        n += 1;
        sql.push_str(&format!(" AND status = ${n}"));
    }
    if after.is_some() {
        sql.push_str(&format!(
            " AND (created_at < ${a} OR (created_at = ${a} AND id < ${b}))",
            a = n + 1,
            b = n + 2
        ));
        n += 2;
    }
    sql.push_str(&format!(
        " ORDER BY created_at DESC, id DESC LIMIT ${}",
        n + 1
    ));
    let mut q = sqlx::query(sqlx::AssertSqlSafe(sql)).bind(owner);
    if let Some(s) = status {
        q = q.bind(s.as_str());
    }
    if let Some((at, id)) = after {
        q = q.bind(at).bind(id);
    }
    let rows = q.bind(i64::from(limit) + 1).fetch_all(&db.pool).await?;
    rows.iter().map(JobRow::from_row).collect()
}

/// Jobs waiting in the queue (all owners).
pub async fn queued_count(db: &Db) -> Result<i64, sqlx::Error> {
    let (n,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM jobs WHERE status = 'queued'")
        .fetch_one(&db.pool)
        .await?;
    Ok(n)
}

/// Job counts by status (all owners), for `/metrics`.
pub async fn counts_by_status(db: &Db) -> Result<Vec<(String, i64)>, sqlx::Error> {
    sqlx::query_as("SELECT status, COUNT(*) FROM jobs GROUP BY status")
        .fetch_all(&db.pool)
        .await
}

/// A claimed job: the row as of the claim and the attempt's token.
#[derive(Clone, Debug)]
pub struct Claim {
    /// The row (status `running`, `attempt` incremented).
    pub row: JobRow,
    /// The attempt token that fences every later write.
    pub token: String,
}

/// Claims the oldest due queued job, if any.
pub async fn claim(db: &Db, worker: &str, lease_ms: i64) -> Result<Option<Claim>, sqlx::Error> {
    let now = now_ms();
    // A plain read first: idle workers poll often, and on SQLite even an
    // UPDATE that matches nothing takes the database's write lock.
    let due: Option<(String,)> =
        sqlx::query_as("SELECT id FROM jobs WHERE status = 'queued' AND run_after <= $1 LIMIT 1")
            .bind(now)
            .fetch_optional(&db.pool)
            .await?;
    if due.is_none() {
        return Ok(None);
    }
    let token = crate::store::new_token();
    let lock = match db.backend {
        Backend::Postgres => " FOR UPDATE SKIP LOCKED",
        Backend::Sqlite => "",
    };
    let sql = format!(
        "UPDATE jobs SET status = 'running', attempt = attempt + 1, lease_token = $1, \
           lease_expires_at = $2, worker = $3, updated_at = $4, published_token = $1, \
           header_ready = 0, frames_ready = 0, stage = 'loading', progress = 0 \
         WHERE id = (SELECT id FROM jobs WHERE status = 'queued' AND run_after <= $4 \
                     ORDER BY created_at, id LIMIT 1{lock}) \
           AND status = 'queued' RETURNING *"
    );
    let row = sqlx::query(sqlx::AssertSqlSafe(sql))
        .bind(&token)
        .bind(now + lease_ms)
        .bind(worker)
        .bind(now)
        .fetch_optional(&db.writer)
        .await?;
    Ok(row
        .map(|r| JobRow::from_row(&r))
        .transpose()?
        .map(|row| Claim { row, token }))
}

/// The lease as a heartbeat found it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lease {
    /// Still ours; whether a cancellation was requested.
    Held {
        /// A client asked to cancel.
        cancel_requested: bool,
    },
    /// Another attempt (or a reclaim, or a cancel) took the job.
    Lost,
}

/// Renews the lease (fenced) and reads the cancellation flag.
pub async fn renew(db: &Db, id: &str, token: &str, lease_ms: i64) -> Result<Lease, sqlx::Error> {
    let row: Option<(i64,)> = sqlx::query_as(
        "UPDATE jobs SET lease_expires_at = $3 WHERE id = $1 AND lease_token = $2 AND status = 'running' \
         RETURNING cancel_requested",
    )
    .bind(id)
    .bind(token)
    .bind(now_ms() + lease_ms)
    .fetch_optional(&db.writer)
    .await?;
    Ok(match row {
        Some((c,)) => Lease::Held {
            cancel_requested: c != 0,
        },
        None => Lease::Lost,
    })
}

/// Reads the lease without renewing it (the cancellation watcher).
pub async fn peek(db: &Db, id: &str, token: &str) -> Result<Lease, sqlx::Error> {
    let row: Option<(i64,)> = sqlx::query_as(
        "SELECT cancel_requested FROM jobs WHERE id = $1 AND lease_token = $2 AND status = 'running'",
    )
    .bind(id)
    .bind(token)
    .fetch_optional(&db.pool)
    .await?;
    Ok(match row {
        Some((c,)) => Lease::Held {
            cancel_requested: c != 0,
        },
        None => Lease::Lost,
    })
}

type Query = sqlx::query::Query<'static, Any, sqlx::any::AnyArguments>;

/// Runs a fenced single-row update; false when it matched nothing (the
/// lease is lost).
async fn fenced(db: &Db, q: Query) -> Result<bool, sqlx::Error> {
    Ok(q.execute(&db.writer).await?.rows_affected() == 1)
}

/// Records the stage and progress (fenced); false when the lease is lost.
pub async fn set_progress(
    db: &Db,
    id: &str,
    token: &str,
    stage: &str,
    progress: f64,
) -> Result<bool, sqlx::Error> {
    let q = sqlx::query(
        "UPDATE jobs SET stage = $3, progress = $4, updated_at = $5 \
         WHERE id = $1 AND lease_token = $2 AND status = 'running'",
    );
    fenced(
        db,
        q.bind(id)
            .bind(token)
            .bind(stage)
            .bind(progress)
            .bind(now_ms()),
    )
    .await
}

/// Publishes the delta stream header (fenced).
pub async fn publish_header(db: &Db, id: &str, token: &str) -> Result<bool, sqlx::Error> {
    let q = sqlx::query(
        "UPDATE jobs SET header_ready = 1 WHERE id = $1 AND lease_token = $2 AND status = 'running'",
    );
    fenced(db, q.bind(id).bind(token)).await
}

/// Publishes frames `0..frames_ready` (fenced).
pub async fn publish_frames(
    db: &Db,
    id: &str,
    token: &str,
    frames_ready: u32,
    progress: f64,
) -> Result<bool, sqlx::Error> {
    let q = sqlx::query(
        "UPDATE jobs SET frames_ready = $3, progress = $4, stage = 'frames', updated_at = $5 \
         WHERE id = $1 AND lease_token = $2 AND status = 'running'",
    );
    let q = q.bind(id).bind(token).bind(i64::from(frames_ready));
    fenced(db, q.bind(progress).bind(now_ms())).await
}

/// Ends a job: `succeeded` with its result, `failed` or `cancelled` with an
/// error — fenced, and in the same transaction as the webhook delivery it
/// schedules. Returns the final row, or `None` when the lease was lost.
pub async fn finish(
    db: &Db,
    id: &str,
    token: &str,
    end: End,
) -> Result<Option<JobRow>, sqlx::Error> {
    let now = now_ms();
    let mut tx = db.writer.begin().await?;
    let row =
        match &end {
            End::Succeeded(result) => sqlx::query(
                "UPDATE jobs SET status = 'succeeded', result = $3, progress = 1, stage = NULL, \
                   frames_ready = $4, lease_token = NULL, lease_expires_at = NULL, updated_at = $5 \
                 WHERE id = $1 AND lease_token = $2 AND status = 'running' RETURNING *",
            )
            .bind(id)
            .bind(token)
            .bind(serde_json::to_string(result).expect("result serialises"))
            .bind(i64::from(result.frames))
            .bind(now)
            .fetch_optional(&mut *tx)
            .await?,
            End::Failed { code, message } | End::Cancelled { code, message } => {
                let status = if matches!(end, End::Failed { .. }) {
                    "failed"
                } else {
                    "cancelled"
                };
                sqlx::query(
                "UPDATE jobs SET status = $3, error_code = $4, error_message = $5, stage = NULL, \
                   lease_token = NULL, lease_expires_at = NULL, updated_at = $6 \
                 WHERE id = $1 AND lease_token = $2 AND status = 'running' RETURNING *",
            )
            .bind(id)
            .bind(token)
            .bind(status)
            .bind(code.as_str())
            .bind(message)
            .bind(now)
            .fetch_optional(&mut *tx)
            .await?
            }
        };
    let row = row.map(|r| JobRow::from_row(&r)).transpose()?;
    if let Some(row) = &row {
        super::webhooks::schedule(&mut tx, row).await?;
    }
    tx.commit().await?;
    Ok(row)
}

/// Records the bytes a job's outputs take (per-key storage quota). Leaves
/// `updated_at` alone: expiry counts from the job's end.
pub async fn record_stored_bytes(db: &Db, id: &str, bytes: u64) -> Result<(), sqlx::Error> {
    sqlx::query("UPDATE jobs SET stored_bytes = $2 WHERE id = $1")
        .bind(id)
        .bind(i64::try_from(bytes).unwrap_or(i64::MAX))
        .execute(&db.writer)
        .await?;
    Ok(())
}

/// How a job ended.
#[derive(Clone, Debug)]
pub enum End {
    /// Succeeded.
    Succeeded(StoredResult),
    /// Failed.
    Failed {
        /// Error code.
        code: ErrorCode,
        /// Message.
        message: String,
    },
    /// Cancelled (by the client).
    Cancelled {
        /// `cancelled`.
        code: ErrorCode,
        /// Message.
        message: String,
    },
}

/// Puts a job whose attempt failed transiently back in the queue, due at
/// `run_after` (fenced; the attempt stays counted).
pub async fn retry_later(
    db: &Db,
    id: &str,
    token: &str,
    run_after: i64,
    message: &str,
) -> Result<bool, sqlx::Error> {
    let q = sqlx::query(
        "UPDATE jobs SET status = 'queued', run_after = $3, error_message = $4, stage = NULL, \
           lease_token = NULL, lease_expires_at = NULL, updated_at = $5 \
         WHERE id = $1 AND lease_token = $2 AND status = 'running'",
    );
    fenced(
        db,
        q.bind(id)
            .bind(token)
            .bind(run_after)
            .bind(message)
            .bind(now_ms()),
    )
    .await
}

/// Gives a job back on shutdown without counting the attempt (fenced).
pub async fn release(db: &Db, id: &str, token: &str) -> Result<bool, sqlx::Error> {
    let q = sqlx::query(
        "UPDATE jobs SET status = 'queued', attempt = attempt - 1, run_after = $3, stage = NULL, \
           lease_token = NULL, lease_expires_at = NULL, updated_at = $3 \
         WHERE id = $1 AND lease_token = $2 AND status = 'running'",
    );
    fenced(db, q.bind(id).bind(token).bind(now_ms())).await
}

/// What [`cancel`] did.
#[derive(Debug)]
pub enum Cancel {
    /// The job was queued and is now cancelled.
    Cancelled(JobRow),
    /// The job is running; its worker will stop within a frame.
    Requested(JobRow),
    /// Already cancelled (idempotent).
    AlreadyCancelled(JobRow),
    /// Succeeded or failed: nothing to cancel.
    Finished(JobRow),
    /// No such job for this owner.
    NotFound,
}

/// Cancels a job on a client's request.
pub async fn cancel(db: &Db, owner: &str, id: &str) -> Result<Cancel, sqlx::Error> {
    let now = now_ms();
    let mut tx = db.writer.begin().await?;
    let row = sqlx::query(
        "UPDATE jobs SET status = 'cancelled', error_code = 'cancelled', \
           error_message = 'cancelled by the client', updated_at = $3 \
         WHERE id = $1 AND owner = $2 AND status = 'queued' RETURNING *",
    )
    .bind(id)
    .bind(owner)
    .bind(now)
    .fetch_optional(&mut *tx)
    .await?;
    if let Some(row) = row {
        let row = JobRow::from_row(&row)?;
        super::webhooks::schedule(&mut tx, &row).await?;
        tx.commit().await?;
        return Ok(Cancel::Cancelled(row));
    }
    let row = sqlx::query(
        "UPDATE jobs SET cancel_requested = 1, updated_at = $3 \
         WHERE id = $1 AND owner = $2 AND status = 'running' RETURNING *",
    )
    .bind(id)
    .bind(owner)
    .bind(now)
    .fetch_optional(&mut *tx)
    .await?;
    tx.commit().await?;
    if let Some(row) = row {
        return Ok(Cancel::Requested(JobRow::from_row(&row)?));
    }
    Ok(match get(db, owner, id).await? {
        None => Cancel::NotFound,
        Some(row) if row.status == JobStatus::Cancelled => Cancel::AlreadyCancelled(row),
        Some(row) => Cancel::Finished(row),
    })
}

/// Deletes a job that has ended (succeeded, failed or cancelled) and
/// ended before `ended_before` (ms), with the records of its webhook
/// deliveries that are done; a delivery still pending stays, so the
/// job's end is still announced. `owner` scopes a client's request;
/// retention passes `None`. Returns whether the row went; its blobs
/// ([`job_prefix`]) are the caller's to delete next. Row first, blobs
/// second: a crash in between leaves blobs without a row, which the
/// orphan sweep removes, never a row without its blobs.
pub async fn delete_ended(
    db: &Db,
    owner: Option<&str>,
    id: &str,
    ended_before: i64,
) -> Result<bool, sqlx::Error> {
    const ENDED: &str = "status IN ('succeeded', 'failed', 'cancelled') AND updated_at < $2";
    let mut tx = db.writer.begin().await?;
    let deleted = match owner {
        Some(owner) => {
            // Our own constant only: no input reaches the SQL text.
            sqlx::query(sqlx::AssertSqlSafe(format!(
                "DELETE FROM jobs WHERE id = $1 AND {ENDED} AND owner = $3"
            )))
            .bind(id)
            .bind(ended_before)
            .bind(owner)
            .execute(&mut *tx)
            .await?
        }
        None => {
            sqlx::query(sqlx::AssertSqlSafe(format!(
                "DELETE FROM jobs WHERE id = $1 AND {ENDED}"
            )))
            .bind(id)
            .bind(ended_before)
            .execute(&mut *tx)
            .await?
        }
    }
    .rows_affected();
    if deleted == 1 {
        sqlx::query("DELETE FROM webhook_deliveries WHERE job_id = $1 AND state <> 'pending'")
            .bind(id)
            .execute(&mut *tx)
            .await?;
    }
    tx.commit().await?;
    Ok(deleted == 1)
}

/// Up to `limit` jobs that ended before `ended_before` (ms), oldest
/// first: what `--result-ttl` expires.
pub async fn ended_before(
    db: &Db,
    ended_before: i64,
    limit: u32,
) -> Result<Vec<String>, sqlx::Error> {
    let rows = sqlx::query(
        "SELECT id FROM jobs WHERE status IN ('succeeded', 'failed', 'cancelled') \
         AND updated_at < $1 ORDER BY updated_at LIMIT $2",
    )
    .bind(ended_before)
    .bind(i64::from(limit))
    .fetch_all(&db.pool)
    .await?;
    rows.iter().map(|r| r.try_get::<String, _>("id")).collect()
}

/// Returns jobs whose lease expired to the queue (or ends them: cancelled
/// when a cancellation was pending, failed when their attempts are used
/// up). Returns how many rows changed.
pub async fn reclaim_expired(db: &Db, max_attempts: u32) -> Result<u64, sqlx::Error> {
    let now = now_ms();
    let mut tx: Transaction<'_, Any> = db.writer.begin().await?;
    let rows = sqlx::query(
        "UPDATE jobs SET \
           status = CASE WHEN cancel_requested = 1 THEN 'cancelled' \
                         WHEN attempt >= $2 THEN 'failed' ELSE 'queued' END, \
           error_code = CASE WHEN cancel_requested = 1 THEN 'cancelled' \
                             WHEN attempt >= $2 THEN 'internal' ELSE error_code END, \
           error_message = CASE WHEN cancel_requested = 1 THEN 'cancelled by the client' \
                                WHEN attempt >= $2 THEN 'the job''s worker stopped responding on every attempt' \
                                ELSE 'the previous attempt''s worker stopped responding' END, \
           run_after = $1, stage = NULL, lease_token = NULL, lease_expires_at = NULL, updated_at = $1 \
         WHERE status = 'running' AND lease_expires_at < $1 RETURNING *",
    )
    .bind(now)
    .bind(i64::from(max_attempts))
    .fetch_all(&mut *tx)
    .await?;
    for row in &rows {
        let row = JobRow::from_row(row)?;
        tracing::warn!(job = %row.id, attempt = row.attempt, status = row.status.as_str(), "reclaimed an expired lease");
        if row.status.is_terminal() {
            super::webhooks::schedule(&mut tx, &row).await?;
        }
    }
    tx.commit().await?;
    Ok(rows.len() as u64)
}

#[cfg(test)]
#[path = "queue_tests.rs"]
mod tests;
