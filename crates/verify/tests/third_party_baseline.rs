//! Baseline of the plausibility check on third-party trees (ez-tree and
//! Modular Tree, written by `tools/third-party-trees`): each tree's
//! original GLB, frame 0 of the imported tree, and every frame of a morph
//! to a tree of the other family and of a sketch into a cone, meshed and
//! written through [`FrameGlbWriter`] as the service's runner does (reference
//! radii from the same probes), checked in-process on the written buffers.
//! Prints a table and, for frame 0, where the imported leaves sit relative
//! to their branch (anchor offset against the branch radius).
//!
//! ```sh
//! npm ci --prefix tools/third-party-trees
//! node tools/third-party-trees/generate.mjs target/third-party
//! python3 -m venv target/third-party-venv
//! target/third-party-venv/bin/pip install -r tools/third-party-trees/requirements.txt
//! target/third-party-venv/bin/python tools/third-party-trees/modular_tree.py target/third-party
//! TREEMORPH_THIRD_PARTY_DIR=$PWD/target/third-party \
//!     cargo test --release -p treemorph-verify --test third_party_baseline -- --ignored --nocapture
//! ```

use std::path::PathBuf;
use std::time::Instant;

use glam::Vec2;
use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_gltf::frame_glb::{FrameGlbOptions, FrameGlbWriter};
use treemorph_gltf::frames::max_radii;
use treemorph_import::{ImportOptions, import};
use treemorph_morph::{MorphOptions, MorphPlan, Morpher};
use treemorph_sketch::{Fit, Sketch, SketchOptions, SketchPlan, Sketcher, View};
use treemorph_tree::{Frame, FrameTopology, Tree};
use treemorph_verify::{MeshView, Plausibility, PlausibilityOptions, Report, read_glb};

/// The runner's probes (src/pipeline/runner.rs `PROBES`).
const PROBES: [f32; 5] = [0.0, 0.25, 0.5, 0.75, 1.0];
const FRAMES: u32 = 9;

struct Loaded {
    name: String,
    family: &'static str,
    tree: Tree,
    analysis: Analysis,
    original: Report,
}

/// Writes every frame of a sequence as the runner does and checks each;
/// returns the per-frame reports and the mean check time.
fn run(topology: &FrameTopology, mut eval: impl FnMut(f32, &mut Frame)) -> (Vec<Report>, f64) {
    let mut frame = Frame::default();
    let mut probes = Vec::new();
    for &t in &PROBES {
        eval(t, &mut frame);
        probes.push(frame.clone());
    }
    let radii = max_radii(&probes);
    let mut writer = FrameGlbWriter::new(topology, &radii, &FrameGlbOptions::default()).unwrap();
    let mut check = Plausibility::new();
    let options = PlausibilityOptions::default();
    let mut out = Vec::new();
    let mut reports = Vec::new();
    let mut seconds = 0.0;
    for i in 0..FRAMES {
        let t = i as f32 / (FRAMES - 1) as f32;
        eval(t, &mut frame);
        writer.write_into(&frame, &mut out).unwrap();
        let started = Instant::now();
        let r = check
            .check(&MeshView::of_frame_meshes(writer.meshes()), &options)
            .unwrap();
        let dt = started.elapsed().as_secs_f64();
        seconds += dt;
        eprintln!(
            "  check t={t:.3}: {:.2} ms, {} branch triangles, {} leaves, {} floating",
            dt * 1e3,
            writer.meshes().branches().buffers().triangle_count(),
            r.leaves,
            r.floating_leaves
        );
        reports.push(r);
    }
    (reports, seconds / FRAMES as f64)
}

fn max_floating(reports: &[Report]) -> (u32, u32, f32) {
    reports.iter().fold((0, 0, 0.0), |(l, b, g), r| {
        (
            l.max(r.floating_leaves),
            b.max(r.floating_branches),
            g.max(r.worst_leaf_gap),
        )
    })
}

/// Where floating leaves of frame 0 sit relative to their branch: the
/// anchor's distance from the branch axis point, over the branch radius.
fn leaf_evidence(tree: &Tree, report: &Report) -> String {
    let sk = tree.skeleton();
    let mut ratios: Vec<f32> = report
        .floating
        .iter()
        .map(|f| {
            let leaf = &tree.leaves()[f.leaf as usize];
            let (_, r) = sk.point_on_branch(leaf.branch, leaf.t);
            leaf.offset.length() / r.max(1e-6)
        })
        .collect();
    if ratios.is_empty() {
        return String::new();
    }
    ratios.sort_by(f32::total_cmp);
    let q = |p: f32| ratios[((ratios.len() - 1) as f32 * p) as usize];
    let worst = report
        .floating
        .iter()
        .max_by(|a, b| a.gap.total_cmp(&b.gap))
        .unwrap();
    let leaf = &tree.leaves()[worst.leaf as usize];
    let (p, r) = sk.point_on_branch(leaf.branch, leaf.t);
    format!(
        "offset/radius of floating leaves: median {:.2}, p90 {:.2}, max {:.2}; worst leaf {} gap {:.3} m \
         (allowed {:.3}): branch node {} t {:.2} axis point {:?} radius {:.4}, offset {:.3} m, size {:.3}x{:.3}",
        q(0.5),
        q(0.9),
        q(1.0),
        worst.leaf,
        worst.gap,
        worst.allowed,
        leaf.branch,
        leaf.t,
        p,
        r,
        leaf.offset.length(),
        leaf.width,
        leaf.height
    )
}

#[test]
#[ignore = "needs TREEMORPH_THIRD_PARTY_DIR written by tools/third-party-trees"]
fn third_party_baseline() {
    let dir = PathBuf::from(
        std::env::var("TREEMORPH_THIRD_PARTY_DIR")
            .expect("set TREEMORPH_THIRD_PARTY_DIR to the output of tools/third-party-trees"),
    );
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "glb"))
        .collect();
    files.sort();
    let options = PlausibilityOptions::default();
    let mut trees = Vec::new();
    for path in &files {
        let name = path.file_stem().unwrap().to_string_lossy().into_owned();
        let bytes = std::fs::read(path).unwrap();
        let family = if name.starts_with("mt-") {
            "modular-tree"
        } else {
            "ez-tree"
        };
        let original = Plausibility::of(&read_glb(&bytes).unwrap().view(), &options).unwrap();
        let imported = match import(&bytes, &ImportOptions::default()) {
            Ok(i) => i,
            Err(e) => {
                eprintln!("{name}: import failed: {e}");
                continue;
            }
        };
        let tree = imported.tree;
        let analysis = Analysis::of(&tree, &AnalysisOptions::default()).unwrap();
        trees.push(Loaded {
            name,
            family,
            tree,
            analysis,
            original,
        });
    }
    eprintln!(
        "| tree | family | branches | leaves | original GLB fl/fb | frame 0 fl (gap) / fb | morph → | morph max fl / fb (gap) | sketch max fl / fb (gap) | check ms/frame |"
    );
    eprintln!("|---|---|---|---|---|---|---|---|---|---|");
    let ez: Vec<usize> = (0..trees.len())
        .filter(|&i| trees[i].family == "ez-tree")
        .collect();
    let mt: Vec<usize> = (0..trees.len())
        .filter(|&i| trees[i].family != "ez-tree")
        .collect();
    let mut evidence = Vec::new();
    for (k, s) in trees.iter().enumerate() {
        // Frame 0 of the imported tree, as written.
        let topology = FrameTopology::of_tree(&s.tree);
        let (zero, _) = run(&topology, |t, f| {
            *f = Frame::of_tree(&s.tree);
            f.t = t;
        });
        let zero = &zero[0];
        evidence.push(format!("{}: {}", s.name, leaf_evidence(&s.tree, zero)));
        // Morph to a tree of the other family.
        let others = if s.family == "ez-tree" { &mt } else { &ez };
        let target = &trees[others[k % others.len().max(1)]];
        let plan = MorphPlan::new(
            &s.tree,
            &s.analysis,
            &target.tree,
            &target.analysis,
            &MorphOptions::default(),
        );
        let (morph, morph_ms) = match plan {
            Ok(plan) => {
                let mut morpher = Morpher::new(&plan);
                let (r, secs) = run(plan.topology(), |t, f| morpher.morph(t, f));
                (Some(r), secs * 1e3)
            }
            Err(e) => {
                eprintln!("{}: morph plan failed: {e}", s.name);
                (None, 0.0)
            }
        };
        // Sketch into a cone, front view.
        let height = s.tree.stats().height;
        let view = View::front(height);
        let cone = Sketch {
            points: vec![
                Vec2::new(-0.45, -0.3),
                Vec2::new(0.45, -0.3),
                Vec2::new(0.0, 0.75),
            ],
            closed: true,
        };
        let sketch = SketchPlan::new(
            &s.tree,
            &s.analysis,
            &view,
            &cone,
            &SketchOptions::default().with_fit(Fit::Crown),
        );
        let sketch = match sketch {
            Ok(plan) => {
                let mut sketcher = Sketcher::new(&plan);
                Some(run(plan.topology(), |t, f| sketcher.deform(t, f)).0)
            }
            Err(e) => {
                eprintln!("{}: sketch plan failed: {e}", s.name);
                None
            }
        };
        let fmt = |r: &Option<Vec<Report>>| match r {
            Some(r) => {
                let (l, b, g) = max_floating(r);
                format!("{} / {} ({:.3} m)", l, b, g)
            }
            None => "—".into(),
        };
        eprintln!(
            "| {} | {} | {} | {} | {} / {} | {} ({:.3} m) / {} | {} | {} | {} | {:.2} |",
            s.name,
            s.family,
            s.tree.skeleton().len() - 1,
            s.tree.leaves().len(),
            s.original.floating_leaves,
            s.original.floating_branches,
            zero.floating_leaves,
            zero.worst_leaf_gap,
            zero.floating_branches,
            target.name,
            fmt(&morph),
            fmt(&sketch),
            morph_ms
        );
        if let Some(m) = &morph {
            let per: Vec<String> = m
                .iter()
                .map(|r| format!("{}/{}", r.floating_leaves, r.floating_branches))
                .collect();
            evidence.push(format!(
                "{} morph per frame fl/fb: {}",
                s.name,
                per.join(" ")
            ));
        }
        if let Some(m) = &sketch {
            let per: Vec<String> = m
                .iter()
                .map(|r| format!("{}/{}", r.floating_leaves, r.floating_branches))
                .collect();
            evidence.push(format!(
                "{} sketch per frame fl/fb: {}",
                s.name,
                per.join(" ")
            ));
        }
    }
    for e in evidence {
        eprintln!("{e}");
    }
}
