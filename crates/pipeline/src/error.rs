//! The error-code table of every domain error: [`ErrorCoded`], implemented
//! once per error type with an exhaustive `match`.
//!
//! The domain crates' error enums are exhaustive on purpose, so a new
//! variant does not compile until it has a code here. Variants that are the
//! caller's mistake map to a 4xx code and keep their message (it names the
//! problem); variants that are bugs map to `internal`, and
//! [`JobError::from_domain`] replaces their message by an opaque one and
//! logs the cause, so a bug is never reported as the caller's 422 and
//! internals never reach clients.

use treemorph_analysis::AnalysisError;
use treemorph_api::ErrorCode;
use treemorph_gltf::frames::EncodeError;
use treemorph_import::ImportError;
use treemorph_morph::MorphError;
use treemorph_sketch::SketchError;
use treemorph_tree::InvalidTree;
use treemorph_tree::json::FormatError;

use crate::spec::SpecError;

/// An error with a stable code from the service's table
/// ([`ErrorCode`]; its status is [`ErrorCode::status`]).
pub trait ErrorCoded: std::error::Error {
    /// The code this error is reported with.
    fn error_code(&self) -> ErrorCode;
}

/// The message clients see for an error whose code is `internal`.
pub const INTERNAL_MESSAGE: &str = "internal error";

impl ErrorCoded for SpecError {
    fn error_code(&self) -> ErrorCode {
        match self {
            SpecError::Frames { .. } => ErrorCode::InvalidRequest,
            SpecError::Keyframes { .. }
            | SpecError::SkeletonJoints { .. }
            | SpecError::Schedule { .. } => ErrorCode::InvalidJob,
            SpecError::MorphOptions(e) => match e.error_code() {
                ErrorCode::Internal => ErrorCode::Internal,
                _ => ErrorCode::InvalidJob,
            },
            SpecError::Sketch(e) => e.error_code(),
        }
    }
}

impl ErrorCoded for MorphError {
    fn error_code(&self) -> ErrorCode {
        match self {
            MorphError::InvalidOption { .. } => ErrorCode::InvalidJob,
            MorphError::AnalysisMismatch { .. } | MorphError::Internal(_) => ErrorCode::Internal,
            MorphError::TooLarge(_) => ErrorCode::IncompatibleTrees,
        }
    }
}

impl ErrorCoded for SketchError {
    fn error_code(&self) -> ErrorCode {
        use SketchError as E;
        match self {
            E::InvalidJson(_)
            | E::TooFewPoints { .. }
            | E::TooManyPoints { .. }
            | E::NonFinite { .. }
            | E::PointOutOfRange { .. }
            | E::SelfIntersecting { .. }
            | E::SplicedCrownSelfIntersecting
            | E::OpenSketchEndsCoincide
            | E::DegenerateSketch
            | E::FitNeedsClosedSketch
            | E::AmbiguousProjection
            | E::MissingProjection
            | E::EyeAtTarget
            | E::UpParallelToView
            | E::FovOutOfRange { .. }
            | E::OrthoHeightOutOfRange { .. }
            | E::AspectOutOfRange { .. }
            | E::NoCrown
            | E::DegenerateCrown
            | E::CameraInsideCrown
            | E::BehindCamera { .. }
            | E::SketchMissesCrown
            | E::OpenSketchTooFar { .. }
            | E::InvalidOption { .. } => ErrorCode::InvalidSketch,
            E::AnalysisMismatch(_) | E::Internal(_) => ErrorCode::Internal,
        }
    }
}

impl ErrorCoded for AnalysisError {
    fn error_code(&self) -> ErrorCode {
        match self {
            AnalysisError::NoBranches => ErrorCode::InvalidTree,
            AnalysisError::InvalidOption { .. } | AnalysisError::Internal(_) => ErrorCode::Internal,
        }
    }
}

impl ErrorCoded for ImportError {
    fn error_code(&self) -> ErrorCode {
        match self {
            ImportError::InvalidGltf(_) => ErrorCode::InvalidGltf,
            ImportError::UnsupportedGltf(_) => ErrorCode::UnsupportedGltf,
            ImportError::InvalidTree(_) => ErrorCode::InvalidTree,
            ImportError::TooLarge(_) => ErrorCode::TooLarge,
            // The service and the command line pass their own options: a bad
            // one is their bug, not the uploader's.
            ImportError::InvalidOptions(_) | ImportError::Internal(_) => ErrorCode::Internal,
        }
    }
}

impl ErrorCoded for InvalidTree {
    fn error_code(&self) -> ErrorCode {
        match self {
            InvalidTree::TooLarge { .. } => ErrorCode::TooLarge,
            _ => ErrorCode::InvalidTree,
        }
    }
}

impl ErrorCoded for FormatError {
    fn error_code(&self) -> ErrorCode {
        match self {
            FormatError::Syntax { .. } | FormatError::UnsupportedFormat { .. } => {
                ErrorCode::InvalidTree
            }
            FormatError::Invalid(e) => e.error_code(),
        }
    }
}

impl ErrorCoded for EncodeError {
    fn error_code(&self) -> ErrorCode {
        match self {
            // An output beyond a format's or the renderer's limits (a
            // 4 GiB GLB, a basis of too many samples): the job asked for
            // too much, and the message says what to ask for instead.
            EncodeError::TooLarge(_) => ErrorCode::TooLarge,
            // Frames come from validated plans: any other refusal is a bug.
            _ => ErrorCode::Internal,
        }
    }
}

/// Why a job failed, as the queue records it and clients read it
/// (`error.code`, `error.message`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{code}: {message}")]
pub struct JobError {
    /// Stable error code (the job's `error.code`).
    pub code: ErrorCode,
    /// What went wrong, for people; [`INTERNAL_MESSAGE`] for bugs.
    pub message: String,
    /// Whether running the job again may succeed (storage hiccups); invalid
    /// input never is.
    pub retryable: bool,
}

impl JobError {
    /// The failure for a domain error: its code from the table, its
    /// message prefixed by `context` (e.g. which tree) when the code is the
    /// caller's, and an opaque message with the cause logged when it is a
    /// bug.
    pub fn from_domain(e: &dyn ErrorCoded, context: &str) -> JobError {
        let code = e.error_code();
        if code == ErrorCode::Internal {
            return JobError::internal(format_args!("{context}{e}"));
        }
        JobError {
            code,
            message: format!("{context}{e}"),
            retryable: false,
        }
    }

    /// A bug: logged with its cause, reported as [`INTERNAL_MESSAGE`].
    pub fn internal(cause: impl std::fmt::Display) -> JobError {
        tracing::error!(%cause, "job failed on an internal error");
        JobError {
            code: ErrorCode::Internal,
            message: INTERNAL_MESSAGE.into(),
            retryable: false,
        }
    }

    /// The caller's mistake with a code of its own (`tree_not_found`, …).
    pub fn invalid(code: ErrorCode, message: impl Into<String>) -> JobError {
        JobError {
            code,
            message: message.into(),
            retryable: false,
        }
    }

    /// A transient failure of storage or another dependency: retried.
    pub fn unavailable(message: impl Into<String>) -> JobError {
        JobError {
            code: ErrorCode::Unavailable,
            message: message.into(),
            retryable: true,
        }
    }

    /// The job was cancelled.
    pub fn cancelled() -> JobError {
        JobError::invalid(ErrorCode::Cancelled, "the job was cancelled")
    }
}

impl From<SpecError> for JobError {
    fn from(e: SpecError) -> JobError {
        JobError::from_domain(&e, "")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn internal_variants_are_internal_with_an_opaque_message() {
        let cases: [&dyn ErrorCoded; 4] = [
            &MorphError::Internal("index 7 out of bounds".into()),
            &SketchError::Internal("index 7 out of bounds".into()),
            &AnalysisError::Internal("index 7 out of bounds".into()),
            &ImportError::Internal("index 7 out of bounds".into()),
        ];
        for e in cases {
            let job = JobError::from_domain(e, "tree \"a\": ");
            assert_eq!(job.code, ErrorCode::Internal, "{e}");
            assert_eq!(job.code.status(), 500);
            assert_eq!(job.message, INTERNAL_MESSAGE);
            assert!(!job.retryable);
        }
    }

    #[test]
    fn the_callers_mistakes_keep_their_message() {
        let job = JobError::from_domain(&AnalysisError::NoBranches, "tree \"a\": ");
        assert_eq!(job.code, ErrorCode::InvalidTree);
        assert!(job.message.starts_with("tree \"a\": "), "{}", job.message);
        let job = JobError::from_domain(&SketchError::DegenerateSketch, "");
        assert_eq!(job.code, ErrorCode::InvalidSketch);
        assert_eq!(job.message, SketchError::DegenerateSketch.to_string());
    }
}
