//! `GET /v1/jobs/{id}/stream`: the binary delta stream
//! (`application/vnd.treemorph.delta`, see `api/README.md`).
//!
//! - **While the job runs** the response is chunked and live: the header
//!   record once it is published, then each frame record as the worker
//!   commits it (`frames_ready`), read from the blob store under the
//!   attempt the row names. When the job succeeds, the rest of the complete
//!   stream (`stream.tmd` from the byte offset already sent — the runner
//!   publishes it as exactly header + frames + end record) closes it. If the
//!   job fails or is cancelled, or a retry replaces the attempt after bytes
//!   were sent, the response simply ends: the missing end record tells the
//!   client the stream is incomplete.
//! - **After success** it is the stored `stream.tmd`, with an ETag and
//!   single-range support (206/416) like every finished output.

use axum::body::Body;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::Response;
use bytes::Bytes;
use tokio::sync::mpsc;
use treemorph_api::ErrorCode;
use treemorph_api::delta::MEDIA_TYPE;
use treemorph_api::jobs::JobStatus;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::events::JobWatch;
use super::extract::ApiQuery;
use super::{AppState, Owner, blob};
use crate::error::ApiError;
use crate::jobs::queue::{self, JobRow};
use crate::pipeline::StreamPart;

/// The routes of this module.
pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(stream))
}

/// Query of `GET /v1/jobs/{id}/stream`.
#[derive(Debug, serde::Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
#[serde(deny_unknown_fields)]
pub struct StreamQuery {
    /// Re-sample a succeeded job's sequence with this many frames,
    /// rendered on request (within the server's frame limit) and sent as
    /// it renders the first time; without it, the job's own stream.
    #[param(minimum = 2)]
    pub frames: Option<u32>,
    /// The one frame at this instant in [0, 1] of a succeeded job, as a
    /// stream of that frame with the job's own header (bounds, grid,
    /// meshes): a player of the job's stream shows it in its own meshes.
    /// Rendered on request; not with `frames`.
    #[param(minimum = 0.0, maximum = 1.0)]
    pub t: Option<f32>,
    /// With `t`: `false` answers the frame record alone
    /// (`application/vnd.treemorph.delta-frame`), encoded against the
    /// job's own stream header, for a client that holds that header (a
    /// player scrubbing the job: a fraction of the bytes). Default `true`.
    pub header: Option<bool>,
}

/// Get the delta stream: live while the job runs, complete afterwards.
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}/stream",
    operation_id = "get_job_stream",
    tag = "jobs",
    params(
        ("id" = String, Path, description = "Job id"),
        StreamQuery,
        ("Range" = Option<String>, Header, description = "A single byte range (finished jobs)"),
        ("If-None-Match" = Option<String>, Header, description = "ETag of a cached copy (finished jobs)"),
    ),
    responses(
        (status = 200, description = "The stream (chunked and live while the job runs, or while a re-sample first renders); with `t` and `header=false`, one frame record (`application/vnd.treemorph.delta-frame`)",
            content_type = "application/vnd.treemorph.delta", body = [u8]),
        (status = 206, description = "A byte range of a finished stream",
            content_type = "application/vnd.treemorph.delta", body = [u8]),
        (status = 304, description = "Not modified"),
        (status = 404, description = "No such job, the job failed, or the stream was not requested (`not_found`)", body = treemorph_api::ErrorBody),
        (status = 409, description = "`frames` or `t` asked of a job that has not succeeded yet (`not_ready`)", body = treemorph_api::ErrorBody),
        (status = 410, description = "The job can no longer be re-sampled (`plan_outdated`); run it again", body = treemorph_api::ErrorBody),
        (status = 416, description = "Bad range (`range_not_satisfiable`)", body = treemorph_api::ErrorBody),
        (status = 422, description = "Bad `frames`, `t` or `header`, both `frames` and `t`, or `header` without `t` (`invalid_request`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn stream(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
    ApiQuery(query): ApiQuery<StreamQuery>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let watcher = JobWatch::new(&state, &owner, &id);
    let row = super::jobs::find(&state, &owner, &id).await?;
    if let Some(t) = query.t {
        if query.frames.is_some() {
            return Err(ApiError::invalid(
                "ask for frames (a re-sampled sequence) or t (one instant), not both",
            ));
        }
        let part = if query.header.unwrap_or(true) {
            StreamPart::Whole
        } else {
            StreamPart::Frame
        };
        let what = super::jobs::Instant::Stream(part);
        return super::jobs::instant(&state, &row, t, what, &headers).await;
    }
    if query.header.is_some() {
        return Err(ApiError::invalid("header applies to one instant (t) only"));
    }
    if let Some(n) = query.frames {
        let what = super::resample::Resample::Frames(n);
        return super::jobs::resampled(&state, &row, what, MEDIA_TYPE, &headers).await;
    }
    if !row.requested_outputs().delta {
        return Err(ApiError::new(
            ErrorCode::NotFound,
            "this job's outputs exclude the delta stream",
        ));
    }
    match row.status {
        JobStatus::Succeeded => {
            let has = row
                .result
                .as_ref()
                .is_some_and(|r| r.files.iter().any(|f| f == "stream.tmd"));
            match row.published_prefix() {
                Some(prefix) if has => {
                    blob::serve(
                        &state.services.blobs,
                        &queue::file_key(&prefix, "stream.tmd"),
                        MEDIA_TYPE,
                        &headers,
                        "stream",
                    )
                    .await
                }
                _ => Err(ApiError::new(
                    ErrorCode::NotFound,
                    "this job produced no delta stream",
                )),
            }
        }
        JobStatus::Failed | JobStatus::Cancelled => Err(ApiError::new(
            ErrorCode::NotFound,
            format!("the job {}; its stream is incomplete", row.status.as_str()),
        )),
        JobStatus::Queued | JobStatus::Running => {
            let (tx, rx) = mpsc::channel::<Result<Bytes, std::io::Error>>(16);
            tokio::spawn(live(state, row, watcher, tx));
            let body = futures_util::stream::unfold(rx, |mut rx| async move {
                rx.recv().await.map(|c| (c, rx))
            });
            Ok(Response::builder()
                .status(StatusCode::OK)
                .header(header::CONTENT_TYPE, MEDIA_TYPE)
                .header(header::CACHE_CONTROL, "no-store")
                .header("x-accel-buffering", "no")
                .body(Body::from_stream(body))
                .expect("valid response"))
        }
    }
}

/// Feeds a live stream until the job ends or the client goes away.
///
/// Once the job has succeeded, the rest comes from `stream.tmd`: the
/// worker deletes the per-frame records after the success it commits
/// ([`crate::jobs::worker`]), so a record found missing while the job
/// runs on means only that the success is on its way; nothing more is sent
/// from records, and the complete stream finishes the response.
async fn live(
    state: AppState,
    mut row: JobRow,
    mut watcher: JobWatch,
    tx: mpsc::Sender<Result<Bytes, std::io::Error>>,
) {
    let mut feed = Feed::default();
    loop {
        if row.published_token != feed.token {
            if feed.sent > 0 {
                // Another attempt replaced the one we were streaming.
                return;
            }
            feed = Feed {
                token: row.published_token.clone(),
                ..Feed::default()
            };
        }
        if let Some(prefix) = row.published_prefix() {
            if row.status == JobStatus::Succeeded {
                finish_from_stream_file(&state, &row, &prefix, feed.sent, &tx).await;
                return;
            }
            if !feed.missing && !feed.send_records(&state, &row, &prefix, &tx).await {
                return;
            }
        }
        if row.status.is_terminal() {
            return;
        }
        match watcher.next().await {
            Some(r) => row = r,
            None => return,
        }
    }
}

/// Where a live stream stands within one attempt.
#[derive(Default)]
struct Feed {
    token: Option<String>,
    header_sent: bool,
    next_frame: u32,
    sent: u64,
    /// A published record was missing: send no more records.
    missing: bool,
}

impl Feed {
    /// Sends the records published since the last call; false when the
    /// client went away or the blob store failed.
    async fn send_records(
        &mut self,
        state: &AppState,
        row: &JobRow,
        prefix: &str,
        tx: &mpsc::Sender<Result<Bytes, std::io::Error>>,
    ) -> bool {
        let mut keys = Vec::new();
        if !self.header_sent && row.header_ready {
            keys.push(queue::header_key(prefix));
            self.header_sent = true;
        }
        if self.header_sent {
            while self.next_frame < row.frames_ready {
                keys.push(queue::frame_delta_key(prefix, self.next_frame));
                self.next_frame += 1;
            }
        }
        for key in keys {
            match state.services.blobs.get(&key).await {
                Ok(Some(bytes)) => {
                    self.sent += bytes.len() as u64;
                    if tx.send(Ok(bytes)).await.is_err() {
                        return false;
                    }
                }
                Ok(None) => {
                    tracing::debug!(job = %row.id, key, "a stream record is gone; waiting for the complete stream");
                    self.missing = true;
                    return true;
                }
                Err(e) => {
                    tracing::warn!(job = %row.id, error = %e, "reading a stream record failed");
                    return false;
                }
            }
        }
        true
    }
}

/// Sends the complete stream of a succeeded job from byte `sent` on.
async fn finish_from_stream_file(
    state: &AppState,
    row: &JobRow,
    prefix: &str,
    sent: u64,
    tx: &mpsc::Sender<Result<Bytes, std::io::Error>>,
) {
    let complete = row
        .result
        .as_ref()
        .is_some_and(|r| r.files.iter().any(|f| f == "stream.tmd"));
    if complete
        && let Ok(Some(all)) = state
            .services
            .blobs
            .get(&queue::file_key(prefix, "stream.tmd"))
            .await
        && (all.len() as u64) >= sent
    {
        let _ = tx.send(Ok(all.slice(sent as usize..))).await;
    }
}
