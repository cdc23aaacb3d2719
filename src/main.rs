//! The `treemorph` command: see `treemorph --help`.

fn main() -> std::process::ExitCode {
    treemorph::cli::main()
}
