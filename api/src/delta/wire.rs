//! Byte-level building blocks shared by the encoder and the decoder:
//! constants, zigzag and byte planes, the record framing and the header
//! payload. `api/README.md` is the normative description of all of it.

use super::types::{AlphaMode, Grid, Material, MaterialGroup, Mesh, StreamHeader, Texture};
use super::{DecoderOptions, DeltaError};

/// Magic bytes at the start of every stream.
pub(crate) const MAGIC: [u8; 4] = *b"TMDS";
/// Major format version: a decoder reads only its own major version.
pub const VERSION_MAJOR: u16 = 1;
/// Minor format version: later minors only add what earlier decoders may
/// skip (ancillary records, trailing payload fields).
pub const VERSION_MINOR: u16 = 0;
/// Per-mesh grid coordinates: `[mesh][axis][vertex]`.
pub(crate) type GridCoordinates = Vec<[Vec<i32>; 3]>;

/// Whether a stream of minor version `minor` may append payload fields this
/// decoder does not know (which it then skips).
pub(crate) fn newer_minor(minor: u16) -> bool {
    minor > VERSION_MINOR
}

/// Magic + major + minor.
pub(crate) const PREAMBLE_LEN: usize = 8;
/// kind, codec, flags, stored length, raw length.
pub(crate) const PREFIX_LEN: usize = 12;
/// The CRC-32 after each record's stored payload.
pub(crate) const CRC_LEN: usize = 4;

pub(crate) const KIND_HEADER: u8 = b'H';
pub(crate) const KIND_FRAME: u8 = b'F';
pub(crate) const KIND_END: u8 = b'E';
/// Record kinds with this bit set are ancillary: skipped when unknown.
pub(crate) const KIND_ANCILLARY: u8 = 0x80;

pub(crate) const CODEC_STORED: u8 = 0;
pub(crate) const CODEC_ZSTD: u8 = 1;

/// "No material" / "no texture" in a u32 reference field.
pub(crate) const NONE: u32 = u32::MAX;

/// Grid coordinates stay within ±2²⁴ so they convert to `f32` exactly.
pub const MAX_GRID_COORDINATE: i32 = 1 << 24;

/// Frame payload bytes before the per-mesh planes: index, t, leaf blend.
pub(crate) const FRAME_FIXED_LEN: usize = 12;

#[inline]
pub(crate) fn zigzag(v: i32) -> u32 {
    ((v << 1) ^ (v >> 31)) as u32
}

#[inline]
pub(crate) fn unzigzag(z: u32) -> i32 {
    ((z >> 1) as i32) ^ -((z & 1) as i32)
}

/// Values per block of an integer array: each block has its own bit
/// width, so one outlier costs only its block.
pub(crate) const BLOCK: usize = 4096;

/// The smallest allowed bit width (0, 1, 2, 4, 8, 16, 24, 32) that holds
/// every value whose bits are OR-ed into `or`.
#[inline]
pub(crate) fn bits_for(or: u32) -> u8 {
    match or {
        0 => 0,
        1 => 1,
        2..=3 => 2,
        4..=0xF => 4,
        0x10..=0xFF => 8,
        0x100..=0xFFFF => 16,
        0x1_0000..=0xFF_FFFF => 24,
        _ => 32,
    }
}

/// Bytes one block of `m` values of width `bits` occupies after its width
/// byte.
#[inline]
pub(crate) fn block_bytes(m: usize, bits: u8) -> usize {
    (m * usize::from(bits)).div_ceil(8)
}

/// Block header bit: values are differences from the previous value.
pub(crate) const BLOCK_PREDICT_PREVIOUS: u8 = 0x80;
/// Block header bits holding the bit width.
pub(crate) const BLOCK_BITS: u8 = 0x3F;

/// Appends one block of `values` (at most [`BLOCK`]; `before` is the value
/// preceding the block in its array, 0 for the first block): the header
/// byte (predictor bit 7, bit width in bits 0–5), then the zigzag
/// residuals packed LSB-first (widths 1, 2, 4) or as byte planes (widths
/// 8–32: plane `k` holds byte `k` of every residual). `z` is scratch of at
/// least `values.len()` entries.
///
/// The predictor is whichever leaves fewer non-zero residuals (zeros are
/// nearly free after zstd); the loops are branch-free so they vectorise.
#[inline]
pub(crate) fn write_block(out: &mut Vec<u8>, values: &[i32], before: i32, z: &mut [u32]) {
    let Some(&first) = values.first() else {
        return;
    };
    let (mut nonzero_plain, mut nonzero_previous) =
        (u32::from(first != 0), u32::from(first != before));
    for (&v, &b) in values[1..].iter().zip(values) {
        nonzero_plain += u32::from(v != 0);
        nonzero_previous += u32::from(v != b);
    }
    let z = &mut z[..values.len()];
    let predict = nonzero_previous < nonzero_plain;
    let mut or = 0;
    if predict {
        z[0] = zigzag(first.wrapping_sub(before));
        for ((z, &v), &b) in z[1..].iter_mut().zip(&values[1..]).zip(values) {
            *z = zigzag(v.wrapping_sub(b));
        }
    } else {
        for (z, &v) in z.iter_mut().zip(values) {
            *z = zigzag(v);
        }
    }
    for &v in z.iter() {
        or |= v;
    }
    let bits = bits_for(or);
    out.push(bits | if predict { BLOCK_PREDICT_PREVIOUS } else { 0 });
    out.reserve(block_bytes(z.len(), bits));
    match bits {
        0 => {}
        1 => pack::<8>(out, z, 1),
        2 => pack::<4>(out, z, 2),
        4 => pack::<2>(out, z, 4),
        _ => {
            for k in 0..u32::from(bits / 8) {
                let shift = 8 * k;
                out.extend(z.iter().map(|&v| (v >> shift) as u8));
            }
        }
    }
}

/// Packs `N` values of `bits` bits into each byte.
#[inline]
fn pack<const N: usize>(out: &mut Vec<u8>, z: &[u32], bits: u32) {
    let (chunks, rest) = z.as_chunks::<N>();
    out.extend(chunks.iter().map(|c| {
        let mut byte = 0u32;
        for (i, &v) in c.iter().enumerate() {
            byte |= v << (bits * i as u32);
        }
        byte as u8
    }));
    if !rest.is_empty() {
        let mut byte = 0u32;
        for (i, &v) in rest.iter().enumerate() {
            byte |= v << (bits * i as u32);
        }
        out.push(byte as u8);
    }
}

/// Unpacks `N` values of `bits` bits from each byte (the inverse of
/// [`pack`]); `bytes` holds exactly `ceil(out.len() / N)` bytes.
#[inline]
fn unpack<const N: usize>(bytes: &[u8], out: &mut [i32], bits: u32) {
    let mask = (1u32 << bits) - 1;
    let (chunks, rest) = out.as_chunks_mut::<N>();
    for (chunk, &byte) in chunks.iter_mut().zip(bytes) {
        for (i, v) in chunk.iter_mut().enumerate() {
            *v = ((u32::from(byte) >> (bits * i as u32)) & mask) as i32;
        }
    }
    if let Some(&byte) = bytes.get(chunks.len()) {
        for (i, v) in rest.iter_mut().enumerate() {
            *v = ((u32::from(byte) >> (bits * i as u32)) & mask) as i32;
        }
    }
}

/// Writes per-vertex grid values (`values[axis][vertex]`) as vertex
/// blocks: for each run of [`BLOCK`] vertices, an x, a y and a z block.
pub(crate) fn write_positions(out: &mut Vec<u8>, values: &[Vec<i32>; 3]) {
    let mut z = vec![0; BLOCK];
    let mut before = [0; 3];
    let n = values[0].len();
    for start in (0..n).step_by(BLOCK) {
        let end = (start + BLOCK).min(n);
        for (axis, before) in values.iter().zip(&mut before) {
            write_block(out, &axis[start..end], *before, &mut z);
            *before = axis[end - 1];
        }
    }
}

/// Writes an integer array: its values in blocks of [`BLOCK`].
pub(crate) fn write_array(out: &mut Vec<u8>, values: &[i32]) {
    let mut z = vec![0; BLOCK];
    let mut before = 0;
    for block in values.chunks(BLOCK) {
        write_block(out, block, before, &mut z);
        before = block[block.len() - 1];
    }
}

/// Reads bounded fields from a record payload; errors name the record.
pub(crate) struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
    /// Stream offset of the record, for error messages.
    record_offset: u64,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(buf: &'a [u8], record_offset: u64) -> Self {
        Reader {
            buf,
            pos: 0,
            record_offset,
        }
    }

    pub(crate) fn corrupt(&self, reason: impl Into<String>) -> DeltaError {
        DeltaError::Corrupt {
            offset: self.record_offset,
            reason: reason.into(),
        }
    }

    pub(crate) fn remaining(&self) -> usize {
        self.buf.len() - self.pos
    }

    pub(crate) fn take(&mut self, n: usize) -> Result<&'a [u8], DeltaError> {
        if n > self.remaining() {
            return Err(self.corrupt(format!(
                "payload ends early: {n} bytes needed at payload byte {}, {} left",
                self.pos,
                self.remaining()
            )));
        }
        let bytes = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(bytes)
    }

    pub(crate) fn array<const N: usize>(&mut self) -> Result<[u8; N], DeltaError> {
        let mut a = [0; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }

    pub(crate) fn u8(&mut self) -> Result<u8, DeltaError> {
        Ok(self.array::<1>()?[0])
    }

    pub(crate) fn u32(&mut self) -> Result<u32, DeltaError> {
        Ok(u32::from_le_bytes(self.array()?))
    }

    pub(crate) fn f32(&mut self) -> Result<f32, DeltaError> {
        Ok(f32::from_le_bytes(self.array()?))
    }

    fn f32s<const N: usize>(&mut self) -> Result<[f32; N], DeltaError> {
        let mut a = [0.0; N];
        for v in &mut a {
            *v = self.f32()?;
        }
        Ok(a)
    }

    fn string(&mut self, limit: u32) -> Result<String, DeltaError> {
        let len = self.u32()?;
        check_limit("name length", u64::from(len), u64::from(limit))?;
        let bytes = self.take(len as usize)?;
        String::from_utf8(bytes.to_vec()).map_err(|_| self.corrupt("a name is not UTF-8"))
    }

    /// Reads an integer array of `n` values into `out` (cleared).
    pub(crate) fn read_array(&mut self, n: usize, out: &mut Vec<i32>) -> Result<(), DeltaError> {
        out.clear();
        out.resize(n, 0);
        let mut before = 0;
        for block in out.chunks_mut(BLOCK) {
            self.read_block(block, &mut before)?;
        }
        Ok(())
    }

    /// Reads vertex blocks (see [`write_positions`]) for
    /// `targets[axis].len()` vertices, calling `apply(target, value)` for
    /// every value read.
    pub(crate) fn read_positions(
        &mut self,
        targets: &mut [Vec<i32>; 3],
        mut apply: impl FnMut(&mut i32, i32),
    ) -> Result<(), DeltaError> {
        let n = targets[0].len();
        let mut block = vec![0; BLOCK.min(n)];
        let mut before = [0; 3];
        for start in (0..n).step_by(BLOCK) {
            let end = (start + BLOCK).min(n);
            let values = &mut block[..end - start];
            for (target, before) in targets.iter_mut().zip(&mut before) {
                self.read_block(values, before)?;
                for (t, &v) in target[start..end].iter_mut().zip(values.iter()) {
                    apply(t, v);
                }
            }
        }
        Ok(())
    }

    /// Reads one block into `out` (its length is the block's value count),
    /// undoing the predictor in wrapping `i32` arithmetic; `before` is the
    /// value preceding the block and becomes its last value.
    pub(crate) fn read_block(
        &mut self,
        out: &mut [i32],
        before: &mut i32,
    ) -> Result<(), DeltaError> {
        let header = self.u8()?;
        let bits = header & BLOCK_BITS;
        if header & !(BLOCK_BITS | BLOCK_PREDICT_PREVIOUS) != 0
            || !matches!(bits, 0 | 1 | 2 | 4 | 8 | 16 | 24 | 32)
        {
            return Err(self.corrupt(format!("invalid block header 0x{header:02x}")));
        }
        let m = out.len();
        let bytes = self.take(block_bytes(m, bits))?;
        match bits {
            0 => out.fill(0),
            1 => unpack::<8>(bytes, out, 1),
            2 => unpack::<4>(bytes, out, 2),
            4 => unpack::<2>(bytes, out, 4),
            _ => {
                out.fill(0);
                for (k, plane) in bytes.chunks_exact(m.max(1)).enumerate() {
                    let shift = 8 * k as u32;
                    for (v, &b) in out.iter_mut().zip(plane) {
                        *v |= (u32::from(b) << shift) as i32;
                    }
                }
            }
        }
        if header & BLOCK_PREDICT_PREVIOUS != 0 {
            let mut previous = *before;
            for v in out.iter_mut() {
                previous = previous.wrapping_add(unzigzag(*v as u32));
                *v = previous;
            }
        } else {
            for v in out.iter_mut() {
                *v = unzigzag(*v as u32);
            }
        }
        if let Some(&last) = out.last() {
            *before = last;
        }
        Ok(())
    }
}

pub(crate) fn check_limit(what: &'static str, size: u64, limit: u64) -> Result<(), DeltaError> {
    if size > limit {
        return Err(DeltaError::TooLarge { what, size, limit });
    }
    Ok(())
}

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_f32s(out: &mut Vec<u8>, values: &[f32]) {
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

fn put_string(out: &mut Vec<u8>, s: &str) {
    put_u32(out, s.len() as u32);
    out.extend_from_slice(s.as_bytes());
}

/// The stream preamble this encoder writes: magic, major, minor.
pub(crate) fn preamble() -> [u8; PREAMBLE_LEN] {
    preamble_of(VERSION_MINOR)
}

/// A preamble of this major version with the given minor version.
pub(crate) fn preamble_of(minor: u16) -> [u8; PREAMBLE_LEN] {
    let mut p = [0; PREAMBLE_LEN];
    p[..4].copy_from_slice(&MAGIC);
    p[4..6].copy_from_slice(&VERSION_MAJOR.to_le_bytes());
    p[6..8].copy_from_slice(&minor.to_le_bytes());
    p
}

/// Serialises a checked header whose base positions are given as grid
/// coordinates (`base[mesh][axis][vertex]`).
pub(crate) fn write_header(out: &mut Vec<u8>, header: &StreamHeader, base: &[[Vec<i32>; 3]]) {
    put_f32s(out, header.bounds.as_flattened());
    put_f32s(out, &header.grid.origin);
    put_f32s(out, &header.grid.step);
    put_u32(out, header.frame_count);
    put_u32(out, header.textures.len() as u32);
    for texture in &header.textures {
        put_u32(out, texture.png.len() as u32);
        out.extend_from_slice(&texture.png);
    }
    put_u32(out, header.materials.len() as u32);
    for material in &header.materials {
        put_string(out, &material.name);
        put_f32s(out, &material.base_color);
        let (mode, cutoff) = match material.alpha_mode {
            AlphaMode::Opaque => (0u8, 0.5),
            AlphaMode::Mask { cutoff } => (1, cutoff),
            AlphaMode::Blend => (2, 0.5),
        };
        out.push(mode);
        put_f32s(out, &[cutoff]);
        out.push(u8::from(material.double_sided));
        put_u32(out, material.texture.unwrap_or(NONE));
    }
    put_u32(out, header.meshes.len() as u32);
    for (mesh, base) in header.meshes.iter().zip(base) {
        put_string(out, &mesh.name);
        put_u32(out, mesh.base_positions.len() as u32);
        put_u32(out, mesh.indices.len() as u32);
        put_u32(out, mesh.groups.len() as u32);
        for g in &mesh.groups {
            for v in [g.first, g.count, g.material, g.fade_to.unwrap_or(NONE)] {
                put_u32(out, v);
            }
        }
        let indices: Vec<i32> = mesh.indices.iter().map(|&i| i as i32).collect();
        write_array(out, &indices);
        put_f32s(out, mesh.uvs.as_flattened());
        write_positions(out, base);
    }
}

/// Parses a header payload within `options`' limits: the header (base
/// positions reconstructed from the grid) and the base grid coordinates.
pub(crate) fn read_header(
    r: &mut Reader<'_>,
    options: &DecoderOptions,
    minor: u16,
) -> Result<(StreamHeader, GridCoordinates), DeltaError> {
    let [x0, y0, z0, x1, y1, z1] = r.f32s()?;
    let bounds = [[x0, y0, z0], [x1, y1, z1]];
    let origin = r.f32s()?;
    let step = r.f32s()?;
    let grid = Grid { origin, step };
    let frame_count = r.u32()?;

    let texture_count = r.u32()?;
    check_limit(
        "texture count",
        texture_count.into(),
        options.max_textures.into(),
    )?;
    let mut textures = Vec::with_capacity(texture_count as usize);
    let mut texture_bytes = 0u64;
    for _ in 0..texture_count {
        let len = r.u32()?;
        texture_bytes += u64::from(len);
        check_limit("texture bytes", texture_bytes, options.max_texture_bytes)?;
        textures.push(Texture {
            png: r.take(len as usize)?.to_vec(),
        });
    }

    let material_count = r.u32()?;
    check_limit(
        "material count",
        material_count.into(),
        options.max_materials.into(),
    )?;
    let mut materials = Vec::with_capacity(material_count as usize);
    for _ in 0..material_count {
        let name = r.string(options.max_name_bytes)?;
        let base_color = r.f32s()?;
        let mode = r.u8()?;
        let cutoff = r.f32()?;
        let alpha_mode = match mode {
            0 => AlphaMode::Opaque,
            1 => AlphaMode::Mask { cutoff },
            2 => AlphaMode::Blend,
            _ => return Err(r.corrupt(format!("unknown alpha mode {mode}"))),
        };
        let double_sided = match r.u8()? {
            0 => false,
            1 => true,
            v => return Err(r.corrupt(format!("double-sided flag {v} is not 0 or 1"))),
        };
        let texture = Some(r.u32()?).filter(|&t| t != NONE);
        materials.push(Material {
            name,
            base_color,
            alpha_mode,
            double_sided,
            texture,
        });
    }

    let mesh_count = r.u32()?;
    check_limit("mesh count", mesh_count.into(), options.max_meshes.into())?;
    let mut meshes = Vec::with_capacity(mesh_count as usize);
    let mut bases = Vec::with_capacity(mesh_count as usize);
    let (mut vertices, mut indices_total, mut groups_total) = (0u64, 0u64, 0u64);
    let mut values = Vec::new();
    for _ in 0..mesh_count {
        let name = r.string(options.max_name_bytes)?;
        let n = r.u32()?;
        let index_count = r.u32()?;
        let group_count = r.u32()?;
        vertices += u64::from(n);
        indices_total += u64::from(index_count);
        groups_total += u64::from(group_count);
        check_limit("vertex count", vertices, options.max_vertices)?;
        check_limit("index count", indices_total, options.max_indices)?;
        check_limit(
            "material group count",
            groups_total,
            options.max_groups.into(),
        )?;
        let (n, index_count) = (n as usize, index_count as usize);

        let mut groups = Vec::with_capacity(group_count as usize);
        for _ in 0..group_count {
            let [first, count, material, fade] = [r.u32()?, r.u32()?, r.u32()?, r.u32()?];
            groups.push(MaterialGroup {
                first,
                count,
                material,
                fade_to: Some(fade).filter(|&f| f != NONE),
            });
        }
        r.read_array(index_count, &mut values)?;
        let indices: Vec<u32> = values.iter().map(|&v| v as u32).collect();
        let uv_bytes = r.take(n * 8)?;
        let uvs = uv_bytes
            .chunks_exact(8)
            .map(|c| {
                [
                    f32::from_le_bytes([c[0], c[1], c[2], c[3]]),
                    f32::from_le_bytes([c[4], c[5], c[6], c[7]]),
                ]
            })
            .collect();
        let mut base: [Vec<i32>; 3] = [vec![0; n], vec![0; n], vec![0; n]];
        r.read_positions(&mut base, |q, v| *q = v)?;
        if base
            .iter()
            .flatten()
            .any(|q| q.unsigned_abs() > MAX_GRID_COORDINATE as u32)
        {
            return Err(r.corrupt("a base grid coordinate is out of range"));
        }
        let base_positions = (0..n)
            .map(|i| grid.dequantise([base[0][i], base[1][i], base[2][i]]))
            .collect();
        meshes.push(Mesh {
            name,
            indices,
            uvs,
            groups,
            base_positions,
        });
        bases.push(base);
    }
    if r.remaining() > 0 && !newer_minor(minor) {
        return Err(r.corrupt(format!(
            "{} unexpected bytes after the header",
            r.remaining()
        )));
    }
    let header = StreamHeader {
        bounds,
        grid,
        frame_count,
        textures,
        materials,
        meshes,
    };
    header.check().map_err(|reason| r.corrupt(reason))?;
    Ok((header, bases))
}

/// The CRC-32 of a record's bytes (prefix and stored payload); the header
/// record's also covers the preamble before it, so that every bit of a
/// stream is checked.
pub(crate) fn record_crc(kind: u8, record: &[u8], preamble: &[u8; PREAMBLE_LEN]) -> u32 {
    let mut hasher = crc32fast::Hasher::new();
    if kind == KIND_HEADER {
        hasher.update(preamble);
    }
    hasher.update(record);
    hasher.finalize()
}

/// Appends one record: prefix, payload (zstd-compressed when a compressor
/// is given and that makes it smaller), CRC-32. `scratch` holds the
/// compressed bytes and is reused between calls.
pub(crate) fn write_record(
    out: &mut Vec<u8>,
    kind: u8,
    raw: &[u8],
    compressor: Option<&mut zstd::bulk::Compressor<'static>>,
    scratch: &mut Vec<u8>,
) -> Result<(), DeltaError> {
    let raw_len = u32::try_from(raw.len()).map_err(|_| {
        DeltaError::InvalidHeader(format!("a record of {} bytes is over 4 GiB", raw.len()))
    })?;
    let mut stored: &[u8] = raw;
    let mut codec = CODEC_STORED;
    if let Some(compressor) = compressor {
        scratch.clear();
        scratch.reserve(zstd::zstd_safe::compress_bound(raw.len()));
        compressor
            .compress_to_buffer(raw, scratch)
            .map_err(|e| DeltaError::Internal(format!("zstd compression failed: {e}")))?;
        if scratch.len() < raw.len() {
            stored = scratch;
            codec = CODEC_ZSTD;
        }
    }
    let start = out.len();
    out.reserve(PREFIX_LEN + stored.len() + CRC_LEN);
    out.extend_from_slice(&[kind, codec, 0, 0]);
    out.extend_from_slice(&(stored.len() as u32).to_le_bytes());
    out.extend_from_slice(&raw_len.to_le_bytes());
    out.extend_from_slice(stored);
    let crc = record_crc(kind, &out[start..], &preamble());
    out.extend_from_slice(&crc.to_le_bytes());
    Ok(())
}
