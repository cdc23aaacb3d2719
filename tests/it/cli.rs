//! The local commands of the real binary (`generate`, `inspect`, `morph`):
//! what they print and write, and their exit codes.

use std::path::Path;
use std::process::{Command, Output};

use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_treemorph");

fn treemorph(args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .output()
        .expect("the binary runs")
}

fn generate(dir: &Path, preset: &str, seed: &str, size: &str) -> String {
    let path = dir.join(format!("{preset}-{seed}.json"));
    let path = path.to_str().unwrap().to_owned();
    let out = treemorph(&[
        "generate", "--preset", preset, "--seed", seed, "--size", size, "-o", &path,
    ]);
    assert!(out.status.success(), "{out:?}");
    path
}

/// The value after `label` on its line of `inspect`'s text output.
fn field<'a>(text: &'a str, label: &str) -> Option<&'a str> {
    text.lines()
        .find_map(|l| l.strip_prefix(label))
        .map(str::trim)
}

/// Regression: `inspect --analysis` without `--json` printed the tree's
/// counts but none of the analysis it had computed.
#[test]
fn inspect_prints_the_analysis_as_text_and_json() {
    let dir = tempfile::tempdir().unwrap();
    let tree = generate(dir.path(), "conifer", "2", "300");
    let out = treemorph(&["inspect", "--analysis", "--json", &tree]);
    assert!(out.status.success(), "{out:?}");
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    let analysis = &report["analysis"];
    assert!(analysis["chains"].as_u64().unwrap() > 1, "{report}");

    let out = treemorph(&["inspect", "--analysis", &tree]);
    assert!(out.status.success(), "{out:?}");
    let text = String::from_utf8(out.stdout).unwrap();
    assert_eq!(field(&text, "branches"), Some("300"), "{text}");
    assert_eq!(
        field(&text, "chains").map(str::to_owned),
        Some(analysis["chains"].to_string()),
        "{text}"
    );
    assert_eq!(
        field(&text, "groups").map(str::to_owned),
        Some(format!(
            "{} (alternate {}, opposite {}, whorled {})",
            analysis["chain_groups"],
            analysis["patterns"]["alternate"],
            analysis["patterns"]["opposite"],
            analysis["patterns"]["whorled"]
        )),
        "{text}"
    );
    assert_eq!(
        field(&text, "orders").map(str::to_owned),
        Some(format!("1..{}", analysis["orders"]["max"])),
        "{text}"
    );
    assert_eq!(
        field(&text, "bptt").map(str::to_owned),
        Some(format!("{} levels", analysis["bptt_depth"])),
        "{text}"
    );
    assert!(field(&text, "lobes").is_some(), "{text}");

    // Without --analysis, no analysis lines.
    let out = treemorph(&["inspect", &tree]);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(field(&text, "chains").is_none(), "{text}");
}

#[test]
fn inspect_refuses_a_missing_or_broken_file_with_exit_code_3() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.glb");
    let out = treemorph(&["inspect", missing.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(3), "{out:?}");
    let broken = dir.path().join("broken.json");
    std::fs::write(&broken, b"{\"format\": \"treemorph.tree/1\", \"nodes\": [").unwrap();
    let out = treemorph(&["inspect", broken.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(3), "{out:?}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("broken.json"), "{stderr}");
    // --full without --json is a usage error.
    let tree = generate(dir.path(), "shrub", "1", "80");
    let out = treemorph(&["inspect", "--analysis", "--full", &tree]);
    assert_eq!(out.status.code(), Some(2), "{out:?}");
}

#[test]
fn morph_writes_frames_animation_stream_and_metrics() {
    let dir = tempfile::tempdir().unwrap();
    let a = generate(dir.path(), "maple", "1", "120");
    let b = generate(dir.path(), "shrub", "2", "120");
    let out_dir = dir.path().join("out");
    let out = treemorph(&[
        "morph",
        &a,
        &b,
        "--frames",
        "4",
        "-o",
        out_dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{out:?}");
    let mut names: Vec<String> = std::fs::read_dir(&out_dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    for expected in ["animation.glb", "metrics.json", "frames.tmd"] {
        assert!(names.iter().any(|n| n == expected), "{names:?}");
    }
    let frames = names.iter().filter(|n| n.starts_with("frame_")).count();
    assert_eq!(frames, 4, "{names:?}");
    let metrics: Value =
        serde_json::from_slice(&std::fs::read(out_dir.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(
        metrics["floating_branches"],
        serde_json::json!([0, 0, 0, 0])
    );
    let stream = std::fs::read(out_dir.join("frames.tmd")).unwrap();
    let (_, decoded) = treemorph_api::delta::decode_all(&stream, &Default::default()).unwrap();
    assert_eq!(decoded.len(), 4);
}

/// `--at T` writes the one frame at `T`: at a frame's instant, that
/// frame's bytes; `T` outside [0, 1] is a usage error.
#[test]
fn morph_at_an_instant_writes_that_frame_only() {
    let dir = tempfile::tempdir().unwrap();
    let a = generate(dir.path(), "maple", "1", "120");
    let b = generate(dir.path(), "shrub", "2", "120");
    let all = dir.path().join("all");
    let run = |out: &Path, extra: &[&str]| {
        let mut args = vec![
            "morph",
            &a,
            &b,
            "--frames",
            "5",
            "-o",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        treemorph(&args)
    };
    assert!(run(&all, &["--format", "glb"]).status.success());
    let one = dir.path().join("one");
    let out = run(&one, &["--at", "0.75"]);
    assert!(out.status.success(), "{out:?}");
    let written = one.join("frame_at_0.7500.glb");
    assert_eq!(
        String::from_utf8_lossy(&out.stdout).trim(),
        written.to_str().unwrap()
    );
    assert_eq!(std::fs::read_dir(&one).unwrap().count(), 1);
    assert_eq!(
        std::fs::read(&written).unwrap(),
        std::fs::read(all.join("frame_0003.glb")).unwrap()
    );
    let out = run(&one, &["--at", "1.5"]);
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("t must be a number in [0, 1]"),
        "{out:?}"
    );
}
