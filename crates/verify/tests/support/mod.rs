//! What the integration tests over third-party trees share: the trees
//! `tools/third-party-trees` writes, imported and analysed, and a sequence
//! of frames meshed and written as the service's runner writes them, each
//! checked on the written buffers.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_gltf::frame_glb::{FrameGlbOptions, FrameGlbWriter};
use treemorph_gltf::frames::max_radii;
use treemorph_import::{ImportOptions, import};
use treemorph_tree::{Frame, FrameTopology, Tree};
use treemorph_verify::{MeshView, Plausibility, PlausibilityOptions, Report};

/// The runner's probes (crates/pipeline/src/runner.rs `PROBES`): the
/// frames whose largest radii size the branch mesh's reference radii.
pub const PROBES: [f32; 5] = [0.0, 0.25, 0.5, 0.75, 1.0];

/// The directory `tools/third-party-trees` wrote, from
/// `TREEMORPH_THIRD_PARTY_DIR`.
pub fn third_party_dir() -> PathBuf {
    PathBuf::from(
        std::env::var("TREEMORPH_THIRD_PARTY_DIR")
            .expect("set TREEMORPH_THIRD_PARTY_DIR to the output of tools/third-party-trees"),
    )
}

/// The GLB files of `dir`, sorted by name.
pub fn glb_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "glb"))
        .collect();
    files.sort();
    files
}

/// Which generator made a tree (Modular Tree's files are named `mt-*`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// npm `@dgreenheck/ez-tree`: loose branch tubes.
    EzTree,
    /// PyPI `modular-tree`: one welded bark mesh.
    ModularTree,
}

impl Family {
    /// The family of the file named `name` (without extension).
    pub fn of(name: &str) -> Family {
        if name.starts_with("mt-") {
            Family::ModularTree
        } else {
            Family::EzTree
        }
    }

    /// The generator's name.
    pub fn name(self) -> &'static str {
        match self {
            Family::EzTree => "ez-tree",
            Family::ModularTree => "modular-tree",
        }
    }
}

/// A third-party tree, imported and analysed.
pub struct Loaded {
    /// File name without extension.
    pub name: String,
    /// Its generator.
    pub family: Family,
    /// The GLB as written by the generator.
    pub bytes: Vec<u8>,
    /// The imported tree.
    pub tree: Tree,
    /// Its analysis with default options.
    pub analysis: Analysis,
}

/// Imports and analyses every GLB of `dir`; panics naming the file when
/// one fails (every tree of the set must import).
pub fn load_all(dir: &Path) -> Vec<Loaded> {
    glb_files(dir)
        .par_iter()
        .map(|path| {
            let name = path.file_stem().unwrap().to_string_lossy().into_owned();
            let bytes = std::fs::read(path).unwrap();
            let tree = import(&bytes, &ImportOptions::default())
                .unwrap_or_else(|e| panic!("{name}: import failed: {e}"))
                .tree;
            let analysis = Analysis::of(&tree, &AnalysisOptions::default())
                .unwrap_or_else(|e| panic!("{name}: analysis failed: {e}"));
            Loaded {
                family: Family::of(&name),
                name,
                bytes,
                tree,
                analysis,
            }
        })
        .collect()
}

/// The `n` frame times of a job of `n` frames: 0, 1/(n−1), …, 1.
pub fn times(n: u32) -> impl Iterator<Item = f32> {
    (0..n).map(move |i| i as f32 / (n.max(2) - 1) as f32)
}

/// A sequence's frames written as the runner writes them: the probes size
/// the branch mesh, then every frame of `n` is evaluated, meshed into a
/// frame GLB and handed to `visit` with the writer's meshes (exactly the
/// geometry of the GLB just written).
pub fn write_frames(
    topology: &FrameTopology,
    n: u32,
    mut eval: impl FnMut(f32, &mut Frame),
    mut visit: impl FnMut(&Frame, MeshView<'_>),
) {
    let mut frame = Frame::default();
    let mut probes = Vec::new();
    for &t in &PROBES {
        eval(t, &mut frame);
        probes.push(frame.clone());
    }
    let radii = max_radii(&probes);
    let mut writer = FrameGlbWriter::new(topology, &radii, &FrameGlbOptions::default()).unwrap();
    let mut out = Vec::new();
    for t in times(n) {
        eval(t, &mut frame);
        writer.write_into(&frame, &mut out).unwrap();
        visit(&frame, MeshView::of_frame_meshes(writer.meshes()));
    }
}

/// The plausibility reports of every frame of a sequence, written as the
/// runner writes them.
pub fn check_frames(
    topology: &FrameTopology,
    n: u32,
    eval: impl FnMut(f32, &mut Frame),
) -> Vec<Report> {
    check_frames_and(topology, n, eval, |_| {})
}

/// [`check_frames`], handing each frame to `also` as well (another
/// measure of the same frames, without evaluating them again).
pub fn check_frames_and(
    topology: &FrameTopology,
    n: u32,
    eval: impl FnMut(f32, &mut Frame),
    mut also: impl FnMut(&Frame),
) -> Vec<Report> {
    let mut check = Plausibility::new();
    let options = PlausibilityOptions::default();
    let mut reports = Vec::new();
    write_frames(topology, n, eval, |frame, view| {
        reports.push(check.check(&view, &options).unwrap());
        also(frame);
    });
    reports
}

/// The largest floating-leaf count, floating-branch count and leaf gap
/// over a sequence's reports.
pub fn max_floating(reports: &[Report]) -> (u32, u32, f32) {
    reports.iter().fold((0, 0, 0.0), |(l, b, g), r| {
        (
            l.max(r.floating_leaves),
            b.max(r.floating_branches),
            g.max(r.worst_leaf_gap),
        )
    })
}
