//! The shell helpers `scripts/test` runs its steps with.

use std::process::{Command, Output};

/// Runs `script` in bash with `scripts/lib.sh` sourced, from the
/// repository's root.
fn with_lib(script: &str) -> Output {
    Command::new("bash")
        .args(["-c", &format!(". scripts/lib.sh\n{script}")])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("bash runs")
}

/// A step hides the command line's progress lines, but a command that
/// fails shows why: a `generate` that failed (on a full disk) once ended a
/// CI run with no message at all, its stderr sent to /dev/null.
#[test]
fn quietly_shows_the_stderr_of_a_failing_command_only() {
    let failed = with_lib("quietly sh -c 'echo wrote 3 frames >&2; echo disk full >&2; exit 3'");
    assert_eq!(failed.status.code(), Some(3));
    let stderr = String::from_utf8_lossy(&failed.stderr);
    assert!(stderr.contains("disk full"), "{stderr}");
    assert!(stderr.contains("exit status 3"), "{stderr}");
    assert!(stderr.contains("sh -c"), "the command is named: {stderr}");

    let passed = with_lib("quietly sh -c 'echo wrote 3 frames >&2; echo out'");
    assert!(passed.status.success());
    assert_eq!(String::from_utf8_lossy(&passed.stdout), "out\n");
    assert!(
        passed.stderr.is_empty(),
        "{:?}",
        String::from_utf8_lossy(&passed.stderr)
    );
}

/// Under `set -e`, as in `scripts/test`, a failing command still stops the
/// script after its message.
#[test]
fn quietly_stops_a_script_under_set_e() {
    let out = with_lib("set -e\nquietly false\necho after");
    assert!(!out.status.success());
    assert!(!String::from_utf8_lossy(&out.stdout).contains("after"));
}

/// The idle share of the CPUs is a percentage, and waiting for an idle
/// machine gives up after its limit instead of failing the step.
#[test]
fn waiting_for_an_idle_machine_reports_and_never_fails() {
    let idle = with_lib("cpu_idle_percent");
    assert!(idle.status.success());
    let percent: u32 = String::from_utf8_lossy(&idle.stdout)
        .trim()
        .parse()
        .expect("a number");
    assert!(percent <= 100);
    let wait = with_lib("set -e\nwait_until_idle 0\necho after");
    assert!(wait.status.success());
    let out = String::from_utf8_lossy(&wait.stdout);
    assert!(out.contains("% idle") && out.ends_with("after\n"), "{out}");
}
