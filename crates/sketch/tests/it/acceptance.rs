//! The acceptance criteria: every preset grows into the example sketches,
//! connected in every frame; the multiscale method beats the single cage.

use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_generate::Preset;
use treemorph_sketch::{Fit, Method, SketchMetrics, SketchOptions, SketchPlan, Sketcher};
use treemorph_tree::{Limits, Tree};

use crate::{Fixture, example, fixture, make};

/// Plans `sketch` for `preset`, checks 9 frames and returns the final IoU.
fn grow(preset: Preset, sketch: &str, method: Method) -> f32 {
    let f = fixture(preset);
    let file = example(sketch);
    let options = SketchOptions::default()
        .with_fit(file.fit)
        .with_method(method);
    let plan = SketchPlan::new(&f.tree, &f.analysis, &file.view, &file.sketch, &options)
        .unwrap_or_else(|e| panic!("{preset} {sketch}: {e}"));
    let mut sketcher = Sketcher::new(&plan);
    let mut metrics = SketchMetrics::new(&plan);
    let mut frame = sketcher.frame(0.0);
    let mut last = None;
    for i in 0..=8 {
        let t = i as f32 / 8.0;
        sketcher.deform(t, &mut frame);
        frame.check(plan.topology()).unwrap();
        let m = metrics.measure(&frame);
        assert_eq!(
            (m.floating_branches, m.floating_leaves),
            (0, 0),
            "{preset} {sketch} t={t}: floating parts"
        );
        last = Some(m);
    }
    last.unwrap().iou
}

fn check_preset(preset: Preset) {
    for sketch in ["heart", "diamond", "star"] {
        let iou = grow(preset, sketch, Method::Multiscale);
        assert!(iou >= 0.8, "{preset} {sketch}: final IoU {iou} < 0.8");
    }
}

#[test]
fn eucalyptus_grows_into_every_sketch() {
    check_preset(Preset::Eucalyptus);
}

#[test]
fn maple_grows_into_every_sketch() {
    check_preset(Preset::Maple);
}

#[test]
fn conifer_grows_into_every_sketch() {
    check_preset(Preset::Conifer);
}

#[test]
fn willow_grows_into_every_sketch() {
    check_preset(Preset::Willow);
}

#[test]
fn shrub_grows_into_every_sketch() {
    check_preset(Preset::Shrub);
}

#[test]
fn dichotomous_grows_into_every_sketch() {
    check_preset(Preset::Dichotomous);
}

/// The paper's Figure 13: where the branches do not cover the crown (a
/// conifer's whorls stop short of its convex outline, a dome's underside
/// is bare), self-adaptive cages fill the sketch better than one global
/// cage.
#[test]
fn multiscale_beats_the_single_cage_where_branches_leave_gaps() {
    for (preset, sketch) in [(Preset::Conifer, "heart"), (Preset::Dichotomous, "diamond")] {
        let multi = grow(preset, sketch, Method::Multiscale);
        let single = grow(preset, sketch, Method::SingleCage);
        assert!(
            multi > single + 0.03,
            "{preset} {sketch}: multiscale IoU {multi} vs single cage {single}"
        );
    }
}

/// An open oversketch reshapes only the part of the crown it redraws.
#[test]
fn an_oversketch_lifts_the_top_of_the_maple() {
    let f = fixture(Preset::Maple);
    let file = example("oversketch");
    assert_eq!(file.fit, Fit::None);
    let plan = SketchPlan::new(
        &f.tree,
        &f.analysis,
        &file.view,
        &file.sketch,
        &SketchOptions::default(),
    )
    .unwrap();
    // The kept part of the silhouette (its whole bottom) does not move.
    let (s0, s1) = (plan.reference_crown(0.0), plan.reference_crown(1.0));
    let stroke_bottom = file
        .sketch
        .points
        .iter()
        .map(|p| p.y)
        .fold(f32::MAX, f32::min);
    let mut kept = 0;
    for (a, b) in s0.iter().zip(&s1) {
        if a.y < stroke_bottom - 0.05 {
            assert_eq!(a, b);
            kept += 1;
        }
    }
    assert!(kept >= 8, "{kept} samples kept");
    let top0 = s0.iter().map(|p| p.y).fold(f32::MIN, f32::max);
    let top1 = s1.iter().map(|p| p.y).fold(f32::MIN, f32::max);
    assert!(top1 > top0 + 0.2);
    let mut sketcher = Sketcher::new(&plan);
    let frame = sketcher.frame(1.0);
    let m = SketchMetrics::new(&plan).measure(&frame);
    assert!(m.iou >= 0.8, "IoU {}", m.iou);
    assert_eq!((m.floating_branches, m.floating_leaves), (0, 0));
    // The foliage reaches up into the new point.
    let outline = SketchMetrics::new(&plan).outline(&frame);
    let foliage_top = outline.iter().map(|p| p.y).fold(f32::MIN, f32::max);
    assert!(
        foliage_top > top0 + 0.1,
        "foliage top {foliage_top} vs crown top {top0}"
    );
}

/// Regression: the trunk's lower nodes followed the bottom of the crown
/// cage, which the foliage fit pulls down toward the heart's lower tip: a
/// maple's trunk ended 0.25 m below its root and its bole folded into a J.
/// The trunk now bends between its ends only: no node of it ends below
/// the root.
#[test]
fn a_sketched_trunk_stays_above_its_root() {
    let f = fixture(Preset::Maple);
    let file = example("heart");
    let options = SketchOptions::default().with_fit(file.fit);
    let plan = SketchPlan::new(&f.tree, &f.analysis, &file.view, &file.sketch, &options).unwrap();
    let end = Sketcher::new(&plan).frame(1.0);
    let root = end.positions[0].y;
    let trunk = f.analysis.chains().iter().find(|c| c.order == 1).unwrap();
    for &n in &trunk.nodes {
        let y = end.positions[n as usize].y;
        assert!(
            y >= root,
            "trunk node {n} ends {:.3} m below the root",
            root - y
        );
    }
}

/// Regression: the foliage fit corrected the crown cage by the mean value
/// coordinates of outline points in the corrected cage, which stopped
/// saying how the leaves move once the cage had deformed; its passes went
/// back and forth, and on open crowns the dips between leaf clusters stayed
/// inside the sketch (Modular Tree trees sketched into a heart or a leaning
/// crown ended at IoU 0.75–0.79). Crowns thinned to a third and a tenth of
/// their leaves stand in for them here: the conifer reached 0.79, the maple
/// 0.73.
#[test]
fn sparse_crowns_reach_the_sketch() {
    let file = example("heart");
    for (preset, keep) in [(Preset::Conifer, 0.3), (Preset::Maple, 0.1)] {
        let f = thinned(&make(preset, 1, 3_000), keep);
        let options = SketchOptions::default().with_fit(file.fit);
        let plan =
            SketchPlan::new(&f.tree, &f.analysis, &file.view, &file.sketch, &options).unwrap();
        let frame = Sketcher::new(&plan).frame(1.0);
        let iou = SketchMetrics::new(&plan).shape(&frame).iou;
        assert!(
            iou >= 0.8,
            "{preset} with {keep} of its leaves: IoU {iou:.3}"
        );
    }
}

/// `f` with every leaf but an evenly spread `keep` fraction removed.
fn thinned(f: &Fixture, keep: f32) -> Fixture {
    let mut parts = f.tree.clone().into_parts();
    let n = parts.leaves.len();
    let k = (n as f32 * keep) as usize;
    parts.leaves = (0..k).map(|i| parts.leaves[i * n / k]).collect();
    let tree = Tree::new(parts, &Limits::default()).unwrap();
    let analysis = Analysis::of(&tree, &AnalysisOptions::default()).unwrap();
    Fixture { tree, analysis }
}

/// The crescent has a deep concavity: cages folded into it are pruned and
/// their chains wilt to nothing, still attached.
#[test]
fn the_crescent_prunes_and_wilts_chains() {
    let f = fixture(Preset::Eucalyptus);
    let file = example("crescent");
    let options = SketchOptions::default().with_fit(file.fit);
    let plan = SketchPlan::new(&f.tree, &f.analysis, &file.view, &file.sketch, &options).unwrap();
    assert!(plan.cages().iter().any(|c| c.pruned()));
    assert!(plan.wilting_chains().iter().any(|&w| w));
    let mut sketcher = Sketcher::new(&plan);
    // Staged: pruned subtrees wilt over [0, 0.45].
    let mid = sketcher.frame(0.2);
    let end = sketcher.frame(1.0);
    let mut metrics = SketchMetrics::new(&plan);
    for frame in [&mid, &end] {
        let m = metrics.measure(frame);
        assert_eq!((m.floating_branches, m.floating_leaves), (0, 0));
    }
    for (n, &w) in plan.wilting_nodes().iter().enumerate() {
        if w {
            assert_eq!(end.radii[n], 0.0);
            assert!(mid.radii[n] > 0.0 || plan.rest_frame().radii[n] == 0.0);
        }
    }
    for (l, &w) in plan.wilting_leaves().iter().enumerate() {
        if w {
            assert_eq!((end.leaves[l].width, end.leaves[l].height), (0.0, 0.0));
        }
    }
}

/// The lobes deform with their cages: at rest they are the analysis'
/// hulls, at the end their silhouette vertices sit on their cages.
#[test]
fn lobes_follow_their_cages() {
    let f = fixture(Preset::Maple);
    let file = example("heart");
    let options = SketchOptions::default().with_fit(file.fit);
    let plan = SketchPlan::new(&f.tree, &f.analysis, &file.view, &file.sketch, &options).unwrap();
    let mut sketcher = Sketcher::new(&plan);
    let cages = sketcher.deform_cages(1.0);
    {
        let lobes = sketcher.deform_lobes(0.0).unwrap();
        assert_eq!(lobes.len(), plan.cages().len());
        for i in 0..lobes.len() {
            assert_eq!(lobes.vertices(i), lobes.rest_vertices(i));
        }
    }
    let lobes = sketcher.deform_lobes(1.0).unwrap();
    let camera = plan.camera();
    let mut checked = 0;
    for (i, cage) in plan.cages().iter().enumerate().skip(1) {
        // Every cage corner is a lobe vertex that lands on the cage.
        for (k, corner) in cages[i].iter().enumerate() {
            let rest_corner = cage.rest()[k];
            let v = lobes
                .rest_vertices(i)
                .iter()
                .position(|&p| camera.project(p).0.distance(rest_corner) < 1e-5)
                .expect("a cage corner is a lobe vertex");
            let moved = camera.project(lobes.vertices(i)[v]).0;
            assert!(moved.distance(*corner) < 1e-3, "cage {i} corner {k}");
            checked += 1;
        }
        for (a, b) in lobes.vertices(i).iter().zip(lobes.rest_vertices(i)) {
            assert!(a.is_finite());
            // Depth is kept.
            assert!((camera.depth(*a) - camera.depth(*b)).abs() < 1e-3 * camera.depth(*b));
        }
    }
    assert!(checked > 100);
}

/// An open stroke below the top of the crown flattens it: the crown's top
/// is carried down onto the stroke (pruning clips the cages where the
/// deformation puts them, and there they are inside).
#[test]
fn an_inward_oversketch_cuts_the_crown_back() {
    let f = fixture(Preset::Maple);
    let mut file = example("oversketch");
    // From the upper-left shoulder straight across to the upper-right one,
    // well below the top of the crown (≈ 0.40).
    file.sketch.points = (0..=10)
        .map(|i| {
            glam::Vec2::new(
                -0.52 + 1.065 * i as f32 / 10.0,
                0.16 - 0.06 * i as f32 / 10.0,
            )
        })
        .collect();
    let plan = SketchPlan::new(
        &f.tree,
        &f.analysis,
        &file.view,
        &file.sketch,
        &SketchOptions::default(),
    )
    .unwrap();
    let mut sketcher = Sketcher::new(&plan);
    let mut metrics = SketchMetrics::new(&plan);
    for t in [0.5, 1.0] {
        let m = metrics.measure(&sketcher.frame(t));
        assert_eq!((m.floating_branches, m.floating_leaves), (0, 0));
    }
    let m = metrics.measure(&sketcher.frame(1.0));
    assert!(m.iou >= 0.8, "IoU {}", m.iou);
    let outline = metrics.outline(&sketcher.frame(1.0));
    let top = outline.iter().map(|p| p.y).fold(f32::MIN, f32::max);
    assert!(top < 0.3, "the foliage still reaches {top}");
}

/// Any view works: from above, orthographic, sketching a round crown.
#[test]
fn a_top_view_sketch() {
    let f = fixture(Preset::Conifer);
    let view = treemorph_sketch::View::orthographic(
        glam::Vec3::new(0.0, 60.0, 0.0),
        glam::Vec3::ZERO,
        glam::Vec3::Z,
        30.0,
    );
    let sketch = treemorph_sketch::Sketch {
        points: (0..24)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / 24.0;
                glam::Vec2::new(a.cos(), a.sin()) * (0.6 + 0.2 * (3.0 * a).cos())
            })
            .collect(),
        closed: true,
    };
    let options = SketchOptions::default().with_fit(Fit::Crown);
    let plan = SketchPlan::new(&f.tree, &f.analysis, &view, &sketch, &options).unwrap();
    let mut sketcher = Sketcher::new(&plan);
    let mut metrics = SketchMetrics::new(&plan);
    let m = metrics.measure(&sketcher.frame(1.0));
    assert_eq!((m.floating_branches, m.floating_leaves), (0, 0));
    assert!(m.iou >= 0.7, "IoU {}", m.iou);
}

/// The foliage fit keeps the crown displacement whose final foliage fits
/// the sketch best, so it never fits worse than the paper's mapping alone —
/// not even for a crescent, whose deep concavity its convex envelope
/// matches poorly.
#[test]
fn the_foliage_fit_never_fits_worse() {
    let f = fixture(Preset::Maple);
    for sketch in ["heart", "crescent"] {
        let file = example(sketch);
        let iou = |passes: u32| {
            let mut options = SketchOptions::default().with_fit(file.fit);
            options.foliage_passes = passes;
            let plan =
                SketchPlan::new(&f.tree, &f.analysis, &file.view, &file.sketch, &options).unwrap();
            let frame = Sketcher::new(&plan).frame(1.0);
            SketchMetrics::new(&plan).shape(&frame).iou
        };
        let (paper, fitted) = (iou(0), iou(2));
        assert!(fitted >= paper, "{sketch}: {fitted} < {paper}");
    }
}
