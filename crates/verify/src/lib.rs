//! Output-level plausibility checks: do the meshes we write look like a
//! tree whose leaves grow on its branches and whose branches hold
//! together?
//!
//! The pipelines' own metrics (e.g. `floating_leaves` in a job's
//! `metrics.json`) count what the *construction* of a frame says: a leaf
//! is attached when the builder gave it a node. That says nothing about
//! the geometry finally written — a leaf anchored to a node can still hang
//! in the air when the importer placed the node off the wood, when
//! re-meshing shrank a radius, or when a deformation moved the leaf and
//! the branch apart. This crate measures **the triangles we write** and
//! nothing else, so it can check any frame — in-process on the very
//! buffers a [`FrameGlbWriter`](treemorph_gltf::frame_glb::FrameGlbWriter)
//! encodes ([`MeshView::of_frame_meshes`]), or on a GLB read back from disk
//! ([`read_glb`]), ours or a third-party generator's.
//!
//! # What is measured
//! Let `H` be the frame's height (extent along Y of all its vertices).
//!
//! - **Floating leaves.** A leaf (a group of leaf-mesh vertices,
//!   [`LeafLayout`]) of size `s` — the largest distance between two of its
//!   vertices — floats when its *nearest vertex* is farther than
//!   `s / 2 + leaf_slack · H` (default slack 0.5 %) from the branch
//!   surface: the union of the branch mesh's triangles of non-zero area.
//!   Distances are exact point-to-triangle distances (Ericson, *Real-Time
//!   Collision Detection*, §5.1.5); no surface sampling. Zero-size leaves
//!   are not drawn and are skipped; zero-area triangles (a strand of zero
//!   radius, not grown yet or wilted) are not surface, so a leaf on an
//!   invisible twig floats, as it looks.
//! - **Floating branch pieces.** A piece is a connected component of the
//!   branch mesh by shared vertex indices (one tube per strand for our
//!   tube soup; one piece for a welded bark). Two pieces *come within* `d`
//!   of each other when the minimum distance between their surfaces — over
//!   all pairs of their visible triangles, the exact triangle–triangle
//!   distance, zero where they cross — is at most `d`. A piece other than
//!   the **root** piece (the one holding the lowest vertex of a visible
//!   triangle) floats when it comes within `branch_reach · H` (default 2 %)
//!   of no other piece. A piece that touches nothing but a floating piece
//!   is not floating by this test: it measures gaps, not connectivity to
//!   the root. A piece sealed inside another without touching its surface
//!   counts as floating when farther than the reach from it.
//! - **Crossings** ([`CrossingMeter`]): pairs of branch pieces whose tubes
//!   pass through each other in a frame of a sequence but at neither of
//!   its ends, from the tubes' capsules (see the `crossings` module).
//!
//! # How
//! [`Plausibility`] is a reusable context (lyon-style): it keeps its
//! buffers between frames and relabels components only when an index
//! buffer changes (never, within one sequence). Sufficient tests come
//! first and settle most leaves and pieces of a frame: what proved a leaf
//! attached or a piece near on the last frame (a vertex and a triangle, or
//! two triangles) is tried again, then the piece that proof named and the
//! pieces its neighbours' proofs name (leaves are numbered along their
//! twigs, strands so that siblings are neighbours). What they leave open
//! is answered exhaustively: on a sequence's frames, a few hundred
//! questions at most, in one pass over the visible triangles (the
//! `sweep` module: the questions go into a small grid and a coarse
//! bitmap, and each triangle visits those its bounds meet); on a first
//! frame, where everything is open, by range queries on a spatial hash of
//! all visible triangles (each triangle in every cell its bounds overlap),
//! which stop at the first hit. A piece none of whose base vertices comes
//! within reach of another piece goes to the exact triangle–triangle
//! search. So the counts are those of the definitions above, and a
//! sequence's later frames cost a few milliseconds on a 5,000-branch tree
//! (`treemorph bench --filter "output check"`).
//! Only floating leaves get their exact gap, through a k-d tree (kiddo)
//! over triangle centroids built on demand.
//!
//! ```
//! use treemorph_gltf::frame_glb::{FrameGlbOptions, FrameGlbWriter};
//! use treemorph_tree::{Frame, FrameTopology};
//! use treemorph_verify::{MeshView, Plausibility, PlausibilityOptions};
//! # let tree = treemorph_gltf::sample::sample_tree(200);
//! let topology = FrameTopology::of_tree(&tree);
//! let frame = Frame::of_tree(&tree);
//! let mut writer = FrameGlbWriter::new(&topology, &frame.radii, &FrameGlbOptions::default())?;
//! let mut check = Plausibility::new();
//! let _glb = writer.write(&frame)?; // `writer.meshes()` now holds its geometry
//! let report = check.check(&MeshView::of_frame_meshes(writer.meshes()), &PlausibilityOptions::default())?;
//! assert!(report.leaves > 0);
//! assert_eq!(report.floating_leaves, 0);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod geometry;
pub mod glb;
pub mod plausibility;
mod sweep;

pub use glb::{GlbMeshes, ReadGlbError, read_glb};
pub use plausibility::{
    FloatingLeaf, FloatingPiece, Hints, LeafLayout, MeshView, Plausibility, PlausibilityOptions,
    Report, VerifyError,
};
pub use treemorph_tree::crossings::{self, CrossingMeter, SiblingCrossings};

#[cfg(test)]
mod tests;
