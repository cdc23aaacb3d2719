//! Serving immutable blobs: strong ETags (keys never change content: tree
//! files are written once, job outputs live under their attempt's token),
//! `If-None-Match` → 304, and single `Range` requests → 206 / 416.

use axum::body::Body;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::Response;
use treemorph_api::ErrorCode;

use super::extract::{RangeRequest, not_modified, parse_range};
use crate::error::ApiError;
use crate::store::Blobs;

/// A strong ETag derived from a blob key (content-addressed in effect,
/// since a key is never overwritten with different bytes).
pub fn etag_for(key: &str) -> String {
    use sha2::Digest;
    let d = sha2::Sha256::digest(key.as_bytes());
    let hex: String = d[..12].iter().map(|b| format!("{b:02x}")).collect();
    format!("\"{hex}\"")
}

/// Serves the blob `key` (404 `not_found` naming `what` when missing).
pub async fn serve(
    blobs: &Blobs,
    key: &str,
    content_type: &'static str,
    request: &HeaderMap,
    what: &str,
) -> Result<Response, ApiError> {
    serve_if_stored(blobs, key, content_type, request)
        .await?
        .ok_or_else(|| ApiError::not_found(what))
}

/// Serves the blob `key`, or `None` when it is not stored (for outputs
/// that are rendered when not stored).
pub async fn serve_if_stored(
    blobs: &Blobs,
    key: &str,
    content_type: &'static str,
    request: &HeaderMap,
) -> Result<Option<Response>, ApiError> {
    let Some(len) = blobs.size(key).await? else {
        return Ok(None);
    };
    let (builder, range) = match plan(key, request, len) {
        Planned::Send(builder, range) => (builder, range),
        Planned::Done(response) => return Ok(Some(response)),
    };
    let length = range.as_ref().map_or(len, |r| r.end - r.start);
    let stream = blobs.stream(key, range).await?;
    Ok(Some(
        builder
            .header(header::CONTENT_TYPE, content_type)
            .header(header::CONTENT_LENGTH, length)
            .body(Body::from_stream(stream))
            .expect("valid response"),
    ))
}

/// Serves `bytes` made on request under the ETag of `key` (a render is a
/// deterministic function of its key), with the same 304 and single-range
/// answers as a stored blob.
pub fn serve_bytes(
    key: &str,
    content_type: &'static str,
    request: &HeaderMap,
    bytes: bytes::Bytes,
) -> Response {
    let len = bytes.len() as u64;
    let (builder, range) = match plan(key, request, len) {
        Planned::Send(builder, range) => (builder, range),
        Planned::Done(response) => return response,
    };
    let body = match range {
        Some(r) => bytes.slice(r.start as usize..r.end as usize),
        None => bytes,
    };
    builder
        .header(header::CONTENT_TYPE, content_type)
        .body(Body::from(body))
        .expect("valid response")
}

/// What to answer for a body of `len` bytes under `key`'s ETag.
enum Planned {
    /// Send the body (or this range of it) with these headers.
    Send(axum::http::response::Builder, Option<std::ops::Range<u64>>),
    /// Answer this without a body (304, 416).
    Done(Response),
}

fn plan(key: &str, request: &HeaderMap, len: u64) -> Planned {
    let etag = etag_for(key);
    let builder = Response::builder()
        .header(header::ETAG, &etag)
        .header(header::ACCEPT_RANGES, "bytes")
        .header(
            header::CACHE_CONTROL,
            "private, max-age=31536000, immutable",
        );
    if not_modified(request, &etag) {
        return Planned::Done(
            builder
                .status(StatusCode::NOT_MODIFIED)
                .body(Body::empty())
                .expect("valid response"),
        );
    }
    match parse_range(request, len) {
        RangeRequest::Full => Planned::Send(builder.status(StatusCode::OK), None),
        RangeRequest::Partial(a, b) => Planned::Send(
            builder
                .status(StatusCode::PARTIAL_CONTENT)
                .header(header::CONTENT_RANGE, format!("bytes {a}-{}/{len}", b - 1)),
            Some(a..b),
        ),
        RangeRequest::Unsatisfiable => {
            let e = ApiError::new(
                ErrorCode::RangeNotSatisfiable,
                format!("the range is outside the {len}-byte body"),
            );
            let mut r = axum::response::IntoResponse::into_response(e);
            r.headers_mut().insert(
                header::CONTENT_RANGE,
                HeaderValue::from_str(&format!("bytes */{len}")).expect("ascii"),
            );
            Planned::Done(r)
        }
    }
}
