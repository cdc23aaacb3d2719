//! The committed `openapi.yaml` is the one the code generates and serves.

use crate::common::spawn;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_committed_openapi_document_matches_the_code() {
    let app = spawn().await;
    let r = app.get("/openapi.yaml").await;
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "application/yaml");
    let served = r.text().await.unwrap();
    assert_eq!(served, treemorph::server::openapi::yaml());
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/openapi.yaml");
    if std::env::var_os("UPDATE_OPENAPI").is_some() {
        std::fs::write(path, &served).unwrap();
    }
    let committed = std::fs::read_to_string(path).unwrap_or_default();
    assert!(
        committed == served,
        "openapi.yaml is out of date: run `UPDATE_OPENAPI=1 cargo test -p treemorph --test it openapi` and commit it"
    );
    for route in [
        "/v1/trees:",
        "/v1/trees/generate:",
        "/v1/trees/{id}:",
        "/v1/trees/{id}/model.glb:",
        "/v1/trees/{id}/tree.json:",
        "/v1/trees/{id}/analysis:",
        "/v1/jobs:",
        "/v1/jobs/{id}:",
        "/v1/jobs/{id}/events:",
        "/v1/jobs/{id}/stream:",
        "/v1/jobs/{id}/frames/{frame}:",
        "/v1/jobs/{id}/animation.glb:",
        "/v1/jobs/{id}/metrics.json:",
        "/healthz:",
        "/readyz:",
        "/metrics:",
        "/openapi.yaml:",
    ] {
        assert!(served.contains(route), "{route} is not documented");
    }
    app.stop().await;
}
