//! Scale-out under fire (issue 10): a fleet of real `treemorph serve`
//! processes — 2 with `--role api`, 3 with `--role worker` — shares one
//! PostgreSQL database and one S3 bucket. 200 jobs are posted through both
//! API processes while a random worker is `kill -9`ed (and restarted) ten
//! times, a few jobs are cancelled from the other API process, and clients
//! follow jobs live (SSE, the delta stream, frames) through either API
//! process. Then:
//!
//! 1. every job is in a terminal state: succeeded, or cancelled when we
//!    asked (none failed);
//! 2. no attempt ran twice, and no two runs of a job overlapped in time
//!    unless the earlier one had lost its lease (and so was fenced): the
//!    worker's test runner logs every run's start and end
//!    ([`treemorph::jobs::testing::TraceEvent`]); a run cut short by
//!    `kill -9` ends when its process died;
//! 3. no output of a superseded attempt is ever served: the test runner
//!    stamps its attempt token into every output, and every frame, file and
//!    complete stream served carries the token the job's row publishes —
//!    the token of a run that ended `ok`.
//!
//! It needs `TREEMORPH_TEST_POSTGRES_URL` (a PostgreSQL server URL without
//! a database name; a fresh database is created) and
//! `TREEMORPH_TEST_S3_URL` (`s3://bucket`, which must exist; a fresh prefix
//! is used) with the `AWS_*` environment for it, which the processes
//! inherit. `scripts/ci/scaleout.sh` starts both servers and runs it.
//! `TREEMORPH_SCALEOUT_OUT` names a directory to keep the processes' logs
//! and traces in (a temporary directory otherwise).

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use futures_util::StreamExt;
use serde_json::{Value, json};
use treemorph::jobs::testing::{TraceEvent, read_trace, stamped_header_token, stamped_token};
use treemorph::store::{Db, new_id, now_ms, random_u64};
use treemorph_api::delta::{Decoder, DecoderOptions, Event, decode_all};

const JOBS: usize = 200;
const KILLS: usize = 10;
const API_PROCESSES: usize = 2;
const WORKER_PROCESSES: usize = 3;
/// Jobs each worker process runs at once.
const SLOTS: usize = 2;
/// The test runner's delay per frame: jobs take a little time while the
/// CPU stays free for the database, the S3 server and the processes.
const FRAME_MS: u64 = 40;
const CANCELS: usize = 8;
const FOLLOWERS: usize = 12;

/// How every process of the fleet is started.
struct Fleet {
    database_url: String,
    blob_url: String,
    trace: PathBuf,
    logs: PathBuf,
}

/// One running process.
struct Proc {
    child: Child,
    base: String,
    name: String,
}

impl Fleet {
    fn launch(&self, role: &str, name: &str) -> Proc {
        let data = self.logs.join(format!("data-{name}"));
        std::fs::create_dir_all(&data).unwrap();
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(self.logs.join(format!("{name}.log")))
            .unwrap();
        let mut child = Command::new(env!("CARGO_BIN_EXE_treemorph"))
            .args(["serve", "--listen", "127.0.0.1:0", "--role", role])
            .args(["--database-url", &self.database_url])
            .args(["--blob-url", &self.blob_url])
            .arg("--data-dir")
            .arg(&data)
            .args(["--workers", &SLOTS.to_string()])
            .args(["--lease-secs", "3", "--poll-ms", "100"])
            .args(["--max-attempts", "10", "--shutdown-grace", "5"])
            // One secret for the fleet, as a deployment must configure it.
            .args(["--webhook-secret", "whsec_MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw"])
            .env(
                "TREEMORPH_TEST_RUNNER",
                format!("slow:{FRAME_MS},trace={}", self.trace.display()),
            )
            .env("RUST_LOG", "info")
            .stdout(Stdio::piped())
            .stderr(Stdio::from(log))
            .spawn()
            .unwrap();
        // For the CI script's cleanup, should this test die without
        // killing its children.
        let _ = std::fs::write(
            self.logs.join(format!("{name}.pid")),
            child.id().to_string(),
        );
        let base = crate::common::base_url(&mut child).unwrap_or_else(|line| {
            panic!(
                "{name} did not start (first line {line:?}); see {}",
                self.logs.join(format!("{name}.log")).display()
            )
        });
        Proc {
            child,
            base,
            name: name.to_owned(),
        }
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Sends SIGTERM and waits up to `within` for the exit (then SIGKILL).
fn terminate(mut proc: Proc, within: Duration) {
    let _ = Command::new("kill")
        .args(["-TERM", &proc.child.id().to_string()])
        .status();
    let deadline = Instant::now() + within;
    while Instant::now() < deadline {
        if proc.child.try_wait().unwrap().is_some() {
            return;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    eprintln!("{} ignored SIGTERM for {within:?}", proc.name);
}

fn pick(n: usize) -> usize {
    (random_u64() % n as u64) as usize
}

/// What a client following a job live saw.
#[derive(Debug)]
enum Seen {
    /// The SSE stream's last event name.
    Events { job: String, last: Option<String> },
    /// The live delta stream: the stamped header token, frames decoded,
    /// whether it was complete, and a decoding error.
    Stream {
        job: String,
        token: Option<String>,
        frames: u32,
        complete: bool,
        error: Option<String>,
    },
    /// A frame fetched while the job ran, and the token stamped into it.
    Frame { job: String, token: Option<String> },
}

/// A job's final row: id, status, published token, frames, attempt, error.
type FinalRow = (String, String, Option<String>, i64, i64, Option<String>);

async fn follow_events(client: reqwest::Client, base: String, job: String) -> Seen {
    let r = client
        .get(format!("{base}/v1/jobs/{job}/events"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let text = tokio::time::timeout(Duration::from_secs(200), r.text())
        .await
        .expect("the SSE stream did not end")
        .unwrap_or_default();
    let last = text
        .lines()
        .filter_map(|l| l.strip_prefix("event: "))
        .next_back()
        .map(str::to_owned);
    Seen::Events { job, last }
}

async fn follow_stream(client: reqwest::Client, base: String, job: String) -> Seen {
    let r = client
        .get(format!("{base}/v1/jobs/{job}/stream"))
        .send()
        .await
        .unwrap();
    let mut decoder = Decoder::new(&DecoderOptions::default());
    let (mut token, mut frames, mut error) = (None, 0, None);
    if r.status() == 200 {
        let mut body = r.bytes_stream();
        let read = async {
            while let Some(chunk) = body.next().await {
                let Ok(chunk) = chunk else { break };
                decoder.push(&chunk);
                loop {
                    match decoder.next_event() {
                        Ok(Some(Event::Header(h))) => {
                            token = stamped_header_token(&h).map(str::to_owned)
                        }
                        Ok(Some(Event::Frame(_))) => frames += 1,
                        Ok(Some(Event::End { .. })) => {}
                        Ok(None) => break,
                        Err(e) => {
                            error = Some(e.to_string());
                            return;
                        }
                    }
                }
            }
        };
        tokio::time::timeout(Duration::from_secs(200), read)
            .await
            .expect("the live stream did not end");
    }
    Seen::Stream {
        job,
        token,
        frames,
        complete: decoder.is_complete(),
        error,
    }
}

/// Frames of running jobs, fetched as they appear (through random API
/// processes).
async fn sample_frames(
    client: reqwest::Client,
    apis: Vec<String>,
    until: tokio::sync::watch::Receiver<bool>,
) -> Vec<Seen> {
    let mut seen = Vec::new();
    while !*until.borrow() {
        let base = &apis[pick(apis.len())];
        let page: Value = client
            .get(format!("{base}/v1/jobs?status=running&limit=20"))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        let running = page["items"].as_array().cloned().unwrap_or_default();
        for doc in running {
            let job = doc["id"].as_str().unwrap_or_default().to_owned();
            let ready = doc["frames_ready"].as_u64().unwrap_or(0);
            if ready == 0 {
                continue;
            }
            let r = client
                .get(format!("{base}/v1/jobs/{job}/frames/{}.glb", ready - 1))
                .send()
                .await
                .unwrap();
            if r.status() == 200 {
                let glb = r.bytes().await.unwrap();
                seen.push(Seen::Frame {
                    job,
                    token: stamped_token(&glb).map(str::to_owned),
                });
            }
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    seen
}

/// One run of an attempt, from the trace.
#[derive(Debug)]
struct Run {
    job: String,
    attempt: u32,
    pid: u32,
    start: i64,
    end: Option<i64>,
    outcome: Option<String>,
}

/// Every violation of the trace's invariants (see the module docs), and the
/// runs by token.
fn check_runs(
    events: &[TraceEvent],
    killed: &HashMap<u32, i64>,
) -> (Vec<String>, HashMap<String, Run>) {
    let mut problems = Vec::new();
    let mut runs: HashMap<String, Run> = HashMap::new();
    for e in events {
        match e.ev.as_str() {
            "start" => {
                if runs.contains_key(&e.token) {
                    problems.push(format!("attempt {} started twice", e.token));
                    continue;
                }
                runs.insert(
                    e.token.clone(),
                    Run {
                        job: e.job.clone(),
                        attempt: e.attempt,
                        pid: e.pid,
                        start: e.at_ms,
                        end: None,
                        outcome: None,
                    },
                );
            }
            "end" => match runs.get_mut(&e.token) {
                Some(run) if run.end.is_none() => {
                    run.end = Some(e.at_ms);
                    run.outcome = e.outcome.clone();
                }
                _ => problems.push(format!("attempt {} ended without a start", e.token)),
            },
            other => problems.push(format!("unknown trace event {other:?}")),
        }
    }
    // A run cut short ends when its process died.
    for (token, run) in &mut runs {
        if run.end.is_none() {
            match killed.get(&run.pid) {
                Some(&at) => {
                    run.end = Some(at);
                    run.outcome = Some("killed".into());
                }
                None => problems.push(format!(
                    "attempt {token} of job {} never ended, and its process {} was not killed",
                    run.job, run.pid
                )),
            }
        }
    }
    let mut by_job: BTreeMap<&str, Vec<(&String, &Run)>> = BTreeMap::new();
    let mut by_attempt: HashSet<(&str, u32)> = HashSet::new();
    for (token, run) in &runs {
        by_job.entry(&run.job).or_default().push((token, run));
        if !by_attempt.insert((&run.job, run.attempt)) {
            problems.push(format!(
                "job {} attempt {} ran more than once",
                run.job, run.attempt
            ));
        }
    }
    for (job, runs) in &mut by_job {
        runs.sort_by_key(|(_, r)| r.start);
        for (i, (token, earlier)) in runs.iter().enumerate() {
            for (later_token, later) in &runs[i + 1..] {
                let end = earlier.end.unwrap_or(i64::MAX);
                if end > later.start && earlier.outcome.as_deref() != Some("stopped") {
                    problems.push(format!(
                        "job {job}: attempt {token} (#{}, until {end}, {:?}) overlaps attempt \
                         {later_token} (#{}, from {})",
                        earlier.attempt, earlier.outcome, later.attempt, later.start
                    ));
                }
            }
        }
    }
    (problems, runs)
}

async fn get_bytes(client: &reqwest::Client, url: &str) -> (u16, bytes::Bytes) {
    let r = client.get(url).send().await.unwrap();
    let status = r.status().as_u16();
    (status, r.bytes().await.unwrap_or_default())
}

/// Jobs deleted at the end of the fleet test: `DELETE` on ended jobs
/// through alternating API processes.
const DELETES: usize = 40;

/// Deletes [`DELETES`] ended jobs and checks that each answers 404 after
/// and that exactly their objects left the blob store (S3): the store's
/// object count under `jobs/` drops by what their prefixes held. Returns
/// how many were deleted.
async fn delete_some(
    client: &reqwest::Client,
    api_urls: &[String],
    blobs: &treemorph::store::Blobs,
    rows: &[FinalRow],
    problems: &mut Vec<String>,
) -> usize {
    let before = blobs.usage("jobs").await.unwrap();
    let mut held = (0, 0);
    for (i, (id, ..)) in rows.iter().take(DELETES).enumerate() {
        let (n, bytes) = blobs.usage(&format!("jobs/{id}")).await.unwrap();
        held = (held.0 + n, held.1 + bytes);
        let base = &api_urls[i % api_urls.len()];
        let r = client
            .delete(format!("{base}/v1/jobs/{id}"))
            .send()
            .await
            .unwrap();
        if r.status() != 204 {
            problems.push(format!("DELETE of ended job {id} answered {}", r.status()));
        }
        let r = client
            .get(format!("{base}/v1/jobs/{id}"))
            .send()
            .await
            .unwrap();
        if r.status() != 404 {
            problems.push(format!("deleted job {id} answered {}", r.status()));
        }
    }
    let after = blobs.usage("jobs").await.unwrap();
    if after != (before.0 - held.0, before.1 - held.1) {
        problems.push(format!(
            "deleting {DELETES} jobs holding {held:?} (objects, bytes) took the store from {before:?} to {after:?}"
        ));
    }
    DELETES.min(rows.len())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs TREEMORPH_TEST_POSTGRES_URL, TREEMORPH_TEST_S3_URL and an S3 server"]
async fn a_fleet_of_processes_survives_kill_9() {
    let admin = std::env::var("TREEMORPH_TEST_POSTGRES_URL").expect("TREEMORPH_TEST_POSTGRES_URL");
    let admin = admin.trim_end_matches('/').to_owned();
    let s3 = std::env::var("TREEMORPH_TEST_S3_URL").expect("TREEMORPH_TEST_S3_URL");
    let run = new_id();
    let name = format!("treemorph_fleet_{run}");
    let server = Db::connect(&format!("{admin}/postgres")).await.unwrap();
    sqlx::query(sqlx::AssertSqlSafe(format!("CREATE DATABASE {name}")))
        .execute(&server.pool)
        .await
        .unwrap();
    let keep = std::env::var_os("TREEMORPH_SCALEOUT_OUT").map(PathBuf::from);
    let scratch = tempfile::tempdir().unwrap();
    let out = keep.unwrap_or_else(|| scratch.path().to_owned());
    let fleet = Fleet {
        database_url: format!("{admin}/{name}"),
        blob_url: format!("{}/fleet-{run}", s3.trim_end_matches('/')),
        trace: out.join("trace"),
        logs: out.join("logs"),
    };
    std::fs::create_dir_all(&fleet.trace).unwrap();
    std::fs::create_dir_all(&fleet.logs).unwrap();
    eprintln!("fleet run {run}: logs and traces in {}", out.display());
    let started = Instant::now();

    // The API processes start first and race each other to migrate the
    // fresh database; the workers start while they do.
    let fleet = std::sync::Arc::new(fleet);
    let launch = |role: &'static str, name: String| {
        let fleet = fleet.clone();
        tokio::task::spawn_blocking(move || fleet.launch(role, &name))
    };
    let mut starting = Vec::new();
    for i in 0..API_PROCESSES {
        starting.push(launch("api", format!("api{i}")));
    }
    for i in 0..WORKER_PROCESSES {
        starting.push(launch("worker", format!("worker{i}")));
    }
    let mut procs = Vec::new();
    for p in starting {
        procs.push(p.await.unwrap());
    }
    let mut workers: Vec<Proc> = procs.split_off(API_PROCESSES);
    let apis = procs;
    let api_urls: Vec<String> = apis.iter().map(|p| p.base.clone()).collect();
    let db = Db::connect(&fleet.database_url).await.unwrap();
    let client = crate::common::http_client();

    // Trees, then the jobs, through both API processes.
    let mut trees = Vec::new();
    for seed in [1, 2] {
        let r: Value = client
            .post(format!("{}/v1/trees/generate", api_urls[seed % 2]))
            .json(&json!({"preset": "maple", "seed": seed, "size": 80}))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        trees.push(r["id"].as_str().expect("tree id").to_owned());
    }
    let posts = (0..JOBS).map(|i| {
        let (client, base) = (client.clone(), api_urls[i % API_PROCESSES].clone());
        let body = json!({
            "kind": "morph",
            "source": trees[0],
            "target": trees[1],
            "frames": 4 + (i % 13),
        });
        async move {
            let r = client
                .post(format!("{base}/v1/jobs"))
                .json(&body)
                .send()
                .await
                .unwrap();
            assert_eq!(r.status(), 202);
            let doc: Value = r.json().await.unwrap();
            doc["id"].as_str().unwrap().to_owned()
        }
    });
    let jobs: Vec<String> = futures_util::stream::iter(posts)
        .buffer_unordered(16)
        .collect()
        .await;
    eprintln!(
        "{} jobs posted after {:.1}s",
        jobs.len(),
        started.elapsed().as_secs_f64()
    );

    // Clients follow jobs live, cancel a few, and fetch frames as they
    // appear — always through a random API process.
    let mut watching = tokio::task::JoinSet::new();
    for i in 0..FOLLOWERS {
        let (client, base) = (client.clone(), api_urls[pick(API_PROCESSES)].clone());
        let job = jobs[pick(JOBS)].clone();
        if i % 2 == 0 {
            watching.spawn(follow_events(client, base, job));
        } else {
            watching.spawn(follow_stream(client, base, job));
        }
    }
    let mut cancelled = HashSet::new();
    let mut cancelling = tokio::task::JoinSet::new();
    for i in 0..CANCELS {
        let job = jobs[pick(JOBS)].clone();
        cancelled.insert(job.clone());
        let (client, base) = (client.clone(), api_urls[i % API_PROCESSES].clone());
        cancelling.spawn(async move {
            tokio::time::sleep(Duration::from_millis(random_u64() % 15_000)).await;
            let r = client
                .post(format!("{base}/v1/jobs/{job}/cancel"))
                .send()
                .await
                .unwrap();
            assert!(
                [200, 202, 409].contains(&r.status().as_u16()),
                "{}",
                r.status()
            );
        });
    }
    let (stop_sampling, until) = tokio::sync::watch::channel(false);
    let sampler = tokio::spawn(sample_frames(client.clone(), api_urls.clone(), until));

    // kill -9 a random worker ten times, restarting it each time.
    let mut killed: HashMap<u32, i64> = HashMap::new();
    for k in 0..KILLS {
        tokio::time::sleep(Duration::from_millis(1500 + random_u64() % 1500)).await;
        let i = pick(WORKER_PROCESSES);
        let mut victim = workers.remove(i);
        let pid = victim.child.id();
        victim.child.kill().unwrap(); // SIGKILL
        victim.child.wait().unwrap();
        killed.insert(pid, now_ms());
        let name = format!("worker{i}-{}", k + 1);
        workers.insert(i, launch("worker", name).await.unwrap());
    }
    eprintln!(
        "{KILLS} workers killed and restarted after {:.1}s",
        started.elapsed().as_secs_f64()
    );

    // Every job reaches a terminal state.
    let deadline = Instant::now() + Duration::from_secs(150);
    loop {
        let (open,): (i64,) = sqlx::query_as(
            "SELECT COUNT(*) FROM jobs WHERE status NOT IN ('succeeded', 'failed', 'cancelled')",
        )
        .fetch_one(&db.pool)
        .await
        .unwrap();
        if open == 0 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "{open} jobs are still not finished; see {}",
            out.display()
        );
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    let _ = stop_sampling.send(true);
    let mut seen = sampler.await.unwrap();
    while let Some(r) = cancelling.join_next().await {
        r.unwrap();
    }
    while let Some(r) = watching.join_next().await {
        seen.push(r.unwrap());
    }
    let finished_after = started.elapsed();

    // The final rows.
    let rows: Vec<FinalRow> = sqlx::query_as(
        "SELECT id, status, published_token, frames, attempt, error_message FROM jobs",
    )
    .fetch_all(&db.pool)
    .await
    .unwrap();
    assert_eq!(rows.len(), JOBS);
    let mut problems = Vec::new();
    let mut by_status: BTreeMap<String, usize> = BTreeMap::new();
    for (id, status, _, _, _, message) in &rows {
        *by_status.entry(status.clone()).or_default() += 1;
        let expected = status == "succeeded" || (status == "cancelled" && cancelled.contains(id));
        if !expected {
            problems.push(format!("job {id} ended {status}: {message:?}"));
        }
    }

    // Stop the workers before reading the traces (nothing is in flight).
    let stop = |procs: Vec<Proc>| async move {
        let stopping: Vec<_> = procs
            .into_iter()
            .map(|p| tokio::task::spawn_blocking(move || terminate(p, Duration::from_secs(15))))
            .collect();
        for s in stopping {
            s.await.unwrap();
        }
    };
    stop(workers).await;

    // 2. Runs never overlapped.
    let events = read_trace(&fleet.trace).unwrap();
    let (run_problems, runs) = check_runs(&events, &killed);
    problems.extend(run_problems);
    let killed_runs = runs
        .values()
        .filter(|r| r.outcome.as_deref() == Some("killed"))
        .count();
    let stopped_runs = runs
        .values()
        .filter(|r| r.outcome.as_deref() == Some("stopped"))
        .count();
    if killed_runs == 0 {
        problems.push("no kill interrupted a running attempt: the crash path went untested".into());
    }

    // 3. Everything served comes from the published attempt.
    let published: HashMap<&str, &str> = rows
        .iter()
        .filter_map(|(id, _, token, ..)| token.as_deref().map(|t| (id.as_str(), t)))
        .collect();
    let mut checked = 0;
    for (n, (id, status, token, frames, _, _)) in rows.iter().enumerate() {
        let base = &api_urls[n % API_PROCESSES];
        let url = |path: &str| format!("{base}/v1/jobs/{id}{path}");
        if status != "succeeded" {
            let (s, _) = get_bytes(&client, &url("/animation.glb")).await;
            if s == 200 {
                problems.push(format!("job {id} is {status} but serves an animation"));
            }
            continue;
        }
        let token = token.as_deref().unwrap_or_default();
        match runs.get(token) {
            Some(run) if run.job == *id && run.outcome.as_deref() == Some("ok") => {}
            other => problems.push(format!(
                "job {id} publishes attempt {token}, whose run is {other:?}"
            )),
        }
        let (s, metrics) = get_bytes(&client, &url("/metrics.json")).await;
        let metrics: Value = serde_json::from_slice(&metrics).unwrap_or(Value::Null);
        if s != 200 || metrics["attempt"] != token {
            problems.push(format!(
                "job {id}: metrics.json {s} from {}",
                metrics["attempt"]
            ));
        }
        let (s, glb) = get_bytes(&client, &url("/animation.glb")).await;
        if s != 200 || stamped_token(&glb) != Some(token) {
            problems.push(format!(
                "job {id}: animation.glb {s} from {:?}",
                stamped_token(&glb)
            ));
        }
        for frame in [0, frames - 1] {
            let (s, glb) = get_bytes(&client, &url(&format!("/frames/{frame}.glb"))).await;
            if s != 200 || stamped_token(&glb) != Some(token) {
                problems.push(format!(
                    "job {id}: frame {frame} {s} from {:?}",
                    stamped_token(&glb)
                ));
            }
        }
        let (s, stream) = get_bytes(&client, &url("/stream")).await;
        match decode_all(&stream, &DecoderOptions::default()) {
            Ok((header, decoded))
                if s == 200
                    && stamped_header_token(&header) == Some(token)
                    && decoded.len() as i64 == *frames => {}
            Ok((header, decoded)) => problems.push(format!(
                "job {id}: stream {s} from {:?} with {} frames",
                stamped_header_token(&header),
                decoded.len()
            )),
            Err(e) => problems.push(format!("job {id}: stream {s} does not decode: {e}")),
        }
        checked += 1;
    }

    // What clients saw live belongs to an attempt of that job, and what
    // completed belongs to the published one.
    let final_status: HashMap<&str, &str> = rows
        .iter()
        .map(|(id, status, ..)| (id.as_str(), status.as_str()))
        .collect();
    let of_job = |job: &str, token: &Option<String>| {
        token
            .as_deref()
            .is_some_and(|t| runs.get(t).is_some_and(|r| r.job == job))
    };
    let (mut complete_streams, mut frames_sampled) = (0, 0);
    for s in &seen {
        match s {
            Seen::Events { job, last } => {
                let want = match final_status[job.as_str()] {
                    "succeeded" => "done",
                    other => other,
                };
                if last.as_deref() != Some(want) {
                    problems.push(format!("SSE of job {job} ended with {last:?}, not {want}"));
                }
            }
            Seen::Stream {
                job,
                token,
                frames,
                complete,
                error,
            } => {
                if let Some(e) = error {
                    problems.push(format!("live stream of job {job} is corrupt: {e}"));
                } else if *complete {
                    complete_streams += 1;
                    if token.as_deref() != published.get(job.as_str()).copied()
                        || final_status[job.as_str()] != "succeeded"
                    {
                        problems.push(format!(
                            "live stream of job {job} completed with attempt {token:?} ({frames} frames)"
                        ));
                    }
                } else if token.is_some() && !of_job(job, token) {
                    problems.push(format!("live stream of job {job} came from {token:?}"));
                }
            }
            Seen::Frame { job, token } => {
                frames_sampled += 1;
                if !of_job(job, token) {
                    problems.push(format!("a live frame of job {job} came from {token:?}"));
                }
            }
        }
    }

    // Superseded attempts' outputs are deleted (reported, not asserted: an
    // attempt that lost its lease while alive may write after the cleanup).
    let blobs = treemorph::store::Blobs::open(&fleet.blob_url).unwrap();
    let mut leftovers = 0;
    for (id, status, token, ..) in &rows {
        if status == "succeeded" {
            let kids = blobs.children(&format!("jobs/{id}")).await.unwrap();
            if !kids.iter().any(|k| Some(k) == token.as_ref()) {
                problems.push(format!(
                    "job {id}: the published attempt's outputs are gone"
                ));
            }
            leftovers += kids.len().saturating_sub(1);
        }
    }

    let deleted = delete_some(&client, &api_urls, &blobs, &rows, &mut problems).await;

    stop(apis).await;
    let attempts: i64 = rows.iter().map(|r| r.4).sum();
    eprintln!(
        "fleet: {JOBS} jobs {by_status:?} in {:.1}s; {} runs ({attempts} attempts), {killed_runs} \
         cut short by {KILLS} kills, {stopped_runs} stopped (cancelled or lease lost); outputs of \
         {checked} jobs checked; {complete_streams} complete live streams, {frames_sampled} live \
         frames; {leftovers} superseded output prefixes left; {deleted} jobs deleted",
        finished_after.as_secs_f64(),
        runs.len(),
    );
    assert!(
        problems.is_empty(),
        "{} problems (logs and traces in {}):\n{}",
        problems.len(),
        out.display(),
        problems.join("\n")
    );
    if std::env::var_os("TREEMORPH_SCALEOUT_OUT").is_none() {
        drop(scratch);
    }
}

/// The fleet's checker catches what it is there to catch.
#[test]
fn the_run_checker_finds_overlaps_repeats_and_lost_runs() {
    let ev = |ev: &str, token: &str, attempt: u32, pid: u32, at_ms: i64, outcome: Option<&str>| {
        TraceEvent {
            ev: ev.into(),
            job: "j".into(),
            attempt,
            token: token.into(),
            pid,
            at_ms,
            outcome: outcome.map(str::to_owned),
        }
    };
    let killed = HashMap::from([(1, 100)]);
    // Killed at 100, re-run from 150: fine.
    let good = [
        ev("start", "a", 1, 1, 0, None),
        ev("start", "b", 2, 2, 150, None),
        ev("end", "b", 2, 2, 300, Some("ok")),
    ];
    let (problems, runs) = check_runs(&good, &killed);
    assert!(problems.is_empty(), "{problems:?}");
    assert_eq!(runs["a"].outcome.as_deref(), Some("killed"));
    assert_eq!(runs["a"].end, Some(100));

    // A run that overlaps a live one, the same attempt twice, a run that
    // never ended in a process that was not killed.
    let bad = [
        ev("start", "a", 1, 2, 0, None),
        ev("start", "b", 2, 3, 50, None),
        ev("end", "a", 1, 2, 100, Some("ok")),
        ev("end", "b", 2, 3, 120, Some("ok")),
        ev("start", "c", 2, 3, 200, None),
        ev("end", "c", 2, 3, 220, Some("ok")),
        ev("start", "d", 3, 4, 300, None),
    ];
    let (problems, _) = check_runs(&bad, &killed);
    let text = problems.join("\n");
    assert!(text.contains("overlaps"), "{text}");
    assert!(text.contains("attempt 2 ran more than once"), "{text}");
    assert!(text.contains("never ended"), "{text}");
    // An attempt fenced out by a lost lease may overlap its successor.
    let fenced = [
        ev("start", "a", 1, 2, 0, None),
        ev("start", "b", 2, 3, 50, None),
        ev("end", "a", 1, 2, 100, Some("stopped")),
        ev("end", "b", 2, 3, 120, Some("ok")),
    ];
    assert!(check_runs(&fenced, &killed).0.is_empty());
}
