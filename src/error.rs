//! [`ApiError`]: every failure of a handler, turned into the uniform body
//! `{"error": {"code", "message"}}` with the status from the code table
//! ([`treemorph_api::ErrorCode::status`]).
//!
//! Server-side failures (database, blob store, bugs) keep their cause for
//! the log and answer with an opaque message, so internals never leak to
//! clients.

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use treemorph_api::{ErrorBody, ErrorCode};

/// An API error.
#[derive(Clone, Debug)]
pub struct ApiError {
    /// The code (decides the status).
    pub code: ErrorCode,
    /// The message sent to the client.
    pub message: String,
    /// Seconds for a `Retry-After` header (429, 503).
    pub retry_after: Option<u64>,
    /// The logged cause of a 5xx.
    pub cause: Option<String>,
}

impl ApiError {
    /// An error with a message for the client.
    pub fn new(code: ErrorCode, message: impl Into<String>) -> ApiError {
        ApiError {
            code,
            message: message.into(),
            retry_after: None,
            cause: None,
        }
    }

    /// 404 `not_found`.
    pub fn not_found(what: &str) -> ApiError {
        ApiError::new(ErrorCode::NotFound, format!("no such {what}"))
    }

    /// 422 `invalid_request`.
    pub fn invalid(message: impl Into<String>) -> ApiError {
        ApiError::new(ErrorCode::InvalidRequest, message)
    }

    /// 500 `internal`, logging `cause`.
    pub fn internal(cause: impl std::fmt::Display) -> ApiError {
        ApiError {
            code: ErrorCode::Internal,
            message: "internal error".into(),
            retry_after: None,
            cause: Some(cause.to_string()),
        }
    }

    /// 503 `unavailable`, logging `cause`.
    pub fn unavailable(cause: impl std::fmt::Display) -> ApiError {
        ApiError {
            code: ErrorCode::Unavailable,
            message: "service temporarily unavailable".into(),
            retry_after: Some(1),
            cause: Some(cause.to_string()),
        }
    }

    /// Adds a `Retry-After` header.
    pub fn retry_after(mut self, seconds: u64) -> ApiError {
        self.retry_after = Some(seconds.max(1));
        self
    }

    /// 507 `insufficient_storage`, logging `cause`: a full disk is the
    /// operator's to fix, and retrying at once does not help.
    pub fn storage_full(cause: impl std::fmt::Display) -> ApiError {
        ApiError {
            code: ErrorCode::InsufficientStorage,
            message: "the server's storage is full; nothing was stored".into(),
            retry_after: None,
            cause: Some(cause.to_string()),
        }
    }

    /// A local file operation failed: 507 on a full disk, else 500.
    pub fn io(e: std::io::Error) -> ApiError {
        if is_storage_full(&e) {
            ApiError::storage_full(e)
        } else {
            ApiError::internal(e)
        }
    }

    /// The HTTP status.
    pub fn status(&self) -> StatusCode {
        StatusCode::from_u16(self.code.status()).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR)
    }
}

impl std::fmt::Display for ApiError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.code, self.message)
    }
}

/// Whether `error` or anything in its source chain is an I/O error of a
/// full disk (`ENOSPC`) or an exhausted disk quota (`EDQUOT`).
pub fn is_storage_full(error: &(dyn std::error::Error + 'static)) -> bool {
    let mut next = Some(error);
    while let Some(e) = next {
        if let Some(io) = e.downcast_ref::<std::io::Error>()
            && (io.kind() == std::io::ErrorKind::StorageFull
                || io.kind() == std::io::ErrorKind::QuotaExceeded)
        {
            return true;
        }
        next = e.source();
    }
    false
}

/// Whether the database refused a write because its disk is full (SQLite
/// `SQLITE_FULL`, PostgreSQL `disk_full`).
fn database_full(e: &sqlx::Error) -> bool {
    e.as_database_error()
        .and_then(|d| d.code())
        .is_some_and(|code| code == "13" || code == "53100")
}

impl From<sqlx::Error> for ApiError {
    fn from(e: sqlx::Error) -> ApiError {
        if database_full(&e) || is_storage_full(&e) {
            return ApiError::storage_full(format!("database: {e}"));
        }
        match e {
            sqlx::Error::PoolTimedOut | sqlx::Error::Io(_) | sqlx::Error::PoolClosed => {
                ApiError::unavailable(format!("database: {e}"))
            }
            other => ApiError::internal(format!("database: {other}")),
        }
    }
}

impl From<crate::pipeline::JobError> for ApiError {
    /// A job refused before it was queued: the caller's mistakes keep their
    /// code and message; anything else is the server's (its message is
    /// already opaque, and its cause was logged where it arose).
    fn from(e: crate::pipeline::JobError) -> ApiError {
        if e.code.is_client_error() {
            ApiError::new(e.code, e.message)
        } else {
            ApiError::internal(e)
        }
    }
}

impl From<crate::store::BlobError> for ApiError {
    fn from(e: crate::store::BlobError) -> ApiError {
        if is_storage_full(&e) {
            ApiError::storage_full(e)
        } else {
            ApiError::unavailable(e)
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = self.status();
        if status.is_server_error() {
            tracing::error!(code = %self.code, cause = self.cause.as_deref().unwrap_or(""), "request failed");
        }
        // 5xx messages are fixed strings by construction (see
        // `internal`/`unavailable`); the cause went to the log above.
        let mut response =
            (status, axum::Json(ErrorBody::new(self.code, self.message))).into_response();
        if let Some(s) = self.retry_after {
            response
                .headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from(s));
        }
        response
    }
}

/// The error code for a status produced outside our handlers (axum's own
/// rejections, timeouts), used to give those responses the uniform body.
pub fn code_for_status(status: StatusCode) -> ErrorCode {
    match status.as_u16() {
        400 => ErrorCode::InvalidJson,
        401 => ErrorCode::Unauthorized,
        404 => ErrorCode::NotFound,
        405 => ErrorCode::MethodNotAllowed,
        408 | 504 => ErrorCode::Timeout,
        413 => ErrorCode::PayloadTooLarge,
        415 => ErrorCode::UnsupportedMediaType,
        416 => ErrorCode::RangeNotSatisfiable,
        422 => ErrorCode::InvalidRequest,
        429 => ErrorCode::RateLimited,
        503 => ErrorCode::Unavailable,
        s if (400..500).contains(&s) => ErrorCode::InvalidRequest,
        _ => ErrorCode::Internal,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn server_errors_are_opaque() {
        let e = ApiError::internal("secret path /var/lib/x");
        assert_eq!(e.status(), StatusCode::INTERNAL_SERVER_ERROR);
        assert!(!e.message.contains("secret"));
        let r = ApiError::new(ErrorCode::QueueFull, "full")
            .retry_after(3)
            .into_response();
        assert_eq!(r.status(), StatusCode::TOO_MANY_REQUESTS);
        assert_eq!(r.headers()[header::RETRY_AFTER], "3");
    }

    /// A full disk (here `/dev/full`, which answers every write with
    /// `ENOSPC`) is 507 `insufficient_storage` from a spool write and from
    /// the blob store, not 503 or 500; other I/O errors stay 500/503.
    #[test]
    fn a_full_disk_is_insufficient_storage() {
        use std::io::Write;
        let full = std::fs::OpenOptions::new()
            .write(true)
            .open("/dev/full")
            .unwrap()
            .write_all(&[0; 4096])
            .unwrap_err();
        assert_eq!(full.kind(), std::io::ErrorKind::StorageFull);
        let blob = |e: std::io::Error| {
            ApiError::from(crate::store::BlobError(object_store::Error::Generic {
                store: "LocalFileSystem",
                source: Box::new(e),
            }))
        };
        let same = || std::io::Error::from_raw_os_error(full.raw_os_error().unwrap());
        assert_eq!(ApiError::io(same()).code, ErrorCode::InsufficientStorage);
        assert_eq!(blob(same()).code, ErrorCode::InsufficientStorage);
        assert_eq!(blob(same()).status().as_u16(), 507);
        let denied = || std::io::Error::from(std::io::ErrorKind::PermissionDenied);
        assert_eq!(ApiError::io(denied()).code, ErrorCode::Internal);
        assert_eq!(blob(denied()).code, ErrorCode::Unavailable);
    }
}
