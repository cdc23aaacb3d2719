//! Static GLB export of a tree, and reading our own tree back from a GLB.
//!
//! [`export_glb`] writes one glTF 2.0 binary file with one scene holding two
//! nodes, named exactly `branches` and `leaves` (clients script against the
//! names), whose meshes have the same names:
//!
//! - `branches`: the tubes of [`BranchMesher`] with material `bark`
//!   (base colour factor and texture, roughness 0.9, metallic 0);
//! - `leaves`: the quads of [`LeafMesher`], one primitive per leaf material,
//!   each material alpha-masked (`MASK`, cutoff 0.5), double-sided, with its
//!   texture embedded as PNG.
//!
//! Vertex attributes are POSITION (with exact min/max), NORMAL and
//! TEXCOORD_0, each in its own tightly packed buffer view; indices are
//! `u16` when a mesh has at most 65,535 vertices (65,535 itself, the
//! primitive-restart value, never occurs) and `u32` otherwise. A node
//! without geometry (a tree with no leaves, or no branches) has no mesh.
//!
//! # Exact round trip
//! With [`ExportOptions::embed_tree`] (the default) the tree itself, in the
//! JSON tree format ([`treemorph_tree::json`]), is stored in a buffer view of
//! the BIN chunk and referenced from `asset.extras`:
//!
//! ```json
//! "asset": {"version": "2.0", "extras": {"treemorph": {
//!     "bufferView": 7,
//!     "mediaType": "application/vnd.treemorph.tree+json",
//!     "format": "treemorph.tree/1"}}}
//! ```
//!
//! [`read_embedded_tree`] finds it (in `asset.extras`, or the default
//! scene's `extras` as written by tools that move it there) and returns the
//! tree bit-identical to the one exported. Third-party files, or ours
//! exported without it, give `Ok(None)`; the importer then rebuilds a tree
//! from the meshes.
//!
//! # Branch mesh modes
//! [`BranchMeshMode::TubeSoup`] (the default): one closed tube per strand,
//! tubes interpenetrating at junctions. [`BranchMeshMode::Welded`]: one
//! continuous watertight surface in which each child grows out of a hole in
//! its parent ([`crate::welded`]), like the meshes many modelling tools
//! write; the importer's tests use it.

use glam::{Vec2, Vec3};
use serde_json::{Map, Value, json};
use thiserror::Error;
use treemorph_tree::json::{FORMAT, FormatError, MEDIA_TYPE};
use treemorph_tree::{Frame, FrameTopology, Limits, Texture, Tree};

use crate::doc::MAX_U16_VERTICES;
use crate::gl::{
    ARRAY_BUFFER, CLAMP_TO_EDGE, ELEMENT_ARRAY_BUFFER, FLOAT, LINEAR, LINEAR_MIPMAP_LINEAR, REPEAT,
    TRIANGLES, UNSIGNED_INT, UNSIGNED_SHORT,
};
use crate::glb::{Glb, GlbError};
use crate::mesh::{BranchMesher, LeafMesher, MeshBuffers, MeshError, MeshOptions};

/// Key of our entry in `extras`.
pub const EXTRAS_KEY: &str = "treemorph";

/// How branches become triangles.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum BranchMeshMode {
    /// One closed tube per strand; tubes overlap at junctions.
    #[default]
    TubeSoup,
    /// One continuous surface: children grow out of holes in their parents
    /// ([`crate::welded`]).
    Welded,
}

/// Options of [`export_glb`].
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct ExportOptions {
    /// Store the tree in the GLB for an exact round trip (default `true`);
    /// `false` writes a file like a third-party tool would.
    pub embed_tree: bool,
    /// Branch geometry (default [`BranchMeshMode::TubeSoup`]).
    pub branch_mode: BranchMeshMode,
    /// Tube sides and leaf shape (default [`MeshOptions::default`]).
    pub mesh: MeshOptions,
}

impl Default for ExportOptions {
    fn default() -> ExportOptions {
        ExportOptions {
            embed_tree: true,
            branch_mode: BranchMeshMode::TubeSoup,
            mesh: MeshOptions::default(),
        }
    }
}

impl ExportOptions {
    /// These options with [`ExportOptions::embed_tree`] set.
    #[must_use]
    pub fn with_embed_tree(mut self, embed: bool) -> ExportOptions {
        self.embed_tree = embed;
        self
    }

    /// These options with [`ExportOptions::branch_mode`] set.
    #[must_use]
    pub fn with_branch_mode(mut self, mode: BranchMeshMode) -> ExportOptions {
        self.branch_mode = mode;
        self
    }

    /// These options with [`ExportOptions::mesh`] set.
    #[must_use]
    pub fn with_mesh(mut self, mesh: MeshOptions) -> ExportOptions {
        self.mesh = mesh;
        self
    }
}

/// Why a tree could not be exported.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum ExportError {
    /// The options are out of range (the caller's mistake).
    #[error("invalid export options: {0}")]
    InvalidOptions(String),
    /// The tree is too large for glTF's 32-bit counts and offsets.
    #[error("the tree is too large to export: {0}")]
    TooLarge(String),
    /// A bug: a valid tree failed to mesh.
    #[error("internal error while exporting: {0}")]
    Internal(String),
}

impl From<MeshError> for ExportError {
    fn from(e: MeshError) -> ExportError {
        match e {
            MeshError::InvalidOptions(m) => ExportError::InvalidOptions(m),
            e @ MeshError::TooLarge { .. } => ExportError::TooLarge(e.to_string()),
            e => ExportError::Internal(e.to_string()),
        }
    }
}

/// Why [`read_embedded_tree`] failed.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum ReadError {
    /// The bytes are not a readable GLB container.
    #[error(transparent)]
    Container(#[from] GlbError),
    /// The JSON chunk is not JSON.
    #[error("the GLB's JSON chunk is not valid JSON: {0}")]
    Json(String),
    /// A treemorph entry exists but points nowhere valid.
    #[error("the embedded treemorph tree reference is invalid: {0}")]
    BadEmbedding(String),
    /// The embedded tree document is refused.
    #[error("the embedded tree is invalid: {0}")]
    Tree(#[from] FormatError),
}

/// Writes `tree` as a GLB (see the [module docs](self)).
pub fn export_glb(tree: &Tree, options: &ExportOptions) -> Result<Vec<u8>, ExportError> {
    let topology = FrameTopology::of_tree(tree);
    let frame = Frame::of_tree(tree);
    let mut branch_mesher;
    let welded;
    let branches = match options.branch_mode {
        BranchMeshMode::TubeSoup => {
            branch_mesher = BranchMesher::new(&topology, &frame.radii, &frame, &options.mesh)?;
            branch_mesher.mesh(&frame)?
        }
        BranchMeshMode::Welded => {
            welded = crate::welded::welded_branch_mesh(&topology, &frame, &options.mesh)?;
            &welded
        }
    };
    let mut leaf_mesher = LeafMesher::new(&topology, &options.mesh)?;
    let leaves = leaf_mesher.mesh(&frame)?;
    let tree_json = options
        .embed_tree
        .then(|| treemorph_tree::json::to_vec(tree));

    let mut doc = Doc::default();

    // Materials: 0 is the bark, 1 + i is leaf material i.
    let materials = tree.materials();
    let bark_texture = materials
        .bark
        .texture
        .as_ref()
        .map(|t| doc.texture(t, "bark", true));
    let mut bark_pbr = json!({
        "baseColorFactor": color(materials.bark.color),
        "metallicFactor": 0.0,
        "roughnessFactor": 0.9,
    });
    if let Some(t) = bark_texture {
        bark_pbr["baseColorTexture"] = json!({ "index": t });
    }
    doc.materials
        .push(json!({ "name": "bark", "pbrMetallicRoughness": bark_pbr }));
    for m in &materials.leaves {
        let texture = m.texture.as_ref().map(|t| doc.texture(t, &m.name, false));
        let mut pbr = json!({
            "baseColorFactor": color(m.color),
            "metallicFactor": 0.0,
            "roughnessFactor": 0.8,
        });
        if let Some(t) = texture {
            pbr["baseColorTexture"] = json!({ "index": t });
        }
        doc.materials.push(json!({
            "name": m.name,
            "pbrMetallicRoughness": pbr,
            "alphaMode": "MASK",
            "alphaCutoff": 0.5,
            "doubleSided": true,
        }));
    }

    let branch_mesh = doc.mesh("branches", branches, |_| 0)?;
    let leaf_mesh = doc.mesh("leaves", leaves, |materials| 1 + materials[0] as usize)?;
    let mut nodes = Vec::new();
    for (name, mesh) in [("branches", branch_mesh), ("leaves", leaf_mesh)] {
        let mut node = json!({ "name": name });
        if let Some(m) = mesh {
            node["mesh"] = json!(m);
        }
        nodes.push(node);
    }

    let mut asset = json!({
        "version": "2.0",
        "generator": concat!("treemorph-gltf ", env!("CARGO_PKG_VERSION")),
    });
    if let Some(bytes) = &tree_json {
        let view = doc.view(Payload::Bytes(bytes), None);
        asset["extras"] = json!({ EXTRAS_KEY: {
            "bufferView": view,
            "mediaType": MEDIA_TYPE,
            "format": FORMAT,
        }});
    }

    let mut root = Map::new();
    root.insert("asset".into(), asset);
    root.insert("scene".into(), json!(0));
    let mut scene = json!({ "nodes": [0, 1] });
    if !tree.name().is_empty() {
        scene["name"] = json!(tree.name());
    }
    root.insert("scenes".into(), json!([scene]));
    root.insert("nodes".into(), Value::Array(nodes));
    doc.finish(root)
}

/// Finds and reads the tree [`export_glb`] embeds. `Ok(None)` when the GLB
/// is well-formed but carries no treemorph entry (a third-party file).
///
/// Every offset and length is checked against the bytes present; hostile
/// input gives an error, never a panic.
pub fn read_embedded_tree(glb: &[u8], limits: &Limits) -> Result<Option<Tree>, ReadError> {
    let container = Glb::from_slice(glb)?;
    let doc: Value =
        serde_json::from_slice(container.json).map_err(|e| ReadError::Json(e.to_string()))?;
    let Some(entry) = find_entry(&doc) else {
        return Ok(None);
    };
    let bad = |m: String| ReadError::BadEmbedding(m);
    let entry = entry
        .as_object()
        .ok_or_else(|| bad(format!("extras.{EXTRAS_KEY} is not an object")))?;
    match entry.get("format").and_then(Value::as_str) {
        Some(FORMAT) => {}
        Some(other) => {
            return Err(FormatError::UnsupportedFormat {
                found: other.to_owned(),
            }
            .into());
        }
        None => return Err(bad("the entry has no \"format\" string".into())),
    }
    match entry.get("mediaType").and_then(Value::as_str) {
        Some(MEDIA_TYPE) => {}
        other => {
            return Err(bad(format!(
                "mediaType is {other:?}, expected {MEDIA_TYPE:?}"
            )));
        }
    }
    let index = entry
        .get("bufferView")
        .and_then(Value::as_u64)
        .ok_or_else(|| bad("the entry has no integer \"bufferView\"".into()))?;
    let view = usize::try_from(index)
        .ok()
        .and_then(|i| doc.get("bufferViews")?.as_array()?.get(i))
        .and_then(Value::as_object)
        .ok_or_else(|| bad(format!("bufferView {index} does not exist")))?;
    let field = |name: &str, default: Option<u64>| {
        match view.get(name) {
            None => default,
            Some(v) => v.as_u64(),
        }
        .ok_or_else(|| bad(format!("bufferView {index} has no valid {name:?}")))
    };
    let buffer = field("buffer", None)?;
    let offset = field("byteOffset", Some(0))?;
    let length = field("byteLength", None)?;
    let buffer_has_uri = usize::try_from(buffer)
        .ok()
        .and_then(|b| doc.get("buffers")?.as_array()?.get(b))
        .map(|b| b.get("uri").is_some());
    if buffer != 0 || buffer_has_uri != Some(false) {
        return Err(bad(format!(
            "bufferView {index} is not in the GLB's own buffer 0"
        )));
    }
    let bin = container
        .bin
        .ok_or_else(|| bad("the GLB has no BIN chunk".into()))?;
    let bytes = offset
        .checked_add(length)
        .filter(|&end| end <= bin.len() as u64)
        .map(|end| &bin[offset as usize..end as usize])
        .ok_or_else(|| {
            bad(format!(
                "bufferView {index} spans bytes {offset}..{offset}+{length} of a {}-byte BIN chunk",
                bin.len()
            ))
        })?;
    Ok(Some(treemorph_tree::json::from_slice(bytes, limits)?))
}

/// `asset.extras.treemorph`, else the default scene's `extras.treemorph`.
fn find_entry(doc: &Value) -> Option<&Value> {
    let in_asset = doc
        .get("asset")
        .and_then(|a| a.get("extras"))
        .and_then(|e| e.get(EXTRAS_KEY));
    in_asset.or_else(|| {
        let scene = doc.get("scene").and_then(Value::as_u64).unwrap_or(0);
        doc.get("scenes")?
            .as_array()?
            .get(usize::try_from(scene).ok()?)?
            .get("extras")?
            .get(EXTRAS_KEY)
    })
}

fn color(c: [f32; 4]) -> [f32; 4] {
    c.map(|x| {
        if x.is_finite() {
            x.clamp(0.0, 1.0)
        } else {
            1.0
        }
    })
}

/// Data of one buffer view, written into the BIN chunk at the end.
enum Payload<'a> {
    Vec3(&'a [Vec3]),
    Vec2(&'a [Vec2]),
    Indices { indices: &'a [u32], wide: bool },
    Bytes(&'a [u8]),
}

impl Payload<'_> {
    fn len(&self) -> usize {
        match self {
            Payload::Vec3(v) => v.len() * 12,
            Payload::Vec2(v) => v.len() * 8,
            Payload::Indices { indices, wide } => indices.len() * if *wide { 4 } else { 2 },
            Payload::Bytes(b) => b.len(),
        }
    }

    /// Writes little-endian data into `out`, exactly [`Payload::len`] bytes.
    fn write(&self, out: &mut [u8]) {
        match self {
            Payload::Vec3(data) => {
                for (o, v) in out.chunks_exact_mut(12).zip(data.iter()) {
                    o[0..4].copy_from_slice(&v.x.to_le_bytes());
                    o[4..8].copy_from_slice(&v.y.to_le_bytes());
                    o[8..12].copy_from_slice(&v.z.to_le_bytes());
                }
            }
            Payload::Vec2(data) => {
                for (o, v) in out.chunks_exact_mut(8).zip(data.iter()) {
                    o[0..4].copy_from_slice(&v.x.to_le_bytes());
                    o[4..8].copy_from_slice(&v.y.to_le_bytes());
                }
            }
            Payload::Indices {
                indices,
                wide: true,
            } => {
                for (o, i) in out.chunks_exact_mut(4).zip(indices.iter()) {
                    o.copy_from_slice(&i.to_le_bytes());
                }
            }
            Payload::Indices {
                indices,
                wide: false,
            } => {
                for (o, &i) in out.chunks_exact_mut(2).zip(indices.iter()) {
                    // The caller checked the vertex count, so every index fits.
                    o.copy_from_slice(&(i as u16).to_le_bytes());
                }
            }
            Payload::Bytes(b) => out.copy_from_slice(b),
        }
    }
}

/// The glTF document being written: JSON arrays, and the layout of the BIN
/// chunk whose bytes are written straight into the GLB at the end.
#[derive(Default)]
struct Doc<'a> {
    payloads: Vec<(usize, Payload<'a>)>,
    bin_len: usize,
    views: Vec<Value>,
    accessors: Vec<Value>,
    meshes: Vec<Value>,
    materials: Vec<Value>,
    textures: Vec<Value>,
    images: Vec<Value>,
    /// Sampler index for repeating (bark) and clamped (leaf) textures.
    samplers: [Option<usize>; 2],
    sampler_list: Vec<Value>,
}

impl<'a> Doc<'a> {
    /// Places a buffer view at the next 4-byte boundary.
    fn view(&mut self, payload: Payload<'a>, target: Option<u32>) -> usize {
        let start = self.bin_len.next_multiple_of(4);
        let len = payload.len();
        self.bin_len = start + len;
        self.payloads.push((start, payload));
        let mut view = json!({
            "buffer": 0,
            "byteOffset": start,
            "byteLength": len,
        });
        if let Some(t) = target {
            view["target"] = json!(t);
        }
        self.views.push(view);
        self.views.len() - 1
    }

    fn accessor(&mut self, accessor: Value) -> usize {
        self.accessors.push(accessor);
        self.accessors.len() - 1
    }

    /// Embeds a PNG and returns its texture index.
    fn texture(&mut self, texture: &'a Texture, name: &str, repeat: bool) -> usize {
        let view = self.view(Payload::Bytes(texture.png()), None);
        self.images.push(json!({
            "name": name,
            "bufferView": view,
            "mimeType": "image/png",
        }));
        let slot = usize::from(!repeat);
        let sampler = match self.samplers[slot] {
            Some(s) => s,
            None => {
                let wrap = if repeat { REPEAT } else { CLAMP_TO_EDGE };
                self.sampler_list.push(json!({
                    "magFilter": LINEAR,
                    "minFilter": LINEAR_MIPMAP_LINEAR,
                    "wrapS": wrap,
                    "wrapT": wrap,
                }));
                let s = self.sampler_list.len() - 1;
                self.samplers[slot] = Some(s);
                s
            }
        };
        self.textures.push(json!({
            "sampler": sampler,
            "source": self.images.len() - 1,
        }));
        self.textures.len() - 1
    }

    /// Writes a mesh with one primitive per non-empty group; `None` when
    /// there is nothing to draw.
    fn mesh(
        &mut self,
        name: &str,
        mesh: &'a MeshBuffers,
        material: impl Fn([u32; 2]) -> usize,
    ) -> Result<Option<usize>, ExportError> {
        if mesh.is_empty() || mesh.positions.is_empty() {
            return Ok(None);
        }
        let count = mesh.positions.len();
        let b = mesh.bounds;
        let position_view = self.view(Payload::Vec3(&mesh.positions), Some(ARRAY_BUFFER));
        let position = self.accessor(json!({
            "bufferView": position_view,
            "componentType": FLOAT,
            "count": count,
            "type": "VEC3",
            "min": b.min.to_array(),
            "max": b.max.to_array(),
        }));
        let normal_view = self.view(Payload::Vec3(&mesh.normals), Some(ARRAY_BUFFER));
        let normal = self.accessor(json!({
            "bufferView": normal_view,
            "componentType": FLOAT,
            "count": count,
            "type": "VEC3",
        }));
        let uv_view = self.view(Payload::Vec2(&mesh.uvs), Some(ARRAY_BUFFER));
        let uv = self.accessor(json!({
            "bufferView": uv_view,
            "componentType": FLOAT,
            "count": count,
            "type": "VEC2",
        }));
        let wide = count > MAX_U16_VERTICES;
        let index_view = self.view(
            Payload::Indices {
                indices: &mesh.indices,
                wide,
            },
            Some(ELEMENT_ARRAY_BUFFER),
        );
        let (component, size) = if wide {
            (UNSIGNED_INT, 4)
        } else {
            (UNSIGNED_SHORT, 2)
        };
        let mut primitives = Vec::new();
        for group in &mesh.groups {
            if group.index_count == 0 {
                continue;
            }
            let first = group.first_index as usize;
            let range = first..first + group.index_count as usize;
            let Some(indices) = mesh.indices.get(range) else {
                return Err(ExportError::Internal(format!(
                    "mesh {name} has a group past its index buffer"
                )));
            };
            let hi = indices.iter().copied().max().unwrap_or(0);
            if hi as usize >= count {
                return Err(ExportError::Internal(format!(
                    "mesh {name} has index {hi} for {count} vertices"
                )));
            }
            let indices = self.accessor(json!({
                "bufferView": index_view,
                "byteOffset": first * size,
                "componentType": component,
                "count": group.index_count,
                "type": "SCALAR",
            }));
            primitives.push(json!({
                "attributes": { "POSITION": position, "NORMAL": normal, "TEXCOORD_0": uv },
                "indices": indices,
                "material": material(group.materials),
                "mode": TRIANGLES,
            }));
        }
        self.meshes
            .push(json!({ "name": name, "primitives": primitives }));
        Ok(Some(self.meshes.len() - 1))
    }

    /// Moves the arrays into the root object, with the buffer when the BIN
    /// chunk is not empty, and writes the GLB.
    fn finish(mut self, mut root: Map<String, Value>) -> Result<Vec<u8>, ExportError> {
        let bin_len = self.bin_len.next_multiple_of(4);
        if u32::try_from(bin_len).is_err() {
            return Err(ExportError::TooLarge(format!(
                "the binary chunk would be {bin_len} bytes; a GLB holds at most 4 GiB"
            )));
        }
        let mut put = |key: &str, list: &mut Vec<Value>| {
            if !list.is_empty() {
                root.insert(key.into(), Value::Array(std::mem::take(list)));
            }
        };
        put("meshes", &mut self.meshes);
        put("materials", &mut self.materials);
        put("textures", &mut self.textures);
        put("images", &mut self.images);
        put("samplers", &mut self.sampler_list);
        put("accessors", &mut self.accessors);
        put("bufferViews", &mut self.views);
        if bin_len > 0 {
            root.insert("buffers".into(), json!([{ "byteLength": bin_len }]));
        }
        let json = serde_json::to_vec(&Value::Object(root))
            .map_err(|e| ExportError::Internal(format!("JSON serialisation failed: {e}")))?;
        let payloads = self.payloads;
        crate::glb::write_with(&json, (bin_len > 0).then_some(bin_len), |bin| {
            for (start, payload) in &payloads {
                payload.write(&mut bin[*start..*start + payload.len()]);
            }
        })
        .map_err(|e| ExportError::TooLarge(e.to_string()))
    }
}

#[cfg(test)]
#[path = "export_tests.rs"]
mod tests;
