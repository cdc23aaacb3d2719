//! Invariants over random sketches, trees and times (proptest).

use std::sync::OnceLock;

use glam::Vec2;
use proptest::prelude::*;
use treemorph_generate::Preset;
use treemorph_sketch::{
    Fit, Method, Sketch, SketchMetrics, SketchOptions, SketchPlan, Sketcher, View,
};
use treemorph_tree::Frame;

use crate::{Fixture, make};

/// Small trees of every preset (400 branches), made once.
fn small(i: usize) -> &'static Fixture {
    static CACHE: OnceLock<Vec<Fixture>> = OnceLock::new();
    &CACHE.get_or_init(|| Preset::ALL.iter().map(|&p| make(p, 3, 400)).collect())[i]
}

/// A random closed sketch: a star-shaped polygon (never self-intersecting),
/// fitted to the crown.
fn sketches() -> impl Strategy<Value = Sketch> {
    (5usize..14, any::<u64>()).prop_flat_map(|(n, _)| {
        (
            prop::collection::vec(0.35f32..1.0, n),
            prop::collection::vec(-0.3f32..0.3, n),
        )
            .prop_map(move |(radii, jitter)| {
                let points = radii
                    .iter()
                    .zip(&jitter)
                    .enumerate()
                    .map(|(k, (&r, &j))| {
                        let a = (k as f32 + j) * std::f32::consts::TAU / n as f32;
                        Vec2::new(a.cos(), a.sin()) * r * 0.9
                    })
                    .collect();
                Sketch {
                    points,
                    closed: true,
                }
            })
    })
}

fn view_of(f: &Fixture) -> View {
    View::front(f.tree.stats().height)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    #[test]
    fn frames_are_valid_connected_and_keep_their_depth(
        tree in 0usize..Preset::ALL.len(),
        sketch in sketches(),
        times in prop::collection::vec(0.0f32..=1.0, 1..4),
        single in any::<bool>(),
        ortho in any::<bool>(),
    ) {
        let f = small(tree);
        let mut view = view_of(f);
        if ortho {
            view.fov_deg = None;
            view.ortho_height = Some(1.3 * f.tree.stats().height);
        }
        let method = if single { Method::SingleCage } else { Method::Multiscale };
        let options = SketchOptions::default().with_fit(Fit::Crown).with_method(method);
        let plan = SketchPlan::new(&f.tree, &f.analysis, &view, &sketch, &options).unwrap();
        let mut sketcher = Sketcher::new(&plan);
        let mut metrics = SketchMetrics::new(&plan);
        // t = 0 is the input tree, bit for bit.
        let rest = Frame::of_tree(&f.tree);
        prop_assert_eq!(&sketcher.frame(0.0), &rest);
        let mut frame = sketcher.frame(0.0);
        for &t in &times {
            sketcher.deform(t, &mut frame);
            prop_assert_eq!(frame.t, t);
            prop_assert!(frame.check(plan.topology()).is_ok());
            prop_assert_eq!(frame.positions.len(), rest.positions.len());
            prop_assert_eq!(frame.leaves.len(), rest.leaves.len());
            // The crown keeps a plausible depth: its depth scales with its
            // width (the depth module), so seen from the side it is neither
            // a slab nor a wall.
            let (before, after) = (metrics.crown_depth_width(&rest), metrics.crown_depth_width(&frame));
            prop_assert!(after >= before / 3.0 && after <= before * 3.0, "depth/width {} → {}", before, after);
            let m = metrics.measure(&frame);
            prop_assert_eq!((m.floating_branches, m.floating_leaves), (0, 0));
            prop_assert!(m.iou.is_finite() && m.frechet.is_finite());
        }
    }

    #[test]
    fn out_of_range_times_are_clamped(t in prop::num::f32::ANY) {
        let f = small(1);
        let sketch = Sketch {
            points: vec![Vec2::new(-0.8, -0.8), Vec2::new(0.8, -0.8), Vec2::new(0.0, 0.8)],
            closed: true,
        };
        let options = SketchOptions::default().with_fit(Fit::Crown);
        let plan = SketchPlan::new(&f.tree, &f.analysis, &view_of(f), &sketch, &options).unwrap();
        let mut sketcher = Sketcher::new(&plan);
        let frame = sketcher.frame(t);
        prop_assert!(frame.check(plan.topology()).is_ok());
        prop_assert!((0.0..=1.0).contains(&frame.t));
    }
}

/// Regression: the chain solve stretched one segment of a chain to many
/// times its length and squeezed its neighbour (up to 33,000 % on trees
/// from other tools; 258 %, 109 % and 78 % on these sketches after the
/// first fix, which evened segments out only between joints). Every chain
/// is now re-solved with its rest segment lengths times its growth, so
/// on every frame no segment stretches more than 15 % beyond the growth
/// the sketch asks of its chain, and that growth is reported.
#[test]
fn segments_between_joints_stretch_alike() {
    for (i, name) in [(0, "heart"), (3, "diamond"), (1, "crescent")] {
        let f = small(i);
        let file = crate::example(name);
        let options = SketchOptions::default().with_fit(file.fit);
        let plan =
            SketchPlan::new(&f.tree, &f.analysis, &file.view, &file.sketch, &options).unwrap();
        let mut sketcher = Sketcher::new(&plan);
        let metrics = SketchMetrics::new(&plan);
        for t in [0.25, 0.5, 0.75, 1.0] {
            let frame = sketcher.frame(t);
            let stretch = metrics.stretch(&frame);
            assert!(
                stretch <= 0.15,
                "{name} at t = {t}: a segment stretched by {stretch} beyond its chain's growth"
            );
            let growth = metrics.growth(&frame);
            assert!(
                growth.is_finite() && growth < 7.0,
                "{name} at t = {t}: growth {growth}"
            );
        }
    }
}

/// Regression: the deformation moved nodes in the view plane only, so a
/// crown squeezed into a column kept its whole depth and one widened kept
/// it too (depth/width 1.01 → 1.88 and 0.95 → 0.62 on trees from other
/// tools). The crown's depth now follows its width: seen from the side it
/// keeps roughly its rest proportions.
#[test]
fn a_squeezed_or_widened_crown_keeps_its_depth_proportions() {
    for i in 0..Preset::ALL.len() {
        let f = small(i);
        let view = view_of(f);
        let probe = SketchPlan::new(
            &f.tree,
            &f.analysis,
            &view,
            &crate::example("diamond").sketch,
            &SketchOptions::default().with_fit(Fit::Crown),
        )
        .unwrap();
        let (lo, hi) = probe.crown_silhouette().iter().fold(
            (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        );
        let centre = 0.5 * (lo.x + hi.x);
        for widen in [0.5f32, 1.3] {
            let half = (0.5 * (hi.x - lo.x) * widen).min(1.05 - centre.abs());
            let sketch = Sketch {
                points: vec![
                    Vec2::new(centre - half, lo.y),
                    Vec2::new(centre + half, lo.y),
                    Vec2::new(centre + half, hi.y),
                    Vec2::new(centre - half, hi.y),
                ],
                closed: true,
            };
            let plan = SketchPlan::new(
                &f.tree,
                &f.analysis,
                &view,
                &sketch,
                &SketchOptions::default(),
            )
            .unwrap();
            let metrics = SketchMetrics::new(&plan);
            let before = metrics.crown_depth_width(plan.rest_frame());
            let after = metrics.crown_depth_width(&Sketcher::new(&plan).frame(1.0));
            assert!(
                (0.7..=1.43).contains(&(after / before)),
                "{:?} ×{widen}: depth/width {before} → {after}",
                Preset::ALL[i]
            );
        }
    }
}
