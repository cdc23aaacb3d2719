//! `POST /v1/jobs` bodies: JSON → [`JobRequest`] → [`JobSpec`], the very
//! conversion the service, the worker and the command line run
//! (`treemorph_pipeline::JobSpec::parse`; the pipeline crate is synchronous
//! and links no service code, so the fuzzer runs the real function).
//!
//! The service stores the request as `serde_json::to_string(&request)` and
//! the worker parses that text again when it claims the job, so every
//! request the service accepts must survive that round trip unchanged —
//! otherwise a `202 Accepted` job could never run.
//!
//! Invariants: never a panic; an accepted request round-trips through its
//! stored form and converts to the same spec again.
#![no_main]

use libfuzzer_sys::fuzz_target;
use treemorph_api::jobs::JobRequest;
use treemorph_pipeline::{JobSpec, Limits};

fuzz_target!(|data: &[u8]| {
    let Ok(request) = serde_json::from_slice::<JobRequest>(data) else {
        return;
    };
    // What the handler does with any parsed request, accepted or not.
    let _ = (request.kind(), request.frames(), request.tree_ids());
    let _ = (request.outputs(), request.callback_url());
    let Ok(spec) = JobSpec::parse(&request, &Limits::default()) else {
        return;
    };
    let stored = serde_json::to_string(&request).expect("requests serialise");
    let claimed: JobRequest = serde_json::from_str(&stored)
        .unwrap_or_else(|e| panic!("the stored request {stored} does not parse: {e}"));
    assert!(claimed == request, "the stored request changed: {stored}");
    let again = JobSpec::parse(&claimed, &Limits::default())
        .expect("the stored request is accepted again");
    assert!(again == spec, "the stored request converts differently: {stored}");
});
