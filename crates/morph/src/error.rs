//! [`MorphError`].

use thiserror::Error;

/// Which input tree an error is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Side {
    /// The tree the morph starts from (t = 0).
    Source,
    /// The tree the morph ends at (t = 1).
    Target,
}

impl std::fmt::Display for Side {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Side::Source => "source",
            Side::Target => "target",
        })
    }
}

/// Why a [`MorphPlan`](crate::MorphPlan) could not be built.
#[derive(Clone, Debug, Error, PartialEq)]
// Exhaustive on purpose: the service's error-code table
// (`treemorph_pipeline::ErrorCoded`) must name a code for every variant.
pub enum MorphError {
    /// The caller's mistake: an option is out of range.
    #[error("invalid morph option `{option}`: {reason}")]
    InvalidOption {
        /// The option's field path (e.g. `group_weights.outer_lobe`).
        option: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// The caller's mistake: the analysis passed with a tree was not made
    /// from that tree.
    #[error("the {side} analysis does not belong to the {side} tree: {reason}")]
    AnalysisMismatch {
        /// Which tree.
        side: Side,
        /// What does not fit.
        reason: String,
    },
    /// The union topology would not fit in 32-bit node ids.
    #[error("the union topology is too large: {0}")]
    TooLarge(String),
    /// A bug in the morph pipeline.
    #[error("internal morph error: {0}")]
    Internal(String),
}
