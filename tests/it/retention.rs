//! Deleting ended jobs with every blob they own, `--result-ttl`, and the
//! sweep of what crashes leave behind. Blobs are counted as files under
//! the data directory's blob store, before and after.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use serde_json::json;
use treemorph::jobs::retention;
use treemorph::jobs::testing::TestRunner;
use treemorph::store::new_id;

use crate::common::{TestApp, error_code, eventually, files, spawn, spawn_with};

fn blob_files(app: &TestApp) -> Vec<PathBuf> {
    files(&app.dir.path().join("blobs"))
}

/// A finished 4-frame morph between two new trees; returns the job id.
async fn finished_job(app: &TestApp, a: &str, b: &str) -> String {
    let (status, job) = app.morph(a, b, 4).await;
    assert_eq!(status, 202, "{job}");
    let id = job["id"].as_str().unwrap().to_owned();
    app.wait_status(&id, "succeeded").await;
    // Its stream records go right after the success: wait until the blobs
    // it keeps have settled.
    let dir = app.dir.path().join("blobs").join("jobs").join(&id);
    let records = || {
        files(&dir)
            .iter()
            .any(|p| p.components().any(|c| c.as_os_str() == "stream"))
    };
    eventually(|| async { !records() }).await;
    assert!(!records(), "the stream records stayed");
    id
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn deleting_an_ended_job_removes_it_and_every_blob_it_owns() {
    let app = spawn().await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let before = blob_files(&app);
    let id = finished_job(&app, &a, &b).await;
    assert!(
        blob_files(&app).len() > before.len(),
        "the job stored nothing"
    );

    let r = app
        .client
        .delete(app.url(&format!("/v1/jobs/{id}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 204);
    assert!(r.bytes().await.unwrap().is_empty());
    assert_eq!(blob_files(&app), before, "blobs left behind");
    for path in [
        "",
        "/frames/0.glb",
        "/animation.glb",
        "/metrics.json",
        "/stream",
    ] {
        let (s, e) = app.get_json(&format!("/v1/jobs/{id}{path}")).await;
        assert_eq!((s, error_code(&e)), (404, "not_found"), "{path}");
    }
    let (s, e) = app.delete(&format!("/v1/jobs/{id}")).await;
    assert_eq!((s, error_code(&e)), (404, "not_found"));
    let (_, page) = app.get_json("/v1/jobs").await;
    assert!(
        page["items"]
            .as_array()
            .unwrap()
            .iter()
            .all(|j| j["id"] != id.as_str())
    );
    // The trees stay, and a tree no job uses any more can be deleted.
    let (s, _) = app.get_json(&format!("/v1/trees/{a}")).await;
    assert_eq!(s, 200);
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancelled_job_is_deleted_by_the_next_delete() {
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::from_millis(50))), |s| {
        s.workers = Some(1)
    })
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let before = blob_files(&app);
    let (_, running) = app.morph(&a, &b, 400).await;
    let running = running["id"].as_str().unwrap().to_owned();
    app.wait_job(&running, |j| j["frames_ready"].as_u64().unwrap() >= 2)
        .await;
    let (s, j) = app.delete(&format!("/v1/jobs/{running}")).await;
    assert_eq!((s, &j["cancel_requested"]), (200, &json!(true)));
    app.wait_status(&running, "cancelled").await;
    // Its published frames are a partial result until it is deleted.
    let (s, _) = app
        .get_json(&format!("/v1/jobs/{running}/frames/0.glb"))
        .await;
    assert_eq!(s, 200);
    let (s, _) = app.delete(&format!("/v1/jobs/{running}")).await;
    assert_eq!(s, 204);
    let (s, _) = app.get_json(&format!("/v1/jobs/{running}")).await;
    assert_eq!(s, 404);
    assert_eq!(blob_files(&app), before, "blobs left behind");
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ended_jobs_expire_after_the_result_ttl_and_trees_stay() {
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |s| {
        s.result_ttl = "2s".parse().unwrap();
        s.sweep_secs = 1;
    })
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let before = blob_files(&app);
    let id = finished_job(&app, &a, &b).await;
    let (s, _) = app.get_json(&format!("/v1/jobs/{id}")).await;
    assert_eq!(s, 200, "expired at once");
    let deadline = tokio::time::Instant::now() + Duration::from_secs(20);
    while app.get_json(&format!("/v1/jobs/{id}")).await.0 != 404 {
        assert!(
            tokio::time::Instant::now() < deadline,
            "the job never expired"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // The row goes first and the blobs right after it, in the same sweep:
    // a job that answers 404 may still be losing its blobs.
    eventually(|| async { blob_files(&app) == before }).await;
    assert_eq!(blob_files(&app), before, "blobs left behind");
    let (s, _) = app.get_json(&format!("/v1/trees/{a}")).await;
    assert_eq!(s, 200, "trees do not expire");
    app.stop().await;
}

/// Blobs a crash left without a row (a kill -9 between an upload's blobs
/// and its row, or a worker's writes after its job was deleted) go once
/// they are older than twice the request timeout; newer ones may belong
/// to a request in flight and stay.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn blobs_without_a_row_are_swept_once_old() {
    let app = spawn().await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let kept = finished_job(&app, &a, &b).await;
    let before = blob_files(&app);
    let blobs = &app.state.services.blobs;
    let (old_job, old_tree, new_tree) = (new_id(), new_id(), new_id());
    let old = [
        format!("jobs/{old_job}/token/files/animation.glb"),
        format!("trees/{old_tree}/original"),
    ];
    for key in old.iter().chain([&format!("trees/{new_tree}/original")]) {
        blobs.put(key, b"orphan".to_vec()).await.unwrap();
    }
    let an_hour_ago = SystemTime::now() - Duration::from_secs(3600);
    for key in &old {
        let path = app.dir.path().join("blobs").join(key);
        std::fs::File::options()
            .write(true)
            .open(&path)
            .unwrap()
            .set_modified(an_hour_ago)
            .unwrap();
    }
    // Webhook records of a deleted job: the done one goes, the pending
    // one stays until it is delivered.
    let db = &app.state.services.db;
    for (id, state) in [("msg_done", "delivered"), ("msg_pending", "pending")] {
        sqlx::query(
            "INSERT INTO webhook_deliveries (id, job_id, url, body, state, attempts, next_at, created_at) \
             VALUES ($1, $2, 'http://127.0.0.1:9/', '{}', $3, 1, $4, 0)",
        )
        .bind(id)
        .bind(&old_job)
        .bind(state)
        .bind(i64::MAX)
        .execute(&db.writer)
        .await
        .unwrap();
    }
    let swept = retention::sweep(&app.state.services).await.unwrap();
    assert_eq!(swept.orphan_prefixes, 2, "{swept:?}");
    assert_eq!(swept.webhook_records, 1, "{swept:?}");
    let (left,): (String,) = sqlx::query_as("SELECT id FROM webhook_deliveries")
        .fetch_one(&db.pool)
        .await
        .unwrap();
    assert_eq!(left, "msg_pending");
    let mut expected = before.clone();
    expected.push(
        app.dir
            .path()
            .join("blobs")
            .join(format!("trees/{new_tree}/original")),
    );
    expected.sort();
    assert_eq!(blob_files(&app), expected);
    assert!(
        !app.dir.path().join("blobs/jobs").join(&old_job).exists(),
        "empty directories stay"
    );
    let (s, _) = app
        .get_json(&format!("/v1/jobs/{kept}/animation.glb"))
        .await;
    assert_eq!(s, 200, "a job with a row lost its outputs");
    app.stop().await;
}

fn bytes_of(paths: &[PathBuf]) -> u64 {
    paths
        .iter()
        // (A file may go between the listing and this: a sweep or the
        // worker's cleanup.)
        .filter_map(|p| std::fs::metadata(p).ok())
        .map(|m| m.len())
        .sum()
}

/// The per-key quota counts the blobs a key's trees and jobs store (the
/// bytes on disk), refuses the upload that would exceed it and a job
/// while the key is at it (507 `quota_exceeded`), and deleting makes room.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_storage_quota_counts_stored_bytes_and_deleting_makes_room() {
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |s| {
        s.max_stored_mb_per_key = 1;
    })
    .await;
    let db = &app.state.services.db;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let job = finished_job(&app, &a, &b).await;
    // The worker drops the stream records and counts the rest right after
    // the job's end is committed: the count settles on the bytes on disk.
    let counted = || async { db.stored_bytes("anonymous").await.unwrap() as u64 };
    eventually(|| async { counted().await == bytes_of(&blob_files(&app)) }).await;
    assert_eq!(
        counted().await,
        bytes_of(&blob_files(&app)),
        "the count is not what is stored"
    );

    // Fill up: trees until one would exceed the quota.
    let mut trees = vec![a, b];
    let refused = loop {
        let (status, body) = app
            .post_json(
                "/v1/trees/generate",
                &json!({"preset": "maple", "seed": trees.len(), "size": 120}),
            )
            .await;
        match status {
            201 => trees.push(body["id"].as_str().unwrap().to_owned()),
            _ => break (status, body),
        }
        assert!(trees.len() < 500, "the quota never bit");
    };
    assert_eq!(
        (refused.0, error_code(&refused.1)),
        (507, "quota_exceeded"),
        "{}",
        refused.1
    );
    let stored = db.stored_bytes("anonymous").await.unwrap() as u64;
    assert!(
        stored <= 1024 * 1024,
        "{stored} bytes stored under a 1 MiB quota"
    );
    assert_eq!(stored, bytes_of(&blob_files(&app)));

    // Deleting a job and a tree makes room again.
    assert_eq!(app.delete(&format!("/v1/jobs/{job}")).await.0, 204);
    assert_eq!(
        app.delete(&format!("/v1/trees/{}", trees.pop().unwrap()))
            .await
            .0,
        204
    );
    assert_eq!(
        db.stored_bytes("anonymous").await.unwrap() as u64,
        bytes_of(&blob_files(&app))
    );
    let (status, body) = app
        .post_json(
            "/v1/trees/generate",
            &json!({"preset": "maple", "seed": 1000, "size": 120}),
        )
        .await;
    assert_eq!(status, 201, "{body}");
    app.stop().await;
}

/// A job is refused while the key is at its quota: its outputs cannot be
/// known before it runs.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_is_refused_while_the_key_is_at_its_quota() {
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |s| {
        s.max_stored_mb_per_key = 1;
    })
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    // Jobs until the key is at its quota (each stores its outputs).
    for _ in 0..200 {
        let (status, body) = app.morph(&a, &b, 40).await;
        if status == 507 {
            assert_eq!(error_code(&body), "quota_exceeded", "{body}");
            app.stop().await;
            return;
        }
        assert_eq!(status, 202, "{body}");
        app.wait_status(body["id"].as_str().unwrap(), "succeeded")
            .await;
    }
    panic!("jobs were never refused");
}
