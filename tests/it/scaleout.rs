//! Scale-out (issue 10): an API-only process and a worker-only process
//! share the database and the blob store; progress, frames, SSE and the
//! live stream reach the API through the database alone. Runs on SQLite,
//! and on PostgreSQL when `TREEMORPH_TEST_POSTGRES_URL` is set (ignored
//! twin).

use std::sync::Arc;
use std::time::Duration;

use serde_json::Value;
use treemorph::config::Role;
use treemorph::jobs::testing::TestRunner;
use treemorph_api::delta::{DecoderOptions, decode_all};

use crate::common::{TestApp, frames_reported, read_events, spawn_in};

/// The API app, the worker app, and the directory they share (keep it).
async fn split(database_url: Option<String>) -> (TestApp, TestApp, tempfile::TempDir) {
    let shared = tempfile::tempdir().unwrap();
    let db = database_url
        .unwrap_or_else(|| format!("sqlite://{}/shared.db?mode=rwc", shared.path().display()));
    let blobs = url::Url::from_directory_path(shared.path().join("blobs"))
        .unwrap()
        .to_string();
    std::fs::create_dir_all(shared.path().join("blobs")).unwrap();
    let (db2, blobs2) = (db.clone(), blobs.clone());
    let api = spawn_in(
        tempfile::tempdir().unwrap(),
        Arc::new(TestRunner::slow(Duration::ZERO)),
        move |s| {
            s.role = Role::Api;
            s.database_url = Some(db);
            s.blob_url = Some(blobs);
        },
    )
    .await;
    let worker = spawn_in(
        tempfile::tempdir().unwrap(),
        Arc::new(TestRunner::slow(Duration::from_millis(40))),
        move |s| {
            s.role = Role::Worker;
            s.database_url = Some(db2);
            s.blob_url = Some(blobs2);
        },
    )
    .await;
    (api, worker, shared)
}

async fn run(api: TestApp, worker: TestApp) {
    // The worker process serves no API.
    let (s, _) = worker.get_json("/v1/trees").await;
    assert_eq!(s, 404);
    assert_eq!(worker.get("/healthz").await.status(), 200);
    let (a, b) = (api.tree(1).await, api.tree(2).await);
    let (s, job) = api.morph(&a, &b, 10).await;
    assert_eq!(s, 202);
    let id = job["id"].as_str().unwrap().to_owned();
    let (events_path, stream_path) = (
        format!("/v1/jobs/{id}/events"),
        format!("/v1/jobs/{id}/stream"),
    );
    let events = api.get(&events_path);
    let stream = api.get(&stream_path);
    let (events, stream) = tokio::join!(events, stream);
    let (events, bytes) = tokio::join!(read_events(events), stream.bytes());
    let bytes = bytes.unwrap();
    // The events request may reach the API after the worker published the
    // first frames: its opening job document counts those.
    assert_eq!(
        frames_reported(&events),
        (0..10).collect::<Vec<_>>(),
        "{events:?}"
    );
    assert_eq!(events.last().unwrap().0, "done", "{events:?}");
    let (_, decoded) = decode_all(&bytes, &DecoderOptions::default()).unwrap();
    assert_eq!(decoded.len(), 10);
    let (_, done): (u16, Value) = api.get_json(&format!("/v1/jobs/{id}")).await;
    assert_eq!(done["status"], "succeeded");
    // Cancellation crosses processes too (through the row).
    let (_, long) = api.morph(&a, &b, 500).await;
    let long = long["id"].as_str().unwrap().to_owned();
    api.wait_job(&long, |j| j["frames_ready"].as_u64().unwrap() >= 1)
        .await;
    api.delete(&format!("/v1/jobs/{long}")).await;
    let end = api.wait_status(&long, "cancelled").await;
    assert!(end["frames_ready"].as_u64().unwrap() < 500);
    // Deleting an ended job removes its blobs from the shared store.
    let blobs = &api.state.services.blobs;
    for job in [&id, &long] {
        let prefix = format!("jobs/{job}");
        assert_ne!(
            blobs.usage(&prefix).await.unwrap().0,
            0,
            "{job} stored nothing"
        );
        assert_eq!(api.delete(&format!("/v1/jobs/{job}")).await.0, 204);
        assert_eq!(
            blobs.usage(&prefix).await.unwrap(),
            (0, 0),
            "{job} left blobs"
        );
        assert_eq!(
            worker.state.services.blobs.usage(&prefix).await.unwrap(),
            (0, 0)
        );
    }
    worker.stop().await;
    api.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_api_process_and_a_worker_process_share_sqlite() {
    let (api, worker, _shared) = split(None).await;
    run(api, worker).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs TREEMORPH_TEST_POSTGRES_URL"]
async fn an_api_process_and_a_worker_process_share_postgres() {
    let admin = std::env::var("TREEMORPH_TEST_POSTGRES_URL").expect("TREEMORPH_TEST_POSTGRES_URL");
    let admin = admin.trim_end_matches('/').to_owned();
    let name = format!("treemorph_it_{}", treemorph::store::new_id());
    let db = treemorph::store::Db::connect(&format!("{admin}/postgres"))
        .await
        .unwrap();
    sqlx::query(sqlx::AssertSqlSafe(format!("CREATE DATABASE {name}")))
        .execute(&db.pool)
        .await
        .unwrap();
    let (api, worker, _shared) = split(Some(format!("{admin}/{name}"))).await;
    run(api, worker).await;
}
