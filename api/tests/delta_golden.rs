//! Golden fixtures of the delta format, shared with the JavaScript decoder.
//!
//! `tests/fixtures/small.tmd` is a small deterministic stream (two meshes,
//! a texture, five frames) and `small.json` what it decodes to; `web/test/`
//! decodes the same file with `web/delta.js`. The README's worked example
//! is checked byte for byte too.
//!
//! After an intentional change to the encoder's output, regenerate with
//! `UPDATE_FIXTURES=1 cargo test -p treemorph-api --test delta_golden` (and
//! bump the format version if old streams no longer decode).

use std::path::PathBuf;

use serde_json::{Value, json};
use treemorph_api::delta::*;

/// A 1×1 RGBA PNG (a translucent green pixel).
const LEAF_PNG: [u8; 70] = [
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44, 0x52,
    0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x01, 0x08, 0x06, 0x00, 0x00, 0x00, 0x1f, 0x15, 0xc4,
    0x89, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x44, 0x41, 0x54, 0x78, 0xda, 0x63, 0x08, 0x58, 0x60, 0x70,
    0x00, 0x00, 0x04, 0x45, 0x01, 0xe1, 0x0c, 0x46, 0x24, 0x7e, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45,
    0x4e, 0x44, 0xae, 0x42, 0x60, 0x82,
];

const FRAMES: u32 = 5;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures")
}

fn updating() -> bool {
    std::env::var_os("UPDATE_FIXTURES").is_some_and(|v| v == "1")
}

/// A trunk tube (3 rings of 4 vertices) and two leaf quads that
/// cross-fade from one leaf material to another. Only +, −, × and ÷ are
/// used, so the input is the same on every platform.
fn small_header() -> StreamHeader {
    let mut branches = Mesh {
        name: "branches".into(),
        ..Mesh::default()
    };
    for ring in 0..3u32 {
        let r = 0.1 - 0.03 * ring as f32;
        for k in 0..4u32 {
            let (x, z) = [(r, 0.0), (0.0, r), (-r, 0.0), (0.0, -r)][k as usize];
            branches.base_positions.push([x, ring as f32 * 0.8, z]);
            branches.uvs.push([k as f32 / 4.0, ring as f32 / 2.0]);
        }
    }
    for ring in 0..2u32 {
        for k in 0..4u32 {
            let (a, b) = (ring * 4 + k, ring * 4 + (k + 1) % 4);
            branches.indices.extend([a, b, a + 4, b, b + 4, a + 4]);
        }
    }
    branches.groups.push(MaterialGroup {
        first: 0,
        count: branches.indices.len() as u32,
        material: 0,
        fade_to: None,
    });
    let mut leaves = Mesh {
        name: "leaves".into(),
        ..Mesh::default()
    };
    for (l, (x, z)) in [(0.1f32, 0.0f32), (-0.1, 0.05)].into_iter().enumerate() {
        let first = leaves.base_positions.len() as u32;
        let y = 1.6;
        for (dx, dy, uv) in [
            (-0.04, 0.0, [0.0, 1.0]),
            (0.04, 0.0, [1.0, 1.0]),
            (0.04, 0.12, [1.0, 0.0]),
            (-0.04, 0.12, [0.0, 0.0]),
        ] {
            leaves
                .base_positions
                .push([x + dx, y + dy + l as f32 * 0.05, z]);
            leaves.uvs.push(uv);
        }
        leaves
            .indices
            .extend([first, first + 1, first + 2, first, first + 2, first + 3]);
    }
    leaves.groups.push(MaterialGroup {
        first: 0,
        count: leaves.indices.len() as u32,
        material: 1,
        fade_to: Some(2),
    });
    let bounds = [[-0.5, 0.0, -0.5], [0.5, 2.0, 0.5]];
    let leaf = |name: &str, color: [f32; 4]| Material {
        name: name.into(),
        base_color: color,
        alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
        double_sided: true,
        texture: Some(0),
    };
    StreamHeader {
        bounds,
        grid: Grid::for_bounds(bounds, 0.001),
        frame_count: FRAMES,
        textures: vec![Texture {
            png: LEAF_PNG.to_vec(),
        }],
        materials: vec![
            Material {
                name: "bark".into(),
                base_color: [0.4, 0.3, 0.2, 1.0],
                ..Material::default()
            },
            leaf("leaf-green", [0.5, 0.9, 0.4, 1.0]),
            leaf("leaf-red", [0.9, 0.3, 0.2, 1.0]),
        ],
        meshes: vec![branches, leaves],
    }
}

/// Frame `i`: the tree leans in x (more with height) and the leaves rise.
fn small_frame(header: &StreamHeader, i: u32) -> Vec<Vec<[f32; 3]>> {
    let s = i as f32 / (FRAMES - 1) as f32;
    header
        .meshes
        .iter()
        .map(|m| {
            m.base_positions
                .iter()
                .map(|&[x, y, z]| [x + 0.1 * s * y * y, y + 0.02 * s * y, z - 0.05 * s * y])
                .collect()
        })
        .collect()
}

fn small_stream() -> Vec<u8> {
    let header = small_header();
    let mut encoder = Encoder::new(header.clone(), &EncoderOptions::default()).unwrap();
    let mut stream = encoder.header_bytes().to_vec();
    for i in 0..FRAMES {
        let frame = small_frame(&header, i);
        let slices: Vec<&[[f32; 3]]> = frame.iter().map(Vec::as_slice).collect();
        let t = i as f32 / (FRAMES - 1) as f32;
        encoder
            .encode_frame(i, t, &slices, t * t, &mut stream)
            .unwrap();
    }
    encoder.finish(&mut stream).unwrap();
    stream
}

fn floats(v: &[f32]) -> Value {
    json!(v)
}

/// The decoded stream as JSON (the shape `web/test/` compares against).
fn decoded_json(stream: &[u8]) -> Value {
    let (header, frames) = decode_all(stream, &DecoderOptions::default()).unwrap();
    json!({
        "header": {
            "bounds": [floats(&header.bounds[0]), floats(&header.bounds[1])],
            "grid": { "origin": floats(&header.grid.origin), "step": floats(&header.grid.step) },
            "frameCount": header.frame_count,
            "textures": header.textures.iter().map(|t| json!({
                "byteLength": t.png.len(),
                "bytes": t.png,
            })).collect::<Vec<_>>(),
            "materials": header.materials.iter().map(|m| {
                let (mode, cutoff) = match m.alpha_mode {
                    AlphaMode::Opaque => ("opaque", None),
                    AlphaMode::Mask { cutoff } => ("mask", Some(cutoff)),
                    AlphaMode::Blend => ("blend", None),
                };
                json!({
                    "name": m.name,
                    "baseColor": floats(&m.base_color),
                    "alphaMode": mode,
                    "alphaCutoff": cutoff,
                    "doubleSided": m.double_sided,
                    "texture": m.texture,
                })
            }).collect::<Vec<_>>(),
            "meshes": header.meshes.iter().map(|m| json!({
                "name": m.name,
                "indices": m.indices,
                "uvs": floats(m.uvs.as_flattened()),
                "groups": m.groups.iter().map(|g| json!({
                    "first": g.first, "count": g.count, "material": g.material, "fadeTo": g.fade_to,
                })).collect::<Vec<_>>(),
                "basePositions": floats(m.base_positions.as_flattened()),
            })).collect::<Vec<_>>(),
        },
        "frames": frames.iter().map(|f| json!({
            "index": f.index,
            "t": f.t,
            "leafBlend": f.leaf_blend,
            "positions": f.positions.iter().map(|p| floats(p.as_flattened())).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "end": { "frames": frames.len() },
    })
}

#[test]
fn the_small_fixture_is_what_the_encoder_writes_and_decodes_as_recorded() {
    let stream = small_stream();
    let expected = decoded_json(&stream);
    let (tmd, json_path) = (fixtures().join("small.tmd"), fixtures().join("small.json"));
    if updating() {
        std::fs::create_dir_all(fixtures()).unwrap();
        std::fs::write(&tmd, &stream).unwrap();
        std::fs::write(
            &json_path,
            serde_json::to_string_pretty(&expected).unwrap() + "\n",
        )
        .unwrap();
    }
    let committed = std::fs::read(&tmd).expect("fixture missing: run with UPDATE_FIXTURES=1");
    let committed_json: Value =
        serde_json::from_slice(&std::fs::read(&json_path).unwrap()).unwrap();
    // Old streams must keep decoding to the same frames.
    assert_eq!(decoded_json(&committed), committed_json);
    assert_eq!(expected, committed_json, "the decoded frames changed");
    assert!(
        stream == committed,
        "the encoder's bytes changed ({} vs {} bytes); if intended, regenerate with UPDATE_FIXTURES=1",
        stream.len(),
        committed.len()
    );
}

#[test]
fn the_small_fixture_stays_within_the_error_bound() {
    let header = small_header();
    let (_, frames) = decode_all(&small_stream(), &DecoderOptions::default()).unwrap();
    assert_eq!(frames.len(), FRAMES as usize);
    for frame in &frames {
        let input = small_frame(&header, frame.index);
        for (got, want) in frame.positions.iter().flatten().zip(input.iter().flatten()) {
            let e: f32 = (0..3)
                .map(|a| (got[a] - want[a]).powi(2))
                .sum::<f32>()
                .sqrt();
            assert!(e <= 0.002, "{got:?} vs {want:?}");
        }
    }
}

/// A 95 × 95 vertex sheet (more than two blocks of 4096 vertices) whose
/// frames exercise every bit width: smooth motion, then single vertices
/// thrown 5 km and 150 km away (24- and 32-bit differences) and back.
fn blocks_header() -> StreamHeader {
    let side = 95u32;
    let mut sheet = Mesh {
        name: "sheet".into(),
        ..Mesh::default()
    };
    for j in 0..side {
        for i in 0..side {
            let (u, v) = (i as f32 / (side - 1) as f32, j as f32 / (side - 1) as f32);
            sheet
                .base_positions
                .push([u * 20.0 - 10.0, v * 10.0, (u - 0.5) * (v - 0.5) * 4.0]);
            sheet.uvs.push([u, v]);
        }
    }
    for j in 0..side - 1 {
        for i in 0..side - 1 {
            let a = j * side + i;
            sheet
                .indices
                .extend([a, a + 1, a + side, a + 1, a + side + 1, a + side]);
        }
    }
    let bounds = [[-10.0, 0.0, -10.0], [10.0, 10.0, 10.0]];
    StreamHeader {
        bounds,
        grid: Grid::for_bounds(bounds, 0.001),
        frame_count: 0,
        textures: vec![],
        materials: vec![],
        meshes: vec![
            sheet,
            Mesh {
                name: "empty".into(),
                ..Mesh::default()
            },
        ],
    }
}

fn blocks_stream() -> Vec<u8> {
    let header = blocks_header();
    let mut encoder = Encoder::new(header.clone(), &EncoderOptions::default()).unwrap();
    let mut stream = encoder.header_bytes().to_vec();
    let base = &header.meshes[0].base_positions;
    for i in 0..4u32 {
        let s = i as f32 * 0.25;
        let mut p: Vec<[f32; 3]> = base
            .iter()
            .map(|&[x, y, z]| [x + s * y * 0.05, y, z + s * x * 0.02])
            .collect();
        if i == 2 {
            p[5000][0] = 5000.0;
            p[8999][2] = -150_000.0;
        }
        encoder
            .encode_frame(i, s, &[&p, &[]], 1.0 - s, &mut stream)
            .unwrap();
    }
    encoder.finish(&mut stream).unwrap();
    stream
}

/// FNV-1a (32-bit) of the positions' little-endian f32 bytes.
fn fnv1a(positions: &[[f32; 3]]) -> u32 {
    let mut h = 0x811c_9dc5u32;
    for b in positions.iter().flatten().flat_map(|v| v.to_le_bytes()) {
        h = (h ^ u32::from(b)).wrapping_mul(0x0100_0193);
    }
    h
}

fn blocks_json(stream: &[u8]) -> Value {
    let (header, frames) = decode_all(stream, &DecoderOptions::default()).unwrap();
    let indices_hash = header.meshes[0]
        .indices
        .iter()
        .flat_map(|i| i.to_le_bytes())
        .fold(0x811c_9dc5u32, |h, b| {
            (h ^ u32::from(b)).wrapping_mul(0x0100_0193)
        });
    let summary = |p: &[[f32; 3]]| {
        let samples: Vec<Value> = [0, 4095, 4096, 5000, 8191, 8192, 8999]
            .iter()
            .filter_map(|&i| p.get(i).map(|v| json!([i, floats(v)])))
            .collect();
        json!({ "vertices": p.len(), "fnv1a": fnv1a(p), "samples": samples })
    };
    json!({
        "header": {
            "indexCount": header.meshes[0].indices.len(),
            "indicesFnv1a": indices_hash,
            "base": header.meshes.iter().map(|m| summary(&m.base_positions)).collect::<Vec<_>>(),
        },
        "frames": frames.iter().map(|f| json!({
            "index": f.index,
            "t": f.t,
            "leafBlend": f.leaf_blend,
            "positions": f.positions.iter().map(|p| summary(p)).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
    })
}

#[test]
fn the_blocks_fixture_is_what_the_encoder_writes_and_decodes_as_recorded() {
    let stream = blocks_stream();
    let expected = blocks_json(&stream);
    let (tmd, json_path) = (
        fixtures().join("blocks.tmd"),
        fixtures().join("blocks.json"),
    );
    if updating() {
        std::fs::create_dir_all(fixtures()).unwrap();
        std::fs::write(&tmd, &stream).unwrap();
        std::fs::write(
            &json_path,
            serde_json::to_string_pretty(&expected).unwrap() + "\n",
        )
        .unwrap();
    }
    let committed = std::fs::read(&tmd).expect("fixture missing: run with UPDATE_FIXTURES=1");
    let committed_json: Value =
        serde_json::from_slice(&std::fs::read(&json_path).unwrap()).unwrap();
    assert_eq!(blocks_json(&committed), committed_json);
    assert_eq!(expected, committed_json, "the decoded frames changed");
    assert!(
        stream == committed,
        "the encoder's bytes changed; if intended, regenerate with UPDATE_FIXTURES=1"
    );
    // The far throws really are there (and come back).
    let (_, frames) = decode_all(&committed, &DecoderOptions::default()).unwrap();
    assert!((frames[2].positions[0][8999][2] + 150_000.0).abs() < 10.0);
    assert!(frames[3].positions[0][8999][2].abs() < 20.0);
}

/// The README's worked example: one triangle, one frame, stored records.
fn readme_stream() -> Vec<u8> {
    let bounds = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]];
    let header = StreamHeader {
        bounds,
        grid: Grid {
            origin: [0.0; 3],
            step: [0.5; 3],
        },
        frame_count: 1,
        textures: vec![],
        materials: vec![Material {
            name: "m".into(),
            ..Material::default()
        }],
        meshes: vec![Mesh {
            name: "t".into(),
            indices: vec![0, 1, 2],
            uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
            groups: vec![MaterialGroup {
                first: 0,
                count: 3,
                material: 0,
                fade_to: None,
            }],
            base_positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        }],
    };
    let mut encoder =
        Encoder::new(header, &EncoderOptions::with_compression(Compression::None)).unwrap();
    let mut stream = encoder.header_bytes().to_vec();
    let moved = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [0.0, 1.0, 0.0]];
    encoder
        .encode_frame(0, 1.0, &[&moved], 0.0, &mut stream)
        .unwrap();
    encoder.finish(&mut stream).unwrap();
    stream
}

#[test]
fn the_readme_worked_example_is_byte_exact() {
    let readme = include_str!("../README.md");
    let start = readme.find("```hex\n").expect("README has a ```hex block") + 7;
    let end = start + readme[start..].find("```").unwrap();
    let mut bytes = Vec::new();
    for line in readme[start..end].lines() {
        let data = line.split('#').next().unwrap_or("");
        for token in data.split_whitespace() {
            bytes.push(u8::from_str_radix(token, 16).expect("hex byte"));
        }
    }
    let stream = readme_stream();
    if bytes != stream {
        let hex: Vec<String> = stream.iter().map(|b| format!("{b:02x}")).collect();
        panic!(
            "README hex example differs; the stream is:\n{}",
            hex.join(" ")
        );
    }
    let (_, frames) = decode_all(&stream, &DecoderOptions::default()).unwrap();
    assert_eq!(
        frames[0].positions,
        vec![vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.5], [0.0, 1.0, 0.0]]]
    );
}
