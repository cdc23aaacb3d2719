//! Hostile input over HTTP, against the real binary: every malformed
//! upload, job request and URL gets a 4xx with a stable error code within
//! a second, and the server's peak memory stays bounded.
//!
//! Inputs:
//! - `crates/import/tests/hostile/` — the importer's corpus of broken GLB
//!   and glTF files (`CODE--what.ext`), uploaded as they are;
//! - `tests/hostile/trees/` — broken tree documents and glTF extras
//!   (`CODE--what.ext`), uploaded with the media type of their extension;
//! - `tests/hostile/jobs/` — broken `POST /v1/jobs` bodies (`CODE--what.json`;
//!   the ids `aaa…a` and `bbb…b` are replaced by two real trees);
//! - `tests/hostile/generate/` — broken `POST /v1/trees/generate` bodies;
//! - `tests/hostile/encoded/` — a gzip and a zstd bomb: the server accepts
//!   no `Content-Encoding`, so they are refused (415) without being read;
//! - URL attacks (path traversal, overlong and odd ids, long query strings
//!   and headers) on every route of the OpenAPI document.
//!
//! The corpus is written by `cargo test -p treemorph --test it --
//! --ignored write_hostile_corpus` from the cases below (the encoded bombs
//! with the `gzip` and `zstd` commands); `the_hostile_corpus_is_current`
//! checks that the committed files are the ones the cases describe.
//!
//! Timing: a response that takes a second or more is retried once before
//! the test fails, so a scheduler hiccup on a loaded CI machine is not
//! reported, but a slow code path (one that does work proportional to a
//! declared size) is.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use treemorph_api::ErrorCode;

/// Placeholder tree ids in `tests/hostile/jobs/`.
const TREE_A: &str = "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa";
const TREE_B: &str = "bbbbbbbbbbbbbbbbbbbbbbbbbbbbbbbb";
/// Most a hostile request may take.
const WITHIN: Duration = Duration::from_secs(1);
/// Upload limit of the server under test (small, so an endless body is
/// cut off quickly).
const MAX_UPLOAD: u64 = 4 << 20;
/// How much the server's peak resident memory may grow over the whole
/// hostile run, after a warm-up with valid requests. Every hostile body is
/// at most a few MiB; allocating by a declared size (a 4 GiB buffer, 2³¹
/// vertices, a 4096² texture per material) would pass this at once.
const MAX_PEAK_GROWTH_KB: u64 = 192 << 10;

fn hostile_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/hostile")
}

struct Server {
    child: Child,
    base: String,
    client: reqwest::Client,
    _dir: tempfile::TempDir,
}

impl Server {
    fn start() -> Server {
        let dir = tempfile::tempdir().unwrap();
        let log = std::fs::File::create(dir.path().join("server.log")).unwrap();
        let mut child = Command::new(env!("CARGO_BIN_EXE_treemorph"))
            .args(["serve", "--listen", "127.0.0.1:0", "--workers", "1"])
            .args(["--max-upload-bytes", &MAX_UPLOAD.to_string()])
            .arg("--data-dir")
            .arg(dir.path())
            .env("TREEMORPH_TEST_RUNNER", "slow:1")
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .stderr(Stdio::from(log))
            .spawn()
            .unwrap();
        let base = crate::common::base_url(&mut child)
            .unwrap_or_else(|line| panic!("unexpected first line {line:?}"));
        Server {
            child,
            base,
            client: treemorph::tls::client_builder()
                .timeout(Duration::from_secs(30))
                .build()
                .unwrap(),
            _dir: dir,
        }
    }

    /// A field of `/proc/PID/status` in kB (`VmHWM`: peak resident set).
    fn status_kb(&self, field: &str) -> u64 {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).unwrap();
        status
            .lines()
            .find_map(|l| l.strip_prefix(field)?.strip_prefix(':'))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
            .unwrap_or_else(|| panic!("no {field} in /proc status"))
    }

    async fn generate(&self, seed: u64) -> String {
        let r = self
            .client
            .post(format!("{}/v1/trees/generate", self.base))
            .json(&json!({"preset": "maple", "seed": seed, "size": 80}))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 201);
        r.json::<Value>().await.unwrap()["id"]
            .as_str()
            .unwrap()
            .to_owned()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A response: status, error code (when the body is our error body) and
/// how long it took to arrive in full.
#[derive(Debug)]
struct Outcome {
    status: u16,
    code: Option<String>,
    elapsed: Duration,
}

async fn send_once(request: reqwest::RequestBuilder) -> Outcome {
    let started = Instant::now();
    let r = request.send().await.unwrap();
    let status = r.status().as_u16();
    let body = r.bytes().await.unwrap_or_default();
    let elapsed = started.elapsed();
    let code = serde_json::from_slice::<Value>(&body)
        .ok()
        .and_then(|v| v["error"]["code"].as_str().map(str::to_owned));
    Outcome {
        status,
        code,
        elapsed,
    }
}

/// Sends a request, once more if the first answer took a second or more
/// (see the module docs), and returns the faster outcome.
async fn send(make: impl Fn() -> reqwest::RequestBuilder) -> Outcome {
    let first = send_once(make()).await;
    if first.elapsed < WITHIN {
        return first;
    }
    let second = send_once(make()).await;
    if second.elapsed < first.elapsed {
        second
    } else {
        first
    }
}

/// The HTTP status of a stable error code.
fn status_of(code: &str) -> u16 {
    ErrorCode::parse(code)
        .unwrap_or_else(|| panic!("{code:?} is not an error code"))
        .status()
}

fn media_type(path: &Path) -> &'static str {
    match path.extension().and_then(|e| e.to_str()) {
        Some("glb" | "bin") => "model/gltf-binary",
        Some("gltf") => "model/gltf+json",
        Some("json") => treemorph_tree::json::MEDIA_TYPE,
        other => panic!("{}: unknown extension {other:?}", path.display()),
    }
}

/// `CODE--what.ext` files of a directory, sorted.
fn corpus(dir: &Path) -> Vec<(PathBuf, String)> {
    let mut files: Vec<(PathBuf, String)> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter_map(|p| {
            let name = p.file_name()?.to_str()?.to_owned();
            let code = name.split_once("--")?.0.to_owned();
            Some((p, code))
        })
        .collect();
    files.sort();
    files
}

/// Bytes of a tree document with `f` applied to a small valid one.
fn tree_doc(f: impl FnOnce(&mut Value)) -> Vec<u8> {
    let mut doc = json!({
        "format": "treemorph.tree/1",
        "name": "hostile",
        "nodes": [
            {"position": [0.0, 0.0, 0.0], "radius": 0.1, "parent": null},
            {"position": [0.0, 1.0, 0.0], "radius": 0.08, "parent": 0},
            {"position": [0.0, 2.0, 0.0], "radius": 0.05, "parent": 1},
            {"position": [0.5, 1.6, 0.0], "radius": 0.03, "parent": 1}
        ],
        "leaves": [
            {"branch": 2, "t": 0.9, "offset": [0.0, 0.0, 0.03], "width": 0.2, "height": 0.3,
             "orientation": [0.0, 0.0, 0.0, 1.0], "material": 0}
        ],
        "materials": {"bark": {"color": [0.3, 0.2, 0.1, 1.0]},
                      "leaves": [{"name": "ovate", "color": [1.0, 1.0, 1.0, 1.0]}]}
    });
    f(&mut doc);
    serde_json::to_vec(&doc).unwrap()
}

/// Replaces the first occurrence of `from` in a JSON text by `to` (for
/// tokens `serde_json::Value` cannot hold: NaN, giant numbers).
fn splice(bytes: Vec<u8>, from: &str, to: &str) -> Vec<u8> {
    let text = String::from_utf8(bytes).unwrap();
    assert!(text.contains(from), "{from} not in {text}");
    text.replacen(from, to, 1).into_bytes()
}

/// A PNG's bytes: signature, IHDR of `side`², and an IDAT that inflates to
/// `rows` all-zero rows (a decompression bomb when `rows` is `side`).
fn png_bomb(side: u32, rows: u32) -> Vec<u8> {
    let image =
        treemorph_tree::RgbaImage::new(side, rows, vec![0; (side * rows * 4) as usize]).unwrap();
    let png = treemorph_tree::Texture::from_rgba(&image).png().to_vec();
    // Patch the height in IHDR (offset 20) and its CRC: a header that
    // declares more rows than the data holds is a second kind of bomb.
    let mut png = png;
    png[20..24].copy_from_slice(&side.to_be_bytes());
    let crc = crc32(&png[12..29]);
    png[29..33].copy_from_slice(&crc.to_be_bytes());
    png
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

fn data_uri(png: &[u8]) -> String {
    use base64::Engine as _;
    format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(png)
    )
}

/// Uploads (`tests/hostile/trees/`).
fn tree_cases() -> Vec<(&'static str, Vec<u8>)> {
    let deep = |open: &str, close: &str, n: usize| {
        let mut s = String::from("{\"format\": \"treemorph.tree/1\", \"nodes\": ");
        s.push_str(&open.repeat(n));
        s.push_str(&close.repeat(n));
        s.push('}');
        s.into_bytes()
    };
    let bomb = data_uri(&png_bomb(4096, 4096));
    vec![
        ("invalid_tree--deep-array-nesting.json", deep("[", "]", 100_000)),
        (
            "invalid_tree--deep-object-nesting.json",
            deep("{\"a\":", "}", 50_000),
        ),
        ("invalid_tree--deep-nesting-unknown-field.json", {
            let mut s = String::from("{\"format\": \"treemorph.tree/1\", \"junk\": ");
            s.push_str(&"[".repeat(100_000));
            s.push_str(&"]".repeat(100_000));
            s.push('}');
            s.into_bytes()
        }),
        (
            "invalid_tree--giant-number.json",
            splice(tree_doc(|_| {}), "\"radius\":0.1", "\"radius\":1e400"),
        ),
        (
            "invalid_tree--giant-integer.json",
            splice(tree_doc(|_| {}), "\"parent\":0", "\"parent\":184467440737095516160000"),
        ),
        (
            "invalid_tree--f32-overflow.json",
            tree_doc(|d| d["nodes"][1]["position"][1] = json!(1e39)),
        ),
        (
            "invalid_tree--nan-token.json",
            splice(tree_doc(|_| {}), "0.08", "NaN"),
        ),
        (
            "invalid_tree--infinity-token.json",
            splice(tree_doc(|_| {}), "0.08", "Infinity"),
        ),
        (
            "invalid_tree--negative-infinity-token.json",
            splice(tree_doc(|_| {}), "0.08", "-Infinity"),
        ),
        (
            "invalid_tree--parent-cycle.json",
            tree_doc(|d| {
                d["nodes"][1]["parent"] = json!(2);
                d["nodes"][2]["parent"] = json!(1);
            }),
        ),
        (
            "invalid_tree--parent-self.json",
            tree_doc(|d| d["nodes"][1]["parent"] = json!(1)),
        ),
        (
            "invalid_tree--parent-out-of-range.json",
            tree_doc(|d| d["nodes"][1]["parent"] = json!(4_000_000_000u64)),
        ),
        (
            "invalid_tree--two-roots.json",
            tree_doc(|d| d["nodes"][3]["parent"] = Value::Null),
        ),
        (
            "invalid_tree--leaf-on-missing-branch.json",
            tree_doc(|d| d["leaves"][0]["branch"] = json!(99)),
        ),
        (
            "invalid_tree--leaf-missing-material.json",
            tree_doc(|d| d["leaves"][0]["material"] = json!(7)),
        ),
        (
            "invalid_tree--negative-radius.json",
            tree_doc(|d| d["nodes"][2]["radius"] = json!(-1.0)),
        ),
        (
            "invalid_tree--zero-quaternion.json",
            tree_doc(|d| d["leaves"][0]["orientation"] = json!([0, 0, 0, 0])),
        ),
        (
            "invalid_tree--duplicate-field.json",
            splice(tree_doc(|_| {}), "\"name\":\"hostile\"", "\"name\":\"a\",\"name\":\"b\""),
        ),
        (
            "invalid_tree--long-name.json",
            tree_doc(|d| d["name"] = json!("n".repeat(1_000_000))),
        ),
        (
            "invalid_tree--wrong-format.json",
            tree_doc(|d| d["format"] = json!("treemorph.tree/99")),
        ),
        ("invalid_tree--null.json", b"null".to_vec()),
        ("invalid_tree--string.json", b"\"treemorph\"".to_vec()),
        ("invalid_tree--utf16.json", {
            let text = String::from_utf8(tree_doc(|_| {})).unwrap();
            let mut bytes = vec![0xFF, 0xFE];
            bytes.extend(text.encode_utf16().flat_map(u16::to_le_bytes));
            bytes
        }),
        ("invalid_tree--invalid-utf8.json", {
            let mut b = tree_doc(|_| {});
            let at = b.windows(7).position(|w| w == b"hostile").unwrap();
            b[at] = 0xC0;
            b[at + 1] = 0x80;
            b
        }),
        (
            "invalid_tree--bad-data-uri.json",
            tree_doc(|d| {
                d["materials"]["leaves"][0]["texture"] = json!("data:image/png;base64,!!!!");
            }),
        ),
        (
            "invalid_tree--texture-not-png.json",
            tree_doc(|d| {
                d["materials"]["leaves"][0]["texture"] =
                    json!("data:image/png;base64,R0lGODlhAQABAAAAACw=");
            }),
        ),
        (
            "invalid_tree--texture-side-65536.json",
            tree_doc(|d| {
                d["materials"]["leaves"][0]["texture"] = json!(data_uri(&png_bomb(65_536, 1)));
            }),
        ),
        (
            "invalid_tree--external-texture.json",
            tree_doc(|d| d["materials"]["leaves"][0]["texture"] = json!("file:///etc/passwd")),
        ),
        // Five leaf materials, each a 4096² all-zero PNG (each within the
        // side limit): 2 MiB of upload that would decode to 320 MiB of
        // pixels, over the total pixel limit of a tree.
        (
            "invalid_tree--texture-pixel-total.json",
            tree_doc(|d| {
                let material = json!({"name": "bomb", "color": [1.0, 1.0, 1.0, 1.0], "texture": bomb});
                d["materials"]["leaves"] = Value::Array(vec![material; 5]);
            }),
        ),
        // glTF extras the importer corpus does not have.
        (
            "invalid_gltf--deep-nesting.gltf",
            {
                let mut s = String::from("{\"asset\": {\"version\": \"2.0\"}, \"nodes\": ");
                s.push_str(&"[".repeat(100_000));
                s.push_str(&"]".repeat(100_000));
                s.push('}');
                s.into_bytes()
            },
        ),
        (
            "invalid_gltf--nan-token.gltf",
            b"{\"asset\": {\"version\": \"2.0\"}, \"nodes\": [{\"translation\": [NaN, 0, 0]}]}".to_vec(),
        ),
        (
            "invalid_gltf--giant-number.gltf",
            b"{\"asset\": {\"version\": \"2.0\"}, \"accessors\": [{\"count\": 1e400, \"componentType\": 5126, \"type\": \"VEC3\"}]}".to_vec(),
        ),
    ]
}

/// `POST /v1/jobs` bodies (`tests/hostile/jobs/`).
fn job_cases() -> Vec<(&'static str, Vec<u8>)> {
    let morph = |f: &dyn Fn(&mut Value)| {
        let mut v = json!({"kind": "morph", "source": TREE_A, "target": TREE_B, "frames": 10});
        f(&mut v);
        serde_json::to_vec(&v).unwrap()
    };
    let sketch = |f: &dyn Fn(&mut Value)| {
        let mut v = json!({"kind": "sketch", "tree": TREE_A, "frames": 10,
            "view": {"eye": [0, 8, 40], "target": [0, 8, 0], "up": [0, 1, 0], "fov_deg": 35},
            "sketch": {"points": [[-0.5, -0.2], [0.5, -0.2], [0.6, 0.5], [0, 0.9], [-0.6, 0.5]], "closed": true}});
        f(&mut v);
        serde_json::to_vec(&v).unwrap()
    };
    let deep = {
        let mut s = String::from("{\"kind\": \"morph\", \"options\": ");
        s.push_str(&"[".repeat(100_000));
        s.push_str(&"]".repeat(100_000));
        s.push('}');
        s.into_bytes()
    };
    vec![
        ("invalid_json--deep-nesting.json", deep),
        (
            "invalid_json--truncated.json",
            b"{\"kind\": \"morph\", \"source\": ".to_vec(),
        ),
        (
            "invalid_json--nan-frames.json",
            splice(morph(&|_| {}), "10", "NaN"),
        ),
        (
            "invalid_json--infinity-frames.json",
            splice(morph(&|_| {}), "10", "Infinity"),
        ),
        (
            "invalid_json--giant-number.json",
            splice(morph(&|_| {}), "10", "1e400"),
        ),
        ("invalid_json--invalid-utf8.json", {
            let mut b = morph(&|_| {});
            let at = b.windows(5).position(|w| w == b"morph").unwrap();
            b[at] = 0xFF;
            b
        }),
        (
            "invalid_request--frames-2-64.json",
            morph(&|v| v["frames"] = json!(u64::MAX)),
        ),
        (
            "invalid_request--frames-fraction.json",
            morph(&|v| v["frames"] = json!(2.5)),
        ),
        (
            "invalid_request--frames-1e39.json",
            splice(morph(&|_| {}), "10", "1e39"),
        ),
        (
            "invalid_request--frames-negative.json",
            morph(&|v| v["frames"] = json!(-3)),
        ),
        (
            "invalid_request--frames-too-many.json",
            morph(&|v| v["frames"] = json!(1_000_000)),
        ),
        (
            "invalid_request--unknown-kind.json",
            morph(&|v| v["kind"] = json!("explode")),
        ),
        (
            "invalid_request--kind-missing.json",
            morph(&|v| {
                v.as_object_mut().unwrap().remove("kind");
            }),
        ),
        (
            "invalid_request--unknown-field.json",
            morph(&|v| v["frame"] = json!(3)),
        ),
        ("invalid_request--array-body.json", b"[1, 2, 3]".to_vec()),
        (
            "invalid_request--ids-are-numbers.json",
            morph(&|v| v["source"] = json!(12)),
        ),
        (
            "invalid_request--keyframes-huge.json",
            morph(&|v| v["options"] = json!({"keyframes": 4_294_967_296u64})),
        ),
        (
            "invalid_job--keyframes-over-frames.json",
            morph(&|v| v["options"] = json!({"keyframes": 11})),
        ),
        (
            "tree_not_found--traversal-id.json",
            morph(&|v| v["source"] = json!("../../../../etc/passwd")),
        ),
        (
            "tree_not_found--overlong-id.json",
            morph(&|v| v["source"] = json!("a".repeat(100_000))),
        ),
        (
            "tree_not_found--nul-in-id.json",
            morph(&|v| v["source"] = json!(format!("{}\u{0}", &TREE_A[..31]))),
        ),
        (
            "tree_not_found--sql-id.json",
            morph(&|v| v["target"] = json!("' OR '1'='1")),
        ),
        (
            "callback_url_refused--file-url.json",
            morph(&|v| v["callback_url"] = json!("file:///etc/passwd")),
        ),
        (
            "callback_url_refused--javascript-url.json",
            morph(&|v| v["callback_url"] = json!("javascript:alert(1)")),
        ),
        (
            "callback_url_refused--metadata-ip.json",
            morph(&|v| v["callback_url"] = json!("http://169.254.169.254/latest/meta-data/")),
        ),
        (
            "callback_url_refused--overlong-url.json",
            morph(&|v| {
                v["callback_url"] = json!(format!("https://{}.example/", "a".repeat(100_000)))
            }),
        ),
        (
            "invalid_sketch--eye-f32-overflow.json",
            sketch(&|v| v["view"]["eye"] = json!([0.0, 1e39, 40.0])),
        ),
        (
            "invalid_sketch--fov-zero.json",
            sketch(&|v| v["view"]["fov_deg"] = json!(0)),
        ),
        (
            "invalid_sketch--fov-180.json",
            sketch(&|v| v["view"]["fov_deg"] = json!(180)),
        ),
        (
            "invalid_sketch--eye-on-target.json",
            sketch(&|v| v["view"]["eye"] = json!([0, 8, 0])),
        ),
        (
            "invalid_sketch--up-along-view.json",
            sketch(&|v| v["view"]["up"] = json!([0, 0, 1])),
        ),
        (
            "invalid_sketch--no-camera-kind.json",
            sketch(&|v| {
                v["view"].as_object_mut().unwrap().remove("fov_deg");
            }),
        ),
        (
            "invalid_sketch--both-camera-kinds.json",
            sketch(&|v| v["view"]["ortho_height"] = json!(10)),
        ),
        (
            "invalid_sketch--two-points.json",
            sketch(&|v| v["sketch"]["points"] = json!([[0, 0], [0.5, 0.5]])),
        ),
        (
            "invalid_sketch--collinear.json",
            sketch(&|v| {
                v["sketch"]["points"] = json!([[0, 0], [0.1, 0.1], [0.2, 0.2], [0.3, 0.3]])
            }),
        ),
        (
            "invalid_sketch--self-intersecting.json",
            sketch(&|v| {
                v["sketch"]["points"] = json!([[-0.5, -0.5], [0.5, 0.5], [0.5, -0.5], [-0.5, 0.5]])
            }),
        ),
        (
            "invalid_sketch--far-outside.json",
            sketch(&|v| v["sketch"]["points"] = json!([[-50, -0.2], [0.5, -0.2], [0.6, 0.5]])),
        ),
        (
            "invalid_sketch--too-many-points.json",
            sketch(&|v| {
                let points: Vec<Value> = (0..20_000)
                    .map(|i| {
                        let a = i as f64 / 20_000.0 * std::f64::consts::TAU;
                        json!([0.5 * a.cos(), 0.5 * a.sin()])
                    })
                    .collect();
                v["sketch"]["points"] = Value::Array(points);
            }),
        ),
        (
            "invalid_request--point-not-pair.json",
            sketch(&|v| v["sketch"]["points"] = json!([[0, 0, 0], [1, 0, 0], [0, 1, 0]])),
        ),
    ]
}

/// `POST /v1/trees/generate` bodies (`tests/hostile/generate/`).
fn generate_cases() -> Vec<(&'static str, Vec<u8>)> {
    vec![
        (
            "invalid_request--size-2-64.json",
            json!({"preset": "maple", "seed": 1, "size": u64::MAX})
                .to_string()
                .into_bytes(),
        ),
        (
            "invalid_request--size-huge.json",
            json!({"preset": "maple", "seed": 1, "size": 100_000_000})
                .to_string()
                .into_bytes(),
        ),
        (
            "invalid_request--seed-negative.json",
            json!({"preset": "maple", "seed": -1})
                .to_string()
                .into_bytes(),
        ),
        (
            "invalid_request--seed-2-64.json",
            b"{\"preset\": \"maple\", \"seed\": 18446744073709551616}".to_vec(),
        ),
        (
            "invalid_request--unknown-preset.json",
            json!({"preset": "../../etc/passwd", "seed": 1})
                .to_string()
                .into_bytes(),
        ),
        (
            "invalid_request--long-preset.json",
            json!({"preset": "m".repeat(1_000_000), "seed": 1})
                .to_string()
                .into_bytes(),
        ),
        (
            "invalid_json--nan-seed.json",
            b"{\"preset\": \"maple\", \"seed\": NaN}".to_vec(),
        ),
        // `preset` is a string: the parser refuses the first `[` as the
        // wrong type before nesting deeper.
        ("invalid_request--deep-nesting.json", {
            let mut s = String::from("{\"preset\": ");
            s.push_str(&"[".repeat(100_000));
            s.push_str(&"]".repeat(100_000));
            s.push('}');
            s.into_bytes()
        }),
    ]
}

/// Named cases: (file name, bytes).
type Cases = Vec<(&'static str, Vec<u8>)>;

fn all_cases() -> Vec<(&'static str, Cases)> {
    vec![
        ("trees", tree_cases()),
        ("jobs", job_cases()),
        ("generate", generate_cases()),
    ]
}

#[test]
#[ignore = "writes the corpus; run after changing the cases"]
fn write_hostile_corpus() {
    for (sub, cases) in all_cases() {
        let dir = hostile_dir().join(sub);
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        for (name, bytes) in cases {
            std::fs::write(dir.join(name), bytes).unwrap();
        }
    }
    // Decompression bombs, made by the standard tools.
    let dir = hostile_dir().join("encoded");
    std::fs::create_dir_all(&dir).unwrap();
    for (name, command) in [
        (
            "gzip--zeros-100mib.gz",
            "head -c 104857600 /dev/zero | gzip -9",
        ),
        (
            "zstd--zeros-1gib.zst",
            "head -c 1073741824 /dev/zero | zstd -19 -q -c",
        ),
    ] {
        let out = Command::new("sh").args(["-c", command]).output().unwrap();
        assert!(out.status.success(), "{command}");
        std::fs::write(dir.join(name), out.stdout).unwrap();
    }
}

#[test]
fn the_hostile_corpus_is_current() {
    for (sub, cases) in all_cases() {
        let dir = hostile_dir().join(sub);
        let on_disk = corpus(&dir);
        assert_eq!(
            on_disk.len(),
            cases.len(),
            "tests/hostile/{sub} is stale: run write_hostile_corpus"
        );
        for (name, bytes) in cases {
            let committed = std::fs::read(dir.join(name)).unwrap_or_default();
            assert!(
                committed == bytes,
                "tests/hostile/{sub}/{name} differs from its case: run write_hostile_corpus"
            );
            let code = name.split("--").next().unwrap();
            assert!(ErrorCode::parse(code).is_some(), "{name}: unknown code");
        }
    }
    assert_eq!(corpus(&hostile_dir().join("encoded")).len(), 2);
}

fn check(what: &str, outcome: &Outcome, expected_code: &str, failures: &mut Vec<String>) {
    let expected_status = status_of(expected_code);
    if outcome.status != expected_status || outcome.code.as_deref() != Some(expected_code) {
        failures.push(format!(
            "{what}: expected {expected_status} {expected_code}, got {} {:?}",
            outcome.status, outcome.code
        ));
    }
    if outcome.elapsed >= WITHIN {
        failures.push(format!("{what}: took {:?}", outcome.elapsed));
    }
}

/// Every file of the hostile corpora, uploaded or posted to a real server:
/// its code, in time, with bounded peak memory.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hostile_bodies_get_their_4xx_quickly_with_bounded_memory() {
    let server = Server::start();
    let base = server.base.clone();
    let client = server.client.clone();
    // Warm up with valid requests, so the baseline includes the allocator's
    // and the pipeline's working set.
    let a = server.generate(1).await;
    let b = server.generate(2).await;
    let glb = client
        .get(format!("{base}/v1/trees/{a}/model.glb"))
        .send()
        .await
        .unwrap()
        .bytes()
        .await
        .unwrap();
    let r = client
        .post(format!("{base}/v1/trees"))
        .header("content-type", "model/gltf-binary")
        .body(glb)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 201);
    let baseline = server.status_kb("VmHWM");

    let mut failures = Vec::new();
    let mut tried = 0;
    let import_corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/import/tests/hostile");
    for dir in [import_corpus, hostile_dir().join("trees")] {
        for (path, code) in corpus(&dir) {
            let bytes = std::fs::read(&path).unwrap();
            let media = media_type(&path);
            let url = format!("{base}/v1/trees");
            let outcome = send(|| {
                client
                    .post(&url)
                    .header("content-type", media)
                    .body(bytes.clone())
            })
            .await;
            let name = path.file_name().unwrap().to_string_lossy();
            check(&format!("upload {name}"), &outcome, &code, &mut failures);
            tried += 1;
        }
    }
    for (sub, route) in [("jobs", "/v1/jobs"), ("generate", "/v1/trees/generate")] {
        for (path, code) in corpus(&hostile_dir().join(sub)) {
            let bytes = std::fs::read(&path).unwrap();
            // The placeholders become real trees, so validation goes past
            // the tree lookup.
            let bytes = String::from_utf8_lossy(&bytes)
                .replace(TREE_A, &a)
                .replace(TREE_B, &b);
            let bytes = if std::str::from_utf8(&std::fs::read(&path).unwrap()).is_ok() {
                bytes.into_bytes()
            } else {
                std::fs::read(&path).unwrap()
            };
            let url = format!("{base}{route}");
            let outcome = send(|| {
                client
                    .post(&url)
                    .header("content-type", "application/json")
                    .body(bytes.clone())
            })
            .await;
            let name = path.file_name().unwrap().to_string_lossy();
            check(
                &format!("POST {route} {name}"),
                &outcome,
                &code,
                &mut failures,
            );
            tried += 1;
        }
    }
    // Compressed bodies: no content coding is accepted, so a bomb is
    // refused without being inflated.
    for (path, _) in corpus(&hostile_dir().join("encoded")) {
        let bytes = std::fs::read(&path).unwrap();
        let encoding = if path.extension().unwrap() == "gz" {
            "gzip"
        } else {
            "zstd"
        };
        for (route, media) in [
            ("/v1/trees", "model/gltf-binary"),
            ("/v1/trees", treemorph_tree::json::MEDIA_TYPE),
            ("/v1/jobs", "application/json"),
            ("/v1/trees/generate", "application/json"),
        ] {
            let url = format!("{base}{route}");
            let outcome = send(|| {
                client
                    .post(&url)
                    .header("content-type", media)
                    .header("content-encoding", encoding)
                    .body(bytes.clone())
            })
            .await;
            check(
                &format!("POST {route} ({media}, {encoding} bomb)"),
                &outcome,
                "unsupported_media_type",
                &mut failures,
            );
            tried += 1;
        }
    }
    // An endless upload without Content-Length is cut off at the limit.
    let url = format!("{base}/v1/trees");
    let outcome = send(|| {
        let chunks = (0..10_000).map(|_| Ok::<_, std::io::Error>(vec![b' '; 64 << 10]));
        client
            .post(&url)
            .header("content-type", "model/gltf-binary")
            .body(reqwest::Body::wrap_stream(futures_util::stream::iter(
                chunks,
            )))
    })
    .await;
    check(
        "endless chunked upload",
        &outcome,
        "payload_too_large",
        &mut failures,
    );
    tried += 1;

    let peak = server.status_kb("VmHWM");
    println!(
        "hostile bodies: {tried} tried, {} failures; peak RSS {} MiB (baseline {} MiB)",
        failures.len(),
        peak >> 10,
        baseline >> 10
    );
    assert!(
        failures.is_empty(),
        "{} failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
    assert!(
        peak.saturating_sub(baseline) < MAX_PEAK_GROWTH_KB,
        "peak memory grew from {baseline} kB to {peak} kB"
    );
    // The server is still healthy.
    let r = client.get(format!("{base}/healthz")).send().await.unwrap();
    assert_eq!(r.status(), 200);
}

/// Path ids that must never reach the database or a blob key.
fn attack_ids() -> Vec<String> {
    vec![
        "..%2f..%2f..%2fetc%2fpasswd".into(),
        "..%252f..%252fetc%252fpasswd".into(),
        "%2e%2e".into(),
        "..".into(),
        "%00".into(),
        "0123456789abcdef0123456789abcde%00".into(),
        "%ff%fe%fd".into(),
        "%E2%80%AE%E2%80%8B".into(),
        "'%20OR%20'1'%3D'1".into(),
        "%3Cscript%3E".into(),
        "0123456789ABCDEF0123456789ABCDEF".into(),
        "0123456789abcdef0123456789abcdef0".into(),
        "a".repeat(10_000),
        "%25".repeat(2_000),
    ]
}

/// URL attacks on every documented route: a 4xx (404 for ids that are not
/// ours, 422 for bad query strings, 414/431 from the HTTP layer for
/// over-long URIs and headers), in time, never a 5xx. Operations routes
/// take no input and may answer 200.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn url_attacks_on_every_route_get_4xx_quickly() {
    let server = Server::start();
    let base = server.base.clone();
    let client = server.client.clone();
    let doc = serde_json::to_value(treemorph::server::openapi::document()).unwrap();
    let long_query = format!("?{}", "a=b&".repeat(4_000));
    // Just under the longest URI the HTTP stack can represent (65,534).
    let huge_query = format!("?q={}", "x".repeat(60_000));
    let baseline = server.status_kb("VmHWM");
    let mut failures = Vec::new();
    let mut tried = 0;
    for (path, item) in doc["paths"].as_object().unwrap() {
        for method in ["get", "post", "delete", "put", "patch"] {
            if item.get(method).is_none() {
                continue;
            }
            let m = reqwest::Method::from_bytes(method.to_uppercase().as_bytes()).unwrap();
            let operational = !path.starts_with("/v1/");
            let mut urls: Vec<String> = Vec::new();
            if path.contains('{') {
                for id in attack_ids() {
                    urls.push(path.replace("{id}", &id).replace("{frame}", "0.glb"));
                }
                let id = "0123456789abcdef0123456789abcdef";
                for frame in attack_ids() {
                    if path.contains("{frame}") {
                        urls.push(path.replace("{id}", id).replace("{frame}", &frame));
                    }
                }
                urls.push(format!(
                    "{}{long_query}",
                    path.replace("{id}", id).replace("{frame}", "0.glb")
                ));
            } else {
                urls.push(format!("{path}{long_query}"));
                urls.push(format!("{path}?limit=99999999999999999999&cursor=%00%ff"));
            }
            urls.push(format!(
                "{}{huge_query}",
                path.replace("{id}", "x").replace("{frame}", "0.glb")
            ));
            for url in urls {
                let full = format!("{base}{url}");
                let outcome = send(|| {
                    let r = client.request(m.clone(), &full);
                    if m == reqwest::Method::POST {
                        r.header("content-type", "application/json").body("{}")
                    } else {
                        r
                    }
                })
                .await;
                let shown: String = url.chars().take(80).collect();
                let ok_status =
                    (400..500).contains(&outcome.status) || (operational && outcome.status == 200);
                if !ok_status {
                    failures.push(format!(
                        "{method} {shown}: {} {:?}",
                        outcome.status, outcome.code
                    ));
                }
                // Our own errors carry a stable code; 414 and 431 come from
                // the HTTP layer before any route runs.
                if (400..500).contains(&outcome.status)
                    && ![414, 431].contains(&outcome.status)
                    && outcome.code.is_none()
                {
                    failures.push(format!(
                        "{method} {shown}: {} without an error code",
                        outcome.status
                    ));
                }
                if outcome.elapsed >= WITHIN {
                    failures.push(format!("{method} {shown}: took {:?}", outcome.elapsed));
                }
                tried += 1;
            }
        }
    }
    // A header section far over any sane size.
    let outcome = send(|| {
        client
            .get(format!("{base}/v1/trees"))
            .header("x-padding", "p".repeat(512 << 10))
    })
    .await;
    if !(400..500).contains(&outcome.status) {
        failures.push(format!("512 KiB header: {}", outcome.status));
    }
    tried += 1;
    let peak = server.status_kb("VmHWM");
    println!(
        "URL attacks: {tried} tried, {} failures; peak RSS {} MiB (baseline {} MiB)",
        failures.len(),
        peak >> 10,
        baseline >> 10
    );
    assert!(
        failures.is_empty(),
        "{} failures:\n{}",
        failures.len(),
        failures.join("\n")
    );
    assert!(peak.saturating_sub(baseline) < MAX_PEAK_GROWTH_KB);
    let r = client.get(format!("{base}/healthz")).send().await.unwrap();
    assert_eq!(r.status(), 200);
}
