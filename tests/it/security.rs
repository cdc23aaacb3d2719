//! API keys, tenancy isolation, rate limits and the uniform error body of
//! axum's own rejections.

use std::sync::Arc;
use std::time::Duration;

use serde_json::{Value, json};
use treemorph::jobs::testing::TestRunner;

use crate::common::{error_code, spawn, spawn_with};

async fn send(
    app: &crate::common::TestApp,
    method: reqwest::Method,
    path: &str,
    key: Option<&str>,
    body: Option<Value>,
) -> (u16, Value) {
    let mut req = app.client.request(method, app.url(path));
    if let Some(k) = key {
        req = req.bearer_auth(k);
    }
    if let Some(b) = body {
        req = req.json(&b);
    }
    let r = req.send().await.unwrap();
    let status = r.status().as_u16();
    (status, r.json().await.unwrap_or(Value::Null))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn each_key_sees_only_its_own_trees_and_jobs() {
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |s| {
        s.api_keys = vec!["alice-key".into(), "bob-key".into()];
    })
    .await;
    use reqwest::Method;
    let alice = Some("alice-key");
    let bob = Some("bob-key");
    // No key, or a wrong one: 401.
    for key in [None, Some("mallory")] {
        let (s, b) = send(&app, Method::GET, "/v1/trees", key, None).await;
        assert_eq!((s, error_code(&b)), (401, "unauthorized"));
    }
    let r = app.get("/v1/jobs").await;
    assert_eq!(r.headers()["www-authenticate"], "Bearer");
    // Ops endpoints need no key.
    assert_eq!(app.get("/healthz").await.status(), 200);

    let spec = json!({"preset": "maple", "seed": 1, "size": 100});
    let (_, t1) = send(
        &app,
        Method::POST,
        "/v1/trees/generate",
        alice,
        Some(spec.clone()),
    )
    .await;
    let (_, t2) = send(
        &app,
        Method::POST,
        "/v1/trees/generate",
        alice,
        Some(spec.clone()),
    )
    .await;
    let (t1, t2) = (t1["id"].as_str().unwrap(), t2["id"].as_str().unwrap());
    let (s, job) = send(
        &app,
        Method::POST,
        "/v1/jobs",
        alice,
        Some(json!({"kind": "morph", "source": t1, "target": t2, "frames": 3})),
    )
    .await;
    assert_eq!(s, 202);
    let job = job["id"].as_str().unwrap().to_owned();
    for _ in 0..200 {
        let (_, j) = send(&app, Method::GET, &format!("/v1/jobs/{job}"), alice, None).await;
        if j["status"] == "succeeded" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    // Alice sees everything of hers.
    for path in [
        format!("/v1/trees/{t1}"),
        format!("/v1/trees/{t1}/model.glb"),
        format!("/v1/jobs/{job}/animation.glb"),
        format!("/v1/jobs/{job}/frames/0.glb"),
    ] {
        let r = app
            .client
            .get(app.url(&path))
            .bearer_auth("alice-key")
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200, "{path}");
    }
    // Bob: every route with Alice's ids is a 404, exactly like a missing id.
    let gets = [
        format!("/v1/trees/{t1}"),
        format!("/v1/trees/{t1}/model.glb"),
        format!("/v1/trees/{t1}/tree.json"),
        format!("/v1/trees/{t1}/analysis"),
        format!("/v1/jobs/{job}"),
        format!("/v1/jobs/{job}/events"),
        format!("/v1/jobs/{job}/stream"),
        format!("/v1/jobs/{job}/frames/0.glb"),
        format!("/v1/jobs/{job}/animation.glb"),
        format!("/v1/jobs/{job}/metrics.json"),
    ];
    for path in &gets {
        let (s, b) = send(&app, Method::GET, path, bob, None).await;
        assert_eq!((s, error_code(&b)), (404, "not_found"), "{path}");
    }
    for path in [format!("/v1/trees/{t1}"), format!("/v1/jobs/{job}")] {
        let (s, b) = send(&app, Method::DELETE, &path, bob, None).await;
        assert_eq!((s, error_code(&b)), (404, "not_found"), "{path}");
    }
    let (s, b) = send(
        &app,
        Method::POST,
        "/v1/jobs",
        bob,
        Some(json!({"kind": "morph", "source": t1, "target": t2, "frames": 3})),
    )
    .await;
    assert_eq!((s, error_code(&b)), (404, "tree_not_found"));
    for path in ["/v1/trees", "/v1/jobs"] {
        let (s, page) = send(&app, Method::GET, path, bob, None).await;
        assert_eq!(s, 200);
        assert_eq!(page["items"].as_array().unwrap().len(), 0, "{path}");
        let (_, page) = send(&app, Method::GET, path, alice, None).await;
        assert!(!page["items"].as_array().unwrap().is_empty(), "{path}");
    }
    // Alice's tree still exists after Bob's delete attempt.
    let (s, _) = send(&app, Method::GET, &format!("/v1/trees/{t1}"), alice, None).await;
    assert_eq!(s, 200);
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_rate_limit_is_per_key_with_retry_after() {
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |s| {
        s.api_keys = vec!["a".into(), "b".into()];
        s.rate_limit = 1.0;
        s.rate_burst = 5;
    })
    .await;
    let mut limited = None;
    for i in 0..8 {
        let r = app
            .client
            .get(app.url("/v1/trees"))
            .bearer_auth("a")
            .send()
            .await
            .unwrap();
        if r.status() == 429 {
            limited = Some((i, r));
            break;
        }
    }
    let (i, r) = limited.expect("the burst runs out");
    assert_eq!(i, 5, "the burst is 5 requests");
    assert!(
        r.headers()["retry-after"]
            .to_str()
            .unwrap()
            .parse::<u64>()
            .unwrap()
            >= 1
    );
    assert_eq!(error_code(&r.json().await.unwrap()), "rate_limited");
    // Another key is unaffected.
    let r = app
        .client
        .get(app.url("/v1/trees"))
        .bearer_auth("b")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn axum_rejections_get_the_uniform_body() {
    let app = spawn().await;
    let (s, b) = app.get_json("/no/such/route").await;
    assert_eq!((s, error_code(&b)), (404, "not_found"));
    let (s, b) = app.get_json("/v1/jobs/x/y/z").await;
    assert_eq!((s, error_code(&b)), (404, "not_found"));
    let r = app.client.put(app.url("/v1/trees")).send().await.unwrap();
    assert_eq!(r.status(), 405);
    assert_eq!(r.headers()["content-type"], "application/json");
    assert_eq!(error_code(&r.json().await.unwrap()), "method_not_allowed");
    let r = app.client.patch(app.url("/healthz")).send().await.unwrap();
    assert_eq!(r.status(), 405);
    assert_eq!(error_code(&r.json().await.unwrap()), "method_not_allowed");
    // Bodies over the JSON limit.
    let r = app
        .client
        .post(app.url("/v1/jobs"))
        .header("content-type", "application/json")
        .body(vec![b' '; 3 * 1024 * 1024])
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 413);
    assert_eq!(error_code(&r.json().await.unwrap()), "payload_too_large");
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_clients_are_cut_off_by_the_header_read_timeout() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |s| {
        s.header_read_timeout = 1
    })
    .await;
    let addr = app.base.trim_start_matches("http://").to_owned();
    let mut stream = tokio::net::TcpStream::connect(&addr).await.unwrap();
    stream
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
        .await
        .unwrap();
    // Never finish the headers: the server must close the connection.
    let mut buf = Vec::new();
    let read = tokio::time::timeout(Duration::from_secs(5), stream.read_to_end(&mut buf)).await;
    assert!(read.is_ok(), "the connection was not closed");
    app.stop().await;
}

/// Slow-body protection: a body dribbled under the minimum rate (or
/// stalled) is refused with 408 `body_too_slow` once the header timeout
/// has passed, on an upload route and on a JSON route.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_bodies_are_cut_off_by_the_minimum_rate() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |s| {
        s.header_read_timeout = 1;
        s.min_body_rate = 100;
    })
    .await;
    let addr = app.base.trim_start_matches("http://").to_owned();
    for (path, media) in [
        ("/v1/trees", "application/vnd.treemorph.tree+json"),
        ("/v1/jobs", "application/json"),
    ] {
        let mut stream = tokio::net::TcpStream::connect(&addr).await.unwrap();
        stream
            .write_all(
                format!(
                    "POST {path} HTTP/1.1\r\nHost: x\r\nContent-Type: {media}\r\nContent-Length: 100000\r\n\r\n{{"
                )
                .as_bytes(),
            )
            .await
            .unwrap();
        // A byte every 300 ms: never idle for the 1 s header timeout, but
        // about 3 bytes/s against a minimum of 100.
        let dribble = async {
            loop {
                tokio::time::sleep(Duration::from_millis(300)).await;
                if stream.write_all(b" ").await.is_err() {
                    break;
                }
            }
        };
        let _ = tokio::time::timeout(Duration::from_secs(10), dribble).await;
        let mut buf = Vec::new();
        let _ = tokio::time::timeout(Duration::from_secs(5), stream.read_to_end(&mut buf)).await;
        let text = String::from_utf8_lossy(&buf);
        assert!(text.starts_with("HTTP/1.1 408"), "{path}: {text}");
        assert!(text.contains("body_too_slow"), "{path}: {text}");
    }
    app.stop().await;
}

/// An upload that keeps flowing above the minimum rate is not cut off by
/// the request timeout, however long it takes (a 200 MB GLB over a
/// 20 Mbit/s link needs 80 s against a 60 s timeout): here a 1 s timeout
/// and an upload spread over about 3 s.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn uploads_that_keep_flowing_outlast_the_request_timeout() {
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |s| {
        s.request_timeout = 1;
        s.header_read_timeout = 1;
        s.min_body_rate = 100;
    })
    .await;
    let id = app.tree(3).await;
    let json = app
        .get(&format!("/v1/trees/{id}/tree.json"))
        .await
        .bytes()
        .await
        .unwrap();
    let chunks: Vec<bytes::Bytes> = json
        .chunks(json.len().div_ceil(12))
        .map(bytes::Bytes::copy_from_slice)
        .collect();
    let slow =
        futures_util::StreamExt::then(futures_util::stream::iter(chunks), |chunk| async move {
            tokio::time::sleep(Duration::from_millis(250)).await;
            Ok::<_, std::io::Error>(chunk)
        });
    let started = std::time::Instant::now();
    let r = app
        .client
        .post(app.url("/v1/trees?name=slow"))
        .header("content-type", "application/vnd.treemorph.tree+json")
        .body(reqwest::Body::wrap_stream(slow))
        .send()
        .await
        .unwrap();
    let took = started.elapsed();
    let status = r.status().as_u16();
    let body: Value = r.json().await.unwrap_or(Value::Null);
    assert_eq!(status, 201, "after {took:?}: {body}");
    assert!(
        took > Duration::from_secs(2),
        "the upload was not slow: {took:?}"
    );
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cors_answers_configured_origins_only() {
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |s| {
        s.cors_origins = vec!["https://viewer.example".into()];
    })
    .await;
    let r = app
        .client
        .get(app.url("/v1/trees"))
        .header("origin", "https://viewer.example")
        .send()
        .await
        .unwrap();
    assert_eq!(
        r.headers()["access-control-allow-origin"],
        "https://viewer.example"
    );
    let r = app
        .client
        .get(app.url("/v1/trees"))
        .header("origin", "https://evil.example")
        .send()
        .await
        .unwrap();
    assert!(r.headers().get("access-control-allow-origin").is_none());
    app.stop().await;
}

/// How a documented route without an id in its path keeps tenants apart.
#[derive(Clone, Copy, Debug)]
enum Tenancy {
    /// Lists only the caller's resources.
    List,
    /// Creates a resource owned by the caller (checked: the other key
    /// cannot see it).
    Creates,
    /// Names trees in its body: another key's trees are `tree_not_found`.
    NamesTrees,
    /// Operations endpoints: no tenant data.
    Public,
}

/// Every route without a path id, with how it is checked. A route added
/// to the OpenAPI document without an entry here fails the test below.
const NO_ID_ROUTES: &[(&str, &str, Tenancy)] = &[
    ("get", "/v1/trees", Tenancy::List),
    ("post", "/v1/trees", Tenancy::Creates),
    ("post", "/v1/trees/generate", Tenancy::Creates),
    ("get", "/v1/jobs", Tenancy::List),
    ("post", "/v1/jobs", Tenancy::NamesTrees),
    ("get", "/healthz", Tenancy::Public),
    ("get", "/readyz", Tenancy::Public),
    ("get", "/metrics", Tenancy::Public),
    ("get", "/openapi.yaml", Tenancy::Public),
];

/// Every operation of the OpenAPI document (generated from the code; the
/// `openapi` test keeps the committed file equal to it), as (method, path).
fn documented_operations() -> Vec<(String, String)> {
    let doc = serde_json::to_value(treemorph::server::openapi::document()).unwrap();
    let mut ops = Vec::new();
    for (path, item) in doc["paths"].as_object().unwrap() {
        for method in ["get", "put", "post", "delete", "patch", "head", "options"] {
            if item.get(method).is_some() {
                ops.push((method.to_owned(), path.clone()));
            }
        }
    }
    ops.sort();
    ops
}

/// Tenancy on **every** documented route: another key's ids answer 404
/// exactly like ids that never existed, lists and body references see
/// only the caller's resources, and every `/v1` route refuses a request
/// without a key. The routes come from the OpenAPI document, so a new
/// route cannot be forgotten.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_documented_route_hides_other_keys_resources() {
    use reqwest::Method;
    let app = spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |s| {
        s.api_keys = vec!["alice-key".into(), "bob-key".into()];
    })
    .await;
    let (alice, bob) = (Some("alice-key"), Some("bob-key"));
    let spec = json!({"preset": "maple", "seed": 1, "size": 100});
    let mut trees = Vec::new();
    for _ in 0..2 {
        let (s, t) = send(
            &app,
            Method::POST,
            "/v1/trees/generate",
            alice,
            Some(spec.clone()),
        )
        .await;
        assert_eq!(s, 201, "{t}");
        trees.push(t["id"].as_str().unwrap().to_owned());
    }
    let morph = json!({"kind": "morph", "source": trees[0], "target": trees[1], "frames": 3});
    let (s, job) = send(&app, Method::POST, "/v1/jobs", alice, Some(morph.clone())).await;
    assert_eq!(s, 202, "{job}");
    let job = job["id"].as_str().unwrap().to_owned();
    let mut done = false;
    for _ in 0..500 {
        let (_, j) = send(&app, Method::GET, &format!("/v1/jobs/{job}"), alice, None).await;
        if j["status"] == "succeeded" {
            done = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(done, "alice's job did not finish");

    let ops = documented_operations();
    assert!(ops.len() >= 21, "{ops:?}");
    let mut checked = 0;
    for (method, path) in &ops {
        let m = Method::from_bytes(method.to_uppercase().as_bytes()).unwrap();
        if path.contains('{') {
            let concrete = if path.starts_with("/v1/trees/{id}") {
                path.replace("{id}", &trees[0])
            } else if path == "/v1/jobs/{id}/frame.glb" {
                // Its required query: without it, every id is a 422 alike.
                format!("/v1/jobs/{job}/frame.glb?t=0.5")
            } else if path.starts_with("/v1/jobs/{id}") {
                path.replace("{id}", &job).replace("{frame}", "0.glb")
            } else {
                panic!(
                    "{method} {path}: a path id of an unknown resource: teach this test its ids"
                );
            };
            assert!(
                !concrete.contains('{'),
                "{method} {path}: unknown path parameter"
            );
            let body = (m == Method::POST).then(|| json!({}));
            // Bob, with Alice's ids: exactly a missing id.
            let (s, b) = send(&app, m.clone(), &concrete, bob, body.clone()).await;
            assert_eq!(
                (s, error_code(&b)),
                (404, "not_found"),
                "{method} {concrete} as bob"
            );
            // Alice (reads only: deletes would spend the fixtures) finds it.
            if m == Method::GET {
                let r = app
                    .client
                    .get(app.url(&concrete))
                    .bearer_auth("alice-key")
                    .send()
                    .await
                    .unwrap();
                assert_eq!(r.status(), 200, "{method} {concrete} as alice");
            }
        } else {
            let Some(&(_, _, kind)) = NO_ID_ROUTES
                .iter()
                .find(|(m2, p, _)| m2 == method && p == path)
            else {
                panic!("{method} {path} is not classified: add it to NO_ID_ROUTES");
            };
            match kind {
                Tenancy::List => {
                    let (s, page) = send(&app, m.clone(), path, bob, None).await;
                    assert_eq!(s, 200, "{path}");
                    assert_eq!(page["items"], json!([]), "{method} {path} as bob");
                    let (_, page) = send(&app, m.clone(), path, alice, None).await;
                    assert!(!page["items"].as_array().unwrap().is_empty(), "{path}");
                }
                Tenancy::Creates => {
                    let r = if path == "/v1/trees" {
                        let bytes = app
                            .client
                            .get(app.url(&format!("/v1/trees/{}/tree.json", trees[0])))
                            .bearer_auth("alice-key")
                            .send()
                            .await
                            .unwrap()
                            .bytes()
                            .await
                            .unwrap();
                        app.client
                            .post(app.url(path))
                            .bearer_auth("bob-key")
                            .header("content-type", "application/vnd.treemorph.tree+json")
                            .body(bytes)
                            .send()
                            .await
                            .unwrap()
                    } else {
                        app.client
                            .post(app.url(path))
                            .bearer_auth("bob-key")
                            .json(&spec)
                            .send()
                            .await
                            .unwrap()
                    };
                    assert_eq!(r.status(), 201, "{method} {path} as bob");
                    let created: Value = r.json().await.unwrap();
                    let id = created["id"].as_str().unwrap();
                    let (s, b) =
                        send(&app, Method::GET, &format!("/v1/trees/{id}"), alice, None).await;
                    assert_eq!(
                        (s, error_code(&b)),
                        (404, "not_found"),
                        "bob's tree as alice"
                    );
                }
                Tenancy::NamesTrees => {
                    let (s, b) = send(&app, m.clone(), path, bob, Some(morph.clone())).await;
                    assert_eq!((s, error_code(&b)), (404, "tree_not_found"), "{path}");
                }
                Tenancy::Public => {
                    let r = app
                        .client
                        .request(m.clone(), app.url(path))
                        .send()
                        .await
                        .unwrap();
                    assert_eq!(r.status(), 200, "{path} needs no key");
                }
            }
        }
        // Every /v1 route needs a key.
        if path.starts_with("/v1/") {
            let concrete = path.replace("{id}", &trees[0]).replace("{frame}", "0.glb");
            let (s, b) = send(&app, m.clone(), &concrete, None, None).await;
            assert_eq!(
                (s, error_code(&b)),
                (401, "unauthorized"),
                "{method} {path}"
            );
        }
        checked += 1;
    }
    assert_eq!(checked, ops.len());
    // Nothing of Alice's was touched by Bob's attempts.
    for path in [format!("/v1/trees/{}", trees[0]), format!("/v1/jobs/{job}")] {
        let (s, _) = send(&app, Method::GET, &path, alice, None).await;
        assert_eq!(s, 200, "{path}");
    }
    app.stop().await;
}
