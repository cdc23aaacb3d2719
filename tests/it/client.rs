//! `treemorph client` against the real binary's server: every subcommand,
//! the files `-o`/`download` write, and the documented exit codes of the
//! error paths. The server runs the test-only runner
//! (`TREEMORPH_TEST_RUNNER=slow:MS`), so jobs are fast and deterministic.

use std::io::{BufRead, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_treemorph");

/// Exit codes documented in `treemorph client --help`.
const OK: i32 = 0;
const FAILED: i32 = 1;
const USAGE: i32 = 2;
const INVALID_INPUT: i32 = 3;
const NOT_FOUND: i32 = 4;
const UNREACHABLE: i32 = 5;
const UNAUTHORIZED: i32 = 6;

/// A `treemorph serve` child process with its own data directory.
struct Server {
    child: Child,
    base: String,
    dir: std::sync::Arc<tempfile::TempDir>,
}

impl Server {
    fn start(runner: &str, extra: &[&str]) -> Server {
        let dir = std::sync::Arc::new(tempfile::tempdir().unwrap());
        Server::start_in(dir, "127.0.0.1:0", runner, extra)
    }

    /// A server on `listen` with its data in `dir` (shared by a server
    /// that replaces a killed one).
    fn start_in(
        dir: std::sync::Arc<tempfile::TempDir>,
        listen: &str,
        runner: &str,
        extra: &[&str],
    ) -> Server {
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(dir.path().join("server.log"))
            .unwrap();
        let mut child = Command::new(BIN)
            .args([
                "serve",
                "--listen",
                listen,
                "--workers",
                "2",
                "--poll-ms",
                "50",
            ])
            .arg("--data-dir")
            .arg(dir.path().join("data"))
            .args(extra)
            .env("TREEMORPH_TEST_RUNNER", runner)
            .env_remove("TREEMORPH_API_KEYS")
            .stdout(Stdio::piped())
            .stderr(Stdio::from(log))
            .spawn()
            .unwrap();
        let base = crate::common::base_url(&mut child)
            .unwrap_or_else(|line| panic!("unexpected first line {line:?}"));
        Server { child, base, dir }
    }

    /// Runs `treemorph client ARGS` against this server.
    fn client(&self, args: &[&str]) -> Run {
        self.client_with(args, &[])
    }

    fn client_with(&self, args: &[&str], env: &[(&str, &str)]) -> Run {
        run_client(&self.base, args, env)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A finished client process.
#[derive(Debug)]
struct Run {
    code: i32,
    stdout: String,
    stderr: String,
}

impl Run {
    /// Asserts the exit code and returns self.
    #[track_caller]
    fn expect(self, code: i32) -> Run {
        assert_eq!(self.code, code, "exit code of {self:#?}");
        self
    }

    /// The first line of stdout (an id).
    fn id(&self) -> String {
        let id = self.stdout.lines().next().unwrap_or_default().trim();
        assert!(!id.is_empty() && !id.contains(' '), "no id in {self:#?}");
        id.to_owned()
    }

    fn json(&self) -> Value {
        serde_json::from_str(&self.stdout).unwrap_or_else(|e| panic!("{e}: {self:#?}"))
    }
}

/// Runs the client with `TREEMORPH_SERVER=server`. A hang guard kills it
/// after two minutes (a bug, never a timing assertion: jobs take
/// milliseconds).
fn run_client(server: &str, args: &[&str], env: &[(&str, &str)]) -> Run {
    let mut command = Command::new(BIN);
    command
        .arg("client")
        .args(args)
        .env("TREEMORPH_SERVER", server)
        .env_remove("TREEMORPH_API_KEY")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    for (k, v) in env {
        command.env(k, v);
    }
    let mut child = command.spawn().unwrap();
    let mut stdout = child.stdout.take().unwrap();
    let mut stderr = child.stderr.take().unwrap();
    let out = std::thread::spawn(move || {
        let mut s = String::new();
        stdout.read_to_string(&mut s).unwrap();
        s
    });
    let err = std::thread::spawn(move || {
        let mut s = String::new();
        stderr.read_to_string(&mut s).unwrap();
        s
    });
    let guard = Instant::now() + Duration::from_secs(120);
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if Instant::now() > guard {
            let _ = child.kill();
            panic!("`treemorph client {}` hung", args.join(" "));
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    Run {
        code: status.code().expect("the client exited normally"),
        stdout: out.join().unwrap(),
        stderr: err.join().unwrap(),
    }
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn assert_glb(path: &Path) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(
        bytes.starts_with(b"glTF"),
        "{} is not a GLB",
        path.display()
    );
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = walk(dir)
        .into_iter()
        .map(|p| {
            p.strip_prefix(dir)
                .unwrap()
                .to_string_lossy()
                .replace('\\', "/")
        })
        .collect();
    names.sort();
    names
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            out.extend(walk(&path));
        } else {
            out.push(path);
        }
    }
    out
}

fn heart() -> &'static str {
    concat!(env!("CARGO_MANIFEST_DIR"), "/examples/sketches/heart.json")
}

#[test]
fn client_generates_uploads_morphs_sketches_and_downloads() {
    let server = Server::start("slow:1", &[]);
    let gen_args = |seed: &'static str| {
        [
            "generate", "--preset", "maple", "--seed", seed, "--size", "80",
        ]
    };
    let a = server.client(&gen_args("1")).expect(OK);
    assert!(a.stderr.contains("branches"), "{a:#?}");
    let a = a.id();
    let b = server.client(&gen_args("2")).expect(OK).id();
    assert_ne!(a, b);

    // Upload a GLB written by the local generator.
    let glb = server.path("shrub.glb");
    let local = Command::new(BIN)
        .args([
            "generate", "--preset", "shrub", "--seed", "3", "--size", "80", "-o",
        ])
        .arg(&glb)
        .output()
        .unwrap();
    assert!(local.status.success(), "{local:?}");
    let up = server.client(&["upload", s(&glb)]).expect(OK);
    assert!(up.stderr.contains("(glb)"), "{up:#?}");
    let uploaded = up.id();
    let info = server
        .client(&["--json", "upload", s(&glb), "--name", "my shrub"])
        .expect(OK)
        .json();
    assert_eq!(info["name"], "my shrub");
    assert_eq!(info["format"], "glb");

    // Morph, wait and download everything.
    let out = server.path("morph");
    let morph = server
        .client(&[
            "morph",
            &a,
            &uploaded,
            "--frames",
            "4",
            "--wait",
            "-o",
            s(&out),
        ])
        .expect(OK);
    let job = morph.id();
    assert!(morph.stderr.contains("succeeded"), "{morph:#?}");
    assert_eq!(
        files_in(&out),
        [
            "animation.glb",
            "frames/0000.glb",
            "frames/0001.glb",
            "frames/0002.glb",
            "frames/0003.glb",
            "metrics.json",
            "stream.tmd"
        ]
    );
    for n in 0..4 {
        assert_glb(&out.join(format!("frames/{n:04}.glb")));
    }
    assert_glb(&out.join("animation.glb"));
    let stream = std::fs::read(out.join("stream.tmd")).unwrap();
    let (_, frames) = treemorph_api::delta::decode_all(&stream, &Default::default()).unwrap();
    assert_eq!(frames.len(), 4);
    let metrics: Value =
        serde_json::from_slice(&std::fs::read(out.join("metrics.json")).unwrap()).unwrap();
    assert!(metrics.is_object(), "{metrics}");

    // A file in place of a tree id is uploaded first; a path that does not
    // exist is the caller's invalid input, and nothing is started.
    let from_file = server
        .client(&["--json", "morph", s(&glb), &a, "--frames", "3", "--wait"])
        .expect(OK);
    assert!(from_file.stderr.contains("uploaded"), "{from_file:#?}");
    let doc = from_file.json();
    assert_eq!(doc["status"], "succeeded", "{doc}");
    let typo = server.client(&["morph", &a, "no-such-tree.glb", "--frames", "3"]);
    assert_eq!(typo.code, INVALID_INPUT, "{typo:#?}");
    assert!(typo.stderr.contains("no-such-tree.glb"), "{typo:#?}");

    // Status, as text and as the server's JSON.
    let status = server.client(&["status", &job]).expect(OK);
    assert!(status.stdout.contains("status:   succeeded"), "{status:#?}");
    assert!(status.stdout.contains("frames:   4/4 ready"), "{status:#?}");
    let doc = server.client(&["status", &job, "--json"]).expect(OK).json();
    assert_eq!(doc["id"], job.as_str());
    assert_eq!(doc["status"], "succeeded");

    // Watching a finished job ends at once with its status.
    let watch = server.client(&["watch", &job]).expect(OK);
    assert_eq!(watch.stdout.trim(), "succeeded");

    // Download selected formats only.
    let some = server.path("some");
    let dl = server
        .client(&[
            "download",
            &job,
            "--format",
            "delta,metrics",
            "-o",
            s(&some),
        ])
        .expect(OK);
    assert_eq!(files_in(&some), ["metrics.json", "stream.tmd"]);
    assert_eq!(dl.stdout.lines().count(), 2, "{dl:#?}");
    let animated = server.path("animated");
    server
        .client(&["download", &job, "--format", "animated", "-o", s(&animated)])
        .expect(OK);
    assert_eq!(files_in(&animated), ["animation.glb"]);
    assert_eq!(
        std::fs::read(animated.join("animation.glb")).unwrap(),
        std::fs::read(out.join("animation.glb")).unwrap()
    );
    // The frame at an instant, rendered by the server (the test runner's
    // stand-in GLB names its instant).
    let at = server.path("at");
    let dl = server
        .client(&["download", &job, "--t", "1", "-o", s(&at)])
        .expect(OK);
    assert_eq!(files_in(&at), ["frame_at_1.0000.glb"]);
    assert_eq!(dl.stdout.trim(), s(&at.join("frame_at_1.0000.glb")));
    assert_eq!(
        std::fs::read(at.join("frame_at_1.0000.glb")).unwrap(),
        treemorph::jobs::testing::instant_glb(1.0)
    );
    let bad = server
        .client(&["download", &job, "--t", "2", "-o", s(&at)])
        .expect(INVALID_INPUT);
    assert!(bad.stderr.contains("invalid_request"), "{bad:#?}");

    // A job without per-frame GLBs: asking for them is "not found", while
    // `all` takes what there is.
    let delta_only = server
        .client(&["morph", &a, &b, "--frames", "3", "--format", "delta"])
        .expect(OK)
        .id();
    let none = server.path("none");
    let missing = server
        .client(&[
            "download",
            &delta_only,
            "--wait",
            "--format",
            "glb",
            "-o",
            s(&none),
        ])
        .expect(NOT_FOUND);
    assert!(missing.stderr.contains("error: not_found:"), "{missing:#?}");
    let all = server.path("all");
    server
        .client(&["download", &delta_only, "-o", s(&all)])
        .expect(OK);
    assert_eq!(files_in(&all), ["metrics.json", "stream.tmd"]);

    // Sketch with an example sketch file; the idempotency key returns the
    // same job when retried.
    let sketch_out = server.path("sketch");
    let args = [
        "sketch",
        &a,
        "--sketch",
        heart(),
        "--frames",
        "3",
        "--idempotency-key",
        "heart-1",
    ];
    let first = server.client(&args).expect(OK).id();
    let again = server.client(&args).expect(OK).id();
    assert_eq!(first, again);
    let sketch = server
        .client(&[
            "sketch",
            &a,
            "--sketch",
            heart(),
            "--frames",
            "3",
            "-o",
            s(&sketch_out),
        ])
        .expect(OK);
    let sketch_job = sketch.id();
    assert_ne!(sketch_job, first);
    assert!(sketch_out.join("frames/0002.glb").is_file());
    let doc = server
        .client(&["status", &sketch_job, "--json"])
        .expect(OK)
        .json();
    assert_eq!(doc["kind"], "sketch");
}

#[test]
fn client_errors_have_documented_exit_codes_and_messages() {
    let server = Server::start("slow:1", &[]);
    let tree = server
        .client(&["generate", "--preset", "maple", "--size", "80"])
        .expect(OK)
        .id();

    // Not found: an unknown job, an unknown tree in a job.
    let r = server.client(&["status", "nosuchjob"]).expect(NOT_FOUND);
    assert!(r.stderr.contains("error: not_found: "), "{r:#?}");
    server.client(&["watch", "nosuchjob"]).expect(NOT_FOUND);
    server.client(&["cancel", "nosuchjob"]).expect(NOT_FOUND);
    server
        .client(&["download", "nosuchjob", "-o", s(&server.path("x"))])
        .expect(NOT_FOUND);
    let r = server
        .client(&["morph", &tree, "nosuchtree", "--frames", "3"])
        .expect(NOT_FOUND);
    assert!(r.stderr.contains("error: tree_not_found: "), "{r:#?}");

    // Invalid input, found locally: missing or invalid files.
    let r = server
        .client(&["upload", s(&server.path("missing.glb"))])
        .expect(INVALID_INPUT);
    assert!(r.stderr.contains("missing.glb"), "{r:#?}");
    let junk = server.path("notes.txt");
    std::fs::write(&junk, "hello").unwrap();
    server.client(&["upload", s(&junk)]).expect(INVALID_INPUT);
    let bad_sketch = server.path("bad-sketch.json");
    std::fs::write(&bad_sketch, r#"{"view": {"eye": [0, 1, 5]}, "points": []}"#).unwrap();
    let r = server
        .client(&["sketch", &tree, "--sketch", s(&bad_sketch)])
        .expect(INVALID_INPUT);
    assert!(r.stderr.contains("bad-sketch.json"), "{r:#?}");
    server
        .client(&["sketch", &tree, "--sketch", s(&server.path("nope.json"))])
        .expect(INVALID_INPUT);

    // Invalid input, refused by the server: code and message shown.
    let fake = server.path("fake.glb");
    std::fs::write(&fake, b"glTF\x02\0\0\0not really").unwrap();
    let r = server.client(&["upload", s(&fake)]).expect(INVALID_INPUT);
    assert!(r.stderr.starts_with("error: invalid_gltf: "), "{r:#?}");
    let r = server
        .client(&["morph", &tree, &tree, "--frames", "1"])
        .expect(INVALID_INPUT);
    assert!(r.stderr.starts_with("error: invalid_request: "), "{r:#?}");
    let r = server
        .client(&["generate", "--preset", "baobab"])
        .expect(INVALID_INPUT);
    assert!(r.stderr.contains("invalid_request"), "{r:#?}");

    // Usage errors.
    server.client(&["morph", &tree]).expect(USAGE);
    server
        .client(&["--server", "ftp://example.com", "status", "x"])
        .expect(USAGE);

    // Nobody listening.
    let port = {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        listener.local_addr().unwrap().port()
    };
    let r =
        run_client(&format!("http://127.0.0.1:{port}"), &["status", "x"], &[]).expect(UNREACHABLE);
    assert!(r.stderr.contains("unreachable"), "{r:#?}");
    let r = server
        .client(&[
            "--server",
            &format!("http://127.0.0.1:{port}"),
            "generate",
            "--preset",
            "maple",
        ])
        .expect(UNREACHABLE);
    assert!(r.stdout.is_empty(), "{r:#?}");
}

#[test]
fn client_with_api_keys_cancels_and_watches_live_jobs() {
    // 100 ms per frame: a 300-frame job runs for half a minute, long
    // enough to be cancelled while it runs.
    let server = Server::start("slow:100", &["--api-keys", "key-one,key-two"]);
    let one = [("TREEMORPH_API_KEY", "key-one")];
    let gen_args = |seed: &'static str| {
        [
            "generate", "--preset", "maple", "--seed", seed, "--size", "80",
        ]
    };

    // Without a key, or with a wrong one: unauthorized.
    let r = server.client(&gen_args("1")).expect(UNAUTHORIZED);
    assert!(r.stderr.starts_with("error: unauthorized: "), "{r:#?}");
    let r = server
        .client(&["--api-key", "wrong", "status", "x"])
        .expect(UNAUTHORIZED);
    assert!(r.stderr.contains("unauthorized"), "{r:#?}");

    // The key from the environment or the flag.
    let a = server.client_with(&gen_args("1"), &one).expect(OK).id();
    let b = server
        .client(&[&gen_args("2")[..], &["--api-key", "key-one"]].concat())
        .expect(OK)
        .id();
    // Another key does not see these trees.
    server
        .client_with(
            &["morph", &a, &b, "--frames", "3"],
            &[("TREEMORPH_API_KEY", "key-two")],
        )
        .expect(NOT_FOUND);

    // A live job: not ready to download, then cancelled.
    let long = server
        .client_with(&["morph", &a, &b, "--frames", "300"], &one)
        .expect(OK)
        .id();
    let r = server
        .client_with(&["download", &long, "-o", s(&server.path("early"))], &one)
        .expect(INVALID_INPUT);
    assert!(r.stderr.contains("not_ready"), "{r:#?}");
    server
        .client_with(&["cancel", &long], &[("TREEMORPH_API_KEY", "key-two")])
        .expect(NOT_FOUND);
    let cancel = server.client_with(&["cancel", &long], &one).expect(OK);
    assert!(
        cancel.stdout.trim() == "cancelled" || cancel.stdout.contains("cancel requested"),
        "{cancel:#?}"
    );
    let watch = server.client_with(&["watch", &long], &one).expect(FAILED);
    assert_eq!(watch.stdout.trim(), "cancelled");
    assert!(watch.stderr.contains("error: cancelled"), "{watch:#?}");
    let status = server.client_with(&["status", &long], &one).expect(OK);
    assert!(status.stdout.contains("status:   cancelled"), "{status:#?}");
    // Cancelling again is a no-op; `--wait` on the ended job reports it.
    server.client_with(&["cancel", &long], &one).expect(OK);
    server
        .client_with(&["download", &long, "-o", s(&server.path("late"))], &one)
        .expect(FAILED);
    // Deleting: another key's job is not found; then the job is gone.
    server
        .client_with(&["delete", &long], &[("TREEMORPH_API_KEY", "key-two")])
        .expect(NOT_FOUND);
    let deleted = server.client_with(&["delete", &long], &one).expect(OK);
    assert_eq!(deleted.stdout.trim(), "deleted", "{deleted:#?}");
    server
        .client_with(&["status", &long], &one)
        .expect(NOT_FOUND);

    // Progress followed live: plain lines on a non-terminal stderr.
    let out = server.path("live");
    let live = server
        .client_with(&["morph", &a, &b, "--frames", "20", "-o", s(&out)], &one)
        .expect(OK);
    let job = live.id();
    assert!(
        live.stderr
            .contains(&format!("job {job}: succeeded (20 frames)")),
        "{live:#?}"
    );
    // The job runs for two seconds after the client subscribed, so the
    // client sees it running.
    assert!(
        live.stderr.contains("/20 frames ("),
        "no progress line in {live:#?}"
    );
    assert!(!live.stderr.contains('\u{1b}'), "escape codes in {live:#?}");
    assert_eq!(files_in(&out.join("frames")).len(), 20);
    let stream = std::fs::read(out.join("stream.tmd")).unwrap();
    let (_, frames) = treemorph_api::delta::decode_all(&stream, &Default::default()).unwrap();
    assert_eq!(frames.len(), 20);
}

#[test]
fn watch_reconnects_when_the_server_is_killed_and_restarted() {
    let port = {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        listener.local_addr().unwrap().port()
    };
    let listen = format!("127.0.0.1:{port}");
    let dir = std::sync::Arc::new(tempfile::tempdir().unwrap());
    let lease = ["--lease-secs", "2"];
    let mut first = Server::start_in(dir.clone(), &listen, "slow:100", &lease);
    let gen_args = |seed: &'static str| {
        [
            "generate", "--preset", "maple", "--seed", seed, "--size", "80",
        ]
    };
    let a = first.client(&gen_args("1")).expect(OK).id();
    let b = first.client(&gen_args("2")).expect(OK).id();
    let job = first
        .client(&["morph", &a, &b, "--frames", "30"])
        .expect(OK)
        .id();

    // Follow it, and kill the server once the watcher has seen frames.
    let mut watch = Command::new(BIN)
        .args(["client", "watch", &job])
        .env("TREEMORPH_SERVER", &first.base)
        .env_remove("TREEMORPH_API_KEY")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let stderr = watch.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        for line in std::io::BufReader::new(stderr).lines() {
            let _ = tx.send(line.unwrap());
        }
    });
    let mut lines = Vec::new();
    loop {
        // A hang guard, not a timing assertion.
        let line = rx
            .recv_timeout(Duration::from_secs(60))
            .expect("the watcher printed no progress");
        let running = line.contains(&format!("job {job}: frames, "));
        lines.push(line);
        if running {
            break;
        }
    }
    first.child.kill().unwrap();
    first.child.wait().unwrap();
    let second = Server::start_in(dir, &listen, "slow:10", &lease);
    assert_eq!(second.base, first.base);

    let guard = Instant::now() + Duration::from_secs(120);
    let status = loop {
        if let Some(status) = watch.try_wait().unwrap() {
            break status;
        }
        if Instant::now() > guard {
            let _ = watch.kill();
            panic!("the watcher hung: {lines:#?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    reader.join().unwrap();
    lines.extend(rx.try_iter());
    let mut stdout = String::new();
    watch
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut stdout)
        .unwrap();
    assert!(status.success(), "{status}: {lines:#?}");
    assert_eq!(stdout.trim(), "succeeded");
    assert!(
        lines.iter().any(|l| l.contains("reconnecting")),
        "{lines:#?}"
    );
    assert!(
        lines
            .iter()
            .any(|l| l == &format!("job {job}: succeeded (30 frames)")),
        "{lines:#?}"
    );
}
