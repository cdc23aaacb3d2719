//! Writes the committed seed corpus `fuzz/corpus/<target>/seed-*`: small
//! valid examples of each format, so the fuzzers start from inputs that
//! reach deep into the parsers.
//!
//! `cargo run --manifest-path fuzz/Cargo.toml --example seeds` (from the
//! repository root). Files the fuzzers add to the corpus directories are
//! left alone; only `seed-*` files are rewritten.

use std::path::{Path, PathBuf};

use serde_json::{Value, json};
use treemorph_api::delta::{
    Encoder, EncoderOptions, Grid, Material, MaterialGroup, Mesh, StreamHeader,
};
use treemorph_tree::glam::{Quat, Vec3};
use treemorph_tree::{
    Bark, BranchingPattern, GroundTruth, GroundTruthGroup, Leaf, LeafMaterial, Limits, Materials,
    Node, RgbaImage, Texture, Tree, TreeParts, json as tree_json,
};

fn corpus(target: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("corpus").join(target);
    std::fs::create_dir_all(&dir).unwrap();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.file_name().unwrap().to_string_lossy().starts_with("seed-") {
            std::fs::remove_file(path).unwrap();
        }
    }
    dir
}

fn write(dir: &Path, name: &str, bytes: &[u8]) {
    std::fs::write(dir.join(format!("seed-{name}")), bytes).unwrap();
}

/// A five-node tree with three leaves; with a 2×2 texture when `textured`.
fn small_tree(textured: bool) -> Tree {
    let node = |x: f32, y: f32, r: f32, parent: Option<u32>| Node {
        position: Vec3::new(x, y, 0.0),
        radius: r,
        parent,
    };
    let nodes = vec![
        node(0.0, 0.0, 0.1, None),
        node(0.0, 1.0, 0.08, Some(0)),
        node(0.0, 2.0, 0.05, Some(1)),
        node(0.5, 1.6, 0.03, Some(1)),
        node(-0.5, 1.6, 0.03, Some(1)),
    ];
    let leaf = |branch: u32, t: f32| Leaf {
        branch,
        t,
        offset: Vec3::new(0.0, 0.0, 0.03),
        width: 0.2,
        height: 0.3,
        orientation: Quat::from_rotation_y(0.5),
        material: 0,
    };
    let texture = textured.then(|| {
        let pixels = [
            [40u8, 120, 30, 255],
            [0, 0, 0, 0],
            [50, 140, 40, 255],
            [60, 150, 50, 200],
        ]
        .concat();
        Texture::from_rgba(&RgbaImage::new(2, 2, pixels).unwrap())
    });
    let parts = TreeParts {
        name: "seed".into(),
        nodes,
        leaves: vec![leaf(2, 0.9), leaf(3, 0.5), leaf(4, 1.0)],
        materials: Materials {
            bark: Bark::default(),
            leaves: vec![LeafMaterial {
                name: "ovate".into(),
                color: [1.0; 4],
                texture,
            }],
        },
        ground_truth: textured.then(|| GroundTruth {
            orders: vec![1, 1, 1, 2, 2],
            groups: vec![
                GroundTruthGroup {
                    chains: vec![1],
                    pattern: BranchingPattern::Alternate,
                },
                GroundTruthGroup {
                    chains: vec![3, 4],
                    pattern: BranchingPattern::Opposite,
                },
            ],
        }),
    };
    Tree::new(parts, &Limits::default()).unwrap()
}

fn glb(doc: &Value, bin: &[u8]) -> Vec<u8> {
    let json = serde_json::to_vec(doc).unwrap();
    treemorph_gltf::Glb {
        json: &json,
        bin: (!bin.is_empty()).then_some(bin),
    }
    .to_vec()
    .unwrap()
}

/// A third-party-style file: a four-sided tube (wood) and two
/// alpha-masked leaf quads, no embedded tree (the importer reconstructs
/// the skeleton). As `crates/import/tests/hostile.rs`'s base file.
fn mesh_only() -> (Value, Vec<u8>) {
    let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let u16s = |v: &[u16]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
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
            indices.extend_from_slice(&[a, b, b + 4, a, b + 4, a + 4]);
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
    let doc = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"name": "wood", "mesh": 0, "translation": [0, 0.1, 0]},
                  {"name": "leaves", "mesh": 1, "rotation": [0, 0, 0, 1]}],
        "meshes": [
            {"name": "trunk", "primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]},
            {"name": "foliage", "primitives": [{"attributes": {"POSITION": 2, "TEXCOORD_0": 3}, "indices": 4, "material": 1}]}
        ],
        "materials": [{"name": "bark"}, {"name": "leaf", "alphaMode": "MASK"}],
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

fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&0)];
        let n = u32::from(b[0]) << 16 | u32::from(b[1]) << 8 | u32::from(b[2]);
        for i in 0..4 {
            if i <= chunk.len() {
                out.push(ALPHABET[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

fn import_seeds() {
    let dir = corpus("import_gltf");
    // Mode byte 0: the bytes as uploaded.
    let with_mode = |mode: u8, bytes: &[u8]| [&[mode][..], bytes].concat();
    let ours = treemorph_gltf::export_glb(&small_tree(false), &Default::default()).unwrap();
    write(&dir, "ours-embedded.glb", &with_mode(0, &ours));
    let mut third = treemorph_gltf::ExportOptions::default();
    third.embed_tree = false;
    let ours_plain = treemorph_gltf::export_glb(&small_tree(false), &third).unwrap();
    write(&dir, "ours-no-tree.glb", &with_mode(0, &ours_plain));
    let (doc, bin) = mesh_only();
    write(&dir, "mesh-only.glb", &with_mode(0, &glb(&doc, &bin)));
    let mut gltf = doc.clone();
    gltf["buffers"][0]["uri"] =
        json!(format!("data:application/octet-stream;base64,{}", base64(&bin)));
    write(&dir, "mesh-only.gltf", &with_mode(0, &serde_json::to_vec(&gltf).unwrap()));
    // Mode byte 1: JSON and BIN chunks split at byte 2's fraction of the
    // rest, wrapped in a GLB container by the target.
    let json = serde_json::to_vec(&doc).unwrap();
    let total = json.len() + bin.len();
    let split = (json.len() * 255).div_ceil(total) as u8;
    let mut input = vec![1, split];
    input.extend_from_slice(&json);
    // The target splits at `rest.len() * split / 255`: pad the JSON side
    // with spaces until the split lands exactly after it.
    while (input.len() - 2 + bin.len()) * usize::from(split) / 255 > input.len() - 2 {
        input.push(b' ');
    }
    assert_eq!((input.len() - 2 + bin.len()) * usize::from(split) / 255, input.len() - 2);
    input.extend_from_slice(&bin);
    write(&dir, "mesh-only-chunks", &input);
}

fn tree_seeds() {
    let dir = corpus("tree_json");
    write(&dir, "plain.json", &tree_json::to_vec(&small_tree(false)));
    write(&dir, "textured.json", &tree_json::to_vec(&small_tree(true)));
}

fn job_seeds() {
    let dir = corpus("job_json");
    let id = |n: u8| format!("{n:032x}");
    let docs = [
        ("morph-minimal", json!({"kind": "morph", "source": id(1), "target": id(2), "frames": 30})),
        ("morph-full", json!({"kind": "morph", "source": id(1), "target": id(2), "frames": 60.0,
            "options": {"matching": "one_to_one", "leaves": "random", "slow_down": false, "keyframes": 12},
            "outputs": {"glb": false, "animated": true, "delta": true},
            "callback_url": "https://hooks.example/treemorph"})),
        ("sketch-perspective", json!({"kind": "sketch", "tree": id(3), "frames": 24,
            "view": {"eye": [0, 8, 40], "target": [0, 8, 0], "up": [0, 1, 0], "fov_deg": 35},
            "sketch": {"points": [[-0.5, -0.2], [0.5, -0.2], [0.6, 0.5], [0, 0.9], [-0.6, 0.5]], "closed": true},
            "options": {"method": "multiscale", "fit": "crown", "keyframes": 6}})),
        ("sketch-ortho-open", json!({"kind": "sketch", "tree": id(3), "frames": 2,
            "view": {"eye": [10, 5, 0], "target": [0, 5, 0], "up": [0, 1, 0], "ortho_height": 12.5},
            "sketch": {"points": [[-0.9, 0.1], [-0.2, 0.8], [0.4, 0.85], [0.9, 0.2]]},
            "options": {"method": "single_cage"}})),
    ];
    for (name, doc) in docs {
        write(&dir, &format!("{name}.json"), &serde_json::to_vec(&doc).unwrap());
    }
}

fn sketch_seeds() {
    let dir = corpus("sketch_json");
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/sketches");
    let mut names: Vec<_> = std::fs::read_dir(&examples)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    names.sort();
    for path in names {
        let bytes = std::fs::read(&path).unwrap();
        treemorph_sketch::parse_sketch_file(&bytes).unwrap();
        write(&dir, &path.file_name().unwrap().to_string_lossy(), &bytes);
    }
}

fn delta_seeds() {
    let dir = corpus("delta_decoder");
    let bounds = [[-1.0, 0.0, -1.0], [1.0, 2.0, 1.0]];
    let tri = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.5, 0.5]];
    let header = StreamHeader {
        bounds,
        grid: Grid::for_bounds(bounds, 0.001),
        frame_count: 3,
        textures: vec![],
        materials: vec![Material::default(), Material::default()],
        meshes: vec![
            Mesh {
                name: "branches".into(),
                indices: vec![0, 1, 2, 1, 2, 3],
                uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]],
                groups: vec![MaterialGroup { first: 0, count: 6, material: 0, fade_to: None }],
                base_positions: tri.to_vec(),
            },
            Mesh {
                name: "leaves".into(),
                indices: vec![0, 1, 2],
                uvs: vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
                groups: vec![MaterialGroup { first: 0, count: 3, material: 0, fade_to: Some(1) }],
                base_positions: tri[..3].to_vec(),
            },
        ],
    };
    let mut encoder = Encoder::new(header, &EncoderOptions::default()).unwrap();
    let mut stream = encoder.header_bytes().to_vec();
    for i in 0..3u32 {
        let s = i as f32 * 0.25;
        let a: Vec<[f32; 3]> = tri.iter().map(|p| [p[0] + s, p[1], p[2] - s]).collect();
        let b: Vec<[f32; 3]> = tri[..3].iter().map(|p| [p[0], p[1] + s, p[2]]).collect();
        encoder
            .encode_frame(i, i as f32 / 2.0, &[&a, &b], s, &mut stream)
            .unwrap();
    }
    encoder.finish(&mut stream).unwrap();
    treemorph_api::delta::decode_all(&stream, &Default::default()).unwrap();
    // Byte 0 seeds the chunk sizes.
    write(&dir, "three-frames.tmd", &[&[7u8][..], &stream].concat());
    let mut stored = EncoderOptions::default();
    stored.compression = treemorph_api::delta::Compression::None;
    let mut header = encoder.header().clone();
    header.frame_count = 1;
    let mut encoder = Encoder::new(header, &stored).unwrap();
    let mut stream = encoder.header_bytes().to_vec();
    encoder.encode_frame(0, 0.0, &[&tri, &tri[..3]], 0.0, &mut stream).unwrap();
    encoder.finish(&mut stream).unwrap();
    write(&dir, "stored.tmd", &[&[200u8][..], &stream].concat());
}

fn main() {
    import_seeds();
    tree_seeds();
    job_seeds();
    sketch_seeds();
    delta_seeds();
    println!("seeds written under fuzz/corpus/");
}
