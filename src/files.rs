//! Reading and writing tree files in every supported format.
//!
//! The format is recognised from the content, not the file name: a GLB
//! starts with the magic `glTF`; a JSON document is our tree format when it
//! has a `"format"` field and glTF when it has an `"asset"` field. Output
//! formats are chosen by extension (`.json` or `.glb`).

use std::path::{Path, PathBuf};

use thiserror::Error;
use treemorph_import::{ImportError, ImportOptions};
use treemorph_tree::{Limits, Tree};

/// The kinds of tree file treemorph reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TreeFileKind {
    /// Our JSON tree format (`application/vnd.treemorph.tree+json`).
    TreeJson,
    /// Binary glTF (`model/gltf-binary`).
    Glb,
    /// glTF JSON with embedded buffers (`model/gltf+json`).
    Gltf,
}

impl TreeFileKind {
    /// The media type of this kind.
    pub fn media_type(self) -> &'static str {
        match self {
            TreeFileKind::TreeJson => treemorph_tree::json::MEDIA_TYPE,
            TreeFileKind::Glb => "model/gltf-binary",
            TreeFileKind::Gltf => "model/gltf+json",
        }
    }

    /// A short name (`tree+json`, `glb`, `gltf`).
    pub fn name(self) -> &'static str {
        match self {
            TreeFileKind::TreeJson => "tree+json",
            TreeFileKind::Glb => "glb",
            TreeFileKind::Gltf => "gltf",
        }
    }
}

/// Recognises a tree file from its first bytes; `None` when it is none of
/// ours.
pub fn sniff(bytes: &[u8]) -> Option<TreeFileKind> {
    if bytes.starts_with(b"glTF") {
        return Some(TreeFileKind::Glb);
    }
    let start = bytes.iter().position(|b| !b.is_ascii_whitespace())?;
    if bytes[start] != b'{' {
        return None;
    }
    // Look at top-level keys without parsing the whole document: the
    // probe deserialises only the two fields that tell the formats apart.
    #[derive(serde::Deserialize)]
    struct Probe {
        format: Option<serde::de::IgnoredAny>,
        asset: Option<serde::de::IgnoredAny>,
    }
    match serde_json::from_slice::<Probe>(bytes) {
        Ok(Probe {
            asset: Some(_),
            format: None,
        }) => Some(TreeFileKind::Gltf),
        Ok(Probe {
            format: Some(_), ..
        }) => Some(TreeFileKind::TreeJson),
        // Broken JSON that looks like ours still goes to our parser so the
        // user sees its line/column error.
        _ => Some(TreeFileKind::TreeJson),
    }
}

/// Why a tree file could not be read.
#[derive(Debug, Error)]
pub enum LoadError {
    /// The file could not be read.
    #[error("cannot read {path}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The content is none of the supported formats.
    #[error(
        "{path} is not a tree file: expected a GLB, a glTF JSON file or a treemorph tree JSON document"
    )]
    UnknownFormat {
        /// The file.
        path: PathBuf,
    },
    /// Our JSON format, but invalid.
    #[error("{path}: {source}")]
    TreeJson {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: treemorph_tree::json::FormatError,
    },
    /// A GLB or glTF file that could not be turned into a tree.
    #[error("{path}: {source}")]
    Gltf {
        /// The file.
        path: PathBuf,
        /// The cause, with its stable code ([`ImportError::code`]).
        source: ImportError,
    },
}

/// Import options with the tree limits applied.
pub fn import_options(limits: &Limits) -> ImportOptions {
    let mut options = ImportOptions::default();
    options.max_nodes = limits.max_nodes;
    options.max_leaves = limits.max_leaves;
    options.max_texture_side = limits.max_texture_side;
    options
}

/// Reads a tree from bytes of any supported kind.
pub fn tree_from_bytes(
    bytes: &[u8],
    limits: &Limits,
    path: &Path,
) -> Result<(Tree, TreeFileKind), LoadError> {
    let kind = sniff(bytes).ok_or_else(|| LoadError::UnknownFormat {
        path: path.to_owned(),
    })?;
    Ok((tree_of_kind(bytes, kind, limits, path)?, kind))
}

/// Reads `bytes` as a tree file of `kind`, without sniffing (for callers
/// told the kind, e.g. by a media type).
pub fn tree_of_kind(
    bytes: &[u8],
    kind: TreeFileKind,
    limits: &Limits,
    path: &Path,
) -> Result<Tree, LoadError> {
    Ok(match kind {
        TreeFileKind::TreeJson => {
            treemorph_tree::json::from_slice(bytes, limits).map_err(|source| {
                LoadError::TreeJson {
                    path: path.to_owned(),
                    source,
                }
            })?
        }
        // The importer reads our own GLBs' embedded tree exactly and
        // reconstructs a skeleton from the meshes of any other file.
        TreeFileKind::Glb | TreeFileKind::Gltf => {
            treemorph_import::import(bytes, &import_options(limits))
                .map_err(|source| LoadError::Gltf {
                    path: path.to_owned(),
                    source,
                })?
                .tree
        }
    })
}

/// Reads a tree file of any supported kind.
pub fn load_tree(path: &Path, limits: &Limits) -> Result<(Tree, TreeFileKind), LoadError> {
    let bytes = std::fs::read(path).map_err(|source| LoadError::Io {
        path: path.to_owned(),
        source,
    })?;
    tree_from_bytes(&bytes, limits, path)
}

/// Output formats chosen by file extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputKind {
    /// `.json`: our tree format.
    TreeJson,
    /// `.glb`: binary glTF with the tree embedded.
    Glb,
}

impl OutputKind {
    /// The kind for a path's extension, if supported.
    pub fn of_path(path: &Path) -> Option<OutputKind> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("json") => Some(OutputKind::TreeJson),
            Some("glb") => Some(OutputKind::Glb),
            _ => None,
        }
    }
}

/// Encodes a tree in an output format.
pub fn encode_tree(tree: &Tree, kind: OutputKind) -> Result<Vec<u8>, String> {
    match kind {
        OutputKind::TreeJson => Ok(treemorph_tree::json::to_vec(tree)),
        OutputKind::Glb => {
            treemorph_gltf::export_glb(tree, &treemorph_gltf::ExportOptions::default())
                .map_err(|e| e.to_string())
        }
    }
}

/// Writes a file atomically: to a temporary sibling first, then renamed, so
/// an interrupted run never leaves a half-written file under the real name.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir)?;
    let mut tmp = tempfile::NamedTempFile::new_in(dir)?;
    std::io::Write::write_all(&mut tmp, bytes)?;
    // Temporary files are created private (0600); outputs are ordinary
    // files that other users and tools may read.
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        tmp.as_file()
            .set_permissions(std::fs::Permissions::from_mode(0o644))?;
    }
    tmp.as_file().sync_all()?;
    tmp.persist(path).map_err(|e| e.error)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sniffs_every_kind() {
        assert_eq!(sniff(b"glTF\x02\0\0\0"), Some(TreeFileKind::Glb));
        assert_eq!(
            sniff(br#" {"asset": {"version": "2.0"}, "meshes": []}"#),
            Some(TreeFileKind::Gltf)
        );
        assert_eq!(
            sniff(br#"{"format": "treemorph.tree/1", "nodes": []}"#),
            Some(TreeFileKind::TreeJson)
        );
        assert_eq!(sniff(b"{broken"), Some(TreeFileKind::TreeJson));
        assert_eq!(sniff(b"\x89PNG"), None);
        assert_eq!(sniff(b""), None);
    }

    /// Regression: outputs were left with the temporary file's 0600 mode.
    #[cfg(unix)]
    #[test]
    fn atomic_writes_leave_readable_files_and_no_temporaries() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/out.json");
        write_atomic(&path, b"{}").unwrap();
        write_atomic(&path, b"{\"a\":1}").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"{\"a\":1}");
        let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o644);
        let names: Vec<_> = std::fs::read_dir(path.parent().unwrap())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("out.json")]);
    }

    #[test]
    fn output_kind_follows_the_extension() {
        assert_eq!(
            OutputKind::of_path(Path::new("a/b.GLB")),
            Some(OutputKind::Glb)
        );
        assert_eq!(
            OutputKind::of_path(Path::new("t.json")),
            Some(OutputKind::TreeJson)
        );
        assert_eq!(OutputKind::of_path(Path::new("t.obj")), None);
    }
}
