//! `treemorph serve`: run the HTTP service (see [`crate::server`]).

use anyhow::Context;

use super::Failure;
use crate::config::Settings;

/// Runs the service until SIGTERM or Ctrl-C.
pub(super) fn run(settings: Settings) -> Result<(), Failure> {
    crate::telemetry::init_tracing();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(settings.listen)
            .await
            .with_context(|| format!("binding {}", settings.listen))?;
        let addr = listener.local_addr()?;
        // Scripts (and the crash tests) read the bound port from this line.
        println!("listening on http://{addr}");
        tracing::info!(%addr, role = ?settings.role, data_dir = %settings.data_dir.display(), "treemorph serve");
        crate::server::serve(settings, listener, crate::server::shutdown_signal()).await
    })?;
    Ok(())
}
