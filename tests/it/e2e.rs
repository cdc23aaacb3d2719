//! End to end with the production runner on real generated trees.

use serde_json::json;
use treemorph::config::Settings;

use crate::common::{error_code, spawn_with};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_real_morph_and_sketch_run_with_the_default_runner() {
    let app = spawn_with(treemorph::pipeline::default_runner(), |s: &mut Settings| {
        s.workers = Some(1)
    })
    .await;
    let a = app
        .post_json(
            "/v1/trees/generate",
            &json!({"preset": "maple", "seed": 1, "size": 400}),
        )
        .await
        .1["id"]
        .as_str()
        .unwrap()
        .to_owned();
    let b = app
        .post_json(
            "/v1/trees/generate",
            &json!({"preset": "conifer", "seed": 2, "size": 400}),
        )
        .await
        .1["id"]
        .as_str()
        .unwrap()
        .to_owned();
    let (id, done) = morph_to_end(&app, &a, &b, 10).await;
    assert_eq!(done["result"]["frames"], 10, "{done}");
    assert_eq!(done["result"]["metrics"]["floating_branches"], 0, "{done}");
    assert_eq!(done["result"]["metrics"]["floating_leaves"], 0, "{done}");
    let animation = app
        .get(&format!("/v1/jobs/{id}/animation.glb"))
        .await
        .bytes()
        .await
        .unwrap();
    assert_eq!(&animation[..4], b"glTF");
    let metrics: serde_json::Value = app
        .get(&format!("/v1/jobs/{id}/metrics.json"))
        .await
        .json()
        .await
        .unwrap();
    assert_eq!(metrics["mtsw"].as_array().unwrap().len(), 10, "{metrics}");
    let stream_bytes = app
        .get(&format!("/v1/jobs/{id}/stream"))
        .await
        .bytes()
        .await
        .unwrap();
    let (header, frames) =
        treemorph_api::delta::decode_all(&stream_bytes, &Default::default()).unwrap();
    assert_eq!(frames.len(), 10);
    let glb = app
        .get(&format!("/v1/jobs/{id}/frames/0.glb"))
        .await
        .bytes()
        .await
        .unwrap();
    assert_eq!(&glb[..4], b"glTF");
    // Any instant renders on request; at a frame's instant, its bytes.
    let frame_4 = app
        .get(&format!("/v1/jobs/{id}/frames/4.glb"))
        .await
        .bytes()
        .await
        .unwrap();
    let at = app
        .get(&format!("/v1/jobs/{id}/frame.glb?t={}", 4.0f32 / 9.0))
        .await;
    assert_eq!(at.status(), 200);
    assert_eq!(
        at.bytes().await.unwrap(),
        frame_4,
        "the instant of frame 4 is not frame 4"
    );
    let between = app.get(&format!("/v1/jobs/{id}/frame.glb?t=0.375")).await;
    assert_eq!(between.status(), 200);
    let between = between.bytes().await.unwrap();
    assert_eq!(&between[..4], b"glTF");
    assert_ne!(between, frame_4);
    // The instant as a one-frame stream with the job's own header (what
    // the viewer scrubs with): at frame 4's instant, frame 4 exactly.
    let at = app
        .get(&format!("/v1/jobs/{id}/stream?t={}", 4.0f32 / 9.0))
        .await;
    assert_eq!(at.status(), 200);
    let at = at.bytes().await.unwrap();
    let (at_header, at_frames) =
        treemorph_api::delta::decode_all(&at, &Default::default()).unwrap();
    assert_eq!(at_frames.len(), 1);
    assert_eq!(
        (at_header.bounds, at_header.grid),
        (header.bounds, header.grid)
    );
    assert_eq!(at_header.meshes.len(), header.meshes.len());
    for (a, b) in at_header.meshes.iter().zip(&header.meshes) {
        assert_eq!(
            (&a.indices, &a.uvs),
            (&b.indices, &b.uvs),
            "mesh {}",
            b.name
        );
    }
    assert_eq!(at_frames[0].positions, frames[4].positions);
    assert_eq!(at_frames[0].t, frames[4].t);
    assert_eq!(at_frames[0].leaf_blend, frames[4].leaf_blend);
    // Its frame record alone decodes after the job's own header, to the
    // same frame (what the viewer fetches when it scrubs).
    let record = app
        .get(&format!(
            "/v1/jobs/{id}/stream?t={}&header=false",
            4.0f32 / 9.0
        ))
        .await;
    assert_eq!(record.status(), 200);
    assert_eq!(
        record.headers()["content-type"],
        "application/vnd.treemorph.delta-frame"
    );
    let record = record.bytes().await.unwrap();
    assert!(
        record.len() * 4 < at.len(),
        "{} of {} bytes",
        record.len(),
        at.len()
    );
    // The preamble (8 bytes), then the header record: a 12-byte prefix
    // with the stored payload length at 4..8, the payload, a 4-byte CRC.
    let stored = u32::from_le_bytes(stream_bytes[12..16].try_into().unwrap()) as usize;
    let header_len = 8 + 12 + stored + 4;
    let mut decoder = treemorph_api::delta::Decoder::new(&Default::default());
    decoder.push(&stream_bytes[..header_len]);
    decoder.push(&record);
    let mut decoded = Vec::new();
    while let Some(event) = decoder.next_event().unwrap() {
        decoded.push(event);
    }
    match &decoded[..] {
        [
            treemorph_api::delta::Event::Header(h),
            treemorph_api::delta::Event::Frame(f),
        ] => {
            assert_eq!(h.frame_count, 10, "not the job's header");
            assert_eq!(f.positions, frames[4].positions);
        }
        other => panic!("{} events after the job's header", other.len()),
    }
    let between = app.get(&format!("/v1/jobs/{id}/stream?t=0.375")).await;
    let between = between.bytes().await.unwrap();
    let (_, between) = treemorph_api::delta::decode_all(&between, &Default::default()).unwrap();
    assert_eq!(between[0].t, 0.375);
    assert_ne!(between[0].positions, frames[3].positions);
    assert_ne!(between[0].positions, frames[4].positions);
    // Re-sampled sequences, run again on request.
    let stream = app
        .get(&format!("/v1/jobs/{id}/stream?frames=4"))
        .await
        .bytes()
        .await
        .unwrap();
    let (_, resampled) = treemorph_api::delta::decode_all(&stream, &Default::default()).unwrap();
    assert_eq!(resampled.len(), 4);
    let keyed = app
        .get(&format!("/v1/jobs/{id}/animation.glb?keyframes=2"))
        .await;
    assert_eq!(keyed.status(), 200);
    let keyed = keyed.bytes().await.unwrap();
    assert_eq!(&keyed[..4], b"glTF");
    assert_ne!(
        keyed, animation,
        "two keyframes wrote the job's own animation"
    );

    let (s, job) = app
        .post_json("/v1/jobs", &json!({
            "kind": "sketch", "tree": a,
            "view": {"eye": [0, 3, 12], "target": [0, 3, 0], "up": [0, 1, 0], "fov_deg": 40},
            "sketch": {"points": [[-0.5, -0.2], [0.5, -0.2], [0.6, 0.5], [0, 0.9], [-0.6, 0.5]], "closed": true},
            "frames": 6, "options": {"fit": "crown"}
        }))
        .await;
    assert_eq!(s, 202, "{job}");
    let done = app
        .wait_job(job["id"].as_str().unwrap(), |j| {
            j["status"] != "queued" && j["status"] != "running"
        })
        .await;
    assert_eq!(done["status"], "succeeded", "{done}");
    assert!(
        done["result"]["metrics"]["final_iou"].as_f64().unwrap() > 0.5,
        "{done}"
    );
    assert_eq!(done["result"]["metrics"]["floating_leaves"], 0, "{done}");
    app.stop().await;
}

/// Posts a morph of `a` into `b` and waits until it succeeded; returns
/// its id and its final document.
async fn morph_to_end(
    app: &crate::common::TestApp,
    a: &str,
    b: &str,
    frames: u32,
) -> (String, serde_json::Value) {
    let (s, job) = app.morph(a, b, frames).await;
    assert_eq!(s, 202, "{job}");
    let id = job["id"].as_str().unwrap().to_owned();
    let done = app
        .wait_job(&id, |j| j["status"] != "queued" && j["status"] != "running")
        .await;
    assert_eq!(done["status"], "succeeded", "{done}");
    (id, done)
}

/// Posts a morph of `a` into `b`, waits for it and returns its stream.
async fn morph_stream(app: &crate::common::TestApp, a: &str, b: &str) -> Vec<u8> {
    let (id, _) = morph_to_end(app, a, b, 5).await;
    let stream = app.get(&format!("/v1/jobs/{id}/stream")).await;
    assert_eq!(stream.status(), 200);
    stream.bytes().await.unwrap().to_vec()
}

/// The tree cache is invisible in the results: a job on trees the upload
/// left in the cache and the same job in a process that loads them from
/// the blob store give the same bytes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cached_and_loaded_trees_give_the_same_animation() {
    // One data directory for both processes, owned here so that stopping
    // the first server keeps it.
    let data = tempfile::tempdir().unwrap();
    let dir = data.path().to_owned();
    let first = spawn_with(treemorph::pipeline::default_runner(), {
        let dir = dir.clone();
        move |s: &mut Settings| {
            s.workers = Some(1);
            s.data_dir = dir;
        }
    })
    .await;
    let mut ids = Vec::new();
    for (preset, seed) in [("maple", 3), ("shrub", 4), ("conifer", 5)] {
        let (s, body) = first
            .post_json(
                "/v1/trees/generate",
                &json!({"preset": preset, "seed": seed, "size": 300}),
            )
            .await;
        assert_eq!(s, 201, "{body}");
        ids.push(body["id"].as_str().unwrap().to_owned());
    }
    let (a, b, spare) = (&ids[0], &ids[1], &ids[2]);
    // The upload seeded the cache with the tree and its analysis.
    let trees = &first.state.services.trees;
    assert!(trees.get(a).is_some_and(|t| t.is_analysed()));

    let from_cache = morph_stream(&first, a, b).await;
    let metrics = first.get("/metrics").await.text().await.unwrap();
    assert!(
        metrics.contains("treemorph_tree_cache_lookups_total{result=\"hit\"} 2"),
        "{metrics}"
    );
    // Deleting a tree drops it from the cache.
    assert!(trees.get(spare).is_some());
    let (s, _) = first.delete(&format!("/v1/trees/{spare}")).await;
    assert_eq!(s, 204);
    assert!(trees.get(spare).is_none());
    first.stop().await;

    // A second process on the same database and blobs, with no cache.
    let second = spawn_with(treemorph::pipeline::default_runner(), move |s| {
        s.workers = Some(1);
        s.data_dir = dir;
        s.tree_cache_mb = 0;
    })
    .await;
    let from_blobs = morph_stream(&second, a, b).await;
    assert_eq!(from_cache.len(), from_blobs.len());
    assert!(from_cache == from_blobs, "the animations differ");
    let metrics = second.get("/metrics").await.text().await.unwrap();
    assert!(
        metrics.contains("treemorph_tree_cache_lookups_total{result=\"miss\"} 2"),
        "{metrics}"
    );
    second.stop().await;
    drop(data);
}

/// A job's plan is stored with it, so a process that did not run it (here
/// a restarted one, with no plan kept and no tree cached) renders its
/// instants from the stored plan without its trees, the same bytes as the
/// process that ran it; a stored plan that cannot be read, with the trees
/// gone too, is answered 410 `plan_outdated`, never a 500.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restarted_server_renders_instants_from_the_stored_plan() {
    let data = tempfile::tempdir().unwrap();
    let dir = data.path().to_owned();
    // No render is kept in the blob store: each server renders its own.
    let configure = |dir: std::path::PathBuf| {
        move |s: &mut Settings| {
            s.workers = Some(1);
            s.data_dir = dir;
            s.render_store_mb = 0;
            s.tree_cache_mb = 0;
        }
    };
    let first = spawn_with(
        treemorph::pipeline::default_runner(),
        configure(dir.clone()),
    )
    .await;
    let mut ids = Vec::new();
    for (preset, seed) in [("maple", 3), ("shrub", 4)] {
        let (s, body) = first
            .post_json(
                "/v1/trees/generate",
                &json!({"preset": preset, "seed": seed, "size": 300}),
            )
            .await;
        assert_eq!(s, 201, "{body}");
        ids.push(body["id"].as_str().unwrap().to_owned());
    }
    let (id, _) = morph_to_end(&first, &ids[0], &ids[1], 5).await;
    let (s, expected) = instant(&first, &id, "0.3").await;
    assert_eq!(s, 200);
    first.stop().await;

    let job_dir = dir.join("blobs").join("jobs").join(&id);
    let plan = crate::common::files(&job_dir)
        .into_iter()
        .find(|p| p.ends_with("plan.bin"))
        .expect("the job stored its plan");
    for id in &ids {
        let tree_dir = dir.join("blobs").join("trees").join(id);
        std::fs::remove_dir_all(tree_dir).unwrap();
    }
    let second = spawn_with(
        treemorph::pipeline::default_runner(),
        configure(dir.clone()),
    )
    .await;
    let (s, rendered) = instant(&second, &id, "0.3").await;
    assert_eq!(s, 200, "{}", String::from_utf8_lossy(&rendered));
    assert!(rendered == expected, "the stored plan renders other bytes");
    second.stop().await;

    std::fs::write(&plan, b"TMPLAN\0\0 not a plan").unwrap();
    let third = spawn_with(treemorph::pipeline::default_runner(), configure(dir)).await;
    let (s, body) = third
        .get_json(&format!("/v1/jobs/{id}/frame.glb?t=0.6"))
        .await;
    assert_eq!((s, error_code(&body)), (410, "plan_outdated"), "{body}");
    third.stop().await;
    drop(data);
}

/// `frame.glb?t=T` of job `id`: its status and body.
async fn instant(app: &crate::common::TestApp, id: &str, t: &str) -> (u16, Vec<u8>) {
    let r = app.get(&format!("/v1/jobs/{id}/frame.glb?t={t}")).await;
    (r.status().as_u16(), r.bytes().await.unwrap().to_vec())
}
