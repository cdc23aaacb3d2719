//! [`ImportError`] and its stable codes.

use thiserror::Error;

/// Why a file could not be imported.
///
/// Every variant maps to one stable snake_case [`code`](ImportError::code):
/// `invalid_gltf` (the container, the JSON or an accessor is broken: the
/// file's fault), `unsupported_gltf` (a valid file using a feature treemorph
/// does not read), `invalid_tree` (the file is readable but its geometry
/// cannot become one tree), `too_large` (a size limit of
/// [`ImportOptions`](crate::ImportOptions) was hit), `invalid_options` (the
/// caller's options are out of range) and `internal` (a bug).
#[derive(Clone, Debug, Error, PartialEq)]
// Exhaustive on purpose: the service's error-code table
// (`treemorph_pipeline::ErrorCoded`) must name a code for every variant.
pub enum ImportError {
    /// The bytes are not a readable GLB or glTF JSON document, or something
    /// inside it (a chunk, a buffer, an accessor, an index, a number) is
    /// inconsistent.
    #[error("invalid glTF: {0}")]
    InvalidGltf(String),
    /// A valid glTF feature that treemorph does not read (external URIs,
    /// compressed geometry, required extensions it does not know, …).
    #[error("unsupported glTF: {0}")]
    UnsupportedGltf(String),
    /// The file was read but its content cannot become one tree.
    #[error("cannot build a tree: {0}")]
    InvalidTree(String),
    /// A size limit was exceeded.
    #[error("too large: {0}")]
    TooLarge(String),
    /// The options are out of range (the caller's mistake).
    #[error("invalid import options: {0}")]
    InvalidOptions(String),
    /// A bug in the importer.
    #[error("internal import error: {0}")]
    Internal(String),
}

impl ImportError {
    /// The stable machine-readable code of this error.
    pub fn code(&self) -> &'static str {
        match self {
            ImportError::InvalidGltf(_) => "invalid_gltf",
            ImportError::UnsupportedGltf(_) => "unsupported_gltf",
            ImportError::InvalidTree(_) => "invalid_tree",
            ImportError::TooLarge(_) => "too_large",
            ImportError::InvalidOptions(_) => "invalid_options",
            ImportError::Internal(_) => "internal",
        }
    }

    /// Every code [`ImportError::code`] can return.
    pub const CODES: [&'static str; 6] = [
        "invalid_gltf",
        "unsupported_gltf",
        "invalid_tree",
        "too_large",
        "invalid_options",
        "internal",
    ];
}

pub(crate) fn invalid(message: impl Into<String>) -> ImportError {
    ImportError::InvalidGltf(message.into())
}

pub(crate) fn unsupported(message: impl Into<String>) -> ImportError {
    ImportError::UnsupportedGltf(message.into())
}
