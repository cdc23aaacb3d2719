//! Importing third-party tree meshes: GLB or glTF in, a
//! [`treemorph_tree::Tree`] out.
//!
//! Studios upload trees made in other tools: a branch mesh plus leaves drawn
//! as alpha-textured quads, with no skeleton. [`import`] turns such a file
//! into the tree model every treemorph stage works on — a skeleton of nodes
//! with radii, and billboard leaves (the papers' septuple: branch, position,
//! width, height, orientation, texture) — and reports how it did
//! ([`ImportReport`]). A GLB written by treemorph itself carries the exact
//! tree ([`treemorph_gltf::read_embedded_tree`]); it is used as is unless
//! [`ImportOptions::ignore_embedded_tree`] is set.
//!
//! # Stages
//! 1. **Reading** (module `read`): GLB or glTF JSON (`data:` URIs only;
//!    external URIs are refused), the default scene's node graph with
//!    matrix or TRS transforms (a node reached twice — a cycle or two
//!    parents — is an error), every mesh and primitive, indexed or not,
//!    `u8`/`u16`/`u32` indices, float or normalised-integer positions and
//!    UVs (KHR_mesh_quantization), sparse accessors, triangle lists, strips
//!    and fans (points and lines are skipped with a warning),
//!    KHR_texture_transform on the base colour texture. The JSON is parsed
//!    into typed structures (unknown members are skipped without
//!    allocating; arrays hold at most 2¹⁸ elements) and accessors are read
//!    by our own reader: every offset, stride, count and index is checked
//!    against the bytes present before it is used, and nothing is allocated
//!    by a declared size before that check and the [limits](ImportOptions).
//!    We do not use the `gltf` crate here: its reader can panic on
//!    malformed accessors and it refuses files that *require* extensions it
//!    does not know, even harmless ones.
//! 2. **Foliage or wood** ([`classify`]): by name overrides, alpha mode,
//!    cut-out textures, or many small flat pieces.
//! 3. **Leaves** ([`leaves`]): one billboard per connected blade (crossed
//!    and double-sided quads count once), frame from the texture
//!    coordinates, PNG or JPEG texture (JPEG decoded with `jpeg-decoder` and
//!    re-encoded as PNG; atlas regions cropped). Zero-area blades are
//!    skipped and counted ([`ImportReport::skipped_leaves`]), not errors: a
//!    degenerate quad among thousands should not sink a file.
//! 4. **Skeleton**: the wood is welded by position and split into connected
//!    components. A component that is a simple tube — every branch a
//!    separate tube, a *tube soup* — gives its axis from its rings (module
//!    `tube`: breadth-first levels from an end are the rings); any other
//!    component (a *welded* mesh where branches share vertices) is
//!    simplified by thickness-adapted vertex clustering, contracted (Au et
//!    al. 2008, sparse Cholesky with one symbolic factorisation) and sliced
//!    into a tree (module `contract`, whose docs give the schedule and the
//!    choices). The pieces are joined into one rooted tree, rooted at the
//!    lowest, thickest point, each attaching by the end nearest to what is
//!    already attached (module `skeleton`). Radii come from the distances
//!    of the original vertices to the skeleton (ring radii for tubes).
//! 5. **Leaf attachment** (module `attach`): each leaf to the nearest
//!    branch through a kd-tree (kiddo) over points sampled along the
//!    branches; `t` and `offset` from the exact closest point. A leaf with
//!    no wood under it (farther from the axis than the radius plus half its
//!    size) proves a twig the skeleton lost — contraction's vertex budget
//!    collapses the thinnest twigs of a welded bark — so a short twig is
//!    grown to its base ([`ImportReport::grown_twigs`]; the module docs give
//!    the rule).
//!
//! # Errors
//! Bad input never panics: it gives an [`ImportError`] whose
//! [`code`](ImportError::code) is `invalid_gltf` (broken container, JSON or
//! accessor; NaN positions; indices out of range; node cycles),
//! `unsupported_gltf` (valid but unsupported: external URIs, Draco or
//! meshopt compression, unknown required extensions, glTF 1), `invalid_tree`
//! (no triangles, no wood, a skeleton of one point), `too_large` (a limit of
//! [`ImportOptions`]; a count the bytes do not hold is `invalid_gltf`
//! first), `invalid_options` or `internal`. A GLB whose embedded treemorph
//! tree is damaged is imported from its meshes, with a warning.
//!
//! # Fidelity
//! The crate's `fidelity` tests export generated trees of every preset as
//! GLB without the embedded tree, as tube soups and as welded meshes, and
//! compare the import with the original: at least 95 % of the branch length
//! within a local radius of the recovered skeleton, chain counts within
//! ±10 %, the exact leaf count, and at least 90 % of leaves on the right
//! chain (the point a recovered leaf hangs from lies, by proximity, on the
//! ground-truth chain of the branch the leaf grew on). The `third_party`
//! test checks trees written by ez-tree (`tools/third-party-trees`).
//!
//! # Performance
//! Reading and the tube-soup path are linear in the mesh size; contraction
//! runs on a proxy of a third of the mesh's vertices, between
//! [`ImportOptions::contraction_vertices`] (40,000 by default) and 150,000. See
//! `examples/import_bench.rs` (inputs from [`bench::bench_glb`]) for the
//! figures on 10,000-branch, 5,000-leaf trees.

mod attach;
pub mod bench;
pub mod classify;
mod contract;
mod error;
pub mod leaves;
mod mesh;
mod options;
mod read;
mod skeleton;
mod tube;

use std::time::Instant;

use treemorph_gltf::ReadError;
use treemorph_tree::{Bark, InvalidTree, Materials, Tree, TreeParts};

pub use error::ImportError;
pub use options::{ImportOptions, name_matches};

use crate::classify::Kind;
use crate::error::invalid;
use crate::mesh::Mesh;
use crate::read::ImageCache;
use crate::skeleton::Piece;

/// How the skeleton was obtained.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum SkeletonMethod {
    /// Every wood component was a separate tube: axes from ring centroids.
    TubeSoup,
    /// At least one wood component was a welded mesh and was contracted.
    Contraction,
    /// The GLB carried a treemorph tree, used as is.
    Embedded,
}

impl SkeletonMethod {
    /// The snake_case name (`tube_soup`, `contraction`, `embedded`).
    pub fn as_str(self) -> &'static str {
        match self {
            SkeletonMethod::TubeSoup => "tube_soup",
            SkeletonMethod::Contraction => "contraction",
            SkeletonMethod::Embedded => "embedded",
        }
    }
}

/// What [`import`] found and did.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct ImportReport {
    /// Primitives (of mesh instances) read as wood.
    pub wood_primitives: usize,
    /// Primitives read as foliage.
    pub leaf_primitives: usize,
    /// How the skeleton was obtained.
    pub skeleton_method: SkeletonMethod,
    /// Connected wood components whose axis came from their rings.
    pub tube_components: usize,
    /// Connected wood components that were contracted.
    pub contracted_components: usize,
    /// Leaf pieces skipped for having (nearly) zero area.
    pub skipped_leaves: usize,
    /// Wood vertices after welding by position.
    pub wood_vertices: usize,
    /// Twigs grown to leaves that had no wood under them (one per chain of
    /// 1–3 new nodes; see the crate docs, stage 5).
    pub grown_twigs: usize,
    /// Milliseconds spent reading, classifying and extracting leaves,
    /// building the skeleton, and attaching leaves.
    pub timings_ms: [f64; 4],
    /// Things that were ignored or guessed.
    pub warnings: Vec<String>,
}

impl ImportReport {
    fn embedded(warnings: Vec<String>) -> ImportReport {
        ImportReport {
            wood_primitives: 0,
            leaf_primitives: 0,
            skeleton_method: SkeletonMethod::Embedded,
            tube_components: 0,
            contracted_components: 0,
            skipped_leaves: 0,
            wood_vertices: 0,
            grown_twigs: 0,
            timings_ms: [0.0; 4],
            warnings,
        }
    }
}

/// The imported tree and the report.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct Imported {
    /// The tree.
    pub tree: Tree,
    /// How it was obtained.
    pub report: ImportReport,
}

/// Imports a GLB or glTF JSON file (recognised by its first bytes).
pub fn import(bytes: &[u8], options: &ImportOptions) -> Result<Imported, ImportError> {
    options.check()?;
    if bytes.len() > options.max_file_bytes {
        return Err(ImportError::TooLarge(format!(
            "the file has {} bytes; at most {} are accepted",
            bytes.len(),
            options.max_file_bytes
        )));
    }
    let mut warnings = Vec::new();
    if bytes.starts_with(b"glTF") && !options.ignore_embedded_tree {
        let glb = treemorph_gltf::Glb::from_slice(bytes).map_err(|e| invalid(e.to_string()))?;
        if glb.json.len() > options.max_json_bytes {
            return Err(ImportError::TooLarge(format!(
                "the JSON chunk has {} bytes; at most {} are accepted",
                glb.json.len(),
                options.max_json_bytes
            )));
        }
        match treemorph_gltf::read_embedded_tree(bytes, &options.limits()) {
            Ok(Some(tree)) => {
                return Ok(Imported {
                    tree,
                    report: ImportReport::embedded(warnings),
                });
            }
            Ok(None) => {}
            Err(e @ (ReadError::Container(_) | ReadError::Json(_))) => {
                return Err(invalid(e.to_string()));
            }
            Err(e) => warnings.push(format!(
                "the embedded treemorph tree is ignored and the meshes are used instead: {e}"
            )),
        }
    }
    let t0 = Instant::now();
    let doc = read::read(bytes, options)?;
    warnings.extend(doc.warnings.iter().cloned());
    let t_read = t0.elapsed();
    build(&doc, options, warnings, t_read.as_secs_f64() * 1e3)
}

fn tree_error(e: InvalidTree) -> ImportError {
    match e {
        InvalidTree::TooLarge { .. } => ImportError::TooLarge(e.to_string()),
        e => ImportError::InvalidTree(e.to_string()),
    }
}

fn build(
    doc: &read::Document,
    options: &ImportOptions,
    mut warnings: Vec<String>,
    read_ms: f64,
) -> Result<Imported, ImportError> {
    let t0 = Instant::now();
    let mut images = ImageCache::default();
    let kinds = classify::classify(doc, options, &mut images, &mut warnings);
    let wood: Vec<&read::Primitive> = doc
        .primitives
        .iter()
        .zip(&kinds)
        .filter(|(_, k)| **k == Kind::Wood)
        .map(|(p, _)| p)
        .collect();
    let foliage: Vec<&read::Primitive> = doc
        .primitives
        .iter()
        .zip(&kinds)
        .filter(|(_, k)| **k == Kind::Leaves)
        .map(|(p, _)| p)
        .collect();
    if doc.primitives.iter().all(|p| p.triangles.is_empty()) {
        return Err(ImportError::InvalidTree(
            "the file has no triangle meshes in its scene".into(),
        ));
    }
    if wood.iter().all(|p| p.triangles.is_empty()) {
        return Err(ImportError::InvalidTree(format!(
            "no branch mesh: all {} primitives look like foliage (alpha-masked or many small pieces); name the bark material in wood_materials",
            doc.primitives.len()
        )));
    }
    let leaves = leaves::extract(doc, &foliage, options, &mut images, &mut warnings);
    if leaves.leaves.len() > options.max_leaves {
        return Err(ImportError::TooLarge(format!(
            "the file has {} leaves; at most {} are accepted",
            leaves.leaves.len(),
            options.max_leaves
        )));
    }
    let t_leaves = t0.elapsed();

    // Wood: one welded mesh, split into connected components.
    let t1 = Instant::now();
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for p in &wood {
        let base = positions.len() as u32;
        positions.extend_from_slice(&p.positions);
        triangles.extend(p.triangles.iter().map(|t| t.map(|v| v + base)));
    }
    let (mesh, _) = Mesh::weld(&positions, &triangles);
    drop((positions, triangles));
    let wood_vertices = mesh.len();
    let parts = mesh::split(&mesh);
    let mut pieces: Vec<Piece> = Vec::with_capacity(parts.len());
    let (mut tubes, mut contracted) = (0usize, 0usize);
    for (part, _) in &parts {
        if let Some(piece) = tube::tube_piece(part) {
            tubes += 1;
            pieces.push(piece);
        } else {
            contracted += 1;
            let piece = contract::contract_piece(part, options)?;
            if !piece.points.is_empty() {
                pieces.push(piece);
            }
        }
    }
    let nodes = skeleton::assemble(&pieces, &mut warnings)?;
    if nodes.len() < 2 {
        return Err(ImportError::InvalidTree(
            "the branch mesh has no extent: its skeleton is a single point".into(),
        ));
    }
    if nodes.len() > options.max_nodes {
        return Err(ImportError::TooLarge(format!(
            "the skeleton has {} nodes; at most {} are accepted",
            nodes.len(),
            options.max_nodes
        )));
    }
    let t_skeleton = t1.elapsed();

    let t2 = Instant::now();
    let attached = attach::attach(nodes, &leaves.leaves);
    if attached.nodes.len() > options.max_nodes {
        return Err(ImportError::TooLarge(format!(
            "the skeleton with the twigs grown to its leaves has {} nodes; at most {} are accepted",
            attached.nodes.len(),
            options.max_nodes
        )));
    }
    let bark = bark(doc, &wood, options, &mut images, &mut warnings);
    let parts = TreeParts {
        name: String::new(),
        nodes: attached.nodes,
        leaves: attached.leaves,
        materials: Materials {
            bark,
            leaves: leaves.materials,
        },
        ground_truth: None,
    };
    let tree = Tree::new(parts, &options.limits()).map_err(tree_error)?;
    let t_attach = t2.elapsed();
    let report = ImportReport {
        wood_primitives: wood.len(),
        leaf_primitives: foliage.len(),
        skeleton_method: if contracted > 0 {
            SkeletonMethod::Contraction
        } else {
            SkeletonMethod::TubeSoup
        },
        tube_components: tubes,
        contracted_components: contracted,
        skipped_leaves: leaves.skipped,
        wood_vertices,
        grown_twigs: attached.grown_twigs,
        timings_ms: [
            read_ms,
            t_leaves.as_secs_f64() * 1e3,
            t_skeleton.as_secs_f64() * 1e3,
            t_attach.as_secs_f64() * 1e3,
        ],
        warnings,
    };
    Ok(Imported { tree, report })
}

/// Bark from the material of the largest wood primitive.
fn bark(
    doc: &read::Document,
    wood: &[&read::Primitive],
    options: &ImportOptions,
    images: &mut ImageCache,
    warnings: &mut Vec<String>,
) -> Bark {
    let Some(material) = wood
        .iter()
        .max_by_key(|p| p.triangles.len())
        .and_then(|p| p.material)
        .map(|m| &doc.materials[m])
    else {
        return Bark::default();
    };
    Bark {
        color: material.color,
        texture: material
            .image
            .and_then(|i| images.get(doc, i, options.max_texture_side, warnings))
            .map(|(t, _)| t),
    }
}
