//! Wire types shared by the treemorph server, client and CLI.
//!
//! The crate stays light (serde, thiserror, zstd, crc32fast) because the CLI
//! client links it too.
//!
//! - [`delta`]: the streamed binary frame format
//!   `application/vnd.treemorph.delta` — an encoder the service uses to send
//!   an animation while its job is still running, and an incremental decoder
//!   for clients. `api/README.md` specifies the format byte by byte; the web
//!   viewer's decoder (`web/delta.js`) is tested against the same fixture.

pub mod delta;
