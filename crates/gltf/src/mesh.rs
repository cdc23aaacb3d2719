//! Branch and leaf meshes from frames: the one code path every GLB we write
//! uses.
//!
//! [`BranchMesher`] sweeps every strand of a [`FrameTopology`] into a
//! generalised cylinder; [`LeafMesher`] turns every [`FrameLeaf`](treemorph_tree::FrameLeaf) into a
//! double-sided quad. Both are reusable context objects: everything that
//! depends only on the topology (vertex and index counts, triangle indices,
//! texture coordinates, per-strand side counts, sine tables) is computed once
//! by `new`, and `mesh(&frame)` only overwrites positions, normals and bounds
//! in buffers it owns, so meshing a sequence allocates nothing after the
//! constructor. The code is hand-written: no crate sweeps tubes along
//! polylines with the guarantees below.
//!
//! # Guarantees
//! - **Counts depend on the topology only.** Every frame of a sequence gives
//!   the same vertex count, index buffer and texture coordinates; the
//!   animated GLB (morph targets) and the binary delta stream rely on it.
//! - **Degenerate input gives degenerate, finite output.** Zero radii (chains
//!   not grown yet, or wilted), zero-length segments and zero-size leaves
//!   collapse triangles but never produce NaN; normals are always unit
//!   length (a fallback direction is used where the geometry defines none).
//!
//! # Tubes
//! Each strand node gets a ring of `sides + 1` vertices (the seam column is
//! duplicated so `u` can run from 0 to 1). Rings are oriented by
//! **parallel transport** (rotation-minimising frames): the first ring's
//! reference direction is world `+X` rotated by the shortest arc from `+Y` to
//! the strand's first tangent — continuous in the tangent everywhere except
//! for a strand pointing straight down, so animated strands do not flip —
//! and each later ring's is the previous one rotated by the shortest arc
//! between consecutive tangents, so tubes do not twist. A node's tangent is
//! the bisector of its incoming and outgoing segment directions. Normals are
//! the radial ring directions (smooth shading; the slope of tapering tubes is
//! ignored, which is invisible at branch scale).
//!
//! **Side count.** Each strand's side count is fixed once from the
//! *reference radii* passed to [`BranchMesher::new`]: with `r` the strand's
//! largest reference radius and `R` the largest over all strands,
//! `sides = min_sides + round((max_sides − min_sides) · √(r / R))`. Pass the
//! static tree's radii, or for an animation the per-node maximum over the
//! sequence so chains that grow later are not meshed as thinnest twigs.
//!
//! **Joins.** A *child strand* starts at a node it shares with the strand it
//! grows from (a skeleton junction: that node's radius is the parent's), or
//! at any node another strand already starts from. Its first ring stays on
//! the parent axis, perpendicular to the child's first segment, but takes
//! the radius `min(r_junction, r_second)` — the child's own thickness — so
//! the child does not flare to the parent's girth; while the child is no
//! thicker than its parent that ring lies inside the parent tube and the
//! visible join is where the child tube leaves the parent surface. No
//! vertices are welded between tubes (a "tube soup"): each tube is closed
//! where it is visible, which is what renderers and the validator need.
//!
//! **Caps.** Every strand ends in an apex vertex one tip radius beyond its
//! last node along the tangent (a rounded cone; it collapses onto the tip
//! when the radius is zero). A strand that is not a child strand (the trunk
//! at the root) also gets a flat base cap: one centre vertex with the
//! backward tangent as normal.
//!
//! **Bark UVs.** `u` runs around the circumference from 0 to 1 (ring vertex
//! `j` has `u = j / sides`); `v` is arc length divided by the local
//! circumference `2π·r` (radius floored at [`MeshOptions::min_uv_radius`]),
//! accumulated along the strand from 0, so a square bark texture keeps
//! square texels on thick and thin branches alike. UVs are computed once from
//! the reference frame and are identical in every frame, so the bark texture
//! sticks to the bark as it moves.
//!
//! # Leaves
//! Each leaf is a quad of 4 vertices and 2 triangles (its material is
//! double-sided, so one face suffices): local corners `(±w/2, 0, 0)` and
//! `(±w/2, h, 0)` rotated by the leaf's orientation and moved to its anchor,
//! normal local `+Z`, UVs `u` 0→1 across the blade, `v = 1` at the base and
//! `v = 0` at the tip: leaf images are drawn upright (base on the bottom row,
//! the tree model's convention) and glTF's `v = 0` is the top row. Leaf vertices are in
//! topology order (leaf `i` owns vertices `4i..4i+4`); the index buffer is
//! sorted into one contiguous [`MeshGroup`] per distinct material pair so an
//! encoder can emit one primitive per material. [`LeafShape`] selects the
//! shape: quads, or [`LeafShape::Contour`] — each leaf the outline of its
//! material's texture ([`crate::contour`]) as a fan of `K` triangles
//! around a centre on the midrib (`K + 1` vertices: the centre, then the
//! rim counter-clockwise from the blade base), morphing from its first
//! material's outline to its second's by the leaf's blend, with UVs from
//! the first material's outline in every frame.
//!
//! # Speed
//! A frame is meshed in parallel (rayon): strands in batches of about
//! 16,000 vertices, leaves in batches of 2,048, each batch writing its own
//! slice of the buffers, so the output does not depend on the thread
//! count. Per ring the dependency chain from one ring's frame to the next
//! has one division and no square root (tangents are computed in a first
//! pass over a run of nodes, where their square roots overlap), and
//! per-vertex work and bounds use SIMD lanes. Thin twigs cost the most
//! vertices in large trees: `MeshOptions::default().with_sides(3, 10)`
//! meshes a 20,000-chain tree with ~20 % fewer branch vertices than the
//! default 4–12.

use std::f32::consts::TAU;

use glam::{Mat3A, Quat, Vec2, Vec3, Vec3A, Vec4};
use rayon::prelude::*;
use thiserror::Error;
use treemorph_tree::frame::FrameMismatch;
use treemorph_tree::geom::NONE;
use treemorph_tree::{Aabb, Frame, FrameTopology, NodeId};

use crate::contour::LeafContour;

/// Largest side count accepted for [`MeshOptions::max_sides`].
pub const MAX_SIDES: u32 = 64;

/// How leaves are shaped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum LeafShape {
    /// A textured quad of 4 vertices: the papers' billboard leaf.
    #[default]
    Quad,
    /// The blade outline of each leaf material's texture with `points`
    /// rim points ([`crate::contour`]), as a fan of `points` triangles
    /// around a centre on the midrib (`points + 1` vertices). A leaf whose
    /// two materials differ morphs from the first material's outline to
    /// the second's by its blend. `points` must be even, in
    /// [`contour::MIN_POINTS`](crate::contour::MIN_POINTS)..=[`contour::MAX_POINTS`](crate::contour::MAX_POINTS).
    Contour {
        /// Rim points per leaf (e.g. 24).
        points: u32,
    },
}

impl LeafShape {
    /// Vertices per leaf.
    pub fn vertices_per_leaf(self) -> usize {
        match self {
            LeafShape::Quad => 4,
            LeafShape::Contour { points } => points as usize + 1,
        }
    }

    /// Triangle indices per leaf.
    pub fn indices_per_leaf(self) -> usize {
        match self {
            LeafShape::Quad => 6,
            LeafShape::Contour { points } => 3 * points as usize,
        }
    }
}

/// Options shared by [`BranchMesher`] and [`LeafMesher`].
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct MeshOptions {
    /// Sides of the thickest strands (default 12; at most [`MAX_SIDES`]).
    pub max_sides: u32,
    /// Sides of the thinnest strands (default 4; at least 3).
    pub min_sides: u32,
    /// Smallest radius used to scale bark `v` coordinates, metres (default
    /// 0.002): keeps `v` finite and modest on zero-radius and hair-thin
    /// strands.
    pub min_uv_radius: f32,
    /// Leaf geometry (default [`LeafShape::Quad`]).
    pub leaf_shape: LeafShape,
}

impl Default for MeshOptions {
    fn default() -> MeshOptions {
        MeshOptions::DEFAULT
    }
}

impl MeshOptions {
    /// The default options, as a constant for other defaults to build on.
    pub const DEFAULT: MeshOptions = MeshOptions {
        max_sides: 12,
        min_sides: 4,
        min_uv_radius: 0.002,
        leaf_shape: LeafShape::Quad,
    };

    /// These options with the side counts of the thinnest and thickest
    /// strands set.
    #[must_use]
    pub const fn with_sides(mut self, min_sides: u32, max_sides: u32) -> MeshOptions {
        self.min_sides = min_sides;
        self.max_sides = max_sides;
        self
    }

    /// These options with [`MeshOptions::leaf_shape`] set.
    #[must_use]
    pub const fn with_leaf_shape(mut self, shape: LeafShape) -> MeshOptions {
        self.leaf_shape = shape;
        self
    }

    pub(crate) fn check(&self) -> Result<(), MeshError> {
        if self.min_sides < 3 || self.max_sides < self.min_sides || self.max_sides > MAX_SIDES {
            return Err(MeshError::InvalidOptions(format!(
                "sides must satisfy 3 ≤ min_sides ≤ max_sides ≤ {MAX_SIDES}; got {}..{}",
                self.min_sides, self.max_sides
            )));
        }
        if let LeafShape::Contour { points } = self.leaf_shape {
            crate::contour::check_points(points)
                .map_err(|e| MeshError::InvalidOptions(e.to_string()))?;
        }
        if !(self.min_uv_radius.is_finite() && self.min_uv_radius > 0.0) {
            return Err(MeshError::InvalidOptions(format!(
                "min_uv_radius must be a positive number of metres; got {}",
                self.min_uv_radius
            )));
        }
        Ok(())
    }
}

/// Why a mesh could not be built.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum MeshError {
    /// The options are out of range.
    #[error("invalid mesh options: {0}")]
    InvalidOptions(String),
    /// A strand names a node the topology does not have.
    #[error("strand {strand} names node {node}, but the topology has {count} nodes")]
    StrandNodeOutOfRange {
        /// Index of the strand.
        strand: usize,
        /// The node id found.
        node: NodeId,
        /// Nodes in the topology.
        count: usize,
    },
    /// A frame (or the reference frame) does not fit the topology.
    #[error(transparent)]
    Frame(#[from] FrameMismatch),
    /// A leaf names a leaf material the topology does not have.
    #[error(
        "leaf {leaf} uses materials {materials:?}, but the topology has {count} leaf materials"
    )]
    LeafMaterialOutOfRange {
        /// Index of the leaf.
        leaf: usize,
        /// Its material pair.
        materials: [u32; 2],
        /// Leaf materials in the topology.
        count: usize,
    },
    /// The mesh would need more vertices or indices than `u32` can count.
    #[error(
        "the mesh would have {count} {what}; at most {} are supported",
        u32::MAX
    )]
    TooLarge {
        /// `"vertices"` or `"indices"`.
        what: &'static str,
        /// How many were needed.
        count: u64,
    },
}

/// A contiguous range of a mesh's index buffer drawn with one material.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MeshGroup {
    /// For leaves, the pair of leaf materials (indices into
    /// [`FrameTopology::leaf_materials`]) blended by the group's leaves; for
    /// branches `[0, 1]`, naming [`FrameTopology::bark`].
    pub materials: [u32; 2],
    /// First index in [`MeshBuffers::indices`].
    pub first_index: u32,
    /// Number of indices (a multiple of 3).
    pub index_count: u32,
}

/// Triangle-list mesh buffers, in metres with Y up.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshBuffers {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Unit vertex normals.
    pub normals: Vec<Vec3>,
    /// Texture coordinates (glTF convention: `(0, 0)` is the image's top-left).
    pub uvs: Vec<Vec2>,
    /// Triangle indices, counter-clockwise seen from the front face.
    pub indices: Vec<u32>,
    /// Index ranges by material, in order, covering every index once.
    pub groups: Vec<MeshGroup>,
    /// Bounds of [`MeshBuffers::positions`] ([`Aabb::EMPTY`] when there are
    /// none), as glTF needs for POSITION accessors.
    pub bounds: Aabb,
}

impl Default for MeshBuffers {
    fn default() -> MeshBuffers {
        MeshBuffers {
            positions: Vec::new(),
            normals: Vec::new(),
            uvs: Vec::new(),
            indices: Vec::new(),
            groups: Vec::new(),
            bounds: Aabb::EMPTY,
        }
    }
}

impl MeshBuffers {
    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Whether there is nothing to draw.
    pub fn is_empty(&self) -> bool {
        self.indices.is_empty()
    }

    fn with_len(vertices: usize, indices: usize) -> MeshBuffers {
        MeshBuffers {
            positions: vec![Vec3::ZERO; vertices],
            normals: vec![Vec3::Y; vertices],
            uvs: vec![Vec2::ZERO; vertices],
            indices: Vec::with_capacity(indices),
            groups: Vec::new(),
            bounds: Aabb::EMPTY,
        }
    }
}

/// Checks that a frame has one finite position and one non-negative finite
/// radius per node (what branch meshing reads).
pub(crate) fn check_nodes(frame: &Frame, count: usize) -> Result<(), FrameMismatch> {
    if frame.positions.len() != count || frame.radii.len() != count {
        return Err(FrameMismatch(format!(
            "{} positions and {} radii for {} nodes",
            frame.positions.len(),
            frame.radii.len(),
            count
        )));
    }
    if let Some(i) = frame.positions.iter().position(|p| !p.is_finite()) {
        return Err(FrameMismatch(format!("position {i} is not finite")));
    }
    if let Some(i) = frame
        .radii
        .iter()
        .position(|r| !(r.is_finite() && *r >= 0.0))
    {
        return Err(FrameMismatch(format!(
            "radius {i} is negative or not finite"
        )));
    }
    Ok(())
}

pub(crate) fn to_u32(count: usize, what: &'static str) -> Result<u32, MeshError> {
    u32::try_from(count).map_err(|_| MeshError::TooLarge {
        what,
        count: count as u64,
    })
}

/// What is fixed about one strand's tube.
#[derive(Clone, Debug)]
struct StrandPlan {
    /// The strand's nodes are `BranchMesher::nodes[first_node..][..node_count]`.
    first_node: u32,
    node_count: u32,
    sides: u32,
    first_vertex: u32,
    /// Starts at another strand's node: first ring takes the child's radius
    /// and there is no base cap.
    child: bool,
    /// Index of the strand in the topology.
    strand: u32,
}

impl StrandPlan {
    fn vertex_count(&self) -> usize {
        (self.node_count as usize) * (self.sides as usize + 1) + 1 + usize::from(!self.child)
    }
}

/// Sweeps strands into tubes, frame after frame, with one set of buffers.
///
/// ```
/// use treemorph_gltf::mesh::{BranchMesher, MeshOptions};
/// use treemorph_tree::{Frame, FrameTopology};
/// # let tree = treemorph_gltf::sample::sample_tree(20);
/// let topology = FrameTopology::of_tree(&tree);
/// let frame = Frame::of_tree(&tree);
/// let mut mesher = BranchMesher::new(&topology, &frame.radii, &frame, &MeshOptions::default())?;
/// let mesh = mesher.mesh(&frame)?;
/// assert_eq!(mesh.normals.len(), mesh.positions.len());
/// # Ok::<(), treemorph_gltf::mesh::MeshError>(())
/// ```
#[derive(Clone, Debug)]
pub struct BranchMesher {
    plans: Vec<StrandPlan>,
    /// Plan indices where the parallel batches of [`BranchMesher::mesh`]
    /// start, then `plans.len()`: consecutive strands holding about
    /// [`BATCH_VERTICES`] vertices each, so a frame is split into enough
    /// pieces for every core without a task per strand.
    batches: Vec<u32>,
    nodes: Vec<NodeId>,
    node_count: usize,
    /// `(cos, sin)` tables: sides `s` starts at `trig_offsets[s]` and has
    /// `s + 1` entries with exact endpoints, so seam vertices coincide.
    trig: Vec<[f32; 2]>,
    trig_offsets: Vec<u32>,
    buffers: MeshBuffers,
}

impl BranchMesher {
    /// Plans the tubes of `topology`.
    ///
    /// `reference_radii` (one per node) fixes each strand's side count — pass
    /// the static tree's radii, or the per-node maximum over an animation.
    /// `uv_frame` fixes the bark texture coordinates (arc lengths and radii);
    /// pass the static tree's frame or the sequence's first frame. Strands
    /// with fewer than two nodes have no tube.
    pub fn new(
        topology: &FrameTopology,
        reference_radii: &[f32],
        uv_frame: &Frame,
        options: &MeshOptions,
    ) -> Result<BranchMesher, MeshError> {
        options.check()?;
        let count = topology.node_count();
        check_nodes(uv_frame, count)?;
        if reference_radii.len() != count {
            return Err(FrameMismatch(format!(
                "{} reference radii for {count} nodes",
                reference_radii.len()
            ))
            .into());
        }
        let reference = |id: NodeId| {
            let r = reference_radii[id as usize];
            if r.is_finite() { r.max(0.0) } else { 0.0 }
        };

        // The strand each node belongs to: the one holding the branch that
        // ends at it, or for start-only nodes (the root) the first strand
        // starting there.
        let strands = &topology.strands;
        let mut owner = vec![NONE; count];
        for (s, ids) in strands.iter().enumerate() {
            for (i, &id) in ids.iter().enumerate() {
                if id as usize >= count {
                    return Err(MeshError::StrandNodeOutOfRange {
                        strand: s,
                        node: id,
                        count,
                    });
                }
                if i > 0 && owner[id as usize] == NONE {
                    owner[id as usize] = s as u32;
                }
            }
        }
        let mut nodes = Vec::with_capacity(strands.total_points());
        let mut plans = Vec::with_capacity(strands.len());
        let mut thickest = 0.0f32;
        let mut strand_radius = Vec::with_capacity(strands.len());
        for (s, ids) in strands.iter().enumerate() {
            if ids.len() < 2 {
                continue;
            }
            let first = ids[0] as usize;
            if owner[first] == NONE {
                owner[first] = s as u32;
            }
            let child = owner[first] != s as u32;
            let skip = usize::from(child);
            let r = ids[skip..]
                .iter()
                .map(|&id| reference(id))
                .fold(0.0f32, f32::max);
            thickest = thickest.max(r);
            strand_radius.push(r);
            plans.push(StrandPlan {
                // Strand offsets are u32, so this cannot truncate.
                first_node: nodes.len() as u32,
                node_count: ids.len() as u32,
                sides: 0,
                first_vertex: 0,
                child,
                strand: s as u32,
            });
            nodes.extend_from_slice(ids);
        }
        let (lo, hi) = (options.min_sides, options.max_sides);
        let mut vertices = 0usize;
        let mut indices = 0usize;
        for (plan, r) in plans.iter_mut().zip(strand_radius) {
            let ratio = if thickest > 0.0 { r / thickest } else { 0.0 };
            plan.sides = lo + ((hi - lo) as f32 * ratio.sqrt()).round() as u32;
            plan.sides = plan.sides.clamp(lo, hi);
            plan.first_vertex = to_u32(vertices, "vertices")?;
            vertices += plan.vertex_count();
            let s = plan.sides as usize;
            indices +=
                (plan.node_count as usize - 1) * s * 6 + s * 3 * (1 + usize::from(!plan.child));
        }
        to_u32(vertices, "vertices")?;
        to_u32(indices, "indices")?;

        let mut trig = Vec::new();
        let mut trig_offsets = vec![0u32; hi as usize + 1];
        for sides in lo..=hi {
            trig_offsets[sides as usize] = trig.len() as u32;
            for j in 0..=sides {
                if j == 0 || j == sides {
                    trig.push([1.0, 0.0]);
                } else {
                    let (sin, cos) = (TAU * j as f32 / sides as f32).sin_cos();
                    trig.push([cos, sin]);
                }
            }
        }

        let mut batches = vec![0u32];
        let mut in_batch = 0usize;
        for (i, plan) in plans.iter().enumerate() {
            if in_batch >= BATCH_VERTICES {
                batches.push(i as u32);
                in_batch = 0;
            }
            in_batch += plan.vertex_count();
        }
        batches.push(plans.len() as u32);

        let mut mesher = BranchMesher {
            plans,
            batches,
            nodes,
            node_count: count,
            trig,
            trig_offsets,
            buffers: MeshBuffers::with_len(vertices, indices),
        };
        mesher.write_indices();
        mesher.write_uvs(uv_frame, options.min_uv_radius);
        mesher.buffers.groups.push(MeshGroup {
            materials: [0, 1],
            first_index: 0,
            index_count: mesher.buffers.indices.len() as u32,
        });
        Ok(mesher)
    }

    /// Number of vertices of every frame's mesh.
    pub fn vertex_count(&self) -> usize {
        self.buffers.positions.len()
    }

    /// Recomputes the bark texture coordinates from `uv_frame` (as `new`
    /// does), for callers that learn the sequence's first frame only after
    /// planning the meshes.
    pub fn set_uv_frame(
        &mut self,
        uv_frame: &Frame,
        options: &MeshOptions,
    ) -> Result<(), MeshError> {
        options.check()?;
        check_nodes(uv_frame, self.node_count)?;
        self.write_uvs(uv_frame, options.min_uv_radius);
        Ok(())
    }

    /// Per vertex: the strand whose tube it belongs to and the node its
    /// ring is at (the tip's apex at the last node, the base cap's centre
    /// at the first). What a skeleton binds the bark to.
    pub fn vertex_owners(&self) -> Vec<(u32, NodeId)> {
        let mut out = Vec::with_capacity(self.vertex_count());
        for plan in &self.plans {
            let a = plan.first_node as usize;
            let ids = &self.nodes[a..a + plan.node_count as usize];
            let stride = plan.sides as usize + 1;
            out.extend(
                ids.iter()
                    .flat_map(|&id| std::iter::repeat_n((plan.strand, id), stride)),
            );
            out.push((plan.strand, ids[ids.len() - 1]));
            if !plan.child {
                out.push((plan.strand, ids[0]));
            }
        }
        out
    }

    /// Number of strands that have a tube.
    pub fn tube_count(&self) -> usize {
        self.plans.len()
    }

    /// The buffers of the last frame meshed (positions and normals are zero
    /// and `+Y` before the first).
    pub fn buffers(&self) -> &MeshBuffers {
        &self.buffers
    }

    /// Meshes one frame: overwrites positions, normals and bounds.
    ///
    /// Strands are swept in parallel (rayon) in batches of consecutive
    /// strands; each batch writes its own slice of the buffers, so the
    /// result does not depend on the number of threads.
    pub fn mesh(&mut self, frame: &Frame) -> Result<&MeshBuffers, MeshError> {
        check_nodes(frame, self.node_count)?;
        let sweep = Sweep {
            plans: &self.plans,
            nodes: &self.nodes,
            trig: &self.trig,
            trig_offsets: &self.trig_offsets,
            frame,
        };
        let buffers = &mut self.buffers;
        let bounds = if self.plans.is_empty() {
            Aabb::EMPTY
        } else {
            sweep.batches(&self.batches, &mut buffers.positions, &mut buffers.normals)
        };
        buffers.bounds = bounds;
        Ok(&self.buffers)
    }

    /// The radius used for ring `i` of a strand.
    fn ring_radius(plan: &StrandPlan, ids: &[NodeId], radii: &[f32], i: usize) -> f32 {
        let r = radii[ids[i] as usize];
        if i == 0 && plan.child {
            r.min(radii[ids[1] as usize])
        } else {
            r
        }
    }

    fn write_indices(&mut self) {
        let out = &mut self.buffers.indices;
        for plan in &self.plans {
            let s = plan.sides;
            let stride = s + 1;
            let base = plan.first_vertex;
            for i in 0..plan.node_count - 1 {
                for j in 0..s {
                    let a = base + i * stride + j;
                    let (b, c) = (a + 1, a + stride);
                    let d = c + 1;
                    out.extend_from_slice(&[a, b, d, a, d, c]);
                }
            }
            let last_ring = base + (plan.node_count - 1) * stride;
            let apex = base + plan.node_count * stride;
            for j in 0..s {
                out.extend_from_slice(&[last_ring + j, last_ring + j + 1, apex]);
            }
            if !plan.child {
                let centre = apex + 1;
                for j in 0..s {
                    out.extend_from_slice(&[base + j + 1, base + j, centre]);
                }
            }
        }
    }

    fn write_uvs(&mut self, frame: &Frame, min_uv_radius: f32) {
        for plan in &self.plans {
            let a = plan.first_node as usize;
            let ids = &self.nodes[a..a + plan.node_count as usize];
            let stride = plan.sides as usize + 1;
            let base = plan.first_vertex as usize;
            let uvs = &mut self.buffers.uvs;
            let mut v = 0.0f32;
            let mut prev = (frame.positions[ids[0] as usize], 0.0f32);
            for i in 0..ids.len() {
                let p = frame.positions[ids[i] as usize];
                let r = Self::ring_radius(plan, ids, &frame.radii, i);
                if i > 0 {
                    let circumference = TAU * (0.5 * (prev.1 + r)).max(min_uv_radius);
                    v += p.distance(prev.0) / circumference;
                }
                prev = (p, r);
                for j in 0..stride {
                    uvs[base + i * stride + j] = Vec2::new(j as f32 / plan.sides as f32, v);
                }
            }
            let tip_v = v + prev.1 / (TAU * prev.1.max(min_uv_radius));
            let apex = base + ids.len() * stride;
            uvs[apex] = Vec2::new(0.5, tip_v);
            if !plan.child {
                uvs[apex + 1] = Vec2::new(0.5, 0.0);
            }
        }
    }
}

/// Vertices per parallel batch of [`BranchMesher::mesh`]: large enough that
/// scheduling costs nothing next to the work, small enough that a 20,000-
/// chain tree splits into dozens of batches for work stealing.
const BATCH_VERTICES: usize = 16_384;

/// The bounds of `points`, exact (the min and max of the stored floats, as
/// glTF POSITION accessors need), in a form that vectorises: twelve lanes
/// (four points) of plain comparisons, which finite input allows.
pub(crate) fn bounds_of(points: &[Vec3]) -> Aabb {
    #[inline(always)]
    fn lanes(p: &[Vec3]) -> [f32; 12] {
        [
            p[0].x, p[0].y, p[0].z, p[1].x, p[1].y, p[1].z, p[2].x, p[2].y, p[2].z, p[3].x, p[3].y,
            p[3].z,
        ]
    }
    let mut lo = [f32::INFINITY; 12];
    let mut hi = [f32::NEG_INFINITY; 12];
    let chunks = points.chunks_exact(4);
    let rest = chunks.remainder();
    for c in chunks {
        let v = lanes(c);
        for i in 0..12 {
            lo[i] = if v[i] < lo[i] { v[i] } else { lo[i] };
            hi[i] = if v[i] > hi[i] { v[i] } else { hi[i] };
        }
    }
    let mut bounds = Aabb::EMPTY;
    for k in 0..4 {
        let (a, b) = (
            Vec3::new(lo[3 * k], lo[3 * k + 1], lo[3 * k + 2]),
            Vec3::new(hi[3 * k], hi[3 * k + 1], hi[3 * k + 2]),
        );
        if a.x <= b.x {
            bounds = bounds.union(Aabb { min: a, max: b });
        }
    }
    rest.iter().fold(bounds, |b, &p| b.with_point(p))
}

/// `v` rotated by the shortest arc taking unit vector `from` to unit vector
/// `to` (Rodrigues' formula with the unnormalised axis `from × to`: no
/// square root or trigonometry, which matters once per ring).
#[inline]
fn rotate_arc(from: Vec3, to: Vec3, v: Vec3) -> Vec3 {
    let c = from.dot(to);
    if c > -0.999_9 {
        let k = from.cross(to);
        v * c + k.cross(v) + k * (k.dot(v) / (1.0 + c))
    } else {
        // Nearly opposite: any half-turn axis will do; glam picks one.
        Quat::from_rotation_arc(from, to) * v
    }
}

/// What sweeping a frame reads; shared by the parallel batches.
#[derive(Clone, Copy)]
struct Sweep<'a> {
    plans: &'a [StrandPlan],
    nodes: &'a [NodeId],
    trig: &'a [[f32; 2]],
    trig_offsets: &'a [u32],
    frame: &'a Frame,
}

impl Sweep<'_> {
    /// Sweeps the strands of batches `bounds[0]..bounds[last]` (plan
    /// indices) into `positions` and `normals`, which start at the first
    /// plan's first vertex; splits in halves with `rayon::join` (no
    /// allocation) and returns the bounds of the written vertices.
    fn batches(&self, batches: &[u32], positions: &mut [Vec3], normals: &mut [Vec3]) -> Aabb {
        if batches.len() <= 2 {
            let (lo, hi) = (batches[0] as usize, batches[batches.len() - 1] as usize);
            let base = self.plans[lo].first_vertex as usize;
            let mut bounds = Aabb::EMPTY;
            for plan in &self.plans[lo..hi] {
                let start = plan.first_vertex as usize - base;
                let end = start + plan.vertex_count();
                bounds = bounds.union(self.strand(
                    plan,
                    &mut positions[start..end],
                    &mut normals[start..end],
                ));
            }
            return bounds;
        }
        let mid = batches.len() / 2;
        let split = (self.plans[batches[mid] as usize].first_vertex
            - self.plans[batches[0] as usize].first_vertex) as usize;
        let (p0, p1) = positions.split_at_mut(split);
        let (n0, n1) = normals.split_at_mut(split);
        let (a, b) = rayon::join(
            || self.batches(&batches[..=mid], p0, n0),
            || self.batches(&batches[mid..], p1, n1),
        );
        a.union(b)
    }

    /// Sweeps one strand into its own vertices (`positions` and `normals`
    /// hold exactly the plan's vertex count).
    fn strand(&self, plan: &StrandPlan, positions: &mut [Vec3], normals: &mut [Vec3]) -> Aabb {
        let a = plan.first_node as usize;
        let ids = &self.nodes[a..a + plan.node_count as usize];
        let k = ids.len();
        let sides = plan.sides as usize;
        let stride = sides + 1;
        let t0 = self.trig_offsets[sides] as usize;
        let trig = &self.trig[t0..t0 + stride];
        let frame = self.frame;
        let at = |i: usize| frame.positions[ids[i] as usize];

        // Direction used where the strand defines none (zero-length
        // segments): the first real segment direction, else up.
        let fallback = (0..k - 1)
            .find_map(|i| (at(i + 1) - at(i)).try_normalize())
            .unwrap_or(Vec3::Y);
        // Two passes per run of nodes: first the tangents, whose square
        // roots do not depend on each other and so overlap in the CPU;
        // then the frames, whose ring-to-ring dependency chain is kept
        // free of square roots and divisions but one.
        const RUN: usize = 32;
        let mut tangents = [Vec3::ZERO; RUN];
        let mut incoming: Option<Vec3> = None;
        let mut tangent_prev = fallback;
        let mut normal = Vec3::X;
        let mut last = (Vec3::ZERO, 0.0f32);
        let (mut lo, mut hi) = (Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
        let mut start = 0;
        while start < k {
            let n = (k - start).min(RUN);
            for (j, tangent) in tangents[..n].iter_mut().enumerate() {
                let i = start + j;
                let outgoing = (i + 1 < k).then(|| {
                    (at(i + 1) - at(i))
                        .try_normalize()
                        .unwrap_or(incoming.unwrap_or(fallback))
                });
                *tangent = match (incoming, outgoing) {
                    (Some(a), Some(b)) => (a + b).try_normalize().unwrap_or(b),
                    (Some(a), None) => a,
                    (None, Some(b)) => b,
                    (None, None) => fallback,
                };
                incoming = outgoing;
            }
            for (j, &tangent) in tangents[..n].iter().enumerate() {
                let i = start + j;
                let point = at(i);
                let turned = if i == 0 {
                    rotate_arc(Vec3::Y, tangent, Vec3::X)
                } else {
                    rotate_arc(tangent_prev, tangent, normal)
                };
                // The rotated normal is already unit and perpendicular up
                // to rounding: project the rounding away and fix the length
                // with one Newton step of 1/√x; fall back where a
                // degenerate tangent left nothing to project.
                let projected = turned - tangent * turned.dot(tangent);
                let len2 = projected.length_squared();
                normal = if (len2 - 1.0).abs() < 0.01 {
                    projected * (1.5 - 0.5 * len2)
                } else {
                    projected
                        .try_normalize()
                        .unwrap_or_else(|| tangent.any_orthonormal_vector())
                };
                let binormal = tangent.cross(normal);
                let r = BranchMesher::ring_radius(plan, ids, &frame.radii, i);
                let ring = i * stride;
                let ring_positions = &mut positions[ring..ring + stride];
                let ring_normals = &mut normals[ring..ring + stride];
                // SIMD lanes (Vec3A) for the per-vertex work, bounds
                // included: plain min/max, as the vertices are finite.
                let (n4, b4, c4) = (
                    Vec3A::from(normal),
                    Vec3A::from(binormal),
                    Vec3A::from(point),
                );
                for ((p, nrm), &[cos, sin]) in ring_positions
                    .iter_mut()
                    .zip(ring_normals.iter_mut())
                    .zip(trig)
                {
                    let dir = n4 * cos + b4 * sin;
                    let v = c4 + dir * r;
                    lo = lo.min(v);
                    hi = hi.max(v);
                    *p = Vec3::from(v);
                    *nrm = Vec3::from(dir);
                }
                tangent_prev = tangent;
                last = (point, r);
            }
            start += n;
        }
        let apex = k * stride;
        let tip = last.0 + tangent_prev * last.1;
        positions[apex] = tip;
        normals[apex] = tangent_prev;
        let mut bounds = Aabb {
            min: Vec3::from(lo),
            max: Vec3::from(hi),
        }
        .with_point(tip);
        if !plan.child {
            // The first tangent, recomputed: the loop above moved on.
            let first = (at(1) - at(0)).try_normalize().unwrap_or(fallback);
            positions[apex + 1] = at(0);
            normals[apex + 1] = -first;
            bounds = bounds.with_point(at(0));
        }
        bounds
    }
}

/// Leaves per parallel batch of [`LeafMesher::mesh`].
const LEAF_BATCH: usize = 2048;

/// Turns leaves into quads or contour fans, frame after frame, with one set
/// of buffers.
#[derive(Clone, Debug)]
pub struct LeafMesher {
    shape: LeafShape,
    leaf_count: usize,
    /// Contour mode: per leaf material, its outline.
    contours: Vec<LeafContour>,
    /// Contour mode: per leaf material, its fan (centre, then rim), flat.
    fans: Vec<Vec2>,
    /// Contour mode: per leaf, its material pair.
    pairs: Vec<[u32; 2]>,
    buffers: MeshBuffers,
}

impl LeafMesher {
    /// Plans the leaves of `topology`: vertex layout, index buffer sorted by
    /// material pair, UVs. In [`LeafShape::Contour`] mode this extracts the
    /// outline of every leaf material's texture
    /// ([`LeafContour::of_material`]); a leaf's UVs are those of its first
    /// material's contour in every frame.
    pub fn new(topology: &FrameTopology, options: &MeshOptions) -> Result<LeafMesher, MeshError> {
        let shape = options.leaf_shape;
        if let LeafShape::Contour { points } = shape {
            crate::contour::check_points(points)
                .map_err(|e| MeshError::InvalidOptions(e.to_string()))?;
        }
        let n = topology.leaves.len();
        let materials = topology.leaf_materials.len();
        if let Some((leaf, l)) = topology
            .leaves
            .iter()
            .enumerate()
            .find(|(_, l)| l.materials.iter().any(|&m| m as usize >= materials))
        {
            return Err(MeshError::LeafMaterialOutOfRange {
                leaf,
                materials: l.materials,
                count: materials,
            });
        }
        let per_leaf = shape.vertices_per_leaf();
        let vertices = n.checked_mul(per_leaf).ok_or(MeshError::TooLarge {
            what: "vertices",
            count: u64::MAX,
        })?;
        to_u32(vertices, "vertices")?;
        let indices = n
            .checked_mul(shape.indices_per_leaf())
            .ok_or(MeshError::TooLarge {
                what: "indices",
                count: u64::MAX,
            })?;
        to_u32(indices, "indices")?;
        let mut buffers = MeshBuffers::with_len(vertices, indices);

        let contours: Vec<LeafContour> = match shape {
            LeafShape::Quad => Vec::new(),
            LeafShape::Contour { points } => topology
                .leaf_materials
                .par_iter()
                .map(|m| LeafContour::of_material(m, points))
                .collect::<Result<_, _>>()
                .map_err(|e| MeshError::InvalidOptions(e.to_string()))?,
        };
        let fans: Vec<Vec2> = contours.iter().flat_map(LeafContour::fan).collect();
        let pairs = match shape {
            LeafShape::Quad => Vec::new(),
            _ => topology.leaves.iter().map(|l| l.materials).collect(),
        };

        // Group leaves by material pair, keeping topology order within a
        // group; groups appear in order of their smallest pair.
        let mut order: Vec<u32> = (0..n as u32).collect();
        order.sort_by_key(|&i| topology.leaves[i as usize].materials);
        let mut group: Option<MeshGroup> = None;
        let per = per_leaf as u32;
        for &leaf in &order {
            let materials = topology.leaves[leaf as usize].materials;
            match &mut group {
                Some(g) if g.materials == materials => {}
                _ => {
                    if let Some(g) = group.take() {
                        buffers.groups.push(g);
                    }
                    group = Some(MeshGroup {
                        materials,
                        first_index: buffers.indices.len() as u32,
                        index_count: 0,
                    });
                }
            }
            let v = leaf * per;
            match shape {
                LeafShape::Quad => {
                    buffers
                        .indices
                        .extend_from_slice(&[v, v + 1, v + 2, v, v + 2, v + 3])
                }
                LeafShape::Contour { points } => {
                    for k in 0..points {
                        buffers.indices.extend_from_slice(&[
                            v,
                            v + 1 + k,
                            v + 1 + (k + 1) % points,
                        ]);
                    }
                }
            }
            if let Some(g) = &mut group {
                g.index_count += shape.indices_per_leaf() as u32;
            }
        }
        buffers.groups.extend(group);
        match shape {
            LeafShape::Quad => {
                for quad in buffers.uvs.chunks_exact_mut(4) {
                    // Upright images: the base (vertices 0, 1) samples the
                    // bottom row, which is glTF's v = 1.
                    quad.copy_from_slice(&[
                        Vec2::new(0.0, 1.0),
                        Vec2::new(1.0, 1.0),
                        Vec2::new(1.0, 0.0),
                        Vec2::new(0.0, 0.0),
                    ]);
                }
            }
            LeafShape::Contour { .. } => {
                for (uvs, leaf) in buffers.uvs.chunks_exact_mut(per_leaf).zip(&topology.leaves) {
                    let fan = &fans[leaf.materials[0] as usize * per_leaf..][..per_leaf];
                    for (uv, &p) in uvs.iter_mut().zip(fan) {
                        *uv = LeafContour::uv(p);
                    }
                }
            }
        }
        Ok(LeafMesher {
            shape,
            leaf_count: n,
            contours,
            fans,
            pairs,
            buffers,
        })
    }

    /// The leaf shape.
    pub fn shape(&self) -> LeafShape {
        self.shape
    }

    /// Contour mode: the outline of every leaf material, indexed like
    /// [`FrameTopology::leaf_materials`]; empty for quads.
    pub fn contours(&self) -> &[LeafContour] {
        &self.contours
    }

    /// Number of vertices of every frame's mesh.
    pub fn vertex_count(&self) -> usize {
        self.buffers.positions.len()
    }

    /// The buffers of the last frame meshed.
    pub fn buffers(&self) -> &MeshBuffers {
        &self.buffers
    }

    /// Meshes one frame's leaves: overwrites positions, normals and bounds.
    ///
    /// Leaves are meshed in parallel (rayon) in batches of consecutive
    /// leaves. In contour mode a leaf's blend (clamped to [0, 1]) morphs
    /// its outline from its first material's contour to its second's.
    pub fn mesh(&mut self, frame: &Frame) -> Result<&MeshBuffers, MeshError> {
        if frame.leaves.len() != self.leaf_count {
            return Err(FrameMismatch(format!(
                "{} leaves for {} in the topology",
                frame.leaves.len(),
                self.leaf_count
            ))
            .into());
        }
        if let Some(i) = frame.leaves.iter().position(|l| {
            !(l.anchor.is_finite()
                && l.orientation.is_finite()
                && l.width.is_finite()
                && l.height.is_finite())
        }) {
            return Err(FrameMismatch(format!("leaf {i} has a non-finite number")).into());
        }
        let per_leaf = self.shape.vertices_per_leaf();
        let (fans, pairs) = (&self.fans, &self.pairs);
        let buffers = &mut self.buffers;
        let bounds = buffers
            .positions
            .par_chunks_mut(per_leaf * LEAF_BATCH)
            .zip(buffers.normals.par_chunks_mut(per_leaf * LEAF_BATCH))
            .zip(frame.leaves.par_chunks(LEAF_BATCH))
            .enumerate()
            .map(|(batch, ((positions, normals), leaves))| {
                let chunks = positions
                    .chunks_exact_mut(per_leaf)
                    .zip(normals.chunks_exact_mut(per_leaf))
                    .zip(leaves);
                // SIMD lanes (Vec3A) for the per-vertex work, bounds
                // included: plain min/max, as the vertices are finite.
                let (mut lo, mut hi) =
                    (Vec3A::splat(f32::INFINITY), Vec3A::splat(f32::NEG_INFINITY));
                for (i, ((vertices, leaf_normals), leaf)) in chunks.enumerate() {
                    // Unit rotation even for a sloppy quaternion; identity
                    // for zero. Its matrix gives all three leaf axes.
                    let q = Vec4::from(leaf.orientation)
                        .try_normalize()
                        .map_or(Quat::IDENTITY, Quat::from_vec4);
                    let m = Mat3A::from_quat(q);
                    let across = m.x_axis * leaf.width.max(0.0);
                    let up = m.y_axis * leaf.height.max(0.0);
                    let a = Vec3A::from(leaf.anchor);
                    let mut put = |v: &mut Vec3, p: Vec3A| {
                        lo = lo.min(p);
                        hi = hi.max(p);
                        *v = Vec3::from(p);
                    };
                    if pairs.is_empty() {
                        let half = across * 0.5;
                        let corners = [a - half, a + half, a + half + up, a - half + up];
                        for (v, p) in vertices.iter_mut().zip(corners) {
                            put(v, p);
                        }
                    } else {
                        let [m0, m1] = pairs[batch * LEAF_BATCH + i];
                        let from = &fans[m0 as usize * per_leaf..][..per_leaf];
                        let s = if leaf.blend.is_finite() {
                            leaf.blend.clamp(0.0, 1.0)
                        } else {
                            0.0
                        };
                        if m0 == m1 || s == 0.0 {
                            for (v, p) in vertices.iter_mut().zip(from) {
                                put(v, a + across * p.x + up * p.y);
                            }
                        } else {
                            let to = &fans[m1 as usize * per_leaf..][..per_leaf];
                            for ((v, p), t) in vertices.iter_mut().zip(from).zip(to) {
                                let p = p.lerp(*t, s);
                                put(v, a + across * p.x + up * p.y);
                            }
                        }
                    }
                    leaf_normals.fill(Vec3::from(m.z_axis));
                }
                if lo.x <= hi.x {
                    Aabb {
                        min: Vec3::from(lo),
                        max: Vec3::from(hi),
                    }
                } else {
                    Aabb::EMPTY
                }
            })
            .reduce(|| Aabb::EMPTY, Aabb::union);
        buffers.bounds = bounds;
        Ok(&self.buffers)
    }
}

#[cfg(test)]
#[path = "mesh_tests.rs"]
mod tests;
