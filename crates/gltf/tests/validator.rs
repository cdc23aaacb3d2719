//! Runs the Khronos glTF validator on GLBs this crate writes: static
//! exports, per-frame GLBs (contour and quad leaves, blended textures) and
//! animated GLBs (float, `KHR_mesh_quantization`, and
//! `EXT_meshopt_compression`, which the validator only checks structurally
//! — the crate's unit tests decode it).
//!
//! Needs Node.js and the validator installed:
//! `npm ci --prefix tools/gltf-validate`, then
//! `cargo test -p treemorph-gltf --test validator -- --ignored`.
//! Set `TREEMORPH_GLB_DIR` to keep the files somewhere else than the target
//! directory.

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::{Quat, Vec3};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_gltf::animated::{AnimatedEncoding, AnimatedGlbBuilder, AnimatedOptions};
use treemorph_gltf::basis::{AnimationKind, BasisGlbBuilder};
use treemorph_gltf::bench::Sway;
use treemorph_gltf::frame_glb::{FrameGlbOptions, FrameGlbWriter};
use treemorph_gltf::mesh::MeshOptions;
use treemorph_gltf::sample::{leaf_texture, sample_tree};
use treemorph_gltf::{ExportOptions, export_glb};
use treemorph_tree::{Leaf, LeafMaterial, Limits, Materials, Node, Tree, TreeParts};

fn node(x: f32, y: f32, radius: f32, parent: Option<u32>) -> Node {
    Node {
        position: Vec3::new(x, y, 0.0),
        radius,
        parent,
    }
}

/// Two leaf materials, one without a texture; no bark texture.
fn two_materials() -> Tree {
    let leaf = |branch: u32, material: u32| Leaf {
        branch,
        t: 0.5,
        offset: Vec3::Z * 0.03,
        width: 0.1,
        height: 0.15,
        orientation: Quat::from_rotation_x(0.5),
        material,
    };
    Tree::new(
        TreeParts {
            name: "two materials".into(),
            nodes: vec![
                node(0.0, 0.0, 0.1, None),
                node(0.0, 1.0, 0.08, Some(0)),
                node(0.5, 1.6, 0.04, Some(1)),
                node(-0.1, 2.0, 0.05, Some(1)),
            ],
            leaves: vec![leaf(2, 0), leaf(3, 1), leaf(3, 0)],
            materials: Materials {
                leaves: vec![
                    LeafMaterial {
                        name: "ovate".into(),
                        color: [1.0; 4],
                        texture: Some(leaf_texture()),
                    },
                    LeafMaterial {
                        name: "plain".into(),
                        color: [0.2, 0.6, 0.1, 1.0],
                        texture: None,
                    },
                ],
                ..Materials::default()
            },
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap()
}

fn bare() -> Tree {
    Tree::new(
        TreeParts {
            nodes: vec![node(0.0, 0.0, 0.1, None), node(0.0, 1.0, 0.05, Some(0))],
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap()
}

fn write_samples(dir: &Path) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    let wide = ExportOptions::default().with_mesh(MeshOptions::default().with_sides(32, 32));
    let cases = [
        (
            "sample-2000.glb",
            sample_tree(2000),
            ExportOptions::default(),
        ),
        (
            "sample-2000-plain.glb",
            sample_tree(2000),
            ExportOptions::default().with_embed_tree(false),
        ),
        ("sample-u32-indices.glb", sample_tree(2500), wide),
        (
            "two-materials.glb",
            two_materials(),
            ExportOptions::default(),
        ),
        ("no-leaves.glb", bare(), ExportOptions::default()),
    ];
    let generated = Preset::ALL.iter().map(|&preset| {
        let tree = generate(&GenerateOptions::new(preset, 1)).unwrap();
        let name: &'static str = format!("generated-{preset:?}.glb").leak();
        (name, tree, ExportOptions::default())
    });
    let mut files: Vec<PathBuf> = cases
        .into_iter()
        .chain(generated)
        .map(|(name, tree, options)| {
            let path = dir.join(name);
            std::fs::write(&path, export_glb(&tree, &options).unwrap()).unwrap();
            path
        })
        .collect();
    files.extend(write_frame_samples(dir));
    files
}

/// Per-frame and animated GLBs of a swaying maple whose leaves fade
/// between its two leaf materials.
fn write_frame_samples(dir: &Path) -> Vec<PathBuf> {
    let tree = generate(&GenerateOptions::new(Preset::Maple, 1).with_size(1500)).unwrap();
    let sway = Sway::new(&tree, 6);
    let (topology, radii) = (sway.topology(), sway.reference_radii());
    let mut files = Vec::new();
    let mut write = |name: &str, bytes: Vec<u8>| {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        files.push(path);
    };
    let quads = FrameGlbOptions::default().with_mesh(MeshOptions::default());
    for (label, options) in [("contour", FrameGlbOptions::default()), ("quad", quads)] {
        let mut writer = FrameGlbWriter::new(topology, radii, &options).unwrap();
        for i in [0, 3, 5] {
            write(
                &format!("frame-{label}-{i}.glb"),
                writer.write(&sway.frame(i)).unwrap(),
            );
        }
    }
    for encoding in [
        AnimatedEncoding::Float,
        AnimatedEncoding::Quantized,
        AnimatedEncoding::Meshopt,
    ] {
        let options = AnimatedOptions::default().with_encoding(encoding);
        let keyframes = AnimationKind::Keyframes
            .default_options()
            .with_encoding(encoding);
        let mut builder =
            AnimatedGlbBuilder::new(topology, radii, sway.bounds(), &keyframes).unwrap();
        for i in 0..sway.len() {
            builder.push(&sway.frame(i)).unwrap();
        }
        write(
            &format!("animated-{encoding:?}.glb").to_lowercase(),
            builder.finish().unwrap(),
        );
        let mut basis = BasisGlbBuilder::new(topology, radii, sway.bounds(), &options).unwrap();
        for i in 0..sway.len() {
            basis.push(&sway.frame(i)).unwrap();
        }
        write(
            &format!("basis-{encoding:?}.glb").to_lowercase(),
            basis.finish().unwrap().0,
        );
    }
    files
}

#[test]
#[ignore = "needs node and `npm ci --prefix tools/gltf-validate`"]
fn written_glbs_pass_the_khronos_validator() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let tool = root.join("tools/gltf-validate");
    assert!(
        tool.join("node_modules/gltf-validator").exists(),
        "run `npm ci --prefix tools/gltf-validate` first"
    );
    let dir = std::env::var_os("TREEMORPH_GLB_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_TARGET_TMPDIR")).join("gltf-validate"));
    let files = write_samples(&dir);
    let output = Command::new("node")
        .arg(tool.join("validate.mjs"))
        .args(&files)
        .output()
        .expect("node runs");
    let report = String::from_utf8_lossy(&output.stdout);
    println!("{report}{}", String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success(), "the validator found errors");
    let lines: Vec<&str> = report.lines().filter(|l| l.contains(" errors, ")).collect();
    assert_eq!(lines.len(), files.len());
    for line in lines {
        assert!(line.contains(": 0 errors, 0 warnings"), "{line}");
    }
}
