//! Wire types shared by the treemorph server, client and CLI.
//!
//! The crate stays light (serde, thiserror, zstd, crc32fast, and utoipa's
//! derive for the OpenAPI schemas) because the CLI client links it too.
//!
//! - [`error`]: the error-code table and the uniform error body.
//! - [`trees`], [`jobs`]: the JSON documents of the `/v1` resources.
//!
//! - [`delta`]: the streamed binary frame format
//!   `application/vnd.treemorph.delta` — an encoder the service uses to send
//!   an animation while its job is still running, and an incremental decoder
//!   for clients. `api/README.md` specifies the format byte by byte; the web
//!   viewer's decoder (`web/delta.js`) is tested against the same fixture.

pub mod delta;
pub mod error;
pub mod int;
pub mod jobs;
pub mod trees;

pub use error::{ErrorBody, ErrorCode, ErrorDetail};
