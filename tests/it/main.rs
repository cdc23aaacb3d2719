//! Integration tests of `treemorph serve`: real servers on port 0 (in
//! process, with a test runner injected through the app state), and for the
//! crash and shutdown tests the real binary; and of the binary's local
//! commands (`cli`) and client (`client`).

mod cli;
mod client;
mod common;
mod e2e;
mod fleet;
mod hostile;
mod jobs;
mod openapi;
mod plan_first;
mod process;
mod retention;
mod scaleout;
mod scripts;
mod security;
mod streaming;
mod trees;
mod webhooks;
