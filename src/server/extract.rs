//! Extractors that fail with our uniform errors instead of axum's plain
//! text rejections, and small helpers shared by the handlers (cursors,
//! ETags, ranges).

use axum::extract::{FromRequest, FromRequestParts, Request};
use axum::http::request::Parts;
use axum::http::{HeaderMap, header};
use serde::de::DeserializeOwned;
use treemorph_api::ErrorCode;

use super::Owner;
use crate::error::ApiError;

impl<S: Send + Sync> FromRequestParts<S> for Owner {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, Self::Rejection> {
        parts
            .extensions
            .get::<Owner>()
            .cloned()
            .ok_or_else(|| ApiError::internal("route without the authentication layer"))
    }
}

/// A JSON body: 415 without `Content-Type: application/json`, 400
/// `invalid_json` for syntax errors, 422 `invalid_request` (naming the
/// field) for content errors, 413 past the body limit.
#[derive(Debug)]
pub struct ApiJson<T>(pub T);

impl<T: DeserializeOwned, S: Send + Sync> FromRequest<S> for ApiJson<T> {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, Self::Rejection> {
        let (value, _) = json_body::<T, S>(req, state).await?;
        Ok(ApiJson(value))
    }
}

/// Reads and parses a JSON body; returns the value and the raw bytes.
pub async fn json_body<T: DeserializeOwned, S: Send + Sync>(
    req: Request,
    state: &S,
) -> Result<(T, bytes::Bytes), ApiError> {
    if !is_json(req.headers()) {
        return Err(ApiError::new(
            ErrorCode::UnsupportedMediaType,
            "expected Content-Type: application/json",
        ));
    }
    let bytes = bytes::Bytes::from_request(req, state).await.map_err(|e| {
        if let Some(slow) = super::slow_body::is_too_slow(&e) {
            ApiError::new(ErrorCode::BodyTooSlow, slow.to_string())
        } else if e.status() == axum::http::StatusCode::PAYLOAD_TOO_LARGE {
            ApiError::new(ErrorCode::PayloadTooLarge, "the request body is too large")
        } else {
            ApiError::new(ErrorCode::InvalidJson, format!("cannot read the body: {e}"))
        }
    })?;
    let value = parse_json(&bytes)?;
    Ok((value, bytes))
}

/// Parses JSON with our error mapping. A value of the wrong kind is named
/// by its path (`options.schedule`), which serde's own message leaves out
/// for enums and nested fields.
pub fn parse_json<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, ApiError> {
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let value = serde_path_to_error::deserialize(&mut de).map_err(|e| {
        let path = e.path().to_string();
        let e = e.into_inner();
        match e.classify() {
            serde_json::error::Category::Data if path == "." => {
                ApiError::invalid(format!("invalid request: {e}"))
            }
            serde_json::error::Category::Data => {
                ApiError::invalid(format!("invalid request at `{path}`: {e}"))
            }
            _ => not_json(e),
        }
    })?;
    de.end().map_err(not_json)?;
    Ok(value)
}

fn not_json(e: serde_json::Error) -> ApiError {
    ApiError::new(
        ErrorCode::InvalidJson,
        format!("the body is not valid JSON: {e}"),
    )
}

fn is_json(headers: &HeaderMap) -> bool {
    media_type(headers).is_some_and(|m| m == "application/json")
}

/// The request's media type, lowercased, without parameters.
pub fn media_type(headers: &HeaderMap) -> Option<String> {
    let v = headers.get(header::CONTENT_TYPE)?.to_str().ok()?;
    Some(v.split(';').next()?.trim().to_ascii_lowercase())
}

/// Query parameters: 422 `invalid_request` when they do not parse.
#[derive(Debug)]
pub struct ApiQuery<T>(pub T);

impl<T: DeserializeOwned, S: Send + Sync> FromRequestParts<S> for ApiQuery<T> {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, Self::Rejection> {
        axum::extract::Query::<T>::try_from_uri(&parts.uri)
            .map(|q| ApiQuery(q.0))
            .map_err(|e| ApiError::invalid(format!("invalid query: {}", e.body_text())))
    }
}

/// Page sizes: default 20, at most 100.
pub fn page_limit(limit: Option<u32>) -> Result<u32, ApiError> {
    match limit {
        None => Ok(20),
        Some(n) if (1..=100).contains(&n) => Ok(n),
        Some(n) => Err(ApiError::invalid(format!(
            "limit must be in 1..=100, not {n}"
        ))),
    }
}

/// The shape of a cursor (documented in the OpenAPI document, so every
/// string a client can build from the schema is a valid position).
pub const CURSOR_PATTERN: &str = "^[0-9a-f]{45}$";

/// An opaque cursor for the position `(created_at, id)`: 13 hex digits of
/// the time, then the id.
pub fn encode_cursor(created_at: i64, id: &str) -> String {
    format!("{:013x}{id}", created_at.max(0))
}

/// Decodes a cursor from [`encode_cursor`]; 422 when it is not one.
pub fn decode_cursor(cursor: &str) -> Result<(i64, String), ApiError> {
    let bad = || ApiError::invalid("invalid cursor: pass a next_cursor unchanged");
    if cursor.len() != 45
        || !cursor
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
    {
        return Err(bad());
    }
    let (at, id) = cursor.split_at(13);
    let at = i64::from_str_radix(at, 16).map_err(|_| bad())?;
    Ok((at, id.to_owned()))
}

/// Checks a path id's shape (404 for anything that is not one of ours).
pub fn path_id(id: &str, what: &str) -> Result<(), ApiError> {
    if crate::store::is_id(id) {
        Ok(())
    } else {
        Err(ApiError::not_found(what))
    }
}

/// Whether `If-None-Match` matches `etag`.
pub fn not_modified(headers: &HeaderMap, etag: &str) -> bool {
    headers
        .get(header::IF_NONE_MATCH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.split(',').any(|t| t.trim() == etag || t.trim() == "*"))
}

/// A parsed `Range` header against a body of `len` bytes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RangeRequest {
    /// No (usable) range: send everything.
    Full,
    /// One satisfiable range, `start..end` (end exclusive).
    Partial(u64, u64),
    /// A syntactically valid range that selects nothing: 416.
    Unsatisfiable,
}

/// Parses a single `bytes=` range. Several ranges, other units and
/// malformed headers are ignored (the full body is sent, as RFC 9110
/// allows); a well-formed range outside the body is unsatisfiable.
pub fn parse_range(headers: &HeaderMap, len: u64) -> RangeRequest {
    let Some(value) = headers.get(header::RANGE).and_then(|v| v.to_str().ok()) else {
        return RangeRequest::Full;
    };
    let Some(spec) = value.trim().strip_prefix("bytes=") else {
        return RangeRequest::Full;
    };
    if spec.contains(',') {
        return RangeRequest::Full;
    }
    let Some((a, b)) = spec.trim().split_once('-') else {
        return RangeRequest::Full;
    };
    let (a, b) = (a.trim(), b.trim());
    if a.is_empty() {
        // Suffix range: the last n bytes.
        return match b.parse::<u64>() {
            Ok(0) => RangeRequest::Unsatisfiable,
            Ok(_) if len == 0 => RangeRequest::Unsatisfiable,
            Ok(n) => RangeRequest::Partial(len.saturating_sub(n), len),
            Err(_) => RangeRequest::Full,
        };
    }
    let Ok(start) = a.parse::<u64>() else {
        return RangeRequest::Full;
    };
    let end = if b.is_empty() {
        len
    } else {
        match b.parse::<u64>() {
            Ok(e) if e >= start => (e + 1).min(len),
            _ => return RangeRequest::Full,
        }
    };
    if start >= len {
        RangeRequest::Unsatisfiable
    } else {
        RangeRequest::Partial(start, end)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn range(v: &str, len: u64) -> RangeRequest {
        let mut h = HeaderMap::new();
        h.insert(header::RANGE, v.parse().unwrap());
        parse_range(&h, len)
    }

    #[test]
    fn ranges_parse() {
        assert_eq!(range("bytes=0-9", 100), RangeRequest::Partial(0, 10));
        assert_eq!(range("bytes=90-", 100), RangeRequest::Partial(90, 100));
        assert_eq!(range("bytes=-10", 100), RangeRequest::Partial(90, 100));
        assert_eq!(range("bytes=50-500", 100), RangeRequest::Partial(50, 100));
        assert_eq!(range("bytes=100-", 100), RangeRequest::Unsatisfiable);
        assert_eq!(range("bytes=-0", 100), RangeRequest::Unsatisfiable);
        assert_eq!(range("bytes=0-1,5-6", 100), RangeRequest::Full);
        assert_eq!(range("items=0-1", 100), RangeRequest::Full);
        assert_eq!(range("bytes=9-3", 100), RangeRequest::Full);
        assert_eq!(range("bytes=x-3", 100), RangeRequest::Full);
        assert_eq!(parse_range(&HeaderMap::new(), 5), RangeRequest::Full);
    }

    #[test]
    fn cursors_round_trip_and_garbage_is_refused() {
        let id = crate::store::new_id();
        let c = encode_cursor(1234, &id);
        assert_eq!(decode_cursor(&c).unwrap(), (1234, id));
        assert!(decode_cursor("garbage!").is_err());
        assert!(decode_cursor(&c.to_uppercase()).is_err());
        assert!(decode_cursor(&c[1..]).is_err());
        // Any string of the documented shape is a position.
        assert_eq!(
            decode_cursor(&"f".repeat(45)).unwrap().0,
            0xf_ffff_ffff_ffff
        );
    }
}
