//! `cargo bench`: the same table as `treemorph bench`.

fn main() {
    // `cargo bench -- FILTER` passes extra arguments; the first non-flag one
    // filters stages like `treemorph bench --filter`.
    let filter = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let rows = treemorph::bench::rows(false, filter.as_deref());
    print!("{}", treemorph::bench::table(&rows));
}
