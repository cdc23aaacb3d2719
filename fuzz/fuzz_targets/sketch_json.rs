//! `treemorph_sketch::parse_sketch_file`: sketch files given to
//! `treemorph sketch --sketch FILE`.
//!
//! Invariants: never a panic; a file that parses has a usable camera and a
//! valid sketch, and writes back (`SketchFile::to_json`) to a file that
//! parses to the same value.
#![no_main]

use libfuzzer_sys::fuzz_target;
use treemorph_sketch::parse_sketch_file;

fuzz_target!(|data: &[u8]| {
    let Ok(file) = parse_sketch_file(data) else {
        return;
    };
    let camera = file.view.camera().expect("a parsed file has a camera");
    let _ = camera;
    let points = file.sketch.validate().expect("a parsed sketch is valid");
    assert!(points.len() >= 3, "fewer than 3 distinct points passed");
    let again = parse_sketch_file(&file.to_json())
        .unwrap_or_else(|e| panic!("a parsed sketch file does not read back: {e}"));
    assert!(again == file, "the sketch file changed on a round trip");
});
