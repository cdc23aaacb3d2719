//! treemorph: an HTTP service and command-line tool that animates leafy 3D
//! trees — morphing one tree into a topologically different one, and
//! animating a tree into a crown shape sketched from a camera.
//!
//! The geometry lives in synchronous crates under `crates/` (tree model,
//! generator, analysis, pipelines, glTF output); this crate holds the
//! command line ([`cli`]), file loading ([`files`]) and the benchmark table
//! ([`bench`]), and the HTTP service: [`server`] (routes), [`jobs`] (durable
//! queue, leases, workers, webhooks), [`store`] (database and blobs),
//! [`config`], [`error`] and [`telemetry`]; [`pipeline`] is the seam between
//! the queue and the geometry.

pub mod bench;
pub mod cli;
pub mod config;
pub mod error;
pub mod files;
pub mod jobs;
pub mod pipeline;
pub mod server;
pub mod store;
pub mod telemetry;
pub mod tls;
