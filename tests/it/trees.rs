//! `/v1/trees`: every upload format and its error paths, generation,
//! listing, downloads with ETag/Range, deletion.

use serde_json::{Value, json};
use treemorph_generate::{GenerateOptions, Preset};

use crate::common::{error_code, spawn, spawn_with};

fn sample_tree() -> treemorph_tree::Tree {
    treemorph_generate::generate(&GenerateOptions::new(Preset::Maple, 3).with_size(150)).unwrap()
}

async fn upload(
    app: &crate::common::TestApp,
    content_type: &str,
    body: Vec<u8>,
    query: &str,
) -> (u16, Value) {
    let r = app
        .client
        .post(app.url(&format!("/v1/trees{query}")))
        .header("content-type", content_type)
        .body(body)
        .send()
        .await
        .unwrap();
    let status = r.status().as_u16();
    let location = r
        .headers()
        .get("location")
        .map(|v| v.to_str().unwrap().to_owned());
    let body: Value = r.json().await.unwrap();
    if status == 201 {
        assert_eq!(
            location.unwrap(),
            format!("/v1/trees/{}", body["id"].as_str().unwrap())
        );
    }
    (status, body)
}

/// A third-party-like GLB (our export without the embedded skeleton) is
/// imported from its meshes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn imports_glbs_without_a_treemorph_skeleton() {
    let app = spawn().await;
    let tree = sample_tree();
    let glb = treemorph_gltf::export_glb(
        &tree,
        &treemorph_gltf::ExportOptions::default().with_embed_tree(false),
    )
    .unwrap();
    let (s, b) = upload(&app, "model/gltf-binary", glb, "?name=imported").await;
    assert_eq!(s, 201, "{b}");
    assert_eq!(b["name"], "imported");
    assert_eq!(b["stats"]["leaves"], tree.leaves().len());
    assert!(b["stats"]["chains"].as_u64().unwrap() > 10, "{b}");
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn uploads_our_json_and_our_glb_and_reports_the_analysis() {
    let app = spawn().await;
    let tree = sample_tree();
    let stats = tree.stats();
    let (status, body) = upload(
        &app,
        treemorph_tree::json::MEDIA_TYPE,
        treemorph_tree::json::to_vec(&tree),
        "?name=my%20maple",
    )
    .await;
    assert_eq!(status, 201, "{body}");
    assert_eq!(body["name"], "my maple");
    assert_eq!(body["format"], "tree+json");
    assert_eq!(body["stats"]["branches"], stats.branches as u64);
    assert_eq!(body["stats"]["leaves"], stats.leaves as u64);
    let chains = body["stats"]["chains"].as_u64().unwrap();
    assert!(chains > 0 && body["stats"]["chain_groups"].as_u64().unwrap() > 0);
    let patterns = &body["stats"]["patterns"];
    let groups = patterns["alternate"].as_u64().unwrap()
        + patterns["opposite"].as_u64().unwrap()
        + patterns["whorled"].as_u64().unwrap();
    assert_eq!(groups, body["stats"]["chain_groups"].as_u64().unwrap());
    assert!((body["stats"]["height"].as_f64().unwrap() - f64::from(stats.height)).abs() < 1e-3);

    let glb = treemorph_gltf::export_glb(&tree, &treemorph_gltf::ExportOptions::default()).unwrap();
    let (status, from_glb) = upload(&app, "model/gltf-binary", glb, "").await;
    assert_eq!(status, 201, "{from_glb}");
    assert_eq!(from_glb["format"], "glb");
    assert_eq!(from_glb["name"], "tree");
    assert_eq!(
        from_glb["stats"], body["stats"],
        "the GLB carries the same tree"
    );

    // Round trip: the stored tree JSON is our format and parses back.
    let id = body["id"].as_str().unwrap();
    let r = app.get(&format!("/v1/trees/{id}/tree.json")).await;
    assert_eq!(r.status(), 200);
    assert_eq!(
        r.headers()["content-type"],
        treemorph_tree::json::MEDIA_TYPE
    );
    let back =
        treemorph_tree::json::from_slice(&r.bytes().await.unwrap(), &Default::default()).unwrap();
    assert_eq!(back.stats().branches, stats.branches);
    // The full analysis.
    let (status, analysis) = app.get_json(&format!("/v1/trees/{id}/analysis")).await;
    assert_eq!(status, 200);
    assert!(analysis.is_object() && !analysis.as_object().unwrap().is_empty());
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_uploads_get_415_or_422_with_their_codes() {
    let app = spawn().await;
    let (s, b) = upload(&app, "image/png", b"\x89PNG....".to_vec(), "").await;
    assert_eq!((s, error_code(&b)), (415, "unsupported_media_type"));
    let r = app
        .client
        .post(app.url("/v1/trees"))
        .body("{}")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 415);
    let (s, b) = upload(
        &app,
        treemorph_tree::json::MEDIA_TYPE,
        b"{\"format\": ".to_vec(),
        "",
    )
    .await;
    assert_eq!((s, error_code(&b)), (422, "invalid_tree"));
    let (s, b) = upload(
        &app,
        treemorph_tree::json::MEDIA_TYPE,
        b"not json at all".to_vec(),
        "",
    )
    .await;
    assert_eq!((s, error_code(&b)), (422, "invalid_tree"));
    let (s, b) = upload(
        &app,
        "model/gltf-binary",
        b"glTF\x02\0\0\0garbage".to_vec(),
        "",
    )
    .await;
    assert_eq!((s, error_code(&b)), (422, "invalid_gltf"));
    let (s, b) = upload(&app, "model/gltf-binary", b"PK\x03\x04zip".to_vec(), "").await;
    assert_eq!((s, error_code(&b)), (422, "invalid_gltf"));
    // glTF JSON without any mesh: valid glTF, but no tree in it.
    let gltf = json!({"asset": {"version": "2.0"}, "meshes": []})
        .to_string()
        .into_bytes();
    let (s, b) = upload(&app, "model/gltf+json", gltf, "").await;
    assert_eq!((s, error_code(&b)), (422, "invalid_tree"));
    // Valid glTF that needs something we don't read.
    let external = json!({"asset": {"version": "2.0"},
        "buffers": [{"byteLength": 4, "uri": "mesh.bin"}]})
    .to_string()
    .into_bytes();
    let (s, b) = upload(&app, "model/gltf+json", external, "").await;
    assert_eq!((s, error_code(&b)), (415, "unsupported_gltf"), "{b}");
    // Declared type and content disagree.
    let tree = treemorph_tree::json::to_vec(&sample_tree());
    let (s, b) = upload(&app, "model/gltf-binary", tree, "").await;
    assert_eq!((s, error_code(&b)), (422, "invalid_gltf"));
    let (s, b) = upload(&app, treemorph_tree::json::MEDIA_TYPE, vec![], "").await;
    assert_eq!((s, error_code(&b)), (422, "invalid_tree"));
    let (s, b) = upload(
        &app,
        treemorph_tree::json::MEDIA_TYPE,
        b"{}".to_vec(),
        "?nam=x",
    )
    .await;
    assert_eq!((s, error_code(&b)), (422, "invalid_request"));
    assert!(
        b["error"]["message"].as_str().unwrap().contains("nam"),
        "{b}"
    );
    // Nothing was stored.
    let (_, page) = app.get_json("/v1/trees").await;
    assert_eq!(page["items"].as_array().unwrap().len(), 0);
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn uploads_over_the_limit_get_413_streamed_or_declared() {
    let app = spawn_with(
        std::sync::Arc::new(treemorph::jobs::testing::TestRunner::slow(
            Default::default(),
        )),
        |s| s.max_upload_bytes = 10_000,
    )
    .await;
    // Declared up front.
    let (s, b) = upload(
        &app,
        treemorph_tree::json::MEDIA_TYPE,
        vec![b' '; 20_000],
        "",
    )
    .await;
    assert_eq!((s, error_code(&b)), (413, "payload_too_large"));
    // Chunked, no Content-Length: counted while streaming.
    let chunks: Vec<Result<Vec<u8>, std::io::Error>> =
        (0..50).map(|_| Ok(vec![b' '; 1000])).collect();
    let r = app
        .client
        .post(app.url("/v1/trees"))
        .header("content-type", treemorph_tree::json::MEDIA_TYPE)
        .body(reqwest::Body::wrap_stream(futures_util::stream::iter(
            chunks,
        )))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 413);
    let b: Value = r.json().await.unwrap();
    assert_eq!(error_code(&b), "payload_too_large");
    // No temporary file is left behind.
    let tmp = std::fs::read_dir(app.dir.path().join("tmp"))
        .unwrap()
        .count();
    assert_eq!(tmp, 0);
    app.stop().await;
}

/// Regression: a client still sending a large body when the 413 arrived
/// saw a broken pipe instead of the answer, because the server closed the
/// connection with unread bytes in its buffers. The server now reads and
/// discards the rest of the body for a bounded while after answering.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clients_still_sending_get_the_413_not_a_broken_pipe() {
    let app = spawn_with(
        std::sync::Arc::new(treemorph::jobs::testing::TestRunner::slow(
            Default::default(),
        )),
        |s| s.max_upload_bytes = 10_000,
    )
    .await;
    for attempt in 0..20 {
        let declared = attempt % 2 == 0;
        let request = app
            .client
            .post(app.url("/v1/trees"))
            .header("content-type", "model/gltf-binary");
        let request = if declared {
            request.body(vec![b' '; 32 << 20])
        } else {
            let chunks = (0..10_000).map(|_| Ok::<_, std::io::Error>(vec![b' '; 64 << 10]));
            request.body(reqwest::Body::wrap_stream(futures_util::stream::iter(
                chunks,
            )))
        };
        let r = request
            .send()
            .await
            .unwrap_or_else(|e| panic!("attempt {attempt} (declared {declared}): {e:?}"));
        assert_eq!(r.status(), 413, "attempt {attempt}");
        let b: Value = r.json().await.unwrap();
        assert_eq!(error_code(&b), "payload_too_large");
    }
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn generate_validates_its_request() {
    let app = spawn().await;
    for preset in Preset::ALL {
        let (s, b) = app
            .post_json(
                "/v1/trees/generate",
                &json!({"preset": preset.name(), "seed": 1, "size": 80}),
            )
            .await;
        assert_eq!(s, 201, "{b}");
        assert_eq!(b["format"], "generated");
        assert_eq!(b["name"], format!("{}-1", preset.name()));
    }
    // `seed` may be left out: it is 1, the same tree as an explicit 1.
    let (s, b) = app
        .post_json(
            "/v1/trees/generate",
            &json!({"preset": "maple", "size": 80}),
        )
        .await;
    assert_eq!(s, 201, "{b}");
    assert_eq!(b["name"], "maple-1");
    for (body, code) in [
        (json!({"preset": "baobab", "seed": 1}), "invalid_request"),
        (
            json!({"preset": "maple", "seed": 1, "size": 1}),
            "invalid_request",
        ),
        (
            json!({"preset": "maple", "seed": 1, "colour": "red"}),
            "invalid_request",
        ),
        (json!({"preset": "maple", "seed": -1}), "invalid_request"),
    ] {
        let (s, b) = app.post_json("/v1/trees/generate", &body).await;
        assert_eq!((s, error_code(&b)), (422, code), "{body}");
    }
    let (s, b) = app
        .post_json(
            "/v1/trees/generate",
            &json!({"preset": "maple", "seed": 1, "colour": 1}),
        )
        .await;
    assert_eq!(s, 422);
    assert!(
        b["error"]["message"].as_str().unwrap().contains("colour"),
        "{b}"
    );
    let r = app
        .client
        .post(app.url("/v1/trees/generate"))
        .header("content-type", "application/json")
        .body("{\"preset\": ")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 400);
    assert_eq!(error_code(&r.json().await.unwrap()), "invalid_json");
    let r = app
        .client
        .post(app.url("/v1/trees/generate"))
        .body("{}")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 415);
    assert_eq!(
        error_code(&r.json().await.unwrap()),
        "unsupported_media_type"
    );
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lists_paginate_newest_first_with_opaque_cursors() {
    let app = spawn().await;
    let mut ids = vec![];
    for seed in 0..7 {
        ids.push(app.tree(seed).await);
    }
    ids.reverse();
    let mut seen = vec![];
    let mut cursor: Option<String> = None;
    loop {
        let path = match &cursor {
            Some(c) => format!("/v1/trees?limit=3&cursor={c}"),
            None => "/v1/trees?limit=3".to_owned(),
        };
        let (s, page) = app.get_json(&path).await;
        assert_eq!(s, 200, "{page}");
        let items = page["items"].as_array().unwrap();
        assert!(items.len() <= 3);
        seen.extend(items.iter().map(|t| t["id"].as_str().unwrap().to_owned()));
        match page["next_cursor"].as_str() {
            Some(c) => cursor = Some(c.to_owned()),
            None => break,
        }
    }
    assert_eq!(seen, ids);
    for bad in [
        "?limit=0",
        "?limit=101",
        "?limit=x",
        "?cursor=%%%",
        "?cursor=abc",
        "?extra=1",
    ] {
        let (s, b) = app.get_json(&format!("/v1/trees{bad}")).await;
        assert_eq!((s, error_code(&b)), (422, "invalid_request"), "{bad}");
    }
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn model_glb_has_an_etag_and_supports_ranges() {
    let app = spawn().await;
    let id = app.tree(1).await;
    let path = format!("/v1/trees/{id}/model.glb");
    let r = app.get(&path).await;
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "model/gltf-binary");
    let etag = r.headers()["etag"].to_str().unwrap().to_owned();
    let glb = r.bytes().await.unwrap();
    assert_eq!(&glb[..4], b"glTF");
    let tree = treemorph_gltf::read_embedded_tree(&glb, &Default::default())
        .unwrap()
        .unwrap();
    assert!(tree.stats().branches > 0);
    let r = app
        .client
        .get(app.url(&path))
        .header("if-none-match", &etag)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 304);
    let r = app
        .client
        .get(app.url(&path))
        .header("range", "bytes=0-3")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 206);
    assert_eq!(
        r.headers()["content-range"],
        format!("bytes 0-3/{}", glb.len())
    );
    assert_eq!(&r.bytes().await.unwrap()[..], b"glTF");
    let r = app
        .client
        .get(app.url(&path))
        .header("range", format!("bytes={}-", glb.len()))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 416);
    assert_eq!(
        r.headers()["content-range"],
        format!("bytes */{}", glb.len())
    );
    assert_eq!(
        error_code(&r.json().await.unwrap()),
        "range_not_satisfiable"
    );
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_ids_are_404_never_500() {
    let app = spawn().await;
    let long = "a".repeat(5000);
    for id in [
        "nope",
        "00000000000000000000000000000000",
        "..%2F..%2Fetc%2Fpasswd",
        "%2e%2e",
        long.as_str(),
        "0192AAAAAAAAAAAAAAAAAAAAAAAAAAAA",
    ] {
        for suffix in ["", "/model.glb", "/tree.json", "/analysis"] {
            let (s, b) = app.get_json(&format!("/v1/trees/{id}{suffix}")).await;
            assert_eq!((s, error_code(&b)), (404, "not_found"), "{id}{suffix}");
        }
        let (s, b) = app.delete(&format!("/v1/trees/{id}")).await;
        assert_eq!((s, error_code(&b)), (404, "not_found"));
    }
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn delete_is_refused_while_a_job_uses_the_tree() {
    let app = spawn_with(
        std::sync::Arc::new(treemorph::jobs::testing::TestRunner::slow(
            std::time::Duration::from_millis(40),
        )),
        |_| {},
    )
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (s, job) = app.morph(&a, &b, 20).await;
    assert_eq!(s, 202, "{job}");
    for id in [&a, &b] {
        let (s, body) = app.delete(&format!("/v1/trees/{id}")).await;
        assert_eq!((s, error_code(&body)), (409, "tree_in_use"));
    }
    let job = job["id"].as_str().unwrap();
    app.wait_status(job, "succeeded").await;
    // Still in use while the job exists: it renders new instants from it.
    let (s, body) = app.delete(&format!("/v1/trees/{a}")).await;
    assert_eq!((s, error_code(&body)), (409, "tree_in_use"));
    assert_eq!(app.delete(&format!("/v1/jobs/{job}")).await.0, 204);
    let r = app
        .client
        .delete(app.url(&format!("/v1/trees/{a}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 204);
    let (s, _) = app.get_json(&format!("/v1/trees/{a}")).await;
    assert_eq!(s, 404);
    let (s, _) = app.get_json(&format!("/v1/trees/{a}/model.glb")).await;
    assert_eq!(s, 404);
    let (s, body) = app.delete(&format!("/v1/trees/{a}")).await;
    assert_eq!((s, error_code(&body)), (404, "not_found"));
    // The blobs are gone too.
    let blobs = app.dir.path().join("blobs/trees").join(&a);
    assert!(!blobs.exists(), "{} still exists", blobs.display());
    app.stop().await;
}
