//! `treemorph inspect`.

use std::path::PathBuf;

use serde::Serialize;
use treemorph_analysis::{Analysis, AnalysisOptions, AnalysisSummary};
use treemorph_tree::{Limits, TreeStats};

use super::Failure;
use crate::files::load_tree;

/// Arguments of `treemorph inspect`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A tree file: GLB, glTF or treemorph JSON.
    file: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    json: bool,
    /// Also analyse the tree: chains, chain groups, branching patterns,
    /// orders, BPTT depth and lobes.
    #[arg(long)]
    analysis: bool,
    /// With --analysis --json: print the whole analysis (chains, groups,
    /// BPTT, lobes with hulls, leaves) instead of its summary.
    #[arg(long, requires = "analysis")]
    full: bool,
}

/// What `inspect --json` prints.
#[derive(Debug, Serialize)]
struct Report {
    file: String,
    format: &'static str,
    name: String,
    #[serde(flatten)]
    stats: TreeStats,
    #[serde(skip_serializing_if = "Option::is_none")]
    analysis: Option<AnalysisSummary>,
}

pub(super) fn run(args: &Args) -> Result<(), Failure> {
    let (tree, kind) = load_tree(&args.file, &Limits::default()).map_err(Failure::invalid_input)?;
    let analysis = if args.analysis {
        Some(Analysis::of(&tree, &AnalysisOptions::default()).map_err(Failure::invalid_input)?)
    } else {
        None
    };
    if args.full
        && let Some(a) = &analysis
    {
        if !args.json {
            return Err(Failure {
                code: super::EXIT_USAGE,
                error: anyhow::anyhow!("--full prints JSON: add --json"),
            });
        }
        use std::io::Write;
        let mut out = std::io::stdout().lock();
        out.write_all(&a.to_json())?;
        writeln!(out)?;
        return Ok(());
    }
    let report = Report {
        file: args.file.display().to_string(),
        format: kind.name(),
        name: tree.name().to_owned(),
        stats: tree.stats(),
        analysis: analysis.as_ref().map(Analysis::summary),
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    let s = &report.stats;
    println!("file      {} ({})", report.file, report.format);
    if !report.name.is_empty() {
        println!("name      {}", report.name);
    }
    println!("nodes     {}", s.nodes);
    println!("branches  {}", s.branches);
    println!("leaves    {}", s.leaves);
    println!("height    {:.3} m", s.height);
    println!("depth     {} nodes", s.depth);
    println!("length    {:.3} m of branches", s.total_length);
    println!(
        "bounds    [{:.3}, {:.3}, {:.3}] .. [{:.3}, {:.3}, {:.3}] m",
        s.bounds[0][0],
        s.bounds[0][1],
        s.bounds[0][2],
        s.bounds[1][0],
        s.bounds[1][1],
        s.bounds[1][2]
    );
    if let Some(a) = &report.analysis {
        let p = &a.patterns;
        println!("chains    {}", a.chains);
        println!(
            "groups    {} (alternate {}, opposite {}, whorled {})",
            a.chain_groups, p.alternate, p.opposite, p.whorled
        );
        let histogram: Vec<String> = a.orders.histogram.iter().map(usize::to_string).collect();
        println!("orders    1..{}", a.orders.max);
        println!("by order  {}", histogram.join(" "));
        println!("bptt      {} levels", a.bptt_depth);
        println!(
            "lobes     inner {}, outer {}, group outer {}",
            a.lobes.inner, a.lobes.outer, a.lobes.group_outer
        );
    }
    Ok(())
}
