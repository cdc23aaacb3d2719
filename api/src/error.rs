//! The error-code table: every error the service returns has the same body,
//! `{"error": {"code": "...", "message": "..."}}`, and a stable snake_case
//! `code` from [`ErrorCode`]; [`ErrorCode::status`] is the one place that
//! maps a code to its HTTP status.
//!
//! Codes are a contract: scripts match on them, so a code is never renamed
//! or reused for something else (add new ones instead). Messages are for
//! people and may change; 5xx messages are deliberately opaque (the cause is
//! logged on the server).

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

/// Defines [`ErrorCode`] from one table: each row is the variant with its
/// docs, its snake_case string and its HTTP status, so adding a code is one
/// row (the enum, [`ErrorCode::ALL`], [`ErrorCode::as_str`] and
/// [`ErrorCode::status`] all come from it).
macro_rules! error_codes {
    ($($(#[doc = $doc:literal])* $variant:ident = $code:literal, $status:literal;)*) => {
        /// A stable error code. Serialised as snake_case (`tree_not_found`).
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema)]
        #[serde(rename_all = "snake_case")]
        #[non_exhaustive]
        pub enum ErrorCode {
            $($(#[doc = $doc])* $variant,)*
        }

        impl ErrorCode {
            /// Every code, in table order.
            pub const ALL: &'static [ErrorCode] = &[$(ErrorCode::$variant,)*];

            /// The HTTP status this code is returned with. `cancelled` and
            /// `internal` are 500: `cancelled` is only ever a job's error,
            /// never an HTTP response (500 if it leaked into one).
            pub fn status(self) -> u16 {
                match self {
                    $(ErrorCode::$variant => $status,)*
                }
            }

            /// The snake_case code string.
            pub fn as_str(self) -> &'static str {
                match self {
                    $(ErrorCode::$variant => $code,)*
                }
            }
        }
    };
}

error_codes! {
    /// 400: the request body is not syntactically valid JSON.
    InvalidJson = "invalid_json", 400;
    /// 422: a well-formed request whose content is wrong (unknown or
    /// missing field, value out of range); the message names the field.
    InvalidRequest = "invalid_request", 422;
    /// 401: an API key is required and was missing or unknown.
    Unauthorized = "unauthorized", 401;
    /// 404: no such resource (or it belongs to another API key).
    NotFound = "not_found", 404;
    /// 404: a tree named in a job request does not exist for this key.
    TreeNotFound = "tree_not_found", 404;
    /// 405: the route exists but not with this method.
    MethodNotAllowed = "method_not_allowed", 405;
    /// 409: the tree is used by a job that still exists.
    TreeInUse = "tree_in_use", 409;
    /// 409: the job has already succeeded or failed and cannot be cancelled.
    JobFinished = "job_finished", 409;
    /// 409: the output is not available yet (the job is still running, or
    /// the frame has not been published yet).
    NotReady = "not_ready", 409;
    /// 413: the upload is larger than the configured limit.
    PayloadTooLarge = "payload_too_large", 413;
    /// 415: the body's media type is not accepted by this route.
    UnsupportedMediaType = "unsupported_media_type", 415;
    /// 416: the `Range` header cannot be satisfied.
    RangeNotSatisfiable = "range_not_satisfiable", 416;
    /// 422: the upload is not a valid treemorph tree document.
    InvalidTree = "invalid_tree", 422;
    /// 422: the upload is a glTF/GLB that cannot be turned into a tree.
    InvalidGltf = "invalid_gltf", 422;
    /// 415: a valid glTF/GLB that uses something treemorph does not read
    /// (external URIs, Draco or meshopt compression, other required
    /// extensions).
    UnsupportedGltf = "unsupported_gltf", 415;
    /// 413: the model exceeds a size limit (vertices, triangles, leaves,
    /// nodes, texture size) although the upload's bytes are within bounds.
    TooLarge = "too_large", 413;
    /// 422: an `Idempotency-Key` was reused with a different request body.
    IdempotencyKeyReused = "idempotency_key_reused", 422;
    /// 422: the `callback_url` is not an acceptable http(s) URL or resolves
    /// to a loopback, private, link-local or unique-local address.
    CallbackUrlRefused = "callback_url_refused", 422;
    /// 422: job parameters the pipeline rejects (e.g. an unusable sketch).
    InvalidJob = "invalid_job", 422;
    /// 422: the sketch polygon is unusable (too few points, degenerate).
    InvalidSketch = "invalid_sketch", 422;
    /// 422: the trees cannot be morphed into each other.
    IncompatibleTrees = "incompatible_trees", 422;
    /// 429: too many jobs are waiting; retry after `Retry-After` seconds.
    QueueFull = "queue_full", 429;
    /// 429: this API key exceeded its request rate; retry after
    /// `Retry-After` seconds.
    RateLimited = "rate_limited", 429;
    /// A job's error: it was cancelled.
    Cancelled = "cancelled", 500;
    /// 500: a bug or an unexpected failure (details are logged only).
    Internal = "internal", 500;
    /// 503: a dependency (database, blob store) is unavailable, or the
    /// server is shutting down.
    Unavailable = "unavailable", 503;
    /// 503: the request took longer than the configured timeout.
    Timeout = "timeout", 503;
    /// 408: the request body arrived too slowly (nothing for the header
    /// timeout, or under the minimum rate once that much time has
    /// passed): slow-body protection.
    BodyTooSlow = "body_too_slow", 408;
    /// 507: the upload or job would take this API key's stored bytes
    /// (trees and job outputs) over `--max-stored-mb-per-key`; delete
    /// trees or jobs to make room.
    QuotaExceeded = "quota_exceeded", 507;
    /// 410: the job's stored plan (or an input it renders from) is from an
    /// older version or gone; run the job again to render new instants.
    PlanOutdated = "plan_outdated", 410;
    /// 507: the server's storage is full; nothing was stored.
    InsufficientStorage = "insufficient_storage", 507;
}

impl ErrorCode {
    /// The code for a snake_case string, if it is one of ours.
    pub fn parse(code: &str) -> Option<ErrorCode> {
        ErrorCode::ALL.iter().copied().find(|c| c.as_str() == code)
    }

    /// Whether the error is the caller's (4xx) rather than the server's.
    pub fn is_client_error(self) -> bool {
        (400..500).contains(&self.status())
    }
}

impl std::fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The body of every error response.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct ErrorBody {
    /// The error.
    pub error: ErrorDetail,
}

/// A code and a message.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct ErrorDetail {
    /// Stable snake_case error code.
    pub code: ErrorCode,
    /// What went wrong, for people.
    pub message: String,
}

impl ErrorBody {
    /// An error body.
    pub fn new(code: ErrorCode, message: impl Into<String>) -> ErrorBody {
        ErrorBody {
            error: ErrorDetail {
                code,
                message: message.into(),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip_through_serde_and_strings() {
        for &code in ErrorCode::ALL {
            let json = serde_json::to_string(&code).unwrap();
            assert_eq!(json, format!("\"{}\"", code.as_str()));
            assert_eq!(serde_json::from_str::<ErrorCode>(&json).unwrap(), code);
            assert_eq!(ErrorCode::parse(code.as_str()), Some(code));
            assert!((400..600).contains(&code.status()));
        }
    }

    #[test]
    fn body_has_the_documented_shape() {
        let body = ErrorBody::new(ErrorCode::TreeInUse, "busy");
        assert_eq!(
            serde_json::to_value(&body).unwrap(),
            serde_json::json!({"error": {"code": "tree_in_use", "message": "busy"}})
        );
    }
}
