//! The web viewer's files: `/` is `index.html`, `/app/…` the viewer's own
//! modules, `/vendor/three/…` and `/vendor/fzstd/…` the npm packages it
//! imports (installed by `npm ci --prefix web`, never copied into the
//! repository). These routes are not part of the API or its OpenAPI
//! document.
//!
//! Files are served from `--web-dir` at request time with tower-http's
//! `ServeDir`, which refuses paths that leave the directory. When the npm
//! packages are missing the page itself says what to run.

use axum::Router;
use tower_http::services::{ServeDir, ServeFile};

use super::AppState;

/// Routes serving the viewer from `state`'s web directory.
pub fn routes(state: &AppState) -> Router<AppState> {
    let dir = &state.settings().web_dir;
    let modules = dir.join("node_modules");
    Router::new()
        .route_service("/", ServeFile::new(dir.join("index.html")))
        .nest_service("/app", ServeDir::new(dir))
        .nest_service("/vendor/three", ServeDir::new(modules.join("three")))
        .nest_service("/vendor/fzstd", ServeDir::new(modules.join("fzstd")))
}
