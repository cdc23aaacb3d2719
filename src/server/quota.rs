//! The per-key storage quota (`--max-stored-mb-per-key`).
//!
//! # Choices
//! - **What counts:** the bytes of every blob an API key's trees and jobs
//!   store (a tree's original upload, JSON, analysis and GLB export; a
//!   job's published outputs), recorded on their rows when they are
//!   stored. Rows stored before the count existed count 0.
//! - **An upload** is refused (507 `quota_exceeded`) when its blobs would
//!   take the key over the quota; their size is known before anything is
//!   stored.
//! - **A job** is refused when the key is already at or over its quota: a
//!   job's outputs are only known once it ran, so a key under its quota
//!   may end a job somewhat over it, and then stores nothing more until it
//!   deletes trees or jobs.
//! - Two requests of one key racing past the check may both be stored: the
//!   quota bounds a key's storage to within one request, which is what it
//!   is for (a disk that cannot be filled by one key), without a lock
//!   across the store.

use treemorph_api::ErrorCode;

use super::{AppState, Owner};
use crate::error::ApiError;

/// Refuses storing `incoming` more bytes for `owner` when that would take
/// it over the quota (`incoming` 0: a job, refused at or over the quota).
pub async fn check(state: &AppState, owner: &Owner, incoming: u64) -> Result<(), ApiError> {
    let mb = state.settings().max_stored_mb_per_key;
    if mb == 0 {
        return Ok(());
    }
    let quota = mb.saturating_mul(1024 * 1024);
    let stored = u64::try_from(state.services.db.stored_bytes(&owner.0).await?).unwrap_or(0);
    if stored >= quota || stored.saturating_add(incoming) > quota {
        return Err(ApiError::new(
            ErrorCode::QuotaExceeded,
            format!(
                "this API key stores {stored} bytes of its {quota}-byte quota; storing {incoming} more would exceed it — delete trees or jobs to make room"
            ),
        ));
    }
    Ok(())
}
