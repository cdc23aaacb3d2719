//! The live delta stream and the SSE event sequence.

use std::sync::Arc;
use std::time::Duration;

use treemorph::jobs::testing::TestRunner;
use treemorph_api::delta::{Decoder, DecoderOptions, Event, decode_all};

use crate::common::{
    error_code, frames_reported, read_events, spawn_with, stage_before_first_frame,
};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_stream_delivers_frames_while_the_job_runs_and_completes_afterwards() {
    let app = spawn_with(
        Arc::new(TestRunner::slow(Duration::from_millis(60))),
        |_| {},
    )
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let frames = 12;
    let (_, job) = app.morph(&a, &b, frames).await;
    let id = job["id"].as_str().unwrap().to_owned();
    // Subscribe before the job starts: the stream waits for the header.
    let mut r = app.get(&format!("/v1/jobs/{id}/stream")).await;
    assert_eq!(r.status(), 200);
    assert_eq!(
        r.headers()["content-type"],
        treemorph_api::delta::MEDIA_TYPE
    );
    let mut decoder = Decoder::new(&DecoderOptions::default());
    let mut all = Vec::new();
    let mut decoded = 0u32;
    let mut saw_running_after_a_frame = false;
    let mut header = false;
    while let Some(chunk) = r.chunk().await.unwrap() {
        all.extend_from_slice(&chunk);
        decoder.push(&chunk);
        while let Some(event) = decoder.next_event().unwrap() {
            match event {
                Event::Header(_) => header = true,
                Event::Frame(f) => {
                    assert_eq!(f.index, decoded);
                    decoded += 1;
                    if decoded == 1 {
                        let (_, now) = app.get_json(&format!("/v1/jobs/{id}")).await;
                        saw_running_after_a_frame = now["status"] == "running";
                    }
                }
                _ => {}
            }
        }
    }
    decoder.finish().unwrap();
    assert!(header);
    assert_eq!(decoded, frames);
    assert!(
        saw_running_after_a_frame,
        "the first frame arrived before the job ended"
    );
    assert!(decoder.is_complete());

    // Afterwards: the same bytes, with an ETag and ranges.
    let r = app.get(&format!("/v1/jobs/{id}/stream")).await;
    assert_eq!(r.status(), 200);
    let etag = r.headers()["etag"].to_str().unwrap().to_owned();
    let complete = r.bytes().await.unwrap();
    assert_eq!(
        complete.to_vec(),
        all,
        "live and stored streams are identical"
    );
    assert_eq!(
        decode_all(&complete, &DecoderOptions::default())
            .unwrap()
            .1
            .len(),
        frames as usize
    );
    let r = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}/stream")))
        .header("range", "bytes=4-9")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 206);
    assert_eq!(r.bytes().await.unwrap()[..], complete[4..10]);
    let r = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}/stream")))
        .header("if-none-match", &etag)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 304);
    let r = app
        .client
        .get(app.url(&format!("/v1/jobs/{id}/stream")))
        .header("range", "bytes=999999-")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 416);
    assert_eq!(
        error_code(&r.json().await.unwrap()),
        "range_not_satisfiable"
    );
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_late_stream_subscriber_gets_everything_from_the_start() {
    let app = spawn_with(
        Arc::new(TestRunner::slow(Duration::from_millis(40))),
        |_| {},
    )
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 15).await;
    let id = job["id"].as_str().unwrap().to_owned();
    app.wait_job(&id, |j| j["frames_ready"].as_u64().unwrap() >= 5)
        .await;
    let bytes = app
        .get(&format!("/v1/jobs/{id}/stream"))
        .await
        .bytes()
        .await
        .unwrap();
    let (_, frames) = decode_all(&bytes, &DecoderOptions::default()).unwrap();
    assert_eq!(frames.len(), 15);
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sse_reports_state_stages_frames_and_the_end() {
    let app = spawn_with(
        Arc::new(TestRunner::slow(Duration::from_millis(40))),
        |_| {},
    )
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 8).await;
    let id = job["id"].as_str().unwrap().to_owned();
    let r = app.get(&format!("/v1/jobs/{id}/events")).await;
    assert_eq!(r.status(), 200);
    assert!(
        r.headers()["content-type"]
            .to_str()
            .unwrap()
            .starts_with("text/event-stream")
    );
    let events = read_events(r).await;
    let names: Vec<&str> = events.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names[0], "job", "{names:?}");
    assert_eq!(*names.last().unwrap(), "done", "{names:?}");
    assert_eq!(events.last().unwrap().1["status"], "succeeded");
    assert_eq!(
        frames_reported(&events),
        (0..8).collect::<Vec<_>>(),
        "{names:?}"
    );
    // The stage reaches the subscriber before any frame: by a `stage`
    // event, or in the opening job document when the subscription came
    // after the stage began.
    assert_eq!(
        stage_before_first_frame(&events).as_deref(),
        Some("frames"),
        "{names:?}"
    );

    // A late subscriber to a finished job gets its state and the end.
    let late = read_events(app.get(&format!("/v1/jobs/{id}/events")).await).await;
    let names: Vec<&str> = late.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["job", "done"]);
    app.stop().await;
}

/// A subscriber that connects while a job runs, after frames were
/// published (the race that the scale-out check lost on CI): its opening
/// job document counts the frames already out, and `frame` events follow
/// for the rest, each once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sse_subscriber_joining_mid_job_gets_every_frame_once() {
    let app = spawn_with(
        Arc::new(TestRunner::slow(Duration::from_millis(40))),
        |_| {},
    )
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 12).await;
    let id = job["id"].as_str().unwrap().to_owned();
    app.wait_job(&id, |j| j["frames_ready"].as_u64().unwrap() >= 3)
        .await;
    let events = read_events(app.get(&format!("/v1/jobs/{id}/events")).await).await;
    assert!(events[0].1["frames_ready"].as_u64().unwrap() >= 3);
    assert_eq!(frames_reported(&events), (0..12).collect::<Vec<_>>());
    // Joining after the frames stage began, it learns the stage from the
    // opening document: no `stage` event comes before its first frame.
    assert_eq!(events[0].1["stage"], "frames");
    assert_eq!(stage_before_first_frame(&events).as_deref(), Some("frames"));
    assert_eq!(events.last().unwrap().0, "done");
    app.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sse_ends_with_cancelled_or_failed() {
    let app = spawn_with(
        Arc::new(TestRunner::slow(Duration::from_millis(50))),
        |_| {},
    )
    .await;
    let (a, b) = (app.tree(1).await, app.tree(2).await);
    let (_, job) = app.morph(&a, &b, 300).await;
    let id = job["id"].as_str().unwrap().to_owned();
    let r = app.get(&format!("/v1/jobs/{id}/events")).await;
    let reader = tokio::spawn(read_events(r));
    app.wait_job(&id, |j| j["frames_ready"].as_u64().unwrap() >= 2)
        .await;
    app.delete(&format!("/v1/jobs/{id}")).await;
    let events = tokio::time::timeout(Duration::from_secs(20), reader)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(events.last().unwrap().0, "cancelled");
    app.stop().await;
}
