//! The tree model every treemorph stage works on.
//!
//! A [`Tree`] is a **skeleton** — a rooted tree of [`Node`]s with positions in
//! metres (Y up) and radii — plus **billboard leaves** ([`Leaf`]) and
//! [`Materials`] (bark colour or texture, leaf textures as PNG with alpha).
//! Trees are built with [`Tree::new`], which validates and canonicalises the
//! parts; a `Tree` value is always valid ([`InvalidTree`] lists what is
//! refused and why).
//!
//! The crate is synchronous and does no I/O: formats are read from and written
//! to byte slices ([`json`]).
//!
//! # Glossary
//! The two papers treemorph implements (Wang et al., *Topologically consistent
//! leafy tree morphing*, CAVW 2017; Wang et al., *Sketch-based shape-preserving
//! tree animations*, CAVW 2018) give the domain language used across the
//! workspace:
//!
//! - **node** — a skeleton point with a radius. Node 0 is the **root**.
//! - **branch** — the skeleton edge from a node's parent to the node; it is
//!   named by its child node's id, so a tree with `n` nodes has `n - 1`
//!   branches and the root carries none.
//! - **order** — the hybrid Gravelius/Weibull branch order, 1 at the root
//!   (morphing paper Eq. 1–2).
//! - **chain** — a maximal run of consecutive branches of one order.
//! - **chain group** — chains of one order growing at one location; its
//!   **branching pattern** is *alternate* (1 chain), *opposite* (2 chains
//!   about 180° apart) or *whorled* (otherwise) ([`BranchingPattern`]).
//! - **BPTT** — the branching-pattern-aware topology tree whose nodes are
//!   chain groups.
//! - **lobes** — leaf clusters: the **inner lobe** (IL, a chain's own
//!   leaves), the **outer lobe** (OL, the leaves over a chain's whole
//!   substructure) and the **group outer lobe** (GOL, the union of a group's
//!   OLs). The root group's GOL is the **crown**.
//! - **cage**, **multiscale cage tree** (MCT) — lobe silhouettes used as
//!   deformation cages by the sketch pipeline.
//! - **grow / wilt / split / merge / morph** — the operations that carry a
//!   chain from the source tree to the target tree.
//! - **frame** — one in-between tree of an animation, in a **union topology**
//!   shared by every frame of the sequence ([`frame`]). A frame's branches
//!   **cross** when their tubes pass through each other there and at
//!   neither end of the sequence ([`crossings`], with the spatial hash in
//!   [`grid`]): the morph planner and the output checks count them
//!   alike.
//!
//! # Leaves
//! A leaf is the papers' billboard septuple: the branch it grows on, a
//! parametric position `t` along that branch, an offset from the branch axis
//! to the leaf's **anchor** (where the petiole meets the bark), width,
//! height, an orientation quaternion and a material. In the leaf's local
//! frame the blade spans `x ∈ [-width/2, width/2]`, `y ∈ [0, height]` (base
//! to tip) and faces `+z`. Leaf images are drawn upright: the blade's base is
//! the image's bottom row and its tip the top row (in glTF texture
//! coordinates, where `v = 0` is the top row, the base is at `v = 1`).

mod bounds;
pub mod crossings;
pub mod frame;
pub mod geom;
pub mod grid;
pub mod json;
mod model;
mod texture;
pub mod timing;
mod validate;

pub use bounds::Aabb;
pub use frame::{
    Frame, FrameLeaf, FrameLeafTopology, FrameTopology, JumpMeter, Strands, jump_ratio,
};
pub use model::{
    Bark, BranchingPattern, GroundTruth, GroundTruthGroup, Leaf, LeafMaterial, Materials, Node,
    NodeId, Skeleton, Tree, TreeParts, TreeStats,
};
pub use texture::{RgbaImage, Texture, TextureError};
pub use validate::{Field, InvalidTree, Limits, SizeKind};

pub use glam;
