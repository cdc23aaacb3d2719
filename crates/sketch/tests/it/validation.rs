//! Every way a caller can get it wrong, each with its own error.

use glam::{Vec2, Vec3};
use treemorph_generate::Preset;
use treemorph_sketch::{Fit, Sketch, SketchEnd, SketchError, SketchOptions, SketchPlan, View};
use treemorph_tree::{Limits, Node, Tree, TreeParts};

use crate::{example, fixture, make};

fn triangle() -> Sketch {
    Sketch {
        points: vec![
            Vec2::new(-0.5, -0.3),
            Vec2::new(0.5, -0.3),
            Vec2::new(0.0, 0.6),
        ],
        closed: true,
    }
}

fn plan(view: &View, sketch: &Sketch, options: &SketchOptions) -> Result<SketchPlan, SketchError> {
    let f = fixture(Preset::Maple);
    SketchPlan::new(&f.tree, &f.analysis, view, sketch, options)
}

fn view() -> View {
    example("oversketch").view
}

#[test]
fn sketch_shape_errors() {
    let o = SketchOptions::default();
    let two = Sketch {
        points: vec![Vec2::ZERO, Vec2::X * 0.5],
        closed: true,
    };
    assert_eq!(
        plan(&view(), &two, &o).unwrap_err(),
        SketchError::TooFewPoints { count: 2 }
    );
    let mut bowtie = triangle();
    bowtie.points = vec![
        Vec2::new(-0.5, -0.5),
        Vec2::new(0.5, 0.5),
        Vec2::new(0.5, -0.5),
        Vec2::new(-0.5, 0.5),
    ];
    assert_eq!(
        plan(&view(), &bowtie, &o).unwrap_err(),
        SketchError::SelfIntersecting {
            first: 0,
            second: 2
        }
    );
    let mut nan = triangle();
    nan.points[2].y = f32::NAN;
    assert_eq!(
        plan(&view(), &nan, &o).unwrap_err(),
        SketchError::NonFinite {
            what: "sketch point 2".into()
        }
    );
    let mut inf = triangle();
    inf.points[0].x = f32::NEG_INFINITY;
    assert_eq!(
        plan(&view(), &inf, &o).unwrap_err(),
        SketchError::NonFinite {
            what: "sketch point 0".into()
        }
    );
    let mut far = triangle();
    far.points[1] = Vec2::new(3.0, 0.0);
    assert_eq!(
        plan(&view(), &far, &o).unwrap_err(),
        SketchError::PointOutOfRange {
            index: 1,
            x: 3.0,
            y: 0.0,
            limit: 1.1
        }
    );
    let mut open_fit = triangle();
    open_fit.closed = false;
    assert_eq!(
        plan(&view(), &open_fit, &o.clone().with_fit(Fit::Crown)).unwrap_err(),
        SketchError::FitNeedsClosedSketch
    );
}

#[test]
fn view_errors() {
    let o = SketchOptions::default();
    let mut v = view();
    v.target = v.eye;
    assert_eq!(
        plan(&v, &triangle(), &o).unwrap_err(),
        SketchError::EyeAtTarget
    );
    let mut v = view();
    v.up = v.target - v.eye;
    assert_eq!(
        plan(&v, &triangle(), &o).unwrap_err(),
        SketchError::UpParallelToView
    );
    for fov in [0.0, 180.0] {
        let mut v = view();
        v.fov_deg = Some(fov);
        assert_eq!(
            plan(&v, &triangle(), &o).unwrap_err(),
            SketchError::FovOutOfRange { fov_deg: fov }
        );
    }
    let mut v = view();
    v.ortho_height = Some(20.0);
    assert_eq!(
        plan(&v, &triangle(), &o).unwrap_err(),
        SketchError::AmbiguousProjection
    );
    let mut v = view();
    v.fov_deg = None;
    assert_eq!(
        plan(&v, &triangle(), &o).unwrap_err(),
        SketchError::MissingProjection
    );
    let mut v = view();
    v.eye.y = f32::INFINITY;
    assert_eq!(
        plan(&v, &triangle(), &o).unwrap_err(),
        SketchError::NonFinite {
            what: "view.eye".into()
        }
    );
}

#[test]
fn sketches_that_miss_the_crown() {
    let o = SketchOptions::default();
    // A closed sketch in a corner of the screen, far from the crown.
    let corner = Sketch {
        points: vec![
            Vec2::new(0.8, 0.8),
            Vec2::new(1.0, 0.8),
            Vec2::new(0.9, 1.0),
        ],
        closed: true,
    };
    assert_eq!(
        plan(&view(), &corner, &o).unwrap_err(),
        SketchError::SketchMissesCrown
    );
    // The same sketch fitted to the crown is fine.
    assert!(plan(&view(), &corner, &o.clone().with_fit(Fit::Crown)).is_ok());
    // An open stroke whose first point is far above the crown.
    let mut stroke = example("oversketch").sketch;
    stroke.points[0] = Vec2::new(-0.5, 0.95);
    assert!(matches!(
        plan(&view(), &stroke, &o).unwrap_err(),
        SketchError::OpenSketchTooFar {
            end: SketchEnd::Start,
            ..
        }
    ));
    let mut stroke = example("oversketch").sketch;
    let last = stroke.points.len() - 1;
    stroke.points[last] = Vec2::new(0.9, -0.95);
    assert!(matches!(
        plan(&view(), &stroke, &o).unwrap_err(),
        SketchError::OpenSketchTooFar {
            end: SketchEnd::End,
            ..
        }
    ));
}

#[test]
fn cameras_inside_the_crown_or_facing_away() {
    let o = SketchOptions::default().with_fit(Fit::Crown);
    let f = fixture(Preset::Maple);
    let crown = &f.analysis.crown();
    let mut v = view();
    v.eye = crown.center;
    v.target = crown.center + Vec3::Z;
    assert_eq!(
        plan(&v, &triangle(), &o).unwrap_err(),
        SketchError::CameraInsideCrown
    );
    // Looking away from the tree: everything is behind the camera.
    let mut v = view();
    v.target = v.eye + Vec3::Z;
    assert!(matches!(
        plan(&v, &triangle(), &o).unwrap_err(),
        SketchError::BehindCamera { .. }
    ));
    // An orthographic camera has no "behind".
    let mut v = view();
    v.fov_deg = None;
    v.ortho_height = Some(20.0);
    assert!(plan(&v, &triangle(), &o).is_ok());
}

#[test]
fn trees_without_leaves_have_no_crown() {
    let node = |y: f32, parent: Option<u32>| Node {
        position: Vec3::new(0.0, y, 0.0),
        radius: 0.1,
        parent,
    };
    let tree = Tree::new(
        TreeParts {
            nodes: vec![node(0.0, None), node(1.0, Some(0)), node(2.0, Some(1))],
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap();
    let analysis =
        treemorph_analysis::Analysis::of(&tree, &treemorph_analysis::AnalysisOptions::default())
            .unwrap();
    let err = SketchPlan::new(
        &tree,
        &analysis,
        &View::front(2.0),
        &triangle(),
        &SketchOptions::default(),
    )
    .unwrap_err();
    assert_eq!(err, SketchError::NoCrown);
}

#[test]
fn an_analysis_of_another_tree_is_refused() {
    let other = make(Preset::Shrub, 5, 300);
    let f = fixture(Preset::Maple);
    let err = SketchPlan::new(
        &f.tree,
        &other.analysis,
        &view(),
        &triangle(),
        &SketchOptions::default().with_fit(Fit::Crown),
    )
    .unwrap_err();
    assert!(matches!(err, SketchError::AnalysisMismatch(_)));
}

#[test]
fn options_are_checked() {
    let mut o = SketchOptions::default();
    o.prune_ratio = f32::NAN;
    assert!(matches!(
        plan(&view(), &triangle(), &o).unwrap_err(),
        SketchError::InvalidOption {
            option: "prune_ratio",
            ..
        }
    ));
    let mut o = SketchOptions::default();
    o.crown_samples = 3;
    assert!(matches!(
        plan(&view(), &triangle(), &o).unwrap_err(),
        SketchError::InvalidOption {
            option: "crown_samples",
            ..
        }
    ));
    let mut o = SketchOptions::default();
    o.foliage_passes = 9;
    assert!(matches!(
        plan(&view(), &triangle(), &o).unwrap_err(),
        SketchError::InvalidOption {
            option: "foliage_passes",
            ..
        }
    ));
}

#[test]
fn error_messages_name_the_problem() {
    let e = SketchError::OpenSketchTooFar {
        end: SketchEnd::Start,
        distance: 0.5,
        limit: 0.1,
    };
    assert_eq!(
        e.to_string(),
        "the first point of the open sketch is 0.5 from the crown's silhouette (screen units); it must be within 0.1"
    );
}
