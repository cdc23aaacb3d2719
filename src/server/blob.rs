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
    let Some(len) = blobs.size(key).await? else {
        return Err(ApiError::not_found(what));
    };
    let etag = etag_for(key);
    let mut builder = Response::builder()
        .header(header::ETAG, &etag)
        .header(header::ACCEPT_RANGES, "bytes")
        .header(
            header::CACHE_CONTROL,
            "private, max-age=31536000, immutable",
        );
    if not_modified(request, &etag) {
        return Ok(builder
            .status(StatusCode::NOT_MODIFIED)
            .body(Body::empty())
            .expect("valid response"));
    }
    let (status, range) = match parse_range(request, len) {
        RangeRequest::Full => (StatusCode::OK, None),
        RangeRequest::Partial(a, b) => {
            builder = builder.header(header::CONTENT_RANGE, format!("bytes {a}-{}/{len}", b - 1));
            (StatusCode::PARTIAL_CONTENT, Some(a..b))
        }
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
            return Ok(r);
        }
    };
    let length = range.as_ref().map_or(len, |r| r.end - r.start);
    let stream = blobs.stream(key, range).await?;
    Ok(builder
        .status(status)
        .header(header::CONTENT_TYPE, content_type)
        .header(header::CONTENT_LENGTH, length)
        .body(Body::from_stream(stream))
        .expect("valid response"))
}
