//! The incremental decoder: bytes in (any chunking), events out.

use super::types::{Grid, StreamHeader};
use super::wire::{
    self, CODEC_STORED, CODEC_ZSTD, CRC_LEN, GridCoordinates, KIND_ANCILLARY, KIND_END, KIND_FRAME,
    KIND_HEADER, MAGIC, MAX_GRID_COORDINATE, PREAMBLE_LEN, PREFIX_LEN, Reader, VERSION_MAJOR,
    check_limit,
};
use super::{DeltaError, Encoder};

/// Limits the decoder enforces before allocating anything a stream
/// declares. The defaults admit ten times the largest animation treemorph
/// produces (20,000 chains, a few hundred thousand vertices).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct DecoderOptions {
    /// Most meshes in a stream. Default 16.
    pub max_meshes: u32,
    /// Most vertices over all meshes. Default 4,000,000.
    pub max_vertices: u64,
    /// Most indices over all meshes. Default 24,000,000.
    pub max_indices: u64,
    /// Most material groups over all meshes. Default 65,536.
    pub max_groups: u32,
    /// Most materials. Default 1,024.
    pub max_materials: u32,
    /// Most textures. Default 256.
    pub max_textures: u32,
    /// Most texture bytes in total. Default 64 MiB.
    pub max_texture_bytes: u64,
    /// Longest mesh or material name, bytes. Default 1,024.
    pub max_name_bytes: u32,
    /// Largest record, stored or decompressed, bytes. Default 256 MiB.
    pub max_record_bytes: u64,
}

impl Default for DecoderOptions {
    fn default() -> Self {
        DecoderOptions {
            max_meshes: 16,
            max_vertices: 4_000_000,
            max_indices: 24_000_000,
            max_groups: 65_536,
            max_materials: 1_024,
            max_textures: 256,
            max_texture_bytes: 64 << 20,
            max_name_bytes: 1_024,
            max_record_bytes: 256 << 20,
        }
    }
}

/// One decoded frame.
#[derive(Clone, Debug, PartialEq)]
pub struct DecodedFrame {
    /// Frame index: 0, 1, 2, … in stream order.
    pub index: u32,
    /// Animation time in [0, 1].
    pub t: f32,
    /// Leaf cross-fade factor in [0, 1] (see [`MaterialGroup::fade_to`](super::MaterialGroup::fade_to)).
    pub leaf_blend: f32,
    /// Positions per mesh, in header order, metres.
    pub positions: Vec<Vec<[f32; 3]>>,
}

/// What the decoder found next in the stream.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    /// The stream header: always the first event.
    Header(Box<StreamHeader>),
    /// The next frame.
    Frame(DecodedFrame),
    /// The end record: the stream is complete with this many frames.
    End {
        /// Number of frames in the stream.
        frames: u32,
    },
}

#[derive(Clone, Debug, PartialEq)]
enum State {
    Preamble,
    Header,
    Frames,
    Ended,
    Failed(DeltaError),
}

/// Decodes a stream incrementally: [`push`](Decoder::push) bytes as they
/// arrive, in chunks of any size, and call
/// [`next_event`](Decoder::next_event) until it returns `Ok(None)` (more
/// bytes needed). At the end of input call [`finish`](Decoder::finish) to
/// learn whether the stream was complete.
///
/// Every declared count is checked against [`DecoderOptions`] and against
/// the bytes actually present before anything is allocated; hostile input
/// yields an error, never a panic. Errors are sticky: once one is returned,
/// every later call returns it again.
pub struct Decoder {
    options: DecoderOptions,
    buf: Vec<u8>,
    /// Start of the unconsumed bytes in `buf`.
    start: usize,
    /// Stream offset of `buf[start]`.
    offset: u64,
    state: State,
    minor: u16,
    grid: Grid,
    frame_count: u32,
    max_frame_payload: usize,
    /// Grid coordinates of the last decoded frame: `q[mesh][axis][vertex]`.
    q: GridCoordinates,
    frames: u32,
    decompressor: Option<zstd::bulk::Decompressor<'static>>,
    raw: Vec<u8>,
}

impl Decoder {
    /// A decoder waiting for the first byte of a stream.
    pub fn new(options: &DecoderOptions) -> Self {
        Decoder {
            options: options.clone(),
            buf: Vec::new(),
            start: 0,
            offset: 0,
            state: State::Preamble,
            minor: 0,
            grid: Grid {
                origin: [0.0; 3],
                step: [1.0; 3],
            },
            frame_count: 0,
            max_frame_payload: 0,
            q: Vec::new(),
            frames: 0,
            decompressor: None,
            raw: Vec::new(),
        }
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        if self.start > 0 {
            self.buf.drain(..self.start);
            self.start = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    /// Frames decoded so far.
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// Whether the end record has been decoded.
    pub fn is_complete(&self) -> bool {
        self.state == State::Ended
    }

    /// The next event, `Ok(None)` when more bytes are needed (or after
    /// [`Event::End`]).
    ///
    /// Errors: [`DeltaError::BadMagic`], [`DeltaError::UnsupportedVersion`],
    /// [`DeltaError::ChecksumMismatch`], [`DeltaError::Corrupt`],
    /// [`DeltaError::TooLarge`], [`DeltaError::FrameOrder`].
    pub fn next_event(&mut self) -> Result<Option<Event>, DeltaError> {
        if let State::Failed(e) = &self.state {
            return Err(e.clone());
        }
        let result = self.step();
        if let Err(e) = &result {
            self.state = State::Failed(e.clone());
        }
        result
    }

    /// Declares the end of input: `Ok` if the stream was complete (its end
    /// record decoded and nothing after it). Call it once
    /// [`next_event`](Self::next_event) has returned `Ok(None)`.
    ///
    /// Errors: [`DeltaError::Truncated`] when the end record is missing, or
    /// the decoder's sticky error.
    pub fn finish(&mut self) -> Result<(), DeltaError> {
        match &self.state {
            State::Failed(e) => Err(e.clone()),
            State::Ended if self.available() == 0 => Ok(()),
            State::Ended => Err(DeltaError::Corrupt {
                offset: self.offset,
                reason: "bytes after the end record".into(),
            }),
            _ => Err(DeltaError::Truncated {
                offset: self.offset + self.available() as u64,
                frames: self.frames,
            }),
        }
    }

    fn available(&self) -> usize {
        self.buf.len() - self.start
    }

    fn consume(&mut self, n: usize) {
        self.start += n;
        self.offset += n as u64;
    }

    fn step(&mut self) -> Result<Option<Event>, DeltaError> {
        loop {
            match self.state {
                State::Failed(_) => unreachable!("checked by next_event"),
                State::Ended => {
                    if self.available() > 0 {
                        return Err(DeltaError::Corrupt {
                            offset: self.offset,
                            reason: "bytes after the end record".into(),
                        });
                    }
                    return Ok(None);
                }
                State::Preamble => {
                    let bytes = &self.buf[self.start..];
                    // Reject a wrong magic as soon as its bytes arrive.
                    let n = bytes.len().min(MAGIC.len());
                    if bytes[..n] != MAGIC[..n] {
                        return Err(DeltaError::BadMagic);
                    }
                    if bytes.len() < PREAMBLE_LEN {
                        return Ok(None);
                    }
                    let major = u16::from_le_bytes([bytes[4], bytes[5]]);
                    let minor = u16::from_le_bytes([bytes[6], bytes[7]]);
                    if major != VERSION_MAJOR {
                        return Err(DeltaError::UnsupportedVersion { major, minor });
                    }
                    self.minor = minor;
                    self.consume(PREAMBLE_LEN);
                    self.state = State::Header;
                }
                State::Header | State::Frames => {
                    let Some((kind, len)) = self.record()? else {
                        return Ok(None);
                    };
                    let event = self.dispatch(kind)?;
                    self.consume(len);
                    if event.is_some() {
                        return Ok(event);
                    }
                }
            }
        }
    }

    /// Checks the next record once it is complete and leaves its payload in
    /// `self.raw`: its kind and total length.
    fn record(&mut self) -> Result<Option<(u8, usize)>, DeltaError> {
        let bytes = &self.buf[self.start..];
        if bytes.len() < PREFIX_LEN {
            return Ok(None);
        }
        let word =
            |i: usize| u32::from_le_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]);
        let (kind, codec, stored_len, raw_len) = (bytes[0], bytes[1], word(4), word(8));
        let limit = self.options.max_record_bytes;
        check_limit("record size", stored_len.into(), limit)?;
        check_limit("decompressed record size", raw_len.into(), limit)?;
        let len = PREFIX_LEN + stored_len as usize + CRC_LEN;
        if bytes.len() < len {
            return Ok(None);
        }
        let record = &bytes[..len];
        let crc = u32::from_le_bytes(record[len - 4..].try_into().expect("4 bytes"));
        let preamble = wire::preamble_of(self.minor);
        if wire::record_crc(kind, &record[..len - 4], &preamble) != crc {
            return Err(DeltaError::ChecksumMismatch {
                offset: self.offset,
                frames: self.frames,
            });
        }
        let corrupt = |reason: String| DeltaError::Corrupt {
            offset: self.offset,
            reason,
        };
        if kind == KIND_FRAME
            && !wire::newer_minor(self.minor)
            && self.state == State::Frames
            && raw_len as usize > self.max_frame_payload
        {
            return Err(corrupt(format!(
                "a frame payload of {raw_len} bytes is larger than any frame of this header"
            )));
        }
        let stored = &record[PREFIX_LEN..len - CRC_LEN];
        self.raw.clear();
        match codec {
            CODEC_STORED => {
                if raw_len != stored_len {
                    return Err(corrupt(format!(
                        "stored payload of {stored_len} bytes declares {raw_len} bytes"
                    )));
                }
                self.raw.extend_from_slice(stored);
            }
            CODEC_ZSTD => {
                // Exactly one zstd frame declaring exactly `raw_len` bytes:
                // the JavaScript decoder relies on both, so both enforce it.
                let frame_len = zstd::zstd_safe::find_frame_compressed_size(stored).ok();
                let content = zstd::zstd_safe::get_frame_content_size(stored)
                    .ok()
                    .flatten();
                if frame_len != Some(stored.len()) || content != Some(raw_len.into()) {
                    return Err(corrupt(format!(
                        "the payload is not one zstd frame of {raw_len} bytes"
                    )));
                }
                let decompressor = match &mut self.decompressor {
                    Some(d) => d,
                    None => self.decompressor.insert(
                        zstd::bulk::Decompressor::new()
                            .map_err(|e| DeltaError::Internal(format!("zstd: {e}")))?,
                    ),
                };
                self.raw.reserve(raw_len as usize);
                let written = decompressor
                    .decompress_to_buffer(stored, &mut self.raw)
                    .map_err(|e| corrupt(format!("zstd: {e}")))?;
                if written != raw_len as usize {
                    return Err(corrupt(format!(
                        "zstd payload decompressed to {written} bytes, not {raw_len}"
                    )));
                }
            }
            _ => return Err(corrupt(format!("unknown codec {codec}"))),
        }
        Ok(Some((kind, len)))
    }

    fn dispatch(&mut self, kind: u8) -> Result<Option<Event>, DeltaError> {
        let raw = std::mem::take(&mut self.raw);
        let result = self.parse(kind, &raw);
        self.raw = raw;
        result
    }

    fn parse(&mut self, kind: u8, raw: &[u8]) -> Result<Option<Event>, DeltaError> {
        let mut r = Reader::new(raw, self.offset);
        let event = match (kind, &self.state) {
            (KIND_HEADER, State::Header) => {
                let (header, q) = wire::read_header(&mut r, &self.options, self.minor)?;
                self.grid = header.grid;
                self.frame_count = header.frame_count;
                self.max_frame_payload =
                    Encoder::max_frame_payload(header.meshes.iter().map(|m| m.vertex_count()));
                self.q = q;
                self.state = State::Frames;
                Event::Header(Box::new(header))
            }
            (KIND_FRAME, State::Frames) => Event::Frame(self.parse_frame(&mut r)?),
            (KIND_END, State::Frames) => {
                let frames = r.u32()?;
                if frames != self.frames {
                    return Err(r.corrupt(format!(
                        "the end record counts {frames} frames but {} were sent",
                        self.frames
                    )));
                }
                if self.frame_count != 0 && frames != self.frame_count {
                    return Err(r.corrupt(format!(
                        "the header announced {} frames but the stream has {frames}",
                        self.frame_count
                    )));
                }
                self.check_trailing(&r)?;
                self.state = State::Ended;
                Event::End { frames }
            }
            (k, _) if k & KIND_ANCILLARY != 0 => return Ok(None),
            (KIND_HEADER | KIND_FRAME | KIND_END, _) => {
                return Err(r.corrupt(format!("record kind {:?} out of place", char::from(kind))));
            }
            _ => return Err(r.corrupt(format!("unknown record kind 0x{kind:02x}"))),
        };
        Ok(Some(event))
    }

    fn parse_frame(&mut self, r: &mut Reader<'_>) -> Result<DecodedFrame, DeltaError> {
        let index = r.u32()?;
        if index != self.frames {
            return Err(DeltaError::FrameOrder {
                expected: self.frames,
                found: index,
            });
        }
        let t = r.f32()?;
        let leaf_blend = r.f32()?;
        if !(0.0..=1.0).contains(&t) || !(0.0..=1.0).contains(&leaf_blend) {
            return Err(r.corrupt(format!(
                "frame {index}: t = {t} or leaf blend {leaf_blend} outside [0, 1]"
            )));
        }
        let mut in_range = true;
        for mesh in &mut self.q {
            r.read_positions(mesh, |q, d| {
                let v = q.wrapping_add(d);
                in_range &= v.unsigned_abs() <= MAX_GRID_COORDINATE as u32
                    && i64::from(*q) + i64::from(d) == i64::from(v);
                *q = v;
            })?;
        }
        if !in_range {
            return Err(r.corrupt(format!("frame {index}: a grid coordinate is out of range")));
        }
        self.check_trailing(r)?;
        let grid = self.grid;
        let positions = self
            .q
            .iter()
            .map(|[xs, ys, zs]| {
                xs.iter()
                    .zip(ys)
                    .zip(zs)
                    .map(|((&x, &y), &z)| grid.dequantise([x, y, z]))
                    .collect()
            })
            .collect();
        self.frames += 1;
        Ok(DecodedFrame {
            index,
            t,
            leaf_blend,
            positions,
        })
    }

    fn check_trailing(&self, r: &Reader<'_>) -> Result<(), DeltaError> {
        if r.remaining() > 0 && !wire::newer_minor(self.minor) {
            return Err(r.corrupt(format!(
                "{} unexpected bytes at the end of a record",
                r.remaining()
            )));
        }
        Ok(())
    }
}

/// Decodes a whole stream held in memory: its header and every frame.
///
/// Errors: as [`Decoder::next_event`] and [`Decoder::finish`].
pub fn decode_all(
    bytes: &[u8],
    options: &DecoderOptions,
) -> Result<(StreamHeader, Vec<DecodedFrame>), DeltaError> {
    let mut decoder = Decoder::new(options);
    decoder.push(bytes);
    let mut header = None;
    let mut frames = Vec::new();
    while let Some(event) = decoder.next_event()? {
        match event {
            Event::Header(h) => header = Some(*h),
            Event::Frame(f) => frames.push(f),
            Event::End { .. } => {}
        }
    }
    decoder.finish()?;
    let header = header.ok_or(DeltaError::Internal(
        "complete stream without a header".into(),
    ))?;
    Ok((header, frames))
}
