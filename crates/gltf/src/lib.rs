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
//!   textured double-sided quad. Vertex and index counts depend on the
//!   topology only, so every frame of a sequence has the same layout — what
//!   morph targets and the delta stream need.
//! - [`export`] — [`export_glb`] writes a static tree as glTF 2.0 binary
//!   with nodes `branches` and `leaves`, and embeds the tree itself so
//!   [`read_embedded_tree`] gives it back bit-identical.
//! - [`glb`] — the GLB container, read with every length bounds-checked.
//! - [`sample`] — a deterministic synthetic tree for tests and benchmarks.
//! - [`welded`] — branches as one continuous, watertight surface
//!   ([`BranchMeshMode::Welded`]), as many modelling tools write them.
//!
//! The papers say nothing about meshing beyond "textured quads" for leaves;
//! the choices made here (side counts, joins, caps, UV scaling) are
//! documented in [`mesh`]. Every GLB written here is meant to pass the
//! Khronos glTF validator with no errors or warnings
//! (`tools/gltf-validate/validate.mjs`).

pub mod export;
pub mod glb;
pub mod mesh;
pub mod sample;
pub mod welded;

pub use export::{
    BranchMeshMode, ExportError, ExportOptions, ReadError, export_glb, read_embedded_tree,
};
pub use glb::{Glb, GlbError};
pub use mesh::{
    BranchMesher, LeafMesher, LeafShape, MeshBuffers, MeshError, MeshGroup, MeshOptions,
};
