//! End to end with the production runner on real generated trees.

use serde_json::json;
use treemorph::config::Settings;

use crate::common::spawn_with;

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
    let (s, job) = app.morph(&a, &b, 10).await;
    assert_eq!(s, 202, "{job}");
    let id = job["id"].as_str().unwrap().to_owned();
    let done = app
        .wait_job(&id, |j| j["status"] != "queued" && j["status"] != "running")
        .await;
    assert_eq!(done["status"], "succeeded", "{done}");
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
    let stream = app
        .get(&format!("/v1/jobs/{id}/stream"))
        .await
        .bytes()
        .await
        .unwrap();
    let (_, frames) = treemorph_api::delta::decode_all(&stream, &Default::default()).unwrap();
    assert_eq!(frames.len(), 10);
    let glb = app
        .get(&format!("/v1/jobs/{id}/frames/0.glb"))
        .await
        .bytes()
        .await
        .unwrap();
    assert_eq!(&glb[..4], b"glTF");

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
