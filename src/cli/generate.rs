//! `treemorph generate`.

use std::path::PathBuf;

use anyhow::{Context, anyhow};
use treemorph_generate::{GenerateOptions, Preset};

use super::{Failure, progress};
use crate::files::{OutputKind, encode_tree, write_atomic};

/// Arguments of `treemorph generate`.
#[derive(Debug, clap::Args)]
#[command(after_help = "Examples:\n  treemorph generate --list\n  \
treemorph generate --preset maple --seed 7 -o maple.glb\n  \
treemorph generate --preset conifer --seed 1 --size 20000 -o conifer.json")]
pub struct Args {
    /// Print the preset names, one per line, and exit.
    #[arg(long, exclusive = true)]
    list: bool,
    /// Tree preset (see --list).
    #[arg(long, required_unless_present = "list")]
    preset: Option<String>,
    /// Random seed; the same preset, seed and size always give the same tree.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Number of branches (skeleton edges) of the generated tree.
    #[arg(long, default_value_t = GenerateOptions::DEFAULT_SIZE)]
    size: u32,
    /// Output file: `.glb` (binary glTF) or `.json` (treemorph tree format).
    #[arg(short, long, required_unless_present = "list")]
    output: Option<PathBuf>,
}

pub(super) fn run(args: &Args) -> Result<(), Failure> {
    if args.list {
        for preset in Preset::ALL {
            println!("{}", preset.name());
        }
        return Ok(());
    }
    let (Some(name), Some(output)) = (&args.preset, &args.output) else {
        unreachable!("clap requires --preset and --output without --list");
    };
    let preset: Preset = name.parse().map_err(|e| Failure {
        code: super::EXIT_USAGE,
        error: anyhow!("{e}"),
    })?;
    let kind = OutputKind::of_path(output).ok_or_else(|| Failure {
        code: super::EXIT_USAGE,
        error: anyhow!(
            "cannot tell the format of {}: use a .glb or .json file name",
            output.display()
        ),
    })?;
    let spinner = progress::spinner("generating");
    let options = GenerateOptions::new(preset, args.seed).with_size(args.size);
    let tree = treemorph_generate::generate(&options).map_err(|e| Failure {
        code: super::EXIT_USAGE,
        error: anyhow!("{e}"),
    })?;
    spinner.set_message("writing");
    let bytes = encode_tree(&tree, kind).map_err(|e| anyhow!(e))?;
    write_atomic(output, &bytes).with_context(|| format!("writing {}", output.display()))?;
    spinner.finish_and_clear();
    let stats = tree.stats();
    eprintln!(
        "wrote {} ({} branches, {} leaves, {:.1} m tall, {} bytes)",
        output.display(),
        stats.branches,
        stats.leaves,
        stats.height,
        bytes.len()
    );
    Ok(())
}
