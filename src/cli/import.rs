//! `treemorph import`.

use std::path::PathBuf;

use anyhow::{Context, anyhow};
use treemorph_tree::Limits;

use super::Failure;
use crate::files::{OutputKind, encode_tree, import_options, write_atomic};

/// Arguments of `treemorph import`.
#[derive(Debug, clap::Args)]
#[command(after_help = "Examples:\n  treemorph import oak.glb -o oak.json\n  \
treemorph import scene.gltf --leaf-material 'Leaf*' -o tree.glb")]
pub struct Args {
    /// A GLB or glTF file (glTF with embedded `data:` buffers only).
    file: PathBuf,
    /// Output: `.json` (treemorph tree format) or `.glb`.
    #[arg(short, long)]
    output: PathBuf,
    /// Treat primitives whose material or mesh name matches as leaves
    /// (`*` wildcards; repeatable).
    #[arg(long = "leaf-material", value_name = "PATTERN")]
    leaf_materials: Vec<String>,
    /// Treat primitives whose material or mesh name matches as wood
    /// (`*` wildcards; repeatable; wins over --leaf-material).
    #[arg(long = "wood-material", value_name = "PATTERN")]
    wood_materials: Vec<String>,
    /// Rebuild the skeleton from the meshes even when the file carries a
    /// treemorph skeleton.
    #[arg(long)]
    ignore_embedded_tree: bool,
}

pub(super) fn run(args: &Args) -> Result<(), Failure> {
    let kind = OutputKind::of_path(&args.output).ok_or_else(|| Failure {
        code: super::EXIT_USAGE,
        error: anyhow!(
            "cannot tell the format of {}: use a .json or .glb file name",
            args.output.display()
        ),
    })?;
    let bytes = std::fs::read(&args.file)
        .with_context(|| format!("cannot read {}", args.file.display()))
        .map_err(Failure::invalid_input)?;
    let options = import_options(&Limits::default())
        .with_leaf_materials(args.leaf_materials.iter().cloned())
        .with_wood_materials(args.wood_materials.iter().cloned())
        .with_ignore_embedded_tree(args.ignore_embedded_tree);
    let imported = treemorph_import::import(&bytes, &options).map_err(|e| {
        Failure::invalid_input(anyhow!("{}: {} ({})", args.file.display(), e, e.code()))
    })?;
    for warning in &imported.report.warnings {
        eprintln!("warning: {warning}");
    }
    let out = encode_tree(&imported.tree, kind).map_err(|e| anyhow!(e))?;
    write_atomic(&args.output, &out)
        .with_context(|| format!("writing {}", args.output.display()))?;
    let stats = imported.tree.stats();
    eprintln!(
        "wrote {} ({} branches, {} leaves; skeleton from {})",
        args.output.display(),
        stats.branches,
        stats.leaves,
        imported.report.skeleton_method.as_str()
    );
    Ok(())
}
