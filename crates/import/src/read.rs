//! Reading GLB and glTF JSON into world-space triangle primitives, with every
//! offset, count and index checked against the bytes present before use.
//!
//! The `gltf` crate's accessor reader can panic on malformed accessors and
//! refuses files that require extensions it does not know, so this module
//! parses the JSON itself (serde, typed, unknown fields skipped without
//! allocating, every top-level array bounded) and reads accessors with its
//! own bounds-checked reader.

use std::collections::HashMap;
use std::fmt;
use std::marker::PhantomData;

use base64::Engine as _;
use glam::{Mat4, Quat, Vec2, Vec3};
use serde::Deserialize;
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use treemorph_gltf::gl::{
    BYTE, FLOAT, SHORT, TRIANGLE_FAN, TRIANGLE_STRIP, TRIANGLES, UNSIGNED_BYTE, UNSIGNED_INT,
    UNSIGNED_SHORT,
};

use crate::error::{ImportError, invalid, unsupported};
use crate::options::ImportOptions;

/// Most elements of any JSON array (nodes, accessors, children, …).
const MAX_ARRAY: usize = 1 << 18;

/// Extensions whose absence of support changes nothing we read.
const HARMLESS_EXTENSIONS: &[&str] = &[
    "KHR_mesh_quantization",
    "KHR_texture_transform",
    "KHR_materials_emissive_strength",
    "KHR_materials_unlit",
    "KHR_materials_transmission",
    "KHR_materials_volume",
    "KHR_materials_ior",
    "KHR_materials_specular",
    "KHR_materials_clearcoat",
    "KHR_materials_sheen",
    "KHR_materials_iridescence",
    "KHR_materials_anisotropy",
    "KHR_materials_dispersion",
    "KHR_materials_pbrSpecularGlossiness",
    "KHR_materials_variants",
    "KHR_lights_punctual",
    "KHR_xmp_json_ld",
    "KHR_animation_pointer",
    "EXT_mesh_gpu_instancing",
];

fn bounded<'de, D, T>(d: D) -> Result<Vec<T>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    struct V<T>(PhantomData<T>);
    impl<'de, T: Deserialize<'de>> Visitor<'de> for V<T> {
        type Value = Vec<T>;
        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str("an array")
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Vec<T>, A::Error> {
            let mut out = Vec::new();
            while let Some(x) = seq.next_element()? {
                if out.len() >= MAX_ARRAY {
                    return Err(de::Error::custom(format!(
                        "an array has more than {MAX_ARRAY} elements"
                    )));
                }
                out.push(x);
            }
            Ok(out)
        }
    }
    d.deserialize_seq(V(PhantomData))
}

#[derive(Deserialize, Default)]
#[serde(rename_all = "camelCase")]
struct Root {
    asset: Option<Asset>,
    #[serde(default, deserialize_with = "bounded")]
    extensions_required: Vec<String>,
    #[serde(default, deserialize_with = "bounded")]
    accessors: Vec<Accessor>,
    #[serde(default, deserialize_with = "bounded")]
    buffer_views: Vec<BufferView>,
    #[serde(default, deserialize_with = "bounded")]
    buffers: Vec<Buffer>,
    #[serde(default, deserialize_with = "bounded")]
    meshes: Vec<Mesh>,
    #[serde(default, deserialize_with = "bounded")]
    nodes: Vec<Node>,
    #[serde(default, deserialize_with = "bounded")]
    scenes: Vec<SceneDef>,
    scene: Option<u32>,
    #[serde(default, deserialize_with = "bounded")]
    materials: Vec<Material>,
    #[serde(default, deserialize_with = "bounded")]
    textures: Vec<TextureDef>,
    #[serde(default, deserialize_with = "bounded")]
    images: Vec<Image>,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct Asset {
    version: Option<String>,
    min_version: Option<String>,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct Accessor {
    buffer_view: Option<u32>,
    #[serde(default)]
    byte_offset: u64,
    component_type: u32,
    #[serde(default)]
    normalized: bool,
    count: u64,
    #[serde(rename = "type")]
    kind: String,
    sparse: Option<Sparse>,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct Sparse {
    count: u64,
    indices: SparseIndices,
    values: SparseValues,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct SparseIndices {
    buffer_view: u32,
    #[serde(default)]
    byte_offset: u64,
    component_type: u32,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct SparseValues {
    buffer_view: u32,
    #[serde(default)]
    byte_offset: u64,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct BufferView {
    buffer: u32,
    #[serde(default)]
    byte_offset: u64,
    byte_length: u64,
    byte_stride: Option<u64>,
    extensions: Option<serde_json::Map<String, serde_json::Value>>,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct Buffer {
    uri: Option<String>,
    byte_length: u64,
}

#[derive(Deserialize)]
struct Mesh {
    name: Option<String>,
    #[serde(deserialize_with = "bounded")]
    primitives: Vec<PrimitiveDef>,
}

#[derive(Deserialize)]
struct PrimitiveDef {
    attributes: Attributes,
    indices: Option<u32>,
    material: Option<u32>,
    mode: Option<u32>,
}

#[derive(Deserialize)]
struct Attributes {
    #[serde(rename = "POSITION")]
    position: Option<u32>,
    #[serde(rename = "TEXCOORD_0")]
    texcoord_0: Option<u32>,
    #[serde(rename = "TEXCOORD_1")]
    texcoord_1: Option<u32>,
}

#[derive(Deserialize)]
struct Node {
    name: Option<String>,
    #[serde(default, deserialize_with = "bounded")]
    children: Vec<u32>,
    mesh: Option<u32>,
    #[serde(default, deserialize_with = "bounded")]
    matrix: Vec<f32>,
    #[serde(default, deserialize_with = "bounded")]
    translation: Vec<f32>,
    #[serde(default, deserialize_with = "bounded")]
    rotation: Vec<f32>,
    #[serde(default, deserialize_with = "bounded")]
    scale: Vec<f32>,
}

#[derive(Deserialize)]
struct SceneDef {
    #[serde(default, deserialize_with = "bounded")]
    nodes: Vec<u32>,
}

#[derive(Deserialize, Default)]
#[serde(rename_all = "camelCase")]
struct Material {
    name: Option<String>,
    pbr_metallic_roughness: Option<Pbr>,
    alpha_mode: Option<String>,
}

#[derive(Deserialize, Default)]
#[serde(rename_all = "camelCase")]
struct Pbr {
    #[serde(default, deserialize_with = "bounded")]
    base_color_factor: Vec<f32>,
    base_color_texture: Option<TextureInfo>,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct TextureInfo {
    index: u32,
    #[serde(default)]
    tex_coord: u32,
    extensions: Option<TextureInfoExtensions>,
}

#[derive(Deserialize)]
struct TextureInfoExtensions {
    #[serde(rename = "KHR_texture_transform")]
    transform: Option<TextureTransform>,
}

#[derive(Deserialize, Clone, Copy)]
#[serde(rename_all = "camelCase")]
struct TextureTransform {
    #[serde(default)]
    offset: [f32; 2],
    #[serde(default)]
    rotation: f32,
    #[serde(default = "unit_scale")]
    scale: [f32; 2],
    tex_coord: Option<u32>,
}

fn unit_scale() -> [f32; 2] {
    [1.0, 1.0]
}

#[derive(Deserialize)]
struct TextureDef {
    source: Option<u32>,
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct Image {
    uri: Option<String>,
    buffer_view: Option<u32>,
    mime_type: Option<String>,
}

/// How a material blends its alpha.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum AlphaMode {
    Opaque,
    Mask,
    Blend,
}

/// What the importer needs of a glTF material.
#[derive(Clone, Debug)]
pub(crate) struct MaterialInfo {
    pub name: String,
    pub alpha: AlphaMode,
    pub color: [f32; 4],
    /// Image index of the base colour texture.
    pub image: Option<usize>,
}

/// One triangle primitive of one mesh instance, in world space.
#[derive(Clone, Debug, Default)]
pub(crate) struct Primitive {
    pub mesh_name: String,
    pub node_name: String,
    pub material: Option<usize>,
    pub positions: Vec<Vec3>,
    /// Base colour texture coordinates (texture transform applied).
    pub uvs: Option<Vec<Vec2>>,
    pub triangles: Vec<[u32; 3]>,
}

/// An encoded image and its media type.
#[derive(Clone, Debug)]
pub(crate) struct EncodedImage {
    pub bytes: Vec<u8>,
    pub mime: Option<String>,
}

/// A document read into world-space primitives.
#[derive(Debug, Default)]
pub(crate) struct Document {
    pub primitives: Vec<Primitive>,
    pub materials: Vec<MaterialInfo>,
    pub images: Vec<Option<EncodedImage>>,
    pub warnings: Vec<String>,
}

/// Reads `bytes` (a GLB container or glTF JSON) into a [`Document`].
pub(crate) fn read(bytes: &[u8], options: &ImportOptions) -> Result<Document, ImportError> {
    if bytes.len() > options.max_file_bytes {
        return Err(ImportError::TooLarge(format!(
            "the file has {} bytes; at most {} are accepted",
            bytes.len(),
            options.max_file_bytes
        )));
    }
    let (json, bin) = if bytes.starts_with(b"glTF") {
        let glb = treemorph_gltf::Glb::from_slice(bytes).map_err(|e| invalid(e.to_string()))?;
        (glb.json, glb.bin)
    } else {
        let body = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
        match body.iter().find(|b| !b.is_ascii_whitespace()) {
            Some(b'{') => (body, None),
            _ => {
                return Err(invalid(
                    "the bytes are neither a GLB container (magic \"glTF\") nor a glTF JSON document",
                ));
            }
        }
    };
    if json.len() > options.max_json_bytes {
        return Err(ImportError::TooLarge(format!(
            "the JSON document has {} bytes; at most {} are accepted",
            json.len(),
            options.max_json_bytes
        )));
    }
    let root: Root = serde_json::from_slice(json)
        .map_err(|e| invalid(format!("the JSON document is not valid glTF: {e}")))?;
    Reader::new(root, bin, options)?.read()
}

struct Reader<'a> {
    root: Root,
    buffers: Vec<std::borrow::Cow<'a, [u8]>>,
    options: &'a ImportOptions,
    vertices: usize,
    triangles: usize,
    warnings: Vec<String>,
}

fn data_uri(uri: &str, what: &str) -> Result<Option<Vec<u8>>, ImportError> {
    let Some(rest) = uri.strip_prefix("data:") else {
        return Ok(None);
    };
    let Some((header, payload)) = rest.split_once(',') else {
        return Err(invalid(format!("{what} has a data URI without a comma")));
    };
    if !header.ends_with(";base64") {
        return Err(unsupported(format!(
            "{what} has a data URI that is not base64-encoded"
        )));
    }
    let engine = base64::engine::GeneralPurpose::new(
        &base64::alphabet::STANDARD,
        base64::engine::GeneralPurposeConfig::new()
            .with_decode_padding_mode(base64::engine::DecodePaddingMode::Indifferent),
    );
    engine.decode(payload.trim()).map(Some).map_err(|e| {
        invalid(format!(
            "{what} has a data URI that is not valid base64: {e}"
        ))
    })
}

fn external(uri: &str, what: &str) -> ImportError {
    let shown: String = uri.chars().take(80).collect();
    unsupported(format!(
        "{what} refers to the external file {shown:?}; only self-contained files (GLB, or glTF with data: URIs) can be imported"
    ))
}

impl<'a> Reader<'a> {
    fn new(
        root: Root,
        bin: Option<&'a [u8]>,
        options: &'a ImportOptions,
    ) -> Result<Reader<'a>, ImportError> {
        let mut warnings = Vec::new();
        match root.asset.as_ref().and_then(|a| a.version.as_deref()) {
            Some(v) if v.starts_with("2.") => {}
            Some(v) => {
                return Err(unsupported(format!(
                    "glTF version {v:?}; only version 2 is supported"
                )));
            }
            None => return Err(invalid("the document has no asset.version")),
        }
        if let Some(min) = root.asset.as_ref().and_then(|a| a.min_version.as_deref())
            && !(min == "2.0" || min == "2")
        {
            return Err(unsupported(format!("the file needs glTF {min}")));
        }
        for ext in &root.extensions_required {
            if !HARMLESS_EXTENSIONS.contains(&ext.as_str()) {
                return Err(unsupported(format!(
                    "the file requires the extension {ext}, which treemorph cannot read"
                )));
            }
            if ext != "KHR_mesh_quantization" && ext != "KHR_texture_transform" {
                warnings.push(format!("required extension {ext} is ignored"));
            }
        }
        let mut buffers = Vec::with_capacity(root.buffers.len());
        for (i, b) in root.buffers.iter().enumerate() {
            let what = format!("buffer {i}");
            let data: std::borrow::Cow<'a, [u8]> = match &b.uri {
                Some(uri) => match data_uri(uri, &what)? {
                    Some(d) => d.into(),
                    None => return Err(external(uri, &what)),
                },
                None if i == 0 => match bin {
                    Some(bin) => bin.into(),
                    None => {
                        return Err(invalid(
                            "buffer 0 has no URI, but the file has no GLB binary chunk",
                        ));
                    }
                },
                None => return Err(invalid(format!("{what} has no URI and no data"))),
            };
            if b.byte_length > data.len() as u64 {
                return Err(invalid(format!(
                    "{what} declares {} bytes but holds only {}",
                    b.byte_length,
                    data.len()
                )));
            }
            let data = match data {
                std::borrow::Cow::Borrowed(d) => {
                    std::borrow::Cow::Borrowed(&d[..b.byte_length as usize])
                }
                std::borrow::Cow::Owned(mut d) => {
                    d.truncate(b.byte_length as usize);
                    std::borrow::Cow::Owned(d)
                }
            };
            buffers.push(data);
        }
        Ok(Reader {
            root,
            buffers,
            options,
            vertices: 0,
            triangles: 0,
            warnings,
        })
    }

    fn read(mut self) -> Result<Document, ImportError> {
        let materials = self.materials()?;
        let images = self.images()?;
        let instances = self.instances()?;
        let mut primitives = Vec::new();
        for (mesh, world, node_name) in instances {
            let Some(def) = self.root.meshes.get(mesh as usize) else {
                return Err(invalid(format!(
                    "a node uses mesh {mesh}, which does not exist"
                )));
            };
            let mesh_name = def.name.clone().unwrap_or_default();
            for p in 0..def.primitives.len() {
                if let Some(prim) = self.primitive(mesh as usize, p, &world, &materials)? {
                    primitives.push(Primitive {
                        mesh_name: mesh_name.clone(),
                        node_name: node_name.clone(),
                        ..prim
                    });
                }
            }
        }
        Ok(Document {
            primitives,
            materials,
            images,
            warnings: self.warnings,
        })
    }

    fn materials(&mut self) -> Result<Vec<MaterialInfo>, ImportError> {
        let mut out = Vec::with_capacity(self.root.materials.len());
        for (i, m) in self.root.materials.iter().enumerate() {
            let alpha = match m.alpha_mode.as_deref() {
                None | Some("OPAQUE") => AlphaMode::Opaque,
                Some("MASK") => AlphaMode::Mask,
                Some("BLEND") => AlphaMode::Blend,
                Some(other) => {
                    return Err(invalid(format!(
                        "material {i} has alphaMode {other:?}; it must be OPAQUE, MASK or BLEND"
                    )));
                }
            };
            let pbr = m.pbr_metallic_roughness.as_ref();
            let mut color = [1.0f32; 4];
            if let Some(f) = pbr.map(|p| &p.base_color_factor).filter(|f| !f.is_empty()) {
                if f.len() != 4 || f.iter().any(|c| !c.is_finite()) {
                    return Err(invalid(format!(
                        "material {i} has a baseColorFactor that is not 4 finite numbers"
                    )));
                }
                for (c, v) in color.iter_mut().zip(f) {
                    *c = v.clamp(0.0, 1.0);
                }
            }
            let image = match pbr.and_then(|p| p.base_color_texture.as_ref()) {
                None => None,
                Some(t) => {
                    let texture = self.root.textures.get(t.index as usize).ok_or_else(|| {
                        invalid(format!(
                            "material {i} uses texture {}, which does not exist",
                            t.index
                        ))
                    })?;
                    match texture.source {
                        Some(s) if (s as usize) < self.root.images.len() => Some(s as usize),
                        Some(s) => {
                            return Err(invalid(format!(
                                "texture {} uses image {s}, which does not exist",
                                t.index
                            )));
                        }
                        None => None,
                    }
                }
            };
            out.push(MaterialInfo {
                name: m.name.clone().unwrap_or_default(),
                alpha,
                color,
                image,
            });
        }
        Ok(out)
    }

    fn images(&mut self) -> Result<Vec<Option<EncodedImage>>, ImportError> {
        let mut out = Vec::with_capacity(self.root.images.len());
        for (i, image) in self.root.images.iter().enumerate() {
            let what = format!("image {i}");
            let bytes = match (&image.uri, image.buffer_view) {
                (Some(uri), _) => match data_uri(uri, &what)? {
                    Some(d) => d,
                    None => return Err(external(uri, &what)),
                },
                (None, Some(v)) => self.view_bytes(v, &what)?.to_vec(),
                (None, None) => {
                    self.warnings
                        .push(format!("{what} has neither a URI nor a buffer view"));
                    out.push(None);
                    continue;
                }
            };
            let mime = image.mime_type.clone().or_else(|| {
                image
                    .uri
                    .as_deref()
                    .and_then(|u| u.strip_prefix("data:"))
                    .and_then(|u| u.split([';', ',']).next())
                    .map(str::to_owned)
            });
            out.push(Some(EncodedImage { bytes, mime }));
        }
        Ok(out)
    }

    /// Meshes to instantiate with their world transforms and node names.
    fn instances(&mut self) -> Result<Vec<(u32, Mat4, String)>, ImportError> {
        let nodes = &self.root.nodes;
        let n = nodes.len();
        if n == 0 {
            if !self.root.meshes.is_empty() {
                self.warnings.push(
                    "the file has meshes but no nodes; every mesh is imported once, untransformed"
                        .into(),
                );
            }
            return Ok((0..self.root.meshes.len() as u32)
                .map(|m| (m, Mat4::IDENTITY, String::new()))
                .collect());
        }
        let roots: Vec<u32> = if self.root.scenes.is_empty() {
            let mut is_child = vec![false; n];
            for node in nodes {
                for &c in &node.children {
                    if let Some(slot) = is_child.get_mut(c as usize) {
                        *slot = true;
                    }
                }
            }
            (0..n as u32).filter(|&i| !is_child[i as usize]).collect()
        } else {
            let s = self.root.scene.unwrap_or(0) as usize;
            self.root
                .scenes
                .get(s)
                .ok_or_else(|| invalid(format!("the default scene {s} does not exist")))?
                .nodes
                .clone()
        };
        let mut visited = vec![false; n];
        let mut out = Vec::new();
        let mut stack: Vec<(u32, Mat4)> =
            roots.iter().rev().map(|&r| (r, Mat4::IDENTITY)).collect();
        while let Some((i, parent)) = stack.pop() {
            let node = nodes
                .get(i as usize)
                .ok_or_else(|| invalid(format!("node {i} does not exist ({n} nodes)")))?;
            if std::mem::replace(&mut visited[i as usize], true) {
                return Err(invalid(format!(
                    "node {i} is reached twice: the node hierarchy has a cycle or a node with two parents"
                )));
            }
            let local = local_transform(node, i)?;
            let world = parent * local;
            if !world.is_finite() {
                return Err(invalid(format!(
                    "the world transform of node {i} is not finite"
                )));
            }
            if let Some(m) = node.mesh {
                out.push((m, world, node.name.clone().unwrap_or_default()));
            }
            for &c in node.children.iter().rev() {
                stack.push((c, world));
            }
        }
        Ok(out)
    }

    fn primitive(
        &mut self,
        mesh: usize,
        index: usize,
        world: &Mat4,
        materials: &[MaterialInfo],
    ) -> Result<Option<Primitive>, ImportError> {
        let what = format!("mesh {mesh} primitive {index}");
        let def = &self.root.meshes[mesh].primitives[index];
        let mode = def.mode.unwrap_or(TRIANGLES);
        if mode > TRIANGLE_FAN {
            return Err(invalid(format!("{what} has mode {mode}")));
        }
        if mode < TRIANGLES {
            self.warnings.push(format!(
                "{what} draws points or lines (mode {mode}) and is skipped"
            ));
            return Ok(None);
        }
        let material = match def.material {
            Some(m) if (m as usize) < materials.len() => Some(m as usize),
            Some(m) => {
                return Err(invalid(format!(
                    "{what} uses material {m}, which does not exist"
                )));
            }
            None => None,
        };
        let Some(position) = def.attributes.position else {
            self.warnings
                .push(format!("{what} has no POSITION attribute and is skipped"));
            return Ok(None);
        };
        let (indices, texcoords) = (
            def.indices,
            [def.attributes.texcoord_0, def.attributes.texcoord_1],
        );
        let transform = material.and_then(|m| self.texture_transform(m));
        let texcoord_set = transform.map(|(set, _)| set).unwrap_or(0) as usize;

        let raw = self.accessor(position, &format!("{what} POSITION"), Use::Position)?;
        let count = raw.count;
        self.vertices = self.vertices.saturating_add(count);
        if self.vertices > self.options.max_vertices {
            return Err(ImportError::TooLarge(format!(
                "the meshes have more than {} vertices",
                self.options.max_vertices
            )));
        }
        let mut positions = Vec::with_capacity(count);
        for (k, p) in raw.values.chunks_exact(3).enumerate() {
            let v = world.transform_point3(Vec3::new(p[0], p[1], p[2]));
            if !v.is_finite() {
                return Err(invalid(format!(
                    "{what} POSITION {k} is not finite after its node transform"
                )));
            }
            positions.push(v);
        }

        let uvs = match texcoords.get(texcoord_set).copied().flatten() {
            Some(a) => {
                let raw =
                    self.accessor(a, &format!("{what} TEXCOORD_{texcoord_set}"), Use::TexCoord)?;
                if raw.count != count {
                    return Err(invalid(format!(
                        "{what} has {} texture coordinates for {count} positions",
                        raw.count
                    )));
                }
                let mut uvs: Vec<Vec2> = raw
                    .values
                    .chunks_exact(2)
                    .map(|c| Vec2::new(c[0], c[1]))
                    .collect();
                if let Some((_, t)) = transform {
                    let (s, c) = t.rotation.sin_cos();
                    for uv in &mut uvs {
                        let scaled = Vec2::new(uv.x * t.scale[0], uv.y * t.scale[1]);
                        let rotated =
                            Vec2::new(c * scaled.x + s * scaled.y, -s * scaled.x + c * scaled.y);
                        *uv = rotated + Vec2::from(t.offset);
                    }
                }
                if uvs.iter().any(|uv| !uv.is_finite()) {
                    return Err(invalid(format!(
                        "{what} has texture coordinates that are not finite"
                    )));
                }
                Some(uvs)
            }
            None => None,
        };

        let list: Vec<u32> = match indices {
            Some(a) => {
                let list = self.indices(a, &format!("{what} indices"))?;
                if let Some(k) = list.iter().position(|&i| i as usize >= count) {
                    return Err(invalid(format!(
                        "{what} index {k} is {}, but there are only {count} vertices",
                        list[k]
                    )));
                }
                list
            }
            None => (0..count as u32).collect(),
        };
        let triangles = triangulate(&list, mode);
        self.triangles = self.triangles.saturating_add(triangles.len());
        if self.triangles > self.options.max_triangles {
            return Err(ImportError::TooLarge(format!(
                "the meshes have more than {} triangles",
                self.options.max_triangles
            )));
        }
        Ok(Some(Primitive {
            material,
            positions,
            uvs,
            triangles,
            ..Primitive::default()
        }))
    }

    /// The base colour texture's coordinate set and KHR_texture_transform.
    fn texture_transform(&self, material: usize) -> Option<(u32, TextureTransform)> {
        let info = self.root.materials[material]
            .pbr_metallic_roughness
            .as_ref()?
            .base_color_texture
            .as_ref()?;
        let t = info
            .extensions
            .as_ref()
            .and_then(|e| e.transform)
            .unwrap_or(TextureTransform {
                offset: [0.0; 2],
                rotation: 0.0,
                scale: [1.0; 2],
                tex_coord: None,
            });
        Some((t.tex_coord.unwrap_or(info.tex_coord), t))
    }

    fn view_bytes(&self, index: u32, what: &str) -> Result<&[u8], ImportError> {
        let view = self.view(index, what)?;
        let buffer = &self.buffers[view.buffer as usize];
        Ok(&buffer[view.byte_offset as usize..(view.byte_offset + view.byte_length) as usize])
    }

    /// A buffer view, checked to lie inside its buffer.
    fn view(&self, index: u32, what: &str) -> Result<&BufferView, ImportError> {
        let view = self.root.buffer_views.get(index as usize).ok_or_else(|| {
            invalid(format!(
                "{what} uses buffer view {index}, which does not exist"
            ))
        })?;
        if view
            .extensions
            .as_ref()
            .is_some_and(|e| e.contains_key("EXT_meshopt_compression"))
        {
            return Err(unsupported(format!(
                "{what} uses buffer view {index}, which is compressed with EXT_meshopt_compression"
            )));
        }
        let buffer = self.buffers.get(view.buffer as usize).ok_or_else(|| {
            invalid(format!(
                "buffer view {index} uses buffer {}, which does not exist",
                view.buffer
            ))
        })?;
        let end = view.byte_offset.checked_add(view.byte_length);
        if end.is_none_or(|e| e > buffer.len() as u64) {
            return Err(invalid(format!(
                "buffer view {index} spans bytes {}..+{} of buffer {}, which has {} bytes",
                view.byte_offset,
                view.byte_length,
                view.buffer,
                buffer.len()
            )));
        }
        Ok(view)
    }

    /// Reads an accessor as floats (positions, texture coordinates).
    fn accessor(&self, index: u32, what: &str, usage: Use) -> Result<Values, ImportError> {
        let (count, values) = self.read_accessor(index, what, usage, |v| v as f32)?;
        if let Some(k) = values.iter().position(|v| !v.is_finite()) {
            let components = if usage == Use::Position { 3 } else { 2 };
            return Err(invalid(format!(
                "{what} (accessor {index}) element {} is not a finite number",
                k / components
            )));
        }
        Ok(Values {
            count,
            values: values.into(),
        })
    }

    /// Reads an index accessor.
    fn indices(&self, index: u32, what: &str) -> Result<Vec<u32>, ImportError> {
        Ok(self.read_accessor(index, what, Use::Index, |v| v as u32)?.1)
    }

    fn read_accessor<T: Copy + Default>(
        &self,
        index: u32,
        what: &str,
        usage: Use,
        convert: impl Fn(f64) -> T,
    ) -> Result<(usize, Vec<T>), ImportError> {
        let a = self.root.accessors.get(index as usize).ok_or_else(|| {
            invalid(format!(
                "{what} uses accessor {index}, which does not exist"
            ))
        })?;
        let what = format!("{what} (accessor {index})");
        let components = match a.kind.as_str() {
            "SCALAR" => 1,
            "VEC2" => 2,
            "VEC3" => 3,
            "VEC4" => 4,
            "MAT2" => 4,
            "MAT3" => 9,
            "MAT4" => 16,
            other => return Err(invalid(format!("{what} has type {other:?}"))),
        };
        let size = match a.component_type {
            BYTE | UNSIGNED_BYTE => 1u64,
            SHORT | UNSIGNED_SHORT => 2,
            UNSIGNED_INT | FLOAT => 4,
            other => return Err(invalid(format!("{what} has componentType {other}"))),
        };
        let (want_components, allowed): (usize, &[u32]) = match usage {
            Use::Position => (3, &[FLOAT, BYTE, UNSIGNED_BYTE, SHORT, UNSIGNED_SHORT]),
            Use::TexCoord => (2, &[FLOAT, BYTE, UNSIGNED_BYTE, SHORT, UNSIGNED_SHORT]),
            Use::Index => (1, &[UNSIGNED_BYTE, UNSIGNED_SHORT, UNSIGNED_INT]),
        };
        if components != want_components {
            return Err(invalid(format!(
                "{what} has type {}, expected {}",
                a.kind,
                ["", "SCALAR", "VEC2", "VEC3"][want_components]
            )));
        }
        if !allowed.contains(&a.component_type) {
            return Err(invalid(format!(
                "{what} has componentType {}, which is not allowed here",
                a.component_type
            )));
        }
        let limit = match usage {
            Use::Index => self.options.max_triangles.saturating_mul(3),
            _ => self.options.max_vertices,
        } as u64;
        let element = size * components as u64;
        let count = a.count;
        // Check the count against the bytes first: a tiny file declaring
        // 2^31 elements is broken, not merely large.
        let dense = match a.buffer_view {
            Some(v) => {
                let view = self.view(v, &what)?;
                let stride = match view.byte_stride {
                    Some(s) if usage != Use::Index => {
                        if !(4..=252).contains(&s) || s < element {
                            return Err(invalid(format!(
                                "buffer view {v} has byteStride {s}, which does not fit {what}'s {element}-byte elements"
                            )));
                        }
                        s
                    }
                    _ => element,
                };
                let need = if count == 0 {
                    Some(0)
                } else {
                    (count - 1)
                        .checked_mul(stride)
                        .and_then(|x| x.checked_add(element))
                        .and_then(|x| x.checked_add(a.byte_offset))
                };
                if need.is_none_or(|n| n > view.byte_length) {
                    return Err(invalid(format!(
                        "{what} needs {count} elements of {element} bytes (stride {stride}) from byte {}, but buffer view {v} has {} bytes",
                        a.byte_offset, view.byte_length
                    )));
                }
                Some((view, stride))
            }
            None => None,
        };
        if let Some(sparse) = &a.sparse
            && (sparse.count == 0 || sparse.count > count)
        {
            return Err(invalid(format!(
                "{what} has {} sparse elements for {count} elements",
                sparse.count
            )));
        }
        if count > limit {
            return Err(ImportError::TooLarge(format!(
                "{what} has {count} elements; at most {limit} are accepted"
            )));
        }
        let scale = match (a.normalized, usage, a.component_type) {
            (true, Use::Position | Use::TexCoord, BYTE) => Some(127.0),
            (true, Use::Position | Use::TexCoord, UNSIGNED_BYTE) => Some(255.0),
            (true, Use::Position | Use::TexCoord, SHORT) => Some(32767.0),
            (true, Use::Position | Use::TexCoord, UNSIGNED_SHORT) => Some(65535.0),
            _ => None,
        };
        let value = |buffer: &[u8], at: usize| {
            let v = component(buffer, at, a.component_type);
            convert(match scale {
                Some(s) => (v / s).max(-1.0),
                None => v,
            })
        };
        let count = count as usize;
        // An accessor without a buffer view is all zeros (glTF 3.6.2.3),
        // then sparse values.
        let mut values = vec![T::default(); count * components];
        if let Some((view, stride)) = dense {
            let buffer = &self.buffers[view.buffer as usize];
            let start = (view.byte_offset + a.byte_offset) as usize;
            for (e, out) in values.chunks_exact_mut(components).enumerate() {
                let at = start + e * stride as usize;
                for (c, o) in out.iter_mut().enumerate() {
                    *o = value(buffer, at + c * size as usize);
                }
            }
        }
        if let Some(sparse) = &a.sparse {
            self.apply_sparse(sparse, a, components, size, &mut values, &what, &value)?;
        }
        Ok((count, values))
    }

    #[allow(clippy::too_many_arguments)]
    fn apply_sparse<T>(
        &self,
        sparse: &Sparse,
        a: &Accessor,
        components: usize,
        size: u64,
        values: &mut [T],
        what: &str,
        value: &impl Fn(&[u8], usize) -> T,
    ) -> Result<(), ImportError> {
        let isize = match sparse.indices.component_type {
            UNSIGNED_BYTE => 1u64,
            UNSIGNED_SHORT => 2,
            UNSIGNED_INT => 4,
            other => {
                return Err(invalid(format!(
                    "{what} has sparse indices of componentType {other}"
                )));
            }
        };
        let iview = self.view(sparse.indices.buffer_view, what)?;
        let vview = self.view(sparse.values.buffer_view, what)?;
        let n = sparse.count;
        let element = size * components as u64;
        let fits = |view: &BufferView, offset: u64, bytes: Option<u64>| {
            bytes
                .and_then(|b| b.checked_add(offset))
                .is_some_and(|end| end <= view.byte_length)
        };
        if !fits(iview, sparse.indices.byte_offset, n.checked_mul(isize))
            || !fits(vview, sparse.values.byte_offset, n.checked_mul(element))
        {
            return Err(invalid(format!(
                "{what}'s sparse indices or values do not fit their buffer views"
            )));
        }
        let ibuf = &self.buffers[iview.buffer as usize];
        let vbuf = &self.buffers[vview.buffer as usize];
        let istart = (iview.byte_offset + sparse.indices.byte_offset) as usize;
        let vstart = (vview.byte_offset + sparse.values.byte_offset) as usize;
        for k in 0..n as usize {
            let target = component(
                ibuf,
                istart + k * isize as usize,
                sparse.indices.component_type,
            ) as u64;
            if target >= a.count {
                return Err(invalid(format!(
                    "{what} sparse index {k} is {target}, but there are only {} elements",
                    a.count
                )));
            }
            for c in 0..components {
                values[target as usize * components + c] =
                    value(vbuf, vstart + k * element as usize + c * size as usize);
            }
        }
        Ok(())
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Use {
    Position,
    TexCoord,
    Index,
}

struct Values {
    count: usize,
    values: Box<[f32]>,
}

/// One little-endian component; the caller checked the bounds.
fn component(buffer: &[u8], at: usize, kind: u32) -> f64 {
    let b = |n: usize| &buffer[at..at + n];
    match kind {
        BYTE => f64::from(b(1)[0] as i8),
        UNSIGNED_BYTE => f64::from(b(1)[0]),
        SHORT => f64::from(i16::from_le_bytes([b(2)[0], b(2)[1]])),
        UNSIGNED_SHORT => f64::from(u16::from_le_bytes([b(2)[0], b(2)[1]])),
        UNSIGNED_INT => {
            let x = b(4);
            f64::from(u32::from_le_bytes([x[0], x[1], x[2], x[3]]))
        }
        _ => {
            let x = b(4);
            f64::from(f32::from_le_bytes([x[0], x[1], x[2], x[3]]))
        }
    }
}

fn local_transform(node: &Node, i: u32) -> Result<Mat4, ImportError> {
    let bad = |what: &str| invalid(format!("node {i} has an invalid {what}"));
    let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
    if !node.matrix.is_empty() {
        if node.matrix.len() != 16 || !finite(&node.matrix) {
            return Err(bad("matrix (it must be 16 finite numbers)"));
        }
        return Ok(Mat4::from_cols_slice(&node.matrix));
    }
    let t = match node.translation.len() {
        0 => Vec3::ZERO,
        3 if finite(&node.translation) => Vec3::from_slice(&node.translation),
        _ => return Err(bad("translation")),
    };
    let r = match node.rotation.len() {
        0 => Quat::IDENTITY,
        4 if finite(&node.rotation) => {
            let q = Quat::from_slice(&node.rotation);
            let len = q.length();
            if len < 1e-6 {
                return Err(bad("rotation (a zero quaternion)"));
            }
            q / len
        }
        _ => return Err(bad("rotation")),
    };
    let s = match node.scale.len() {
        0 => Vec3::ONE,
        3 if finite(&node.scale) => Vec3::from_slice(&node.scale),
        _ => return Err(bad("scale")),
    };
    Ok(Mat4::from_scale_rotation_translation(s, r, t))
}

/// Triangles of an index list in glTF mode 4 (list), 5 (strip) or 6 (fan);
/// degenerate triangles (a repeated index) are dropped.
fn triangulate(list: &[u32], mode: u32) -> Vec<[u32; 3]> {
    let mut out = Vec::new();
    match mode {
        TRIANGLES => {
            out.reserve(list.len() / 3);
            out.extend(list.chunks_exact(3).map(|t| [t[0], t[1], t[2]]));
        }
        TRIANGLE_STRIP => {
            for k in 2..list.len() {
                let t = if k % 2 == 0 {
                    [list[k - 2], list[k - 1], list[k]]
                } else {
                    [list[k - 1], list[k - 2], list[k]]
                };
                out.push(t);
            }
        }
        _ => {
            for k in 2..list.len() {
                out.push([list[0], list[k - 1], list[k]]);
            }
        }
    }
    out.retain(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2]);
    out
}

/// Decoded RGBA pixels of an encoded image, or why not.
pub(crate) fn decode_image(
    image: &EncodedImage,
    max_side: u32,
) -> Result<(treemorph_tree::Texture, treemorph_tree::RgbaImage), String> {
    let is_png = image.bytes.starts_with(b"\x89PNG");
    let is_jpeg = image.bytes.starts_with(&[0xFF, 0xD8]);
    if is_png {
        let texture = treemorph_tree::Texture::from_png(image.bytes.clone(), max_side)
            .map_err(|e| e.to_string())?;
        let rgba = texture.decode().map_err(|e| e.to_string())?;
        return Ok((texture, rgba));
    }
    if is_jpeg {
        let mut decoder = jpeg_decoder::Decoder::new(std::io::Cursor::new(&image.bytes));
        decoder
            .read_info()
            .map_err(|e| format!("not a readable JPEG: {e}"))?;
        let info = decoder.info().ok_or("not a readable JPEG")?;
        let (w, h) = (u32::from(info.width), u32::from(info.height));
        if w > max_side || h > max_side {
            return Err(format!(
                "the image is {w}×{h} pixels; at most {max_side} pixels per side are allowed"
            ));
        }
        decoder.set_max_decoding_buffer_size((max_side as usize).pow(2) * 4);
        let pixels = decoder
            .decode()
            .map_err(|e| format!("not a readable JPEG: {e}"))?;
        let rgba: Vec<u8> = match info.pixel_format {
            jpeg_decoder::PixelFormat::RGB24 => pixels
                .chunks_exact(3)
                .flat_map(|c| [c[0], c[1], c[2], 255])
                .collect(),
            jpeg_decoder::PixelFormat::L8 => pixels.iter().flat_map(|&g| [g, g, g, 255]).collect(),
            jpeg_decoder::PixelFormat::L16 => pixels
                .chunks_exact(2)
                .flat_map(|c| [c[0], c[0], c[0], 255])
                .collect(),
            jpeg_decoder::PixelFormat::CMYK32 => pixels
                .chunks_exact(4)
                .flat_map(|c| {
                    let k = 255 - u16::from(c[3]);
                    let ch = |x: u8| ((255 - u16::from(x)) * k / 255) as u8;
                    [ch(c[0]), ch(c[1]), ch(c[2]), 255]
                })
                .collect(),
        };
        let rgba = treemorph_tree::RgbaImage::new(w, h, rgba).map_err(|e| e.to_string())?;
        return Ok((treemorph_tree::Texture::from_rgba(&rgba), rgba));
    }
    let mime = image.mime.as_deref().unwrap_or("unknown type");
    Err(format!("the image ({mime}) is neither PNG nor JPEG"))
}

/// Per-material image decode cache, shared by the classification and the
/// leaves.
#[derive(Default)]
pub(crate) struct ImageCache {
    decoded: HashMap<
        usize,
        Option<(
            treemorph_tree::Texture,
            std::sync::Arc<treemorph_tree::RgbaImage>,
        )>,
    >,
}

impl ImageCache {
    /// The decoded image `index`, or `None` (with a warning) when it cannot
    /// be read.
    pub(crate) fn get(
        &mut self,
        doc: &Document,
        index: usize,
        max_side: u32,
        warnings: &mut Vec<String>,
    ) -> Option<(
        treemorph_tree::Texture,
        std::sync::Arc<treemorph_tree::RgbaImage>,
    )> {
        self.decoded
            .entry(index)
            .or_insert_with(|| {
                let image = doc.images.get(index)?.as_ref()?;
                match decode_image(image, max_side) {
                    Ok((t, rgba)) => Some((t, std::sync::Arc::new(rgba))),
                    Err(e) => {
                        warnings.push(format!("image {index} is ignored: {e}"));
                        None
                    }
                }
            })
            .clone()
    }
}

#[cfg(test)]
#[path = "read_tests.rs"]
mod tests;
