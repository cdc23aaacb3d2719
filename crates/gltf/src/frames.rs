//! What every frame encoder shares: the error type, the pair of meshers a
//! frame sequence is meshed with ([`FrameMeshes`]), and the blended looks
//! of leaves and bark between their two materials.
//!
//! # Reference radii and bark UVs
//! Tube side counts are fixed per strand from the *reference radii* (see
//! [`crate::mesh`]): for a sequence, pass **the per-node maximum radius over
//! all frames** ([`max_radii`]), so a chain that grows later is meshed with
//! the sides its final girth needs rather than as a twig. Bark texture
//! coordinates are fixed by the **first frame meshed** (or the frame given
//! to [`FrameMeshes::set_uv_frame`]) and reused for every later frame, so
//! the bark sticks to the branches as they move.

use std::collections::HashMap;

use rayon::prelude::*;

use thiserror::Error;
use treemorph_api::delta::DeltaError;
use treemorph_tree::frame::FrameMismatch;
use treemorph_tree::{Bark, Frame, FrameTopology, LeafMaterial, RgbaImage, Texture};

use crate::contour::{BlendLayers, BlendSource, LeafContour, blend_textures};
use crate::mesh::{BranchMesher, LeafMesher, LeafShape, MeshBuffers, MeshError, MeshOptions};

/// Why a frame encoder could not be built or could not encode a frame.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum EncodeError {
    /// The options are out of range (the caller's mistake).
    #[error("invalid options: {0}")]
    InvalidOptions(String),
    /// The topology is inconsistent (the caller's mistake): a strand or a
    /// leaf names a node or material that does not exist.
    #[error("invalid frame topology: {0}")]
    Topology(String),
    /// A frame does not fit the topology (the caller's mistake).
    #[error(transparent)]
    Frame(#[from] FrameMismatch),
    /// The output would exceed a format limit (4 GiB GLB, `u32` counts).
    #[error("too large: {0}")]
    TooLarge(String),
    /// The delta codec refused the stream (positions outside the grid the
    /// bounds allow are the caller's mistake; anything else is a bug).
    #[error("delta stream: {0}")]
    Stream(#[from] DeltaError),
    /// A call out of order (e.g. finishing an animation without keyframes).
    #[error("{0}")]
    Usage(String),
    /// Writing the output failed.
    #[error("writing the output failed: {0}")]
    Io(String),
    /// A bug.
    #[error("internal error: {0}")]
    Internal(String),
}

impl From<MeshError> for EncodeError {
    fn from(e: MeshError) -> EncodeError {
        match e {
            MeshError::InvalidOptions(m) => EncodeError::InvalidOptions(m),
            MeshError::Frame(m) => EncodeError::Frame(m),
            e @ MeshError::TooLarge { .. } => EncodeError::TooLarge(e.to_string()),
            e @ (MeshError::StrandNodeOutOfRange { .. }
            | MeshError::LeafMaterialOutOfRange { .. }) => EncodeError::Topology(e.to_string()),
        }
    }
}

/// The per-node maximum radius over a sequence: the reference radii to
/// pass to the encoders. Frames that do not fit the first one's node count
/// are skipped (the encoders refuse them later).
pub fn max_radii<'a>(frames: impl IntoIterator<Item = &'a Frame>) -> Vec<f32> {
    let mut out: Vec<f32> = Vec::new();
    for frame in frames {
        if out.is_empty() {
            out = vec![0.0; frame.radii.len()];
        }
        if frame.radii.len() == out.len() {
            for (o, &r) in out.iter_mut().zip(&frame.radii) {
                if r.is_finite() {
                    *o = o.max(r);
                }
            }
        }
    }
    out
}

/// The branch and leaf meshers of one frame sequence, meshing both halves
/// of a frame in parallel.
#[derive(Clone, Debug)]
pub struct FrameMeshes {
    branches: BranchMesher,
    leaves: LeafMesher,
    options: MeshOptions,
    uvs_set: bool,
}

impl FrameMeshes {
    /// Plans the meshes of `topology` (see the [module docs](self) for
    /// `reference_radii`).
    pub fn new(
        topology: &FrameTopology,
        reference_radii: &[f32],
        options: &MeshOptions,
    ) -> Result<FrameMeshes, EncodeError> {
        let n = topology.node_count();
        if reference_radii.len() != n {
            return Err(FrameMismatch(format!(
                "{} reference radii for {n} nodes",
                reference_radii.len()
            ))
            .into());
        }
        // Bark UVs come from the first real frame; until then a frame of
        // the right size stands in.
        let placeholder = Frame {
            t: 0.0,
            positions: vec![glam::Vec3::ZERO; n],
            radii: reference_radii
                .iter()
                .map(|&r| if r.is_finite() { r.max(0.0) } else { 0.0 })
                .collect(),
            leaves: Vec::new(),
            bark_blend: 0.0,
        };
        let branches = BranchMesher::new(topology, reference_radii, &placeholder, options)?;
        let leaves = LeafMesher::new(topology, options)?;
        Ok(FrameMeshes {
            branches,
            leaves,
            options: options.clone(),
            uvs_set: false,
        })
    }

    /// Fixes the bark texture coordinates from `frame` (otherwise the first
    /// frame meshed fixes them).
    pub fn set_uv_frame(&mut self, frame: &Frame) -> Result<(), EncodeError> {
        self.branches.set_uv_frame(frame, &self.options)?;
        self.uvs_set = true;
        Ok(())
    }

    /// Meshes a frame: branches and leaves in parallel.
    pub fn mesh(&mut self, frame: &Frame) -> Result<(&MeshBuffers, &MeshBuffers), EncodeError> {
        if !self.uvs_set {
            self.set_uv_frame(frame)?;
        }
        let (branches, leaves) = (&mut self.branches, &mut self.leaves);
        let (b, l) = rayon::join(|| branches.mesh(frame), || leaves.mesh(frame));
        Ok((b?, l?))
    }

    /// The branch mesher.
    pub fn branches(&self) -> &BranchMesher {
        &self.branches
    }

    /// The leaf mesher.
    pub fn leaves(&self) -> &LeafMesher {
        &self.leaves
    }

    /// The mesh options.
    pub fn options(&self) -> &MeshOptions {
        &self.options
    }
}

/// Checks a frame against its topology, and its time.
pub(crate) fn check_frame(
    frame: &Frame,
    topology_nodes: usize,
    leaves: usize,
) -> Result<(), EncodeError> {
    if frame.positions.len() != topology_nodes || frame.leaves.len() != leaves {
        return Err(FrameMismatch(format!(
            "{} positions and {} leaves for {topology_nodes} nodes and {leaves} leaves",
            frame.positions.len(),
            frame.leaves.len()
        ))
        .into());
    }
    if !(0.0..=1.0).contains(&frame.t) {
        return Err(FrameMismatch(format!("t = {} is outside [0, 1]", frame.t)).into());
    }
    if !(0.0..=1.0).contains(&frame.bark_blend) {
        return Err(
            FrameMismatch(format!("bark blend {} is outside [0, 1]", frame.bark_blend)).into(),
        );
    }
    if let Some(i) = frame
        .leaves
        .iter()
        .position(|l| !(0.0..=1.0).contains(&l.blend))
    {
        return Err(FrameMismatch(format!("leaf {i} has a blend outside [0, 1]")).into());
    }
    Ok(())
}

/// How a surface looks: a material's name, colour factor and texture.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Look {
    pub(crate) name: String,
    pub(crate) color: [f32; 4],
    pub(crate) texture: Option<Texture>,
}

/// Leaf and bark looks between a sequence's two materials, blended
/// texel-wise ([`blend_textures`]) at quantised blends and cached, so a
/// sequence blends each (pair, step) once.
pub(crate) struct Looks {
    materials: Vec<LeafMaterial>,
    bark: [Bark; 2],
    contours: Vec<LeafContour>,
    images: Vec<Option<RgbaImage>>,
    bark_images: [Option<RgbaImage>; 2],
    rectangle: LeafContour,
    steps: u32,
    leaf_cache: HashMap<(u32, u32, u32), Look>,
    bark_cache: HashMap<u32, Look>,
}

impl Looks {
    /// `contours` are the leaf mesher's (empty for quads: the textures then
    /// map rectangle to rectangle). `steps` quantises blends.
    pub(crate) fn new(topology: &FrameTopology, leaves: &LeafMesher, steps: u32) -> Looks {
        let rectangle = LeafContour::rectangle(4).expect("4 is a valid point count");
        let contours = match leaves.shape() {
            LeafShape::Quad => vec![rectangle.clone(); topology.leaf_materials.len()],
            _ => leaves.contours().to_vec(),
        };
        let decode = |t: &Option<Texture>| t.as_ref().and_then(|t| t.decode().ok());
        Looks {
            images: topology
                .leaf_materials
                .iter()
                .map(|m| decode(&m.texture))
                .collect(),
            bark_images: [
                decode(&topology.bark[0].texture),
                decode(&topology.bark[1].texture),
            ],
            materials: topology.leaf_materials.clone(),
            bark: topology.bark.clone(),
            contours,
            rectangle,
            steps: steps.max(1),
            leaf_cache: HashMap::new(),
            bark_cache: HashMap::new(),
        }
    }

    /// The quantisation step of a blend: `round(blend · steps)`.
    pub(crate) fn step(&self, blend: f32) -> u32 {
        let b = if blend.is_finite() {
            blend.clamp(0.0, 1.0)
        } else {
            0.0
        };
        (b * self.steps as f32).round() as u32
    }

    pub(crate) fn steps(&self) -> u32 {
        self.steps
    }

    /// Leaf material `m` as it is.
    pub(crate) fn leaf(&self, m: u32) -> Look {
        let material = &self.materials[m as usize];
        Look {
            name: material.name.clone(),
            color: material.color,
            texture: material.texture.clone(),
        }
    }

    /// The cache key of a leaf blending `a → b` at step `q`.
    fn leaf_key(&self, a: u32, b: u32, q: u32) -> (u32, u32, u32) {
        if a == b {
            (a, a, 0)
        } else {
            (a, b, q.min(self.steps))
        }
    }

    /// The cache key of the bark at step `q`.
    fn bark_key(&self, q: u32) -> u32 {
        if self.bark[0] == self.bark[1] {
            0
        } else {
            q.min(self.steps)
        }
    }

    /// Computes the looks of the leaf `keys` (`[a, b, q]`, as
    /// [`Looks::leaf_blend`] takes them) and of the bark at `bark_step`
    /// that are not cached yet, in parallel. A writer made for one frame
    /// (an instant rendered on request) needs a few dozen at once, most of
    /// them one pair of materials at many steps: each pair's textures are
    /// sampled once ([`BlendLayers`]), then each look mixes the layers and
    /// encodes a PNG. The looks are the same whichever order they are
    /// computed in, and the same as one at a time.
    pub(crate) fn prepare(&mut self, bark_step: u32, keys: &[[u32; 3]]) {
        let mut leaves: Vec<(u32, u32, u32)> = keys
            .iter()
            .map(|&[a, b, q]| self.leaf_key(a, b, q))
            .filter(|k| !self.leaf_cache.contains_key(k))
            .collect();
        leaves.sort_unstable();
        leaves.dedup();
        let bark = Some(self.bark_key(bark_step)).filter(|q| !self.bark_cache.contains_key(q));
        let mut pairs: Vec<(u32, u32)> = leaves
            .iter()
            .filter(|k| k.2 != 0)
            .map(|k| (k.0, k.1))
            .collect();
        pairs.dedup();
        let this = &*self;
        let (bark_look, leaf_looks) = rayon::join(
            || bark.map(|q| this.bark_look(q)),
            || {
                let layers: HashMap<(u32, u32), Option<BlendLayers>> = pairs
                    .par_iter()
                    .map(|&(a, b)| ((a, b), this.leaf_layers(a, b)))
                    .collect();
                leaves
                    .par_iter()
                    .map(|&k| {
                        let pair = layers.get(&(k.0, k.1)).and_then(Option::as_ref);
                        this.leaf_look_with(k, pair)
                    })
                    .collect::<Vec<Look>>()
            },
        );
        if let (Some(q), Some(look)) = (bark, bark_look) {
            self.bark_cache.insert(q, look);
        }
        self.leaf_cache.extend(leaves.into_iter().zip(leaf_looks));
    }

    /// How many leaf and bark looks are cached.
    #[cfg(test)]
    pub(crate) fn cached(&self) -> (usize, usize) {
        (self.leaf_cache.len(), self.bark_cache.len())
    }

    /// The look of a leaf blending materials `a → b` at step `q`, in the
    /// texture space of `a`'s contour: `a` itself at step 0 or when
    /// `a == b`.
    pub(crate) fn leaf_blend(&mut self, a: u32, b: u32, q: u32) -> &Look {
        let key = self.leaf_key(a, b, q);
        if !self.leaf_cache.contains_key(&key) {
            let look = self.leaf_look(key);
            self.leaf_cache.insert(key, look);
        }
        &self.leaf_cache[&key]
    }

    /// The look of leaf key `(a, b, q)` ([`Looks::leaf_key`]), computed.
    fn leaf_look(&self, key: (u32, u32, u32)) -> Look {
        let layers = (key.2 != 0)
            .then(|| self.leaf_layers(key.0, key.1))
            .flatten();
        self.leaf_look_with(key, layers.as_ref())
    }

    /// The blend layers of materials `a → b`, in the texture space of
    /// `a`'s contour; `None` when neither has a texture (their blends are
    /// plain colours).
    fn leaf_layers(&self, a: u32, b: u32) -> Option<BlendLayers> {
        let (ia, ib) = (&self.images[a as usize], &self.images[b as usize]);
        if ia.is_none() && ib.is_none() {
            return None;
        }
        let (ma, mb) = (&self.materials[a as usize], &self.materials[b as usize]);
        Some(BlendLayers::new(
            BlendSource {
                image: ia.as_ref(),
                contour: &self.contours[a as usize],
                color: ma.color,
            },
            BlendSource {
                image: ib.as_ref(),
                contour: &self.contours[b as usize],
                color: mb.color,
            },
        ))
    }

    /// The look of leaf key `(a, b, q)` from its pair's `layers`
    /// ([`Looks::leaf_layers`]).
    fn leaf_look_with(&self, (a, b, q): (u32, u32, u32), layers: Option<&BlendLayers>) -> Look {
        if q == 0 {
            return self.leaf(a);
        }
        let s = q as f32 / self.steps as f32;
        let (ma, mb) = (&self.materials[a as usize], &self.materials[b as usize]);
        let name = format!("{}→{}@{:.3}", ma.name, mb.name, s);
        let Some(layers) = layers else {
            return Look {
                name,
                color: lerp4(ma.color, mb.color, s),
                texture: None,
            };
        };
        Look {
            name,
            color: [1.0; 4],
            texture: Some(Texture::from_rgba(&layers.blend(s))),
        }
    }

    /// The bark at step `q` between the two barks.
    pub(crate) fn bark(&mut self, q: u32) -> &Look {
        let q = self.bark_key(q);
        if !self.bark_cache.contains_key(&q) {
            let look = self.bark_look(q);
            self.bark_cache.insert(q, look);
        }
        &self.bark_cache[&q]
    }

    /// The bark at key `q` ([`Looks::bark_key`]), computed.
    fn bark_look(&self, q: u32) -> Look {
        let s = q as f32 / self.steps as f32;
        let [b0, b1] = &self.bark;
        if q == 0 || q == self.steps {
            let b = if q == 0 { b0 } else { b1 };
            return Look {
                name: "bark".into(),
                color: b.color,
                texture: b.texture.clone(),
            };
        }
        if b0.texture.is_none() && b1.texture.is_none() {
            return Look {
                name: "bark".into(),
                color: lerp4(b0.color, b1.color, s),
                texture: None,
            };
        }
        let image = blend_textures(
            BlendSource {
                image: self.bark_images[0].as_ref(),
                contour: &self.rectangle,
                color: b0.color,
            },
            BlendSource {
                image: self.bark_images[1].as_ref(),
                contour: &self.rectangle,
                color: b1.color,
            },
            s,
        );
        Look {
            name: "bark".into(),
            color: [1.0; 4],
            texture: Some(Texture::from_rgba(&image)),
        }
    }
}

fn lerp4(a: [f32; 4], b: [f32; 4], s: f32) -> [f32; 4] {
    [0, 1, 2, 3].map(|k| a[k] + (b[k] - a[k]) * s)
}

#[cfg(test)]
#[path = "frames_tests.rs"]
mod tests;
