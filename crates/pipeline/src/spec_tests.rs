use proptest::prelude::*;
use treemorph_api::ErrorCode;
use treemorph_api::jobs::{
    JobRequest, MorphJobOptions, MorphRequest, Outputs, SketchInput, SketchJobOptions,
    SketchRequest,
};
use treemorph_gltf::basis::AnimationKind;

use super::*;
use crate::ErrorCoded;

fn morph(frames: u32, options: MorphJobOptions) -> JobRequest {
    JobRequest::Morph(MorphRequest {
        source: "a".into(),
        target: "b".into(),
        frames,
        options,
        outputs: Outputs::default(),
        callback_url: None,
    })
}

fn sketch(view: treemorph_api::jobs::View) -> JobRequest {
    JobRequest::Sketch(SketchRequest {
        tree: "t".into(),
        view,
        sketch: SketchInput {
            points: vec![[-0.5, -0.5], [0.5, -0.5], [0.0, 0.5]],
            closed: true,
        },
        frames: 10,
        options: SketchJobOptions::default(),
        outputs: Outputs::default(),
        callback_url: None,
    })
}

#[test]
fn frames_above_600_are_accepted_when_the_limit_allows_them() {
    // Regression: the runner hard-coded 2..=600 whatever `--max-frames` said.
    let limits = Limits::default().with_max_frames(1200);
    let spec = JobSpec::parse(&morph(1200, MorphJobOptions::default()), &limits).unwrap();
    assert_eq!(spec.frames(), 1200);
    let err = JobSpec::parse(&morph(1201, MorphJobOptions::default()), &limits).unwrap_err();
    assert_eq!(
        err,
        SpecError::Frames {
            frames: 1201,
            max: 1200
        }
    );
    assert_eq!(err.error_code(), ErrorCode::InvalidRequest);
    assert!(err.to_string().contains("frames"), "{err}");
}

#[test]
fn keyframes_resolve_to_the_kinds_default_or_the_frame_count() {
    let spec = JobSpec::parse(&morph(10, MorphJobOptions::default()), &Limits::default()).unwrap();
    assert_eq!(spec.render().keyframes, 10);
    // A basis (the default) samples every frame; keyframes default to 24.
    let spec = JobSpec::parse(&morph(60, MorphJobOptions::default()), &Limits::default()).unwrap();
    assert_eq!(spec.render().keyframes, 60);
    assert_eq!(spec.render().animation, AnimationKind::Basis);
    let spec = JobSpec::parse(&morph(600, MorphJobOptions::default()), &Limits::default()).unwrap();
    assert_eq!(spec.render().keyframes, DEFAULT_BASIS_SAMPLES);
    let keyframes = MorphJobOptions {
        animation: treemorph_api::jobs::AnimationKind::Keyframes,
        ..MorphJobOptions::default()
    };
    let spec = JobSpec::parse(&morph(60, keyframes), &Limits::default()).unwrap();
    assert_eq!(spec.render().keyframes, DEFAULT_KEYFRAMES);
    assert_eq!(spec.render().animation, AnimationKind::Keyframes);
    let options = MorphJobOptions {
        keyframes: Some(11),
        ..MorphJobOptions::default()
    };
    let err = JobSpec::parse(&morph(10, options), &Limits::default()).unwrap_err();
    assert_eq!(err.error_code(), ErrorCode::InvalidJob);
}

#[test]
fn morph_options_compose_instead_of_overwriting() {
    use treemorph_api::jobs::{LeafAssignment, Matching};
    let options = MorphJobOptions {
        matching: Matching::OneToOne,
        leaves: LeafAssignment::Random,
        slow_down: Some(false),
        untangle: Some(false),
        ..MorphJobOptions::default()
    };
    let JobSpec::Morph(spec) = JobSpec::parse(&morph(5, options), &Limits::default()).unwrap()
    else {
        panic!("not a morph")
    };
    let want = MorphOptions::default()
        .with_chain_matching(ChainMatching::OneToOne)
        .with_leaf_morph(LeafMorph::RandomLinear { seed: 0 })
        .with_slow_down(false)
        .with_untangle(false);
    assert_eq!(spec.options, want);
}

#[test]
fn a_cameras_aspect_survives_the_round_trip() {
    // Regression: `treemorph sketch` turned the sketch file's camera into a
    // wire camera and back through `View::perspective(.., NaN)`, which
    // dropped `aspect`.
    let mut domain = View::perspective(Vec3::new(0.0, 1.0, 5.0), Vec3::Y, Vec3::Y, 40.0);
    domain.aspect = 16.0 / 9.0;
    let wire = wire_view(&domain);
    assert_eq!(wire.aspect, Some(16.0 / 9.0));
    let JobSpec::Sketch(spec) = JobSpec::parse(&sketch(wire), &Limits::default()).unwrap() else {
        panic!("not a sketch")
    };
    assert_eq!(spec.view, domain);
    let ortho = View::orthographic(Vec3::new(0.0, 1.0, 5.0), Vec3::Y, Vec3::Y, 3.0);
    assert_eq!(view(&wire_view(&ortho)), ortho);
}

#[test]
fn a_bad_aspect_is_the_callers_invalid_sketch() {
    let mut wire = wire_view(&View::front(10.0));
    wire.aspect = Some(0.0);
    let err = JobSpec::parse(&sketch(wire), &Limits::default()).unwrap_err();
    assert_eq!(err.error_code(), ErrorCode::InvalidSketch);
    assert!(err.to_string().contains("aspect"), "{err}");
}

proptest! {
    #[test]
    fn parse_never_panics_and_accepted_requests_round_trip(
        frames in 0u32..2000,
        max_frames in 2u32..1500,
        keyframes in proptest::option::of(0u32..2000),
        fov in proptest::option::of(-10.0f32..200.0),
        aspect in proptest::option::of(-1.0f32..4.0),
    ) {
        let limits = Limits::default().with_max_frames(max_frames);
        let options = MorphJobOptions { keyframes, ..MorphJobOptions::default() };
        let request = morph(frames, options);
        if let Ok(spec) = JobSpec::parse(&request, &limits) {
            prop_assert!(spec.frames() <= max_frames);
            prop_assert!(spec.render().keyframes <= spec.frames());
        }
        let mut wire = wire_view(&View::front(10.0));
        wire.fov_deg = fov;
        wire.aspect = aspect;
        let request = sketch(wire);
        if let Ok(JobSpec::Sketch(spec)) = JobSpec::parse(&request, &limits) {
            prop_assert_eq!(view(&wire_view(&spec.view)), spec.view);
        }
    }
}

#[test]
fn the_schedule_reaches_the_morph_options() {
    use treemorph_api::jobs::ScheduleKind;
    let staged = |options| match JobSpec::parse(&morph(5, options), &Limits::default()) {
        Ok(JobSpec::Morph(spec)) => Ok(spec.options.schedule),
        Ok(_) => panic!("not a morph"),
        Err(e) => Err(e),
    };
    let default = staged(MorphJobOptions::default()).unwrap();
    assert_eq!(default, treemorph_morph::ScheduleOptions::default());
    let options = MorphJobOptions {
        schedule: ScheduleKind::Linear,
        stagger: Some(0.1),
        easing: Some(0.5),
        ..MorphJobOptions::default()
    };
    let got = staged(options).unwrap();
    assert_eq!(got.kind, treemorph_morph::ScheduleKind::Linear);
    assert_eq!((got.stagger, got.easing), (0.1, 0.5));
    for (stagger, easing, option) in [(Some(1.5), None, "stagger"), (None, Some(0.7), "easing")] {
        let options = MorphJobOptions {
            stagger,
            easing,
            ..MorphJobOptions::default()
        };
        let err = staged(options).unwrap_err();
        assert_eq!(err.error_code(), ErrorCode::InvalidJob);
        assert!(err.to_string().contains(option), "{err}");
    }
}

#[test]
fn the_schedule_reaches_the_sketch_options() {
    use treemorph_api::jobs::{ScheduleKind, SketchJobOptions};
    let default = sketch_options(&SketchJobOptions::default()).schedule;
    assert_eq!(default, treemorph_tree::timing::ScheduleOptions::default());
    let got = sketch_options(&SketchJobOptions {
        schedule: ScheduleKind::Linear,
        stagger: Some(0.2),
        easing: Some(0.0),
        ..SketchJobOptions::default()
    })
    .schedule;
    assert_eq!(got.kind, treemorph_tree::timing::ScheduleKind::Linear);
    assert_eq!((got.stagger, got.easing), (0.2, 0.0));
    for (stagger, easing, option) in [(Some(0.95), None, "stagger"), (None, Some(-0.1), "easing")] {
        let JobRequest::Sketch(mut request) = sketch(wire_view(&View::front(10.0))) else {
            unreachable!()
        };
        request.options.stagger = stagger;
        request.options.easing = easing;
        let err = JobSpec::parse(&JobRequest::Sketch(request), &Limits::default()).unwrap_err();
        assert_eq!(err.error_code(), ErrorCode::InvalidJob);
        assert!(err.to_string().contains(option), "{err}");
    }
}
