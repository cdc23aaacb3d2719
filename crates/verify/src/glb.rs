//! Reading a GLB's branch and leaf meshes back, for tests and tools:
//! [`read_glb`] gives a [`GlbMeshes`] whose [`GlbMeshes::view`] the check
//! takes like the in-process meshes.

use glam::{Mat4, Vec3};
use thiserror::Error;

use crate::plausibility::{LeafLayout, MeshView};

/// Why a GLB could not be read.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum ReadGlbError {
    /// Not a glTF binary the `gltf` crate accepts.
    #[error("not a readable GLB: {0}")]
    Gltf(String),
    /// A primitive lacks positions, or its data lies outside the binary chunk.
    #[error("mesh {mesh}: {message}")]
    Primitive {
        /// The mesh's name.
        mesh: String,
        /// What is wrong.
        message: String,
    },
    /// No mesh or node is named `branches`.
    #[error("no mesh or node named `branches`")]
    NoBranches,
}

/// The branch and leaf triangles of a GLB, in scene (world) coordinates.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GlbMeshes {
    /// Branch vertex positions.
    pub branch_positions: Vec<Vec3>,
    /// Branch triangle indices.
    pub branch_indices: Vec<u32>,
    /// Leaf vertex positions.
    pub leaf_positions: Vec<Vec3>,
    /// Leaf triangle indices.
    pub leaf_indices: Vec<u32>,
}

impl GlbMeshes {
    /// The meshes for [`Plausibility::check`](crate::Plausibility::check):
    /// leaves are the leaf mesh's connected components
    /// ([`LeafLayout::Components`]).
    pub fn view(&self) -> MeshView<'_> {
        MeshView {
            branch_positions: &self.branch_positions,
            branch_indices: &self.branch_indices,
            leaf_positions: &self.leaf_positions,
            leaf_indices: &self.leaf_indices,
            leaves: LeafLayout::Components,
        }
    }
}

/// Reads the triangles of every mesh instanced in the default scene whose
/// mesh or node is named `branches` (bark) or `leaves`, as treemorph's
/// frame and static GLBs, and the third-party tree generators under
/// `tools/third-party-trees`, name them; node transforms are applied and
/// other meshes are ignored. Meant for files we or our tools wrote: the
/// `gltf` crate's readers are trusted with the accessor layout.
pub fn read_glb(bytes: &[u8]) -> Result<GlbMeshes, ReadGlbError> {
    let gltf = gltf::Gltf::from_slice(bytes).map_err(|e| ReadGlbError::Gltf(e.to_string()))?;
    let blob = gltf.blob.as_deref();
    let mut out = GlbMeshes::default();
    let mut found = false;
    let scene = gltf
        .default_scene()
        .or_else(|| gltf.scenes().next())
        .ok_or_else(|| ReadGlbError::Gltf("no scene".into()))?;
    let mut stack: Vec<(gltf::Node<'_>, Mat4, Option<bool>)> =
        scene.nodes().map(|n| (n, Mat4::IDENTITY, None)).collect();
    while let Some((node, parent, class)) = stack.pop() {
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        let named = |name: Option<&str>| match name {
            Some("branches") => Some(true),
            Some("leaves") => Some(false),
            _ => None,
        };
        let class = named(node.name()).or(class);
        if let Some(mesh) = node.mesh()
            && let Some(is_branch) = named(mesh.name()).or(class)
        {
            found |= is_branch;
            let name = mesh.name().unwrap_or("").to_string();
            for p in mesh.primitives() {
                if p.mode() != gltf::mesh::Mode::Triangles {
                    continue;
                }
                let err = |m: &str| ReadGlbError::Primitive {
                    mesh: name.clone(),
                    message: m.into(),
                };
                for a in p.attributes().map(|(_, a)| a).chain(p.indices()) {
                    let view = a
                        .view()
                        .ok_or_else(|| err("sparse accessors are not read"))?;
                    let end = view.offset() + view.length();
                    if blob.is_none_or(|b| end > b.len()) {
                        return Err(err("accessor data lies outside the binary chunk"));
                    }
                }
                let reader = p.reader(|b| match b.source() {
                    gltf::buffer::Source::Bin => blob,
                    _ => None,
                });
                let (positions, indices) = if is_branch {
                    (&mut out.branch_positions, &mut out.branch_indices)
                } else {
                    (&mut out.leaf_positions, &mut out.leaf_indices)
                };
                let base = positions.len() as u32;
                let read = reader.read_positions().ok_or_else(|| err("no POSITION"))?;
                positions.extend(read.map(|p| world.transform_point3(Vec3::from(p))));
                let count = positions.len() as u32 - base;
                match reader.read_indices() {
                    Some(ix) => indices.extend(ix.into_u32().map(|i| base + i)),
                    None => indices.extend(base..base + count - count % 3),
                }
            }
        }
        stack.extend(node.children().map(|c| (c, world, class)));
    }
    if !found {
        return Err(ReadGlbError::NoBranches);
    }
    Ok(out)
}
