//! A glTF document under construction, for the frame, animated and stream
//! encoders: JSON arrays plus the layout of the BIN chunk, whose payloads
//! are written once, in parallel, straight into the output (or streamed to
//! a writer for files too large to hold twice).

use std::io::{self, Write};

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use serde_json::{Map, Value, json};

use crate::gl::{
    ARRAY_BUFFER, CLAMP_TO_EDGE, ELEMENT_ARRAY_BUFFER, FLOAT, LINEAR, LINEAR_MIPMAP_LINEAR, REPEAT,
    UNSIGNED_INT, UNSIGNED_SHORT,
};
use crate::glb::{CHUNK_BIN, CHUNK_JSON, MAGIC};

/// Meshes with more vertices than this need `u32` indices (65,535 itself is
/// the primitive-restart value and never used).
pub(crate) const MAX_U16_VERTICES: usize = 65_535;

/// Bytes of one buffer view, written into the BIN chunk at the end.
pub(crate) enum Data<'a> {
    Vec3(&'a [Vec3]),
    Vec2(&'a [Vec2]),
    /// Indices as `u32`.
    U32(&'a [u32]),
    /// Indices as `u16` (the caller checked they fit).
    U16(&'a [u32]),
    Bytes(&'a [u8]),
    Owned(Vec<u8>),
}

impl Data<'_> {
    pub(crate) fn len(&self) -> usize {
        match self {
            Data::Vec3(v) => v.len() * 12,
            Data::Vec2(v) => v.len() * 8,
            Data::U32(v) => v.len() * 4,
            Data::U16(v) => v.len() * 2,
            Data::Bytes(b) => b.len(),
            Data::Owned(b) => b.len(),
        }
    }

    /// Piece `i` of this data when cut into runs of about [`PIECE`]
    /// bytes (whole elements), `None` past the end.
    fn piece(&self, i: usize) -> Option<Data<'_>> {
        fn cut<T>(v: &[T], size: usize, i: usize) -> Option<&[T]> {
            let per = (PIECE / size).max(1);
            let start = i * per;
            (start < v.len() || (i == 0 && v.is_empty()))
                .then(|| &v[start.min(v.len())..(start + per).min(v.len())])
        }
        Some(match self {
            Data::Vec3(v) => Data::Vec3(cut(v, 12, i)?),
            Data::Vec2(v) => Data::Vec2(cut(v, 8, i)?),
            Data::U32(v) => Data::U32(cut(v, 4, i)?),
            Data::U16(v) => Data::U16(cut(v, 2, i)?),
            Data::Bytes(b) => Data::Bytes(cut(b, 1, i)?),
            Data::Owned(b) => Data::Bytes(cut(b, 1, i)?),
        })
    }

    /// Writes exactly [`Data::len`] little-endian bytes.
    fn write(&self, out: &mut [u8]) {
        fn floats(out: &mut [u8], values: impl Iterator<Item = f32>) {
            for (o, v) in out.chunks_exact_mut(4).zip(values) {
                o.copy_from_slice(&v.to_le_bytes());
            }
        }
        match self {
            Data::Vec3(v) => floats(out, v.iter().flat_map(|p| p.to_array())),
            Data::Vec2(v) => floats(out, v.iter().flat_map(|p| p.to_array())),
            Data::U32(v) => {
                for (o, i) in out.chunks_exact_mut(4).zip(v.iter()) {
                    o.copy_from_slice(&i.to_le_bytes());
                }
            }
            Data::U16(v) => {
                for (o, &i) in out.chunks_exact_mut(2).zip(v.iter()) {
                    o.copy_from_slice(&(i as u16).to_le_bytes());
                }
            }
            Data::Bytes(b) => out.copy_from_slice(b),
            Data::Owned(b) => out.copy_from_slice(b),
        }
    }
}

/// Bytes per piece of the parallel BIN write.
const PIECE: usize = 1 << 20;

/// Which sampler a texture uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Wrap {
    /// Bark: repeats around and along branches.
    Repeat,
    /// Leaves: clamped, so the blade's edge does not bleed across.
    Clamp,
}

/// The document: JSON arrays and the BIN chunk's payloads.
#[derive(Default)]
pub(crate) struct Doc<'a> {
    payloads: Vec<(usize, Data<'a>)>,
    bin_len: usize,
    pub(crate) views: Vec<Value>,
    pub(crate) accessors: Vec<Value>,
    pub(crate) meshes: Vec<Value>,
    pub(crate) materials: Vec<Value>,
    pub(crate) textures: Vec<Value>,
    pub(crate) images: Vec<Value>,
    pub(crate) nodes: Vec<Value>,
    pub(crate) animations: Vec<Value>,
    samplers: [Option<usize>; 2],
    sampler_list: Vec<Value>,
    /// Buffers after buffer 0 (the BIN chunk), e.g. a meshopt fallback.
    pub(crate) extra_buffers: Vec<Value>,
    pub(crate) extensions_used: Vec<&'static str>,
    pub(crate) extensions_required: Vec<&'static str>,
}

impl<'a> Doc<'a> {
    /// Places data at the next 4-byte boundary of the BIN chunk; returns
    /// its offset and length.
    pub(crate) fn place(&mut self, data: Data<'a>) -> (usize, usize) {
        let start = self.bin_len.next_multiple_of(4);
        let len = data.len();
        self.bin_len = start + len;
        self.payloads.push((start, data));
        (start, len)
    }

    /// Places data in a buffer view of its own; returns the view's index.
    pub(crate) fn view(
        &mut self,
        data: Data<'a>,
        target: Option<u32>,
        stride: Option<usize>,
    ) -> usize {
        let (start, len) = self.place(data);
        let mut view = json!({ "buffer": 0, "byteOffset": start, "byteLength": len });
        if let Some(t) = target {
            view["target"] = json!(t);
        }
        if let Some(s) = stride {
            view["byteStride"] = json!(s);
        }
        self.push_view(view)
    }

    pub(crate) fn push_view(&mut self, view: Value) -> usize {
        self.views.push(view);
        self.views.len() - 1
    }

    pub(crate) fn accessor(&mut self, accessor: Value) -> usize {
        self.accessors.push(accessor);
        self.accessors.len() - 1
    }

    /// A float VEC3 accessor (with `min`/`max` when given, as POSITION
    /// needs) over its own view.
    pub(crate) fn vec3(&mut self, data: &'a [Vec3], bounds: Option<(Vec3, Vec3)>) -> usize {
        let view = self.view(Data::Vec3(data), Some(ARRAY_BUFFER), None);
        let mut a = json!({
            "bufferView": view, "componentType": FLOAT, "count": data.len(), "type": "VEC3",
        });
        if let Some((lo, hi)) = bounds {
            a["min"] = json!(lo.to_array());
            a["max"] = json!(hi.to_array());
        }
        self.accessor(a)
    }

    /// A float VEC2 accessor over its own view.
    pub(crate) fn vec2(&mut self, data: &'a [Vec2]) -> usize {
        let view = self.view(Data::Vec2(data), Some(ARRAY_BUFFER), None);
        self.accessor(json!({
            "bufferView": view, "componentType": FLOAT, "count": data.len(), "type": "VEC2",
        }))
    }

    /// An index accessor over its own view: `u16` when every index is
    /// below `vertex_count ≤ 65,535`, else `u32`.
    pub(crate) fn indices(&mut self, indices: &'a [u32], vertex_count: usize) -> usize {
        let wide = vertex_count > MAX_U16_VERTICES;
        let (data, component) = if wide {
            (Data::U32(indices), UNSIGNED_INT)
        } else {
            (Data::U16(indices), UNSIGNED_SHORT)
        };
        let view = self.view(data, Some(ELEMENT_ARRAY_BUFFER), None);
        self.accessor(json!({
            "bufferView": view, "componentType": component, "count": indices.len(), "type": "SCALAR",
        }))
    }

    /// Embeds a PNG; returns the texture index.
    pub(crate) fn texture(&mut self, png: Data<'a>, name: &str, wrap: Wrap) -> usize {
        let view = self.view(png, None, None);
        self.images
            .push(json!({ "name": name, "bufferView": view, "mimeType": "image/png" }));
        let slot = usize::from(wrap == Wrap::Clamp);
        let sampler = match self.samplers[slot] {
            Some(s) => s,
            None => {
                let mode = if wrap == Wrap::Repeat {
                    REPEAT
                } else {
                    CLAMP_TO_EDGE
                };
                self.sampler_list.push(json!({
                    "magFilter": LINEAR, "minFilter": LINEAR_MIPMAP_LINEAR,
                    "wrapS": mode, "wrapT": mode,
                }));
                self.samplers[slot] = Some(self.sampler_list.len() - 1);
                self.sampler_list.len() - 1
            }
        };
        self.textures
            .push(json!({ "sampler": sampler, "source": self.images.len() - 1 }));
        self.textures.len() - 1
    }

    /// Adds an extension name to `extensionsUsed` (and `extensionsRequired`).
    pub(crate) fn use_extension(&mut self, name: &'static str, required: bool) {
        if !self.extensions_used.contains(&name) {
            self.extensions_used.push(name);
        }
        if required && !self.extensions_required.contains(&name) {
            self.extensions_required.push(name);
        }
    }

    /// The JSON chunk (the document with its arrays and buffers moved into
    /// `root`) and the padded BIN length (`None` without binary data).
    fn json(&mut self, mut root: Map<String, Value>) -> (Vec<u8>, Option<usize>) {
        let bin_len = self.bin_len.next_multiple_of(4);
        let mut put = |key: &str, list: &mut Vec<Value>| {
            if !list.is_empty() {
                root.insert(key.into(), Value::Array(std::mem::take(list)));
            }
        };
        put("nodes", &mut self.nodes);
        put("meshes", &mut self.meshes);
        put("animations", &mut self.animations);
        put("materials", &mut self.materials);
        put("textures", &mut self.textures);
        put("images", &mut self.images);
        put("samplers", &mut self.sampler_list);
        put("accessors", &mut self.accessors);
        put("bufferViews", &mut self.views);
        let mut buffers = Vec::new();
        if bin_len > 0 || !self.extra_buffers.is_empty() {
            buffers.push(json!({ "byteLength": bin_len }));
        }
        buffers.append(&mut self.extra_buffers);
        if !buffers.is_empty() {
            root.insert("buffers".into(), Value::Array(buffers));
        }
        let names = |v: &[&str]| Value::Array(v.iter().map(|&n| json!(n)).collect());
        if !self.extensions_used.is_empty() {
            root.insert("extensionsUsed".into(), names(&self.extensions_used));
        }
        if !self.extensions_required.is_empty() {
            root.insert(
                "extensionsRequired".into(),
                names(&self.extensions_required),
            );
        }
        let json = serde_json::to_vec(&Value::Object(root)).expect("a JSON value serialises");
        (json, (bin_len > 0).then_some(bin_len))
    }

    /// Size of the GLB [`Doc::write`] would produce for `root`, bytes (as
    /// `u64`: it may exceed what a GLB can hold).
    fn total_len(json_len: usize, bin_len: Option<usize>) -> u64 {
        12 + 8 + json_len.next_multiple_of(4) as u64 + bin_len.map_or(0, |n| 8 + n as u64)
    }

    /// Writes the GLB into `out` (cleared; its capacity is reused, so a
    /// writer called frame after frame does not fault in fresh pages).
    /// Payloads are written in parallel. Errors when the file would exceed
    /// the 4 GiB a GLB header can describe.
    pub(crate) fn write(mut self, root: Map<String, Value>, out: &mut Vec<u8>) -> Result<(), u64> {
        let (json, bin_len) = self.json(root);
        let total = Self::total_len(json.len(), bin_len);
        if u32::try_from(total).is_err() {
            return Err(total);
        }
        if out.len() != total as usize {
            // Same size as last time (the usual case frame after frame):
            // every byte is overwritten below, padding included, so the
            // buffer is not cleared first.
            out.clear();
            out.resize(total as usize, 0);
        }
        let header = glb_header(total as u32, json.len(), bin_len);
        let (head, rest) = out.split_at_mut(header.len());
        head.copy_from_slice(&header);
        let json_padded = json.len().next_multiple_of(4);
        let (json_chunk, rest) = rest.split_at_mut(json_padded);
        json_chunk[..json.len()].copy_from_slice(&json);
        json_chunk[json.len()..].fill(b' ');
        if let Some(len) = bin_len {
            let (chunk_header, bin) = rest.split_at_mut(8);
            chunk_header[..4].copy_from_slice(&(len as u32).to_le_bytes());
            chunk_header[4..].copy_from_slice(&CHUNK_BIN.to_le_bytes());
            // Disjoint slices — each payload cut into pieces of at most
            // `PIECE` bytes, so large views spread over every core — filled
            // in parallel.
            let mut slices = Vec::with_capacity(self.payloads.len() * 2);
            let mut rest = bin;
            let mut at = 0;
            for (start, data) in &self.payloads {
                let (gap, tail) = rest.split_at_mut(start - at);
                gap.fill(0);
                let (mut slice, tail) = tail.split_at_mut(data.len());
                let mut piece = 0;
                while let Some(part) = data.piece(piece) {
                    let (head, more) = slice.split_at_mut(part.len());
                    slices.push((head, part));
                    slice = more;
                    piece += 1;
                }
                rest = tail;
                at = start + data.len();
            }
            rest.fill(0);
            slices
                .into_par_iter()
                .with_max_len(1)
                .for_each(|(slice, data)| data.write(slice));
        }
        Ok(())
    }

    /// Streams the GLB to `w` (for files too large to hold twice in
    /// memory). Errors: I/O errors, and `InvalidInput` when the file would
    /// exceed 4 GiB.
    pub(crate) fn write_to(
        mut self,
        root: Map<String, Value>,
        w: &mut impl Write,
    ) -> io::Result<u64> {
        let (json, bin_len) = self.json(root);
        let total = Self::total_len(json.len(), bin_len);
        let total32 = u32::try_from(total).map_err(|_| {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("a GLB holds at most 4 GiB; this one would be {total} bytes"),
            )
        })?;
        w.write_all(&glb_header(total32, json.len(), bin_len))?;
        w.write_all(&json)?;
        w.write_all(&b"   "[..json.len().next_multiple_of(4) - json.len()])?;
        if let Some(len) = bin_len {
            w.write_all(&(len as u32).to_le_bytes())?;
            w.write_all(&CHUNK_BIN.to_le_bytes())?;
            let mut at = 0;
            let mut scratch = Vec::new();
            for (start, data) in &self.payloads {
                w.write_all(&[0u8; 4][..start - at])?;
                match data {
                    Data::Bytes(b) => w.write_all(b)?,
                    Data::Owned(b) => w.write_all(b)?,
                    other => {
                        scratch.clear();
                        scratch.resize(other.len(), 0);
                        other.write(&mut scratch);
                        w.write_all(&scratch)?;
                    }
                }
                at = start + data.len();
            }
            w.write_all(&[0u8; 4][..len - at])?;
        }
        Ok(total)
    }
}

/// The 12-byte GLB header and the JSON chunk's 8-byte header.
fn glb_header(total: u32, json_len: usize, _bin: Option<usize>) -> [u8; 20] {
    let mut h = [0u8; 20];
    h[0..4].copy_from_slice(&MAGIC.to_le_bytes());
    h[4..8].copy_from_slice(&2u32.to_le_bytes());
    h[8..12].copy_from_slice(&total.to_le_bytes());
    h[12..16].copy_from_slice(&(json_len.next_multiple_of(4) as u32).to_le_bytes());
    h[16..20].copy_from_slice(&CHUNK_JSON.to_le_bytes());
    h
}

/// Clamps a linear RGBA colour into [0, 1] (non-finite components become 1).
pub(crate) fn color(c: [f32; 4]) -> [f32; 4] {
    c.map(|x| {
        if x.is_finite() {
            x.clamp(0.0, 1.0)
        } else {
            1.0
        }
    })
}

/// The `asset` object of every file this crate writes.
pub(crate) fn asset() -> Value {
    json!({
        "version": "2.0",
        "generator": concat!("treemorph-gltf ", env!("CARGO_PKG_VERSION")),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parallel_pieces_write_the_bytes_of_a_sequential_stream() {
        // Views larger than a piece, of every element size, and empty ones.
        let points: Vec<Vec3> = (0..200_000).map(|i| Vec3::splat(i as f32)).collect();
        let uvs: Vec<Vec2> = (0..300_000).map(|i| Vec2::new(i as f32, 0.5)).collect();
        let indices: Vec<u32> = (0..700_001).collect();
        let small: Vec<u32> = (0..65_000).collect();
        let bytes: Vec<u8> = (0..3_000_003).map(|i| (i % 251) as u8).collect();
        let build = || {
            let mut doc = Doc::default();
            doc.vec3(&points, None);
            doc.vec2(&uvs);
            doc.view(Data::U32(&indices), None, None);
            doc.view(Data::U16(&small), None, None);
            doc.view(Data::Bytes(&bytes), None, None);
            doc.view(Data::Owned(vec![7; 5]), None, None);
            doc.view(Data::Vec3(&[]), None, None);
            let mut root = Map::new();
            root.insert("asset".into(), asset());
            (doc, root)
        };
        let (doc, root) = build();
        let mut parallel = vec![1u8; 10]; // stale contents are overwritten
        doc.write(root, &mut parallel).unwrap();
        let (doc, root) = build();
        let mut sequential = Vec::new();
        let len = doc.write_to(root, &mut sequential).unwrap();
        assert_eq!(len as usize, sequential.len());
        assert!(parallel == sequential);
        // A buffer of the right size full of stale bytes: every byte,
        // padding included, is written.
        let (doc, root) = build();
        let mut reused = vec![0xFFu8; sequential.len()];
        doc.write(root, &mut reused).unwrap();
        assert!(reused == sequential);
        let glb = crate::glb::Glb::from_slice(&parallel).unwrap();
        let bin = glb.bin.unwrap();
        assert_eq!(&bin[..12], &[0u8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
        assert_eq!(&bin[12..16], &1f32.to_le_bytes());
    }
}
