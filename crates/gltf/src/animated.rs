//! One animated GLB for a whole frame sequence: [`AnimatedGlbBuilder`].
//!
//! The file holds one scene with the nodes `branches` and `leaves`, each
//! with one mesh in the union topology whose **morph targets are the
//! keyframes**, and one animation that plays them, so any glTF viewer
//! (three.js, Blender, Babylon.js) plays the morph without code of ours:
//!
//! - The **base mesh** is keyframe 0; **target `k`** (k = 1…K−1) holds
//!   keyframe `k` minus the base, for POSITION and NORMAL.
//! - The animation has one sampler (LINEAR) on the `weights` of both
//!   nodes: at keyframe time `t_k` the weights are the unit vector of
//!   target `k` (all zero at `t_0`), so between keyframes `k` and `k+1`
//!   exactly those two targets blend and the mesh moves linearly from one
//!   keyframe to the next. Keyframe times are the frames' `t` times
//!   [`AnimatedOptions::duration`] seconds. (The quantised encodings add a
//!   target for keyframe 0; see below.)
//!
//! # Leaf materials without popping
//! A leaf whose two materials differ is drawn in **two layers** — one
//! primitive with its first material's texture, one with its second's —
//! that share the leaf's interpolated contour (each layer with its own
//! material's contour as UVs, so each texture is warped onto the current
//! outline). At every keyframe exactly one layer shows: layer 2 once the
//! leaf's blend reaches the leaf's own threshold `h ∈ (0, 1)` (a hash of
//! the leaf index, so thresholds are spread evenly over the leaves), layer
//! 1 before. The hidden layer is collapsed to a point: layer 1 onto the
//! leaf's tip, layer 2 onto its base. Across the keyframe interval where a
//! leaf swaps, the new layer grows out of the base while the old one
//! shrinks into the tip; because the base is the outline's lowest point
//! and the tip its highest (see [`crate::contour`]), the two never overlap
//! (no z-fighting). So the crown's texture change is a dissolve at leaf
//! granularity, staggered over the blend ramp, with positions only: it
//! plays in every viewer that plays morph targets (Blender's shape keys
//! included), with no vertex-colour or material animation. Leaves whose
//! materials are the same have one layer.
//!
//! The **bark** is one material: the two barks blended at the mean bark
//! blend of the keyframes (core glTF cannot animate a material).
//!
//! # Encodings ([`AnimatedEncoding`])
//! - [`Float`](AnimatedEncoding::Float) (default): 32-bit floats
//!   everywhere; plain glTF 2.0, validator-clean.
//! - [`Quantized`](AnimatedEncoding::Quantized) (`KHR_mesh_quantization`,
//!   required): positions and position targets as normalised `i16`
//!   (stride 8) on a uniform grid over [`AnimatedGlbBuilder::new`]'s
//!   bounds — the bounds map to ±16,383 so every target delta fits `i16`;
//!   the node's translation and scale undo the quantisation — and normals
//!   as normalised `i8` (stride 4). A normal *difference* `n_k − n_0` can
//!   reach 2 per component, beyond any normalised type, and scaling it
//!   down cannot reach normals turned by more than 90° from an axis-aligned
//!   base. So normal targets store **absolute** normals: target 0 is
//!   keyframe 0 (no displacement — an accessor without a buffer view —
//!   and the base's normal accessor), target `k` is keyframe `k`, and
//!   from keyframe 1 on the animation keeps target 0's weight at −1, so the
//!   morphed normal is `n_0 − n_0 + n_k` (positions are unaffected: target
//!   0 moves nothing). Viewers renormalise the morphed normal, so linear
//!   interpolation between keyframes stays exact in direction. Texture
//!   coordinates stay `f32` (bark `v` runs far beyond 1).
//! - [`Meshopt`](AnimatedEncoding::Meshopt) (`EXT_meshopt_compression`
//!   and `KHR_mesh_quantization`, both required): the quantised data with
//!   every vertex and index buffer view compressed by meshoptimizer
//!   (attribute codec version 0, triangle index codec) into the GLB's
//!   buffer; the views' plain layout lives in a data-less fallback buffer
//!   marked `"fallback": true`, as the extension specifies.
//!
//!
//! Target 0 moves no vertex, so viewers that ignore morphed normals
//! (Blender imports targets as shape keys of positions) are unaffected by
//! its negative weight.
//!
//! # Size
//! Every keyframe stores every vertex. For a 20,000-chain tree with the
//! keyframes' default meshes ([`KEYFRAMES_MESH`]: 3–10 sides, 12-point
//! leaf contours) whose every leaf
//! changes material — so every leaf has two layers — that is 1.67 million
//! vertices, and a keyframe costs about 41 MB as floats, 21 MB quantised
//! and 7 MB with meshopt: 60 keyframes make 2.4 GB, 1.2 GB and 400 MB
//! (measured by [`crate::bench`]). Pick [`AnimatedOptions::keyframes`]
//! well below the frame count for long sequences, and prefer the meshopt
//! encoding for downloads.

use std::io::Write;

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use serde_json::{Map, Value, json};
use treemorph_tree::{Aabb, Frame, FrameTopology};

use crate::contour::LeafContour;
use crate::doc::{Data, Doc, MAX_U16_VERTICES, Wrap, asset};
use crate::frame_glb::material_json;
use crate::frames::{EncodeError, FrameMeshes, Looks, check_frame};
use crate::gl::{
    ARRAY_BUFFER, BYTE, ELEMENT_ARRAY_BUFFER, FLOAT, SHORT, TRIANGLES, UNSIGNED_BYTE, UNSIGNED_INT,
    UNSIGNED_SHORT,
};
use crate::mesh::{LeafShape, MeshBuffers, MeshOptions};

pub(crate) const KHR_MESH_QUANTIZATION: &str = "KHR_mesh_quantization";
pub(crate) const EXT_MESHOPT_COMPRESSION: &str = "EXT_meshopt_compression";
/// Quantised positions within the bounds stay within ±`HALF_RANGE`, so the
/// difference of two fits `i16`.
pub(crate) const HALF_RANGE: f32 = 16_383.0;

/// How vertex data is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum AnimatedEncoding {
    /// 32-bit floats, no extension.
    #[default]
    Float,
    /// `KHR_mesh_quantization`: `i16` positions, `i8` normals.
    Quantized,
    /// The quantised data compressed with `EXT_meshopt_compression`.
    Meshopt,
}

/// Options of the animated GLB.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct AnimatedOptions {
    /// Keyframes [`animated_glb`] picks from a sequence (default 24; at
    /// least 2; all frames when there are fewer). The builder takes
    /// whatever frames it is given.
    pub keyframes: usize,
    /// Length of the animation in seconds (default 4): keyframe times are
    /// the frames' `t` times this.
    pub duration: f32,
    /// Vertex storage (default [`AnimatedEncoding::Float`]).
    pub encoding: AnimatedEncoding,
    /// Tube sides and leaf shape (default: 3 to 10 sides and quad
    /// leaves, [`ANIMATED_MESH`]; [`KEYFRAMES_MESH`] for one target per
    /// keyframe).
    pub mesh: MeshOptions,
    /// Most joints of a skinned animation besides its still root (default
    /// [`DEFAULT_SKELETON_JOINTS`], for game engines; 0: one per chain).
    pub skeleton_joints: usize,
}

/// The joint cap of a skinned animation unless asked otherwise: a few
/// hundred bones is what engines play vegetation with.
pub const DEFAULT_SKELETON_JOINTS: usize = 256;

/// The meshes of a motion basis or a skinned animation unless asked
/// otherwise: 3 to 10 tube sides and quad leaves.
///
/// Every vertex is stored once per morph target (up to 17 of them in a
/// basis), and leaves are most of a tree's vertices: a 12-point contour
/// fan has 13 vertices to a quad's 4. The blade's alpha cuts out its
/// outline either way (leaf materials are alpha-masked). What the fan adds
/// is the outline's morph in the geometry between a leaf's two materials,
/// and these animations already change a leaf's texture in one swap at
/// its own time (the dissolve of [`crate::basis`]): with quads the outline
/// changes in that swap, while the leaf's size and proportions still
/// follow its blend. Quads halve the default morph's file
/// (`benches/animation.sh`): 22.4 → 13.6 MB with meshopt, 130.8 → 64.9 MB
/// as floats, and three.js's GPU estimate 223 → 129 MB.
pub const ANIMATED_MESH: MeshOptions = MeshOptions::DEFAULT.with_sides(3, 10);

/// The meshes of a keyframes animation unless asked otherwise: 3 to 10
/// tube sides and [`LeafShape::Contour`] leaves of 12 points, as per-frame
/// GLBs have: the keyframes output, kept for compatibility, stays as it
/// was.
pub const KEYFRAMES_MESH: MeshOptions = MeshOptions::DEFAULT
    .with_sides(3, 10)
    .with_leaf_shape(LeafShape::Contour { points: 12 });

impl Default for AnimatedOptions {
    fn default() -> AnimatedOptions {
        AnimatedOptions {
            keyframes: 24,
            duration: 4.0,
            encoding: AnimatedEncoding::Float,
            mesh: ANIMATED_MESH,
            skeleton_joints: DEFAULT_SKELETON_JOINTS,
        }
    }
}

impl AnimatedOptions {
    /// These options with [`AnimatedOptions::skeleton_joints`] set.
    #[must_use]
    pub fn with_skeleton_joints(mut self, joints: usize) -> AnimatedOptions {
        self.skeleton_joints = joints;
        self
    }

    /// These options with [`AnimatedOptions::keyframes`] set.
    #[must_use]
    pub fn with_keyframes(mut self, keyframes: usize) -> AnimatedOptions {
        self.keyframes = keyframes;
        self
    }

    /// These options with [`AnimatedOptions::duration`] set.
    #[must_use]
    pub fn with_duration(mut self, seconds: f32) -> AnimatedOptions {
        self.duration = seconds;
        self
    }

    /// These options with [`AnimatedOptions::encoding`] set.
    #[must_use]
    pub fn with_encoding(mut self, encoding: AnimatedEncoding) -> AnimatedOptions {
        self.encoding = encoding;
        self
    }

    /// These options with [`AnimatedOptions::mesh`] set.
    #[must_use]
    pub fn with_mesh(mut self, mesh: MeshOptions) -> AnimatedOptions {
        self.mesh = mesh;
        self
    }
}

/// `keyframes` frame indices spread evenly over `frames` frames, first and
/// last included (all of them when there are fewer frames).
pub fn keyframe_indices(frames: usize, keyframes: usize) -> Vec<usize> {
    if frames == 0 {
        return Vec::new();
    }
    let k = keyframes.clamp(2, frames.max(2)).min(frames);
    if k <= 1 {
        return vec![0];
    }
    let mut out: Vec<usize> = (0..k)
        .map(|i| ((i * (frames - 1)) as f64 / (k - 1) as f64).round() as usize)
        .collect();
    out.dedup();
    out
}

/// The animated GLB of a sequence: keyframes picked by
/// [`keyframe_indices`], bounds from every keyframe's meshes (for the
/// quantised encodings), reference radii as given (use
/// [`crate::frames::max_radii`]).
pub fn animated_glb(
    topology: &FrameTopology,
    reference_radii: &[f32],
    frames: &[Frame],
    options: &AnimatedOptions,
) -> Result<Vec<u8>, EncodeError> {
    let picks = keyframe_indices(frames.len(), options.keyframes);
    let bounds = if options.encoding == AnimatedEncoding::Float {
        Aabb::of_points([Vec3::ZERO])
    } else {
        let mut meshes = FrameMeshes::new(topology, reference_radii, &options.mesh)?;
        let mut bounds = Aabb::EMPTY;
        for &i in &picks {
            let (b, l) = meshes.mesh(&frames[i])?;
            bounds = bounds.union(b.bounds).union(l.bounds);
        }
        bounds
    };
    let mut builder = AnimatedGlbBuilder::new(topology, reference_radii, bounds, options)?;
    for &i in &picks {
        builder.push(&frames[i])?;
    }
    builder.finish()
}

/// Per-vertex data of one mesh at one keyframe, ready to write.
struct Stored {
    /// POSITION bytes (or meshopt-compressed bytes).
    positions: Vec<u8>,
    /// NORMAL bytes (or compressed).
    normals: Vec<u8>,
    /// Min and max of the POSITION accessor, in its component type.
    min: [f64; 3],
    max: [f64; 3],
}

/// One keyframe's data of both meshes.
struct Keyframe {
    time: f32,
    meshes: [Stored; 2],
}

/// A mesh's keyframe-0 data, kept to compute target differences.
struct Base {
    /// Float encoding: positions and normals; quantised: grid
    /// coordinates and `i8` normals.
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    q_positions: Vec<[i16; 3]>,
    q_normals: Vec<[i8; 3]>,
}

/// Builds the animated GLB of a sequence from its keyframes, one at a
/// time: each keyframe is meshed and stored in its final encoding when it
/// is pushed, so the builder holds no frames.
///
/// ```
/// use treemorph_gltf::animated::{AnimatedGlbBuilder, AnimatedOptions};
/// use treemorph_tree::{Aabb, Frame, FrameTopology};
/// # let tree = treemorph_gltf::sample::sample_tree(20);
/// let topology = FrameTopology::of_tree(&tree);
/// let mut frame = Frame::of_tree(&tree);
/// let bounds = Aabb::of_points(frame.positions.iter().copied()).inflated(1.0);
/// let mut builder = AnimatedGlbBuilder::new(&topology, &frame.radii, bounds, &AnimatedOptions::default())?;
/// builder.push(&frame)?;
/// frame.t = 1.0;
/// builder.push(&frame)?;
/// let glb = builder.finish()?;
/// assert_eq!(&glb[..4], b"glTF");
/// # Ok::<(), treemorph_gltf::frames::EncodeError>(())
/// ```
pub struct AnimatedGlbBuilder {
    meshes: FrameMeshes,
    looks: Looks,
    topology: FrameTopology,
    options: AnimatedOptions,
    /// Quantisation: world = translation + scale · (q / 32767).
    translation: Vec3,
    scale: f32,
    /// Leaves whose materials differ: each has a second layer, in order.
    fading: Vec<u32>,
    /// Per fading leaf: the blend at which it swaps layers.
    thresholds: Vec<f32>,
    /// Layered leaf vertices of the current keyframe.
    leaf_positions: Vec<Vec3>,
    leaf_normals: Vec<Vec3>,
    /// Keyframe 0 of each mesh.
    bases: Option<[Base; 2]>,
    /// Keyframe 0 as stored, and its bounds (float) for the accessors.
    stored_base: Option<[Stored; 2]>,
    base_bounds: [Aabb; 2],
    /// Keyframes 1… as stored targets.
    targets: Vec<Keyframe>,
    first_time: f32,
    bark_blends: f64,
}

impl AnimatedGlbBuilder {
    /// Plans the meshes of `topology`. `bounds` must hold every keyframe's
    /// vertices for the quantised encodings (positions up to twice as far
    /// from its centre still encode; farther ones are refused); the float
    /// encoding ignores it. Pass the per-node maximum radius over the
    /// sequence as `reference_radii` ([`crate::frames::max_radii`]).
    pub fn new(
        topology: &FrameTopology,
        reference_radii: &[f32],
        bounds: Aabb,
        options: &AnimatedOptions,
    ) -> Result<AnimatedGlbBuilder, EncodeError> {
        check_duration(options)?;
        if options.keyframes < 2 {
            return Err(EncodeError::InvalidOptions(format!(
                "an animation needs at least 2 keyframes; got {}",
                options.keyframes
            )));
        }
        let (translation, scale) = grid(bounds, options.encoding)?.unwrap_or((Vec3::ZERO, 1.0));
        let meshes = FrameMeshes::new(topology, reference_radii, &options.mesh)?;
        let looks = Looks::new(topology, meshes.leaves(), 64);
        let fading = fading_leaves(topology);
        let thresholds = fading.iter().map(|&i| threshold(i)).collect();
        Ok(AnimatedGlbBuilder {
            meshes,
            looks,
            topology: topology.clone(),
            options: options.clone(),
            translation,
            scale,
            fading,
            thresholds,
            leaf_positions: Vec::new(),
            leaf_normals: Vec::new(),
            bases: None,
            stored_base: None,
            base_bounds: [Aabb::EMPTY; 2],
            targets: Vec::new(),
            first_time: 0.0,
            bark_blends: 0.0,
        })
    }

    /// Keyframes pushed so far.
    pub fn keyframe_count(&self) -> usize {
        self.targets.len() + usize::from(self.bases.is_some())
    }

    /// Adds the next keyframe (its time `frame.t · duration` must be later
    /// than the previous keyframe's).
    pub fn push(&mut self, frame: &Frame) -> Result<(), EncodeError> {
        check_frame(
            frame,
            self.topology.node_count(),
            self.topology.leaves.len(),
        )?;
        let time = frame.t * self.options.duration;
        let last = self.targets.last().map_or(self.first_time, |k| k.time);
        if self.bases.is_some() && time <= last {
            return Err(EncodeError::Usage(format!(
                "keyframe times must increase: t = {} after a keyframe at {} s",
                frame.t, last
            )));
        }
        if self.keyframe_count() + 1 > 1024 {
            return Err(EncodeError::TooLarge(
                "at most 1,024 keyframes (morph targets) are supported".into(),
            ));
        }
        let shape = self.meshes.leaves().shape();
        let (branches, leaves) = self.meshes.mesh(frame)?;
        layer_leaves(
            leaves,
            &self.topology,
            shape,
            &self.fading,
            &self.thresholds,
            frame,
            &mut self.leaf_positions,
            &mut self.leaf_normals,
        );
        let branches = (branches.positions.as_slice(), branches.normals.as_slice());
        let leaves = (self.leaf_positions.as_slice(), self.leaf_normals.as_slice());
        let encoding = self.options.encoding;
        let (t, s) = (self.translation, self.scale);
        self.bark_blends += f64::from(frame.bark_blend);
        match &self.bases {
            None => {
                let bases = [
                    base(branches, encoding, t, s)?,
                    base(leaves, encoding, t, s)?,
                ];
                self.base_bounds = [bounds(branches.0), bounds(leaves.0)];
                self.stored_base = Some([
                    store_base(&bases[0], encoding),
                    store_base(&bases[1], encoding),
                ]);
                self.bases = Some(bases);
                self.first_time = time;
            }
            Some(bases) => {
                let (b, l) = rayon::join(
                    || target(&bases[0], branches, encoding, t, s),
                    || target(&bases[1], leaves, encoding, t, s),
                );
                self.targets.push(Keyframe {
                    time,
                    meshes: [b?, l?],
                });
            }
        }
        Ok(())
    }

    /// The GLB (at most 4 GiB). Errors: [`EncodeError::Usage`] with fewer
    /// than two keyframes.
    pub fn finish(self) -> Result<Vec<u8>, EncodeError> {
        let mut out = Vec::new();
        let (doc, root) = self.document()?;
        doc.write(root, &mut out).map_err(|total| {
            EncodeError::TooLarge(format!(
                "the animated GLB would be {total} bytes; a GLB holds at most 4 GiB"
            ))
        })?;
        Ok(out)
    }

    /// Streams the GLB to `w` without holding it in memory; returns its
    /// size in bytes.
    pub fn finish_to(self, w: &mut impl Write) -> Result<u64, EncodeError> {
        let (doc, root) = self.document()?;
        doc.write_to(root, w).map_err(|e| match e.kind() {
            std::io::ErrorKind::InvalidInput => EncodeError::TooLarge(e.to_string()),
            _ => EncodeError::Io(e.to_string()),
        })
    }

    fn document(mut self) -> Result<(Doc<'static>, Map<String, Value>), EncodeError> {
        let (Some(bases), Some(stored_base)) = (self.bases.take(), self.stored_base.take()) else {
            return Err(EncodeError::Usage(
                "an animation needs at least 2 keyframes; got none".into(),
            ));
        };
        if self.targets.is_empty() {
            return Err(EncodeError::Usage(
                "an animation needs at least 2 keyframes; got 1".into(),
            ));
        }
        let encoding = self.options.encoding;
        let layout = TargetLayout::new(encoding, self.targets.len() + 1);
        let mut w = Writer::new(encoding);
        self.write_materials(&mut w.doc, layout.keyframes);
        let inputs = self.mesh_inputs(bases, stored_base);
        let mut targets = std::mem::take(&mut self.targets);
        for (m, input) in inputs.into_iter().enumerate() {
            let node = self.write_mesh(&mut w, m, input, &mut targets, &layout);
            w.doc.nodes.push(node);
        }
        let times: Vec<f32> = std::iter::once(self.first_time)
            .chain(targets.iter().map(|k| k.time))
            .collect();
        write_animation(&mut w.doc, &times, &layout);
        let doc = w.into_doc();
        let mut root = Map::new();
        root.insert("asset".into(), asset());
        root.insert("scene".into(), json!(0));
        root.insert("scenes".into(), json!([{ "nodes": [0, 1] }]));
        Ok((doc, root))
    }

    /// Materials: bark (at the sequence's mean bark blend), then every leaf
    /// material.
    fn write_materials(&mut self, doc: &mut Doc<'static>, keyframes: usize) {
        let mean_bark = (self.bark_blends / keyframes as f64) as f32;
        let bark = self.looks.bark(self.looks.step(mean_bark)).clone();
        let mut looks = vec![bark];
        looks.extend((0..self.topology.leaf_materials.len() as u32).map(|m| self.looks.leaf(m)));
        for (i, look) in looks.iter().enumerate() {
            let leaf = i > 0;
            let wrap = if leaf { Wrap::Clamp } else { Wrap::Repeat };
            let texture = look
                .texture
                .as_ref()
                .map(|t| doc.texture(Data::Owned(t.png().to_vec()), &look.name, wrap));
            doc.materials.push(material_json(look, texture, leaf));
        }
    }

    /// The branch and leaf meshes' keyframe-0 data, UVs and primitives
    /// (index ranges and materials).
    fn mesh_inputs(&self, bases: [Base; 2], stored_base: [Stored; 2]) -> [MeshInput; 2] {
        let branch_buffers = self.meshes.branches().buffers();
        let leaf_buffers = self.meshes.leaves().buffers();
        let leaf_uvs = layered_uvs(
            leaf_buffers,
            &self.topology,
            self.meshes.leaves(),
            &self.fading,
        );
        let branch_primitives = vec![(branch_buffers.indices.clone(), 0usize)];
        let leaf_primitives =
            layered_primitives(leaf_buffers, self.meshes.leaves().shape(), &self.fading);
        let [branch_base, leaf_base] = stored_base;
        [
            MeshInput {
                name: "branches",
                vertices: bases[0].len(),
                base: branch_base,
                uvs: branch_buffers.uvs.clone(),
                primitives: branch_primitives,
            },
            MeshInput {
                name: "leaves",
                vertices: bases[1].len(),
                base: leaf_base,
                uvs: leaf_uvs,
                primitives: leaf_primitives,
            },
        ]
    }

    /// Writes mesh `m` with its morph targets (taking its data out of
    /// `targets`) and returns its node; an empty mesh gets a node without
    /// a mesh.
    fn write_mesh(
        &self,
        w: &mut Writer,
        m: usize,
        input: MeshInput,
        targets: &mut [Keyframe],
        layout: &TargetLayout,
    ) -> Value {
        let MeshInput {
            name,
            vertices: n,
            base,
            uvs,
            primitives,
        } = input;
        if n == 0 || primitives.iter().all(|(i, _)| i.is_empty()) {
            return json!({ "name": name });
        }
        let (pos_kind, nrm_kind) = kinds(w.encoding);
        let (lo, hi) = match w.encoding {
            AnimatedEncoding::Float => {
                let b = self.base_bounds[m];
                (
                    b.min.to_array().map(f64::from),
                    b.max.to_array().map(f64::from),
                )
            }
            _ => (base.min, base.max),
        };
        let position = w.attribute(n, base.positions, pos_kind, Some((lo, hi)));
        let normal = w.attribute(n, base.normals, nrm_kind, None);
        let uv_bytes: Vec<u8> = uvs
            .iter()
            .flat_map(|v| v.to_array())
            .flat_map(f32::to_le_bytes)
            .collect();
        let uv = w.attribute(n, uv_bytes, Attr::Vec2F32, None);
        let target_json = w.morph_targets(m, n, normal, targets, layout);
        let mut prims = Vec::new();
        for (indices, material) in &primitives {
            if indices.is_empty() {
                continue;
            }
            let accessor = index_accessor(&mut w.doc, &mut w.fallback_len, indices, n, w.encoding);
            prims.push(json!({
                "attributes": { "POSITION": position, "NORMAL": normal, "TEXCOORD_0": uv },
                "indices": accessor,
                "material": material,
                "mode": TRIANGLES,
                "targets": target_json,
            }));
        }
        let first = if layout.absolute_normals { 0 } else { 1 };
        let target_names: Vec<String> = (first..layout.keyframes)
            .map(|k| format!("keyframe {k}"))
            .collect();
        w.doc.meshes.push(json!({
            "name": name,
            "primitives": prims,
            "weights": vec![0.0; layout.target_count],
            "extras": { "targetNames": target_names },
        }));
        let mut node = json!({ "name": name, "mesh": w.doc.meshes.len() - 1 });
        if w.encoding != AnimatedEncoding::Float {
            node["translation"] = json!(self.translation.to_array());
            node["scale"] = json!([self.scale, self.scale, self.scale]);
        }
        node
    }
}

/// One mesh's data for the document.
struct MeshInput {
    name: &'static str,
    vertices: usize,
    /// Keyframe 0 as stored.
    base: Stored,
    uvs: Vec<Vec2>,
    /// Index lists and their glTF materials.
    primitives: Vec<(Vec<u32>, usize)>,
}

/// How keyframes map to morph targets.
struct TargetLayout {
    keyframes: usize,
    /// Quantised normals are stored absolute, with keyframe 0 as an extra
    /// target (see the module docs).
    absolute_normals: bool,
    /// Morph targets per mesh.
    target_count: usize,
}

impl TargetLayout {
    fn new(encoding: AnimatedEncoding, keyframes: usize) -> TargetLayout {
        let absolute_normals = encoding != AnimatedEncoding::Float;
        let target_count = if absolute_normals {
            keyframes
        } else {
            keyframes - 1
        };
        TargetLayout {
            keyframes,
            absolute_normals,
            target_count,
        }
    }
}

/// The document being written and the length of the meshopt fallback
/// buffer so far.
pub(crate) struct Writer {
    pub(crate) doc: Doc<'static>,
    pub(crate) fallback_len: usize,
    pub(crate) encoding: AnimatedEncoding,
}

impl Writer {
    /// An empty document declaring the extensions `encoding` needs.
    pub(crate) fn new(encoding: AnimatedEncoding) -> Writer {
        let mut doc = Doc::default();
        if encoding != AnimatedEncoding::Float {
            doc.use_extension(KHR_MESH_QUANTIZATION, true);
        }
        if encoding == AnimatedEncoding::Meshopt {
            doc.use_extension(EXT_MESHOPT_COMPRESSION, true);
        }
        Writer {
            doc,
            fallback_len: 0,
            encoding,
        }
    }

    /// The document, with the meshopt fallback buffer when compressed.
    pub(crate) fn into_doc(self) -> Doc<'static> {
        let mut doc = self.doc;
        if self.encoding == AnimatedEncoding::Meshopt {
            doc.extra_buffers.push(json!({
                "byteLength": self.fallback_len.max(4),
                "extensions": { EXT_MESHOPT_COMPRESSION: { "fallback": true } },
            }));
        }
        doc
    }

    /// A vertex attribute's view and accessor; returns the accessor.
    pub(crate) fn attribute(
        &mut self,
        count: usize,
        bytes: Vec<u8>,
        kind: Attr,
        bounds: Option<([f64; 3], [f64; 3])>,
    ) -> usize {
        let view = attribute_view(
            &mut self.doc,
            &mut self.fallback_len,
            count,
            self.encoding,
            bytes,
            kind,
        );
        self.doc.accessor(accessor_json(view, kind, count, bounds))
    }

    /// An accessor of `count` zeros of `kind`: without a buffer view, so
    /// it costs nothing in the file (glTF reads it as zeros).
    pub(crate) fn zeros(&mut self, count: usize, kind: Attr) -> usize {
        let mut a = accessor_json(0, kind, count, None);
        if let Some(a) = a.as_object_mut() {
            a.remove("bufferView");
        }
        self.doc.accessor(a)
    }

    /// The morph targets of mesh `m` (`n` vertices, keyframe-0 normals
    /// `normal`), taking their data out of `targets`.
    fn morph_targets(
        &mut self,
        m: usize,
        n: usize,
        normal: usize,
        targets: &mut [Keyframe],
        layout: &TargetLayout,
    ) -> Vec<Value> {
        let (pos_kind, nrm_kind) = kinds(self.encoding);
        let mut target_json = Vec::with_capacity(targets.len() + 1);
        if layout.absolute_normals {
            // Target 0 is keyframe 0: no displacement (an accessor
            // without a buffer view reads as zeros) and its normals,
            // shared with the base.
            let zero = self.doc.accessor(json!({
                "componentType": SHORT, "normalized": true, "count": n, "type": "VEC3",
                "min": [0, 0, 0], "max": [0, 0, 0],
            }));
            target_json.push(json!({ "POSITION": zero, "NORMAL": normal }));
        }
        for keyframe in targets {
            let stored = std::mem::replace(
                &mut keyframe.meshes[m],
                Stored {
                    positions: Vec::new(),
                    normals: Vec::new(),
                    min: [0.0; 3],
                    max: [0.0; 3],
                },
            );
            let pa = self.attribute(
                n,
                stored.positions,
                pos_kind,
                Some((stored.min, stored.max)),
            );
            let na = self.attribute(n, stored.normals, nrm_kind, None);
            target_json.push(json!({ "POSITION": pa, "NORMAL": na }));
        }
        target_json
    }
}

/// The animation: keyframe k (at `times[k]`) weighs target k alone.
fn write_animation(doc: &mut Doc<'static>, times: &[f32], layout: &TargetLayout) {
    let (keyframes, target_count) = (layout.keyframes, layout.target_count);
    let mut weights = vec![0f32; keyframes * target_count];
    for k in 1..keyframes {
        let row = &mut weights[k * target_count..(k + 1) * target_count];
        if layout.absolute_normals {
            // Keyframe k's normals replace keyframe 0's.
            row[0] = -1.0;
            row[k] = 1.0;
        } else {
            row[k - 1] = 1.0;
        }
    }
    let time_view = doc.view(Data::Owned(f32_bytes(times)), None, None);
    let input = doc.accessor(json!({
        "bufferView": time_view, "componentType": FLOAT, "count": times.len(), "type": "SCALAR",
        "min": [times[0]], "max": [times[times.len() - 1]],
    }));
    let weight_view = doc.view(Data::Owned(f32_bytes(&weights)), None, None);
    let output = doc.accessor(json!({
        "bufferView": weight_view, "componentType": FLOAT, "count": weights.len(), "type": "SCALAR",
    }));
    let channels: Vec<Value> = doc
        .nodes
        .iter()
        .enumerate()
        .filter(|(_, n)| n.get("mesh").is_some())
        .map(|(i, _)| json!({ "sampler": 0, "target": { "node": i, "path": "weights" } }))
        .collect();
    if !channels.is_empty() {
        doc.animations.push(json!({
            "name": "morph",
            "samplers": [{ "input": input, "output": output, "interpolation": "LINEAR" }],
            "channels": channels,
        }));
    }
}

impl Base {
    fn len(&self) -> usize {
        self.positions.len().max(self.q_positions.len())
    }
}

/// Refuses a duration that is not a positive number of seconds.
pub(crate) fn check_duration(options: &AnimatedOptions) -> Result<(), EncodeError> {
    if options.duration.is_finite() && options.duration > 0.0 {
        return Ok(());
    }
    Err(EncodeError::InvalidOptions(format!(
        "duration must be a positive number of seconds; got {}",
        options.duration
    )))
}

/// The quantisation grid of `bounds` for `encoding` (none for floats):
/// world = translation plus scale times q / 32767, the bounds mapped to
/// ±[`HALF_RANGE`].
pub(crate) fn grid(
    bounds: Aabb,
    encoding: AnimatedEncoding,
) -> Result<Option<(Vec3, f32)>, EncodeError> {
    if encoding == AnimatedEncoding::Float {
        return Ok(None);
    }
    if bounds.is_empty() || !(bounds.min.is_finite() && bounds.max.is_finite()) {
        return Err(EncodeError::InvalidOptions(format!(
            "quantised encodings need finite bounds; got {bounds:?}"
        )));
    }
    let extent = bounds.size().max_element().max(1e-6);
    Ok(Some((
        bounds.center(),
        extent * 0.5 * 32_767.0 / HALF_RANGE,
    )))
}

/// Leaves whose two materials differ, in order.
pub(crate) fn fading_leaves(topology: &FrameTopology) -> Vec<u32> {
    (0..topology.leaves.len() as u32)
        .filter(|&i| {
            let m = topology.leaves[i as usize].materials;
            m[0] != m[1]
        })
        .collect()
}

/// A fading leaf's threshold in (0, 1): a hash of its index, so the swaps
/// spread evenly over the blend ramp whatever the leaf order.
pub(crate) fn threshold(leaf: u32) -> f32 {
    let mut z = u64::from(leaf).wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    ((z >> 40) as f32 + 0.5) / (1u64 << 24) as f32
}

/// Local vertex indices of a leaf's base and tip.
fn base_and_tip(shape: LeafShape) -> (Option<usize>, Option<usize>) {
    match shape {
        LeafShape::Contour { points } => (Some(1), Some(1 + points as usize / 2)),
        // A quad's base and tip are its bottom and top edges' midpoints.
        _ => (None, None),
    }
}

/// The leaf vertices of one keyframe with every fading leaf's second layer
/// appended, and the hidden layer of each fading leaf collapsed (layer 1
/// onto the tip, layer 2 onto the base).
#[allow(clippy::too_many_arguments)]
fn layer_leaves(
    mesh: &MeshBuffers,
    topology: &FrameTopology,
    shape: LeafShape,
    fading: &[u32],
    thresholds: &[f32],
    frame: &Frame,
    positions: &mut Vec<Vec3>,
    normals: &mut Vec<Vec3>,
) {
    let per = shape.vertices_per_leaf();
    let n = topology.leaves.len() * per;
    positions.clear();
    normals.clear();
    positions.extend_from_slice(&mesh.positions);
    normals.extend_from_slice(&mesh.normals);
    positions.resize(n + fading.len() * per, Vec3::ZERO);
    normals.resize(n + fading.len() * per, Vec3::Z);
    let (base_i, tip_i) = base_and_tip(shape);
    let (first, second) = positions.split_at_mut(n);
    let (first_n, second_n) = normals.split_at_mut(n);
    for (slot, (&leaf, &h)) in fading.iter().zip(thresholds).enumerate() {
        let l = leaf as usize;
        let a = &mut first[l * per..(l + 1) * per];
        let b = &mut second[slot * per..(slot + 1) * per];
        b.copy_from_slice(a);
        second_n[slot * per..(slot + 1) * per].copy_from_slice(&first_n[l * per..(l + 1) * per]);
        let base = base_i.map_or_else(|| (a[0] + a[1]) * 0.5, |i| a[i]);
        let tip = tip_i.map_or_else(|| (a[2] + a[3]) * 0.5, |i| a[i]);
        if frame.leaves[l].blend >= h {
            a.fill(tip);
        } else {
            b.fill(base);
        }
    }
}

/// UVs of the layered leaf mesh: the mesher's (first material's contour),
/// then each second layer with its own material's contour.
fn layered_uvs(
    mesh: &MeshBuffers,
    topology: &FrameTopology,
    leaves: &crate::mesh::LeafMesher,
    fading: &[u32],
) -> Vec<Vec2> {
    let per = leaves.shape().vertices_per_leaf();
    let mut uvs = mesh.uvs.clone();
    for &leaf in fading {
        let b = topology.leaves[leaf as usize].materials[1] as usize;
        match leaves.contours().get(b) {
            Some(c) => uvs.extend(c.fan().map(LeafContour::uv)),
            // Quads: the same UVs in both layers.
            None => uvs.extend_from_slice(&mesh.uvs[leaf as usize * per..][..per]),
        }
    }
    uvs
}

/// The leaf mesh's primitives: per material pair, the first layer with
/// the first material, and for fading pairs the second layer (same
/// triangles on the appended vertices) with the second material. Leaf
/// material `m` is glTF material `1 + m`.
fn layered_primitives(
    mesh: &MeshBuffers,
    shape: LeafShape,
    fading: &[u32],
) -> Vec<(Vec<u32>, usize)> {
    let per = shape.vertices_per_leaf() as u32;
    let layer_base = mesh.positions.len() as u32;
    let mut slot_of = std::collections::HashMap::new();
    for (slot, &leaf) in fading.iter().enumerate() {
        slot_of.insert(leaf, slot as u32);
    }
    let mut out = Vec::new();
    for g in &mesh.groups {
        let range = g.first_index as usize..(g.first_index + g.index_count) as usize;
        let indices = &mesh.indices[range];
        let [a, b] = g.materials;
        out.push((indices.to_vec(), 1 + a as usize));
        if a != b {
            let second: Vec<u32> = indices
                .iter()
                .map(|&i| {
                    let (leaf, local) = (i / per, i % per);
                    layer_base + slot_of[&leaf] * per + local
                })
                .collect();
            out.push((second, 1 + b as usize));
        }
    }
    out
}

fn bounds(points: &[Vec3]) -> Aabb {
    crate::mesh::bounds_of(points)
}

/// The grid coordinate of `p` (world = t + s·q/32767), refused beyond the
/// `i16` range.
pub(crate) fn quantise(p: Vec3, t: Vec3, s: f32) -> Option<[i16; 3]> {
    let q = (p - t) / s * 32_767.0;
    let r = q.round();
    (r.abs().max_element() <= 32_767.0).then_some([r.x as i16, r.y as i16, r.z as i16])
}

pub(crate) fn quantise_normal(n: Vec3) -> [i8; 3] {
    let q = (n.clamp(Vec3::NEG_ONE, Vec3::ONE) * 127.0).round();
    [q.x as i8, q.y as i8, q.z as i8]
}

fn base(
    (positions, normals): (&[Vec3], &[Vec3]),
    encoding: AnimatedEncoding,
    t: Vec3,
    s: f32,
) -> Result<Base, EncodeError> {
    Ok(match encoding {
        AnimatedEncoding::Float => Base {
            positions: positions.to_vec(),
            normals: normals.to_vec(),
            q_positions: Vec::new(),
            q_normals: Vec::new(),
        },
        _ => Base {
            positions: Vec::new(),
            normals: Vec::new(),
            q_positions: positions
                .par_iter()
                .map(|&p| quantise(p, t, s))
                .collect::<Option<Vec<_>>>()
                .ok_or_else(outside)?,
            q_normals: normals.par_iter().map(|&n| quantise_normal(n)).collect(),
        },
    })
}

pub(crate) fn outside() -> EncodeError {
    EncodeError::Frame(treemorph_tree::frame::FrameMismatch(
        "a vertex lies too far outside the animation's bounds to quantise".into(),
    ))
}

/// The keyframe-0 data as stored.
fn store_base(base: &Base, encoding: AnimatedEncoding) -> Stored {
    match encoding {
        AnimatedEncoding::Float => Stored {
            positions: vec3_bytes(&base.positions),
            normals: vec3_bytes(&base.normals),
            min: [0.0; 3],
            max: [0.0; 3],
        },
        _ => {
            let (min, max) = i16_bounds(&base.q_positions);
            let mut s = Stored {
                positions: i16x4_bytes(&base.q_positions),
                normals: i8x4_bytes(&base.q_normals),
                min,
                max,
            };
            if encoding == AnimatedEncoding::Meshopt {
                s.positions = compress::<8>(&s.positions);
                s.normals = compress::<4>(&s.normals);
            }
            s
        }
    }
}

/// One keyframe as a morph target against `base`.
fn target(
    base: &Base,
    (positions, normals): (&[Vec3], &[Vec3]),
    encoding: AnimatedEncoding,
    t: Vec3,
    s: f32,
) -> Result<Stored, EncodeError> {
    match encoding {
        AnimatedEncoding::Float => {
            let dp: Vec<Vec3> = positions
                .par_iter()
                .zip(&base.positions)
                .map(|(&p, &b)| p - b)
                .collect();
            let dn: Vec<Vec3> = normals
                .par_iter()
                .zip(&base.normals)
                .map(|(&n, &b)| n - b)
                .collect();
            let b = bounds(&dp);
            let (min, max) = if b.is_empty() {
                ([0.0; 3], [0.0; 3])
            } else {
                (
                    b.min.to_array().map(f64::from),
                    b.max.to_array().map(f64::from),
                )
            };
            Ok(Stored {
                positions: vec3_bytes(&dp),
                normals: vec3_bytes(&dn),
                min,
                max,
            })
        }
        _ => {
            let dp: Vec<[i16; 3]> = positions
                .par_iter()
                .zip(&base.q_positions)
                .map(|(&p, b)| {
                    let q = quantise(p, t, s)?;
                    let d = [0, 1, 2].map(|a| i32::from(q[a]) - i32::from(b[a]));
                    d.iter()
                        .all(|d| d.abs() <= 32_767)
                        .then(|| d.map(|d| d as i16))
                })
                .collect::<Option<Vec<_>>>()
                .ok_or_else(outside)?;
            // Absolute normals (see the module docs): unit vectors always
            // fit the normalised range, differences of them do not.
            let dn: Vec<[i8; 3]> = normals.par_iter().map(|&n| quantise_normal(n)).collect();
            let (min, max) = i16_bounds(&dp);
            let mut stored = Stored {
                positions: i16x4_bytes(&dp),
                normals: i8x4_bytes(&dn),
                min,
                max,
            };
            if encoding == AnimatedEncoding::Meshopt {
                let (p, n) = rayon::join(
                    || compress::<8>(&stored.positions),
                    || compress::<4>(&stored.normals),
                );
                stored.positions = p;
                stored.normals = n;
            }
            Ok(stored)
        }
    }
}

pub(crate) fn i16_bounds(values: &[[i16; 3]]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [i16::MAX; 3];
    let mut hi = [i16::MIN; 3];
    for v in values {
        for a in 0..3 {
            lo[a] = lo[a].min(v[a]);
            hi[a] = hi[a].max(v[a]);
        }
    }
    if values.is_empty() {
        return ([0.0; 3], [0.0; 3]);
    }
    (lo.map(f64::from), hi.map(f64::from))
}

pub(crate) fn vec3_bytes(v: &[Vec3]) -> Vec<u8> {
    let mut out = vec![0u8; v.len() * 12];
    out.par_chunks_mut(12 * 4096)
        .zip(v.par_chunks(4096))
        .for_each(|(o, v)| {
            for (o, p) in o.chunks_exact_mut(12).zip(v) {
                o[0..4].copy_from_slice(&p.x.to_le_bytes());
                o[4..8].copy_from_slice(&p.y.to_le_bytes());
                o[8..12].copy_from_slice(&p.z.to_le_bytes());
            }
        });
    out
}

pub(crate) fn i16x4_bytes(v: &[[i16; 3]]) -> Vec<u8> {
    let mut out = vec![0u8; v.len() * 8];
    for (o, p) in out.chunks_exact_mut(8).zip(v) {
        for a in 0..3 {
            o[2 * a..2 * a + 2].copy_from_slice(&p[a].to_le_bytes());
        }
    }
    out
}

pub(crate) fn i8x4_bytes(v: &[[i8; 3]]) -> Vec<u8> {
    let mut out = vec![0u8; v.len() * 4];
    for (o, p) in out.chunks_exact_mut(4).zip(v) {
        for a in 0..3 {
            o[a] = p[a] as u8;
        }
    }
    out
}

pub(crate) fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// meshopt's attribute codec (version 0, as EXT_meshopt_compression
/// requires) over elements of `N` bytes.
pub(crate) fn compress<const N: usize>(bytes: &[u8]) -> Vec<u8> {
    let (elements, _) = bytes.as_chunks::<N>();
    meshopt::encode_vertex_buffer_level(elements, 0, Some(0))
        .expect("meshopt encodes any well-sized buffer")
}

/// What an attribute view holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Attr {
    /// `u16` VEC4 joint indices.
    Joints4U16,
    /// Normalised `u8` VEC4 joint weights.
    Weights4U8,
    Vec3F32,
    Vec2F32,
    /// Normalised `i16` VEC3 padded to 8 bytes.
    Vec3I16,
    /// Normalised `i8` VEC3 padded to 4 bytes.
    Vec3I8,
    /// Normalised `u16` VEC2 (texture coordinates in [0, 1]).
    Vec2U16,
}

impl Attr {
    fn stride(self) -> usize {
        match self {
            Attr::Vec3F32 => 12,
            Attr::Vec2F32 | Attr::Vec3I16 | Attr::Joints4U16 => 8,
            Attr::Vec3I8 | Attr::Vec2U16 | Attr::Weights4U8 => 4,
        }
    }
}

pub(crate) fn kinds(encoding: AnimatedEncoding) -> (Attr, Attr) {
    match encoding {
        AnimatedEncoding::Float => (Attr::Vec3F32, Attr::Vec3F32),
        _ => (Attr::Vec3I16, Attr::Vec3I8),
    }
}

pub(crate) fn accessor_json(
    view: usize,
    kind: Attr,
    count: usize,
    bounds: Option<([f64; 3], [f64; 3])>,
) -> Value {
    let (component, ty, normalized) = match kind {
        Attr::Vec3F32 => (FLOAT, "VEC3", false),
        Attr::Vec2F32 => (FLOAT, "VEC2", false),
        Attr::Vec3I16 => (SHORT, "VEC3", true),
        Attr::Vec3I8 => (BYTE, "VEC3", true),
        Attr::Vec2U16 => (UNSIGNED_SHORT, "VEC2", true),
        Attr::Joints4U16 => (UNSIGNED_SHORT, "VEC4", false),
        Attr::Weights4U8 => (UNSIGNED_BYTE, "VEC4", true),
    };
    let mut a =
        json!({ "bufferView": view, "componentType": component, "count": count, "type": ty });
    if normalized {
        a["normalized"] = json!(true);
    }
    if let Some((lo, hi)) = bounds {
        a["min"] = json!(lo);
        a["max"] = json!(hi);
    }
    a
}

/// A vertex attribute view: plain, or (meshopt) compressed with its plain
/// layout in the fallback buffer. Views of padded or non-12-byte elements
/// declare their stride; compressed bytes were produced by the caller,
/// except UVs, compressed here.
pub(crate) fn attribute_view(
    doc: &mut Doc<'static>,
    fallback_len: &mut usize,
    count: usize,
    encoding: AnimatedEncoding,
    bytes: Vec<u8>,
    kind: Attr,
) -> usize {
    let stride = kind.stride();
    if encoding != AnimatedEncoding::Meshopt {
        // Padded elements need their stride; packed floats do not.
        let s = matches!(kind, Attr::Vec3I16 | Attr::Vec3I8).then_some(stride);
        return doc.view(Data::Owned(bytes), Some(ARRAY_BUFFER), s);
    }
    let compressed = if kind == Attr::Vec2F32 {
        compress::<8>(&bytes)
    } else {
        bytes
    };
    let (offset, len) = doc.place(Data::Owned(compressed));
    let plain = fallback(fallback_len, count * stride);
    doc.push_view(json!({
        "buffer": 1, "byteOffset": plain, "byteLength": count * stride, "byteStride": stride,
        "target": ARRAY_BUFFER,
        "extensions": { EXT_MESHOPT_COMPRESSION: {
            "buffer": 0, "byteOffset": offset, "byteLength": len, "byteStride": stride,
            "mode": "ATTRIBUTES", "count": count,
        }},
    }))
}

/// Reserves `len` bytes of the fallback buffer (4-byte aligned).
pub(crate) fn fallback(fallback_len: &mut usize, len: usize) -> usize {
    let start = fallback_len.next_multiple_of(4);
    *fallback_len = start + len;
    start
}

pub(crate) fn index_accessor(
    doc: &mut Doc<'static>,
    fallback_len: &mut usize,
    indices: &[u32],
    vertex_count: usize,
    encoding: AnimatedEncoding,
) -> usize {
    let wide = vertex_count > MAX_U16_VERTICES;
    let (component, size) = if wide {
        (UNSIGNED_INT, 4)
    } else {
        (UNSIGNED_SHORT, 2)
    };
    let view = if encoding == AnimatedEncoding::Meshopt {
        let compressed = meshopt::encode_index_buffer(indices, vertex_count)
            .expect("meshopt encodes any triangle list");
        let (offset, len) = doc.place(Data::Owned(compressed));
        let plain = fallback(fallback_len, indices.len() * size);
        doc.push_view(json!({
            "buffer": 1, "byteOffset": plain, "byteLength": indices.len() * size,
            "target": ELEMENT_ARRAY_BUFFER,
            "extensions": { EXT_MESHOPT_COMPRESSION: {
                "buffer": 0, "byteOffset": offset, "byteLength": len, "byteStride": size,
                "mode": "TRIANGLES", "count": indices.len(),
            }},
        }))
    } else {
        let bytes: Vec<u8> = if wide {
            indices.iter().flat_map(|i| i.to_le_bytes()).collect()
        } else {
            indices
                .iter()
                .flat_map(|&i| (i as u16).to_le_bytes())
                .collect()
        };
        doc.view(Data::Owned(bytes), Some(ELEMENT_ARRAY_BUFFER), None)
    };
    doc.accessor(json!({
        "bufferView": view, "componentType": component, "count": indices.len(), "type": "SCALAR",
    }))
}

#[cfg(test)]
#[path = "animated_tests.rs"]
mod tests;
