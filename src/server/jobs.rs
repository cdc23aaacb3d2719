//! `/v1/jobs`: start, inspect, list and cancel jobs, and fetch their
//! outputs.
//!
//! # Choices
//! - A request naming a tree that does not exist for this API key is a
//!   **404 `tree_not_found`** (the tree is a missing resource, not a
//!   malformed request).
//! - **Idempotency.** With an `Idempotency-Key` header (1–255 visible
//!   ASCII characters), the first request creates the job and every later
//!   one with the same key and the same body (compared by a hash of the
//!   parsed request, so formatting and field order do not matter) returns
//!   that job (`202`, same `id`) — also under concurrency, since the unique
//!   index decides. A different body with a reused key is 422
//!   `idempotency_key_reused`. Keys are scoped per API key.
//! - **Cancelling** (`DELETE /v1/jobs/{id}`, or `POST
//!   /v1/jobs/{id}/cancel`, which never deletes) a queued job cancels it
//!   at once; a running job gets `cancel_requested: true` and stops within
//!   one frame (the response is the job with status `running`).
//! - **Deleting.** `DELETE` on a job that has ended (succeeded, failed or
//!   cancelled) deletes the job and every blob it owns (204), after which
//!   the job answers 404; `--result-ttl` does the same to jobs that ended
//!   long enough ago ([`crate::jobs::retention`]). `POST …/cancel` on a
//!   cancelled job is a no-op `200`, on a succeeded or failed one 409
//!   `job_finished`.
//! - Whole-sequence outputs (`animation.glb`, `stream.tmd`,
//!   `metrics.json`) of a job that has not succeeded (yet) answer 409
//!   `not_ready` while it is queued or running and 404 once it failed or
//!   was cancelled. A frame is available as soon as it is published
//!   (`frames_ready`) and stays available when the job later fails or is
//!   cancelled: the frames its last attempt published are a usable partial
//!   result; frames never published answer 409 or 404 as above.
//! - **Rendered on request.** A job run plan-first ([`crate::jobs::worker`])
//!   stored no per-frame GLBs and no animated GLB. A frame it published is
//!   rendered at its instant ([`crate::pipeline::frame_instant`]) when
//!   first asked for, the animated GLB by a run of the job for that one
//!   output; both are kept in the render cache ([`super::renders`]) under
//!   their blob key, whose ETag they carry, with ranges and 304 like a
//!   stored blob. A stored blob under the key (a job run by an earlier
//!   version) is served as it is.

use axum::Json;
use axum::extract::{Path, Request, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Deserialize;
use sha2::Digest;
use treemorph_api::ErrorCode;
use treemorph_api::jobs::{JobInfo, JobPage, JobRequest, JobStatus};
use utoipa::IntoParams;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::extract::{ApiQuery, decode_cursor, encode_cursor, json_body, page_limit, path_id};
use super::{AppState, Owner, blob, resample};
use crate::error::ApiError;
use crate::jobs::queue::{self, Cancel, Created, JobRow, NewJob};
use crate::jobs::retention;
use crate::pipeline::StreamPart;
use crate::store::new_id;

/// The routes of this module.
pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(post, list))
        .routes(routes!(get, delete))
        .routes(routes!(cancel))
        .routes(routes!(frame))
        .routes(routes!(frame_at))
        .routes(routes!(animation))
        .routes(routes!(metrics))
}

/// Query of `GET /v1/jobs`.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
#[serde(deny_unknown_fields)]
pub struct JobListQuery {
    /// Page size, 1..=100 (default 20).
    #[param(minimum = 1, maximum = 100)]
    pub limit: Option<u32>,
    /// `next_cursor` of the previous page.
    #[param(pattern = "^[0-9a-f]{45}$")]
    pub cursor: Option<String>,
    /// Only jobs with this status.
    pub status: Option<JobStatus>,
}

fn idempotency_key(headers: &HeaderMap) -> Result<Option<String>, ApiError> {
    let Some(v) = headers.get("idempotency-key") else {
        return Ok(None);
    };
    let key = v
        .to_str()
        .ok()
        .filter(|k| !k.is_empty() && k.len() <= 255 && k.bytes().all(|b| b.is_ascii_graphic()))
        .ok_or_else(|| {
            ApiError::invalid("Idempotency-Key must be 1 to 255 visible ASCII characters")
        })?;
    Ok(Some(key.to_owned()))
}

fn accepted(row: &JobRow) -> Response {
    (
        StatusCode::ACCEPTED,
        [(header::LOCATION, format!("/v1/jobs/{}", row.id))],
        Json(row.info()),
    )
        .into_response()
}

/// Start a morph or sketch job.
///
/// The job is queued and runs in the background; follow it with
/// `GET /v1/jobs/{id}`, its SSE `events`, or its delta `stream`.
#[utoipa::path(
    post,
    path = "/v1/jobs",
    operation_id = "create_job",
    tag = "jobs",
    params(("Idempotency-Key" = Option<String>, Header,
        description = "Retries with the same key and body return the same job (1 to 255 visible ASCII characters)",
        pattern = "^[!-~]{1,255}$")),
    request_body(content = JobRequest, content_type = "application/json"),
    responses(
        (status = 202, description = "Queued (or the existing job of this idempotency key)", body = JobInfo,
            headers(("Location" = String, description = "URL of the job"))),
        (status = 400, description = "Malformed JSON (`invalid_json`)", body = treemorph_api::ErrorBody),
        (status = 404, description = "A named tree does not exist (`tree_not_found`)", body = treemorph_api::ErrorBody),
        (status = 413, description = "Body too large (`payload_too_large`)", body = treemorph_api::ErrorBody),
        (status = 415, description = "Not `application/json` (`unsupported_media_type`)", body = treemorph_api::ErrorBody),
        (status = 422, description = "Invalid request (`invalid_request`, `idempotency_key_reused`, `callback_url_refused`, `invalid_job`, `invalid_sketch`, `incompatible_trees`)", body = treemorph_api::ErrorBody),
        (status = 507, description = "The API key is at its storage quota (`quota_exceeded`), or the server's storage is full (`insufficient_storage`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn post(
    State(state): State<AppState>,
    owner: Owner,
    request: Request,
) -> Result<Response, ApiError> {
    let key = idempotency_key(request.headers())?;
    let (job, _) = json_body::<JobRequest, _>(request, &state).await?;
    let settings = state.settings();
    let spec = state.services.runner.check(&job, &settings.limits())?;
    for id in job.tree_ids() {
        let found =
            crate::store::is_id(id) && state.services.db.tree(&owner.0, id).await?.is_some();
        if !found {
            return Err(ApiError::new(
                ErrorCode::TreeNotFound,
                format!("no tree {id:?}"),
            ));
        }
    }
    if let Some(url) = job.callback_url() {
        crate::jobs::webhooks::resolve_callback(url, settings.allow_private_callbacks)
            .await
            .map_err(|e| ApiError::new(ErrorCode::CallbackUrlRefused, e))?;
    }
    let canonical = serde_json::to_string(&job).expect("requests serialise");
    let hash: String = sha2::Sha256::digest(canonical.as_bytes())
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    let db = &state.services.db;
    // A retry of an accepted request gets its job even when the queue has
    // filled up since.
    if let Some(replayed) = queue::replay(db, &owner.0, key.as_deref(), &hash).await? {
        return created(replayed, &state);
    }
    super::quota::check(&state, &owner, 0).await?;
    let queued = queue::queued_count(db).await?;
    if queued >= settings.max_queued as i64 {
        return Err(ApiError::new(
            ErrorCode::QueueFull,
            format!("{queued} jobs are waiting; try again later"),
        )
        .retry_after(5));
    }
    let trees = spec.tree_ids();
    let new = NewJob {
        id: new_id(),
        owner: owner.0.clone(),
        kind: spec.kind(),
        request: canonical,
        tree_a: trees[0].to_owned(),
        tree_b: trees.get(1).map(|s| (*s).to_owned()),
        frames: spec.frames(),
        idempotency_key: key,
        request_hash: hash,
        callback_url: job.callback_url().map(str::to_owned),
    };
    created(queue::create(db, &new).await?, &state)
}

/// The answer to `POST /v1/jobs` once the queue has decided.
fn created(created: Created, state: &AppState) -> Result<Response, ApiError> {
    match created {
        Created::New(row) => {
            tracing::info!(job = %row.id, kind = row.kind.as_str(), "job queued");
            state.services.hub.work.notify_one();
            Ok(accepted(&row))
        }
        Created::Existing(row) => Ok(accepted(&row)),
        Created::KeyReused => Err(key_reused()),
    }
}

fn key_reused() -> ApiError {
    ApiError::new(
        ErrorCode::IdempotencyKeyReused,
        "this Idempotency-Key was used with a different request",
    )
}

/// List jobs, newest first.
#[utoipa::path(
    get,
    path = "/v1/jobs",
    operation_id = "list_jobs",
    tag = "jobs",
    params(JobListQuery),
    responses(
        (status = 200, description = "One page of jobs", body = JobPage),
        (status = 422, description = "Bad limit, cursor or status (`invalid_request`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn list(
    State(state): State<AppState>,
    owner: Owner,
    ApiQuery(query): ApiQuery<JobListQuery>,
) -> Result<Json<JobPage>, ApiError> {
    let limit = page_limit(query.limit)?;
    let after = query.cursor.as_deref().map(decode_cursor).transpose()?;
    let mut rows = queue::list(&state.services.db, &owner.0, query.status, after, limit).await?;
    let next_cursor = if rows.len() > limit as usize {
        rows.truncate(limit as usize);
        rows.last().map(|r| encode_cursor(r.created_at, &r.id))
    } else {
        None
    };
    Ok(Json(JobPage {
        items: rows.iter().map(JobRow::info).collect(),
        next_cursor,
    }))
}

/// Finds `owner`'s job `id` (404 otherwise).
pub async fn find(state: &AppState, owner: &Owner, id: &str) -> Result<JobRow, ApiError> {
    path_id(id, "job")?;
    queue::get(&state.services.db, &owner.0, id)
        .await?
        .ok_or_else(|| ApiError::not_found("job"))
}

/// Get a job.
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}",
    operation_id = "get_job",
    tag = "jobs",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "The job", body = JobInfo),
        (status = 404, description = "No such job (`not_found`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn get(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
) -> Result<Json<JobInfo>, ApiError> {
    Ok(Json(find(&state, &owner, &id).await?.info()))
}

/// Cancel or delete a job.
///
/// A queued job is cancelled at once and a running one stops within a
/// frame (the response shows `cancel_requested: true`): 200 with the job.
/// A job that has ended (succeeded, failed or cancelled) is deleted with
/// every output it stored: 204, after which the job answers 404.
#[utoipa::path(
    delete,
    path = "/v1/jobs/{id}",
    operation_id = "cancel_job",
    tag = "jobs",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "Cancelled, or cancellation requested", body = JobInfo),
        (status = 204, description = "The job had ended; it and its outputs are deleted"),
        (status = 404, description = "No such job (`not_found`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn delete(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    path_id(&id, "job")?;
    match cancel_queued_or_running(&state, &owner, &id).await? {
        Ok(info) => Ok(Json(info).into_response()),
        Err(_ended) => {
            let db = &state.services.db;
            if !queue::delete_ended(db, Some(&owner.0), &id, i64::MAX).await? {
                // Deleted by a concurrent request or by expiry meanwhile.
                return Err(ApiError::not_found("job"));
            }
            retention::delete_job_blobs(&state.services.blobs, &id).await;
            state.services.hub.changed(&id);
            Ok(StatusCode::NO_CONTENT.into_response())
        }
    }
}

/// Cancel a job, never deleting it.
///
/// The cancellation of `DELETE /v1/jobs/{id}` for clients that must not
/// delete by mistake: a queued job is cancelled at once, a running one
/// stops within a frame (`cancel_requested: true`), a cancelled one is
/// answered as it is, and a job that succeeded or failed answers 409
/// `job_finished`.
#[utoipa::path(
    post,
    path = "/v1/jobs/{id}/cancel",
    operation_id = "cancel_job_only",
    tag = "jobs",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "Cancelled, or cancellation requested", body = JobInfo),
        (status = 404, description = "No such job (`not_found`)", body = treemorph_api::ErrorBody),
        (status = 409, description = "The job already succeeded or failed (`job_finished`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn cancel(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
) -> Result<Json<JobInfo>, ApiError> {
    path_id(&id, "job")?;
    match cancel_queued_or_running(&state, &owner, &id).await? {
        Ok(info) => Ok(Json(info)),
        Err(row) if row.status == JobStatus::Cancelled => Ok(Json(row.info())),
        Err(row) => Err(ApiError::new(
            ErrorCode::JobFinished,
            format!("the job already {}", row.status.as_str()),
        )),
    }
}

/// Cancels `owner`'s job `id` if it is queued or running (the job as it
/// is now), or returns it as it ended (`Err`); 404 when there is none.
async fn cancel_queued_or_running(
    state: &AppState,
    owner: &Owner,
    id: &str,
) -> Result<Result<JobInfo, JobRow>, ApiError> {
    match queue::cancel(&state.services.db, &owner.0, id).await? {
        Cancel::Cancelled(row) => {
            state.services.hub.changed(id);
            state.services.hub.webhooks.notify_one();
            Ok(Ok(row.info()))
        }
        Cancel::Requested(row) => {
            state.services.hub.cancel(id);
            state.services.hub.changed(id);
            Ok(Ok(row.info()))
        }
        Cancel::AlreadyCancelled(row) | Cancel::Finished(row) => Ok(Err(row)),
        Cancel::NotFound => Err(ApiError::not_found("job")),
    }
}

/// Query of `GET /v1/jobs/{id}/frame.glb`.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
#[serde(deny_unknown_fields)]
pub struct InstantQuery {
    /// The instant, in [0, 1] (0 is the first frame, 1 the last).
    #[param(minimum = 0.0, maximum = 1.0)]
    pub t: f32,
}

/// Get the frame at any instant as GLB.
///
/// Rendered on request, for a job that succeeded: the job is planned
/// again from its stored request and trees (plans are deterministic), so
/// at `t = i / (frames − 1)` the bytes are those of `frames/{i}.glb`, and
/// any instant between renders too. The ETag names the job's attempt and
/// the instant (a render is a deterministic function of both), so a
/// cached copy is revalidated without rendering.
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}/frame.glb",
    operation_id = "get_job_frame_at",
    tag = "jobs",
    params(
        ("id" = String, Path, description = "Job id"),
        InstantQuery,
        ("If-None-Match" = Option<String>, Header, description = "ETag of a cached copy"),
    ),
    responses(
        (status = 200, description = "The frame at `t`", content_type = "model/gltf-binary", body = [u8],
            headers(("ETag" = String, description = "Strong entity tag"))),
        (status = 304, description = "Not modified"),
        (status = 404, description = "No such job, or it failed or was cancelled (`not_found`)", body = treemorph_api::ErrorBody),
        (status = 409, description = "The job has not succeeded yet (`not_ready`)", body = treemorph_api::ErrorBody),
        (status = 410, description = "The job can no longer render new instants (`plan_outdated`); run it again", body = treemorph_api::ErrorBody),
        (status = 422, description = "`t` is missing or not a number in [0, 1] (`invalid_request`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn frame_at(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
    ApiQuery(query): ApiQuery<InstantQuery>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let row = find(&state, &owner, &id).await?;
    instant(&state, &row, query.t, Instant::Glb, &headers).await
}

/// What an instant is rendered as.
#[derive(Clone, Copy, Debug)]
pub enum Instant {
    /// `frame.glb?t=`: the per-frame GLB.
    Glb,
    /// `stream?t=`: a delta stream of the one frame, or (`header=false`)
    /// its frame record alone.
    Stream(StreamPart),
}

/// The media type of a frame record without its stream
/// (`stream?t=&header=false`): it decodes only after the job's own stream
/// header.
pub const FRAME_RECORD_MEDIA_TYPE: &str = "application/vnd.treemorph.delta-frame";

impl Instant {
    fn content_type(self) -> &'static str {
        match self {
            Instant::Glb => "model/gltf-binary",
            Instant::Stream(StreamPart::Whole) => treemorph_api::delta::MEDIA_TYPE,
            Instant::Stream(StreamPart::Frame) => FRAME_RECORD_MEDIA_TYPE,
        }
    }

    /// The render cache key (and ETag source) under the job's attempt.
    fn key(self, prefix: &str, t: f32) -> String {
        match self {
            Instant::Glb => format!("{prefix}/at/{:08x}", t.to_bits()),
            Instant::Stream(StreamPart::Whole) => format!("{prefix}/stream-at/{:08x}", t.to_bits()),
            Instant::Stream(StreamPart::Frame) => {
                format!("{prefix}/stream-frame-at/{:08x}", t.to_bits())
            }
        }
    }
}

/// Serves `row`'s frame at `t` as `what`, rendered on request and kept in
/// the render cache: 422 for a bad `t`, 409 or 404 for a job that has not
/// succeeded.
pub async fn instant(
    state: &AppState,
    row: &JobRow,
    t: f32,
    what: Instant,
    headers: &HeaderMap,
) -> Result<Response, ApiError> {
    let t = crate::pipeline::check_instant(t)?;
    let prefix = succeeded_prefix(row, "frame")?;
    let key = what.key(&prefix, t);
    let render = state
        .renders
        .get_or_render(&key, render_at(state, row, t, what));
    serve_rendered(headers, &key, what.content_type(), render).await
}

/// Renders `row`'s frame at `t` ([`resample::on_inputs`]); the caller
/// keeps it in the render cache ([`super::renders`]).
async fn render_at(
    state: &AppState,
    row: &JobRow,
    t: f32,
    what: Instant,
) -> Result<Vec<u8>, ApiError> {
    resample::check_version(row)?;
    let spec =
        crate::jobs::worker::claimed_spec(&state.services, row).map_err(resample::outdated)?;
    resample::on_inputs(state, row, spec, move |runner, input| match what {
        Instant::Glb => runner.frame_at(input, t),
        Instant::Stream(part) => runner.stream_at(input, t, part),
    })
    .await
}

/// Serves a re-sampled whole-sequence file of a succeeded job: 409 or 404
/// for other jobs (as their stored files), a key-derived ETag, and 304
/// without a run when it matches.
pub async fn resampled(
    state: &AppState,
    row: &JobRow,
    what: resample::Resample,
    content_type: &'static str,
    headers: &HeaderMap,
) -> Result<Response, ApiError> {
    let prefix = succeeded_prefix(row, "output")?;
    let (key, spec) = resample::prepare(state, row, &prefix, what)?;
    if matches!(what, resample::Resample::Frames(_)) && super::streamed::applies(headers, &key) {
        return resample::streamed(state, row, &key, spec, headers).await;
    }
    let render = resample::file(state, row, &key, spec, what);
    serve_rendered(headers, &key, content_type, render).await
}

/// The blob prefix of a succeeded job's outputs; 409 or 404 naming `what`
/// for any other job.
fn succeeded_prefix(row: &JobRow, what: &str) -> Result<String, ApiError> {
    match (&row.status, row.published_prefix()) {
        (JobStatus::Succeeded, Some(prefix)) => Ok(prefix),
        _ => Err(not_available(row, what)),
    }
}

/// Serves a render on request: an ETag derived from its `key` (a render is
/// a deterministic function of the key), 304 without rendering when it
/// matches, else the bytes `render` gives (or the range asked for).
async fn serve_rendered(
    headers: &HeaderMap,
    key: &str,
    content_type: &'static str,
    render: impl std::future::Future<Output = Result<bytes::Bytes, ApiError>>,
) -> Result<Response, ApiError> {
    // A matching ETag is answered 304 before any bytes are looked at.
    let bytes = if super::extract::not_modified(headers, &blob::etag_for(key)) {
        bytes::Bytes::new()
    } else {
        render.await?
    };
    Ok(blob::serve_bytes(key, content_type, headers, bytes))
}

/// 409 `not_ready` while the job may still produce it, 404 otherwise.
fn not_available(row: &JobRow, what: &str) -> ApiError {
    if row.status.is_terminal() {
        ApiError::new(ErrorCode::NotFound, format!("this job has no {what}"))
    } else {
        ApiError::new(ErrorCode::NotReady, format!("the {what} is not ready yet")).retry_after(1)
    }
}

/// Get one frame as GLB (available as soon as the frame is published;
/// rendered when first asked for, see the module docs).
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}/frames/{frame}",
    operation_id = "get_job_frame",
    tag = "jobs",
    params(
        ("id" = String, Path, description = "Job id"),
        ("frame" = String, Path, description = "`{n}.glb` with the 0-based frame index n", pattern = r"^[0-9]+\.glb$"),
        ("Range" = Option<String>, Header, description = "A single byte range"),
        ("If-None-Match" = Option<String>, Header, description = "ETag of a cached copy"),
    ),
    responses(
        (status = 200, description = "The frame", content_type = "model/gltf-binary", body = [u8],
            headers(("ETag" = String, description = "Strong entity tag"))),
        (status = 206, description = "A byte range of the frame", content_type = "model/gltf-binary", body = [u8]),
        (status = 304, description = "Not modified"),
        (status = 404, description = "No such job or frame (`not_found`)", body = treemorph_api::ErrorBody),
        (status = 409, description = "The frame is not published yet (`not_ready`)", body = treemorph_api::ErrorBody),
        (status = 410, description = "The frame is rendered on request, and this job can no longer render (`plan_outdated`); run it again", body = treemorph_api::ErrorBody),
        (status = 416, description = "Bad range (`range_not_satisfiable`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn frame(
    State(state): State<AppState>,
    owner: Owner,
    Path((id, frame)): Path<(String, String)>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let n: u32 = frame
        .strip_suffix(".glb")
        .filter(|n| !n.is_empty() && n.len() <= 6 && n.bytes().all(|b| b.is_ascii_digit()))
        .and_then(|n| n.parse().ok())
        .ok_or_else(|| ApiError::not_found("frame"))?;
    let row = find(&state, &owner, &id).await?;
    if n >= row.frames {
        return Err(ApiError::not_found("frame"));
    }
    let prefix = match row.published_prefix() {
        Some(p) if n < row.frames_ready => p,
        _ => return Err(not_available(&row, "frame")),
    };
    let key = queue::frame_glb_key(&prefix, n);
    let blobs = &state.services.blobs;
    if !row.requested_outputs().glb {
        let what = "frame (per-frame GLBs were not requested)";
        return blob::serve(blobs, &key, "model/gltf-binary", &headers, what).await;
    }
    if let Some(stored) = blob::serve_if_stored(blobs, &key, "model/gltf-binary", &headers).await? {
        return Ok(stored);
    }
    let t = crate::pipeline::frame_instant(n, row.frames);
    let render = state
        .renders
        .get_or_render(&key, render_at(&state, &row, t, Instant::Glb));
    serve_rendered(&headers, &key, "model/gltf-binary", render).await
}

async fn file(
    state: &AppState,
    row: &JobRow,
    name: &str,
    content_type: &'static str,
    headers: &HeaderMap,
) -> Result<Response, ApiError> {
    let produced = row
        .result
        .as_ref()
        .is_some_and(|r| r.files.iter().any(|f| f == name));
    match row.published_prefix() {
        Some(prefix) if row.status == JobStatus::Succeeded && produced => {
            let key = queue::file_key(&prefix, name);
            let blobs = &state.services.blobs;
            match blob::serve_if_stored(blobs, &key, content_type, headers).await? {
                Some(stored) => Ok(stored),
                None if name == "animation.glb" => {
                    let what = resample::Resample::Animation;
                    resampled(state, row, what, content_type, headers).await
                }
                None => Err(ApiError::not_found(name)),
            }
        }
        _ if row.status == JobStatus::Succeeded => Err(ApiError::not_found(name)),
        _ => Err(not_available(row, name)),
    }
}

/// Get the animated GLB of the whole sequence.
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}/animation.glb",
    operation_id = "get_job_animation",
    tag = "jobs",
    params(
        ("id" = String, Path, description = "Job id"),
        AnimationQuery,
        ("Range" = Option<String>, Header, description = "A single byte range"),
        ("If-None-Match" = Option<String>, Header, description = "ETag of a cached copy"),
    ),
    responses(
        (status = 200, description = "The animated GLB", content_type = "model/gltf-binary", body = [u8],
            headers(("ETag" = String, description = "Strong entity tag"))),
        (status = 206, description = "A byte range", content_type = "model/gltf-binary", body = [u8]),
        (status = 304, description = "Not modified"),
        (status = 404, description = "No such job, or no animation (`not_found`)", body = treemorph_api::ErrorBody),
        (status = 409, description = "The job has not finished (`not_ready`)", body = treemorph_api::ErrorBody),
        (status = 410, description = "The job can no longer be re-sampled (`plan_outdated`); run it again", body = treemorph_api::ErrorBody),
        (status = 416, description = "Bad range (`range_not_satisfiable`)", body = treemorph_api::ErrorBody),
        (status = 422, description = "Bad `keyframes` (`invalid_request`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn animation(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
    ApiQuery(query): ApiQuery<AnimationQuery>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let row = find(&state, &owner, &id).await?;
    match query.keyframes {
        Some(k) => {
            let what = resample::Resample::Keyframes(k);
            resampled(&state, &row, what, "model/gltf-binary", &headers).await
        }
        None => file(&state, &row, "animation.glb", "model/gltf-binary", &headers).await,
    }
}

/// Query of `GET /v1/jobs/{id}/animation.glb`.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
#[serde(deny_unknown_fields)]
pub struct AnimationQuery {
    /// Re-sample the sequence with this many keyframes (2 to the job's
    /// frame count), rendered on request; without it, the job's own file.
    #[param(minimum = 2)]
    pub keyframes: Option<u32>,
}

/// Get the job's metrics document.
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}/metrics.json",
    operation_id = "get_job_metrics",
    tag = "jobs",
    params(
        ("id" = String, Path, description = "Job id"),
        ("Range" = Option<String>, Header, description = "A single byte range"),
        ("If-None-Match" = Option<String>, Header, description = "ETag of a cached copy"),
    ),
    responses(
        (status = 200, description = "The metrics", content_type = "application/json", body = super::trees::JsonDocument,
            headers(("ETag" = String, description = "Strong entity tag"))),
        (status = 206, description = "A byte range", content_type = "application/json", body = [u8]),
        (status = 304, description = "Not modified"),
        (status = 404, description = "No such job, or no metrics (`not_found`)", body = treemorph_api::ErrorBody),
        (status = 409, description = "The job has not finished (`not_ready`)", body = treemorph_api::ErrorBody),
        (status = 416, description = "Bad range (`range_not_satisfiable`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn metrics(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let row = find(&state, &owner, &id).await?;
    file(&state, &row, "metrics.json", "application/json", &headers).await
}
