//! Plan-first jobs: a job stores its delta stream and metrics, and the
//! per-frame GLBs and the animated GLB are rendered when first asked for,
//! behind the routes and links a job that stored everything has.

use std::sync::Arc;
use std::time::Duration;

use serde_json::json;
use treemorph::jobs::testing::{TestRunner, instant_glb};
use treemorph::pipeline::frame_instant;
use treemorph::store::renders::RenderStore;

use crate::common::{error_code, eventually, files, spawn_with};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn jobs_store_their_stream_and_render_frames_and_the_animation_on_request() {
    let runner = Arc::new(TestRunner::slow(Duration::from_millis(60)).plan_first());
    let app = spawn_with(runner.clone(), |_| {}).await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 5).await;
    let id = job["id"].as_str().unwrap().to_owned();

    // A published frame renders while the job runs.
    app.wait_job(&id, |j| j["frames_ready"].as_u64() >= Some(2))
        .await;
    let r = app.get(&format!("/v1/jobs/{id}/frames/1.glb")).await;
    assert_eq!(r.status(), 200);
    assert_eq!(r.bytes().await.unwrap(), instant_glb(frame_instant(1, 5)));
    let (s, e) = app.get_json(&format!("/v1/jobs/{id}/frames/4.glb")).await;
    if s != 200 {
        assert_eq!((s, error_code(&e)), (409, "not_ready"));
    }
    let done = app.wait_status(&id, "succeeded").await;

    // The job stores its stream and its metrics, nothing else (the
    // per-frame stream records go right after the success), and links
    // every output it was asked for.
    let job_dir = app.dir.path().join("blobs").join("jobs").join(&id);
    // (Renders kept in the blob store are a cache beside them.)
    let names = || -> Vec<String> {
        files(&job_dir)
            .iter()
            .filter(|p| !p.components().any(|c| c.as_os_str() == "renders"))
            .map(|p| p.file_name().unwrap().to_str().unwrap().to_owned())
            .collect()
    };
    eventually(|| async { names().len() <= 2 }).await;
    assert_eq!(names(), ["metrics.json", "stream.tmd"]);
    let links = &done["result"]["links"];
    assert_eq!(links["frames"], format!("/v1/jobs/{id}/frames/{{n}}.glb"));
    assert_eq!(links["animation"], format!("/v1/jobs/{id}/animation.glb"));
    assert_eq!(links["stream"], format!("/v1/jobs/{id}/stream"));

    // Every frame renders at its instant, with an ETag, 304 and ranges.
    for n in 0..5 {
        let r = app.get(&format!("/v1/jobs/{id}/frames/{n}.glb")).await;
        assert_eq!(r.status(), 200, "frame {n}");
        assert_eq!(r.headers()["content-type"], "model/gltf-binary");
        assert_eq!(r.bytes().await.unwrap(), instant_glb(frame_instant(n, 5)));
    }
    let path = app.url(&format!("/v1/jobs/{id}/frames/2.glb"));
    let r = app
        .client
        .get(&path)
        .header("range", "bytes=0-3")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 206);
    let len = instant_glb(0.5).len();
    assert_eq!(
        r.headers()["content-range"],
        format!("bytes 0-3/{len}").as_str()
    );
    let etag = r.headers()["etag"].to_str().unwrap().to_owned();
    assert_eq!(&r.bytes().await.unwrap()[..], b"glTF");
    let r = app
        .client
        .get(&path)
        .header("range", "bytes=900-")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 416);
    let r = app
        .client
        .get(&path)
        .header("if-none-match", &etag)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 304);
    let (s, e) = app.get_json(&format!("/v1/jobs/{id}/frames/5.glb")).await;
    assert_eq!((s, error_code(&e)), (404, "not_found"));

    // The animated GLB renders once, in a run of its own, then is kept.
    let runs = runner.runs();
    let first = app.get(&format!("/v1/jobs/{id}/animation.glb")).await;
    assert_eq!(first.status(), 200);
    let first = first.bytes().await.unwrap();
    assert_eq!(&first[..4], b"glTF");
    let again = app.get(&format!("/v1/jobs/{id}/animation.glb")).await;
    assert_eq!(again.bytes().await.unwrap(), first);
    assert_eq!(runner.runs(), runs + 1);

    // The stored stream and metrics serve as before.
    let r = app.get(&format!("/v1/jobs/{id}/stream")).await;
    assert_eq!(r.status(), 200);
    assert!(!r.bytes().await.unwrap().is_empty());
    let (s, _) = app.get_json(&format!("/v1/jobs/{id}/metrics.json")).await;
    assert_eq!(s, 200);
    app.stop().await;
}

/// Outputs a job did not ask for are not rendered either.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn outputs_left_out_of_the_request_stay_404() {
    let runner = Arc::new(TestRunner::slow(Duration::ZERO).plan_first());
    let app = spawn_with(runner, |_| {}).await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (s, job) = app
        .post_json(
            "/v1/jobs",
            &json!({"kind": "morph", "source": a, "target": b, "frames": 3,
                    "outputs": {"glb": false, "animated": false, "delta": true}}),
        )
        .await;
    assert_eq!(s, 202, "{job}");
    let id = job["id"].as_str().unwrap().to_owned();
    let done = app.wait_status(&id, "succeeded").await;
    assert!(done["result"]["links"]["frames"].is_null(), "{done}");
    // Its (empty) stream records go after the success too.
    let job_dir = app.dir.path().join("blobs").join("jobs").join(&id);
    eventually(|| async { files(&job_dir).len() <= 2 }).await;
    let names: Vec<_> = files(&job_dir)
        .iter()
        .map(|p| p.file_name().unwrap().to_str().unwrap().to_owned())
        .collect();
    assert_eq!(names, ["metrics.json", "stream.tmd"]);
    assert!(done["result"]["links"]["animation"].is_null(), "{done}");
    for path in ["frames/0.glb", "animation.glb"] {
        let (s, e) = app.get_json(&format!("/v1/jobs/{id}/{path}")).await;
        assert_eq!((s, error_code(&e)), (404, "not_found"), "{path}");
    }
    app.stop().await;
}

/// A job run by another version of the renderer renders nothing more
/// (its renders would not be the bytes it wrote): 410 `plan_outdated`
/// saying how to re-run it. What it stored still serves.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn jobs_of_another_render_version_answer_410_for_renders() {
    let runner = Arc::new(TestRunner::slow(Duration::ZERO).plan_first());
    let app = spawn_with(runner, |_| {}).await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 3).await;
    let id = job["id"].as_str().unwrap().to_owned();
    app.wait_status(&id, "succeeded").await;
    let db = &app.state.services.db;
    let (result,): (String,) = sqlx::query_as("SELECT result FROM jobs WHERE id = $1")
        .bind(&id)
        .fetch_one(&db.pool)
        .await
        .unwrap();
    let mut result: serde_json::Value = serde_json::from_str(&result).unwrap();
    assert_eq!(
        result["render_version"],
        treemorph::pipeline::RENDER_VERSION
    );
    result["render_version"] = json!(0);
    sqlx::query("UPDATE jobs SET result = $1 WHERE id = $2")
        .bind(result.to_string())
        .bind(&id)
        .execute(&db.writer)
        .await
        .unwrap();
    for path in [
        "frames/0.glb",
        "animation.glb",
        "frame.glb?t=0.5",
        "animation.glb?keyframes=2",
        "stream?frames=4",
    ] {
        let (s, e) = app.get_json(&format!("/v1/jobs/{id}/{path}")).await;
        assert_eq!((s, error_code(&e)), (410, "plan_outdated"), "{path}: {e}");
        let message = e["error"]["message"].as_str().unwrap();
        assert!(message.contains("post the same request again"), "{message}");
    }
    for path in ["stream", "metrics.json"] {
        assert_eq!(
            app.get(&format!("/v1/jobs/{id}/{path}")).await.status(),
            200
        );
    }
    app.stop().await;
}

/// A render is stored under its job in the blob store: another process
/// (or this one after a restart) serves it without rendering, and it goes
/// with the job.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn renders_are_kept_in_the_blob_store_for_every_process() {
    let first_runner = Arc::new(TestRunner::slow(Duration::ZERO).plan_first());
    let first = spawn_with(first_runner.clone(), |_| {}).await;
    let (a, b) = (first.tree(1).await, first.tree(2).await);
    let (_, job) = first.morph(&a, &b, 3).await;
    let id = job["id"].as_str().unwrap().to_owned();
    first.wait_status(&id, "succeeded").await;
    let path = format!("/v1/jobs/{id}/frames/1.glb");
    let made = first.get(&path).await.bytes().await.unwrap();
    assert_eq!(first_runner.instants(), 1);
    // Stored in the background: the blob first, then its record.
    let job_dir = first.dir.path().join("blobs").join("jobs").join(&id);
    let db = &first.state.services.db;
    let records = || async {
        let (n,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM renders")
            .fetch_one(&db.pool)
            .await
            .unwrap();
        n
    };
    eventually(|| async { records().await > 0 }).await;
    let stored = files(&job_dir);
    assert!(
        stored
            .iter()
            .any(|p| p.ends_with("renders/frames/000001.glb")),
        "the render was not stored: {stored:?}"
    );

    let settings = first.state.settings().clone();
    let second_runner = Arc::new(TestRunner::slow(Duration::ZERO).plan_first());
    let second = spawn_with(second_runner.clone(), |s| {
        s.database_url = Some(settings.database_url());
        s.blob_url = Some(settings.blob_url().unwrap());
    })
    .await;
    assert_eq!(second.get(&path).await.bytes().await.unwrap(), made);
    assert_eq!(second_runner.instants(), 0, "the second process rendered");

    assert_eq!(first.delete(&format!("/v1/jobs/{id}")).await.0, 204);
    assert!(files(&job_dir).is_empty());
    // The record goes with the next sweep: ours below, or the second
    // process's start-up sweep when that runs late (it is spawned, and a
    // busy machine can delay it past the delete).
    treemorph::jobs::retention::sweep(&first.state.services)
        .await
        .unwrap();
    assert_eq!(records().await, 0, "a render record outlived its job");
    second.stop().await;
    first.stop().await;
}

/// The stored renders stay within their cap: the least recently used go
/// first, blob and record.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stored_renders_past_the_cap_evict_the_least_recently_used() {
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |_| {}).await;
    // Renders of a job that exists, under its published attempt (a sweep
    // drops the records of other jobs, and an attempt deletes the blobs of
    // the job's other attempts when it starts).
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 2).await;
    let id = job["id"].as_str().unwrap().to_owned();
    app.wait_status(&id, "succeeded").await;
    let services = &app.state.services;
    let (token,): (String,) = sqlx::query_as("SELECT published_token FROM jobs WHERE id = $1")
        .bind(&id)
        .fetch_one(&services.db.pool)
        .await
        .unwrap();
    let store = RenderStore::new(services.blobs.clone(), services.db.clone(), 50);
    let key = |n: u32| format!("jobs/{id}/{token}/at/{n}");
    let render = |n: u8| bytes::Bytes::from(vec![n; 20]);
    for n in 1..=2u8 {
        store.save(&key(n.into()), render(n)).await;
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    // Using render 1 makes render 2 the least recently used.
    assert_eq!(store.load(&key(1)).await, Some(render(1)));
    tokio::time::sleep(Duration::from_millis(5)).await;
    store.save(&key(3), render(3)).await;
    assert_eq!(store.load(&key(2)).await, None);
    assert_eq!(store.load(&key(1)).await, Some(render(1)));
    assert_eq!(store.load(&key(3)).await, Some(render(3)));
    let (rows,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM renders")
        .fetch_one(&services.db.pool)
        .await
        .unwrap();
    assert_eq!(rows, 2);
    // Larger than the cap: not stored at all.
    store.save(&key(4), bytes::Bytes::from(vec![4; 60])).await;
    assert_eq!(store.load(&key(4)).await, None);
    app.stop().await;
}
