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
/// encoding allocates nothing unless `out` must grow (meshes of 65,536
/// vertices or more are encoded on scoped worker threads, one per core, at
/// most 8, started for each frame; their buffers are kept too).
pub struct Encoder {
    header: StreamHeader,
    header_bytes: Vec<u8>,
    compressor: Option<zstd::bulk::Compressor<'static>>,
    /// The decoder's grid coordinates: `state[mesh][axis][vertex]`.
    state: Vec<[Vec<i32>; 3]>,
    /// Those of the header's base positions, where [`Encoder::restart`]
    /// starts again.
    base: Vec<[Vec<i32>; 3]>,
    /// The frame being encoded, same layout; swapped with `state` on success.
    next: Vec<[Vec<i32>; 3]>,
    /// One per worker thread (the first is the calling thread's).
    scratch: Vec<Scratch>,
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
        let workers = std::thread::available_parallelism()
            .map_or(1, |n| n.get())
            .clamp(1, MAX_WORKERS);
        let largest = state.iter().map(|axes| axes[0].len()).max().unwrap_or(0);
        let run_payload = Self::max_frame_payload(std::iter::once(
            largest.div_ceil(BLOCK).div_ceil(workers) * BLOCK,
        ));
        let compressed_capacity = if compressor.is_some() {
            zstd::zstd_safe::compress_bound(max_payload)
        } else {
            0
        };
        Ok(Encoder {
            next: state.clone(),
            base: state.clone(),
            state,
            header,
            header_bytes,
            compressor,
            scratch: (0..workers)
                .map(|w| Scratch {
                    deltas: vec![0; BLOCK],
                    zigzags: vec![0; BLOCK],
                    // The calling thread writes into `payload` itself.
                    out: Vec::with_capacity(if w == 0 { 0 } else { run_payload }),
                })
                .collect(),
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

    /// Starts the same stream again after its header: the next frame is
    /// frame 0, encoded against the header's base positions, so
    /// [`header_bytes`](Self::header_bytes) followed by what is encoded
    /// from now on is the stream a new encoder of the same header would
    /// write. A renderer of one instant at a time of one animation (the
    /// service's `stream?t=`) makes the header — its meshes, textures and
    /// compression — once this way.
    pub fn restart(&mut self) {
        for (state, base) in self.state.iter_mut().zip(&self.base) {
            for (axis, from) in state.iter_mut().zip(base) {
                axis.clone_from(from);
            }
        }
        self.next_index = 0;
        self.finished = false;
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
        self.encode_frame_of(index, t, positions, leaf_blend, out)
    }

    /// [`encode_frame`](Self::encode_frame) for positions of any point
    /// type that converts to `[f32; 3]` (a vector type with three `f32`
    /// fields, such as `glam::Vec3`), so a mesher's buffers are encoded
    /// without copying them first.
    pub fn encode_frame_of<P: Copy + Into<[f32; 3]> + Sync>(
        &mut self,
        index: u32,
        t: f32,
        positions: &[&[P]],
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
            // Blocks are independent but for the value each one's
            // predictor starts from, so a large mesh is split into runs of
            // whole blocks encoded on parallel threads, each into its own
            // buffer, appended in order: the bytes are exactly those of
            // one sequential pass.
            let blocks = n.div_ceil(BLOCK);
            let runs = if n >= PARALLEL_MIN_VERTICES {
                self.scratch.len().min(blocks)
            } else {
                1
            };
            let in_range = if runs <= 1 {
                let [xs, ys, zs] = next;
                let [sx, sy, sz] = state;
                let s = &mut self.scratch[0];
                encode_run(
                    &quantiser,
                    mesh,
                    [xs, ys, zs],
                    [sx, sy, sz],
                    [0; 3],
                    &mut s.deltas,
                    &mut s.zigzags,
                    &mut self.payload,
                )
            } else {
                let run_len = blocks.div_ceil(runs) * BLOCK;
                encode_parallel(
                    &quantiser,
                    mesh,
                    next,
                    state,
                    run_len,
                    &mut self.scratch[..runs],
                    &mut self.payload,
                )
            };
            if !in_range {
                let grid = self.header.grid;
                let i = mesh
                    .iter()
                    .position(|&p| grid.quantise(p.into()).is_none())
                    .unwrap_or(0);
                return Err(invalid(format!(
                    "mesh {m} position {i} ({:?}) is not finite or off the grid",
                    mesh.get(i).map(|&p| p.into())
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

    /// Encodes on at most `workers` threads from now on (tests compare the
    /// parallel encoding with the sequential one).
    #[cfg(test)]
    pub(crate) fn limit_workers(&mut self, workers: usize) {
        self.scratch.truncate(workers.max(1));
    }

    /// Capacities of the per-frame buffers (for the no-reallocation test).
    #[cfg(test)]
    pub(crate) fn buffer_capacities(&self) -> [usize; 3] {
        [
            self.scratch
                .iter()
                .map(|s| s.zigzags.capacity() + s.out.capacity())
                .sum(),
            self.payload.capacity(),
            self.compressed.capacity(),
        ]
    }
}

/// Meshes with fewer vertices are encoded on the calling thread alone.
const PARALLEL_MIN_VERTICES: usize = 1 << 16;
/// Most threads one frame is encoded on.
const MAX_WORKERS: usize = 8;

/// Buffers of one encoding thread.
struct Scratch {
    deltas: Vec<i32>,
    zigzags: Vec<u32>,
    /// The run's bytes (unused by the calling thread).
    out: Vec<u8>,
}

/// Encodes a run of whole blocks of one mesh — one pass, a block of
/// vertices at a time, so the deltas stay in L1: quantise into `next`,
/// then write the block's x, y and z differences from `state`. `before`
/// holds the differences of the vertex preceding the run (0 at the start
/// of a mesh). Returns whether every position was on the grid.
#[allow(clippy::too_many_arguments)]
#[inline]
fn encode_run<P: Copy + Into<[f32; 3]>>(
    quantiser: &Quantiser,
    mesh: &[P],
    next: [&mut [i32]; 3],
    state: [&[i32]; 3],
    mut before: [i32; 3],
    deltas: &mut [i32],
    zigzags: &mut [u32],
    out: &mut Vec<u8>,
) -> bool {
    let n = mesh.len();
    let mut in_range = true;
    let [xs_all, ys_all, zs_all] = next;
    for start in (0..n).step_by(BLOCK) {
        let end = (start + BLOCK).min(n);
        let (xs, ys, zs) = (
            &mut xs_all[start..end],
            &mut ys_all[start..end],
            &mut zs_all[start..end],
        );
        for (((&p, x), y), z) in mesh[start..end].iter().zip(xs).zip(ys).zip(zs) {
            let p: [f32; 3] = p.into();
            let c = [0, 1, 2].map(|a| quantiser.coordinate(a, p[a]));
            in_range &=
                Quantiser::in_range(c[0]) & Quantiser::in_range(c[1]) & Quantiser::in_range(c[2]);
            *x = Quantiser::round(c[0]);
            *y = Quantiser::round(c[1]);
            *z = Quantiser::round(c[2]);
        }
        let news = [
            &xs_all[start..end],
            &ys_all[start..end],
            &zs_all[start..end],
        ];
        for axis in 0..3 {
            let deltas = &mut deltas[..end - start];
            for ((d, &new), &old) in deltas
                .iter_mut()
                .zip(news[axis])
                .zip(&state[axis][start..end])
            {
                *d = new.wrapping_sub(old);
            }
            write_block(out, deltas, before[axis], zigzags);
            before[axis] = deltas[deltas.len() - 1];
        }
    }
    in_range
}

/// Encodes one mesh as runs of `run_len` vertices (whole blocks) on
/// `scratch.len()` threads, the first run on the calling thread straight
/// into `payload`, the others into their scratch buffers, appended after.
#[allow(clippy::too_many_arguments)]
fn encode_parallel<P: Copy + Into<[f32; 3]> + Sync>(
    quantiser: &Quantiser,
    mesh: &[P],
    next: &mut [Vec<i32>; 3],
    state: &[Vec<i32>; 3],
    run_len: usize,
    scratch: &mut [Scratch],
    payload: &mut Vec<u8>,
) -> bool {
    let [xs, ys, zs] = next;
    let runs = xs
        .chunks_mut(run_len)
        .zip(ys.chunks_mut(run_len))
        .zip(zs.chunks_mut(run_len))
        .zip(scratch.iter_mut())
        .enumerate();
    let ok = std::thread::scope(|scope| {
        let mut first = None;
        let mut handles = Vec::with_capacity(MAX_WORKERS);
        for (r, (((x, y), z), s)) in runs {
            let start = r * run_len;
            let end = start + x.len();
            // The differences of the vertex before the run, computed as
            // the sequential pass would (without a range check: an
            // off-grid vertex fails the frame anyway).
            let before = if start == 0 {
                [0; 3]
            } else {
                let p: [f32; 3] = mesh[start - 1].into();
                [0, 1, 2].map(|a| {
                    Quantiser::round(quantiser.coordinate(a, p[a]))
                        .wrapping_sub(state[a][start - 1])
                })
            };
            let run_state = [
                &state[0][start..end],
                &state[1][start..end],
                &state[2][start..end],
            ];
            let run_mesh = &mesh[start..end];
            if r == 0 {
                first = Some((run_mesh, [x, y, z], run_state, s));
            } else {
                handles.push(scope.spawn(move || {
                    s.out.clear();
                    encode_run(
                        quantiser,
                        run_mesh,
                        [x, y, z],
                        run_state,
                        before,
                        &mut s.deltas,
                        &mut s.zigzags,
                        &mut s.out,
                    )
                }));
            }
        }
        let mut ok = match first {
            Some((run_mesh, next, run_state, s)) => encode_run(
                quantiser,
                run_mesh,
                next,
                run_state,
                [0; 3],
                &mut s.deltas,
                &mut s.zigzags,
                payload,
            ),
            None => true,
        };
        for h in handles {
            // A panicking worker is a bug; fail the frame rather than the
            // process.
            ok &= h.join().unwrap_or(false);
        }
        ok
    });
    let runs = mesh.len().div_ceil(run_len);
    for s in &scratch[1..runs] {
        payload.extend_from_slice(&s.out);
    }
    ok
}
