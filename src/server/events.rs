//! `GET /v1/jobs/{id}/events`: a job's progress as Server-Sent Events.
//!
//! Events, in order: `job` (the current job document, so a late subscriber
//! starts from the present), then as they happen `stage`
//! (`{"stage", "progress"}`), `progress` (`{"progress"}`), `frame`
//! (`{"index"}`: frame `index` can be fetched now), and finally one of
//! `done`, `failed` or `cancelled` with the final job document, after
//! which the stream ends. Comments (`:`) keep idle connections alive.
//!
//! Changes are detected by diffing successive reads of the job row, which
//! a [`JobWatch`] re-reads whenever this process's [`crate::jobs::Hub`]
//! announces a change (worker in the same process) or every `--poll-ms`
//! (worker in another process) — the same code path either way.

use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::{Path, State};
use axum::response::sse::{Event, KeepAlive, Sse};
use futures_util::Stream;
use tokio::sync::{broadcast, mpsc, watch};
use treemorph_api::jobs::JobStatus;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::{AppState, Owner};
use crate::error::ApiError;
use crate::jobs::queue::{self, JobRow};

/// The routes of this module.
pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(events))
}

/// Waits for changes of one job.
pub struct JobWatch {
    state: AppState,
    owner: String,
    id: String,
    changes: broadcast::Receiver<Arc<str>>,
    shutdown: watch::Receiver<bool>,
}

impl JobWatch {
    /// Starts watching (subscribe before reading the row you diff against,
    /// so no change is missed).
    pub fn new(state: &AppState, owner: &Owner, id: &str) -> JobWatch {
        JobWatch {
            state: state.clone(),
            owner: owner.0.clone(),
            id: id.to_owned(),
            changes: state.services.hub.changes.subscribe(),
            shutdown: state.shutdown.clone(),
        }
    }

    /// The row after the next change (or poll interval); `None` when the
    /// server shuts down or the job disappeared.
    pub async fn next(&mut self) -> Option<JobRow> {
        let poll = self.state.settings().poll();
        let id = self.id.clone();
        let changes = &mut self.changes;
        let announced = async move {
            loop {
                match changes.recv().await {
                    Ok(changed) if *changed == *id => return,
                    Ok(_) => {}
                    Err(broadcast::error::RecvError::Lagged(_)) => return,
                    Err(broadcast::error::RecvError::Closed) => {
                        std::future::pending::<()>().await;
                    }
                }
            }
        };
        tokio::select! {
            () = announced => {}
            () = tokio::time::sleep(poll) => {}
            _ = self.shutdown.changed() => return None,
        }
        if *self.shutdown.borrow() {
            return None;
        }
        match queue::get(&self.state.services.db, &self.owner, &self.id).await {
            Ok(row) => row,
            Err(e) => {
                tracing::warn!(job = %self.id, error = %e, "reading a watched job failed");
                tokio::time::sleep(Duration::from_millis(500)).await;
                queue::get(&self.state.services.db, &self.owner, &self.id)
                    .await
                    .ok()
                    .flatten()
            }
        }
    }
}

fn json_event(name: &str, data: &impl serde::Serialize) -> Event {
    Event::default()
        .event(name)
        .json_data(data)
        .expect("event data serialises")
}

/// The events between two reads of a job (frames counted from
/// `frames_sent`).
fn diff(last: &JobRow, row: &JobRow, frames_sent: &mut u32, out: &mut Vec<Event>) {
    if row.published_token != last.published_token {
        // A new attempt starts over.
        *frames_sent = 0;
    }
    if row.stage != last.stage
        && let Some(stage) = &row.stage
    {
        out.push(json_event(
            "stage",
            &serde_json::json!({"stage": stage, "progress": row.progress}),
        ));
    } else if row.progress != last.progress && !row.status.is_terminal() {
        out.push(json_event(
            "progress",
            &serde_json::json!({"progress": row.progress}),
        ));
    }
    while *frames_sent < row.frames_ready {
        out.push(json_event(
            "frame",
            &serde_json::json!({"index": *frames_sent}),
        ));
        *frames_sent += 1;
    }
}

fn terminal_event(row: &JobRow) -> Option<Event> {
    let name = match row.status {
        JobStatus::Succeeded => "done",
        JobStatus::Failed => "failed",
        JobStatus::Cancelled => "cancelled",
        _ => return None,
    };
    Some(json_event(name, &row.info()))
}

/// Follow a job's progress (Server-Sent Events).
///
/// Events: `job` (current state, first), `stage`, `progress`, `frame`, then
/// `done`, `failed` or `cancelled` (the final job document) and the stream
/// ends.
#[utoipa::path(
    get,
    path = "/v1/jobs/{id}/events",
    operation_id = "get_job_events",
    tag = "jobs",
    params(("id" = String, Path, description = "Job id")),
    responses(
        (status = 200, description = "An event stream", content_type = "text/event-stream", body = String),
        (status = 404, description = "No such job (`not_found`)", body = treemorph_api::ErrorBody),
    )
)]
pub async fn events(
    State(state): State<AppState>,
    owner: Owner,
    Path(id): Path<String>,
) -> Result<Sse<impl Stream<Item = Result<Event, Infallible>>>, ApiError> {
    let mut watcher = JobWatch::new(&state, &owner, &id);
    let row = super::jobs::find(&state, &owner, &id).await?;
    let (tx, rx) = mpsc::channel::<Event>(64);
    tokio::spawn(async move {
        let mut frames_sent = row.frames_ready;
        if tx.send(json_event("job", &row.info())).await.is_err() {
            return;
        }
        let mut last = row;
        loop {
            if let Some(end) = terminal_event(&last) {
                let _ = tx.send(end).await;
                return;
            }
            let Some(row) = watcher.next().await else {
                return;
            };
            let mut out = Vec::new();
            diff(&last, &row, &mut frames_sent, &mut out);
            for event in out {
                if tx.send(event).await.is_err() {
                    return;
                }
            }
            last = row;
        }
    });
    let stream =
        futures_util::stream::unfold(
            rx,
            |mut rx| async move { rx.recv().await.map(|e| (Ok(e), rx)) },
        );
    Ok(Sse::new(stream).keep_alive(KeepAlive::new().interval(Duration::from_secs(15))))
}
