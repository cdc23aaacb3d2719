//! One GLB per frame: [`FrameGlbWriter`].
//!
//! Each file is a standalone glTF 2.0 binary with the same layout as the
//! static export ([`crate::export`]): one scene, nodes and meshes named
//! `branches` and `leaves`, float POSITION (exact min/max), NORMAL and
//! TEXCOORD_0, `u16` or `u32` indices. What differs:
//!
//! - **Leaves** are the frame's morphed contours by default
//!   ([`LeafShape::Contour`] with 24 points; quads on request), and carry
//!   the frame's **blended leaf texture**: a leaf blending materials
//!   `a → b` at blend `s` is drawn with the texel-wise blend of `a`'s
//!   texture and `b`'s texture warped onto `a`'s outline
//!   ([`crate::contour::blend_textures`]), colour factors baked in. Blends
//!   are quantised to [`FrameGlbOptions::blend_steps`] steps; one
//!   primitive (and one texture) per distinct (pair, step) present in the
//!   frame. Blended textures are cached in the writer, so a sequence
//!   computes each (pair, step) once.
//! - **Bark** is blended between the topology's two barks by the frame's
//!   `bark_blend` the same way (colour factors, and textures when present).
//! - **No tree is embedded**: a frame is not a tree (its union topology
//!   keeps zero-size chains and leaves). The scene's `extras` hold
//!   `{"frame": {"t": …}}`.
//!
//! The writer is a reusable context: meshers, blended textures and the
//! output buffer ([`FrameGlbWriter::write_into`]) persist between frames.

use serde_json::{Map, Value, json};
use treemorph_tree::{Frame, FrameTopology};

use crate::doc::{Data, Doc, Wrap, asset, color};
use crate::frames::{EncodeError, FrameMeshes, Look, Looks, check_frame};
use crate::gl::TRIANGLES;
use crate::mesh::{LeafShape, MeshBuffers, MeshOptions};

/// Options of [`FrameGlbWriter`].
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct FrameGlbOptions {
    /// Tube sides and leaf shape (default: 3 to 10 sides and
    /// [`LeafShape::Contour`] of 12 points — the blade's alpha cuts out
    /// its exact shape; the contour only has to carry the morph between
    /// two outlines, and a frame stays a fraction of the size it would be
    /// with finer outlines).
    pub mesh: MeshOptions,
    /// Leaf and bark blends are rounded to multiples of `1 / blend_steps`
    /// (default 16; at least 1): each distinct step present in a frame is
    /// one primitive and one texture.
    pub blend_steps: u32,
}

impl Default for FrameGlbOptions {
    fn default() -> FrameGlbOptions {
        let mesh = MeshOptions::default()
            .with_sides(3, 10)
            .with_leaf_shape(LeafShape::Contour { points: 12 });
        FrameGlbOptions {
            mesh,
            blend_steps: 16,
        }
    }
}

impl FrameGlbOptions {
    /// These options with [`FrameGlbOptions::mesh`] set.
    #[must_use]
    pub fn with_mesh(mut self, mesh: MeshOptions) -> FrameGlbOptions {
        self.mesh = mesh;
        self
    }

    /// These options with [`FrameGlbOptions::blend_steps`] set.
    #[must_use]
    pub fn with_blend_steps(mut self, steps: u32) -> FrameGlbOptions {
        self.blend_steps = steps;
        self
    }
}

/// Writes frames of one sequence as standalone GLB files.
///
/// ```
/// use treemorph_gltf::frame_glb::{FrameGlbOptions, FrameGlbWriter};
/// use treemorph_tree::{Frame, FrameTopology};
/// # let tree = treemorph_gltf::sample::sample_tree(20);
/// let topology = FrameTopology::of_tree(&tree);
/// let frame = Frame::of_tree(&tree);
/// let mut writer = FrameGlbWriter::new(&topology, &frame.radii, &FrameGlbOptions::default())?;
/// let glb = writer.write(&frame)?;
/// assert_eq!(&glb[..4], b"glTF");
/// # Ok::<(), treemorph_gltf::frames::EncodeError>(())
/// ```
pub struct FrameGlbWriter {
    meshes: FrameMeshes,
    looks: Looks,
    node_count: usize,
    leaf_count: usize,
    /// Per leaf mesh group: the leaves of that group, in index order.
    group_leaves: Vec<Vec<u32>>,
    /// Reordered leaf indices of the current frame, for groups whose
    /// leaves fall on several blend steps.
    sorted: Vec<u32>,
    /// Scratch: per leaf of a group, its step.
    steps: Vec<u32>,
}

impl FrameGlbWriter {
    /// Plans the meshes and materials of `topology`. Pass the per-node
    /// maximum radius over the sequence as `reference_radii`
    /// ([`crate::frames::max_radii`]); bark UVs come from the first frame
    /// written.
    pub fn new(
        topology: &FrameTopology,
        reference_radii: &[f32],
        options: &FrameGlbOptions,
    ) -> Result<FrameGlbWriter, EncodeError> {
        if options.blend_steps == 0 || options.blend_steps > 1024 {
            return Err(EncodeError::InvalidOptions(format!(
                "blend_steps must be in 1..=1024; got {}",
                options.blend_steps
            )));
        }
        let meshes = FrameMeshes::new(topology, reference_radii, &options.mesh)?;
        let looks = Looks::new(topology, meshes.leaves(), options.blend_steps);
        let leaves = meshes.leaves().buffers();
        let shape = meshes.leaves().shape();
        let (per_vertex, per_index) = (shape.vertices_per_leaf(), shape.indices_per_leaf());
        let group_leaves = leaves
            .groups
            .iter()
            .map(|g| {
                let first = g.first_index as usize;
                (0..g.index_count as usize / per_index)
                    .map(|j| leaves.indices[first + j * per_index] / per_vertex as u32)
                    .collect()
            })
            .collect();
        Ok(FrameGlbWriter {
            meshes,
            looks,
            node_count: topology.node_count(),
            leaf_count: topology.leaves.len(),
            group_leaves,
            sorted: Vec::new(),
            steps: Vec::new(),
        })
    }

    /// The meshers (for their vertex counts and last buffers).
    pub fn meshes(&self) -> &FrameMeshes {
        &self.meshes
    }

    /// Fixes the bark texture coordinates from `frame` instead of the
    /// first frame written.
    pub fn set_uv_frame(&mut self, frame: &Frame) -> Result<(), EncodeError> {
        self.meshes.set_uv_frame(frame)
    }

    /// The GLB of one frame.
    pub fn write(&mut self, frame: &Frame) -> Result<Vec<u8>, EncodeError> {
        let mut out = Vec::new();
        self.write_into(frame, &mut out)?;
        Ok(out)
    }

    /// The GLB of one frame, written into `out` (replacing its contents;
    /// reusing one buffer across frames saves faulting in fresh memory).
    pub fn write_into(&mut self, frame: &Frame, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        check_frame(frame, self.node_count, self.leaf_count)?;
        let bark_step = self.looks.step(frame.bark_blend);
        // Leaf primitives: (index range source, material key).
        let shape_indices = self.meshes.leaves().shape().indices_per_leaf();
        let (branches, leaves) = self.meshes.mesh(frame)?;

        // Sort each blending group's leaves by step (a counting sort into
        // `sorted`), keeping groups whose leaves share one step as they are.
        let steps = self.looks.steps() as usize;
        let mut parts: Vec<(Part, [u32; 3])> = Vec::new();
        self.sorted.clear();
        for (group, members) in leaves.groups.iter().zip(&self.group_leaves) {
            let [a, b] = group.materials;
            if group.index_count == 0 {
                continue;
            }
            let whole = Part::Mesher {
                first: group.first_index as usize,
                count: group.index_count as usize,
            };
            if a == b {
                parts.push((whole, [a, a, 0]));
                continue;
            }
            self.steps.clear();
            self.steps.extend(
                members
                    .iter()
                    .map(|&l| self.looks.step(frame.leaves[l as usize].blend)),
            );
            let first_step = self.steps[0];
            if self.steps.iter().all(|&q| q == first_step) {
                parts.push((whole, [a, b, first_step]));
                continue;
            }
            let mut counts = vec![0usize; steps + 1];
            for &q in &self.steps {
                counts[q as usize] += 1;
            }
            let mut starts = vec![0usize; steps + 2];
            for q in 0..=steps {
                starts[q + 1] = starts[q] + counts[q];
            }
            let base = self.sorted.len();
            self.sorted.resize(base + members.len() * shape_indices, 0);
            let mut fill = starts.clone();
            let first = group.first_index as usize;
            for (j, &q) in self.steps.iter().enumerate() {
                let at = base + fill[q as usize] * shape_indices;
                let from = first + j * shape_indices;
                self.sorted[at..at + shape_indices]
                    .copy_from_slice(&leaves.indices[from..from + shape_indices]);
                fill[q as usize] += 1;
            }
            for q in 0..=steps {
                if counts[q] > 0 {
                    parts.push((
                        Part::Sorted {
                            first: base + starts[q] * shape_indices,
                            count: counts[q] * shape_indices,
                        },
                        [a, b, q as u32],
                    ));
                }
            }
        }

        // Materials: 0 is the bark, then one per distinct leaf look. A pair
        // at step 0 looks like its first material alone: one material (and
        // texture) for all of them.
        let part_keys: Vec<[u32; 3]> = parts
            .iter()
            .map(|&(_, [a, b, q])| {
                if a == b || q == 0 {
                    [a, a, 0]
                } else {
                    [a, b, q]
                }
            })
            .collect();
        self.looks.prepare(bark_step, &part_keys);
        let mut looks: Vec<Look> = vec![self.looks.bark(bark_step).clone()];
        let mut keys: Vec<[u32; 3]> = Vec::new();
        let mut primitive_materials = Vec::with_capacity(parts.len());
        for key in part_keys {
            let index = match keys.iter().position(|k| *k == key) {
                Some(i) => i,
                None => {
                    keys.push(key);
                    looks.push(self.looks.leaf_blend(key[0], key[1], key[2]).clone());
                    keys.len() - 1
                }
            };
            primitive_materials.push(1 + index);
        }

        let mut doc = Doc::default();
        for (i, look) in looks.iter().enumerate() {
            let leaf = i > 0;
            let wrap = if leaf { Wrap::Clamp } else { Wrap::Repeat };
            let texture = look
                .texture
                .as_ref()
                .map(|t| doc.texture(Data::Bytes(t.png()), &look.name, wrap));
            doc.materials.push(material_json(look, texture, leaf));
        }
        let branch_mesh = mesh_json(
            &mut doc,
            "branches",
            branches,
            &[(
                Part::Mesher {
                    first: 0,
                    count: branches.indices.len(),
                },
                0,
            )],
            &self.sorted,
        );
        let leaf_parts: Vec<(Part, usize)> = parts
            .iter()
            .zip(&primitive_materials)
            .map(|((p, _), &m)| (*p, m))
            .collect();
        let leaf_mesh = mesh_json(&mut doc, "leaves", leaves, &leaf_parts, &self.sorted);
        for (name, mesh) in [("branches", branch_mesh), ("leaves", leaf_mesh)] {
            let mut node = json!({ "name": name });
            if let Some(m) = mesh {
                node["mesh"] = json!(m);
            }
            doc.nodes.push(node);
        }
        let mut root = Map::new();
        root.insert("asset".into(), asset());
        root.insert("scene".into(), json!(0));
        root.insert(
            "scenes".into(),
            json!([{ "nodes": [0, 1], "extras": { "frame": { "t": frame.t } } }]),
        );
        doc.write(root, out).map_err(|total| {
            EncodeError::TooLarge(format!(
                "the frame's GLB would be {total} bytes; a GLB holds at most 4 GiB"
            ))
        })
    }
}

/// Where a primitive's indices come from.
#[derive(Clone, Copy, Debug)]
enum Part {
    /// A range of the mesher's index buffer.
    Mesher { first: usize, count: usize },
    /// A range of the writer's reordered indices.
    Sorted { first: usize, count: usize },
}

/// The glTF material of a look (leaves: alpha-masked and double-sided).
pub(crate) fn material_json(look: &Look, texture: Option<usize>, leaf: bool) -> Value {
    let mut pbr = json!({
        "baseColorFactor": color(look.color),
        "metallicFactor": 0.0,
        "roughnessFactor": if leaf { 0.8 } else { 0.9 },
    });
    if let Some(t) = texture {
        pbr["baseColorTexture"] = json!({ "index": t });
    }
    let mut m = json!({ "name": look.name, "pbrMetallicRoughness": pbr });
    if leaf {
        m["alphaMode"] = json!("MASK");
        m["alphaCutoff"] = json!(0.5);
        m["doubleSided"] = json!(true);
    }
    m
}

/// Writes a mesh with shared attributes and one primitive per part; `None`
/// when there is nothing to draw.
fn mesh_json<'a>(
    doc: &mut Doc<'a>,
    name: &str,
    mesh: &'a MeshBuffers,
    parts: &[(Part, usize)],
    sorted: &'a [u32],
) -> Option<usize> {
    let count = mesh.positions.len();
    if mesh.indices.is_empty() || count == 0 {
        return None;
    }
    let b = mesh.bounds;
    let position = doc.vec3(&mesh.positions, Some((b.min, b.max)));
    let normal = doc.vec3(&mesh.normals, None);
    let uv = doc.vec2(&mesh.uvs);
    let primitives: Vec<Value> = parts
        .iter()
        .filter_map(|&(part, material)| {
            let indices = match part {
                Part::Mesher { first, count } => &mesh.indices[first..first + count],
                Part::Sorted { first, count } => &sorted[first..first + count],
            };
            (!indices.is_empty()).then(|| {
                let accessor = doc.indices(indices, count);
                json!({
                    "attributes": { "POSITION": position, "NORMAL": normal, "TEXCOORD_0": uv },
                    "indices": accessor,
                    "material": material,
                    "mode": TRIANGLES,
                })
            })
        })
        .collect();
    doc.meshes
        .push(json!({ "name": name, "primitives": primitives }));
    Some(doc.meshes.len() - 1)
}

#[cfg(test)]
#[path = "frame_glb_tests.rs"]
mod tests;
