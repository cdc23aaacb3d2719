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
//! - a zstd frame (with its content size and checksum) of the plan in
//!   postcard, serde's compact binary encoding. Floats are stored as
//!   their bits, so a plan read back renders the same bytes as the plan
//!   that was written. Plans stored by earlier versions hold a streamed
//!   frame without its content size; they read the same.
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
pub(crate) const HEADER: usize = MAGIC.len() + 8;

/// zstd level, one of its fast ones: a plan is mostly float bits, which
/// compress little at any level, and it is written on the job's path to
/// `succeeded`. On the default job's 3.55 MB plan, level 1 made 2.56 MB
/// in 12 ms (one call; 21 ms through the streaming encoder used before),
/// level −3 makes 2.81 MB in 4.6 ms and reads back in 3 ms.
const LEVEL: i32 = -3;

/// How many times its compressed size a plan's body may claim to be and
/// still be decompressed in one call into a buffer of that size (plans
/// compress about 1.3 times): a damaged frame claiming more is read as a
/// stream, which stops at the damage instead of allocating the claim.
const MAX_RATIO: u64 = 64;

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
    let frame = compress(&body);
    let mut out = Vec::with_capacity(HEADER + frame.len());
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&FORMAT.to_le_bytes());
    out.extend_from_slice(&RENDER_VERSION.to_le_bytes());
    out.extend_from_slice(&frame);
    out
}

/// One zstd frame of `body`, in one call, so the frame records its
/// content size and [`decompress`] can read it in one call too.
fn compress(body: &[u8]) -> Vec<u8> {
    let mut compressor = zstd::bulk::Compressor::new(LEVEL).expect("zstd compressor in memory");
    compressor
        .include_checksum(true)
        .expect("zstd checksum parameter");
    compressor.compress(body).expect("zstd into memory")
}

/// The body of a plan's zstd frame: in one call into a buffer of the
/// size the frame records, or as a stream when it records none (plans of
/// earlier versions) or claims more than a plan can be.
fn decompress(frame: &[u8]) -> Result<Vec<u8>, ReadError> {
    let damaged = |e: std::io::Error| ReadError::Damaged(e.to_string());
    let most = (frame.len() as u64).saturating_mul(MAX_RATIO);
    match zstd::zstd_safe::get_frame_content_size(frame) {
        Ok(Some(size)) if size <= most => {
            zstd::bulk::decompress(frame, size as usize).map_err(damaged)
        }
        _ => zstd::decode_all(frame).map_err(damaged),
    }
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
    let body = decompress(&bytes[HEADER..])?;
    postcard::from_bytes(&body).map_err(|e| ReadError::Damaged(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame compressed in one call, so that it records its size.
    fn one_call(body: &[u8]) -> Vec<u8> {
        zstd::bulk::compress(body, 3).unwrap()
    }

    #[test]
    fn a_frame_claiming_more_than_max_ratio_times_its_size_is_read_as_a_stream() {
        // A megabyte of zeros compresses far beyond the ratio a plan
        // reaches: its recorded size is refused for the one-call buffer,
        // and the stream decoder reads it the same.
        let body = vec![0u8; 1 << 20];
        let frame = one_call(&body);
        let claimed = zstd::zstd_safe::get_frame_content_size(&frame).unwrap();
        assert_eq!(claimed, Some(body.len() as u64));
        assert!(claimed.unwrap() > frame.len() as u64 * MAX_RATIO);
        assert_eq!(decompress(&frame).unwrap(), body);
    }

    #[test]
    fn a_truncated_frame_is_damaged_whichever_way_it_is_read() {
        // Scrambled words, which barely compress (as a plan's floats), and
        // zeros, which compress beyond the ratio: one call and the stream.
        let plan_like: Vec<u8> = (0..200_000u32)
            .flat_map(|i| i.wrapping_mul(2_654_435_761).to_le_bytes())
            .collect();
        let zeros = vec![0u8; 1 << 20];
        for body in [plan_like, zeros] {
            let frame = one_call(&body);
            let cut = &frame[..frame.len() - 4];
            assert!(
                matches!(decompress(cut), Err(ReadError::Damaged(_))),
                "{} of {} bytes",
                cut.len(),
                frame.len()
            );
        }
    }
}
