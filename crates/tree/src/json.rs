//! The JSON tree format, media type [`MEDIA_TYPE`], version [`FORMAT`].
//!
//! ```json
//! {
//!   "format": "treemorph.tree/1",
//!   "name": "maple",
//!   "nodes": [
//!     {"position": [0, 0, 0], "radius": 0.2, "parent": null},
//!     {"position": [0, 1, 0], "radius": 0.15, "parent": 0}
//!   ],
//!   "leaves": [
//!     {"branch": 1, "t": 0.5, "offset": [0.15, 0, 0], "width": 0.08,
//!      "height": 0.12, "orientation": [0, 0, 0, 1], "material": 0}
//!   ],
//!   "materials": {
//!     "bark": {"color": [0.23, 0.16, 0.1, 1]},
//!     "leaves": [{"name": "ovate", "color": [1, 1, 1, 1],
//!                 "texture": "data:image/png;base64,iVBORw0KGgo…"}]
//!   },
//!   "ground_truth": {"orders": [1, 1], "groups": [{"chains": [1], "pattern": "alternate"}]}
//! }
//! ```
//!
//! Positions and offsets are metres with Y up; `orientation` is a quaternion
//! `[x, y, z, w]`; colours are linear RGBA in [0, 1]; textures are PNG images
//! embedded as `data:image/png;base64,` URIs so a browser can show them
//! as they are. Nodes may come in any order (see [`Tree::new`]); unknown
//! fields are refused so that typos do not pass silently. The JSON Schema is
//! `api/schemas/tree.schema.json`.
//!
//! Numbers are written with the shortest representation that reads back to
//! the same `f32`, so a tree written here reads back identical.

use base64::Engine;
use base64::engine::general_purpose::STANDARD as BASE64;
use glam::{Quat, Vec3};
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::model::{
    Bark, BranchingPattern, GroundTruth, GroundTruthGroup, Leaf, LeafMaterial, Materials, Node,
    Tree, TreeParts,
};
use crate::texture::{Texture, TextureError};
use crate::validate::{InvalidTree, Limits};

/// Media type of the JSON tree format.
pub const MEDIA_TYPE: &str = "application/vnd.treemorph.tree+json";
/// Value of the `format` field this version reads and writes.
pub const FORMAT: &str = "treemorph.tree/1";
const DATA_URI_PREFIX: &str = "data:image/png;base64,";

/// Why a JSON tree document was refused.
#[derive(Clone, Debug, Error, PartialEq)]
// Exhaustive on purpose: the service's error-code table
// (`treemorph_pipeline::ErrorCoded`) must name a code for every variant.
pub enum FormatError {
    /// Not JSON, or JSON of the wrong shape.
    #[error("line {line}, column {column}: {message}")]
    Syntax {
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// What the parser expected.
        message: String,
    },
    /// The `format` field names a format this version does not read.
    #[error("format {found:?} is not supported; this version reads {FORMAT:?}")]
    UnsupportedFormat {
        /// The value found.
        found: String,
    },
    /// The document parsed, but the tree it describes is invalid.
    #[error(transparent)]
    Invalid(#[from] InvalidTree),
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TreeDoc {
    format: String,
    #[serde(default)]
    name: String,
    nodes: Vec<NodeDoc>,
    #[serde(default)]
    leaves: Vec<LeafDoc>,
    #[serde(default)]
    materials: MaterialsDoc,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    ground_truth: Option<GroundTruthDoc>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct NodeDoc {
    position: [f32; 3],
    radius: f32,
    parent: Option<u64>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct LeafDoc {
    branch: u64,
    t: f32,
    offset: [f32; 3],
    width: f32,
    height: f32,
    orientation: [f32; 4],
    material: u32,
}

#[derive(Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct MaterialsDoc {
    #[serde(default)]
    bark: BarkDoc,
    #[serde(default)]
    leaves: Vec<LeafMaterialDoc>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct BarkDoc {
    color: [f32; 4],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    texture: Option<String>,
}

impl Default for BarkDoc {
    fn default() -> BarkDoc {
        BarkDoc {
            color: Bark::default().color,
            texture: None,
        }
    }
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct LeafMaterialDoc {
    #[serde(default)]
    name: String,
    #[serde(default = "white")]
    color: [f32; 4],
    #[serde(default, skip_serializing_if = "Option::is_none")]
    texture: Option<String>,
}

fn white() -> [f32; 4] {
    [1.0; 4]
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct GroundTruthDoc {
    orders: Vec<u32>,
    groups: Vec<GroundTruthGroupDoc>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct GroundTruthGroupDoc {
    chains: Vec<u64>,
    pattern: BranchingPattern,
}

/// Only the version, read when the full document is refused, so that a file
/// of a newer format gets the error that explains it.
#[derive(Deserialize)]
struct Probe {
    format: Option<String>,
}

fn syntax(e: &serde_json::Error) -> FormatError {
    FormatError::Syntax {
        line: e.line(),
        column: e.column(),
        message: e.to_string(),
    }
}

/// Reads a tree from JSON bytes and validates it against `limits`.
pub fn from_slice(bytes: &[u8], limits: &Limits) -> Result<Tree, FormatError> {
    let doc: TreeDoc = match serde_json::from_slice(bytes) {
        Ok(doc) => doc,
        Err(e) => {
            if let Ok(Probe {
                format: Some(found),
            }) = serde_json::from_slice::<Probe>(bytes)
                && found != FORMAT
            {
                return Err(FormatError::UnsupportedFormat { found });
            }
            return Err(syntax(&e));
        }
    };
    if doc.format != FORMAT {
        return Err(FormatError::UnsupportedFormat { found: doc.format });
    }
    Ok(Tree::new(parts_of(doc, limits)?, limits)?)
}

/// Out-of-range indices are clamped to `u32::MAX` here and reported by
/// validation with the original value, so a 2^40 parent gets the same
/// precise error as any other dangling one.
fn index(i: u64, count: usize) -> Result<u32, u64> {
    match u32::try_from(i) {
        Ok(v) if (v as usize) < count => Ok(v),
        _ => Err(i),
    }
}

fn parts_of(doc: TreeDoc, limits: &Limits) -> Result<TreeParts, InvalidTree> {
    let n = doc.nodes.len();
    // Refuse oversized inputs before converting them.
    if n > limits.max_nodes {
        return Err(InvalidTree::TooLarge {
            kind: crate::SizeKind::Nodes,
            count: n,
            limit: limits.max_nodes,
        });
    }
    let mut nodes = Vec::with_capacity(n);
    for (i, node) in doc.nodes.iter().enumerate() {
        let parent = match node.parent {
            None => None,
            Some(p) => Some(index(p, n).map_err(|parent| InvalidTree::DanglingParent {
                node: i,
                parent,
                count: n,
            })?),
        };
        nodes.push(Node {
            position: Vec3::from_array(node.position),
            radius: node.radius,
            parent,
        });
    }
    let mut leaves = Vec::with_capacity(doc.leaves.len().min(limits.max_leaves));
    for (i, leaf) in doc.leaves.iter().enumerate() {
        let branch = index(leaf.branch, n).map_err(|branch| InvalidTree::LeafOnMissingBranch {
            leaf: i,
            branch,
            count: n,
        })?;
        leaves.push(Leaf {
            branch,
            t: leaf.t,
            offset: Vec3::from_array(leaf.offset),
            width: leaf.width,
            height: leaf.height,
            orientation: Quat::from_array(leaf.orientation),
            material: leaf.material,
        });
    }
    let texture = |uri: &Option<String>, material: String| -> Result<_, InvalidTree> {
        uri.as_deref()
            .map(|u| decode_texture(u, limits.max_texture_side))
            .transpose()
            .map_err(|reason| InvalidTree::InvalidTexture { material, reason })
    };
    let bark = Bark {
        color: doc.materials.bark.color,
        texture: texture(&doc.materials.bark.texture, "bark".into())?,
    };
    let mut leaf_materials = Vec::with_capacity(doc.materials.leaves.len());
    for (i, m) in doc.materials.leaves.iter().enumerate() {
        leaf_materials.push(LeafMaterial {
            name: m.name.clone(),
            color: m.color,
            texture: texture(&m.texture, format!("leaves[{i}]"))?,
        });
    }
    let ground_truth = match doc.ground_truth {
        None => None,
        Some(gt) => {
            let mut groups = Vec::with_capacity(gt.groups.len());
            for (g, group) in gt.groups.into_iter().enumerate() {
                let chains = group
                    .chains
                    .iter()
                    .map(|&c| index(c, n))
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(|c| InvalidTree::GroundTruthMismatch {
                        reason: format!("groups[{g}] names node {c}, which does not exist"),
                    })?;
                groups.push(GroundTruthGroup {
                    chains,
                    pattern: group.pattern,
                });
            }
            Some(GroundTruth {
                orders: gt.orders,
                groups,
            })
        }
    };
    Ok(TreeParts {
        name: doc.name,
        nodes,
        leaves,
        materials: Materials {
            bark,
            leaves: leaf_materials,
        },
        ground_truth,
    })
}

fn decode_texture(uri: &str, max_side: u32) -> Result<Texture, String> {
    let Some(data) = uri.strip_prefix(DATA_URI_PREFIX) else {
        return Err(format!(
            "textures must be {DATA_URI_PREFIX}… URIs; found one starting {:?}",
            uri.chars().take(24).collect::<String>()
        ));
    };
    let bytes = BASE64
        .decode(data)
        .map_err(|e| format!("invalid base64: {e}"))?;
    Texture::from_png(bytes, max_side).map_err(|e: TextureError| e.to_string())
}

fn encode_texture(texture: &Texture) -> String {
    let mut s = String::with_capacity(DATA_URI_PREFIX.len() + texture.png().len() * 4 / 3 + 4);
    s.push_str(DATA_URI_PREFIX);
    BASE64.encode_string(texture.png(), &mut s);
    s
}

fn doc_of(tree: &Tree) -> TreeDoc {
    let skeleton = tree.skeleton();
    TreeDoc {
        format: FORMAT.to_owned(),
        name: tree.name().to_owned(),
        nodes: skeleton
            .nodes()
            .iter()
            .map(|n| NodeDoc {
                position: n.position.to_array(),
                radius: n.radius,
                parent: n.parent.map(u64::from),
            })
            .collect(),
        leaves: tree
            .leaves()
            .iter()
            .map(|l| LeafDoc {
                branch: u64::from(l.branch),
                t: l.t,
                offset: l.offset.to_array(),
                width: l.width,
                height: l.height,
                orientation: l.orientation.to_array(),
                material: l.material,
            })
            .collect(),
        materials: MaterialsDoc {
            bark: BarkDoc {
                color: tree.materials().bark.color,
                texture: tree.materials().bark.texture.as_ref().map(encode_texture),
            },
            leaves: tree
                .materials()
                .leaves
                .iter()
                .map(|m| LeafMaterialDoc {
                    name: m.name.clone(),
                    color: m.color,
                    texture: m.texture.as_ref().map(encode_texture),
                })
                .collect(),
        },
        ground_truth: tree.ground_truth().map(|gt| GroundTruthDoc {
            orders: gt.orders.clone(),
            groups: gt
                .groups
                .iter()
                .map(|g| GroundTruthGroupDoc {
                    chains: g.chains.iter().map(|&c| u64::from(c)).collect(),
                    pattern: g.pattern,
                })
                .collect(),
        }),
    }
}

/// Writes a tree as compact JSON.
pub fn to_vec(tree: &Tree) -> Vec<u8> {
    serde_json::to_vec(&doc_of(tree)).expect("tree documents hold only finite numbers and strings")
}

/// Writes a tree as indented JSON (for people reading the file).
pub fn to_vec_pretty(tree: &Tree) -> Vec<u8> {
    serde_json::to_vec_pretty(&doc_of(tree))
        .expect("tree documents hold only finite numbers and strings")
}

#[cfg(test)]
#[path = "json_tests.rs"]
mod tests;
