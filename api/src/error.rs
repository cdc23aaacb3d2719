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

/// A stable error code. Serialised as snake_case (`tree_not_found`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum ErrorCode {
    /// 400: the request body is not syntactically valid JSON.
    InvalidJson,
    /// 422: a well-formed request whose content is wrong (unknown or
    /// missing field, value out of range); the message names the field.
    InvalidRequest,
    /// 401: an API key is required and was missing or unknown.
    Unauthorized,
    /// 404: no such resource (or it belongs to another API key).
    NotFound,
    /// 404: a tree named in a job request does not exist for this key.
    TreeNotFound,
    /// 405: the route exists but not with this method.
    MethodNotAllowed,
    /// 409: the tree is used by a queued or running job.
    TreeInUse,
    /// 409: the job has already succeeded or failed and cannot be cancelled.
    JobFinished,
    /// 409: the output is not available yet (the job is still running, or
    /// the frame has not been published yet).
    NotReady,
    /// 413: the upload is larger than the configured limit.
    PayloadTooLarge,
    /// 415: the body's media type is not accepted by this route.
    UnsupportedMediaType,
    /// 416: the `Range` header cannot be satisfied.
    RangeNotSatisfiable,
    /// 422: the upload is not a valid treemorph tree document.
    InvalidTree,
    /// 422: the upload is a glTF/GLB that cannot be turned into a tree.
    InvalidGltf,
    /// 415: a valid glTF/GLB that uses something treemorph does not read
    /// (external URIs, Draco or meshopt compression, other required
    /// extensions).
    UnsupportedGltf,
    /// 413: the model exceeds a size limit (vertices, triangles, leaves,
    /// nodes, texture size) although the upload's bytes are within bounds.
    TooLarge,
    /// 422: an `Idempotency-Key` was reused with a different request body.
    IdempotencyKeyReused,
    /// 422: the `callback_url` is not an acceptable http(s) URL or resolves
    /// to a loopback, private, link-local or unique-local address.
    CallbackUrlRefused,
    /// 422: job parameters the pipeline rejects (e.g. an unusable sketch).
    InvalidJob,
    /// 422: the sketch polygon is unusable (too few points, degenerate).
    InvalidSketch,
    /// 422: the trees cannot be morphed into each other.
    IncompatibleTrees,
    /// 429: too many jobs are waiting; retry after `Retry-After` seconds.
    QueueFull,
    /// 429: this API key exceeded its request rate; retry after
    /// `Retry-After` seconds.
    RateLimited,
    /// A job's error: it was cancelled.
    Cancelled,
    /// 500: a bug or an unexpected failure (details are logged only).
    Internal,
    /// 503: a dependency (database, blob store) is unavailable, or the
    /// server is shutting down.
    Unavailable,
    /// 503: the request took longer than the configured timeout.
    Timeout,
    /// 408: the request body arrived too slowly (nothing for the header
    /// timeout, or under the minimum rate once that much time has
    /// passed): slow-body protection.
    BodyTooSlow,
}

impl ErrorCode {
    /// Every code, in table order.
    pub const ALL: [ErrorCode; 28] = [
        ErrorCode::InvalidJson,
        ErrorCode::InvalidRequest,
        ErrorCode::Unauthorized,
        ErrorCode::NotFound,
        ErrorCode::TreeNotFound,
        ErrorCode::MethodNotAllowed,
        ErrorCode::TreeInUse,
        ErrorCode::JobFinished,
        ErrorCode::NotReady,
        ErrorCode::PayloadTooLarge,
        ErrorCode::UnsupportedMediaType,
        ErrorCode::RangeNotSatisfiable,
        ErrorCode::InvalidTree,
        ErrorCode::InvalidGltf,
        ErrorCode::UnsupportedGltf,
        ErrorCode::TooLarge,
        ErrorCode::IdempotencyKeyReused,
        ErrorCode::CallbackUrlRefused,
        ErrorCode::InvalidJob,
        ErrorCode::InvalidSketch,
        ErrorCode::IncompatibleTrees,
        ErrorCode::QueueFull,
        ErrorCode::RateLimited,
        ErrorCode::Cancelled,
        ErrorCode::Internal,
        ErrorCode::Unavailable,
        ErrorCode::Timeout,
        ErrorCode::BodyTooSlow,
    ];

    /// The HTTP status this code is returned with.
    pub fn status(self) -> u16 {
        match self {
            ErrorCode::InvalidJson => 400,
            ErrorCode::Unauthorized => 401,
            ErrorCode::NotFound | ErrorCode::TreeNotFound => 404,
            ErrorCode::MethodNotAllowed => 405,
            ErrorCode::BodyTooSlow => 408,
            ErrorCode::TreeInUse | ErrorCode::JobFinished | ErrorCode::NotReady => 409,
            ErrorCode::PayloadTooLarge | ErrorCode::TooLarge => 413,
            ErrorCode::UnsupportedMediaType | ErrorCode::UnsupportedGltf => 415,
            ErrorCode::RangeNotSatisfiable => 416,
            ErrorCode::InvalidRequest
            | ErrorCode::InvalidTree
            | ErrorCode::InvalidGltf
            | ErrorCode::IdempotencyKeyReused
            | ErrorCode::CallbackUrlRefused
            | ErrorCode::InvalidJob
            | ErrorCode::InvalidSketch
            | ErrorCode::IncompatibleTrees => 422,
            ErrorCode::QueueFull | ErrorCode::RateLimited => 429,
            // Only ever a job's error, never an HTTP response; 500 if it
            // leaked into one.
            ErrorCode::Cancelled | ErrorCode::Internal => 500,
            ErrorCode::Unavailable | ErrorCode::Timeout => 503,
        }
    }

    /// The snake_case code string.
    pub fn as_str(self) -> &'static str {
        match self {
            ErrorCode::InvalidJson => "invalid_json",
            ErrorCode::InvalidRequest => "invalid_request",
            ErrorCode::Unauthorized => "unauthorized",
            ErrorCode::NotFound => "not_found",
            ErrorCode::TreeNotFound => "tree_not_found",
            ErrorCode::MethodNotAllowed => "method_not_allowed",
            ErrorCode::TreeInUse => "tree_in_use",
            ErrorCode::JobFinished => "job_finished",
            ErrorCode::NotReady => "not_ready",
            ErrorCode::PayloadTooLarge => "payload_too_large",
            ErrorCode::UnsupportedMediaType => "unsupported_media_type",
            ErrorCode::RangeNotSatisfiable => "range_not_satisfiable",
            ErrorCode::InvalidTree => "invalid_tree",
            ErrorCode::InvalidGltf => "invalid_gltf",
            ErrorCode::UnsupportedGltf => "unsupported_gltf",
            ErrorCode::TooLarge => "too_large",
            ErrorCode::IdempotencyKeyReused => "idempotency_key_reused",
            ErrorCode::CallbackUrlRefused => "callback_url_refused",
            ErrorCode::InvalidJob => "invalid_job",
            ErrorCode::InvalidSketch => "invalid_sketch",
            ErrorCode::IncompatibleTrees => "incompatible_trees",
            ErrorCode::QueueFull => "queue_full",
            ErrorCode::RateLimited => "rate_limited",
            ErrorCode::Cancelled => "cancelled",
            ErrorCode::Internal => "internal",
            ErrorCode::Unavailable => "unavailable",
            ErrorCode::Timeout => "timeout",
            ErrorCode::BodyTooSlow => "body_too_slow",
        }
    }

    /// The code for a snake_case string, if it is one of ours.
    pub fn parse(code: &str) -> Option<ErrorCode> {
        ErrorCode::ALL.into_iter().find(|c| c.as_str() == code)
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
        for code in ErrorCode::ALL {
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
