//! The stored plan: what a job keeps so that its outputs render on request
//! without planning again, in another process or after a restart.
//!
//! A plan is the union topology with its materials and textures, and the
//! per-chain and per-leaf interpolation data every frame is computed from,
//! with the probes that fix tube side counts and the stream's grid (see
//! `runner`). Rendering needs nothing else: a frame is a function of the
//! plan and `t`.
//!
//! # Format
//! - 8 bytes of magic, `TMPLAN` and two zero bytes;
//! - the format version ([`FORMAT`]) and the [`RENDER_VERSION`] that wrote
//!   it, little-endian `u32`s;
//! - a zstd frame (level 1, with its content checksum) of the plan in
//!   postcard, serde's compact binary encoding. Floats are stored as
//!   their bits, so a plan read back renders the same bytes as the plan
//!   that was written.
//!
//! A plan of another format or render version is refused as
//! [`ReadError::Outdated`]: its renders would not be the bytes the job
//! wrote. The caller plans again from the trees, or answers
//! `410 plan_outdated` when it cannot.

use serde::{Deserialize, Serialize};

use crate::RENDER_VERSION;
use crate::plans::Planned;
use crate::runner::Probed;

/// The version of this layout; bump it when the header or the encoding
/// changes (a change of what a plan holds bumps [`RENDER_VERSION`]).
pub const FORMAT: u32 = 1;

const MAGIC: [u8; 8] = *b"TMPLAN\0\0";
const HEADER: usize = MAGIC.len() + 8;

/// zstd level: plans are written on the job's path to `succeeded`, so
/// speed matters more than the last few per cent of size.
const LEVEL: i32 = 1;

/// Why stored bytes are not a plan this build can render.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ReadError {
    /// The bytes do not start like a stored plan.
    #[error("not a stored plan")]
    NotAPlan,
    /// Written by another version of the format or the renderer.
    #[error(
        "the plan was written in format {format} for render version {render}; this build reads format {FORMAT}, render version {RENDER_VERSION}"
    )]
    Outdated {
        /// Its format version.
        format: u32,
        /// Its render version.
        render: u32,
    },
    /// The bytes are damaged.
    #[error("the stored plan is damaged: {0}")]
    Damaged(String),
}

/// A plan with its probes, as stored.
#[derive(Serialize, Deserialize)]
pub(crate) struct StoredPlan {
    pub plan: Planned,
    pub probed: Probed,
}

/// Encodes a plan and its probes.
pub(crate) fn write(plan: &Planned, probed: &Probed) -> Vec<u8> {
    #[derive(Serialize)]
    struct Borrowed<'a> {
        plan: &'a Planned,
        probed: &'a Probed,
    }
    // Serialising plain data into a Vec cannot fail.
    let body =
        postcard::to_stdvec(&Borrowed { plan, probed }).expect("a plan serialises into memory");
    let mut out = Vec::with_capacity(HEADER + body.len() / 3);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&FORMAT.to_le_bytes());
    out.extend_from_slice(&RENDER_VERSION.to_le_bytes());
    let mut encoder = zstd::Encoder::new(out, LEVEL).expect("zstd encoder in memory");
    encoder
        .include_checksum(true)
        .expect("zstd checksum parameter");
    std::io::Write::write_all(&mut encoder, &body).expect("zstd into memory");
    encoder.finish().expect("zstd into memory")
}

/// Decodes a stored plan.
pub(crate) fn read(bytes: &[u8]) -> Result<StoredPlan, ReadError> {
    if bytes.len() < HEADER || bytes[..MAGIC.len()] != MAGIC {
        return Err(ReadError::NotAPlan);
    }
    let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    let (format, render) = (word(MAGIC.len()), word(MAGIC.len() + 4));
    if (format, render) != (FORMAT, RENDER_VERSION) {
        return Err(ReadError::Outdated { format, render });
    }
    let body = zstd::decode_all(&bytes[HEADER..]).map_err(|e| ReadError::Damaged(e.to_string()))?;
    postcard::from_bytes(&body).map_err(|e| ReadError::Damaged(e.to_string()))
}
