//! Timing of the frame encoders on a ~20,000-chain tree, for the report and
//! `treemorph bench`. Run with
//! `cargo test --release -p treemorph-gltf --test frames_timing -- --ignored --nocapture`
//! (set `TREEMORPH_BENCH_ANIMATED=0` to skip the animated GLBs, which take
//! gigabytes of memory at 60 keyframes, and `TREEMORPH_BENCH_ZSTD=LEVEL` to
//! compress the delta stream's records).

use treemorph_api::delta::{Compression, EncoderOptions};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_gltf::bench::{self, BenchOptions};

#[test]
#[ignore = "timing: run in release with --ignored --nocapture"]
fn frame_encoder_figures() {
    let tree = generate(&GenerateOptions::new(Preset::Eucalyptus, 1).with_size(65_000)).unwrap();
    let mut options = BenchOptions::default();
    if std::env::var("TREEMORPH_BENCH_ANIMATED").as_deref() == Ok("0") {
        options.animated.clear();
    }
    if let Ok(level) = std::env::var("TREEMORPH_BENCH_ZSTD") {
        options.stream = options
            .stream
            .with_encoder(EncoderOptions::with_compression(Compression::Zstd {
                level: level.parse().unwrap(),
            }));
    }
    let r = bench::run(&tree, &options).unwrap();
    println!(
        "{} strands, {} leaves; per-frame GLB meshes {} + {} vertices",
        r.strands, r.leaves, r.glb_vertices[0], r.glb_vertices[1]
    );
    println!(
        "meshing per frame: {:.2} ms (fastest {:.2}); with quad leaves {:.2} ms (fastest {:.2})",
        r.mesh_ms[0], r.mesh_ms[1], r.mesh_quads_ms[0], r.mesh_quads_ms[1]
    );
    println!(
        "per-frame GLB: {:.0} bytes, {:.1} ms (fastest {:.1})",
        r.frame_glb_bytes, r.frame_glb_ms[0], r.frame_glb_ms[1]
    );
    println!(
        "delta stream: {} vertices, header {} B, {:.0} B/frame = {:.3} % of the GLB; \
         codec {:.2} ms/frame (fastest {:.2}), mesh + encode {:.2} ms (fastest {:.2}); \
         max error {:.4} % of height",
        r.delta_vertices,
        r.delta_header_bytes,
        r.delta_bytes_per_frame,
        r.delta_ratio() * 100.0,
        r.delta_encode_ms[0],
        r.delta_encode_ms[1],
        r.delta_frame_ms[0],
        r.delta_frame_ms[1],
        r.delta_max_error_fraction * 100.0
    );
    for a in &r.animated {
        println!(
            "animated GLB {:?}, {} keyframes: {:.1} MB, built in {:.0} ms",
            a.encoding,
            a.keyframes,
            a.bytes as f64 / 1e6,
            a.build_ms
        );
    }
    assert!(r.delta_max_error_fraction <= 0.001);
    assert!(r.delta_ratio() <= 0.25);
}
