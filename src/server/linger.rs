//! Lingering reads: a body the handler stopped reading is read on, and
//! thrown away, for a short while after the answer.
//!
//! When a handler answers before the body has ended (a 413 for an upload
//! over the limit, an error found in the headers) and the connection is
//! closed with the client's unread bytes still in the server's socket
//! buffer, the kernel resets the connection. The reset discards the
//! answer at the client, which sees a broken pipe instead of our error
//! (a client on the same host saw it on every second endless upload).
//! Reading on for [`LINGER`] gives the client time to receive the answer,
//! as nginx's `lingering_close` does; [`MAX_DISCARD`] bounds the bytes and
//! the slow-body guard still ends a body that stalls.
//!
//! Written by hand: neither hyper nor tower-http linger on close.

use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use axum::body::{Body, BodyDataStream};
use axum::extract::Request;
use axum::middleware::Next;
use axum::response::Response;
use futures_util::{Stream, StreamExt};

/// How long an abandoned body is read on.
pub const LINGER: Duration = Duration::from_secs(2);
/// How many bytes of an abandoned body are read, at most.
pub const MAX_DISCARD: u64 = 1 << 30;

/// A body stream that, dropped before its end, is drained in the
/// background instead.
struct Lingering {
    inner: Option<BodyDataStream>,
    ended: bool,
}

impl Stream for Lingering {
    type Item = Result<bytes::Bytes, axum::Error>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        let Some(inner) = self.inner.as_mut() else {
            return Poll::Ready(None);
        };
        let next = inner.poll_next_unpin(cx);
        if matches!(next, Poll::Ready(None | Some(Err(_)))) {
            self.ended = true;
        }
        next
    }
}

impl Drop for Lingering {
    fn drop(&mut self) {
        let Some(inner) = self.inner.take() else {
            return;
        };
        if self.ended {
            return;
        }
        if let Ok(runtime) = tokio::runtime::Handle::try_current() {
            runtime.spawn(discard(inner));
        }
    }
}

/// Reads and drops what is left of a body, within [`LINGER`] and
/// [`MAX_DISCARD`].
async fn discard(mut rest: BodyDataStream) {
    let mut read = 0u64;
    let drain = async {
        while let Some(Ok(chunk)) = rest.next().await {
            read += chunk.len() as u64;
            if read > MAX_DISCARD {
                break;
            }
        }
    };
    let _ = tokio::time::timeout(LINGER, drain).await;
}

/// Wraps `body` so that an early answer reaches its client.
pub fn lingering(body: Body) -> Body {
    Body::from_stream(Lingering {
        inner: Some(body.into_data_stream()),
        ended: false,
    })
}

/// Middleware: every request that may have a body gets a lingering one.
pub async fn layer(request: Request, next: Next) -> Response {
    if !super::slow_body::has_body(&request) {
        return next.run(request).await;
    }
    let (parts, body) = request.into_parts();
    next.run(Request::from_parts(parts, lingering(body))).await
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A body of `n` chunks that counts how many were read.
    fn counted(n: usize, read: Arc<AtomicUsize>) -> Body {
        let s = futures_util::stream::iter(0..n).map(move |_| {
            read.fetch_add(1, Ordering::SeqCst);
            Ok::<_, std::io::Error>(bytes::Bytes::from_static(b"0123456789"))
        });
        Body::from_stream(s)
    }

    #[tokio::test]
    async fn an_abandoned_body_is_read_to_its_end_in_the_background() {
        let read = Arc::new(AtomicUsize::new(0));
        let mut stream = lingering(counted(1000, read.clone())).into_data_stream();
        stream.next().await.unwrap().unwrap();
        drop(stream);
        tokio::time::timeout(LINGER, async {
            while read.load(Ordering::SeqCst) < 1000 {
                tokio::task::yield_now().await;
            }
        })
        .await
        .expect("the rest of the body was read");
    }

    #[tokio::test]
    async fn a_body_read_to_its_end_passes_whole() {
        let read = Arc::new(AtomicUsize::new(0));
        let body = lingering(counted(10, read.clone()));
        let bytes = axum::body::to_bytes(body, usize::MAX).await.unwrap();
        assert_eq!(bytes.len(), 100);
    }
}
