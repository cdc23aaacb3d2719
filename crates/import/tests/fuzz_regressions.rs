//! Inputs the fuzzer (`fuzz/`, target `import_gltf`) found, kept as
//! regression tests: each file in `tests/fuzz/` must import or fail with a
//! caller's-mistake code — never `internal`, never a panic.

use std::path::PathBuf;

use treemorph_import::{ImportError, ImportOptions, import};

#[test]
fn fuzz_findings_never_give_internal_errors() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    assert!(!files.is_empty());
    let mut failures = Vec::new();
    for path in files {
        let bytes = std::fs::read(&path).unwrap();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        match import(&bytes, &ImportOptions::default()) {
            Ok(imported) if imported.tree.skeleton().len() < 2 => {
                failures.push(format!("{name}: a tree of one node"));
            }
            Ok(_) => {}
            Err(e) if !ImportError::CODES.contains(&e.code()) || e.code() == "internal" => {
                failures.push(format!("{name}: {} {e}", e.code()));
            }
            Err(_) => {}
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
