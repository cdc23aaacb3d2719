//! The real binary: a `kill -9` during a job loses nothing, and SIGTERM
//! drains (the in-flight job finishes, or is released and later completes).
//! These use the test-only runner (`TREEMORPH_TEST_RUNNER=slow:MS`).

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};

struct Server {
    child: Child,
    base: String,
    client: reqwest::Client,
}

fn start(dir: &std::path::Path, runner: &str, extra: &[&str]) -> Server {
    let log = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(dir.join("server.log"))
        .unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_treemorph"))
        .args([
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--lease-secs",
            "2",
            "--poll-ms",
            "50",
            "--workers",
            "1",
        ])
        .arg("--data-dir")
        .arg(dir)
        .args(extra)
        .env("TREEMORPH_TEST_RUNNER", runner)
        .env("RUST_LOG", "info")
        .stdout(Stdio::piped())
        .stderr(Stdio::from(log))
        .spawn()
        .unwrap();
    let addr = crate::common::base_url(&mut child)
        .unwrap_or_else(|line| panic!("unexpected first line {line:?}"));
    Server {
        child,
        base: addr,
        client: crate::common::http_client(),
    }
}

impl Server {
    async fn post(&self, path: &str, body: Value) -> Value {
        let r = self
            .client
            .post(format!("{}{path}", self.base))
            .json(&body)
            .send()
            .await
            .unwrap();
        assert!(r.status().is_success(), "{}", r.status());
        r.json().await.unwrap()
    }

    async fn job(&self, id: &str) -> Value {
        self.client
            .get(format!("{}/v1/jobs/{id}", self.base))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap()
    }

    async fn wait(&self, id: &str, done: impl Fn(&Value) -> bool, within: Duration) -> Value {
        let deadline = Instant::now() + within;
        loop {
            let job = self.job(id).await;
            if done(&job) {
                return job;
            }
            assert!(Instant::now() < deadline, "timed out: {job}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    async fn setup_job(&self, frames: u32) -> String {
        let spec = |seed| json!({"preset": "maple", "seed": seed, "size": 80});
        let a = self.post("/v1/trees/generate", spec(1)).await["id"]
            .as_str()
            .unwrap()
            .to_owned();
        let b = self.post("/v1/trees/generate", spec(2)).await["id"]
            .as_str()
            .unwrap()
            .to_owned();
        let job = self
            .post(
                "/v1/jobs",
                json!({"kind": "morph", "source": a, "target": b, "frames": frames}),
            )
            .await;
        job["id"].as_str().unwrap().to_owned()
    }

    fn sigterm(&self) {
        let ok = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status()
            .unwrap()
            .success();
        assert!(ok);
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

async fn wait_exit(server: &mut Server, within: Duration) -> std::process::ExitStatus {
    let deadline = Instant::now() + within;
    loop {
        if let Some(status) = server.child.try_wait().unwrap() {
            return status;
        }
        assert!(Instant::now() < deadline, "the server did not exit");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kill_9_during_a_job_then_restart_completes_the_job() {
    let dir = tempfile::tempdir().unwrap();
    let mut first = start(dir.path(), "slow:100", &[]);
    let id = first.setup_job(20).await;
    first
        .wait(
            &id,
            |j| j["frames_ready"].as_u64().unwrap_or(0) >= 3,
            Duration::from_secs(20),
        )
        .await;
    first.child.kill().unwrap(); // SIGKILL
    first.child.wait().unwrap();

    let second = start(dir.path(), "slow:10", &[]);
    let done = second
        .wait(&id, |j| j["status"] == "succeeded", Duration::from_secs(30))
        .await;
    assert_eq!(done["attempt"], 2, "{done}");
    assert_eq!(done["frames_ready"], 20);
    let stream = second
        .client
        .get(format!("{}/v1/jobs/{id}/stream", second.base))
        .send()
        .await
        .unwrap()
        .bytes()
        .await
        .unwrap();
    let (_, frames) = treemorph_api::delta::decode_all(&stream, &Default::default()).unwrap();
    assert_eq!(frames.len(), 20);
    // Only the winning attempt's outputs are left.
    let attempts = std::fs::read_dir(dir.path().join("blobs/jobs").join(&id))
        .unwrap()
        .count();
    assert_eq!(attempts, 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_lets_the_in_flight_job_finish() {
    let dir = tempfile::tempdir().unwrap();
    let mut server = start(dir.path(), "slow:100", &["--shutdown-grace", "30"]);
    let id = server.setup_job(15).await;
    server
        .wait(
            &id,
            |j| j["frames_ready"].as_u64().unwrap_or(0) >= 1,
            Duration::from_secs(20),
        )
        .await;
    server.sigterm();
    let status = wait_exit(&mut server, Duration::from_secs(30)).await;
    assert!(status.success(), "{status}");
    let after = start(dir.path(), "slow:10", &[]);
    let job = after.job(&id).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    assert_eq!(job["attempt"], 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_releases_a_long_job_which_completes_after_restart() {
    let dir = tempfile::tempdir().unwrap();
    let mut server = start(dir.path(), "slow:100", &["--shutdown-grace", "1"]);
    let id = server.setup_job(200).await;
    server
        .wait(
            &id,
            |j| j["frames_ready"].as_u64().unwrap_or(0) >= 1,
            Duration::from_secs(20),
        )
        .await;
    let t = Instant::now();
    server.sigterm();
    let status = wait_exit(&mut server, Duration::from_secs(15)).await;
    assert!(status.success(), "{status}");
    assert!(t.elapsed() < Duration::from_secs(10));
    let after = start(dir.path(), "slow:1", &[]);
    let job = after.job(&id).await;
    assert!(
        job["status"] == "queued" || job["status"] == "running" || job["status"] == "succeeded",
        "{job}"
    );
    let done = after
        .wait(&id, |j| j["status"] == "succeeded", Duration::from_secs(30))
        .await;
    assert_eq!(
        done["attempt"], 1,
        "a released attempt is not counted: {done}"
    );
}
