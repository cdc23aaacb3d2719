//! Renders sent while they are made: a succeeded job's re-sampled delta
//! stream (`GET /v1/jobs/{id}/stream?frames=N`), the first time it is
//! asked for.
//!
//! # Choices
//! - **Records as the runner makes them.** A delta stream is a header
//!   record, one record a frame and an end record: the pieces a runner
//!   hands its sink, in that order. The first request for a stream that no
//!   cache holds is answered with each piece as soon as it is made
//!   (chunked), not after the whole run. Its ETag is sent first: a render
//!   is a deterministic function of its key, so the ETag does not wait for
//!   the bytes.
//! - **Requests that come while it renders join it**
//!   ([`super::renders::RenderCache::live`]): each is sent every piece
//!   made so far, then the rest as it comes. The render runs once.
//! - **Kept when complete.** The whole stream enters the render cache only
//!   after its end record, as every render does. A render that fails, or
//!   a process that dies, caches nothing, and the responses it was feeding
//!   end without an end record, which tells a client the stream is
//!   incomplete (as a running job's stream does when the job fails). A
//!   render that fails before its first piece is answered with its error
//!   (410 `plan_outdated` when the job's plan and trees are gone).
//! - **It runs to the end** when its clients go away, on the blocking pool
//!   like every render: the cache then has it for the next request.
//! - A request with a `Range` header (whose answer needs the length) or a
//!   matching `If-None-Match` takes the whole-file path, which waits for
//!   a stream rendering here instead of rendering it again.
//!
//! Hand-written: a broadcast whose late subscribers also get what was sent
//! before they came (tokio's `broadcast` drops what a receiver missed).

use std::sync::{Arc, Mutex, MutexGuard};

use axum::body::Body;
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::Response;
use bytes::Bytes;
use tokio::sync::watch;

use super::blob;
use crate::error::ApiError;
use crate::pipeline::{FrameOutput, JobSink, SinkError};

/// A render in progress: the pieces made so far and, once it is over,
/// the whole file or why there is none.
#[derive(Debug)]
pub struct Live {
    pieces: Mutex<Pieces>,
    /// Bumped on every change, to wake the responses waiting for one.
    changed: watch::Sender<()>,
}

#[derive(Debug, Default)]
struct Pieces {
    chunks: Vec<Bytes>,
    /// Bytes in `chunks`.
    len: usize,
    end: Option<Result<Bytes, ApiError>>,
}

/// What a response gets next.
enum Next {
    Chunk(Bytes),
    End,
    Wait,
}

impl Live {
    /// A render that has made nothing yet.
    pub fn new() -> Arc<Live> {
        Arc::new(Live {
            pieces: Mutex::new(Pieces::default()),
            changed: watch::Sender::new(()),
        })
    }

    fn pieces(&self) -> MutexGuard<'_, Pieces> {
        // A poisoned lock means a panic while pushing a chunk, which
        // leaves the pieces consistent.
        self.pieces.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Adds a piece and wakes the responses.
    fn push(&self, chunk: Bytes) {
        {
            let mut p = self.pieces();
            p.len += chunk.len();
            p.chunks.push(chunk);
        }
        self.changed.send_replace(());
    }

    /// Ends the render: with the whole file, whatever it holds past the
    /// pieces sent (the end record) is the last piece; with an error the
    /// responses end where they are.
    pub fn end(&self, whole: Result<Bytes, ApiError>) {
        {
            let mut p = self.pieces();
            if let Ok(all) = &whole {
                if continues(&p.chunks, all) {
                    let tail = all.slice(p.len..);
                    if !tail.is_empty() {
                        p.len += tail.len();
                        p.chunks.push(tail);
                    }
                } else {
                    tracing::error!(
                        "a streamed render's file differs from the pieces it sent; its responses end short"
                    );
                }
            }
            p.end = Some(whole);
        }
        self.changed.send_replace(());
    }

    fn next(&self, index: usize) -> Next {
        let p = self.pieces();
        match (p.chunks.get(index), &p.end) {
            (Some(chunk), _) => Next::Chunk(chunk.clone()),
            (None, Some(_)) => Next::End,
            (None, None) => Next::Wait,
        }
    }

    /// Waits for the first piece; the render's error when it ended
    /// without one.
    pub async fn started(&self) -> Result<(), ApiError> {
        let started = self
            .wait_for(|p| match &p.end {
                _ if !p.chunks.is_empty() => Some(Ok(())),
                Some(Err(e)) => Some(Err(e.clone())),
                Some(Ok(_)) => Some(Ok(())),
                None => None,
            })
            .await;
        started.unwrap_or(Ok(()))
    }

    /// Waits for the end: the whole file, or the render's error.
    pub async fn finished(&self) -> Result<Bytes, ApiError> {
        let end = self.wait_for(|p| p.end.clone()).await;
        end.unwrap_or_else(|| Err(ApiError::internal("a render ended without a result")))
    }

    /// Waits until `ready` finds what it looks for in the pieces; `None`
    /// when the render is gone without it.
    async fn wait_for<T>(&self, mut ready: impl FnMut(&Pieces) -> Option<T>) -> Option<T> {
        // Subscribed before the first look, so a change between the look
        // and the wait still wakes it.
        let mut rx = self.changed.subscribe();
        loop {
            // The lock is let go before the wait.
            let found = ready(&self.pieces());
            if found.is_some() {
                return found;
            }
            rx.changed().await.ok()?;
        }
    }

    /// A response body: every piece from the first, then each new one,
    /// until the render ends.
    fn body(self: Arc<Self>) -> Body {
        let rx = self.changed.subscribe();
        let pieces =
            futures_util::stream::unfold((self, rx, 0usize), |(live, mut rx, at)| async move {
                loop {
                    match live.next(at) {
                        Next::Chunk(chunk) => {
                            return Some((Ok::<_, std::io::Error>(chunk), (live, rx, at + 1)));
                        }
                        Next::End => return None,
                        Next::Wait => {
                            if rx.changed().await.is_err() {
                                return None;
                            }
                        }
                    }
                }
            });
        Body::from_stream(pieces)
    }
}

/// Whether `all` starts with the bytes of `chunks`.
fn continues(chunks: &[Bytes], all: &[u8]) -> bool {
    let mut at = 0;
    chunks.iter().all(|c| {
        let ok = all.get(at..at + c.len()) == Some(&c[..]);
        at += c.len();
        ok
    })
}

/// Whether a request is answered from a render as it is made: not when it
/// asks for a range or already holds the file (`If-None-Match`).
pub fn applies(request: &HeaderMap, key: &str) -> bool {
    !request.contains_key(header::RANGE)
        && !super::extract::not_modified(request, &blob::etag_for(key))
}

/// The response that streams `live`, whose render is `key`'s.
pub fn response(key: &str, content_type: &'static str, live: Arc<Live>) -> Response {
    Response::builder()
        .status(StatusCode::OK)
        .header(header::CONTENT_TYPE, content_type)
        .header(header::ETAG, blob::etag_for(key))
        .header(
            header::CACHE_CONTROL,
            "private, max-age=31536000, immutable",
        )
        .header("x-accel-buffering", "no")
        .body(live.body())
        .expect("valid response")
}

/// The sink of a streamed run: the stream's records go to `live` as they
/// are made; the whole `stream.tmd` is kept for the cache.
pub struct LiveSink {
    live: Arc<Live>,
    whole: Option<Vec<u8>>,
}

impl LiveSink {
    /// A sink feeding `live`.
    pub fn new(live: Arc<Live>) -> LiveSink {
        LiveSink { live, whole: None }
    }

    /// The whole stream the run wrote, if it wrote one.
    pub fn into_whole(self) -> Option<Vec<u8>> {
        self.whole
    }
}

impl JobSink for LiveSink {
    fn stage(&mut self, _stage: &'static str, _progress: f32) {}

    fn cancelled(&self) -> bool {
        false
    }

    fn stream_header(&mut self, bytes: Vec<u8>) -> Result<(), SinkError> {
        self.live.push(Bytes::from(bytes));
        Ok(())
    }

    fn frame(&mut self, frame: FrameOutput) -> Result<(), SinkError> {
        self.live.push(Bytes::from(frame.delta));
        Ok(())
    }

    fn file(&mut self, name: &str, bytes: Vec<u8>) -> Result<(), SinkError> {
        if name == "stream.tmd" {
            self.whole = Some(bytes);
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "streamed_tests.rs"]
mod tests;
