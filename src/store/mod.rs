//! Persistence: the metadata database ([`Db`]) and the blob store
//! ([`Blobs`]).
//!
//! # Layout
//! - The **database** (SQLite by default, PostgreSQL for scale-out) holds
//!   the `trees` and `jobs` tables (the durable job queue, see
//!   [`crate::jobs::queue`]), `webhook_deliveries` and `renders` (see
//!   [`renders`]). One code path serves
//!   both databases through sqlx's `Any` driver: `$N` placeholders, ids as
//!   TEXT (32 lowercase hex digits, UUIDv7 so they sort by creation time),
//!   times as INTEGER milliseconds, JSON documents as TEXT. Migrations are
//!   plain SQL files under `migrations/{sqlite,postgres}/`, embedded in the
//!   binary and applied in order by [`Db::migrate`].
//! - The **blob store** (a local directory by default, S3 for scale-out)
//!   holds every byte that is not metadata: `trees/{id}/original`,
//!   `trees/{id}/tree.json`, `trees/{id}/analysis.json`,
//!   `trees/{id}/model.glb`, and per-attempt job outputs under
//!   `jobs/{id}/{attempt_token}/…` (see [`crate::jobs`] for why outputs
//!   are keyed by attempt).
//!
//! Blobs are written before the row that names them is committed, so a row
//! never points at a missing blob; a crash between the two leaves an
//! unreferenced blob, never a broken row.

mod blobs;
mod db;
pub mod renders;
pub mod trees;

pub use blobs::{BlobError, BlobWriter, Blobs};
pub use db::{Backend, Db};

use std::time::{SystemTime, UNIX_EPOCH};

/// Milliseconds since the Unix epoch.
pub fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .unwrap_or(0)
}

/// A new id: a UUIDv7 as 32 lowercase hex digits (time-ordered, so index
/// inserts stay local).
pub fn new_id() -> String {
    uuid::Uuid::now_v7().simple().to_string()
}

/// A fresh random token (128 bits, hex), e.g. a lease's attempt token.
pub fn new_token() -> String {
    uuid::Uuid::new_v4().simple().to_string()
}

/// 64 random bits (from the OS generator, through a v4 UUID's 122 random
/// bits), for jitter.
pub fn random_u64() -> u64 {
    let b = uuid::Uuid::new_v4().into_bytes();
    u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[8], b[9]])
}

/// Whether `s` has the shape of one of our ids. Path ids that fail this
/// are answered with 404 before they reach the database or become part of
/// a blob key (so `../` and overlong ids can never escape a prefix).
pub fn is_id(s: &str) -> bool {
    s.len() == 32
        && s.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// Formats milliseconds since the epoch as RFC 3339 UTC with millisecond
/// precision (`2026-11-22T03:15:58.123Z`).
pub fn rfc3339(ms: i64) -> String {
    let secs = ms.div_euclid(1000);
    let millis = ms.rem_euclid(1000);
    let days = secs.div_euclid(86_400);
    let tod = secs.rem_euclid(86_400);
    // Howard Hinnant's civil_from_days.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = if m <= 2 { y + 1 } else { y };
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}.{millis:03}Z",
        tod / 3600,
        (tod / 60) % 60,
        tod % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rfc3339_formats_known_instants() {
        assert_eq!(rfc3339(0), "1970-01-01T00:00:00.000Z");
        assert_eq!(rfc3339(951_782_400_123), "2000-02-29T00:00:00.123Z");
        assert_eq!(rfc3339(1_795_317_358_000), "2026-11-22T03:15:58.000Z");
    }

    #[test]
    fn ids_are_recognised_and_impostors_are_not() {
        let id = new_id();
        assert!(is_id(&id), "{id}");
        assert!(new_id() > id || new_id() != id);
        assert!(!is_id("../../etc/passwd"));
        assert!(!is_id(&"a".repeat(33)));
        assert!(!is_id(&id.to_uppercase()));
    }
}
