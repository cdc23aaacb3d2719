//! The benchmark cases of every stage, at the papers' input sizes where
//! the papers give them.

use treemorph_generate::{GenerateOptions, Preset};
use treemorph_tree::Tree;

use super::{Row, measure, per_second, thousands};

pub(super) fn tree(preset: Preset, seed: u64, size: u32) -> Tree {
    treemorph_generate::generate(&GenerateOptions::new(preset, seed).with_size(size))
        .expect("bench sizes are within the generator's range")
}

/// Rows of the foundation: generating and exporting trees.
pub(super) fn foundation_rows(quick: bool, rows: &mut Vec<Row>) {
    for (size, target) in [(1_000u32, None), (20_000, Some(200.0))] {
        let preset = Preset::Eucalyptus;
        let sample = tree(preset, 1, size);
        let branches = sample.skeleton().branch_count();
        let input = format!("{} seed 1", preset.name());
        let (median, min, runs) = measure(quick, || {
            std::hint::black_box(tree(preset, 1, size));
        });
        rows.push(Row {
            stage: "generate".into(),
            input: input.clone(),
            size: format!("{} branches", thousands(branches)),
            median_ms: median,
            min_ms: min,
            runs,
            throughput: per_second(branches, "branches", median),
            target_ms: None,
            note: String::new(),
        });
        let options = treemorph_gltf::ExportOptions::default();
        let (median, min, runs) = measure(quick, || {
            std::hint::black_box(treemorph_gltf::export_glb(&sample, &options).expect("export"));
        });
        rows.push(Row {
            stage: "export glb".into(),
            input: input.clone(),
            size: format!("{} branches", thousands(branches)),
            median_ms: median,
            min_ms: min,
            runs,
            throughput: per_second(branches, "branches", median),
            target_ms: None,
            note: String::new(),
        });
        let (median, min, runs) = measure(quick, || {
            let t = tree(preset, 1, size);
            std::hint::black_box(treemorph_gltf::export_glb(&t, &options).expect("export"));
        });
        rows.push(Row {
            stage: "generate + export glb".into(),
            input,
            size: format!("{} branches", thousands(branches)),
            median_ms: median,
            min_ms: min,
            runs,
            throughput: per_second(branches, "branches", median),
            target_ms: target,
            note: String::new(),
        });
    }
}

/// A tree with `keep_leaves` leaves picked evenly, so leaf counts match the papers.
/// inputs (their trees carry about one leaf per chain; ours carry several).
pub(super) fn thinned(tree: &Tree, keep_leaves: usize) -> Tree {
    let mut parts = tree.clone().into_parts();
    let n = parts.leaves.len();
    if n > keep_leaves {
        parts.leaves = (0..keep_leaves)
            .map(|i| parts.leaves[i * n / keep_leaves])
            .collect();
    }
    Tree::new(parts, &treemorph_tree::Limits::default()).expect("a subset of valid leaves is valid")
}

/// Rows of the skeleton-lobe analysis at the morphing paper's sizes
/// (Table 2: 4,507 chains / 4,436 leaves and 20,195 chains / 5,919 leaves).
pub(super) fn analysis_rows(quick: bool, rows: &mut Vec<Row>) {
    use treemorph_analysis::{Analysis, AnalysisOptions};
    let options = AnalysisOptions::default();
    for (preset, size, leaves, target) in [
        (Preset::Eucalyptus, 15_000u32, None, None),
        (Preset::Eucalyptus, 15_000, Some(4_436), Some(50.0)),
        (Preset::Conifer, 15_000, Some(4_436), Some(50.0)),
        (Preset::Eucalyptus, 65_000, Some(5_919), Some(200.0)),
        (Preset::Dichotomous, 46_000, Some(5_919), Some(200.0)),
    ] {
        let full = tree(preset, 1, size);
        let input_tree = match leaves {
            Some(n) => thinned(&full, n),
            None => full,
        };
        let analysis = Analysis::of(&input_tree, &options).expect("generated trees analyse");
        let chains = analysis.chains().len();
        let (median, min, runs) = measure(quick, || {
            std::hint::black_box(Analysis::of(&input_tree, &options).expect("analysis"));
        });
        rows.push(Row {
            stage: "analysis".into(),
            input: format!(
                "{} seed 1{}",
                preset.name(),
                if leaves.is_some() {
                    ", leaves thinned"
                } else {
                    ""
                }
            ),
            size: format!(
                "{} chains, {} leaves",
                thousands(chains),
                thousands(input_tree.leaves().len())
            ),
            median_ms: median,
            min_ms: min,
            runs,
            throughput: per_second(chains, "chains", median),
            target_ms: target,
            note: String::new(),
        });
    }
}

/// A row with the usual fields.
#[allow(clippy::too_many_arguments)]
fn row(
    stage: &str,
    input: String,
    size: String,
    (median_ms, min_ms, runs): (f64, f64, usize),
    throughput: String,
    target_ms: Option<f64>,
    note: String,
) -> Row {
    Row {
        stage: stage.into(),
        input,
        size,
        median_ms,
        min_ms,
        runs,
        throughput,
        target_ms,
        note,
    }
}

/// Importing third-party-like GLBs (no embedded skeleton) of 10,000
/// branches and 5,000 leaves, tube soup and welded.
pub(super) fn import_rows(quick: bool, rows: &mut Vec<Row>) {
    use treemorph_gltf::BranchMeshMode;
    let source = tree(Preset::Eucalyptus, 1, 10_000);
    let options = treemorph_import::ImportOptions::default();
    for (mode, name) in [
        (BranchMeshMode::TubeSoup, "tube soup"),
        (BranchMeshMode::Welded, "welded"),
    ] {
        let glb = treemorph_import::bench::bench_glb(&source, mode, 5_000).expect("export");
        let imported = treemorph_import::import(&glb, &options).expect("import");
        let timing = measure(quick, || {
            std::hint::black_box(treemorph_import::import(&glb, &options).expect("import"));
        });
        rows.push(row(
            "import glb",
            format!("eucalyptus seed 1, {name}"),
            format!(
                "10,000 branches, {} leaves",
                thousands(imported.tree.leaves().len())
            ),
            timing,
            format!("{:.1} MB/s", glb.len() as f64 / 1e3 / timing.0),
            Some(1000.0),
            format!(
                "{:.1} MB GLB; {} nodes recovered",
                glb.len() as f64 / 1e6,
                thousands(imported.tree.skeleton().len())
            ),
        ));
    }
}

/// The morphing paper's Table 2 inputs: 4,507/4,590 chains with
/// 4,436/3,765 leaves, and 5,220/20,195 chains with 4,690/5,919 leaves.
pub(super) fn morph_rows(quick: bool, rows: &mut Vec<Row>) {
    use treemorph_analysis::{Analysis, AnalysisOptions};
    use treemorph_gltf::frames::FrameMeshes;
    use treemorph_gltf::stream::StreamOptions;
    use treemorph_morph::{MorphPlan, Morpher};
    let cases = [
        (
            (Preset::Eucalyptus, 14_500u32, 4_436usize),
            (Preset::Conifer, 14_500u32, 3_765usize),
            None,
            None,
        ),
        (
            (Preset::Eucalyptus, 16_800, 4_690),
            (Preset::Shrub, 65_500, 5_919),
            Some(100.0),
            Some(10.0),
        ),
    ];
    for (k, ((pa, sa, la), (pb, sb, lb), plan_target, frame_target)) in
        cases.into_iter().enumerate()
    {
        let a = thinned(&tree(pa, 1, sa), la);
        let b = thinned(&tree(pb, 2, sb), lb);
        let options = AnalysisOptions::default();
        let (aa, ab) = (
            Analysis::of(&a, &options).expect("analysis"),
            Analysis::of(&b, &options).expect("analysis"),
        );
        let input = format!("{} → {}", pa.name(), pb.name());
        let size = format!(
            "{}/{} chains, {}/{} leaves",
            thousands(aa.chains().len()),
            thousands(ab.chains().len()),
            thousands(a.leaves().len()),
            thousands(b.leaves().len())
        );
        // What a job with default options runs.
        let morph = crate::pipeline::morph_options(&Default::default());
        let timing = measure(quick, || {
            std::hint::black_box(MorphPlan::new(&a, &aa, &b, &ab, &morph).expect("plan"));
        });
        let plan = MorphPlan::new(&a, &aa, &b, &ab, &morph).expect("plan");
        let chains = plan.chains().len();
        rows.push(row(
            "morph plan",
            input.clone(),
            size.clone(),
            timing,
            per_second(chains, "union chains", timing.0),
            plan_target,
            format!(
                "{} union chains, {} nodes, {} leaves",
                thousands(chains),
                thousands(plan.topology().node_count()),
                thousands(plan.topology().leaves.len())
            ),
        ));
        let mut morpher = Morpher::new(&plan);
        let mut frame = morpher.new_frame();
        let mut i = 0u32;
        let mut next_t = || {
            i += 1;
            (i % 61) as f32 / 60.0
        };
        let timing = measure(quick, || morpher.morph(next_t(), &mut frame));
        rows.push(row(
            "morph frame",
            input.clone(),
            size.clone(),
            timing,
            format!("{:.0} frames/s", 1e3 / timing.0),
            None,
            "skeleton and leaves".into(),
        ));
        let radii = {
            let probes: Vec<_> = [0.0, 0.5, 1.0].iter().map(|&t| plan.frame(t)).collect();
            treemorph_gltf::frames::max_radii(&probes)
        };
        let mut meshes = FrameMeshes::new(plan.topology(), &radii, &StreamOptions::default().mesh)
            .expect("mesh");
        let timing = measure(quick, || {
            morpher.morph(next_t(), &mut frame);
            std::hint::black_box(meshes.mesh(&frame).expect("mesh"));
        });
        let (branches, leaves) = meshes.mesh(&frame).expect("mesh");
        let instant_target = [50.0, 150.0][k];
        rows.extend(instant_rows(
            quick,
            (&a, &aa),
            (&b, &ab),
            instant_target,
            (&input, &size),
        ));
        rows.push(row(
            "morph frame + meshes",
            input,
            size,
            timing,
            format!("{:.0} frames/s", 1e3 / timing.0),
            frame_target,
            format!(
                "{} + {} vertices (stream meshes)",
                thousands(branches.positions.len()),
                thousands(leaves.positions.len())
            ),
        ));
    }
}

/// `GET /v1/jobs/{id}/frame.glb?t=` and `stream?t=` without HTTP: the
/// frame at an instant of a 60-frame morph with default options, from
/// trees whose analysis is cached (as the service keeps them). Cold, the
/// runner plans and probes first, as the CLI's `--at` does; from the plan
/// the job stored, a process that did not run the job reads it and
/// renders (the service's first request for an instant: the issue's
/// target for an uncached render is on this row); with the plan kept (the
/// job ran in this process, or an instant of it was asked before), it
/// renders one per-frame GLB, one one-frame delta stream, or that
/// stream's frame record (what the web viewer fetches when scrubbing
/// between frames).
fn instant_rows(
    quick: bool,
    (a, aa): (&Tree, &treemorph_analysis::Analysis),
    (b, ab): (&Tree, &treemorph_analysis::Analysis),
    target: f64,
    (input, size): (&str, &str),
) -> [Row; 5] {
    use std::collections::HashMap;
    use std::sync::Arc;

    use treemorph_api::jobs::{JobRequest, MorphRequest};

    use crate::pipeline::{
        InputTree, JobInput, JobSpec, Limits, PipelineRunner, Runner, StreamPart,
    };
    let trees = HashMap::from([
        (
            "a".to_owned(),
            Arc::new(InputTree::with_analysis(a.clone(), aa.clone())),
        ),
        (
            "b".to_owned(),
            Arc::new(InputTree::with_analysis(b.clone(), ab.clone())),
        ),
    ]);
    let request = JobRequest::Morph(MorphRequest {
        source: "a".into(),
        target: "b".into(),
        frames: 60,
        options: Default::default(),
        outputs: Default::default(),
        callback_url: None,
    });
    let spec = JobSpec::parse(&request, &Limits::default()).expect("a valid job");
    let job = JobInput {
        spec: &spec,
        trees: &trees,
        stored_plan: None,
    };
    let one = |name: &str, what: &str, target: Option<f64>, render: &dyn Fn() -> Vec<u8>| {
        let mut bytes = 0;
        let timing = measure(quick, || bytes = render().len());
        row(
            name,
            input.to_owned(),
            size.to_owned(),
            timing,
            String::new(),
            target,
            format!("{what} of {:.2} MB", bytes as f64 / 1e6),
        )
    };
    // Cold: a new runner plans each time, at t = 0.375. Warm: the runner
    // keeps the plan (after the job ran in this process, or after its
    // first instant) and its writers, and each run asks for another
    // instant, as a scrubbed timeline does (golden-ratio steps over [0, 1],
    // so blended looks are not all found kept).
    let kept = PipelineRunner::default();
    let scrub = std::cell::Cell::new(0u32);
    let scrubbed = || {
        scrub.set(scrub.get() + 1);
        (0.375 + scrub.get() as f32 * 0.618_034).fract()
    };
    let plan = stored_plan(&job);
    let at = |runner: &PipelineRunner, t: f32, part: Option<StreamPart>| match part {
        None => runner.frame_at(&job, t).expect("an instant"),
        Some(part) => runner.stream_at(&job, t, part).expect("an instant"),
    };
    [
        one(
            "frame at an instant",
            "plan + probes + one GLB (`morph --at`, or frame.glb?t= with no stored plan)",
            None,
            &|| at(&PipelineRunner::default(), 0.375, None),
        ),
        one(
            "frame at an instant, stored plan",
            "a process that did not run the job: plan read, one GLB (frame.glb?t=)",
            Some(target),
            &|| from_stored_plan(&spec, &plan, 0.375),
        ),
        one(
            "frame at an instant, plan kept",
            "one GLB (frame.glb?t=), each run at another instant",
            Some(target),
            &|| at(&kept, scrubbed(), None),
        ),
        one(
            "stream at an instant, plan kept",
            "a one-frame stream (stream?t=), each run at another instant",
            Some(target),
            &|| at(&kept, scrubbed(), Some(StreamPart::Whole)),
        ),
        one(
            "frame record at an instant, plan kept",
            "its frame record (stream?t=&header=false), each run at another instant",
            Some(target),
            &|| at(&kept, scrubbed(), Some(StreamPart::Frame)),
        ),
    ]
}

/// The plan `job` stores, as a worker running it publishes it.
fn stored_plan(job: &crate::pipeline::JobInput<'_>) -> Vec<u8> {
    use crate::pipeline::{JobInput, PipelineRunner, Runner};
    let spec = job.spec.stored_part().unmeasured();
    let mut kept = super::job::Kept::run();
    let run = JobInput {
        spec: &spec,
        ..*job
    };
    PipelineRunner::default()
        .run(&run, &mut kept)
        .expect("the job runs");
    kept.plan.expect("the run published its plan")
}

/// The frame at `t` of `spec`'s job, rendered by a process that did not
/// run it: from the plan it stored, without its trees.
fn from_stored_plan(spec: &crate::pipeline::JobSpec, plan: &[u8], t: f32) -> Vec<u8> {
    use crate::pipeline::{PipelineRunner, Runner};
    super::job::from_stored_plan(spec, plan, |job| {
        PipelineRunner::default()
            .frame_at(job, t)
            .expect("an instant")
    })
}

/// The sketch paper's Table 1 input sizes (5,031 branches / 3,830 leaves)
/// and a four times larger tree, sketched into the heart example.
pub(super) fn sketch_rows(quick: bool, rows: &mut Vec<Row>) {
    use treemorph_analysis::{Analysis, AnalysisOptions};
    use treemorph_gltf::frames::FrameMeshes;
    use treemorph_gltf::stream::StreamOptions;
    use treemorph_sketch::{SketchPlan, Sketcher, parse_sketch_file};
    let file = parse_sketch_file(include_bytes!("../../examples/sketches/heart.json"))
        .expect("the example sketch parses");
    for (size, leaves, target) in [(5_031u32, 3_830usize, Some(10.0)), (20_000, 15_000, None)] {
        let t = thinned(&tree(Preset::Maple, 1, size), leaves);
        let analysis = Analysis::of(&t, &AnalysisOptions::default()).expect("analysis");
        // What a job with the file's fit runs.
        let options = crate::pipeline::sketch_options(&treemorph_api::jobs::SketchJobOptions {
            fit: (file.fit == treemorph_sketch::Fit::Crown)
                .then_some(treemorph_api::jobs::SketchFit::Crown),
            ..Default::default()
        });
        let input = "maple seed 1 → heart".to_owned();
        let size_text = format!(
            "{} branches, {} leaves",
            thousands(t.skeleton().branch_count()),
            thousands(t.leaves().len())
        );
        let timing = measure(quick, || {
            std::hint::black_box(
                SketchPlan::new(&t, &analysis, &file.view, &file.sketch, &options).expect("plan"),
            );
        });
        rows.push(row(
            "sketch plan",
            input.clone(),
            size_text.clone(),
            timing,
            per_second(analysis.chains().len(), "chains", timing.0),
            target.map(|_| 200.0),
            String::new(),
        ));
        let plan =
            SketchPlan::new(&t, &analysis, &file.view, &file.sketch, &options).expect("plan");
        let mut sketcher = Sketcher::new(&plan);
        let mut frame = sketcher.frame(0.0);
        let mut i = 0u32;
        let mut next_t = || {
            i += 1;
            (i % 61) as f32 / 60.0
        };
        // The lobe factorisation happens on first use; time steady frames.
        sketcher.deform(0.5, &mut frame);
        let timing = measure(quick, || sketcher.deform(next_t(), &mut frame));
        rows.push(row(
            "sketch frame",
            input.clone(),
            size_text.clone(),
            timing,
            format!("{:.0} frames/s", 1e3 / timing.0),
            target,
            "skeleton and leaves".into(),
        ));
        let radii = {
            let probes: Vec<_> = [0.0, 0.5, 1.0].iter().map(|&t| sketcher.frame(t)).collect();
            treemorph_gltf::frames::max_radii(&probes)
        };
        let mut meshes = FrameMeshes::new(plan.topology(), &radii, &StreamOptions::default().mesh)
            .expect("mesh");
        let timing = measure(quick, || {
            sketcher.deform(next_t(), &mut frame);
            std::hint::black_box(meshes.mesh(&frame).expect("mesh"));
        });
        rows.push(row(
            "sketch frame + meshes",
            input,
            size_text,
            timing,
            format!("{:.0} frames/s", 1e3 / timing.0),
            None,
            String::new(),
        ));
    }
}

/// Frame output at 20,000 chains: meshing, per-frame GLB, the delta stream
/// against the per-frame GLB, and the animated GLB's size at 60 keyframes.
pub(super) fn output_rows(quick: bool, rows: &mut Vec<Row>) {
    use treemorph_gltf::animated::{
        AnimatedEncoding, AnimatedGlbBuilder, AnimatedOptions, KEYFRAMES_MESH,
    };
    use treemorph_gltf::bench::Sway;
    use treemorph_gltf::frame_glb::{FrameGlbOptions, FrameGlbWriter};
    use treemorph_gltf::frames::FrameMeshes;
    use treemorph_gltf::stream::{DeltaStreamWriter, StreamOptions};

    let t = tree(Preset::Eucalyptus, 1, 65_000);
    let frames = 60;
    let sway = Sway::new(&t, frames);
    let topology = sway.topology();
    let radii = sway.reference_radii();
    let input = "eucalyptus seed 1, swaying".to_owned();
    let size = format!(
        "{} strands, {} leaves",
        thousands(topology.strands.len()),
        thousands(topology.leaves.len())
    );
    let mut frame = sway.frame(0);
    let mut i = 0usize;
    let mut next = |frame: &mut treemorph_tree::Frame| {
        i = (i + 1) % frames;
        sway.frame_into(i, frame);
    };

    let stream_mesh = StreamOptions::default().mesh;
    let mut meshes = FrameMeshes::new(topology, radii, &stream_mesh).expect("mesh");
    let timing = measure(quick, || {
        std::hint::black_box(meshes.mesh(&frame).expect("mesh"));
    });
    let (b, l) = meshes.mesh(&frame).expect("mesh");
    rows.push(row(
        "mesh frame",
        input.clone(),
        size.clone(),
        timing,
        format!("{:.0} frames/s", 1e3 / timing.0),
        None,
        format!(
            "{} + {} vertices (quad leaves)",
            thousands(b.positions.len()),
            thousands(l.positions.len())
        ),
    ));

    let mut writer =
        FrameGlbWriter::new(topology, radii, &FrameGlbOptions::default()).expect("glb");
    let mut glb = Vec::new();
    writer.write_into(&frame, &mut glb).expect("glb");
    let timing = measure(quick, || {
        next(&mut frame);
        writer.write_into(&frame, &mut glb).expect("glb");
    });
    let glb_bytes = glb.len();
    rows.push(row(
        "per-frame glb",
        input.clone(),
        size.clone(),
        timing,
        format!("{:.0} MB/s", glb_bytes as f64 / 1e3 / timing.0),
        None,
        format!(
            "{:.1} MB per frame (24-point contour leaves)",
            glb_bytes as f64 / 1e6
        ),
    ));

    let mut stream =
        DeltaStreamWriter::new(topology, radii, sway.bounds(), &StreamOptions::default())
            .expect("stream");
    let mut out = Vec::new();
    stream.write_frame(&frame, &mut out).expect("stream");
    let mut bytes = 0usize;
    let mut count = 0usize;
    let timing = measure(quick, || {
        next(&mut frame);
        out.clear();
        stream.write_frame(&frame, &mut out).expect("stream");
        bytes += out.len();
        count += 1;
    });
    let per_frame = bytes as f64 / count.max(1) as f64;
    rows.push(row(
        "delta stream",
        input.clone(),
        size.clone(),
        timing,
        format!("{:.0} frames/s", 1e3 / timing.0),
        None,
        format!(
            "{:.0} KB per frame = {:.2} % of a per-frame GLB; meshing included",
            per_frame / 1e3,
            100.0 * per_frame / glb_bytes as f64
        ),
    ));

    for (encoding, name) in [
        (AnimatedEncoding::Float, "float"),
        (AnimatedEncoding::Quantized, "quantised"),
        (AnimatedEncoding::Meshopt, "meshopt"),
    ] {
        let options = AnimatedOptions::default()
            .with_mesh(KEYFRAMES_MESH)
            .with_keyframes(frames)
            .with_encoding(encoding);
        let mut written = 0u64;
        // One run: the float file alone is gigabytes (counted, not kept).
        let timing = measure(true, || {
            let mut builder = AnimatedGlbBuilder::new(topology, radii, sway.bounds(), &options)
                .expect("animated");
            for k in 0..frames {
                builder.push(&sway.frame(k)).expect("keyframe");
            }
            let mut counter = Counter(0);
            written = builder.finish_to(&mut counter).expect("write");
        });
        rows.push(row(
            "animated glb",
            input.clone(),
            size.clone(),
            timing,
            String::new(),
            None,
            format!("{name}: {:.0} MB for 60 keyframes", written as f64 / 1e6),
        ));
    }
}

/// Counts bytes written and keeps none.
struct Counter(u64);

impl std::io::Write for Counter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0 += buf.len() as u64;
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}
