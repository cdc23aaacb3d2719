//! Spawning servers and talking to them.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use serde_json::{Value, json};
use tokio::sync::oneshot;
use treemorph::config::Settings;
use treemorph::jobs::testing::TestRunner;
use treemorph::pipeline::Runner;
use treemorph::server::{AppState, serve_state};

/// A running server.
pub struct TestApp {
    pub base: String,
    pub client: reqwest::Client,
    pub state: AppState,
    pub dir: tempfile::TempDir,
    shutdown: Option<oneshot::Sender<()>>,
    handle: Option<tokio::task::JoinHandle<anyhow::Result<()>>>,
}

impl TestApp {
    pub fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    pub async fn get(&self, path: &str) -> reqwest::Response {
        self.client.get(self.url(path)).send().await.unwrap()
    }

    pub async fn get_json(&self, path: &str) -> (u16, Value) {
        let r = self.get(path).await;
        let status = r.status().as_u16();
        (status, r.json().await.unwrap_or(Value::Null))
    }

    pub async fn post_json(&self, path: &str, body: &Value) -> (u16, Value) {
        let r = self
            .client
            .post(self.url(path))
            .json(body)
            .send()
            .await
            .unwrap();
        let status = r.status().as_u16();
        (status, r.json().await.unwrap_or(Value::Null))
    }

    pub async fn delete(&self, path: &str) -> (u16, Value) {
        let r = self.client.delete(self.url(path)).send().await.unwrap();
        let status = r.status().as_u16();
        (status, r.json().await.unwrap_or(Value::Null))
    }

    /// Generates a small tree; returns its id.
    pub async fn tree(&self, seed: u64) -> String {
        let (status, body) = self
            .post_json(
                "/v1/trees/generate",
                &json!({"preset": "maple", "seed": seed, "size": 120}),
            )
            .await;
        assert_eq!(status, 201, "{body}");
        body["id"].as_str().unwrap().to_owned()
    }

    /// Posts a morph job; returns (status, body).
    pub async fn morph(&self, source: &str, target: &str, frames: u32) -> (u16, Value) {
        self.post_json(
            "/v1/jobs",
            &json!({"kind": "morph", "source": source, "target": target, "frames": frames}),
        )
        .await
    }

    /// Polls a job until `done(job)` or the deadline (then panics).
    pub async fn wait_job(&self, id: &str, done: impl Fn(&Value) -> bool) -> Value {
        let deadline = tokio::time::Instant::now() + Duration::from_secs(30);
        loop {
            let (status, job) = self.get_json(&format!("/v1/jobs/{id}")).await;
            assert_eq!(status, 200, "{job}");
            if done(&job) {
                return job;
            }
            assert!(
                tokio::time::Instant::now() < deadline,
                "timed out waiting: {job}"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    pub async fn wait_status(&self, id: &str, status: &str) -> Value {
        self.wait_job(id, |j| j["status"] == status).await
    }

    pub async fn stop(mut self) {
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
        if let Some(h) = self.handle.take() {
            h.await.unwrap().unwrap();
        }
    }
}

impl Drop for TestApp {
    fn drop(&mut self) {
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
    }
}

/// Test settings: 2 workers, fast polls, loopback callbacks allowed.
pub fn settings(dir: &std::path::Path) -> Settings {
    let mut s = Settings::with_data_dir(dir);
    s.workers = Some(2);
    s.poll_ms = 30;
    s.lease_secs = 5;
    s.shutdown_grace = 5;
    s.allow_private_callbacks = true;
    s.webhook_secret = Some("whsec_MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw".into());
    s
}

pub async fn spawn_with(runner: Arc<dyn Runner>, configure: impl FnOnce(&mut Settings)) -> TestApp {
    let dir = tempfile::tempdir().unwrap();
    spawn_in(dir, runner, configure).await
}

/// A server with its data in `dir` (several servers may share one
/// database and blob store: pass the same paths through `configure`).
pub async fn spawn_in(
    dir: tempfile::TempDir,
    runner: Arc<dyn Runner>,
    configure: impl FnOnce(&mut Settings),
) -> TestApp {
    let mut s = settings(dir.path());
    configure(&mut s);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let base = format!("http://{}", listener.local_addr().unwrap());
    let state = AppState::new(s, runner).await.unwrap();
    let (tx, rx) = oneshot::channel::<()>();
    let handle = tokio::spawn(serve_state(state.clone(), listener, async move {
        let _ = rx.await;
    }));
    TestApp {
        base,
        client: http_client(),
        state,
        dir,
        shutdown: Some(tx),
        handle: Some(handle),
    }
}

/// A server whose jobs emit frames at once.
pub async fn spawn() -> TestApp {
    spawn_with(Arc::new(TestRunner::slow(Duration::ZERO)), |_| {}).await
}

/// Asserts the uniform error body and returns the code.
pub fn error_code(body: &Value) -> &str {
    assert!(
        body["error"]["message"].is_string(),
        "not an error body: {body}"
    );
    body["error"]["code"].as_str().expect("error code")
}

/// The base URL a spawned `treemorph serve --listen 127.0.0.1:0` prints
/// as its first stdout line (`listening on URL`); the line itself when it
/// is something else.
pub fn base_url(child: &mut std::process::Child) -> Result<String, String> {
    use std::io::BufRead;
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().expect("stdout is piped"))
        .read_line(&mut line)
        .map_err(|e| e.to_string())?;
    line.trim()
        .strip_prefix("listening on ")
        .map(str::to_owned)
        .ok_or(line)
}

/// Every file under `dir`, recursively.
pub fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_owned()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).into_iter().flatten().flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else {
                out.push(path);
            }
        }
    }
    out.sort();
    out
}

/// Polls `done` every 20 ms until it holds or 10 s have passed (for what
/// a server does right after an answer, such as cleaning up after a job's
/// end); the caller asserts on what it then finds.
pub async fn eventually<F: std::future::Future<Output = bool>>(mut done: impl FnMut() -> F) {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    while !done().await && tokio::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// An HTTP client for the tests, with the process's TLS crypto provider
/// installed (reqwest is built without one: `treemorph::tls`).
pub fn http_client() -> reqwest::Client {
    treemorph::tls::client_builder()
        .build()
        .expect("a client with default settings")
}

/// Reads SSE events (name, data) until the stream ends.
pub async fn read_events(mut r: reqwest::Response) -> Vec<(String, Value)> {
    let mut buf = String::new();
    let mut events = vec![];
    while let Some(chunk) = r.chunk().await.unwrap() {
        buf.push_str(std::str::from_utf8(&chunk).unwrap());
        while let Some(end) = buf.find("\n\n") {
            let block: String = buf.drain(..end + 2).collect();
            let mut name = String::from("message");
            let mut data = String::new();
            for line in block.lines() {
                if let Some(n) = line.strip_prefix("event:") {
                    name = n.trim().to_owned();
                } else if let Some(d) = line.strip_prefix("data:") {
                    data.push_str(d.trim());
                }
            }
            if !data.is_empty() {
                events.push((name, serde_json::from_str(&data).unwrap()));
            }
        }
    }
    events
}

/// The frame indices an event stream reported: those its first `job`
/// document already counted as ready (a subscriber that connects late
/// starts from the present, frames included), then each `frame` event.
pub fn frames_reported(events: &[(String, Value)]) -> Vec<u64> {
    let (first, job) = events.first().expect("an event stream starts");
    assert_eq!(first, "job", "the first event is the job document");
    let ready = job["frames_ready"].as_u64().unwrap_or(0);
    let announced = events
        .iter()
        .filter(|(n, _)| n == "frame")
        .map(|(_, d)| d["index"].as_u64().unwrap());
    (0..ready).chain(announced).collect()
}

/// The stage an event stream reported before its first `frame` event: the
/// last `stage` event before it, else the stage of its opening `job`
/// document (a subscriber that connects after the stage began is told it
/// there, not by an event).
pub fn stage_before_first_frame(events: &[(String, Value)]) -> Option<String> {
    let before = events.iter().take_while(|(n, _)| n != "frame");
    before
        .filter(|(n, _)| n == "stage" || n == "job")
        .filter_map(|(_, d)| d["stage"].as_str().map(str::to_owned))
        .last()
}
