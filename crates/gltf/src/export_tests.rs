use glam::{Quat, Vec3};
use gltf::mesh::Semantic;
use gltf::{Gltf, accessor::DataType, image::Source, material::AlphaMode};
use proptest::prelude::*;
use serde_json::{Value, json};
use treemorph_tree::json::FormatError;
use treemorph_tree::{
    BranchingPattern, Frame, FrameTopology, GroundTruth, GroundTruthGroup, Leaf, LeafMaterial,
    Limits, Materials, Node, Tree, TreeParts,
};

use super::*;
use crate::glb::Glb;
use crate::mesh::{BranchMesher, LeafMesher, MeshOptions};
use crate::sample;

fn node(x: f32, y: f32, z: f32, radius: f32, parent: Option<u32>) -> Node {
    Node {
        position: Vec3::new(x, y, z),
        radius,
        parent,
    }
}

/// A forked tree with leaves of two materials (one textured) and ground
/// truth.
fn fork() -> Tree {
    let leaf = |branch: u32, material: u32| Leaf {
        branch,
        t: 0.25 * branch as f32 % 1.0,
        offset: Vec3::new(0.0, 0.0, 0.04),
        width: 0.1,
        height: 0.15,
        orientation: Quat::from_rotation_x(0.4),
        material,
    };
    Tree::new(
        TreeParts {
            name: "fork".into(),
            nodes: vec![
                node(0.0, 0.0, 0.0, 0.2, None),
                node(0.0, 1.0, 0.0, 0.15, Some(0)),
                node(0.1, 2.0, 0.0, 0.12, Some(1)),
                node(0.1, 3.0, 0.2, 0.08, Some(2)),
                node(0.8, 2.6, 0.0, 0.05, Some(2)),
            ],
            leaves: vec![leaf(3, 0), leaf(4, 1), leaf(4, 0)],
            materials: Materials {
                leaves: vec![
                    LeafMaterial {
                        name: "ovate".into(),
                        color: [1.0; 4],
                        texture: Some(sample::leaf_texture()),
                    },
                    LeafMaterial {
                        name: "plain".into(),
                        color: [0.2, 0.6, 0.1, 1.0],
                        texture: None,
                    },
                ],
                ..Materials::default()
            },
            ground_truth: Some(GroundTruth {
                orders: vec![1, 1, 1, 1, 2],
                groups: vec![
                    GroundTruthGroup {
                        chains: vec![1],
                        pattern: BranchingPattern::Alternate,
                    },
                    GroundTruthGroup {
                        chains: vec![4],
                        pattern: BranchingPattern::Alternate,
                    },
                ],
            }),
        },
        &Limits::default(),
    )
    .unwrap()
}

fn meshes(tree: &Tree, options: &MeshOptions) -> (MeshBuffers, MeshBuffers) {
    let topology = FrameTopology::of_tree(tree);
    let frame = Frame::of_tree(tree);
    let mut b = BranchMesher::new(&topology, &frame.radii, &frame, options).unwrap();
    let mut l = LeafMesher::new(&topology, options).unwrap();
    (
        b.mesh(&frame).unwrap().clone(),
        l.mesh(&frame).unwrap().clone(),
    )
}

fn export(tree: &Tree) -> Vec<u8> {
    export_glb(tree, &ExportOptions::default()).unwrap()
}

fn as_f32s(v: Option<Value>) -> Vec<f32> {
    v.and_then(|v| v.as_array().cloned())
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap() as f32)
        .collect()
}

/// Layout rules the validator checks: views 4-byte aligned and inside the
/// buffer, accessors inside their views, buffer length exact.
fn assert_layout(gltf: &Gltf) {
    let blob = gltf.blob.as_ref().unwrap();
    let buffers: Vec<_> = gltf.buffers().collect();
    assert_eq!(buffers.len(), 1);
    assert_eq!(buffers[0].length(), blob.len());
    assert_eq!(blob.len() % 4, 0);
    for view in gltf.views() {
        assert_eq!(view.offset() % 4, 0);
        assert!(view.offset() + view.length() <= blob.len());
    }
    for a in gltf.accessors() {
        let view = a.view().unwrap();
        let end = a.offset() + a.count() * a.size();
        assert!(end <= view.length(), "accessor {} overruns", a.index());
        assert_eq!(a.offset() % a.data_type().size(), 0);
    }
}

#[test]
fn writes_named_nodes_meshes_and_materials() {
    let tree = sample::sample_tree(300);
    let glb = export(&tree);
    let gltf = Gltf::from_slice(&glb).unwrap();
    assert_layout(&gltf);
    let scenes: Vec<_> = gltf.scenes().collect();
    assert_eq!(scenes.len(), 1);
    assert_eq!(scenes[0].name(), Some("sample"));
    let names: Vec<_> = scenes[0]
        .nodes()
        .map(|n| {
            (
                n.name().unwrap().to_owned(),
                n.mesh().unwrap().name().unwrap().to_owned(),
            )
        })
        .collect();
    assert_eq!(
        names,
        [("branches", "branches"), ("leaves", "leaves")].map(|(a, b)| (a.into(), b.into()))
    );

    let (branch_mesh, leaf_mesh) = meshes(&tree, &MeshOptions::default());
    let mesh = |name: &str| gltf.meshes().find(|m| m.name() == Some(name)).unwrap();
    for (name, expected) in [("branches", &branch_mesh), ("leaves", &leaf_mesh)] {
        let prims: Vec<_> = mesh(name).primitives().collect();
        assert_eq!(prims.len(), 1, "{name}");
        let p = &prims[0];
        let pos = p.get(&Semantic::Positions).unwrap();
        assert_eq!(pos.count(), expected.positions.len());
        assert_eq!(as_f32s(pos.min()), expected.bounds.min.to_array());
        assert_eq!(as_f32s(pos.max()), expected.bounds.max.to_array());
        assert_eq!(
            p.get(&Semantic::Normals).unwrap().count(),
            expected.positions.len()
        );
        assert_eq!(
            p.get(&Semantic::TexCoords(0)).unwrap().count(),
            expected.positions.len()
        );
        let indices = p.indices().unwrap();
        assert_eq!(indices.count(), expected.indices.len());
        assert_eq!(
            indices.data_type(),
            DataType::U16,
            "{name} has few vertices"
        );
        assert_eq!(p.mode(), gltf::mesh::Mode::Triangles);
    }

    let bark = mesh("branches").primitives().next().unwrap().material();
    assert_eq!(bark.name(), Some("bark"));
    assert_eq!(bark.alpha_mode(), AlphaMode::Opaque);
    let pbr = bark.pbr_metallic_roughness();
    assert_eq!(pbr.roughness_factor(), 0.9);
    assert_eq!(pbr.metallic_factor(), 0.0);
    assert_eq!(pbr.base_color_factor(), tree.materials().bark.color);
    assert!(pbr.base_color_texture().is_some());

    let leaf = mesh("leaves").primitives().next().unwrap().material();
    assert_eq!(leaf.name(), Some("ovate"));
    assert_eq!(leaf.alpha_mode(), AlphaMode::Mask);
    assert_eq!(leaf.alpha_cutoff(), Some(0.5));
    assert!(leaf.double_sided());
    let texture = leaf.pbr_metallic_roughness().base_color_texture().unwrap();
    let Source::View { view, mime_type } = texture.texture().source().source() else {
        panic!("the image is not embedded");
    };
    assert_eq!(mime_type, "image/png");
    let blob = gltf.blob.as_ref().unwrap();
    assert_eq!(
        &blob[view.offset()..view.offset() + view.length()],
        tree.materials().leaves[0].texture.as_ref().unwrap().png()
    );
    assert_eq!(gltf.images().count(), 2);
}

/// The vertex data in the file is the mesher's, byte for byte.
#[test]
fn writes_the_mesher_output() {
    let tree = fork();
    let gltf = Gltf::from_slice(&export(&tree)).unwrap();
    let blob = gltf.blob.as_ref().unwrap();
    let (branches, _) = meshes(&tree, &MeshOptions::default());
    let prim = gltf.meshes().next().unwrap().primitives().next().unwrap();
    let view = prim.get(&Semantic::Positions).unwrap().view().unwrap();
    let floats: Vec<f32> = blob[view.offset()..view.offset() + view.length()]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let expected: Vec<f32> = branches
        .positions
        .iter()
        .flat_map(|p| p.to_array())
        .collect();
    assert_eq!(floats, expected);
    let view = prim.indices().unwrap().view().unwrap();
    let indices: Vec<u32> = blob[view.offset()..view.offset() + view.length()]
        .chunks_exact(2)
        .map(|b| u32::from(u16::from_le_bytes([b[0], b[1]])))
        .collect();
    assert_eq!(indices, branches.indices);
}

#[test]
fn one_leaf_primitive_per_material() {
    let tree = fork();
    let gltf = Gltf::from_slice(&export(&tree)).unwrap();
    assert_layout(&gltf);
    let leaves = gltf.meshes().find(|m| m.name() == Some("leaves")).unwrap();
    let prims: Vec<_> = leaves.primitives().collect();
    assert_eq!(prims.len(), 2);
    let names: Vec<_> = prims
        .iter()
        .map(|p| p.material().name().unwrap().to_owned())
        .collect();
    assert_eq!(names, ["ovate", "plain"]);
    assert_eq!(prims[0].indices().unwrap().count(), 12);
    assert_eq!(prims[1].indices().unwrap().count(), 6);
    assert!(
        prims
            .iter()
            .all(|p| p.material().alpha_mode() == AlphaMode::Mask)
    );
    assert!(
        prims[1]
            .material()
            .pbr_metallic_roughness()
            .base_color_texture()
            .is_none()
    );
    // No bark texture: the bark material has none and one image remains.
    assert_eq!(gltf.images().count(), 1);
    assert_eq!(gltf.materials().count(), 3);
}

#[test]
fn large_meshes_use_u32_indices() {
    let tree = sample::sample_tree(2500);
    let mesh_options = MeshOptions {
        min_sides: 32,
        max_sides: 32,
        ..MeshOptions::default()
    };
    let (branches, leaves) = meshes(&tree, &mesh_options);
    assert!(branches.vertex_count() > 65_535);
    assert!(leaves.vertex_count() <= 65_535);
    let glb = export_glb(&tree, &ExportOptions::default().with_mesh(mesh_options)).unwrap();
    let gltf = Gltf::from_slice(&glb).unwrap();
    assert_layout(&gltf);
    let index_type = |name: &str| {
        let m = gltf.meshes().find(|m| m.name() == Some(name)).unwrap();
        m.primitives()
            .next()
            .unwrap()
            .indices()
            .unwrap()
            .data_type()
    };
    assert_eq!(index_type("branches"), DataType::U32);
    assert_eq!(index_type("leaves"), DataType::U16);
}

#[test]
fn embedded_tree_round_trips_exactly() {
    for tree in [fork(), sample::sample_tree(400)] {
        let glb = export(&tree);
        let back = read_embedded_tree(&glb, &Limits::default()).unwrap();
        assert_eq!(back.as_ref(), Some(&tree));
        let gltf = Gltf::from_slice(&glb).unwrap();
        let extras: Value =
            serde_json::from_str(gltf.as_json().asset.extras.as_ref().unwrap().get()).unwrap();
        assert_eq!(extras["treemorph"]["format"], "treemorph.tree/1");
        assert_eq!(
            extras["treemorph"]["mediaType"],
            "application/vnd.treemorph.tree+json"
        );
    }
}

#[test]
fn files_without_our_extras_read_as_none() {
    let tree = fork();
    let glb = export_glb(&tree, &ExportOptions::default().with_embed_tree(false)).unwrap();
    assert_eq!(read_embedded_tree(&glb, &Limits::default()), Ok(None));
    let gltf = Gltf::from_slice(&glb).unwrap();
    assert!(gltf.as_json().asset.extras.is_none());
    assert_layout(&gltf);
    // Smaller than the file with the tree inside.
    assert!(glb.len() < export(&tree).len());
}

#[test]
fn trees_without_leaves_or_branches_keep_both_nodes() {
    let bare = Tree::new(
        TreeParts {
            nodes: vec![
                node(0.0, 0.0, 0.0, 0.1, None),
                node(0.0, 1.0, 0.0, 0.05, Some(0)),
            ],
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap();
    let gltf = Gltf::from_slice(&export(&bare)).unwrap();
    let nodes: Vec<_> = gltf
        .nodes()
        .map(|n| (n.name().unwrap().to_owned(), n.mesh().is_some()))
        .collect();
    assert_eq!(
        nodes,
        [("branches".to_owned(), true), ("leaves".to_owned(), false)]
    );

    let seed = Tree::new(
        TreeParts {
            nodes: vec![node(0.0, 0.0, 0.0, 0.1, None)],
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap();
    let glb = export_glb(&seed, &ExportOptions::default().with_embed_tree(false)).unwrap();
    let gltf = Gltf::from_slice(&glb).unwrap();
    assert!(gltf.blob.is_none());
    assert_eq!(gltf.nodes().count(), 2);
    assert!(gltf.nodes().all(|n| n.mesh().is_none()));
    let glb = export(&seed);
    assert_eq!(read_embedded_tree(&glb, &Limits::default()), Ok(Some(seed)));
}

#[test]
fn invalid_options_are_the_callers_mistake() {
    let options = ExportOptions::default().with_mesh(MeshOptions {
        min_sides: 2,
        ..MeshOptions::default()
    });
    assert!(matches!(
        export_glb(&fork(), &options),
        Err(ExportError::InvalidOptions(_))
    ));
}

/// Rewrites the JSON chunk of a GLB.
fn with_json(glb: &[u8], edit: impl FnOnce(&mut Value)) -> Vec<u8> {
    let container = Glb::from_slice(glb).unwrap();
    let mut doc: Value = serde_json::from_slice(container.json).unwrap();
    edit(&mut doc);
    let json = serde_json::to_vec(&doc).unwrap();
    Glb {
        json: &json,
        bin: container.bin,
    }
    .to_vec()
    .unwrap()
}

fn entry(doc: &mut Value) -> &mut Value {
    &mut doc["asset"]["extras"]["treemorph"]
}

#[test]
fn hostile_references_are_errors() {
    let glb = export(&fork());
    let limits = Limits::default();
    let read = |bytes: &[u8]| read_embedded_tree(bytes, &limits);
    let bad = |edit: fn(&mut Value)| {
        let r = read(&with_json(&glb, edit));
        assert!(matches!(r, Err(ReadError::BadEmbedding(_))), "{r:?}");
    };
    bad(|d| entry(d)["bufferView"] = json!(999));
    bad(|d| entry(d)["bufferView"] = json!(-1));
    bad(|d| entry(d)["bufferView"] = json!(1.5));
    bad(|d| entry(d)["bufferView"] = json!(u64::MAX));
    bad(|d| *entry(d) = json!("tree.json"));
    bad(|d| entry(d)["mediaType"] = json!("text/plain"));
    bad(|d| {
        entry(d).as_object_mut().unwrap().remove("format");
    });
    bad(|d| {
        let v = entry(d)["bufferView"].as_u64().unwrap() as usize;
        d["bufferViews"][v]["byteLength"] = json!(u64::MAX);
    });
    bad(|d| {
        let v = entry(d)["bufferView"].as_u64().unwrap() as usize;
        d["bufferViews"][v]["byteOffset"] = json!(u64::MAX - 2);
    });
    bad(|d| {
        let v = entry(d)["bufferView"].as_u64().unwrap() as usize;
        d["bufferViews"][v]["byteLength"] = json!(1u64 << 40);
    });
    bad(|d| {
        let v = entry(d)["bufferView"].as_u64().unwrap() as usize;
        d["bufferViews"][v]["buffer"] = json!(1);
    });
    bad(|d| d["buffers"][0]["uri"] = json!("elsewhere.bin"));
    bad(|d| {
        d.as_object_mut().unwrap().remove("bufferViews");
    });

    // A newer format is named as such.
    let r = read(&with_json(&glb, |d| {
        entry(d)["format"] = json!("treemorph.tree/2");
    }));
    assert_eq!(
        r,
        Err(ReadError::Tree(FormatError::UnsupportedFormat {
            found: "treemorph.tree/2".into()
        }))
    );
    // Pointing at the PNG: not a tree document.
    let r = read(&with_json(&glb, |d| entry(d)["bufferView"] = json!(0)));
    assert!(
        matches!(r, Err(ReadError::Tree(FormatError::Syntax { .. }))),
        "{r:?}"
    );
    // The entry moved to the scene's extras is still found.
    let moved = with_json(&glb, |d| {
        let e = d["asset"]["extras"]
            .as_object_mut()
            .unwrap()
            .remove("treemorph")
            .unwrap();
        d["scenes"][0]["extras"] = json!({ "treemorph": e });
    });
    assert_eq!(read(&moved), Ok(Some(fork())));
    // No BIN chunk.
    let container = Glb::from_slice(&glb).unwrap();
    let no_bin = Glb {
        json: container.json,
        bin: None,
    }
    .to_vec()
    .unwrap();
    assert!(matches!(read(&no_bin), Err(ReadError::BadEmbedding(_))));
    // A JSON chunk that is not JSON.
    let garbage = Glb {
        json: b"{\"asset\": ",
        bin: container.bin,
    }
    .to_vec()
    .unwrap();
    assert!(matches!(read(&garbage), Err(ReadError::Json(_))));
    // Tree limits apply to the embedded tree.
    let r = read_embedded_tree(&glb, &Limits::with_sizes(3, 100));
    assert!(
        matches!(r, Err(ReadError::Tree(FormatError::Invalid(_)))),
        "{r:?}"
    );
}

#[test]
fn hostile_containers_are_errors() {
    let glb = export(&fork());
    let read = |bytes: &[u8]| read_embedded_tree(bytes, &Limits::default());
    let mut magic = glb.clone();
    magic[0] = b'G';
    assert_eq!(read(&magic), Err(ReadError::Container(GlbError::NotGlb)));
    for cut in [0, 3, 11, 12, 19, 20, glb.len() / 2, glb.len() - 1] {
        assert!(read(&glb[..cut]).is_err(), "cut at {cut}");
    }
    let mut chunk = glb.clone();
    chunk[12..16].copy_from_slice(&(glb.len() as u32).to_le_bytes());
    assert!(matches!(
        read(&chunk),
        Err(ReadError::Container(GlbError::Malformed(_)))
    ));
    let json_len = u32::from_le_bytes([glb[12], glb[13], glb[14], glb[15]]) as usize;
    let mut bin_chunk = glb.clone();
    bin_chunk[20 + json_len..24 + json_len].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(
        read(&bin_chunk),
        Err(ReadError::Container(GlbError::Malformed(_)))
    ));
}

fn small_glb() -> Vec<u8> {
    let tree = Tree::new(
        TreeParts {
            name: "twig".into(),
            nodes: vec![
                node(0.0, 0.0, 0.0, 0.02, None),
                node(0.0, 0.3, 0.0, 0.01, Some(0)),
            ],
            leaves: vec![Leaf {
                branch: 1,
                t: 0.5,
                offset: Vec3::X * 0.015,
                width: 0.05,
                height: 0.08,
                orientation: Quat::IDENTITY,
                material: 0,
            }],
            materials: Materials {
                leaves: vec![LeafMaterial {
                    name: "plain".into(),
                    color: [0.3, 0.7, 0.2, 1.0],
                    texture: None,
                }],
                ..Materials::default()
            },
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap();
    export(&tree)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Any corruption of a valid GLB gives a result, never a panic.
    #[test]
    fn mutated_glbs_never_panic(
        edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        cut in proptest::option::of(any::<prop::sample::Index>()),
    ) {
        let mut glb = small_glb();
        for (at, byte) in edits {
            let i = at.index(glb.len());
            glb[i] = byte;
        }
        if let Some(cut) = cut {
            glb.truncate(cut.index(glb.len()));
        }
        let _ = read_embedded_tree(&glb, &Limits::default());
        let _ = Glb::from_slice(&glb);
    }

    /// Corrupting only the JSON text (keeping the container valid) reaches
    /// the reference checks rather than stopping at the container.
    #[test]
    fn mutated_json_never_panics(
        edits in proptest::collection::vec((any::<prop::sample::Index>(), b' '..=b'~'), 1..6),
    ) {
        let glb = small_glb();
        let container = Glb::from_slice(&glb).unwrap();
        let mut json = container.json.to_vec();
        for (at, byte) in edits {
            let i = at.index(json.len());
            json[i] = byte;
        }
        let bytes = Glb { json: &json, bin: container.bin }.to_vec().unwrap();
        let _ = read_embedded_tree(&bytes, &Limits::default());
    }
}

/// Timing for the report: `cargo test --release -p treemorph-gltf --lib --
/// --ignored --nocapture export_timing`.
#[test]
#[ignore = "timing; run in release with --nocapture"]
fn export_timing() {
    let tree = sample::sample_tree(20_000);
    let stats = tree.stats();
    let mut best = [f64::MAX; 3];
    let mut size = 0;
    for _ in 0..5 {
        let start = std::time::Instant::now();
        let topology = FrameTopology::of_tree(&tree);
        let frame = Frame::of_tree(&tree);
        let options = MeshOptions::default();
        let mut b = BranchMesher::new(&topology, &frame.radii, &frame, &options).unwrap();
        let mut l = LeafMesher::new(&topology, &options).unwrap();
        b.mesh(&frame).unwrap();
        l.mesh(&frame).unwrap();
        let mesh = start.elapsed().as_secs_f64();
        let start = std::time::Instant::now();
        let glb = export(&tree);
        let export = start.elapsed().as_secs_f64();
        let start = std::time::Instant::now();
        let _ = read_embedded_tree(&glb, &Limits::default()).unwrap();
        let read = start.elapsed().as_secs_f64();
        size = glb.len();
        best = [best[0].min(mesh), best[1].min(export), best[2].min(read)];
    }
    println!(
        "{} branches, {} leaves: mesh {:.1} ms, export_glb (mesh + write) {:.1} ms, \
         read_embedded_tree {:.1} ms, GLB {} bytes",
        stats.branches,
        stats.leaves,
        best[0] * 1e3,
        best[1] * 1e3,
        best[2] * 1e3,
        size
    );
}
