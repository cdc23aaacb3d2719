//! The `treemorph` command line.
//!
//! Exit codes are part of the interface scripts rely on:
//! `0` success, `1` an operation failed, `2` the command line was wrong,
//! `3` an input file is invalid or unreadable. `treemorph client` adds
//! `4` not found, `5` the server is unreachable, `6` unauthorized and `7`
//! busy (rate limited or queue full): see its module.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod animate;
mod client;
mod generate;
mod import;
mod inspect;
mod job_args;
mod progress;
mod serve;

/// Exit code: an operation failed.
pub const EXIT_FAILURE: u8 = 1;
/// Exit code: the command line was wrong (clap's own code).
pub const EXIT_USAGE: u8 = 2;
/// Exit code: an input file is invalid or unreadable.
pub const EXIT_INVALID_INPUT: u8 = 3;

/// treemorph animates leafy 3D trees: it morphs one tree into another and
/// grows a tree into a crown shape sketched from a camera.
#[derive(Debug, Parser)]
#[command(
    name = "treemorph",
    version,
    about,
    long_about = "treemorph animates leafy 3D trees: it morphs one tree into a topologically \
different one, and animates a tree into a crown shape sketched from a camera.\n\n\
Start with `treemorph generate --list`, then e.g. \
`treemorph generate --preset maple --seed 1 -o maple.glb` and `treemorph inspect maple.glb`.",
    propagate_version = true
)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Generate a procedural leafy tree (GLB or JSON by the output's extension).
    Generate(generate::Args),
    /// Print counts, bounds, height and depth of a tree file (GLB, glTF or JSON).
    Inspect(inspect::Args),
    /// Turn a GLB or glTF tree mesh (branches plus leaf quads) into a tree file.
    Import(import::Args),
    /// Morph one tree into another and write the frames.
    Morph(animate::MorphArgs),
    /// Animate a tree into a crown shape sketched from a camera.
    Sketch(animate::SketchArgs),
    /// Run the benchmarks and print a table of named figures.
    Bench(crate::bench::Args),
    /// Run the HTTP service (API and workers; see `treemorph serve --help`).
    Serve(Box<crate::config::Settings>),
    /// Talk to a running service: upload, generate, morph, sketch, watch,
    /// download (see `treemorph client --help`).
    Client(client::Args),
}

/// A command's failure: what to print and which exit code to use.
#[derive(Debug)]
pub struct Failure {
    /// The exit code.
    pub code: u8,
    /// The error, printed with its causes.
    pub error: anyhow::Error,
}

impl Failure {
    /// An input file is invalid or unreadable.
    pub fn invalid_input(error: impl Into<anyhow::Error>) -> Failure {
        Failure {
            code: EXIT_INVALID_INPUT,
            error: error.into(),
        }
    }
}

impl<E: Into<anyhow::Error>> From<E> for Failure {
    fn from(error: E) -> Failure {
        Failure {
            code: EXIT_FAILURE,
            error: error.into(),
        }
    }
}

/// Parses the command line, runs the command and returns the exit code.
pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Generate(args) => generate::run(&args),
        Command::Inspect(args) => inspect::run(&args),
        Command::Import(args) => import::run(&args),
        Command::Morph(args) => animate::morph(&args),
        Command::Sketch(args) => animate::sketch(&args),
        Command::Bench(args) => crate::bench::run(&args),
        Command::Serve(settings) => serve::run(*settings),
        Command::Client(args) => client::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(failure) => {
            eprintln!("error: {:#}", failure.error);
            ExitCode::from(failure.code)
        }
    }
}
