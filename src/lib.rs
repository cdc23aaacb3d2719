//! treemorph: an HTTP service and command-line tool that animates leafy 3D
//! trees — morphing one tree into a topologically different one, and
//! animating a tree into a crown shape sketched from a camera.
//!
//! The geometry lives in synchronous crates under `crates/` (tree model,
//! generator, analysis, pipelines, glTF output); this crate holds the
//! command line ([`cli`]), file loading ([`files`]) and the benchmark table
//! ([`bench`]).

pub mod bench;
pub mod cli;
pub mod files;
