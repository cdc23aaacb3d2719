//! The encoder: a reusable context that turns frames into records.

use super::DeltaError;
use super::types::{Quantiser, StreamHeader};
use super::wire::{self, BLOCK, FRAME_FIXED_LEN, KIND_END, KIND_FRAME, KIND_HEADER, write_block};

/// How record payloads are compressed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Compression {
    /// Payloads are stored as they are (for debugging and the README's
    /// worked example).
    None,
    /// zstd at the given level (negative levels are zstd's fast modes;
    /// 1–3 are the useful range for live streaming).
    Zstd {
        /// zstd compression level.
        level: i32,
    },
}

/// Encoder settings.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct EncoderOptions {
    /// Payload compression. Default: zstd level 1 (about 1 ms per frame of
    /// 300,000 vertices on one core; higher levels gain a few percent).
    /// A record whose compressed payload is not smaller is stored as is.
    pub compression: Compression,
}

impl Default for EncoderOptions {
    fn default() -> Self {
        EncoderOptions {
            compression: Compression::Zstd { level: 1 },
        }
    }
}

impl EncoderOptions {
    /// Options with the given compression.
    pub fn with_compression(compression: Compression) -> Self {
        EncoderOptions { compression }
    }
}

/// Encodes one stream: [`header_bytes`](Encoder::header_bytes) first, then
/// [`encode_frame`](Encoder::encode_frame) for frames 0, 1, 2, … and
/// [`finish`](Encoder::finish).
///
/// The encoder tracks the grid coordinates the decoder will hold after each
/// frame and sends differences against those, so quantisation error never
/// accumulates. Its buffers are kept between frames: after the first frame,
/// encoding allocates nothing unless `out` must grow.
pub struct Encoder {
    header: StreamHeader,
    header_bytes: Vec<u8>,
    compressor: Option<zstd::bulk::Compressor<'static>>,
    /// The decoder's grid coordinates: `state[mesh][axis][vertex]`.
    state: Vec<[Vec<i32>; 3]>,
    /// The frame being encoded, same layout; swapped with `state` on success.
    next: Vec<[Vec<i32>; 3]>,
    deltas: Vec<i32>,
    zigzags: Vec<u32>,
    payload: Vec<u8>,
    compressed: Vec<u8>,
    next_index: u32,
    finished: bool,
}

impl Encoder {
    /// Checks `header`, snaps its base positions to its grid and writes the
    /// preamble and header record (see [`header_bytes`](Self::header_bytes)).
    ///
    /// Errors: [`DeltaError::InvalidHeader`] for an inconsistent header or
    /// a base position that is not finite or off the grid's range.
    pub fn new(mut header: StreamHeader, options: &EncoderOptions) -> Result<Self, DeltaError> {
        header.check().map_err(DeltaError::InvalidHeader)?;
        let mut compressor = match options.compression {
            Compression::None => None,
            Compression::Zstd { level } => Some(
                zstd::bulk::Compressor::new(level)
                    .map_err(|e| DeltaError::Internal(format!("zstd: {e}")))?,
            ),
        };
        let grid = header.grid;
        let mut state = Vec::with_capacity(header.meshes.len());
        for (m, mesh) in header.meshes.iter_mut().enumerate() {
            let n = mesh.base_positions.len();
            let mut axes: [Vec<i32>; 3] = [vec![0; n], vec![0; n], vec![0; n]];
            for (i, p) in mesh.base_positions.iter_mut().enumerate() {
                let q = grid.quantise(*p).ok_or_else(|| {
                    DeltaError::InvalidHeader(format!(
                        "mesh {m} base position {i} ({p:?}) is not finite or off the grid"
                    ))
                })?;
                for a in 0..3 {
                    axes[a][i] = q[a];
                }
                *p = grid.dequantise(q);
            }
            state.push(axes);
        }
        let mut raw = Vec::new();
        wire::write_header(&mut raw, &header, &state);
        let mut header_bytes = wire::preamble().to_vec();
        let mut scratch = Vec::new();
        wire::write_record(
            &mut header_bytes,
            KIND_HEADER,
            &raw,
            compressor.as_mut(),
            &mut scratch,
        )?;
        // Sized for the largest possible frame, so encoding never
        // reallocates.
        let max_payload = Self::max_frame_payload(state.iter().map(|axes| axes[0].len()));
        let compressed_capacity = if compressor.is_some() {
            zstd::zstd_safe::compress_bound(max_payload)
        } else {
            0
        };
        Ok(Encoder {
            next: state.clone(),
            state,
            header,
            header_bytes,
            compressor,
            deltas: vec![0; BLOCK],
            zigzags: vec![0; BLOCK],
            payload: Vec::with_capacity(max_payload),
            compressed: Vec::with_capacity(compressed_capacity),
            next_index: 0,
            finished: false,
        })
    }

    /// The preamble and header record: the first bytes of the stream.
    pub fn header_bytes(&self) -> &[u8] {
        &self.header_bytes
    }

    /// The header as the decoder will return it (base positions snapped to
    /// the grid).
    pub fn header(&self) -> &StreamHeader {
        &self.header
    }

    /// Index the next [`encode_frame`](Self::encode_frame) call must use.
    pub fn next_index(&self) -> u32 {
        self.next_index
    }

    /// Appends frame `index`'s record to `out`.
    ///
    /// `positions` holds one slice per mesh, in header order, with one
    /// position per vertex; `t` is the animation time and `leaf_blend` the
    /// cross-fade factor, both in [0, 1]. On error nothing is written and
    /// the encoder's state is unchanged.
    ///
    /// Errors: [`DeltaError::FrameOrder`] unless `index` is
    /// [`next_index`](Self::next_index); [`DeltaError::InvalidFrame`] for
    /// wrong counts, `t` or `leaf_blend` outside [0, 1], or a position that
    /// is not finite or off the grid's range; [`DeltaError::Finished`] after
    /// [`finish`](Self::finish).
    pub fn encode_frame(
        &mut self,
        index: u32,
        t: f32,
        positions: &[&[[f32; 3]]],
        leaf_blend: f32,
        out: &mut Vec<u8>,
    ) -> Result<(), DeltaError> {
        if self.finished {
            return Err(DeltaError::Finished);
        }
        if index != self.next_index {
            return Err(DeltaError::FrameOrder {
                expected: self.next_index,
                found: index,
            });
        }
        let invalid = |reason: String| DeltaError::InvalidFrame { index, reason };
        if !(0.0..=1.0).contains(&t) {
            return Err(invalid(format!("t = {t} is outside [0, 1]")));
        }
        if !(0.0..=1.0).contains(&leaf_blend) {
            return Err(invalid(format!(
                "leaf blend {leaf_blend} is outside [0, 1]"
            )));
        }
        if positions.len() != self.state.len() {
            return Err(invalid(format!(
                "{} position slices for {} meshes",
                positions.len(),
                self.state.len()
            )));
        }
        self.payload.clear();
        self.payload.extend_from_slice(&index.to_le_bytes());
        self.payload.extend_from_slice(&t.to_le_bytes());
        self.payload.extend_from_slice(&leaf_blend.to_le_bytes());
        let quantiser = self.header.grid.quantiser();
        for (m, ((mesh, next), state)) in positions
            .iter()
            .zip(&mut self.next)
            .zip(&self.state)
            .enumerate()
        {
            let n = next[0].len();
            if mesh.len() != n {
                return Err(invalid(format!(
                    "mesh {m} has {} positions for {n} vertices",
                    mesh.len()
                )));
            }
            // One pass over the frame, a block of vertices at a time, so
            // the deltas stay in L1: quantise into `next`, then write the
            // block's x, y and z differences from `state`.
            let mut in_range = true;
            let mut before = [0i32; 3];
            for start in (0..n).step_by(BLOCK) {
                let end = (start + BLOCK).min(n);
                let [xs, ys, zs] = next;
                let (xs, ys, zs) = (
                    &mut xs[start..end],
                    &mut ys[start..end],
                    &mut zs[start..end],
                );
                for (((p, x), y), z) in mesh[start..end].iter().zip(xs).zip(ys).zip(zs) {
                    let c = [0, 1, 2].map(|a| quantiser.coordinate(a, p[a]));
                    in_range &= Quantiser::in_range(c[0])
                        & Quantiser::in_range(c[1])
                        & Quantiser::in_range(c[2]);
                    *x = Quantiser::round(c[0]);
                    *y = Quantiser::round(c[1]);
                    *z = Quantiser::round(c[2]);
                }
                for axis in 0..3 {
                    let deltas = &mut self.deltas[..end - start];
                    for ((d, &new), &old) in deltas
                        .iter_mut()
                        .zip(&next[axis][start..end])
                        .zip(&state[axis][start..end])
                    {
                        *d = new.wrapping_sub(old);
                    }
                    write_block(&mut self.payload, deltas, before[axis], &mut self.zigzags);
                    before[axis] = deltas[deltas.len() - 1];
                }
            }
            if !in_range {
                let grid = self.header.grid;
                let i = mesh
                    .iter()
                    .position(|p| grid.quantise(*p).is_none())
                    .unwrap_or(0);
                return Err(invalid(format!(
                    "mesh {m} position {i} ({:?}) is not finite or off the grid",
                    mesh.get(i)
                )));
            }
        }
        wire::write_record(
            out,
            KIND_FRAME,
            &self.payload,
            self.compressor.as_mut(),
            &mut self.compressed,
        )?;
        std::mem::swap(&mut self.state, &mut self.next);
        self.next_index += 1;
        Ok(())
    }

    /// Appends the end record (carrying the number of frames encoded).
    ///
    /// Errors: [`DeltaError::Finished`] when called twice;
    /// [`DeltaError::InvalidFrame`] when the header announced a frame count
    /// and a different number of frames was encoded.
    pub fn finish(&mut self, out: &mut Vec<u8>) -> Result<(), DeltaError> {
        if self.finished {
            return Err(DeltaError::Finished);
        }
        let announced = self.header.frame_count;
        if announced != 0 && announced != self.next_index {
            return Err(DeltaError::InvalidFrame {
                index: self.next_index,
                reason: format!(
                    "the header announced {announced} frames but {} were encoded",
                    self.next_index
                ),
            });
        }
        self.finished = true;
        wire::write_record(
            out,
            KIND_END,
            &self.next_index.to_le_bytes(),
            None,
            &mut self.compressed,
        )
    }

    /// The positions the decoder holds after the last encoded frame (the
    /// base positions before the first), per mesh.
    pub fn reconstructed_positions(&self) -> Vec<Vec<[f32; 3]>> {
        let grid = self.header.grid;
        self.state
            .iter()
            .map(|[xs, ys, zs]| {
                (0..xs.len())
                    .map(|i| grid.dequantise([xs[i], ys[i], zs[i]]))
                    .collect()
            })
            .collect()
    }

    /// Largest possible frame payload before compression, bytes.
    pub(crate) fn max_frame_payload(vertex_counts: impl Iterator<Item = usize>) -> usize {
        FRAME_FIXED_LEN
            + vertex_counts
                .map(|n| 3 * (1 + n.div_ceil(BLOCK) + 4 * n))
                .sum::<usize>()
    }

    /// Capacities of the per-frame buffers (for the no-reallocation test).
    #[cfg(test)]
    pub(crate) fn buffer_capacities(&self) -> [usize; 3] {
        [
            self.zigzags.capacity(),
            self.payload.capacity(),
            self.compressed.capacity(),
        ]
    }
}
