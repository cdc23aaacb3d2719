//! The TLS crypto provider of every HTTPS client the process builds: S3
//! through object_store, webhook deliveries and `treemorph client`.
//!
//! reqwest is built without a provider of its own (`rustls-no-provider`):
//! its default, AWS-LC, is a large C library, and ring serves the same
//! clients. reqwest then panics when it builds a client before a process
//! default is installed, so our clients start from [`client_builder`],
//! which installs it, and code that lets a library build its own clients
//! (object_store's S3 client) calls [`install_crypto_provider`] first.

use std::sync::Once;

/// Makes ring rustls's process-wide crypto provider. Idempotent, and
/// cheap after the first call.
pub fn install_crypto_provider() {
    static INSTALL: Once = Once::new();
    INSTALL.call_once(|| {
        // An error means another provider was installed first, which
        // serves these clients as well.
        let _ = rustls::crypto::ring::default_provider().install_default();
    });
}

/// A reqwest client builder, with the crypto provider installed: every
/// reqwest client of ours starts here, so none can be built before it.
pub fn client_builder() -> reqwest::ClientBuilder {
    install_crypto_provider();
    reqwest::Client::builder()
}
