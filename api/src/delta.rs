//! The streamed binary delta format `application/vnd.treemorph.delta`.
//!
//! Clients (the web viewer, the CLI client) play an animation **while its job
//! is still running**: the service sends frames one by one over HTTP as the
//! pipeline produces them. Every frame of a job shares one *union topology*
//! (the same vertices and triangles in every frame, see
//! `treemorph_tree::frame`), so the stream sends the topology once and then
//! only what changes: vertex positions and the leaf blend factor.
//!
//! `api/README.md` specifies every byte; this module is the reference
//! implementation and `web/delta.js` the browser one. In short:
//!
//! - A **preamble** (magic `TMDS`, major and minor version), then
//!   **records**, each self-delimiting and protected by a CRC-32: one
//!   **header** record ([`StreamHeader`]: meshes with index buffers, UVs,
//!   material groups and base positions; materials; PNG textures; the
//!   quantisation [`Grid`]; the animation bounds; the frame count if known),
//!   one **frame** record per frame, and an **end** record carrying the frame
//!   count, so a client can tell a complete stream from a cut one.
//! - Positions travel as integer coordinates on a uniform **quantisation
//!   grid** ([`Grid::for_bounds`] picks a step so the error is at most
//!   0.1 % of the tree height). A frame carries, per mesh and axis, the
//!   difference between its grid coordinates and those of the *previously
//!   decoded* frame. Both ends keep integer state, so the error never
//!   accumulates: every decoded position is within the grid's error of the
//!   encoder's input, however long the stream.
//! - Integers travel in **blocks** of 4096 values, each with its own bit
//!   width (0, 1, 2, 4 bits packed; 8–32 bits as byte planes) and its own
//!   choice of predictor (the value itself, or its difference from the
//!   previous vertex's), zigzag-coded; every record payload is then
//!   **zstd**-compressed. Smooth motion leaves residuals of a bit or two,
//!   which zstd shrinks further.
//!
//! # Choices where the issue left room
//! - **Normals are not sent.** Clients recompute them from the positions
//!   and the index buffer (three.js `BufferGeometry::computeVertexNormals`);
//!   octahedral normals would cost about as much as the positions again.
//! - **One blend factor per frame** drives every material group that has a
//!   fade material ([`MaterialGroup::fade_to`]); the README describes how to
//!   draw the cross-fade without popping (a complementary dithered dissolve).
//! - The grid step is the same on all axes and chosen so the *Euclidean*
//!   error `step·√3/2` stays below the requested fraction of the tree height
//!   (the Y extent of [`StreamHeader::bounds`]).
//! - Dequantisation is defined in `f32` arithmetic
//!   (`origin + f32(q) · step`, each operation rounded to `f32`), so the Rust
//!   and JavaScript decoders produce bit-identical positions.
//! - Checksums (CRC-32, as zlib) cover the stored (compressed) bytes, so
//!   corruption is caught before any decompression; the header's also
//!   covers the preamble, so every bit of a stream is checked. Frame
//!   indices must be consecutive, so a lost record is caught too.
//! - The encoder picks the predictor per block by counting non-zero
//!   residuals (a cheap, vectorisable proxy for the compressed size), and
//!   encodes a frame in one pass over blocks of 4096 vertices so its
//!   working set stays in L1. Meshes of 65,536 vertices or more are split
//!   into runs of whole blocks encoded on parallel threads (one per core,
//!   at most 8); the runs are appended in order and each run starts its
//!   predictor from the previous vertex's difference, so the bytes are
//!   exactly those of a sequential pass. Past a few hundred thousand
//!   vertices the pass is bound by memory bandwidth (it reads every
//!   position and the decoder's state once and writes the new state), and
//!   zstd, which cannot be split without changing the format, becomes the
//!   larger cost.
//!
//! # Performance
//! [`bench::run`] measures a synthetic smoothly swaying animation; for
//! 300,000 vertices a frame record is about 0.7 % of the same frame as a
//! GLB, and encoding takes about 2–2.5 ms per frame at zstd level 1 on
//! one core of the 2-core build machine (about 1.5 ms without the zstd
//! step; `Compression::Zstd { level: -5 }` is a faster, 50 % larger
//! middle ground).
//!
//! # Example
//! ```
//! use treemorph_api::delta::*;
//!
//! let bounds = [[-1.0, 0.0, -1.0], [1.0, 2.0, 1.0]];
//! let header = StreamHeader {
//!     bounds,
//!     grid: Grid::for_bounds(bounds, 0.001),
//!     frame_count: 2,
//!     textures: vec![],
//!     materials: vec![Material::default()],
//!     meshes: vec![Mesh {
//!         name: "branches".into(),
//!         indices: vec![0, 1, 2],
//!         uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
//!         groups: vec![MaterialGroup { first: 0, count: 3, material: 0, fade_to: None }],
//!         base_positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
//!     }],
//! };
//! let mut encoder = Encoder::new(header, &EncoderOptions::default())?;
//! let mut stream = encoder.header_bytes().to_vec();
//! let triangle = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
//! encoder.encode_frame(0, 0.0, &[&triangle], 0.0, &mut stream)?;
//! encoder.encode_frame(1, 1.0, &[&triangle], 1.0, &mut stream)?;
//! encoder.finish(&mut stream)?;
//!
//! let mut decoder = Decoder::new(&DecoderOptions::default());
//! for chunk in stream.chunks(7) {
//!     decoder.push(chunk);
//! }
//! let mut frames = 0;
//! while let Some(event) = decoder.next_event()? {
//!     if let Event::Frame(frame) = event {
//!         assert_eq!(frame.index, frames);
//!         frames += 1;
//!     }
//! }
//! decoder.finish()?;
//! assert_eq!(frames, 2);
//! # Ok::<(), DeltaError>(())
//! ```

pub mod bench;
mod decode;
mod encode;
mod types;
mod wire;

pub use decode::{DecodedFrame, Decoder, DecoderOptions, Event, decode_all};
pub use encode::{Compression, Encoder, EncoderOptions};
pub use types::{AlphaMode, Grid, Material, MaterialGroup, Mesh, StreamHeader, Texture};
pub use wire::{MAX_GRID_COORDINATE, VERSION_MAJOR, VERSION_MINOR};

/// The HTTP media type of a delta stream.
pub const MEDIA_TYPE: &str = "application/vnd.treemorph.delta";

/// The conventional file extension of a delta stream saved to disk.
pub const FILE_EXTENSION: &str = "tmd";

/// Everything that can go wrong while encoding or decoding a delta stream.
///
/// Decoder errors (bad bytes from the network) are [`BadMagic`],
/// [`UnsupportedVersion`], [`Truncated`], [`ChecksumMismatch`], [`Corrupt`],
/// [`TooLarge`] and [`FrameOrder`]; encoder errors (the caller's mistake)
/// are [`InvalidHeader`], [`InvalidFrame`], [`FrameOrder`] and [`Finished`];
/// [`Internal`] is a bug or a failure of the zstd library.
///
/// [`BadMagic`]: DeltaError::BadMagic
/// [`UnsupportedVersion`]: DeltaError::UnsupportedVersion
/// [`Truncated`]: DeltaError::Truncated
/// [`ChecksumMismatch`]: DeltaError::ChecksumMismatch
/// [`Corrupt`]: DeltaError::Corrupt
/// [`TooLarge`]: DeltaError::TooLarge
/// [`FrameOrder`]: DeltaError::FrameOrder
/// [`InvalidHeader`]: DeltaError::InvalidHeader
/// [`InvalidFrame`]: DeltaError::InvalidFrame
/// [`Finished`]: DeltaError::Finished
/// [`Internal`]: DeltaError::Internal
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DeltaError {
    /// The stream does not start with the magic bytes `TMDS`.
    #[error("not a treemorph delta stream (bad magic bytes)")]
    BadMagic,
    /// The stream's major version is not one this decoder reads.
    #[error(
        "unsupported delta stream version {major}.{minor} (this decoder reads {}.x)",
        VERSION_MAJOR
    )]
    UnsupportedVersion {
        /// Major version found in the preamble.
        major: u16,
        /// Minor version found in the preamble.
        minor: u16,
    },
    /// The stream ended before its end record (cut connection, cancelled
    /// job): the `frames` frames already returned are intact.
    #[error("stream truncated at byte {offset}, after {frames} complete frames")]
    Truncated {
        /// Stream bytes received in total.
        offset: u64,
        /// Frames decoded before the cut.
        frames: u32,
    },
    /// A record's CRC-32 does not match its bytes.
    #[error("checksum mismatch in the record at byte {offset}, after {frames} frames")]
    ChecksumMismatch {
        /// Stream offset of the record's first byte.
        offset: u64,
        /// Frames decoded before the damaged record.
        frames: u32,
    },
    /// A record passed its checksum but its content is inconsistent.
    #[error("corrupt delta stream in the record at byte {offset}: {reason}")]
    Corrupt {
        /// Stream offset of the record's first byte.
        offset: u64,
        /// What is wrong.
        reason: String,
    },
    /// A declared size exceeds a [`DecoderOptions`] limit.
    #[error("{what} is {size}, over the limit of {limit}")]
    TooLarge {
        /// Which quantity (e.g. `"vertex count"`).
        what: &'static str,
        /// The declared size.
        size: u64,
        /// The configured limit.
        limit: u64,
    },
    /// Frames must be numbered 0, 1, 2, … without gaps: each is a delta
    /// against the one before.
    #[error("frame {found} where frame {expected} was expected")]
    FrameOrder {
        /// The next index in sequence.
        expected: u32,
        /// The index given or found.
        found: u32,
    },
    /// The encoder was given an inconsistent [`StreamHeader`].
    #[error("invalid stream header: {0}")]
    InvalidHeader(String),
    /// The encoder was given a frame that does not fit the header.
    #[error("invalid frame {index}: {reason}")]
    InvalidFrame {
        /// The frame's index.
        index: u32,
        /// What is wrong.
        reason: String,
    },
    /// [`Encoder::finish`] was already called.
    #[error("the stream is already finished")]
    Finished,
    /// A bug, or a failure inside the zstd library.
    #[error("internal error: {0}")]
    Internal(String),
}

#[cfg(test)]
mod tests;
