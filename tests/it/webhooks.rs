//! Webhooks: a local receiver checks the Standard Webhooks signature; a
//! failed delivery is retried.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::http::{HeaderMap, StatusCode};
use base64::Engine;
use hmac::{KeyInit, Mac};
use serde_json::{Value, json};
use treemorph::jobs::testing::TestRunner;

use crate::common::spawn_with;

#[derive(Clone, Default)]
struct Received {
    calls: Arc<Mutex<Vec<(HeaderMap, String)>>>,
    fail_first: Arc<Mutex<u32>>,
}

async fn receiver(received: Received) -> String {
    let app = axum::Router::new().route(
        "/hook",
        axum::routing::post(
            |axum::extract::State(r): axum::extract::State<Received>,
             headers: HeaderMap,
             body: String| async move {
                r.calls.lock().unwrap().push((headers, body));
                let mut fail = r.fail_first.lock().unwrap();
                if *fail > 0 {
                    *fail -= 1;
                    StatusCode::INTERNAL_SERVER_ERROR
                } else {
                    StatusCode::NO_CONTENT
                }
            },
        ),
    );
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let url = format!("http://{}/hook", listener.local_addr().unwrap());
    tokio::spawn(async move {
        axum::serve(listener, app.with_state(received))
            .await
            .unwrap()
    });
    url
}

fn verify(secret: &str, headers: &HeaderMap, body: &str) {
    let key = base64::engine::general_purpose::STANDARD
        .decode(secret.strip_prefix("whsec_").unwrap())
        .unwrap();
    let id = headers["webhook-id"].to_str().unwrap();
    let ts = headers["webhook-timestamp"].to_str().unwrap();
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs();
    assert!(ts.parse::<u64>().unwrap().abs_diff(now) < 60);
    let mut mac = hmac::Hmac::<sha2::Sha256>::new_from_slice(&key).unwrap();
    mac.update(format!("{id}.{ts}.{body}").as_bytes());
    let expected = base64::engine::general_purpose::STANDARD.encode(mac.finalize().into_bytes());
    let sigs = headers["webhook-signature"].to_str().unwrap();
    assert!(
        sigs.split(' ').any(|s| s == format!("v1,{expected}")),
        "bad signature {sigs}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn completion_is_posted_signed_and_retried_after_a_500() {
    let received = Received::default();
    *received.fail_first.lock().unwrap() = 1;
    let url = receiver(received.clone()).await;
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |_| {}).await;
    let secret = app.state.settings().webhook_secret.clone().unwrap();
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (s, job) = app
        .post_json(
            "/v1/jobs",
            &json!({"kind": "morph", "source": a, "target": b, "frames": 3, "callback_url": url}),
        )
        .await;
    assert_eq!(s, 202, "{job}");
    let id = job["id"].as_str().unwrap().to_owned();
    app.wait_status(&id, "succeeded").await;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(20);
    while received.calls.lock().unwrap().len() < 2 {
        assert!(tokio::time::Instant::now() < deadline, "no retry arrived");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    tokio::time::sleep(Duration::from_millis(700)).await;
    let calls = received.calls.lock().unwrap().clone();
    assert_eq!(calls.len(), 2, "delivered once after one failure");
    for (headers, body) in &calls {
        verify(&secret, headers, body);
        let doc: Value = serde_json::from_str(body).unwrap();
        assert_eq!(doc["id"], id.as_str());
        assert_eq!(doc["status"], "succeeded");
        assert_eq!(doc["result"]["frames"], 3);
    }
    assert_eq!(
        calls[0].0["webhook-id"], calls[1].0["webhook-id"],
        "the id is stable across retries"
    );
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cancelling_a_queued_job_posts_its_webhook() {
    let received = Received::default();
    let url = receiver(received.clone()).await;
    let app = spawn_with(
        Arc::new(TestRunner::slow(Duration::from_millis(100))),
        |s| s.workers = Some(1),
    )
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, blocker) = app.morph(&a, &b, 100).await;
    app.wait_status(blocker["id"].as_str().unwrap(), "running")
        .await;
    let (_, job) = app
        .post_json(
            "/v1/jobs",
            &json!({"kind": "morph", "source": a, "target": b, "frames": 3, "callback_url": url}),
        )
        .await;
    let id = job["id"].as_str().unwrap();
    app.delete(&format!("/v1/jobs/{id}")).await;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    while received.calls.lock().unwrap().is_empty() {
        assert!(tokio::time::Instant::now() < deadline, "no webhook");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let (_, body) = received.calls.lock().unwrap()[0].clone();
    let doc: Value = serde_json::from_str(&body).unwrap();
    assert_eq!(doc["status"], "cancelled");
    app.delete(&format!("/v1/jobs/{}", blocker["id"].as_str().unwrap()))
        .await;
    app.stop().await;
}
