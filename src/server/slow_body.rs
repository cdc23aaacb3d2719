//! Slow-body protection: every request body must keep arriving.
//!
//! The header-read timeout (hyper) cuts off clients that send their
//! headers slowly; this guard does the same for bodies, which hyper reads
//! only as the handler asks. A body is refused (`408 body_too_slow`) when
//! no byte arrives for `idle` (the header timeout), or when, once `grace`
//! (also the header timeout) has passed, fewer than `min_rate` bytes per
//! second have arrived on average since the request started. The average
//! (not the rate of the last read) is what an attacker dribbling a byte
//! every few seconds cannot keep up, while a legitimate client on a slow
//! link (a kilobyte per second is a 1990s modem) is never refused. The
//! same rule is Apache's `mod_reqtimeout` `MinRate`.
//!
//! Written by hand: tower-http's timeouts bound a whole request or the
//! gap between body frames, not an average rate.

use std::time::Duration;

use axum::body::Body;
use axum::extract::Request;
use axum::middleware::Next;
use axum::response::Response;
use futures_util::StreamExt;
use tokio::time::Instant;

/// The guard's limits.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Longest gap between two pieces of a body.
    pub idle: Duration,
    /// Time before the average rate is enforced.
    pub grace: Duration,
    /// Least average rate after `grace`, in bytes per second.
    pub min_rate: u64,
}

/// The error a too-slow body ends with; handlers find it in the source
/// chain of their body error (see [`is_too_slow`]).
#[derive(Debug, thiserror::Error)]
#[error("the request body arrived too slowly: {0}")]
pub struct BodyTooSlow(pub String);

/// Whether `error` (or anything in its source chain) is [`BodyTooSlow`].
pub fn is_too_slow<'a>(error: &'a (dyn std::error::Error + 'static)) -> Option<&'a BodyTooSlow> {
    let mut next = Some(error);
    while let Some(e) = next {
        if let Some(slow) = e.downcast_ref::<BodyTooSlow>() {
            return Some(slow);
        }
        next = e.source();
    }
    None
}

/// When the body must have delivered more: the earlier of the idle
/// deadline and the moment the average rate falls under the minimum.
fn deadline(limits: &Limits, started: Instant, last: Instant, received: u64) -> Instant {
    let idle = last + limits.idle;
    if limits.min_rate == 0 {
        return idle;
    }
    let allowed = Duration::from_secs_f64(received as f64 / limits.min_rate as f64);
    idle.min(started + limits.grace.max(allowed))
}

/// Wraps `body` in the guard.
pub fn guard(body: Body, limits: Limits) -> Body {
    let started = Instant::now();
    let state = (body.into_data_stream(), started, 0u64, false);
    let stream =
        futures_util::stream::unfold(state, move |(mut inner, last, received, done)| async move {
            if done {
                return None;
            }
            let until = deadline(&limits, started, last, received);
            match tokio::time::timeout_at(until, inner.next()).await {
                Ok(Some(Ok(chunk))) => {
                    let received = received + chunk.len() as u64;
                    Some((Ok(chunk), (inner, Instant::now(), received, false)))
                }
                Ok(Some(Err(e))) => {
                    Some((Err(axum::BoxError::from(e)), (inner, last, received, true)))
                }
                Ok(None) => None,
                Err(_) => {
                    let elapsed = started.elapsed().as_secs_f64();
                    let why = if Instant::now() >= last + limits.idle {
                        format!("nothing arrived for {} s", limits.idle.as_secs())
                    } else {
                        format!(
                            "{received} bytes in {elapsed:.0} s, under the minimum of {} bytes/s",
                            limits.min_rate
                        )
                    };
                    tracing::info!(%why, "slow request body cut off");
                    Some((
                        Err(axum::BoxError::from(BodyTooSlow(why))),
                        (inner, last, received, true),
                    ))
                }
            }
        });
    Body::from_stream(stream)
}

/// Whether `request` may have a body: it declares a length or a
/// transfer encoding.
pub fn has_body(request: &Request) -> bool {
    let headers = request.headers();
    headers.contains_key(axum::http::header::CONTENT_LENGTH)
        || headers.contains_key(axum::http::header::TRANSFER_ENCODING)
}

/// Middleware: guards the body of every request that may have one.
pub async fn layer(limits: Limits, request: Request, next: Next) -> Response {
    if !has_body(&request) {
        return next.run(request).await;
    }
    let (parts, body) = request.into_parts();
    next.run(Request::from_parts(parts, guard(body, limits)))
        .await
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> Limits {
        Limits {
            idle: Duration::from_secs(10),
            grace: Duration::from_secs(10),
            min_rate: 1000,
        }
    }

    #[tokio::test(start_paused = true)]
    async fn a_prompt_body_passes_whole() {
        let body = guard(Body::from(vec![7u8; 100_000]), limits());
        let bytes = axum::body::to_bytes(body, usize::MAX).await.unwrap();
        assert_eq!(bytes.len(), 100_000);
    }

    /// A body that sends `chunk` bytes every `every`, `n` times.
    fn dribble(chunk: usize, every: Duration, n: usize) -> Body {
        let s = futures_util::stream::iter(0..n).then(move |_| async move {
            tokio::time::sleep(every).await;
            Ok::<_, std::io::Error>(bytes::Bytes::from(vec![1u8; chunk]))
        });
        Body::from_stream(s)
    }

    async fn outcome(body: Body) -> Result<usize, String> {
        let guarded = guard(body, limits());
        match axum::body::to_bytes(guarded, usize::MAX).await {
            Ok(b) => Ok(b.len()),
            Err(e) => match is_too_slow(&e) {
                Some(slow) => Err(slow.0.clone()),
                None => panic!("another error: {e}"),
            },
        }
    }

    #[tokio::test(start_paused = true)]
    async fn a_stalled_body_is_cut_off_after_the_idle_time() {
        let err = outcome(dribble(10, Duration::from_secs(11), 3))
            .await
            .unwrap_err();
        assert!(err.contains("nothing arrived for 10 s"), "{err}");
    }

    #[tokio::test(start_paused = true)]
    async fn a_dribbling_body_is_cut_off_by_the_average_rate() {
        // 10 bytes every 2 s: never idle for 10 s, but 5 bytes/s.
        let err = outcome(dribble(10, Duration::from_secs(2), 100))
            .await
            .unwrap_err();
        assert!(err.contains("under the minimum"), "{err}");
    }

    #[tokio::test(start_paused = true)]
    async fn a_slow_but_steady_body_passes() {
        // 2 KB every second for 30 s: slow, over the minimum rate.
        assert_eq!(
            outcome(dribble(2000, Duration::from_secs(1), 30)).await,
            Ok(60_000)
        );
    }
}
