//! `/v1/jobs`: validation, completion, outputs, cancellation, idempotency,
//! the bounded queue, failures, panics and retries.

use std::sync::Arc;
use std::time::Duration;

use serde_json::{Value, json};
use treemorph::jobs::testing::{TestBehaviour, TestRunner, frame_glb, instant_glb, instant_stream};
use treemorph_api::ErrorCode;

use crate::common::{error_code, eventually, spawn, spawn_with};

fn sketch(tree: &str, frames: u32) -> Value {
    json!({
        "kind": "sketch", "tree": tree,
        "view": {"eye": [0, 2, 8], "target": [0, 2, 0], "up": [0, 1, 0], "fov_deg": 40},
        "sketch": {"points": [[-0.5, 0], [0.5, 0], [0, 0.8]], "closed": true},
        "frames": frames
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn morph_and_sketch_jobs_run_to_completion_with_all_outputs() {
    let app = spawn().await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .json(&json!({"kind": "morph", "source": a, "target": b, "frames": 5,
                      "options": {"matching": "one_to_one", "leaves": "random", "slow_down": false, "keyframes": 3}}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 202);
    let location = r.headers()["location"].to_str().unwrap().to_owned();
    let queued: Value = r.json().await.unwrap();
    assert_eq!(
        location,
        format!("/v1/jobs/{}", queued["id"].as_str().unwrap())
    );
    assert_eq!(queued["status"], "queued");
    assert_eq!(queued["kind"], "morph");
    assert_eq!(queued["attempt"], 0);
    let id = queued["id"].as_str().unwrap().to_owned();
    let done = app.wait_status(&id, "succeeded").await;
    assert_eq!(done["progress"], 1.0);
    assert_eq!(done["attempt"], 1);
    assert_eq!(done["frames_ready"], 5);
    let result = &done["result"];
    assert_eq!(result["frames"], 5);
    assert_eq!(result["metrics"]["runner"], "test");
    assert_eq!(
        result["links"]["animation"],
        format!("/v1/jobs/{id}/animation.glb")
    );
    assert_eq!(result["links"]["stream"], format!("/v1/jobs/{id}/stream"));
    assert_eq!(
        result["links"]["metrics"],
        format!("/v1/jobs/{id}/metrics.json")
    );
    assert_eq!(
        result["links"]["frames"],
        format!("/v1/jobs/{id}/frames/{{n}}.glb")
    );
    for n in 0..5u32 {
        let r = app.get(&format!("/v1/jobs/{id}/frames/{n}.glb")).await;
        assert_eq!(r.status(), 200);
        assert_eq!(r.headers()["content-type"], "model/gltf-binary");
        assert_eq!(r.bytes().await.unwrap().to_vec(), frame_glb(n));
    }
    for bad in ["5.glb", "x.glb", "1.gltf", "-1.glb", "99999999999.glb"] {
        let (s, b) = app.get_json(&format!("/v1/jobs/{id}/frames/{bad}")).await;
        assert_eq!((s, error_code(&b)), (404, "not_found"), "{bad}");
    }
    let r = app.get(&format!("/v1/jobs/{id}/animation.glb")).await;
    assert_eq!(r.status(), 200);
    assert!(r.headers().contains_key("etag"));
    assert_eq!(r.bytes().await.unwrap().to_vec(), frame_glb(u32::MAX));
    let (s, m) = app.get_json(&format!("/v1/jobs/{id}/metrics.json")).await;
    assert_eq!((s, &m["frames"]), (200, &json!(5)));

    // A sketch job without per-frame GLBs or animation.
    let mut body = sketch(&a, 3);
    body["outputs"] = json!({"glb": false, "animated": false});
    body["options"] = json!({"method": "single_cage", "fit": "crown"});
    let (s, job) = app.post_json("/v1/jobs", &body).await;
    assert_eq!(s, 202, "{job}");
    let id = job["id"].as_str().unwrap();
    let done = app.wait_status(id, "succeeded").await;
    assert_eq!(done["kind"], "sketch");
    assert!(done["result"]["links"].get("frames").is_none(), "{done}");
    assert!(done["result"]["links"].get("animation").is_none());
    let (s, _) = app.get_json(&format!("/v1/jobs/{id}/frames/0.glb")).await;
    assert_eq!(s, 404);
    let (s, _) = app.get_json(&format!("/v1/jobs/{id}/animation.glb")).await;
    assert_eq!(s, 404);

    // Listing with a status filter.
    let (s, page) = app.get_json("/v1/jobs?status=succeeded&limit=1").await;
    assert_eq!(s, 200);
    assert_eq!(page["items"].as_array().unwrap().len(), 1);
    assert_eq!(page["items"][0]["id"], id, "newest first");
    assert!(page["next_cursor"].is_string());
    let (_, page) = app.get_json("/v1/jobs?status=queued").await;
    assert_eq!(page["items"].as_array().unwrap().len(), 0);
    let (s, b) = app.get_json("/v1/jobs?status=sleeping").await;
    assert_eq!((s, error_code(&b)), (422, "invalid_request"));
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn job_requests_are_validated_before_queueing() {
    let runner = TestRunner::slow(Duration::ZERO).rejecting_frames(13);
    let app = spawn_with(Arc::new(runner), |s| s.max_frames = 50).await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let missing = "0192f0c0c0c0c0c0c0c0c0c0c0c0c0c0";
    let cases = [
        (
            json!({"kind": "morph", "source": a, "target": b, "frames": 5, "frobnicate": true}),
            422,
            "invalid_request",
            Some("frobnicate"),
        ),
        (
            json!({"kind": "morph", "source": a, "target": b, "frames": 5, "options": {"matchng": "one_to_one"}}),
            422,
            "invalid_request",
            Some("matchng"),
        ),
        (
            json!({"kind": "morph", "source": a, "target": b, "frames": 5, "options": {"matching": "all"}}),
            422,
            "invalid_request",
            Some("all"),
        ),
        (
            json!({"kind": "morph", "source": a, "target": b, "frames": 5, "outputs": {"gif": true}}),
            422,
            "invalid_request",
            Some("gif"),
        ),
        (
            json!({"kind": "dance", "tree": a, "frames": 5}),
            422,
            "invalid_request",
            Some("dance"),
        ),
        (
            json!({"kind": "morph", "source": a, "frames": 5}),
            422,
            "invalid_request",
            Some("target"),
        ),
        (
            json!({"kind": "morph", "source": a, "target": b, "frames": 1}),
            422,
            "invalid_request",
            Some("frames"),
        ),
        (
            json!({"kind": "morph", "source": a, "target": b, "frames": 51}),
            422,
            "invalid_request",
            Some("frames"),
        ),
        (
            json!({"kind": "morph", "source": a, "target": missing, "frames": 5}),
            404,
            "tree_not_found",
            None,
        ),
        (
            json!({"kind": "morph", "source": "../x", "target": b, "frames": 5}),
            404,
            "tree_not_found",
            None,
        ),
        (
            json!({"kind": "morph", "source": a, "target": b, "frames": 13}),
            422,
            "invalid_job",
            None,
        ),
        (
            json!({"kind": "morph", "source": a, "target": b, "frames": 5, "options": {"schedule": "eased"}}),
            422,
            "invalid_request",
            Some("schedule"),
        ),
        (
            json!({"kind": "morph", "source": a, "target": b, "frames": 5, "options": {"stagger": 2.0}}),
            422,
            "invalid_job",
            Some("stagger"),
        ),
        (
            json!({"kind": "morph", "source": a, "target": b, "frames": 5, "options": {"easing": -0.1}}),
            422,
            "invalid_job",
            Some("easing"),
        ),
        (
            json!({"kind": "morph", "source": a, "target": b, "frames": 5, "callback_url": "ftp://x/"}),
            422,
            "callback_url_refused",
            None,
        ),
    ];
    for (body, status, code, mentions) in cases {
        let (s, e) = app.post_json("/v1/jobs", &body).await;
        assert_eq!((s, error_code(&e)), (status, code), "{body} → {e}");
        if let Some(word) = mentions {
            assert!(
                e["error"]["message"].as_str().unwrap().contains(word),
                "{e}"
            );
        }
    }
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("content-type", "application/json")
        .body("{")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 400);
    assert_eq!(error_code(&r.json().await.unwrap()), "invalid_json");
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .body("{}")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 415);
    let (_, page) = app.get_json("/v1/jobs").await;
    assert_eq!(
        page["items"].as_array().unwrap().len(),
        0,
        "nothing was queued"
    );
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn max_frames_above_600_is_honoured_end_to_end() {
    // Regression: the server checked `--max-frames`, but the runner also
    // hard-coded 2..=600, so a raised limit had no effect.
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |s| {
        s.max_frames = 700
    })
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (s, job) = app.morph(&a, &b, 650).await;
    assert_eq!(s, 202, "{job}");
    let done = app
        .wait_status(job["id"].as_str().unwrap(), "succeeded")
        .await;
    assert_eq!(done["frames_ready"], 650, "{done}");
    let (s, e) = app.morph(&a, &b, 701).await;
    assert_eq!((s, error_code(&e)), (422, "invalid_request"), "{e}");
    assert!(
        e["error"]["message"].as_str().unwrap().contains("700"),
        "{e}"
    );
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn private_callback_urls_are_refused_by_default() {
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |s| {
        s.allow_private_callbacks = false
    })
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    for url in [
        "http://127.0.0.1:9/hook",
        "http://localhost/hook",
        "http://10.0.0.1/",
        "http://[::1]:80/",
        "http://169.254.169.254/",
    ] {
        let (s, e) = app
            .post_json("/v1/jobs", &json!({"kind": "morph", "source": a, "target": b, "frames": 3, "callback_url": url}))
            .await;
        assert_eq!((s, error_code(&e)), (422, "callback_url_refused"), "{url}");
    }
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cancel_queued_and_running_jobs() {
    // One worker, slow frames: the first job runs, the second waits.
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::from_millis(50))), |s| {
        s.workers = Some(1)
    })
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, running) = app.morph(&a, &b, 400).await;
    let running = running["id"].as_str().unwrap().to_owned();
    app.wait_job(&running, |j| j["frames_ready"].as_u64().unwrap() >= 2)
        .await;
    let (_, queued) = app.morph(&a, &b, 400).await;
    let queued = queued["id"].as_str().unwrap().to_owned();

    let (s, j) = app.delete(&format!("/v1/jobs/{queued}")).await;
    assert_eq!(s, 200);
    assert_eq!(j["status"], "cancelled");
    assert_eq!(j["error"]["code"], "cancelled");
    let (s, j) = app
        .post_json(&format!("/v1/jobs/{queued}/cancel"), &json!(null))
        .await;
    assert_eq!((s, &j["status"]), (200, &json!("cancelled")), "idempotent");

    let (s, j) = app.delete(&format!("/v1/jobs/{running}")).await;
    assert_eq!(s, 200);
    assert_eq!(j["status"], "running");
    assert_eq!(j["cancel_requested"], true);
    let before = j["frames_ready"].as_u64().unwrap();
    let end = app.wait_status(&running, "cancelled").await;
    // Within one frame of the request (plus the one in flight).
    assert!(end["frames_ready"].as_u64().unwrap() <= before + 2, "{end}");
    assert_eq!(end["error"]["code"], "cancelled");
    let (s, e) = app
        .get_json(&format!("/v1/jobs/{running}/animation.glb"))
        .await;
    assert_eq!((s, error_code(&e)), (404, "not_found"));
    let (s, e) = app.get_json(&format!("/v1/jobs/{running}/stream")).await;
    assert_eq!((s, error_code(&e)), (404, "not_found"));

    // The worker lives on: a new job completes.
    let (_, next) = app.morph(&a, &b, 2).await;
    app.wait_status(next["id"].as_str().unwrap(), "succeeded")
        .await;
    let next = next["id"].as_str().unwrap();
    let (s, e) = app
        .post_json(&format!("/v1/jobs/{next}/cancel"), &json!(null))
        .await;
    assert_eq!((s, error_code(&e)), (409, "job_finished"));
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn outputs_of_unfinished_jobs_are_not_ready() {
    let app = spawn_with(
        Arc::new(TestRunner::slow(Duration::from_millis(100))),
        |s| s.workers = Some(1),
    )
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 30).await;
    let id = job["id"].as_str().unwrap().to_owned();
    app.wait_job(&id, |j| j["frames_ready"].as_u64().unwrap() >= 1)
        .await;
    let r = app.get(&format!("/v1/jobs/{id}/frames/0.glb")).await;
    assert_eq!(
        r.status(),
        200,
        "published frames are served while the job runs"
    );
    let (s, e) = app.get_json(&format!("/v1/jobs/{id}/frames/29.glb")).await;
    assert_eq!((s, error_code(&e)), (409, "not_ready"));
    let (s, e) = app.get_json(&format!("/v1/jobs/{id}/animation.glb")).await;
    assert_eq!((s, error_code(&e)), (409, "not_ready"));
    let (s, e) = app.get_json(&format!("/v1/jobs/{id}/metrics.json")).await;
    assert_eq!((s, error_code(&e)), (409, "not_ready"));
    app.delete(&format!("/v1/jobs/{id}")).await;
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn concurrent_requests_with_one_idempotency_key_make_one_job() {
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::from_millis(5))), |_| {}).await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let body = json!({"kind": "morph", "source": a, "target": b, "frames": 4});
    let mut tasks = vec![];
    for _ in 0..12 {
        let (client, url, body) = (app.client.clone(), app.url("/v1/jobs"), body.clone());
        tasks.push(tokio::spawn(async move {
            let r = client
                .post(url)
                .header("idempotency-key", "k-1")
                .json(&body)
                .send()
                .await
                .unwrap();
            assert_eq!(r.status(), 202);
            r.json::<Value>().await.unwrap()["id"]
                .as_str()
                .unwrap()
                .to_owned()
        }));
    }
    let mut ids = vec![];
    for t in tasks {
        ids.push(t.await.unwrap());
    }
    ids.dedup();
    assert_eq!(ids.len(), 1, "{ids:?}");
    let (_, page) = app.get_json("/v1/jobs").await;
    assert_eq!(page["items"].as_array().unwrap().len(), 1);
    // Same body in another field order: still the same job.
    let reordered = json!({"frames": 4, "target": b, "source": a, "kind": "morph"});
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("idempotency-key", "k-1")
        .json(&reordered)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 202);
    assert_eq!(r.json::<Value>().await.unwrap()["id"], ids[0].as_str());
    // A different body with the key is refused.
    let other = json!({"kind": "morph", "source": a, "target": b, "frames": 5});
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("idempotency-key", "k-1")
        .json(&other)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 422);
    assert_eq!(
        error_code(&r.json().await.unwrap()),
        "idempotency_key_reused"
    );
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("idempotency-key", "")
        .json(&other)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 422);
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_queue_answers_429_with_retry_after() {
    let app = spawn_with(
        Arc::new(TestRunner::slow(Duration::from_millis(200))),
        |s| {
            s.workers = Some(1);
            s.max_queued = 2;
        },
    )
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, first) = app.morph(&a, &b, 50).await;
    app.wait_status(first["id"].as_str().unwrap(), "running")
        .await;
    assert_eq!(app.morph(&a, &b, 5).await.0, 202);
    assert_eq!(app.morph(&a, &b, 5).await.0, 202);
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .json(&json!({"kind": "morph", "source": a, "target": b, "frames": 5}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 429);
    assert!(
        r.headers()["retry-after"]
            .to_str()
            .unwrap()
            .parse::<u64>()
            .unwrap()
            >= 1
    );
    assert_eq!(error_code(&r.json().await.unwrap()), "queue_full");
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn failures_panics_and_transient_errors() {
    let runner = TestRunner::new(|req| match req.frames() {
        3 => TestBehaviour::Fail(ErrorCode::IncompatibleTrees),
        4 => TestBehaviour::Panic,
        5 => TestBehaviour::Flaky(1),
        _ => TestBehaviour::Frames(Duration::ZERO),
    });
    let app = spawn_with(Arc::new(runner), |s| s.max_attempts = 3).await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);

    let (_, job) = app.morph(&a, &b, 3).await;
    let end = app.wait_status(job["id"].as_str().unwrap(), "failed").await;
    assert_eq!(end["error"]["code"], "incompatible_trees");
    assert_eq!(end["attempt"], 1, "invalid input fails at once");

    let (_, job) = app.morph(&a, &b, 4).await;
    let end = app.wait_status(job["id"].as_str().unwrap(), "failed").await;
    assert_eq!(end["error"]["code"], "internal");
    assert!(
        !end["error"]["message"]
            .as_str()
            .unwrap()
            .contains("told to panic"),
        "opaque: {end}"
    );
    assert_eq!(end["attempt"], 1);

    // The panicking worker lives on, and a transient failure is retried.
    let (_, job) = app.morph(&a, &b, 5).await;
    let end = app
        .wait_status(job["id"].as_str().unwrap(), "succeeded")
        .await;
    assert_eq!(end["attempt"], 2, "{end}");
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn transient_failures_stop_after_max_attempts() {
    let runner = TestRunner::new(|_| TestBehaviour::Flaky(100));
    let app = spawn_with(Arc::new(runner), |s| s.max_attempts = 2).await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 5).await;
    let end = app.wait_status(job["id"].as_str().unwrap(), "failed").await;
    assert_eq!(end["attempt"], 2);
    assert_eq!(end["error"]["code"], "unavailable");
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_and_health_report() {
    let app = spawn().await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 3).await;
    let id = job["id"].as_str().unwrap();
    app.wait_status(id, "succeeded").await;
    app.get(&format!("/v1/jobs/{id}")).await;
    let (s, h) = app.get_json("/healthz").await;
    assert_eq!((s, &h["status"]), (200, &json!("ok")));
    let (s, _) = app.get_json("/readyz").await;
    assert_eq!(s, 200);
    let needles = [
        "treemorph_jobs{status=\"succeeded\"} 1",
        "treemorph_jobs{status=\"queued\"} 0",
        "route=\"/v1/jobs/{id}\",status=\"200\"",
        "treemorph_job_duration_seconds_count{kind=\"morph\",outcome=\"succeeded\"} 1",
        "treemorph_job_stage_duration_seconds_count{kind=\"morph\",stage=\"frames\"}",
        "treemorph_jobs_in_flight 0",
    ];
    let metrics = || async {
        let r = app.get("/metrics").await;
        assert_eq!(r.status(), 200);
        r.text().await.unwrap()
    };
    // The worker records the attempt's duration and leaves the in-flight
    // gauge once it has committed the job's end, so the job can answer
    // `succeeded` a moment before /metrics counts it (CI saw the duration
    // missing once).
    eventually(|| async {
        let text = metrics().await;
        needles.iter().all(|n| text.contains(n))
    })
    .await;
    let text = metrics().await;
    for needle in needles {
        assert!(text.contains(needle), "{needle} missing:\n{text}");
    }
    app.stop().await;
}

/// `GET /v1/jobs/{id}/frame.glb?t=`: the frame at any instant of a job
/// that succeeded, with an ETag that revalidates without rendering; bad
/// instants are 422, unfinished jobs 409, deleted ones 404.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_render_at_any_instant_on_request() {
    let app = spawn_with(
        Arc::new(TestRunner::slow(Duration::from_millis(30))),
        |_| {},
    )
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 5).await;
    let id = job["id"].as_str().unwrap().to_owned();
    let (s, e) = app
        .get_json(&format!("/v1/jobs/{id}/frame.glb?t=0.5"))
        .await;
    assert_eq!((s, error_code(&e)), (409, "not_ready"));
    app.wait_status(&id, "succeeded").await;

    let r = app.get(&format!("/v1/jobs/{id}/frame.glb?t=0.375")).await;
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "model/gltf-binary");
    let etag = r.headers()["etag"].to_str().unwrap().to_owned();
    assert_eq!(r.bytes().await.unwrap(), instant_glb(0.375));
    let again = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}/frame.glb?t=0.375")))
        .header("if-none-match", &etag)
        .send()
        .await
        .unwrap();
    assert_eq!(again.status(), 304);
    let other = app.get(&format!("/v1/jobs/{id}/frame.glb?t=0.5")).await;
    assert_ne!(other.headers()["etag"].to_str().unwrap(), etag);

    for bad in [
        "",
        "?t=",
        "?t=1.5",
        "?t=-0.1",
        "?t=abc",
        "?t=NaN",
        "?t=0.5&x=1",
    ] {
        let (s, e) = app.get_json(&format!("/v1/jobs/{id}/frame.glb{bad}")).await;
        assert_eq!((s, error_code(&e)), (422, "invalid_request"), "{bad}: {e}");
    }
    let (s, e) = app
        .get_json("/v1/jobs/0123456789abcdef0123456789abcdef/frame.glb?t=0.5")
        .await;
    assert_eq!((s, error_code(&e)), (404, "not_found"));
    assert_eq!(app.delete(&format!("/v1/jobs/{id}")).await.0, 204);
    let (s, e) = app
        .get_json(&format!("/v1/jobs/{id}/frame.glb?t=0.5"))
        .await;
    assert_eq!((s, error_code(&e)), (404, "not_found"));
    app.stop().await;
}

/// `GET /v1/jobs/{id}/stream?t=`: the frame at any instant as a one-frame
/// stream, rendered on request like `frame.glb?t=` and cached apart from
/// it; `t` with `frames`, or a bad `t`, is 422; unfinished jobs 409.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn streams_render_at_any_instant_on_request() {
    let runner = Arc::new(TestRunner::slow(Duration::from_millis(30)));
    let app = spawn_with(runner.clone(), |_| {}).await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 5).await;
    let id = job["id"].as_str().unwrap().to_owned();
    let (s, e) = app.get_json(&format!("/v1/jobs/{id}/stream?t=0.5")).await;
    assert_eq!((s, error_code(&e)), (409, "not_ready"));
    let done = app.wait_status(&id, "succeeded").await;
    assert_eq!(
        done["result"]["links"]["stream_at"],
        format!("/v1/jobs/{id}/stream?t={{t}}"),
        "{done}"
    );

    let r = app.get(&format!("/v1/jobs/{id}/stream?t=0.375")).await;
    assert_eq!(r.status(), 200);
    assert_eq!(
        r.headers()["content-type"],
        treemorph_api::delta::MEDIA_TYPE
    );
    let etag = r.headers()["etag"].to_str().unwrap().to_owned();
    assert_eq!(r.bytes().await.unwrap(), instant_stream(0.375));
    let glb = app.get(&format!("/v1/jobs/{id}/frame.glb?t=0.375")).await;
    assert_ne!(glb.headers()["etag"].to_str().unwrap(), etag);
    assert_eq!(glb.bytes().await.unwrap(), instant_glb(0.375));
    assert_eq!(
        runner.instants(),
        2,
        "the stream and the GLB share a cache entry"
    );
    let again = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}/stream?t=0.375")))
        .header("if-none-match", &etag)
        .send()
        .await
        .unwrap();
    assert_eq!(again.status(), 304);
    assert_eq!(runner.instants(), 2, "a cached instant was rendered again");

    // The frame record alone: its own media type and cache entry.
    let r = app
        .get(&format!("/v1/jobs/{id}/stream?t=0.375&header=false"))
        .await;
    assert_eq!(r.status(), 200);
    assert_eq!(
        r.headers()["content-type"],
        "application/vnd.treemorph.delta-frame"
    );
    assert_ne!(r.headers()["etag"].to_str().unwrap(), etag);
    assert_eq!(
        r.bytes().await.unwrap(),
        [&instant_stream(0.375)[..], b" frame"].concat()
    );
    assert_eq!(runner.instants(), 3);
    let whole = app
        .get(&format!("/v1/jobs/{id}/stream?t=0.375&header=true"))
        .await;
    assert_eq!(whole.headers()["etag"].to_str().unwrap(), etag);

    for bad in [
        "?t=",
        "?t=1.5",
        "?t=-0.1",
        "?t=abc",
        "?t=NaN",
        "?t=0.5&frames=4",
        "?t=0.5&header=no",
        "?header=false",
        "?frames=4&header=false",
    ] {
        let (s, e) = app.get_json(&format!("/v1/jobs/{id}/stream{bad}")).await;
        assert_eq!((s, error_code(&e)), (422, "invalid_request"), "{bad}: {e}");
    }
    app.stop().await;
}

/// A server whose test runner takes `ms` a frame, and its succeeded
/// morph of `frames` frames.
async fn succeeded_morph(
    ms: u64,
    frames: u32,
) -> (crate::common::TestApp, Arc<TestRunner>, String) {
    let runner = Arc::new(TestRunner::slow(Duration::from_millis(ms)));
    let app = spawn_with(runner.clone(), |_| {}).await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, frames).await;
    let id = job["id"].as_str().unwrap().to_owned();
    app.wait_status(&id, "succeeded").await;
    (app, runner, id)
}

/// Concurrent requests for one instant render it once, and the render is
/// kept for later requests; another instant renders anew.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_instant_renders_once_for_concurrent_requests() {
    let (app, runner, id) = succeeded_morph(100, 3).await;
    let path = format!("/v1/jobs/{id}/frame.glb?t=0.25");
    let answers = futures_util::future::join_all(
        (0..8).map(|_| async { app.get(&path).await.bytes().await.unwrap() }),
    )
    .await;
    assert!(answers.iter().all(|b| b[..] == instant_glb(0.25)[..]));
    assert_eq!(
        runner.instants(),
        1,
        "eight concurrent requests rendered more than once"
    );
    app.get(&path).await.bytes().await.unwrap();
    assert_eq!(runner.instants(), 1, "a cached render was rendered again");
    app.get(&format!("/v1/jobs/{id}/frame.glb?t=0.5")).await;
    assert_eq!(runner.instants(), 2);
    app.stop().await;
}

/// The first `stream?frames=N` of a job is sent as it renders (the header
/// record before the frames are made, 150 ms apart), a request that comes
/// meanwhile joins that render, and the finished stream is cached: one run
/// for all of them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_resampled_stream_is_sent_as_it_renders_and_rendered_once() {
    let (app, runner, id) = succeeded_morph(150, 2).await;
    let runs = runner.runs();
    let url = format!("/v1/jobs/{id}/stream?frames=6");

    let mut first = app.get(&url).await;
    assert_eq!(first.status(), 200);
    assert_eq!(
        first.headers()["content-type"],
        treemorph_api::delta::MEDIA_TYPE
    );
    let etag = first.headers()["etag"].to_str().unwrap().to_owned();
    let head = first.chunk().await.unwrap().expect("a first piece");
    let joined = app.get(&url).await;
    assert_eq!(joined.status(), 200);
    let mut whole = head.to_vec();
    while let Some(chunk) = first.chunk().await.unwrap() {
        whole.extend_from_slice(&chunk);
    }
    assert!(
        head.len() < whole.len(),
        "the whole stream came in one piece"
    );
    assert_eq!(joined.bytes().await.unwrap(), whole);
    let (_, frames) = treemorph_api::delta::decode_all(&whole, &Default::default()).unwrap();
    assert_eq!(frames.len(), 6);

    let cached = app.get(&url).await;
    assert_eq!(cached.headers()["etag"].to_str().unwrap(), etag);
    assert_eq!(cached.bytes().await.unwrap(), whole);
    let range = app
        .client
        .get(app.url(&url))
        .header("range", "bytes=0-3")
        .send()
        .await
        .unwrap();
    assert_eq!(range.status(), 206);
    assert_eq!(range.bytes().await.unwrap(), whole[..4]);
    assert_eq!(runner.runs(), runs + 1, "the re-sample ran more than once");
    app.stop().await;
}

/// `stream?frames=N` and `animation.glb?keyframes=K` re-sample a succeeded
/// job on request, once (cached, then 304 by ETag); bad counts are 422,
/// an unfinished job is 409.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sequences_are_resampled_on_request() {
    let runner = Arc::new(TestRunner::slow(Duration::from_millis(20)));
    let app = spawn_with(runner.clone(), |_| {}).await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 5).await;
    let id = job["id"].as_str().unwrap().to_owned();
    let (s, e) = app
        .get_json(&format!("/v1/jobs/{id}/stream?frames=9"))
        .await;
    assert_eq!((s, error_code(&e)), (409, "not_ready"));
    app.wait_status(&id, "succeeded").await;
    let runs = runner.runs();

    let r = app.get(&format!("/v1/jobs/{id}/stream?frames=9")).await;
    assert_eq!(r.status(), 200);
    assert_eq!(
        r.headers()["content-type"],
        treemorph_api::delta::MEDIA_TYPE
    );
    let etag = r.headers()["etag"].to_str().unwrap().to_owned();
    let (_, frames) =
        treemorph_api::delta::decode_all(&r.bytes().await.unwrap(), &Default::default()).unwrap();
    assert_eq!(frames.len(), 9);
    let own = app
        .get(&format!("/v1/jobs/{id}/stream"))
        .await
        .bytes()
        .await
        .unwrap();
    let (_, own) = treemorph_api::delta::decode_all(&own, &Default::default()).unwrap();
    assert_eq!(own.len(), 5, "the job's own stream changed");
    let again = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}/stream?frames=9")))
        .header("if-none-match", &etag)
        .send()
        .await
        .unwrap();
    assert_eq!(again.status(), 304);
    app.get(&format!("/v1/jobs/{id}/stream?frames=9"))
        .await
        .bytes()
        .await
        .unwrap();
    assert_eq!(runner.runs(), runs + 1, "a cached re-sample ran again");

    let r = app
        .get(&format!("/v1/jobs/{id}/animation.glb?keyframes=3"))
        .await;
    assert_eq!(r.status(), 200);
    assert_eq!(&r.bytes().await.unwrap()[..4], b"glTF");
    for bad in [
        "stream?frames=1",
        "stream?frames=100000",
        "stream?frames=x",
        "stream?frame=9",
        "animation.glb?keyframes=1",
        "animation.glb?keyframes=6",
        "animation.glb?keyframes=-2",
    ] {
        let (s, e) = app.get_json(&format!("/v1/jobs/{id}/{bad}")).await;
        assert_eq!((s, error_code(&e)), (422, "invalid_request"), "{bad}: {e}");
    }
    app.stop().await;
}
