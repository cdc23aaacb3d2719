//! The binary delta stream of a frame sequence: [`DeltaStreamWriter`].
//!
//! The writer meshes each frame with the same meshers as the GLB encoders
//! and feeds the positions to the delta codec of
//! [`treemorph_api::delta`] (format: `api/README.md`):
//!
//! - **Header** (written with the first frame, whose meshes are the base
//!   positions, or on its own from a given frame,
//!   [`DeltaStreamWriter::write_header`]): two meshes, `branches` then `leaves`, with their index
//!   buffers, UVs and material groups; the materials and PNG textures; the
//!   quantisation grid from the animation's bounds
//!   ([`Grid::for_bounds`], error at most
//!   [`StreamOptions::max_error_fraction`] of the bounds' height).
//! - **Material groups.** Branches: one group, material `bark`, fading to
//!   the second bark when the topology's two barks differ. Leaves: one
//!   group per material pair `a → b`; its material is leaf material `a`,
//!   and when `b ≠ a` it fades to a material whose texture is `b`'s
//!   texture warped onto `a`'s outline ([`crate::contour::blend_textures`]
//!   at blend 1), because a vertex has one UV — that of `a`'s contour — in
//!   every frame.
//! - **Frames** carry positions only (clients recompute normals) and one
//!   blend factor. The format has a single factor per frame, while a
//!   frame has one blend per leaf and a bark blend: the writer sends the
//!   **mean blend of the leaves whose two materials differ** (the bark
//!   blend when there are none). Each leaf's *shape* still morphs at its
//!   own pace: that is in the positions.
//!
//! # Defaults: a live preview
//! The stream is what the web viewer plays while a job runs, so its
//! defaults favour encoding speed over fidelity: leaves are quads (their
//! outlines still change through the texture cross-fade; pass
//! [`LeafShape::Contour`](crate::mesh::LeafShape::Contour) to morph them geometrically, at 3–6× the leaf
//! vertices), the thinnest twigs get 3 sides and the thickest 10, and
//! records are stored without zstd. At 20,000 chains the codec is then
//! bound by memory bandwidth (it reads each position and the decoder's
//! integer state once), and zstd level 1 — a third of the bytes — costs
//! more than the rest of the encoding: enable it with
//! [`StreamOptions::encoder`] when bandwidth matters more than latency,
//! or compress the HTTP response instead, which runs beside the encoder
//! rather than in its way. Frames are a few hundred kilobytes either way,
//! under 1 % of the same frame as a GLB.

use treemorph_api::delta::{
    AlphaMode, Compression, Encoder, EncoderOptions, Grid, Material, MaterialGroup, Mesh,
    StreamHeader, Texture,
};
use treemorph_tree::{Aabb, Frame, FrameTopology};

use crate::frames::{EncodeError, FrameMeshes, Look, Looks, check_frame};
use crate::mesh::{MeshBuffers, MeshOptions};

/// Options of [`DeltaStreamWriter`].
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct StreamOptions {
    /// Tube sides and leaf shape (default: quads, 3 to 10 sides).
    pub mesh: MeshOptions,
    /// Largest quantisation error as a fraction of the bounds' height
    /// (default 0.001, i.e. 0.1 %).
    pub max_error_fraction: f32,
    /// Frames the stream will carry, announced in the header (default 0:
    /// unknown; the end record always carries the actual count).
    pub frame_count: u32,
    /// Codec settings (default: records stored without zstd; see the
    /// [module docs](self)).
    pub encoder: EncoderOptions,
}

impl Default for StreamOptions {
    fn default() -> StreamOptions {
        StreamOptions {
            mesh: MeshOptions::default().with_sides(3, 10),
            max_error_fraction: 0.001,
            frame_count: 0,
            encoder: EncoderOptions::with_compression(Compression::None),
        }
    }
}

impl StreamOptions {
    /// These options with [`StreamOptions::mesh`] set.
    #[must_use]
    pub fn with_mesh(mut self, mesh: MeshOptions) -> StreamOptions {
        self.mesh = mesh;
        self
    }

    /// These options with [`StreamOptions::frame_count`] set.
    #[must_use]
    pub fn with_frame_count(mut self, frames: u32) -> StreamOptions {
        self.frame_count = frames;
        self
    }

    /// These options with [`StreamOptions::encoder`] set.
    #[must_use]
    pub fn with_encoder(mut self, encoder: EncoderOptions) -> StreamOptions {
        self.encoder = encoder;
        self
    }
}

/// Encodes a frame sequence as a delta stream, frame by frame.
///
/// ```
/// use treemorph_gltf::stream::{DeltaStreamWriter, StreamOptions};
/// use treemorph_tree::{Aabb, Frame, FrameTopology};
/// # let tree = treemorph_gltf::sample::sample_tree(20);
/// let topology = FrameTopology::of_tree(&tree);
/// let frame = Frame::of_tree(&tree);
/// let bounds = Aabb::of_points(frame.positions.iter().copied()).inflated(1.0);
/// let mut writer = DeltaStreamWriter::new(&topology, &frame.radii, bounds, &StreamOptions::default())?;
/// let mut stream = Vec::new();
/// writer.write_frame(&frame, &mut stream)?; // the header, then frame 0
/// writer.finish(&mut stream)?;
/// let options = treemorph_api::delta::DecoderOptions::default();
/// let (header, frames) = treemorph_api::delta::decode_all(&stream, &options)?;
/// assert_eq!(frames.len(), 1);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub struct DeltaStreamWriter {
    meshes: FrameMeshes,
    looks: Looks,
    topology: FrameTopology,
    bounds: [[f32; 3]; 2],
    options: StreamOptions,
    encoder: Option<Encoder>,
    /// Leaves whose two materials differ (their mean blend is sent).
    fading: Vec<u32>,
}

impl DeltaStreamWriter {
    /// Plans the meshes of `topology`. `bounds` should hold every frame of
    /// the animation (e.g. the union of the source and target trees'
    /// bounds): the grid's step is chosen from its height, and positions
    /// far outside it (beyond ±2²⁴ grid steps) are refused. Pass the
    /// per-node maximum radius over the sequence as `reference_radii`
    /// ([`crate::frames::max_radii`]).
    pub fn new(
        topology: &FrameTopology,
        reference_radii: &[f32],
        bounds: Aabb,
        options: &StreamOptions,
    ) -> Result<DeltaStreamWriter, EncodeError> {
        if !(options.max_error_fraction.is_finite() && options.max_error_fraction > 0.0) {
            return Err(EncodeError::InvalidOptions(format!(
                "max_error_fraction must be positive; got {}",
                options.max_error_fraction
            )));
        }
        if bounds.is_empty() || !(bounds.min.is_finite() && bounds.max.is_finite()) {
            return Err(EncodeError::InvalidOptions(format!(
                "bounds {bounds:?} are empty or not finite"
            )));
        }
        let meshes = FrameMeshes::new(topology, reference_radii, &options.mesh)?;
        // Leaf blends need no quantisation here: only blend 1 is baked.
        let looks = Looks::new(topology, meshes.leaves(), 1);
        let fading = topology
            .leaves
            .iter()
            .enumerate()
            .filter(|(_, l)| l.materials[0] != l.materials[1])
            .map(|(i, _)| i as u32)
            .collect();
        Ok(DeltaStreamWriter {
            meshes,
            looks,
            topology: topology.clone(),
            bounds: [bounds.min.to_array(), bounds.max.to_array()],
            options: options.clone(),
            encoder: None,
            fading,
        })
    }

    /// The header as clients decode it (base positions snapped to the
    /// grid), once the first frame was written.
    pub fn header(&self) -> Option<&StreamHeader> {
        self.encoder.as_ref().map(Encoder::header)
    }

    /// The encoded header (the stream's first bytes, which
    /// [`DeltaStreamWriter::write_frame`] puts before the first frame's
    /// record), once the first frame was written.
    pub fn header_bytes(&self) -> Option<&[u8]> {
        self.encoder.as_ref().map(Encoder::header_bytes)
    }

    /// Writes the stream's preamble and header to `out` with `frame`'s
    /// meshes as the base positions (they also fix the bark UVs), and no
    /// frame record: the next frame written is frame 0, encoded against
    /// `frame`. A sequence's own stream has its first frame as the base,
    /// so a stream of one later instant based on that first frame has the
    /// sequence's header but for the frame count, and its frame record
    /// decodes against the sequence's header. Errors:
    /// [`EncodeError::Usage`] once a header was written.
    pub fn write_header(&mut self, frame: &Frame, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        if self.encoder.is_some() {
            return Err(EncodeError::Usage(
                "a delta stream has one header, and it is written".into(),
            ));
        }
        check_frame(
            frame,
            self.topology.node_count(),
            self.topology.leaves.len(),
        )?;
        let (branches, leaves) = self.meshes.mesh(frame)?;
        let encoder = start(
            &mut self.looks,
            &self.topology,
            (self.bounds, &self.options),
            (branches, leaves),
            out,
        )?;
        self.encoder = Some(encoder);
        Ok(())
    }

    /// Starts the same stream again ([`Encoder::restart`]): appends the
    /// header written first to `out` again, and the next frame is encoded
    /// against it, as after [`write_header`](Self::write_header). Its
    /// meshes, textures and compression are not made again: a renderer of
    /// one-frame streams of one animation (the service's `stream?t=`) keeps
    /// one writer. Errors: [`EncodeError::Usage`] before a header.
    pub fn restart(&mut self, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let encoder = self
            .encoder
            .as_mut()
            .ok_or_else(|| EncodeError::Usage("a delta stream restarts after its header".into()))?;
        encoder.restart();
        out.extend_from_slice(encoder.header_bytes());
        Ok(())
    }

    /// The meshers.
    pub fn meshes(&self) -> &FrameMeshes {
        &self.meshes
    }

    /// Appends the next frame's record to `out`; for the first frame the
    /// stream's preamble and header come first (its meshes are the base
    /// positions and fix the bark UVs).
    pub fn write_frame(&mut self, frame: &Frame, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        check_frame(
            frame,
            self.topology.node_count(),
            self.topology.leaves.len(),
        )?;
        let blend = if self.fading.is_empty() {
            frame.bark_blend
        } else {
            let sum: f64 = self
                .fading
                .iter()
                .map(|&i| f64::from(frame.leaves[i as usize].blend))
                .sum();
            ((sum / self.fading.len() as f64) as f32).clamp(0.0, 1.0)
        };
        let (branches, leaves) = self.meshes.mesh(frame)?;
        let encoder = match &mut self.encoder {
            Some(e) => e,
            None => {
                let encoder = start(
                    &mut self.looks,
                    &self.topology,
                    (self.bounds, &self.options),
                    (branches, leaves),
                    out,
                )?;
                self.encoder.insert(encoder)
            }
        };
        let index = encoder.next_index();
        encoder.encode_frame_of(
            index,
            frame.t,
            &[&branches.positions, &leaves.positions],
            blend,
            out,
        )?;
        Ok(())
    }

    /// Appends the end record. Errors: [`EncodeError::Usage`] when no frame
    /// was written (the stream has no header yet), and the codec's errors
    /// (e.g. a frame count announced in the options but not reached).
    pub fn finish(&mut self, out: &mut Vec<u8>) -> Result<(), EncodeError> {
        let encoder = self.encoder.as_mut().ok_or_else(|| {
            EncodeError::Usage("a delta stream needs at least one frame before it ends".into())
        })?;
        encoder.finish(out)?;
        Ok(())
    }
}

/// Makes the encoder for the base meshes and writes the stream's first
/// bytes (preamble and header) to `out`.
fn start(
    looks: &mut Looks,
    topology: &FrameTopology,
    (bounds, options): ([[f32; 3]; 2], &StreamOptions),
    (branches, leaves): (&MeshBuffers, &MeshBuffers),
    out: &mut Vec<u8>,
) -> Result<Encoder, EncodeError> {
    prepare_blends(looks, leaves);
    let header = header_for(looks, topology, bounds, options, branches, leaves);
    let encoder = Encoder::new(header, &options.encoder)?;
    out.extend_from_slice(encoder.header_bytes());
    Ok(encoder)
}

/// Computes the blended leaf textures the header carries (each fading
/// group's look at blend 1) in parallel, before [`header_for`] reads them
/// one by one: a morph between trees with textured leaves needs several,
/// each a texture sampled and encoded, and made one after the other they
/// took about 20 ms of the default job's first frame.
fn prepare_blends(looks: &mut Looks, leaves: &MeshBuffers) {
    let keys: Vec<[u32; 3]> = leaves
        .groups
        .iter()
        .filter(|g| g.materials[0] != g.materials[1])
        .map(|g| [g.materials[0], g.materials[1], 1])
        .collect();
    looks.prepare(0, &keys);
}

/// The stream header for the first frame's meshes.
fn header_for(
    looks: &mut Looks,
    topology: &FrameTopology,
    bounds: [[f32; 3]; 2],
    options: &StreamOptions,
    branches: &MeshBuffers,
    leaves: &MeshBuffers,
) -> StreamHeader {
    {
        let mut textures: Vec<Texture> = Vec::new();
        let mut materials: Vec<Material> = Vec::new();
        let mut add = |look: &Look, leaf: bool| -> u32 {
            let texture = look.texture.as_ref().map(|t| {
                // Textures are shared between materials by their bytes.
                match textures.iter().position(|x| x.png == t.png()) {
                    Some(i) => i as u32,
                    None => {
                        textures.push(Texture {
                            png: t.png().to_vec(),
                        });
                        textures.len() as u32 - 1
                    }
                }
            });
            materials.push(Material {
                name: look.name.clone(),
                base_color: crate::doc::color(look.color),
                alpha_mode: if leaf {
                    AlphaMode::Mask { cutoff: 0.5 }
                } else {
                    AlphaMode::Opaque
                },
                double_sided: leaf,
                texture,
            });
            materials.len() as u32 - 1
        };
        let bark0 = add(&looks.bark(0).clone(), false);
        let bark_fade =
            (topology.bark[0] != topology.bark[1]).then(|| add(&looks.bark(1).clone(), false));
        let mut leaf_groups = Vec::with_capacity(leaves.groups.len());
        let mut originals: Vec<Option<u32>> = vec![None; topology.leaf_materials.len()];
        for g in &leaves.groups {
            let [a, b] = g.materials;
            let material = match originals[a as usize] {
                Some(m) => m,
                None => {
                    let m = add(&looks.leaf(a), true);
                    originals[a as usize] = Some(m);
                    m
                }
            };
            let fade_to = (a != b).then(|| add(&looks.leaf_blend(a, b, 1).clone(), true));
            leaf_groups.push(MaterialGroup {
                first: g.first_index,
                count: g.index_count,
                material,
                fade_to,
            });
        }
        let mesh = |name: &str, m: &MeshBuffers, groups: Vec<MaterialGroup>| Mesh {
            name: name.into(),
            indices: m.indices.clone(),
            uvs: m.uvs.iter().map(|uv| uv.to_array()).collect(),
            groups,
            base_positions: m.positions.iter().map(|p| p.to_array()).collect(),
        };
        let branch_groups = branches
            .groups
            .iter()
            .map(|g| MaterialGroup {
                first: g.first_index,
                count: g.index_count,
                material: bark0,
                fade_to: bark_fade,
            })
            .collect();
        StreamHeader {
            bounds,
            grid: Grid::for_bounds(bounds, options.max_error_fraction),
            frame_count: options.frame_count,
            textures,
            materials,
            meshes: vec![
                mesh("branches", branches, branch_groups),
                mesh("leaves", leaves, leaf_groups),
            ],
        }
    }
}

#[cfg(test)]
#[path = "stream_tests.rs"]
mod tests;
