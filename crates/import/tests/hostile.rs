//! Hostile input: a committed corpus of small broken files, each with its
//! expected error code in its name (`CODE--what.ext`), plus property tests
//! that mutate valid files. Bad input must give an error with a stable
//! code, never a panic.
//!
//! The corpus is written by `cargo test -p treemorph-import --test hostile
//! -- --ignored write_corpus` from the cases below; the main test checks
//! both that the committed files give their codes and that they are the
//! files the cases describe.

use std::path::PathBuf;

use proptest::prelude::*;
use serde_json::{Value, json};
use treemorph_gltf::Glb;
use treemorph_import::{ImportError, ImportOptions, import};

fn glb(doc: &Value, bin: &[u8]) -> Vec<u8> {
    let json = serde_json::to_vec(doc).unwrap();
    Glb {
        json: &json,
        bin: (!bin.is_empty()).then_some(bin),
    }
    .to_vec()
    .unwrap()
}

fn f32s(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn u16s(values: &[u16]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// A valid little tree: an open 4-sided tube (wood) and two leaf quads
/// (alpha-masked), in one GLB buffer.
fn base() -> (Value, Vec<u8>) {
    let mut positions = Vec::new();
    for ring in 0..4 {
        for j in 0..4 {
            let a = j as f32 * std::f32::consts::FRAC_PI_2;
            positions.extend_from_slice(&[0.1 * a.cos(), ring as f32, 0.1 * a.sin()]);
        }
    }
    let mut indices: Vec<u16> = Vec::new();
    for ring in 0..3u16 {
        for j in 0..4u16 {
            let a = ring * 4 + j;
            let b = ring * 4 + (j + 1) % 4;
            let (c, d) = (a + 4, b + 4);
            indices.extend_from_slice(&[a, b, d, a, d, c]);
        }
    }
    let leaf_positions = [
        0.1f32, 2.5, 0.0, 0.3, 2.5, 0.0, 0.3, 2.8, 0.0, 0.1, 2.8, 0.0, //
        -0.1, 1.5, 0.0, -0.3, 1.5, 0.0, -0.3, 1.8, 0.0, -0.1, 1.8, 0.0,
    ];
    let leaf_uvs = [
        0.0f32, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, //
        0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0,
    ];
    let leaf_indices: [u16; 12] = [0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7];
    let mut bin = Vec::new();
    let mut views = Vec::new();
    for chunk in [
        f32s(&positions),
        u16s(&indices),
        f32s(&leaf_positions),
        f32s(&leaf_uvs),
        u16s(&leaf_indices),
    ] {
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        views.push(json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": chunk.len()}));
        bin.extend_from_slice(&chunk);
    }
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let doc = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"name": "wood", "mesh": 0}, {"name": "leaves", "mesh": 1}],
        "meshes": [
            {"name": "trunk", "primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]},
            {"name": "foliage", "primitives": [{"attributes": {"POSITION": 2, "TEXCOORD_0": 3}, "indices": 4, "material": 1}]}
        ],
        "materials": [
            {"name": "bark"},
            {"name": "leaf", "alphaMode": "MASK"}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 16, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5123, "count": 72, "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5126, "count": 8, "type": "VEC3"},
            {"bufferView": 3, "componentType": 5126, "count": 8, "type": "VEC2"},
            {"bufferView": 4, "componentType": 5123, "count": 12, "type": "SCALAR"}
        ],
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}]
    });
    (doc, bin)
}

fn base_glb() -> Vec<u8> {
    let (doc, bin) = base();
    glb(&doc, &bin)
}

/// The same document as glTF JSON with the buffer in a data URI.
fn base_gltf(doc: &mut Value, bin: &[u8]) -> Vec<u8> {
    use base64::Engine as _;
    let uri = format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bin)
    );
    doc["buffers"][0]["uri"] = json!(uri);
    serde_json::to_vec(doc).unwrap()
}

fn edit(f: impl FnOnce(&mut Value, &mut Vec<u8>)) -> Vec<u8> {
    let (mut doc, mut bin) = base();
    f(&mut doc, &mut bin);
    glb(&doc, &bin)
}

fn edit_gltf(f: impl FnOnce(&mut Value, &mut Vec<u8>)) -> Vec<u8> {
    let (mut doc, mut bin) = base();
    f(&mut doc, &mut bin);
    base_gltf(&mut doc, &bin)
}

/// Every corpus case: file name (`CODE--what.ext`) and bytes.
fn cases() -> Vec<(String, Vec<u8>)> {
    let good = base_glb();
    let mut out: Vec<(&str, Vec<u8>)> = vec![
        ("invalid_gltf--empty.glb", Vec::new()),
        (
            "invalid_gltf--garbage.bin",
            b"\x00\x01\x02 not a tree".to_vec(),
        ),
        (
            "invalid_gltf--truncated-header.glb",
            b"glTF\x02\x00\x00\x00".to_vec(),
        ),
        (
            "invalid_gltf--truncated-half.glb",
            good[..good.len() / 2].to_vec(),
        ),
        ("invalid_gltf--truncated-bin.glb", {
            let mut g = good.clone();
            let n = g.len() - 8;
            g.truncate(n);
            let len = (g.len() as u32).to_le_bytes();
            g[8..12].copy_from_slice(&len);
            g
        }),
        ("invalid_gltf--chunk-length-overflow.glb", {
            let mut g = good.clone();
            g[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
            g
        }),
        (
            "invalid_gltf--bad-json.gltf",
            b"{\"asset\": {\"version\": \"2.0\"}, \"nodes\": [".to_vec(),
        ),
        ("invalid_gltf--json-array.gltf", b"[1, 2, 3]".to_vec()),
        // Ignored values are skipped without recursion: no stack overflow,
        // and an empty document.
        ("invalid_tree--deep-nesting-in-extras.gltf", {
            let mut s = String::from("{\"asset\":{\"version\":\"2.0\"},\"extras\":");
            s.push_str(&"[".repeat(10_000));
            s.push_str(&"]".repeat(10_000));
            s.push('}');
            s.into_bytes()
        }),
        // Values that are read hit serde_json's recursion limit.
        (
            "invalid_gltf--deep-nesting-in-extensions.glb",
            edit(|d, _| {
                let mut v = json!(0);
                for _ in 0..1000 {
                    v = json!([v]);
                }
                d["bufferViews"][0]["extensions"] = json!({"deep": v});
            }),
        ),
        ("invalid_gltf--no-asset.gltf", b"{\"meshes\": []}".to_vec()),
        (
            "invalid_gltf--accessor-count-2-31.glb",
            edit(|d, _| {
                d["accessors"][0]["count"] = json!(1u64 << 31);
            }),
        ),
        (
            "invalid_gltf--buffer-4gb.glb",
            edit(|d, _| {
                d["buffers"][0]["byteLength"] = json!(4_294_967_295u64);
            }),
        ),
        (
            "invalid_gltf--view-past-buffer.glb",
            edit(|d, _| {
                d["bufferViews"][0]["byteOffset"] = json!(1_000_000);
            }),
        ),
        (
            "invalid_gltf--view-offset-overflow.glb",
            edit(|d, _| {
                d["bufferViews"][0]["byteOffset"] = json!(u64::MAX - 4);
            }),
        ),
        (
            "invalid_gltf--accessor-offset-past-view.glb",
            edit(|d, _| {
                d["accessors"][0]["byteOffset"] = json!(4_000_000_000u64);
            }),
        ),
        (
            "invalid_gltf--stride-too-small.glb",
            edit(|d, _| {
                d["bufferViews"][0]["byteStride"] = json!(4);
            }),
        ),
        (
            "invalid_gltf--stride-too-large.glb",
            edit(|d, _| {
                d["bufferViews"][0]["byteStride"] = json!(100_000);
            }),
        ),
        (
            "invalid_gltf--index-out-of-range.glb",
            edit(|d, bin| {
                let at = d["bufferViews"][1]["byteOffset"].as_u64().unwrap() as usize;
                bin[at..at + 2].copy_from_slice(&60_000u16.to_le_bytes());
            }),
        ),
        (
            "invalid_gltf--nan-position.glb",
            edit(|_, bin| {
                bin[0..4].copy_from_slice(&f32::NAN.to_le_bytes());
            }),
        ),
        (
            "invalid_gltf--infinite-position.glb",
            edit(|_, bin| {
                bin[4..8].copy_from_slice(&f32::INFINITY.to_le_bytes());
            }),
        ),
        (
            "invalid_gltf--positions-not-vec3.glb",
            edit(|d, _| {
                d["accessors"][0]["type"] = json!("VEC2");
            }),
        ),
        (
            "invalid_gltf--bad-component-type.glb",
            edit(|d, _| {
                d["accessors"][1]["componentType"] = json!(5130);
            }),
        ),
        (
            "invalid_gltf--float-indices.glb",
            edit(|d, _| {
                d["accessors"][1]["componentType"] = json!(5126);
            }),
        ),
        (
            "invalid_gltf--missing-accessor.glb",
            edit(|d, _| {
                d["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = json!(99);
            }),
        ),
        (
            "invalid_gltf--missing-mesh.glb",
            edit(|d, _| {
                d["nodes"][0]["mesh"] = json!(7);
            }),
        ),
        (
            "invalid_gltf--missing-material.glb",
            edit(|d, _| {
                d["meshes"][0]["primitives"][0]["material"] = json!(9);
            }),
        ),
        (
            "invalid_gltf--missing-node.glb",
            edit(|d, _| {
                d["scenes"][0]["nodes"] = json!([0, 1, 5]);
            }),
        ),
        (
            "invalid_gltf--node-cycle.glb",
            edit(|d, _| {
                d["nodes"][0]["children"] = json!([1]);
                d["nodes"][1]["children"] = json!([0]);
            }),
        ),
        (
            "invalid_gltf--node-self-child.glb",
            edit(|d, _| {
                d["nodes"][0]["children"] = json!([0]);
            }),
        ),
        (
            "invalid_gltf--node-two-parents.glb",
            edit(|d, _| {
                d["nodes"]
                    .as_array_mut()
                    .unwrap()
                    .push(json!({"children": [1]}));
                d["scenes"][0]["nodes"] = json!([0, 1, 2]);
            }),
        ),
        (
            "invalid_gltf--matrix-15-numbers.glb",
            edit(|d, _| {
                d["nodes"][0]["matrix"] = json!([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0]);
            }),
        ),
        (
            "invalid_gltf--scale-overflows.glb",
            edit(|d, _| {
                d["nodes"][0]["scale"] = json!([1e39, 1, 1]);
            }),
        ),
        (
            "invalid_gltf--zero-rotation.glb",
            edit(|d, _| {
                d["nodes"][0]["rotation"] = json!([0, 0, 0, 0]);
            }),
        ),
        (
            "invalid_gltf--bad-alpha-mode.glb",
            edit(|d, _| {
                d["materials"][1]["alphaMode"] = json!("SOMETIMES");
            }),
        ),
        (
            "invalid_gltf--bad-mode.glb",
            edit(|d, _| {
                d["meshes"][0]["primitives"][0]["mode"] = json!(9);
            }),
        ),
        (
            "invalid_gltf--sparse-index-out-of-range.glb",
            edit(|d, bin| {
                let at = bin.len();
                bin.extend_from_slice(&1000u16.to_le_bytes());
                bin.extend_from_slice(&[0, 0]);
                bin.extend_from_slice(&f32s(&[0.0, 9.0, 0.0]));
                let n = d["bufferViews"].as_array().unwrap().len();
                d["bufferViews"]
                    .as_array_mut()
                    .unwrap()
                    .push(json!({"buffer": 0, "byteOffset": at, "byteLength": 2}));
                d["bufferViews"]
                    .as_array_mut()
                    .unwrap()
                    .push(json!({"buffer": 0, "byteOffset": at + 4, "byteLength": 12}));
                d["buffers"][0]["byteLength"] = json!(bin.len());
                d["accessors"][0]["sparse"] = json!({"count": 1,
                "indices": {"bufferView": n, "componentType": 5123},
                "values": {"bufferView": n + 1}});
            }),
        ),
        (
            "invalid_gltf--sparse-count-too-large.glb",
            edit(|d, _| {
                d["accessors"][0]["sparse"] = json!({"count": 1_000_000,
                "indices": {"bufferView": 1, "componentType": 5123},
                "values": {"bufferView": 0}});
            }),
        ),
        (
            "invalid_gltf--sparse-values-short.glb",
            edit(|d, _| {
                d["accessors"][0]["sparse"] = json!({"count": 16,
                "indices": {"bufferView": 1, "componentType": 5123},
                "values": {"bufferView": 4}});
            }),
        ),
        ("invalid_gltf--bad-base64.gltf", edit_gltf(|_, _| {})),
        (
            "invalid_gltf--data-uri-too-short.gltf",
            edit_gltf(|d, _| {
                d["buffers"][0]["byteLength"] = json!(1 << 30);
            }),
        ),
        ("unsupported_gltf--external-buffer.gltf", {
            let (mut d, _) = base();
            d["buffers"][0]["uri"] = json!("tree.bin");
            serde_json::to_vec(&d).unwrap()
        }),
        (
            "unsupported_gltf--external-image.glb",
            edit(|d, _| {
                d["images"] = json!([{"uri": "../../etc/passwd"}]);
            }),
        ),
        (
            "unsupported_gltf--draco-required.glb",
            edit(|d, _| {
                d["extensionsRequired"] = json!(["KHR_draco_mesh_compression"]);
                d["extensionsUsed"] = json!(["KHR_draco_mesh_compression"]);
            }),
        ),
        (
            "unsupported_gltf--meshopt-view.glb",
            edit(|d, _| {
                d["bufferViews"][0]["extensions"] = json!({"EXT_meshopt_compression": {}});
            }),
        ),
        (
            "unsupported_gltf--version-3.glb",
            edit(|d, _| {
                d["asset"]["version"] = json!("3.0");
            }),
        ),
        ("unsupported_gltf--percent-encoded-data-uri.gltf", {
            let (mut d, _) = base();
            d["buffers"][0]["uri"] = json!("data:application/octet-stream,%00%01");
            serde_json::to_vec(&d).unwrap()
        }),
        (
            "invalid_tree--only-leaves.glb",
            edit(|d, _| {
                d["scenes"][0]["nodes"] = json!([1]);
            }),
        ),
        (
            "invalid_tree--no-meshes.gltf",
            br#"{"asset": {"version": "2.0"}}"#.to_vec(),
        ),
        (
            "invalid_tree--points-only.glb",
            edit(|d, _| {
                d["meshes"][0]["primitives"][0]["mode"] = json!(0);
            }),
        ),
        (
            "too_large--zero-accessor-2-31.glb",
            edit(|d, _| {
                d["accessors"][0] =
                    json!({"componentType": 5126, "count": 1u64 << 31, "type": "VEC3"});
            }),
        ),
    ];
    // Corrupt base64 in place: a character outside the alphabet.
    for (name, bytes) in &mut out {
        if *name == "invalid_gltf--bad-base64.gltf" {
            let s = String::from_utf8(bytes.clone()).unwrap();
            *bytes = s.replacen("base64,", "base64,!!!!", 1).into_bytes();
        }
    }
    out.into_iter().map(|(n, b)| (n.to_owned(), b)).collect()
}

fn corpus_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/hostile")
}

#[test]
#[ignore = "writes the corpus; run after changing the cases"]
fn write_corpus() {
    let dir = corpus_dir();
    std::fs::create_dir_all(&dir).unwrap();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.file_name().unwrap().to_string_lossy().contains("--") {
            std::fs::remove_file(path).unwrap();
        }
    }
    for (name, bytes) in cases() {
        std::fs::write(dir.join(name), bytes).unwrap();
    }
}

#[test]
fn base_files_import() {
    let imported = import(&base_glb(), &ImportOptions::default()).unwrap();
    assert_eq!(imported.tree.leaves().len(), 2);
    let (mut doc, bin) = base();
    let imported = import(&base_gltf(&mut doc, &bin), &ImportOptions::default()).unwrap();
    assert_eq!(imported.tree.leaves().len(), 2);
}

#[test]
fn corpus_files_give_their_codes() {
    let dir = corpus_dir();
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().contains("--"))
        .collect();
    files.sort();
    let cases = cases();
    assert_eq!(
        files.len(),
        cases.len(),
        "the corpus is stale: run write_corpus"
    );
    for (name, bytes) in &cases {
        let on_disk = std::fs::read(dir.join(name)).unwrap_or_default();
        assert!(
            &on_disk == bytes,
            "{name} differs from its case: run write_corpus"
        );
    }
    for path in files {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let expected = name.split("--").next().unwrap();
        assert!(
            ImportError::CODES.contains(&expected),
            "{name}: unknown code"
        );
        let bytes = std::fs::read(&path).unwrap();
        match import(&bytes, &ImportOptions::default()) {
            Ok(_) => panic!("{name}: imported, expected {expected}"),
            Err(e) => assert_eq!(e.code(), expected, "{name}: {e}"),
        }
    }
}

#[test]
fn limits_are_enforced_before_work() {
    let good = base_glb();
    let mut small = ImportOptions::default();
    small.max_file_bytes = good.len() - 1;
    assert_eq!(import(&good, &small).unwrap_err().code(), "too_large");
    let mut few = ImportOptions::default();
    few.max_vertices = 10;
    assert_eq!(import(&good, &few).unwrap_err().code(), "too_large");
    let mut json = ImportOptions::default();
    json.max_json_bytes = 100;
    assert_eq!(import(&good, &json).unwrap_err().code(), "too_large");
    // A huge (but valid) data URI is refused by size, not decoded.
    let (mut doc, mut bin) = base();
    bin.resize(8 << 20, 0);
    doc["buffers"][0]["byteLength"] = json!(bin.len());
    let gltf = base_gltf(&mut doc, &bin);
    let mut limit = ImportOptions::default();
    limit.max_file_bytes = 4 << 20;
    assert_eq!(import(&gltf, &limit).unwrap_err().code(), "too_large");
    assert!(import(&gltf, &ImportOptions::default()).is_ok());
}

#[test]
fn zero_area_leaves_are_skipped_and_counted() {
    let bytes = edit(|d, bin| {
        // Collapse the second leaf quad onto a line.
        let at = d["bufferViews"][2]["byteOffset"].as_u64().unwrap() as usize + 12 * 4;
        let line = f32s(&[
            -0.1, 1.5, 0.0, -0.3, 1.5, 0.0, -0.3, 1.5, 0.0, -0.1, 1.5, 0.0,
        ]);
        bin[at..at + line.len()].copy_from_slice(&line);
    });
    let imported = import(&bytes, &ImportOptions::default()).unwrap();
    assert_eq!(imported.tree.leaves().len(), 1);
    assert_eq!(imported.report.skipped_leaves, 1);
    assert!(
        imported
            .report
            .warnings
            .iter()
            .any(|w| w.contains("zero area"))
    );
}

/// Every number in a JSON text, as byte ranges.
fn number_spans(json: &[u8]) -> Vec<(usize, usize)> {
    let mut spans = Vec::new();
    let mut i = 0;
    let mut in_string = false;
    while i < json.len() {
        let c = json[i];
        if in_string {
            if c == b'\\' {
                i += 1;
            } else if c == b'"' {
                in_string = false;
            }
            i += 1;
            continue;
        }
        if c == b'"' {
            in_string = true;
            i += 1;
            continue;
        }
        if c == b'-' || c.is_ascii_digit() {
            let start = i;
            while i < json.len()
                && matches!(json[i], b'-' | b'+' | b'.' | b'e' | b'E' | b'0'..=b'9')
            {
                i += 1;
            }
            spans.push((start, i));
            continue;
        }
        i += 1;
    }
    spans
}

fn check_outcome(result: Result<treemorph_import::Imported, ImportError>) {
    if let Err(e) = result {
        assert!(ImportError::CODES.contains(&e.code()));
        assert_ne!(e.code(), "internal", "{e}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Any JSON number replaced by a hostile value: an error with a code
    /// (or a tree), never a panic or an internal error.
    #[test]
    fn hostile_numbers_never_panic(which in any::<prop::sample::Index>(), value in prop::sample::select(vec![
        "0", "-1", "1", "3", "7", "65535", "2147483648", "4294967295", "4294967296",
        "18446744073709551615", "1e39", "-1e39", "0.5", "1e-45", "99999999999999999999999",
    ])) {
        let (doc, bin) = base();
        let mut json = serde_json::to_vec(&doc).unwrap();
        let spans = number_spans(&json);
        let (a, b) = spans[which.index(spans.len())];
        json.splice(a..b, value.bytes());
        let bytes = Glb { json: &json, bin: Some(&bin) }.to_vec().unwrap();
        check_outcome(import(&bytes, &ImportOptions::default()));
    }

    /// Random byte edits anywhere in a valid GLB.
    #[test]
    fn flipped_bytes_never_panic(edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8)) {
        let mut bytes = base_glb();
        for (at, v) in edits {
            let i = at.index(bytes.len());
            bytes[i] = v;
        }
        check_outcome(import(&bytes, &ImportOptions::default()));
    }

    /// Every prefix of a valid GLB.
    #[test]
    fn truncations_never_panic(cut in any::<prop::sample::Index>()) {
        let bytes = base_glb();
        let n = cut.index(bytes.len());
        let result = import(&bytes[..n], &ImportOptions::default());
        prop_assert!(result.is_err());
        check_outcome(result);
    }
}
