//! `POST /v1/jobs` bodies: JSON → [`JobRequest`], then the checks the
//! service runs before queueing.
//!
//! The service stores the request as `serde_json::to_string(&request)` and
//! the worker parses that text again when it claims the job, so every
//! request the service accepts must survive that round trip unchanged —
//! otherwise a `202 Accepted` job could never run.
//!
//! [`check`] mirrors `PipelineRunner::check` in `src/pipeline/runner.rs`
//! with the same crate calls (linking the service crate — sqlx, object
//! store, TLS — into an instrumented fuzzer would triple the build time).
//!
//! Invariants: never a panic; an accepted request round-trips through its
//! stored form and is accepted again.
#![no_main]

use glam::{Vec2, Vec3};
use libfuzzer_sys::fuzz_target;
use treemorph_api::jobs::{
    JobRequest, LeafAssignment, Matching, MorphRequest, SketchFit, SketchMethod, SketchRequest,
};
use treemorph_morph::MorphOptions;
use treemorph_sketch::{Fit, Method, SketchOptions};

fn check_common(frames: u32, keyframes: Option<u32>) -> Result<(), String> {
    if !(2..=600).contains(&frames) {
        return Err(format!("frames {frames}"));
    }
    if let Some(k) = keyframes
        && !(2..=frames).contains(&k)
    {
        return Err(format!("keyframes {k}"));
    }
    Ok(())
}

fn morph(r: &MorphRequest) -> Result<(), String> {
    check_common(r.frames, r.options.keyframes)?;
    let mut options = match r.options.matching {
        Matching::OneToMany => MorphOptions::default(),
        Matching::OneToOne => MorphOptions::one_to_one(),
    };
    if r.options.leaves == LeafAssignment::Random {
        let one_to_one = r.options.matching == Matching::OneToOne;
        options = MorphOptions::random_leaves(0);
        if one_to_one {
            options.chain_matching = MorphOptions::one_to_one().chain_matching;
        }
    }
    if let Some(slow_down) = r.options.slow_down {
        options.slow_down = slow_down;
    }
    options.validate().map_err(|e| e.to_string())
}

fn sketch(r: &SketchRequest) -> Result<(), String> {
    check_common(r.frames, r.options.keyframes)?;
    let v = &r.view;
    let mut view = treemorph_sketch::View::perspective(
        Vec3::from_array(v.eye),
        Vec3::from_array(v.target),
        Vec3::from_array(v.up),
        v.fov_deg.unwrap_or(f32::NAN),
    );
    view.fov_deg = v.fov_deg;
    view.ortho_height = v.ortho_height;
    let sketch = treemorph_sketch::Sketch {
        points: r.sketch.points.iter().map(|p| Vec2::from_array(*p)).collect(),
        closed: r.sketch.closed,
    };
    view.camera().map_err(|e| e.to_string())?;
    sketch.validate().map_err(|e| e.to_string())?;
    let method = match r.options.method {
        SketchMethod::Multiscale => Method::Multiscale,
        SketchMethod::SingleCage => Method::SingleCage,
    };
    let fit = match r.options.fit {
        Some(SketchFit::Crown) => Fit::Crown,
        None => Fit::None,
    };
    SketchOptions::default()
        .with_method(method)
        .with_fit(fit)
        .validate()
        .map_err(|e| e.to_string())
}

fn check(request: &JobRequest) -> Result<(), String> {
    match request {
        JobRequest::Morph(r) => morph(r),
        JobRequest::Sketch(r) => sketch(r),
    }
}

fuzz_target!(|data: &[u8]| {
    let Ok(request) = serde_json::from_slice::<JobRequest>(data) else {
        return;
    };
    // What the handler does with any parsed request, accepted or not.
    let _ = (request.kind(), request.frames(), request.tree_ids());
    let _ = (request.outputs(), request.callback_url());
    if check(&request).is_err() {
        return;
    }
    let stored = serde_json::to_string(&request).expect("requests serialise");
    let claimed: JobRequest = serde_json::from_str(&stored)
        .unwrap_or_else(|e| panic!("the stored request {stored} does not parse: {e}"));
    assert!(claimed == request, "the stored request changed: {stored}");
    check(&claimed).expect("the stored request is accepted again");
});
