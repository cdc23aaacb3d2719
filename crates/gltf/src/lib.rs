//! Meshes and glTF output: the output encoder at the end of every treemorph
//! pipeline.
//!
//! The stage takes trees and frames in the **union topology** of
//! [`treemorph_tree::frame`] ([`FrameTopology`](treemorph_tree::FrameTopology)
//! plus one [`Frame`](treemorph_tree::Frame) per in-between tree) and
//! returns triangle meshes and GLB files:
//!
//! - [`mesh`] — [`BranchMesher`] sweeps each strand into a generalised
//!   cylinder with parallel-transport frames; [`LeafMesher`] turns each
//!   billboard leaf (the papers' septuple, morphing paper §4.3) into a
//!   textured double-sided quad, or into its texture's outline
//!   ([`LeafShape::Contour`]). Vertex and index counts depend on the
//!   topology only, so every frame of a sequence has the same layout — what
//!   morph targets and the delta stream need. Both mesh a frame in
//!   parallel (rayon) and allocate nothing after their constructor.
//! - [`contour`] — leaf outlines from texture alpha, resampled to a fixed
//!   point count with a consistent parameterisation, so leaves of two
//!   shapes morph point by point (the morphing paper's "interpolation of
//!   leaves, including shapes and textures"); texture warps and blends
//!   between two outlines.
//!
//! Frame sequences (the morph and sketch pipelines' output) have three
//! encoders, all reusable context objects built from the
//! [`FrameTopology`](treemorph_tree::FrameTopology), the per-node maximum
//! radius over the sequence ([`frames::max_radii`]) and options:
//!
//! - [`frame_glb`] — [`FrameGlbWriter`](frame_glb::FrameGlbWriter): one
//!   standalone GLB per frame, leaves with morphed outlines and blended
//!   textures, bark blended.
//! - [`animated`] — [`AnimatedGlbBuilder`](animated::AnimatedGlbBuilder):
//!   one GLB whose morph targets are keyframes, played by any glTF viewer;
//!   float, `KHR_mesh_quantization` or `EXT_meshopt_compression`.
//! - [`basis`] — [`BasisGlbBuilder`](basis::BasisGlbBuilder): one GLB
//!   whose few morph targets are the motion's principal displacements,
//!   with per-frame weights; the same encodings.
//! - [`stream`] — [`DeltaStreamWriter`](stream::DeltaStreamWriter): the
//!   binary delta stream of [`treemorph_api::delta`], frame by frame.
//! - [`frames`] — what they share: [`EncodeError`](frames::EncodeError),
//!   [`FrameMeshes`](frames::FrameMeshes) and blended materials.
//! - [`bench`](mod@bench) — a swaying synthetic sequence and the timing figures of all
//!   of the above, for `treemorph bench`.
//! - [`export`] — [`export_glb`] writes a static tree as glTF 2.0 binary
//!   with nodes `branches` and `leaves`, and embeds the tree itself so
//!   [`read_embedded_tree`] gives it back bit-identical.
//! - [`glb`] — the GLB container, read with every length bounds-checked.
//! - [`gl`] — the numeric glTF enums (component types, targets, modes),
//!   shared with the importer.
//! - [`sample`] — a deterministic synthetic tree for tests and benchmarks.
//! - [`welded`] — branches as one continuous, watertight surface
//!   ([`BranchMeshMode::Welded`]), as many modelling tools write them.
//!
//! The papers say nothing about meshing beyond "textured quads" for leaves;
//! the choices made here (side counts, joins, caps, UV scaling) are
//! documented in [`mesh`], [`contour`] and [`animated`]. Every GLB written
//! here passes the Khronos glTF validator with no errors or warnings
//! (`tools/gltf-validate/validate.mjs`, the crate's ignored `validator`
//! test), except that the validator cannot look inside
//! `EXT_meshopt_compression` (the unit tests decode it with meshoptimizer);
//! `tools/render/check-animated.mjs` checks that three.js plays the
//! animated GLBs as written (the ignored `threejs` unit test).

pub mod animated;
pub mod basis;
pub mod bench;
pub mod contour;
mod doc;
pub mod export;
pub mod frame_glb;
pub mod frames;
pub mod gl;
pub mod glb;
pub mod mesh;
pub mod sample;
pub mod stream;
pub mod welded;

#[cfg(test)]
mod test_support;

pub use export::{
    BranchMeshMode, ExportError, ExportOptions, ReadError, export_glb, read_embedded_tree,
};
pub use glb::{Glb, GlbError};
pub use mesh::{
    BranchMesher, LeafMesher, LeafShape, MeshBuffers, MeshError, MeshGroup, MeshOptions,
};
