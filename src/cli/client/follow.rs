//! Following a job to its end through `GET /v1/jobs/{id}/events`.
//!
//! The server's events (see `src/server/events.rs`): `job` (the current
//! job document, always first), `stage` (`{"stage", "progress"}`),
//! `progress` (`{"progress"}`), `frame` (`{"index"}`), and one of `done`,
//! `failed`, `cancelled` carrying the final job document. Because the
//! first event of every connection is the whole current state, a
//! reconnection loses nothing: the client reconnects when the connection
//! drops (sending `Last-Event-ID` when the server gave ids) and carries
//! on from the fresh `job` event.
//!
//! Progress goes to stderr: an indicatif bar on a terminal, plain lines
//! (one per stage, one per tenth of progress) otherwise, so logs stay
//! readable and small.

use std::io::IsTerminal;
use std::time::Duration;

use anyhow::anyhow;
use indicatif::{ProgressBar, ProgressStyle};
use reqwest::Method;
use reqwest::header::{ACCEPT, CACHE_CONTROL};
use serde::Deserialize;
use treemorph_api::jobs::{JobInfo, JobStatus};

use super::EXIT_UNREACHABLE;
use super::api::{Api, failure, is_transient};
use super::sse::{SseEvent, SseParser};
use crate::cli::{EXIT_FAILURE, Failure};

/// Consecutive reconnections without a single event before giving up.
const MAX_RECONNECTS: u32 = 8;
/// First delay before reconnecting (doubles up to [`MAX_BACKOFF`]) unless
/// the server sent `retry:`.
const FIRST_BACKOFF: Duration = Duration::from_millis(250);
/// Longest delay between reconnections.
const MAX_BACKOFF: Duration = Duration::from_secs(8);

#[derive(Deserialize)]
struct StageEvent {
    stage: String,
    progress: f32,
}

#[derive(Deserialize)]
struct ProgressEvent {
    progress: f32,
}

#[derive(Deserialize)]
struct FrameEvent {
    index: u32,
}

/// Follows job `id` until it ends and returns its final document.
///
/// The first connection's errors are returned at once (unknown job, wrong
/// key, no server); later drops and transient failures (5xx, unreachable
/// while the server restarts) are retried with backoff.
pub async fn follow(api: &Api, id: &str) -> Result<JobInfo, Failure> {
    let url = api.v1(&["jobs", id, "events"])?;
    let mut display = Display::new(id);
    let mut last_id: Option<String> = None;
    let mut retry: Option<Duration> = None;
    let mut backoff = FIRST_BACKOFF;
    let mut fruitless = 0u32;
    let mut connected_before = false;
    loop {
        let mut request = api
            .request(Method::GET, url.clone())
            .header(ACCEPT, "text/event-stream")
            .header(CACHE_CONTROL, "no-cache");
        if let Some(last) = &last_id {
            request = request.header("Last-Event-ID", last);
        }
        let mut received = false;
        let dropped = match api.send(request).await {
            Ok(mut response) => {
                connected_before = true;
                let mut parser = SseParser::new();
                let mut events = Vec::new();
                let reason = loop {
                    let chunk = match response.chunk().await {
                        Ok(Some(chunk)) => chunk,
                        Ok(None) => break anyhow!("the event stream ended before the job did"),
                        Err(e) => break anyhow!(e).context("the event stream broke"),
                    };
                    if let Err(e) = parser.push(&chunk, &mut events) {
                        break anyhow!(e);
                    }
                    for event in events.drain(..) {
                        received = true;
                        match display.event(&event) {
                            Ok(None) => {}
                            Ok(Some(end)) => {
                                display.finish(&end);
                                return Ok(end);
                            }
                            Err(f) => {
                                display.abandon();
                                return Err(f);
                            }
                        }
                    }
                };
                last_id = parser.last_event_id().map(str::to_owned).or(last_id);
                retry = parser.retry().or(retry);
                failure(EXIT_UNREACHABLE, reason)
            }
            Err(f) if connected_before && is_transient(&f) => f,
            Err(f) => {
                display.abandon();
                return Err(f);
            }
        };
        if received {
            fruitless = 0;
            backoff = FIRST_BACKOFF;
        } else {
            fruitless += 1;
        }
        if fruitless > MAX_RECONNECTS {
            display.abandon();
            return Err(dropped);
        }
        display.note(&format!("{:#}; reconnecting", dropped.error));
        tokio::time::sleep(retry.unwrap_or(backoff)).await;
        backoff = (backoff * 2).min(MAX_BACKOFF);
    }
}

/// The failure of a job that ended without succeeding (exit code 1), with
/// the job's own error code and message.
pub fn job_failure(info: &JobInfo) -> Failure {
    let error = match &info.error {
        Some(e) => anyhow!("{}: {} (job {})", e.code, e.message, info.id),
        None => anyhow!(
            "{}: job {} {}",
            info.status.as_str(),
            info.id,
            info.status.as_str()
        ),
    };
    failure(EXIT_FAILURE, error)
}

/// Where progress goes.
enum Display {
    Bar {
        bar: ProgressBar,
        state: State,
    },
    Lines {
        state: State,
        /// The stage last printed.
        printed_stage: Option<String>,
        /// Tenths of progress last printed.
        printed_tenth: Option<u32>,
    },
}

/// What is known about the job.
struct State {
    id: String,
    /// Shown until the job has a stage.
    status: JobStatus,
    stage: Option<String>,
    progress: f32,
    frames: u32,
    frames_ready: u32,
}

impl State {
    fn summary(&self) -> String {
        let stage = self.stage.as_deref().unwrap_or(self.status.as_str());
        if self.frames > 0 {
            format!("{stage}, {}/{} frames", self.frames_ready, self.frames)
        } else {
            stage.to_owned()
        }
    }
}

impl Display {
    fn new(id: &str) -> Display {
        let state = State {
            id: id.to_owned(),
            status: JobStatus::Queued,
            stage: None,
            progress: 0.0,
            frames: 0,
            frames_ready: 0,
        };
        if std::io::stderr().is_terminal() {
            let bar = ProgressBar::new(1000);
            bar.set_style(
                // `wide_bar` fits the terminal's width: a line that wraps
                // is redrawn as two and scrolls.
                ProgressStyle::with_template("{msg:<24} [{wide_bar}] {percent:>3}%")
                    .expect("the template is valid")
                    .progress_chars("=> "),
            );
            bar.enable_steady_tick(Duration::from_millis(200));
            Display::Bar { bar, state }
        } else {
            Display::Lines {
                state,
                printed_stage: None,
                printed_tenth: None,
            }
        }
    }

    fn state(&mut self) -> &mut State {
        match self {
            Display::Bar { state, .. } | Display::Lines { state, .. } => state,
        }
    }

    /// Applies an event; `Some(final document)` when the job ended.
    fn event(&mut self, event: &SseEvent) -> Result<Option<JobInfo>, Failure> {
        let bad = |e: serde_json::Error| {
            failure(
                EXIT_FAILURE,
                anyhow!("unexpected `{}` event from the server: {e}", event.event),
            )
        };
        let state = self.state();
        match event.event.as_str() {
            "job" => {
                let info: JobInfo = serde_json::from_str(&event.data).map_err(bad)?;
                state.status = info.status;
                state.stage = info.stage.clone().or(state.stage.take());
                state.progress = info.progress;
                state.frames = info.frames;
                state.frames_ready = info.frames_ready;
                if info.status.is_terminal() {
                    // The terminal event follows; nothing to draw yet.
                    return Ok(None);
                }
            }
            "stage" => {
                let e: StageEvent = serde_json::from_str(&event.data).map_err(bad)?;
                state.stage = Some(e.stage);
                state.progress = e.progress;
            }
            "progress" => {
                let e: ProgressEvent = serde_json::from_str(&event.data).map_err(bad)?;
                state.progress = e.progress;
            }
            "frame" => {
                let e: FrameEvent = serde_json::from_str(&event.data).map_err(bad)?;
                state.frames_ready = state.frames_ready.max(e.index + 1);
            }
            "done" | "failed" | "cancelled" => {
                let info: JobInfo = serde_json::from_str(&event.data).map_err(bad)?;
                return Ok(Some(info));
            }
            // Events a newer server may add.
            _ => return Ok(None),
        }
        self.draw();
        Ok(None)
    }

    fn draw(&mut self) {
        match self {
            Display::Bar { bar, state } => {
                bar.set_position((state.progress.clamp(0.0, 1.0) * 1000.0) as u64);
                bar.set_message(state.summary());
            }
            Display::Lines {
                state,
                printed_stage,
                printed_tenth,
            } => {
                let tenth = (state.progress.clamp(0.0, 1.0) * 10.0).floor() as u32;
                let stage_changed = state.stage.is_some() && *printed_stage != state.stage;
                if stage_changed || Some(tenth) > *printed_tenth {
                    eprintln!(
                        "job {}: {} ({:.0}%)",
                        state.id,
                        state.summary(),
                        state.progress * 100.0
                    );
                    printed_stage.clone_from(&state.stage);
                    *printed_tenth = Some(tenth);
                }
            }
        }
    }

    /// A message about the connection.
    fn note(&self, message: &str) {
        match self {
            Display::Bar { bar, .. } => bar.println(message),
            Display::Lines { .. } => eprintln!("{message}"),
        }
    }

    fn finish(&mut self, info: &JobInfo) {
        if let Display::Bar { bar, .. } = self {
            bar.finish_and_clear();
        }
        let how = match (&info.status, &info.result, &info.error) {
            (JobStatus::Succeeded, Some(result), _) => format!(" ({} frames)", result.frames),
            (_, _, Some(e)) => format!(" ({}: {})", e.code, e.message),
            _ => String::new(),
        };
        eprintln!("job {}: {}{how}", info.id, info.status.as_str());
    }

    fn abandon(&self) {
        if let Display::Bar { bar, .. } = self {
            bar.finish_and_clear();
        }
    }
}
