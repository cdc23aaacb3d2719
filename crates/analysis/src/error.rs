//! [`AnalysisError`].

use thiserror::Error;

/// Why an analysis failed.
#[derive(Clone, Debug, Error, PartialEq)]
// Exhaustive on purpose: the service's error-code table
// (`treemorph_pipeline::ErrorCoded`) must name a code for every variant.
pub enum AnalysisError {
    /// The caller's mistake: an option is out of range.
    #[error("invalid analysis option `{option}`: {reason}")]
    InvalidOption {
        /// The option's field name.
        option: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// The caller's mistake: the skeleton is a lone root, so there is no
    /// chain to analyse.
    #[error("the skeleton has no branches, so it has no chains to analyse")]
    NoBranches,
    /// A bug in the analysis.
    #[error("internal analysis error: {0}")]
    Internal(String),
}
