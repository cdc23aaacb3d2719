//! The animated GLB as a motion basis: [`BasisGlbBuilder`].
//!
//! [`crate::animated`] stores every keyframe as a morph target, so a file
//! grows with its keyframes and a player holds all of them in memory.
//! Here the sequence's vertex motion is stored as at most
//! [`MAX_TARGETS`] morph targets — its principal displacements from the
//! first frame ([`motion`]) — and one weight per target and frame:
//!
//! - The **base mesh** is the first frame. Every frame pushed is a sample
//!   of the animation at its time (`t` × [`AnimatedOptions::duration`]);
//!   the animation's weights sampler has one key per sample (LINEAR), so
//!   the file's size is set by the target count, not the frame count.
//! - The **target count `K`** is the smallest that keeps every vertex of
//!   every sample within [`ERROR_BUDGET`] of the tree's height (the
//!   largest vertical extent of any sample's meshes) of its exact
//!   position, measured on the targets as stored (float targets are the
//!   basis offset and scaled, equal to it but for rounding; quantised
//!   ones are measured as a player reads them back). When
//!   [`MAX_TARGETS`] are not enough, all of them are used and the
//!   [`BasisReport`] says so with the error reached. The figures are also
//!   in the scene's `extras.treemorph`.
//! - Targets carry POSITION, and the leading ones NORMAL (`normals`: the
//!   others' NORMAL accessors read as zeros and cost nothing); the weights are the frames'
//!   coordinates in the basis, so any glTF player (three.js, Blender's
//!   shape keys, game engines) plays them as ordinary morph targets.
//!   Blender clamps shape-key values to [0, 1], so the weights are mapped
//!   onto that range and a constant *rest offset* target makes up the
//!   difference (see `Targets`).
//!
//! # Looks: dissolves instead of blends
//! Core glTF cannot blend two textures on one surface, and a blend factor
//! in a vertex attribute needs a shader of our own. So the change of
//! material is a **dissolve in a few steps** that every player follows:
//! the meshes are drawn by several nodes, and each swapping node's
//! `scale` switches between 1 and 0 with STEP interpolation at its swap
//! time — a node at scale 0 draws nothing. Every primitive holds only the
//! vertices it draws (three.js keeps morph data per primitive, so
//! primitives sharing one big vertex set would each upload all of it);
//! the two sides of a swap share theirs.
//!
//! - **Leaves** whose two materials differ swap when their blend passes
//!   their own threshold (a hash of the leaf index, as in
//!   [`crate::animated`]), so the crown changes leaf by leaf. Leaves that
//!   swap at the same sample form one group; more than
//!   [`MAX_LEAF_GROUPS`] distinct swap times are merged into that many
//!   groups. A group is two nodes: its leaves in their first material
//!   until the swap, and in their second material (with that material's
//!   outline as texture coordinates) from it. The two are never shown
//!   together, so they cannot z-fight.
//! - **Bark** changes in [`BARK_BANDS`] horizontal bands from the ground
//!   up (by the first frame's height of each triangle), band `g` when the
//!   sequence's bark blend has gone `(g + ½) / BARK_BANDS` of its way: a
//!   wave of new bark rising through the tree. The first frame's bark is
//!   exactly the first frame's blend of the source bark, and the last
//!   frame's the last frame's.
//!
//! # Encodings
//! As [`crate::animated`]: float, or `KHR_mesh_quantization` (base
//! positions on the `i16` grid of the bounds, base normals `i8`, leaf
//! texture coordinates `u16`), or that compressed with
//! `EXT_meshopt_compression`. Quantised targets are normalised `i16`
//! positions in the grid's units and `i8` normal changes; a target whose
//! positions would overflow the range is divided by its largest component
//! and its weights carry the scale back (see `quantised_target`). The
//! error reported for them is measured as a player reads them back.
//!
//! The nodes hang under one root node `tree`, which carries the
//! quantisation grid's translation and scale, so the swap nodes' own
//! scale is free for the dissolve.

mod appearance;
mod motion;
mod normals;
mod skin;
mod skinning;
mod weighted;

pub use skinning::SKIN_ERROR_BUDGET;

use std::io::Write;

use glam::{Vec2, Vec3};
use rayon::prelude::*;
use serde_json::{Map, Value, json};
use treemorph_tree::{Aabb, Frame, FrameTopology};

use crate::animated::{
    AnimatedEncoding, AnimatedGlbBuilder, AnimatedOptions, Attr, KEYFRAMES_MESH, Writer,
    check_duration, compress, f32_bytes, fading_leaves, grid, i8x4_bytes, i16_bounds, i16x4_bytes,
    index_accessor, outside, quantise, quantise_normal, threshold, vec3_bytes,
};
use crate::contour::LeafContour;
use crate::doc::{Data, Doc, Wrap, asset};
use crate::frame_glb::material_json;
use crate::frames::{EncodeError, FrameMeshes, Looks, check_frame};
use crate::gl::FLOAT;
use appearance::{NodePlan, Show};
use motion::Columns;

/// Most morph targets a basis animation uses.
pub const MAX_TARGETS: usize = 16;
/// The largest vertex error a basis animation aims for, as a fraction of
/// the tree's height.
pub const ERROR_BUDGET: f32 = 0.005;
/// Most residual morph targets of a skinned animation: engines that play
/// skeletons want few, and each costs every vertex's bytes; as many as a
/// basis animation's [`MAX_TARGETS`] at most. At 12, the default morph
/// missed the 1 % budget (1.02 %) once growing twigs waited for their
/// limbs to reshape: its growth phase moves more ways than 256 rigid
/// joints and 12 targets follow. 16 reach 0.76 %, with every sample's
/// residual fitted (`skin::residuals`; 1.08 % without).
pub const MAX_SKIN_TARGETS: usize = 16;
/// The target counts a skinned residual is fitted with, in turn, until
/// one keeps within budget (see `BasisGlbBuilder::residual_targets`).
/// Not 4, 12 and 16: where 12 missed (the default morph and five of six
/// third-party pairs measured, 60 frames), a fit of 16 came nearer
/// (third-party 1.9–5.2 % → 1.0–2.4 %), so the middle fit would only
/// cost time (default morph: 4.6 s against 3.4 s for the whole CLI run).
const SKIN_TARGET_RANKS: [usize; 2] = [4, MAX_SKIN_TARGETS];
/// Most groups of leaves that change material at one time.
pub const MAX_LEAF_GROUPS: usize = 16;
/// Bands in which the bark changes, from the ground up.
pub const BARK_BANDS: usize = 8;
/// Most bytes of samples a builder keeps (8 per vertex and sample:
/// position and normal displacements): beyond, it asks for fewer samples
/// rather than exhaust the memory of the process rendering it.
pub const MAX_SAMPLE_BYTES: u64 = 3 << 30;

/// Which animated GLB to build.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub enum AnimationKind {
    /// [`BasisGlbBuilder`]: the motion's principal displacements.
    #[default]
    Basis,
    /// [`AnimatedGlbBuilder`]: one morph target per keyframe.
    Keyframes,
    /// [`BasisGlbBuilder::skinned`]: a skeleton following the branch
    /// hierarchy ([`AnimatedOptions::skeleton_joints`] joints at most),
    /// with a few residual morph targets.
    Skinned,
}

impl AnimationKind {
    /// The options an animation of this kind is built with unless asked
    /// otherwise: [`AnimatedOptions::default`] (quad leaves, see
    /// [`ANIMATED_MESH`](crate::animated::ANIMATED_MESH)), with
    /// [`KEYFRAMES_MESH`] for keyframes.
    pub fn default_options(self) -> AnimatedOptions {
        match self {
            AnimationKind::Keyframes => AnimatedOptions::default().with_mesh(KEYFRAMES_MESH),
            AnimationKind::Basis | AnimationKind::Skinned => AnimatedOptions::default(),
        }
    }
}

/// The animated GLB of either kind, built from frames pushed in order.
pub enum AnimationBuilder {
    /// One morph target per keyframe.
    Keyframes(Box<AnimatedGlbBuilder>),
    /// The motion basis.
    Basis(Box<BasisGlbBuilder>),
}

impl AnimationBuilder {
    /// The builder of `kind` (see each builder's `new`).
    pub fn new(
        kind: AnimationKind,
        topology: &FrameTopology,
        reference_radii: &[f32],
        bounds: Aabb,
        options: &AnimatedOptions,
    ) -> Result<AnimationBuilder, EncodeError> {
        Ok(match kind {
            AnimationKind::Keyframes => AnimationBuilder::Keyframes(Box::new(
                AnimatedGlbBuilder::new(topology, reference_radii, bounds, options)?,
            )),
            AnimationKind::Basis => AnimationBuilder::Basis(Box::new(BasisGlbBuilder::new(
                topology,
                reference_radii,
                bounds,
                options,
            )?)),
            AnimationKind::Skinned => AnimationBuilder::Basis(Box::new(
                BasisGlbBuilder::new(topology, reference_radii, bounds, options)?.skinned(),
            )),
        })
    }

    /// Adds the next keyframe or sample.
    pub fn push(&mut self, frame: &Frame) -> Result<(), EncodeError> {
        match self {
            AnimationBuilder::Keyframes(b) => b.push(frame),
            AnimationBuilder::Basis(b) => b.push(frame),
        }
    }

    /// The GLB, and for a basis what it reached.
    pub fn finish(self) -> Result<(Vec<u8>, Option<BasisReport>), EncodeError> {
        match self {
            AnimationBuilder::Keyframes(b) => Ok((b.finish()?, None)),
            AnimationBuilder::Basis(b) => b.finish().map(|(glb, r)| (glb, Some(r))),
        }
    }
}

/// What a basis animation reached.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BasisReport {
    /// Morph targets used (0 for a still sequence).
    pub targets: usize,
    /// The largest distance of any vertex of any sample from its exact
    /// position, as a fraction of the tree's height.
    pub max_error: f32,
    /// Whether that is within [`ERROR_BUDGET`] (false when
    /// [`MAX_TARGETS`] were not enough).
    pub within_budget: bool,
    /// The tree's height: the largest vertical extent of a sample, metres.
    pub height: f32,
    /// Joints of a skinned animation besides its still root (0 for a
    /// basis).
    pub joints: usize,
    /// How many of the leading targets carry normals (the others' NORMAL
    /// accessors read as zeros; see `normals`).
    pub normal_targets: usize,
    /// The largest mean angle, in degrees, between a sample's normals as a
    /// player computes them and its exact normals.
    pub normal_error_degrees: f32,
}

/// Builds the basis animation of a sequence from its frames, pushed in
/// time order. It keeps every sample's vertex displacements (12 bytes per
/// vertex and frame, twice: positions and normals) until
/// [`BasisGlbBuilder::finish`], which needs all of them.
///
/// ```
/// use treemorph_gltf::animated::AnimatedOptions;
/// use treemorph_gltf::basis::BasisGlbBuilder;
/// use treemorph_tree::{Aabb, Frame, FrameTopology};
/// # let tree = treemorph_gltf::sample::sample_tree(20);
/// let topology = FrameTopology::of_tree(&tree);
/// let mut frame = Frame::of_tree(&tree);
/// let bounds = Aabb::of_points(frame.positions.iter().copied()).inflated(1.0);
/// let mut builder = BasisGlbBuilder::new(&topology, &frame.radii, bounds, &AnimatedOptions::default())?;
/// builder.push(&frame)?;
/// frame.t = 1.0;
/// frame.positions[1].x += 0.5;
/// builder.push(&frame)?;
/// let (glb, report) = builder.finish()?;
/// assert_eq!(&glb[..4], b"glTF");
/// assert_eq!(report.targets, 1);
/// # Ok::<(), treemorph_gltf::frames::EncodeError>(())
/// ```
pub struct BasisGlbBuilder {
    meshes: FrameMeshes,
    looks: Looks,
    topology: FrameTopology,
    options: AnimatedOptions,
    /// Quantisation: world = translation + scale · (q / 32767).
    grid: Option<(Vec3, f32)>,
    base: Option<BasePose>,
    displacements: Columns,
    normal_changes: Columns,
    times: Vec<f32>,
    bark_blends: Vec<f32>,
    /// Leaves whose materials differ, their thresholds and the first
    /// sample at which each one's blend reached its threshold.
    fading: Vec<u32>,
    thresholds: Vec<f32>,
    swaps: Vec<Option<u32>>,
    /// The largest vertical extent of a sample.
    heights: f32,
    /// Most samples [`MAX_SAMPLE_BYTES`] allows.
    max_samples: usize,
    /// Whether the motion goes to a skeleton first ([`BasisGlbBuilder::skinned`]).
    skinned: bool,
    /// Tests: bind this way alone instead of trying both.
    #[cfg(test)]
    only_bind: Option<skin::Bind>,
    /// Tests: a skinned error budget instead of [`SKIN_ERROR_BUDGET`].
    #[cfg(test)]
    skin_budget: Option<f32>,
    /// Tests: target counts to fit a skinned residual with instead of
    /// [`SKIN_TARGET_RANKS`].
    #[cfg(test)]
    skin_ranks: Option<Vec<usize>>,
}

/// The first frame as the file stores it, and what the document needs of
/// the meshes besides positions.
#[derive(Clone)]
struct BasePose {
    /// Positions and normals as a player reads them back (dequantised for
    /// the quantised encodings): displacements are taken from these.
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    q_positions: Vec<[i16; 3]>,
    q_normals: Vec<[i8; 3]>,
    branch_vertices: usize,
    branch_uvs: Vec<Vec2>,
    branch_indices: Vec<u32>,
    /// Leaf texture coordinates in the first and in the second material's
    /// outline.
    leaf_uvs: [Vec<Vec2>; 2],
    leaf_indices: Vec<u32>,
    per_leaf: usize,
}

impl BasisGlbBuilder {
    /// Plans the meshes of `topology` (as [`crate::animated::AnimatedGlbBuilder::new`]:
    /// `bounds` matter for the quantised encodings only; pass the per-node
    /// maximum radius as `reference_radii`). [`AnimatedOptions::keyframes`]
    /// is only a capacity hint here: every frame pushed is a sample.
    pub fn new(
        topology: &FrameTopology,
        reference_radii: &[f32],
        bounds: Aabb,
        options: &AnimatedOptions,
    ) -> Result<BasisGlbBuilder, EncodeError> {
        check_duration(options)?;
        let grid = grid(bounds, options.encoding)?;
        let meshes = FrameMeshes::new(topology, reference_radii, &options.mesh)?;
        let looks = Looks::new(topology, meshes.leaves(), 64);
        let fading = fading_leaves(topology);
        let rows = 3 * (meshes.branches().vertex_count() + meshes.leaves().vertex_count());
        let max_samples = (MAX_SAMPLE_BYTES / (8 * rows.max(1) as u64)) as usize;
        if options.keyframes > max_samples {
            return Err(too_many_samples(options.keyframes, rows / 3, max_samples));
        }
        let capacity = options.keyframes.clamp(2, max_samples.max(2));
        Ok(BasisGlbBuilder {
            thresholds: fading.iter().map(|&i| threshold(i)).collect(),
            swaps: vec![None; fading.len()],
            fading,
            meshes,
            looks,
            topology: topology.clone(),
            options: options.clone(),
            grid,
            base: None,
            displacements: Columns::new(rows, capacity),
            normal_changes: Columns::new(rows, capacity),
            times: Vec::new(),
            bark_blends: Vec::new(),
            heights: 0.0,
            max_samples,
            skinned: false,
            #[cfg(test)]
            only_bind: None,
            #[cfg(test)]
            skin_budget: None,
            #[cfg(test)]
            skin_ranks: None,
        })
    }

    /// Makes this builder write a skinned animation: joints that follow
    /// the branch hierarchy (at most [`AnimatedOptions::skeleton_joints`]
    /// besides the root), their translation, rotation and scale at every
    /// sample, and the fewest residual morph targets (up to
    /// [`MAX_SKIN_TARGETS`]) that keep every vertex within
    /// [`SKIN_ERROR_BUDGET`] of the tree's height. See `skin` and
    /// `skinning` for the choices.
    #[must_use]
    pub fn skinned(mut self) -> BasisGlbBuilder {
        self.skinned = true;
        self
    }

    /// Frames pushed so far.
    pub fn sample_count(&self) -> usize {
        self.times.len()
    }

    /// Adds the next sample (its time `frame.t · duration` must be later
    /// than the previous one's).
    pub fn push(&mut self, frame: &Frame) -> Result<(), EncodeError> {
        check_frame(
            frame,
            self.topology.node_count(),
            self.topology.leaves.len(),
        )?;
        let time = frame.t * self.options.duration;
        if let Some(&last) = self.times.last()
            && time <= last
        {
            return Err(EncodeError::Usage(format!(
                "sample times must increase: t = {} after a sample at {last} s",
                frame.t
            )));
        }
        if self.times.len() >= self.max_samples {
            let vertices = self.displacements.rows / 3;
            return Err(too_many_samples(
                self.times.len() + 1,
                vertices,
                self.max_samples,
            ));
        }
        self.meshes.mesh(frame)?;
        if self.base.is_none() {
            let base = self.base_pose()?;
            self.base = Some(base);
        }
        self.record(frame, time)
    }

    /// The first frame as stored, with the meshes' UVs and indices.
    fn base_pose(&self) -> Result<BasePose, EncodeError> {
        let branches = self.meshes.branches().buffers();
        let leaves = self.meshes.leaves().buffers();
        let positions = [&branches.positions[..], &leaves.positions[..]].concat();
        let normals = [&branches.normals[..], &leaves.normals[..]].concat();
        let (positions, normals, q_positions, q_normals) = match self.grid {
            None => (positions, normals, Vec::new(), Vec::new()),
            Some((t, s)) => {
                let q: Vec<[i16; 3]> = positions
                    .iter()
                    .map(|&p| quantise(p, t, s))
                    .collect::<Option<_>>()
                    .ok_or_else(outside)?;
                let qn: Vec<[i8; 3]> = normals.iter().map(|&n| quantise_normal(n)).collect();
                let p = q
                    .iter()
                    .map(|q| t + s * Vec3::from(q.map(f32::from)) / 32_767.0)
                    .collect();
                let n = qn
                    .iter()
                    .map(|q| Vec3::from(q.map(f32::from)) / 127.0)
                    .collect();
                (p, n, q, qn)
            }
        };
        Ok(BasePose {
            positions,
            normals,
            q_positions,
            q_normals,
            branch_vertices: branches.positions.len(),
            branch_uvs: branches.uvs.clone(),
            branch_indices: branches.indices.clone(),
            leaf_uvs: [leaves.uvs.clone(), self.second_uvs()],
            leaf_indices: leaves.indices.clone(),
            per_leaf: self.meshes.leaves().shape().vertices_per_leaf(),
        })
    }

    /// Leaf texture coordinates in each leaf's second material's outline.
    fn second_uvs(&self) -> Vec<Vec2> {
        let leaves = self.meshes.leaves();
        let uvs = &leaves.buffers().uvs;
        let per = leaves.shape().vertices_per_leaf();
        let mut out = uvs.clone();
        for (l, leaf) in self.topology.leaves.iter().enumerate() {
            if let Some(c) = leaves.contours().get(leaf.materials[1] as usize) {
                for (o, uv) in out[l * per..(l + 1) * per]
                    .iter_mut()
                    .zip(c.fan().map(LeafContour::uv))
                {
                    *o = uv;
                }
            }
        }
        out
    }

    /// Records the sample just meshed: its displacements from the base,
    /// its time, bark blend, leaf swaps and height.
    fn record(&mut self, frame: &Frame, time: f32) -> Result<(), EncodeError> {
        let Some(base) = &self.base else {
            return Err(EncodeError::Internal("no base pose".into()));
        };
        let branches = self.meshes.branches().buffers();
        let leaves = self.meshes.leaves().buffers();
        let (lo, hi) = branches
            .positions
            .iter()
            .chain(&leaves.positions)
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p.y), hi.max(p.y))
            });
        if hi >= lo {
            self.heights = self.heights.max(hi - lo);
        }
        let (displacements, normal_changes) = (&mut self.displacements, &mut self.normal_changes);
        rayon::join(
            || {
                let values = [&branches.positions[..], &leaves.positions[..]];
                extend_differences(displacements, values, &base.positions);
            },
            || {
                let values = [&branches.normals[..], &leaves.normals[..]];
                extend_differences(normal_changes, values, &base.normals);
            },
        );
        let sample = self.times.len() as u32;
        for ((slot, &leaf), &h) in self
            .swaps
            .iter_mut()
            .zip(&self.fading)
            .zip(&self.thresholds)
        {
            if slot.is_none() && frame.leaves[leaf as usize].blend >= h {
                *slot = Some(sample);
            }
        }
        self.times.push(time);
        self.bark_blends.push(frame.bark_blend);
        Ok(())
    }

    /// The GLB and what the basis reached. Errors: [`EncodeError::Usage`]
    /// with fewer than two samples.
    pub fn finish(self) -> Result<(Vec<u8>, BasisReport), EncodeError> {
        let mut out = Vec::new();
        let (doc, root, report) = self.document()?;
        doc.write(root, &mut out).map_err(|total| {
            EncodeError::TooLarge(format!(
                "the animated GLB would be {total} bytes; a GLB holds at most 4 GiB"
            ))
        })?;
        Ok((out, report))
    }

    /// Streams the GLB to `w`; returns its size in bytes and the report.
    pub fn finish_to(self, w: &mut impl Write) -> Result<(u64, BasisReport), EncodeError> {
        let (doc, root, report) = self.document()?;
        let len = doc.write_to(root, w).map_err(|e| match e.kind() {
            std::io::ErrorKind::InvalidInput => EncodeError::TooLarge(e.to_string()),
            _ => EncodeError::Io(e.to_string()),
        })?;
        Ok((len, report))
    }

    fn document(mut self) -> Result<(Doc<'static>, Map<String, Value>, BasisReport), EncodeError> {
        if self.times.len() < 2 {
            return Err(EncodeError::Usage(format!(
                "an animation needs at least 2 frames; got {}",
                self.times.len()
            )));
        }
        let mut base = self.base.take().expect("a pushed frame sets the base");
        let (skin, targets, report) = if self.skinned {
            let (skin, targets, report) = self.skinned_fit(&mut base)?;
            (Some(skin), targets, report)
        } else {
            let (targets, report) = self.fit(ERROR_BUDGET, None, &base.normals);
            (None, targets, report)
        };
        let encoding = self.options.encoding;
        let mut w = Writer::new(encoding);
        let bark_looks = self.write_materials(&mut w.doc);
        // Bark bands by the first frame's heights, skinned or not.
        let first = skin
            .as_ref()
            .map_or(&base.positions[..], |s| s.first_positions());
        let plans = appearance::plan(&appearance::Inputs {
            base: &first[..base.branch_vertices],
            branch_indices: &base.branch_indices,
            leaf_indices: &base.leaf_indices,
            per_leaf: self.meshes.leaves().shape().vertices_per_leaf(),
            topology: &self.topology,
            fading: &self.fading,
            swaps: &self.swaps,
            times: &self.times,
            bark_blends: &self.bark_blends,
            bark_looks,
        });
        let parts = Parts {
            plans: &plans,
            base: &base,
            targets: &targets,
            skin: skin.as_ref(),
        };
        let nodes = write_nodes(&mut w, &parts);
        let mut root = Map::new();
        let scene_nodes = match &skin {
            None => {
                write_animation(&mut w.doc, &self.times, &parts, &nodes, None);
                let mut tree = json!({ "name": "tree", "children": nodes.iter().map(|n| n.1).collect::<Vec<_>>() });
                if let Some((t, s)) = self.grid {
                    tree["translation"] = json!(t.to_array());
                    tree["scale"] = json!([s, s, s]);
                }
                w.doc.nodes.push(tree);
                vec![w.doc.nodes.len() - 1]
            }
            // Skinned mesh nodes are scene roots: glTF ignores their
            // parents' transforms, and validators warn of any.
            Some(skin) => {
                let (skin_json, first_joint) = skin.write_skeleton(&mut w, self.grid);
                root.insert("skins".into(), json!([skin_json]));
                write_animation(&mut w.doc, &self.times, &parts, &nodes, Some(first_joint));
                std::iter::once(first_joint)
                    .chain(nodes.iter().map(|n| n.1))
                    .collect()
            }
        };
        let doc = w.into_doc();
        root.insert("asset".into(), asset());
        root.insert("scene".into(), json!(0));
        let (kind, error_budget) = match skin {
            Some(_) => ("skinned", SKIN_ERROR_BUDGET),
            None => ("basis", ERROR_BUDGET),
        };
        let mut extras = json!({
            "animation": kind,
            "targets": report.targets,
            "max_error": report.max_error,
            "within_budget": report.within_budget,
            "error_budget": error_budget,
            "normal_targets": report.normal_targets,
            "normal_error_degrees": report.normal_error_degrees,
        });
        if report.joints > 0 {
            extras["joints"] = json!(report.joints);
        }
        root.insert(
            "scenes".into(),
            json!([{ "nodes": scene_nodes, "extras": { "treemorph": extras } }]),
        );
        Ok((doc, root, report))
    }

    /// A skinned animation's skeleton, with the base pose made the bind
    /// pose, its residual targets and its report: of the two ways of
    /// choosing the joints' bind samples ([`skin::Bind`]), the one whose
    /// file a player shows nearer the samples (the first alone when it is
    /// within budget). Both rigs share the joints.
    fn skinned_fit(
        &mut self,
        base: &mut BasePose,
    ) -> Result<(skinning::Skin, Targets, BasisReport), EncodeError> {
        let rig = self.rig(base)?;
        #[cfg(test)]
        if let Some(bind) = self.only_bind {
            return self.bind_and_fit(base, rig, bind);
        }
        let unbound = base.clone();
        let mut first = self.bind_and_fit(base, rig.clone(), skin::Bind::Bark)?;
        if first.2.within_budget {
            return Ok(first);
        }
        (self.displacements, self.normal_changes) = first.0.take_samples();
        let mut other = unbound;
        // The first rig is a whole file already: a second that cannot be
        // made (it binds at other samples, so its pose could fall outside
        // the quantisation grid) leaves it.
        match self.bind_and_fit(&mut other, rig, skin::Bind::Open) {
            Ok(second) if second.2.max_error < first.2.max_error => {
                *base = other;
                Ok(second)
            }
            Ok(mut second) => {
                first.0.put_samples(second.0.take_samples());
                Ok(first)
            }
            Err(_) => Ok(first),
        }
    }

    /// The largest vertex error a skinned animation aims for, as a
    /// fraction of the height.
    fn skin_budget(&self) -> f32 {
        #[cfg(test)]
        if let Some(budget) = self.skin_budget {
            return budget;
        }
        SKIN_ERROR_BUDGET
    }

    /// The target counts a skinned residual is fitted with, in turn.
    fn skin_ranks(&self) -> Vec<usize> {
        #[cfg(test)]
        if let Some(ranks) = &self.skin_ranks {
            return ranks.clone();
        }
        SKIN_TARGET_RANKS.to_vec()
    }

    /// The skeleton of the samples.
    fn rig(&self, base: &BasePose) -> Result<skin::Rig, EncodeError> {
        let owners = self.meshes.branches().vertex_owners();
        let leaf_vertices = base.positions.len() - base.branch_vertices;
        let samples = skin::Samples {
            base: &base.positions,
            base_normals: &base.normals,
            displacements: &self.displacements,
            normal_changes: &self.normal_changes,
        };
        let rig = skin::Rig::new(
            &self.topology,
            &owners,
            (base.per_leaf, leaf_vertices),
            &samples,
            self.options.skeleton_joints,
        );
        if rig.joint_count() > usize::from(u16::MAX) {
            return Err(EncodeError::TooLarge(format!(
                "a skeleton of {} joints does not fit glTF's 16-bit joint indices; set skeleton_joints",
                rig.joint_count()
            )));
        }
        Ok(rig)
    }

    /// `rig` bound as `bind` chooses, with the base pose made the bind
    /// pose, the residual's targets and the error a player shows (the
    /// samples go into the skin).
    fn bind_and_fit(
        &mut self,
        base: &mut BasePose,
        rig: skin::Rig,
        bind: skin::Bind,
    ) -> Result<(skinning::Skin, Targets, BasisReport), EncodeError> {
        let owners = self.meshes.branches().vertex_owners();
        let skin = skinning::rig_up(
            base,
            (&mut self.displacements, &mut self.normal_changes),
            &owners,
            (rig, bind),
            self.grid,
        )?;
        let budget = self.skin_budget();
        let (targets, mut report) = self.fit(budget, Some((&skin, base)), &base.normals);
        let error = skin.max_error(base, &targets);
        report.max_error = error / report.height;
        report.within_budget = error <= budget * report.height;
        report.joints = skin.rig.joint_count() - 1;
        Ok((skin, targets, report))
    }

    /// The principal displacements, cut to the fewest that keep within
    /// `budget` (a fraction of the height), in the file's encoding, and
    /// the error of what is written.
    /// A skinned animation's count is chosen by the error a player shows
    /// (`skin`, over the bind pose `base`).
    fn fit(
        &mut self,
        budget: f32,
        skin: Option<(&skinning::Skin, &BasePose)>,
        base_normals: &[Vec3],
    ) -> (Targets, BasisReport) {
        let most = if self.skinned {
            MAX_SKIN_TARGETS
        } else {
            MAX_TARGETS
        };
        let spectrum = motion::Spectrum::of(&self.displacements, most);
        let height = self.heights.max(1e-6);
        let budget = budget * height;
        let (mut principal, (k, error)) = match skin {
            None => {
                let p = motion::principal_of(&self.displacements, &self.normal_changes, spectrum);
                let fewest = motion::fewest_within(
                    &self.displacements,
                    &p.positions,
                    &p.weights,
                    p.count,
                    budget,
                );
                (p, fewest)
            }
            Some((skin, base)) => self.residual_targets(skin, base, spectrum, budget),
        };
        principal.truncate(k);
        let (normal_targets, normal_error_degrees) =
            normals::leading_normals(base_normals, &self.normal_changes, &principal, k);
        let targets = Targets::encode(&principal, (k, normal_targets), self.grid);
        // Float targets are the basis itself, offset and scaled (rounding
        // apart); quantised ones are measured again as a player reads
        // them back (a skinned animation's by its caller, through the
        // skeleton).
        let error = if self.grid.is_some() && skin.is_none() {
            let count = targets.stored.len();
            motion::max_error(
                &self.displacements,
                &targets.read_back,
                &targets.weights_read_back,
                count,
            )
        } else {
            error
        };
        // Free the samples before the document is written.
        self.displacements = Columns::default();
        self.normal_changes = Columns::default();
        let report = BasisReport {
            targets: k,
            max_error: error / height,
            within_budget: error <= budget,
            height,
            joints: 0,
            normal_targets,
            normal_error_degrees,
        };
        (targets, report)
    }

    /// A skinned residual's targets and how many of them to keep, with the
    /// error a player then shows (metres): fitted to the error as shown
    /// with as many targets as each of [`SKIN_TARGET_RANKS`] (at most as
    /// many as the plain motion has directions, `spectrum`) in turn, until
    /// one keeps within `budget`; the fit that a player shows nearest is
    /// kept. A weighted fit of many targets is not the best of fewer (its
    /// leading targets share the motion with the rest): where no count
    /// kept within budget, a fit of 4 came nearer than one of 12 on six
    /// of ten third-party pairs (when 12 was the larger fit). The plain
    /// principal displacements are formed only where that fit does not
    /// apply.
    fn residual_targets(
        &self,
        skin: &skinning::Skin,
        base: &BasePose,
        spectrum: motion::Spectrum,
        budget: f32,
    ) -> (motion::Principal, (usize, f32)) {
        let mut kept: Option<(motion::Principal, (usize, f32))> = None;
        let mut ranks: Vec<usize> = self
            .skin_ranks()
            .iter()
            .map(|&r| r.min(spectrum.count()))
            .collect();
        ranks.dedup();
        for rank in ranks {
            let Some(p) = skin.refit(&self.displacements, &self.normal_changes, rank) else {
                break;
            };
            let (k, error) = skin.fewest_that_help(base, &p, budget);
            if kept.as_ref().is_none_or(|(_, (_, e))| error < *e) {
                kept = Some((p, (k, error)));
            }
            if error <= budget {
                break;
            }
        }
        kept.unwrap_or_else(|| {
            let p = motion::principal_of(&self.displacements, &self.normal_changes, spectrum);
            let fewest = skin.fewest_that_help(base, &p, budget);
            (p, fewest)
        })
    }

    /// Materials: the bark looks of the first and (when it differs) the
    /// last sample, then every leaf material. Returns how many bark looks
    /// there are (leaf material `m` is glTF material `bark_looks + m`).
    fn write_materials(&mut self, doc: &mut Doc<'static>) -> usize {
        let first = self.looks.step(self.bark_blends[0]);
        let last = self
            .looks
            .step(*self.bark_blends.last().expect("two samples"));
        let mut looks = vec![self.looks.bark(first).clone()];
        if self.looks.bark(last) != &looks[0] {
            looks.push(self.looks.bark(last).clone());
        }
        let bark_looks = looks.len();
        looks.extend((0..self.topology.leaf_materials.len() as u32).map(|m| self.looks.leaf(m)));
        for (i, look) in looks.iter().enumerate() {
            let leaf = i >= bark_looks;
            let wrap = if leaf { Wrap::Clamp } else { Wrap::Repeat };
            let texture = look
                .texture
                .as_ref()
                .map(|t| doc.texture(Data::Owned(t.png().to_vec()), &look.name, wrap));
            doc.materials.push(material_json(look, texture, leaf));
        }
        bark_looks
    }
}

/// The refusal of more samples than [`MAX_SAMPLE_BYTES`] allows.
fn too_many_samples(samples: usize, vertices: usize, max: usize) -> EncodeError {
    EncodeError::TooLarge(format!(
        "a basis animation of {samples} sampled frames of {vertices} vertices needs more than \
         {} GiB; ask for at most {max} keyframes",
        MAX_SAMPLE_BYTES >> 30
    ))
}

/// Appends `values − base` as one planar column (`values` in pieces:
/// branch then leaf vertices).
fn extend_differences(columns: &mut Columns, values: [&[Vec3]; 2], base: &[Vec3]) {
    let (first, second) = base.split_at(values[0].len());
    for axis in 0..3 {
        for (piece, base) in [(values[0], first), (values[1], second)] {
            columns
                .data
                .extend(piece.iter().zip(base).map(|(v, b)| v[axis] - b[axis]));
        }
    }
}

/// The morph targets as written.
///
/// Principal weights are signed and unbounded, but Blender's importer
/// clamps shape-key values to [0, 1] (it widens a key's range by the
/// first keyframe's weight only). So each target is scaled by its weight
/// range and its weights mapped onto [0, 1]: `w = lo + w′ · range`. The
/// constant part `Σ lo_k · target_k` becomes one more target, the *rest
/// offset*, first in the file, at weight 1 throughout. The base mesh stays
/// the first frame, exactly.
struct Targets {
    /// The rest offset (when any weight range starts below zero), then
    /// the motion targets.
    stored: Vec<StoredTarget>,
    /// Written weights, `[frame · stored.len() + k]`.
    weights: Vec<f32>,
    /// Quantised encodings: the stored positions as a player reads them
    /// back (world units) and the weights that go with them, for measuring
    /// the written error (float targets are not measured again).
    read_back: Columns,
    weights_read_back: Vec<f32>,
    /// Whether the first target is the rest offset.
    offset: bool,
}

/// A quantised target's positions as a player reads them back (a planar
/// column) and the scale its weights carry.
type ReadBack = (Vec<f32>, f32);

/// One target's positions and normals as written; empty normals are
/// written as an accessor without a buffer view, which reads as zeros.
enum StoredTarget {
    Float(Vec<Vec3>, Vec<Vec3>),
    /// Normalised `i16` positions in the grid's mesh space, normalised
    /// `i8` normal changes.
    Quantised(Vec<[i16; 3]>, Vec<[i8; 3]>),
}

impl Targets {
    /// The first `k` targets of `p`, offset and scaled as the type docs
    /// say, in the encoding of `grid` (none: floats); only the first
    /// `normal_targets` carry normals (an empty normal column reads as
    /// zeros), and the rest offset sums only theirs.
    fn encode(
        p: &motion::Principal,
        (k, normal_targets): (usize, usize),
        grid: Option<(Vec3, f32)>,
    ) -> Targets {
        let frames = p.weights.len().checked_div(p.count).unwrap_or(0);
        let weight = |j: usize, t: usize| p.weights[j * p.count + t];
        let ranges: Vec<(f32, f32)> = (0..k)
            .map(|t| {
                let (lo, hi) = (0..frames).fold((0f32, 0f32), |(lo, hi), j| {
                    (lo.min(weight(j, t)), hi.max(weight(j, t)))
                });
                (lo, (hi - lo).max(1e-12))
            })
            .collect();
        let offset = ranges.iter().any(|&(lo, _)| lo < 0.0);
        let mut columns: Vec<(Vec<f32>, Vec<f32>)> = Vec::with_capacity(k + 1);
        if offset {
            let mut pos = vec![0f32; p.positions.rows];
            let rows = if normal_targets > 0 {
                p.normals.rows
            } else {
                0
            };
            let mut nrm = vec![0f32; rows];
            for (t, &(lo, _)) in ranges.iter().enumerate() {
                add_scaled(&mut pos, p.positions.column(t), lo);
                if t < normal_targets {
                    add_scaled(&mut nrm, p.normals.column(t), lo);
                }
            }
            columns.push((pos, nrm));
        }
        let scaled: Vec<(Vec<f32>, Vec<f32>)> = ranges
            .par_iter()
            .enumerate()
            .map(|(t, &(_, range))| {
                let scaled = |c: &[f32]| c.iter().map(|v| v * range).collect::<Vec<f32>>();
                let normals = if t < normal_targets {
                    scaled(p.normals.column(t))
                } else {
                    Vec::new()
                };
                (scaled(p.positions.column(t)), normals)
            })
            .collect();
        columns.extend(scaled);
        let unit: Vec<f32> = (0..frames)
            .flat_map(|j| {
                let first = offset.then_some(1.0);
                first.into_iter().chain(
                    ranges
                        .iter()
                        .enumerate()
                        .map(move |(t, &(lo, range))| (weight(j, t) - lo) / range),
                )
            })
            .collect();
        Targets::store(columns, unit, grid, offset)
    }

    /// Stores `columns` (world units) with weights `unit` in [0, 1].
    fn store(
        columns: Vec<(Vec<f32>, Vec<f32>)>,
        unit: Vec<f32>,
        grid: Option<(Vec3, f32)>,
        offset: bool,
    ) -> Targets {
        let count = columns.len();
        let rows = columns.first().map_or(0, |c| c.0.len());
        let mut weights = unit.clone();
        let mut read_back = Columns::new(rows, if grid.is_some() { count } else { 0 });
        // Converted in parallel; read back and weights scaled in order.
        let converted: Vec<(StoredTarget, Option<ReadBack>)> = columns
            .into_par_iter()
            .map(|(pos, nrm)| match grid {
                None => (StoredTarget::Float(as_vec3(&pos), as_vec3(&nrm)), None),
                Some((_, s)) => {
                    let (target, back, scale) = quantised_target(&pos, &nrm, s);
                    (target, Some((back, scale)))
                }
            })
            .collect();
        let mut stored = Vec::with_capacity(count);
        for (t, (target, quantised)) in converted.into_iter().enumerate() {
            if let Some((back, scale)) = quantised {
                read_back.data.extend(back);
                for w in weights.iter_mut().skip(t).step_by(count) {
                    *w *= scale;
                }
            }
            stored.push(target);
        }
        Targets {
            stored,
            weights_read_back: unit,
            weights,
            read_back,
            offset,
        }
    }
}

impl Targets {
    /// Vertex `v`'s offset at sample `f`, as a player reads the targets.
    fn offset_at(&self, f: usize, v: usize) -> Vec3 {
        let count = self.stored.len();
        let mut d = Vec3::ZERO;
        for (k, t) in self.stored.iter().enumerate() {
            d += match t {
                StoredTarget::Float(p, _) => p[v] * self.weights[f * count + k],
                StoredTarget::Quantised(..) => {
                    self.read_back.vertex(k, v) * self.weights_read_back[f * count + k]
                }
            };
        }
        d
    }
}

fn add_scaled(to: &mut [f32], from: &[f32], by: f32) {
    for (t, f) in to.iter_mut().zip(from) {
        *t += f * by;
    }
}

/// The VEC3s of a planar column.
fn as_vec3(values: &[f32]) -> Vec<Vec3> {
    let n = values.len() / 3;
    (0..n)
        .map(|i| Vec3::new(values[i], values[n + i], values[2 * n + i]))
        .collect()
}

/// A target as normalised `i16` positions in the mesh space of a grid of
/// scale `s` and normalised `i8` normal changes. Positions that fit the
/// range are stored as they are (weight scale 1, so weights stay in
/// [0, 1]); larger ones are divided by their largest component, which the
/// weights carry back. Normal changes are divided by the same scale and
/// clamped to the range: a normal turned by more than about 60° along one
/// target shades slightly off, never the geometry; their 1/127 steps are
/// below what shading shows. Returns the target, its positions read back
/// in world units and the weight scale.
fn quantised_target(positions: &[f32], normals: &[f32], s: f32) -> (StoredTarget, Vec<f32>, f32) {
    let largest = positions.iter().fold(0f32, |m, x| m.max(x.abs() / s));
    let scale = largest.max(1.0);
    let q = |v: f32| {
        (v / s / scale * 32_767.0)
            .round()
            .clamp(-32_767.0, 32_767.0) as i16
    };
    let qp: Vec<[i16; 3]> = as_vec3(positions)
        .iter()
        .map(|c| [q(c.x), q(c.y), q(c.z)])
        .collect();
    let qn: Vec<[i8; 3]> = as_vec3(normals)
        .iter()
        .map(|c| {
            c.to_array()
                .map(|v| (v / scale * 127.0).round().clamp(-127.0, 127.0) as i8)
        })
        .collect();
    let n = qp.len();
    let mut back = vec![0f32; 3 * n];
    for (i, v) in qp.iter().enumerate() {
        for a in 0..3 {
            back[a * n + i] = f32::from(v[a]) / 32_767.0 * scale * s;
        }
    }
    (StoredTarget::Quantised(qp, qn), back, scale)
}

/// Accessors of the vertices one node draws.
#[derive(Clone, Debug, Default)]
struct VertexSet {
    count: usize,
    position: usize,
    normal: usize,
    /// JOINTS_0 and WEIGHTS_0 (skinned).
    influences: Option<(usize, usize)>,
    /// TEXCOORD_0 accessors, written when first used: the first
    /// material's, and (leaves) the second material's outline.
    uvs: [Option<usize>; 2],
    targets: Vec<Value>,
}

/// What the nodes are written from.
struct Parts<'a> {
    plans: &'a [NodePlan],
    base: &'a BasePose,
    targets: &'a Targets,
    skin: Option<&'a skinning::Skin>,
}

impl Parts<'_> {
    /// Whether a node of `plan` carries the `hidden` target (skinned
    /// swap nodes).
    fn hides(&self, plan: &NodePlan) -> bool {
        self.skin.is_some() && plan.show != Show::Always
    }
}

/// The vertices of the base meshes that a node draws: `indices` into
/// `base` (branch vertices first, then leaf vertices), with the `hidden`
/// target when `hides`.
fn write_vertex_set(w: &mut Writer, parts: &Parts, indices: &[usize], hides: bool) -> VertexSet {
    let base = parts.base;
    let count = indices.len();
    let quantised = w.encoding != AnimatedEncoding::Float;
    let (position, normal) = if quantised {
        let q = pick(&base.q_positions, indices);
        let bounds = i16_bounds(&q);
        let p = meshopt_if(w.encoding, i16x4_bytes(&q), 8);
        let n = meshopt_if(w.encoding, i8x4_bytes(&pick(&base.q_normals, indices)), 4);
        (
            w.attribute(count, p, Attr::Vec3I16, Some(bounds)),
            w.attribute(count, n, Attr::Vec3I8, None),
        )
    } else {
        let p = pick(&base.positions, indices);
        let n = pick(&base.normals, indices);
        (
            w.attribute(count, vec3_bytes(&p), Attr::Vec3F32, Some(f32_bounds(&p))),
            w.attribute(count, vec3_bytes(&n), Attr::Vec3F32, None),
        )
    };
    let hidden = parts.skin.filter(|_| hides).map(|s| &s.hidden);
    let stored: Vec<&StoredTarget> = parts.targets.stored.iter().chain(hidden).collect();
    // Picked and encoded in parallel (meshopt's compression too), written
    // in order.
    let encoding = w.encoding;
    let encoded: Vec<EncodedTarget> = stored
        .par_iter()
        .map(|t| encode_target(encoding, t, indices))
        .collect();
    let targets = encoded
        .into_iter()
        .map(|t| write_target(w, t, count))
        .collect();
    VertexSet {
        count,
        position,
        normal,
        influences: parts.skin.map(|s| s.write_influences(w, indices)),
        uvs: [None; 2],
        targets,
    }
}

/// One morph target of some vertices, encoded: positions (bytes, kind,
/// bounds) and normals (bytes, kind).
struct EncodedTarget {
    position: (Vec<u8>, Attr, ([f64; 3], [f64; 3])),
    /// Empty bytes: zeros, without a buffer view.
    normal: (Vec<u8>, Attr),
}

/// Target `t` of the vertices at `indices`, in the file's `encoding`.
fn encode_target(encoding: AnimatedEncoding, t: &StoredTarget, indices: &[usize]) -> EncodedTarget {
    match t {
        StoredTarget::Float(p, n) => {
            let (p, n) = (pick(p, indices), pick_some(n, indices));
            EncodedTarget {
                position: (vec3_bytes(&p), Attr::Vec3F32, f32_bounds(&p)),
                normal: (vec3_bytes(&n), Attr::Vec3F32),
            }
        }
        StoredTarget::Quantised(p, n) => {
            let (p, n) = (pick(p, indices), pick_some(n, indices));
            EncodedTarget {
                position: (
                    meshopt_if(encoding, i16x4_bytes(&p), 8),
                    Attr::Vec3I16,
                    i16_bounds(&p),
                ),
                normal: if n.is_empty() {
                    (Vec::new(), Attr::Vec3I8)
                } else {
                    (meshopt_if(encoding, i8x4_bytes(&n), 4), Attr::Vec3I8)
                },
            }
        }
    }
}

/// The accessors of an encoded target of `count` vertices.
fn write_target(w: &mut Writer, t: EncodedTarget, count: usize) -> Value {
    let (pb, pk, bounds) = t.position;
    let (nb, nk) = t.normal;
    let pa = w.attribute(count, pb, pk, Some(bounds));
    let na = if nb.is_empty() {
        w.zeros(count, nk)
    } else {
        w.attribute(count, nb, nk, None)
    };
    json!({ "POSITION": pa, "NORMAL": na })
}

/// `values` at `indices`.
fn pick<T: Copy>(values: &[T], indices: &[usize]) -> Vec<T> {
    indices.iter().map(|&i| values[i]).collect()
}

/// `values` at `indices`, or none when there are none (a target without
/// normals).
fn pick_some<T: Copy>(values: &[T], indices: &[usize]) -> Vec<T> {
    if values.is_empty() {
        return Vec::new();
    }
    pick(values, indices)
}

/// A float POSITION accessor's `min` and `max`.
fn f32_bounds(points: &[Vec3]) -> ([f64; 3], [f64; 3]) {
    let b = crate::mesh::bounds_of(points);
    if b.is_empty() {
        return ([0.0; 3], [0.0; 3]);
    }
    (
        b.min.to_array().map(f64::from),
        b.max.to_array().map(f64::from),
    )
}

/// A texture coordinate accessor: normalised `u16` in the quantised
/// encodings when every coordinate is in [0, 1] (leaves), else floats
/// (bark coordinates run beyond 1 along a branch).
fn uv_attribute(w: &mut Writer, uvs: &[Vec2]) -> usize {
    let unit = uvs
        .iter()
        .all(|v| (0.0..=1.0).contains(&v.x) && (0.0..=1.0).contains(&v.y));
    if w.encoding == AnimatedEncoding::Float || !unit {
        let bytes: Vec<u8> = uvs
            .iter()
            .flat_map(|v| v.to_array())
            .flat_map(f32::to_le_bytes)
            .collect();
        return w.attribute(uvs.len(), bytes, Attr::Vec2F32, None);
    }
    let bytes: Vec<u8> = uvs
        .iter()
        .flat_map(|v| v.to_array().map(|c| (c * 65_535.0).round() as u16))
        .flat_map(u16::to_le_bytes)
        .collect();
    let bytes = meshopt_if(w.encoding, bytes, 4);
    w.attribute(uvs.len(), bytes, Attr::Vec2U16, None)
}

/// `bytes` compressed with meshopt's attribute codec for the meshopt
/// encoding (elements of `stride` bytes), else as they are.
fn meshopt_if(encoding: AnimatedEncoding, bytes: Vec<u8>, stride: usize) -> Vec<u8> {
    if encoding != AnimatedEncoding::Meshopt {
        return bytes;
    }
    match stride {
        4 => compress::<4>(&bytes),
        _ => compress::<8>(&bytes),
    }
}

/// Morph target names: the rest offset, then `motion 0`, `motion 1`, …
fn target_names(targets: &Targets) -> Vec<String> {
    let motions = targets.stored.len() - usize::from(targets.offset);
    let offset = targets.offset.then(|| "rest offset".to_string());
    offset
        .into_iter()
        .chain((0..motions).map(|k| format!("motion {k}")))
        .collect()
}

/// Writes a node per plan that draws anything; returns each one's plan
/// and node index.
///
/// Each primitive has vertex accessors of its own, holding only the
/// vertices it draws: three.js makes a geometry per primitive and keeps
/// morph data per geometry, so primitives sharing one big vertex set would
/// each upload all of its targets. The two sides of a swap draw the same
/// vertices and share their accessors (their texture coordinates differ).
fn write_nodes(w: &mut Writer, parts: &Parts) -> Vec<(usize, usize)> {
    let names = target_names(parts.targets);
    let mut sets: std::collections::HashMap<Vec<usize>, VertexSet> = Default::default();
    let mut nodes = Vec::new();
    for (p, plan) in parts.plans.iter().enumerate() {
        let hides = parts.hides(plan);
        let prims: Vec<Value> = plan
            .primitives
            .iter()
            .filter(|(_, indices)| !indices.is_empty())
            .map(|(&(material, uv, _), indices)| {
                let mut prim =
                    write_primitive(w, &mut sets, parts, (plan.leaves, hides), uv, indices);
                prim["material"] = json!(material);
                prim
            })
            .collect();
        if prims.is_empty() {
            continue;
        }
        let mut mesh = json!({ "name": plan.name, "primitives": prims });
        let mut names = names.clone();
        let mut weights = vec![0.0; names.len()];
        if let Some(skin) = parts.skin.filter(|_| hides) {
            names.push("hidden".into());
            let hidden = matches!(plan.show, Show::From(_));
            weights.push(if hidden { skin.hidden_weight } else { 0.0 });
        }
        if !names.is_empty() {
            mesh["weights"] = json!(weights);
            mesh["extras"] = json!({ "targetNames": names });
        }
        w.doc.meshes.push(mesh);
        let mut node = json!({ "name": plan.name, "mesh": w.doc.meshes.len() - 1 });
        if parts.skin.is_some() {
            node["skin"] = json!(0);
        } else if matches!(plan.show, Show::From(_)) {
            node["scale"] = json!([0.0, 0.0, 0.0]);
        }
        w.doc.nodes.push(node);
        nodes.push((p, w.doc.nodes.len() - 1));
    }
    nodes
}

/// A primitive drawing `indices` (into the branch or leaf vertices, as
/// `leaves_hides.0` says) with texture coordinate set `uv`, over the
/// vertex set of exactly the vertices it uses (written on first use, then
/// shared), with the morph targets when there are any.
fn write_primitive(
    w: &mut Writer,
    sets: &mut std::collections::HashMap<Vec<usize>, VertexSet>,
    parts: &Parts,
    (leaves, hides): (bool, bool),
    uv: usize,
    indices: &[u32],
) -> Value {
    let base = parts.base;
    let offset = if leaves { base.branch_vertices } else { 0 };
    let local: std::collections::BTreeSet<u32> = indices.iter().copied().collect();
    let global: Vec<usize> = local.iter().map(|&i| offset + i as usize).collect();
    let mut remap = vec![u32::MAX; local.last().map_or(0, |&l| l as usize + 1)];
    for (new, &old) in local.iter().enumerate() {
        remap[old as usize] = new as u32;
    }
    let set = sets
        .entry(global.clone())
        .or_insert_with(|| write_vertex_set(w, parts, &global, hides));
    let uv_accessor = *set.uvs[uv].get_or_insert_with(|| {
        let all: &[Vec2] = if leaves {
            &base.leaf_uvs[uv]
        } else {
            &base.branch_uvs
        };
        let mine: Vec<Vec2> = local.iter().map(|&i| all[i as usize]).collect();
        uv_attribute(w, &mine)
    });
    let local_indices: Vec<u32> = indices.iter().map(|&i| remap[i as usize]).collect();
    let accessor = index_accessor(
        &mut w.doc,
        &mut w.fallback_len,
        &local_indices,
        set.count,
        w.encoding,
    );
    let mut prim = json!({
        "attributes": { "POSITION": set.position, "NORMAL": set.normal, "TEXCOORD_0": uv_accessor },
        "indices": accessor,
        "mode": crate::gl::TRIANGLES,
    });
    if let Some((joints, weights)) = set.influences {
        prim["attributes"]["JOINTS_0"] = json!(joints);
        prim["attributes"]["WEIGHTS_0"] = json!(weights);
    }
    if !set.targets.is_empty() {
        prim["targets"] = json!(set.targets);
    }
    prim
}

/// The animation: the weights of every mesh node (one LINEAR sampler
/// keyed at every sample), and every swap node's visibility: its scale
/// (STEP) in a basis animation, its `hidden` weight in a skinned one,
/// whose joints (from node `first_joint` on) get their channels too.
fn write_animation(
    doc: &mut Doc<'static>,
    times: &[f32],
    parts: &Parts,
    nodes: &[(usize, usize)],
    first_joint: Option<usize>,
) {
    let targets = parts.targets;
    let mut samplers = Vec::new();
    let mut channels = Vec::new();
    let mut input = None;
    if !targets.stored.is_empty() {
        let input = *input.get_or_insert_with(|| time_accessor(doc, times));
        let view = doc.view(Data::Owned(f32_bytes(&targets.weights)), None, None);
        let output = doc.accessor(json!({
            "bufferView": view, "componentType": FLOAT, "count": targets.weights.len(), "type": "SCALAR",
        }));
        samplers.push(json!({ "input": input, "output": output, "interpolation": "LINEAR" }));
        for &(p, node) in nodes {
            if !parts.hides(&parts.plans[p]) {
                channels
                    .push(json!({ "sampler": 0, "target": { "node": node, "path": "weights" } }));
            }
        }
    }
    match (parts.skin, first_joint) {
        (Some(skin), Some(first)) => {
            hidden_channels(
                doc,
                times,
                parts,
                nodes,
                skin,
                (&mut samplers, &mut channels),
            );
            let input = *input.get_or_insert_with(|| time_accessor(doc, times));
            skin.write_channels(doc, input, first, &mut samplers, &mut channels);
        }
        _ => scale_channels(
            doc,
            times,
            parts.plans,
            nodes,
            (&mut samplers, &mut channels),
        ),
    }
    if !channels.is_empty() {
        doc.animations
            .push(json!({ "name": "morph", "samplers": samplers, "channels": channels }));
    }
}

/// Samplers and channels being gathered.
type Channels<'a> = (&'a mut Vec<Value>, &'a mut Vec<Value>);

/// A basis animation's swap nodes: scale 1 or 0, STEP at the swap.
fn scale_channels(
    doc: &mut Doc<'static>,
    times: &[f32],
    plans: &[NodePlan],
    nodes: &[(usize, usize)],
    (samplers, channels): Channels,
) {
    let mut scales: Option<[usize; 2]> = None;
    let mut inputs = std::collections::HashMap::new();
    for &(p, node) in nodes {
        let (time, show) = match plans[p].show {
            Show::Always => continue,
            Show::Until(t) => (t, false),
            Show::From(t) => (t, true),
        };
        let [hide, reveal] = *scales.get_or_insert_with(|| {
            let mut v = |a: f32, b: f32| -> usize {
                let view = doc.view(Data::Owned(f32_bytes(&[a, a, a, b, b, b])), None, None);
                doc.accessor(json!({
                    "bufferView": view, "componentType": FLOAT, "count": 2, "type": "VEC3",
                }))
            };
            [v(1.0, 0.0), v(0.0, 1.0)]
        });
        let input = *inputs
            .entry(time.to_bits())
            .or_insert_with(|| time_accessor(doc, &[times[0], time]));
        samplers.push(json!({
            "input": input, "output": if show { reveal } else { hide }, "interpolation": "STEP",
        }));
        channels.push(json!({
            "sampler": samplers.len() - 1, "target": { "node": node, "path": "scale" },
        }));
    }
}

/// A skinned animation's swap nodes: their weights, the motion's then
/// `hidden` switching at the swap (see [`skinning::swap_keys`]).
fn hidden_channels(
    doc: &mut Doc<'static>,
    times: &[f32],
    parts: &Parts,
    nodes: &[(usize, usize)],
    skin: &skinning::Skin,
    (samplers, channels): Channels,
) {
    let count = parts.targets.stored.len();
    for &(p, node) in nodes {
        let (swap, hidden_before) = match parts.plans[p].show {
            Show::Always => continue,
            Show::Until(t) => (t, false),
            Show::From(t) => (t, true),
        };
        let (keys, values) = skinning::swap_keys(
            times,
            &parts.targets.weights,
            count,
            swap,
            hidden_before,
            skin.hidden_weight,
        );
        let input = time_accessor(doc, &keys);
        let view = doc.view(Data::Owned(f32_bytes(&values)), None, None);
        let output = doc.accessor(json!({
            "bufferView": view, "componentType": FLOAT, "count": values.len(), "type": "SCALAR",
        }));
        samplers.push(json!({ "input": input, "output": output, "interpolation": "LINEAR" }));
        channels.push(json!({
            "sampler": samplers.len() - 1, "target": { "node": node, "path": "weights" },
        }));
    }
}

/// A SCALAR float accessor of increasing times.
fn time_accessor(doc: &mut Doc<'static>, times: &[f32]) -> usize {
    let view = doc.view(Data::Owned(f32_bytes(times)), None, None);
    doc.accessor(json!({
        "bufferView": view, "componentType": FLOAT, "count": times.len(), "type": "SCALAR",
        "min": [times[0]], "max": [times[times.len() - 1]],
    }))
}

#[cfg(test)]
#[path = "basis_tests.rs"]
mod tests;
