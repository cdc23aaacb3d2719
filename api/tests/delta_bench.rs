//! Timing of the delta codec on synthetic animations of 200,000 and
//! 300,000 vertices. Run with
//! `cargo test --release -p treemorph-api --test delta_bench -- --ignored --nocapture`.

use treemorph_api::delta::bench;
use treemorph_api::delta::{Compression, EncoderOptions};

#[test]
#[ignore = "timing: run in release with --ignored --nocapture"]
fn delta_codec_figures() {
    for compression in [
        Compression::Zstd { level: 1 },
        Compression::Zstd { level: 3 },
        Compression::Zstd { level: -5 },
        Compression::None,
    ] {
        for chains in [5_000, 3_334] {
            let options = EncoderOptions::with_compression(compression);
            let report = bench::run(chains, 100, &options).unwrap();
            println!(
                "{compression:?}: {} vertices, header {} B, {:.0} B/frame vs GLB {} B/frame ({:.2} %), \
                 encode {:.3} ms/frame (min {:.3}), decode {:.3} ms/frame (min {:.3}), \
                 max error {:.5} % of height",
                report.vertices,
                report.header_bytes,
                report.bytes_per_frame,
                report.glb_bytes_per_frame,
                report.ratio() * 100.0,
                report.encode_ms_per_frame,
                report.encode_ms_min,
                report.decode_ms_per_frame,
                report.decode_ms_min,
                report.max_error_fraction * 100.0
            );
            assert!(report.max_error_fraction <= 0.001);
            assert!(report.ratio() <= 0.25);
        }
    }
}
