//! The benchmark table printed by `treemorph bench` and `cargo bench`.
//!
//! Each stage contributes named cases; a case runs its closure repeatedly
//! (at least 3 times, then until about a second has passed or 30 runs) and
//! reports the median and fastest run. Inputs are generated trees, so the
//! figures are reproducible on any machine. Timings belong here and never in
//! tests.

use std::time::{Duration, Instant};

use serde::Serialize;

use crate::cli::Failure;

mod job;
mod stages;

/// Arguments of `treemorph bench`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Only run cases whose stage contains this text.
    #[arg(long)]
    filter: Option<String>,
    /// Run each case once (for smoke tests; the figures are noisy).
    #[arg(long)]
    quick: bool,
}

/// One row of the table.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// The stage measured (e.g. `generate`).
    pub stage: String,
    /// What it ran on (e.g. `eucalyptus seed 1`).
    pub input: String,
    /// Size of the input (e.g. `20,011 branches`).
    pub size: String,
    /// Median wall time of one run, milliseconds.
    pub median_ms: f64,
    /// Fastest run, milliseconds.
    pub min_ms: f64,
    /// Runs measured.
    pub runs: usize,
    /// Work per second at the median, with its unit.
    pub throughput: String,
    /// The target for this row, milliseconds, when there is one.
    pub target_ms: Option<f64>,
    /// Other figures of the row (sizes, ratios).
    #[serde(skip_serializing_if = "String::is_empty")]
    pub note: String,
}

/// Times `f`: a few runs, then more until about a second has passed.
pub fn measure(quick: bool, mut f: impl FnMut()) -> (f64, f64, usize) {
    let mut times = Vec::new();
    let budget = Duration::from_secs(1);
    let start = Instant::now();
    loop {
        let t = Instant::now();
        f();
        times.push(t.elapsed().as_secs_f64() * 1e3);
        let enough = if quick {
            true
        } else {
            times.len() >= 3 && (start.elapsed() > budget || times.len() >= 30)
        };
        if enough {
            break;
        }
    }
    times.sort_by(f64::total_cmp);
    (times[times.len() / 2], times[0], times.len())
}

pub(crate) fn per_second(count: usize, unit: &str, ms: f64) -> String {
    let rate = count as f64 / (ms / 1e3);
    if rate >= 1e6 {
        format!("{:.2} M {unit}/s", rate / 1e6)
    } else if rate >= 1e3 {
        format!("{:.1} k {unit}/s", rate / 1e3)
    } else {
        format!("{rate:.1} {unit}/s")
    }
}

pub(crate) fn thousands(n: usize) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// A group of cases and the stage names its rows use.
type Group = (fn(bool, &mut Vec<Row>), &'static [&'static str]);

const GROUPS: &[Group] = &[
    (
        stages::foundation_rows,
        &["generate", "export glb", "generate + export glb"],
    ),
    (stages::analysis_rows, &["analysis"]),
    (stages::import_rows, &["import glb"]),
    (
        stages::morph_rows,
        &[
            "morph plan",
            "morph frame",
            "frame at an instant",
            "frame at an instant, plan kept",
            "stream at an instant, plan kept",
            "frame record at an instant, plan kept",
            "morph frame + meshes",
        ],
    ),
    (
        stages::sketch_rows,
        &["sketch plan", "sketch frame", "sketch frame + meshes"],
    ),
    (
        job::job_rows,
        &[
            "default job",
            "frame at an instant, stored plan",
            "animation.glb, stored plan",
        ],
    ),
    (
        job::measurement_rows,
        &[
            "output check per frame",
            "crossings per frame",
            "frame metrics per frame",
        ],
    ),
    (
        stages::output_rows,
        &[
            "mesh frame",
            "per-frame glb",
            "delta stream",
            "animated glb",
        ],
    ),
];

/// Runs every case whose stage contains `filter` (all without one).
pub fn rows(quick: bool, filter: Option<&str>) -> Vec<Row> {
    let wanted = |stage: &str| filter.is_none_or(|f| stage.contains(f));
    let mut rows = Vec::new();
    for (run, stages) in GROUPS {
        if stages.iter().any(|s| wanted(s)) {
            run(quick, &mut rows);
        }
    }
    rows.retain(|r| wanted(&r.stage));
    rows
}

/// Formats rows as an aligned text table.
pub fn table(rows: &[Row]) -> String {
    let header = [
        "stage",
        "input",
        "size",
        "median",
        "min",
        "runs",
        "throughput",
        "target",
        "note",
    ];
    let cells: Vec<[String; 9]> = rows
        .iter()
        .map(|r| {
            [
                r.stage.clone(),
                r.input.clone(),
                r.size.clone(),
                format!("{:.2} ms", r.median_ms),
                format!("{:.2} ms", r.min_ms),
                r.runs.to_string(),
                r.throughput.clone(),
                match r.target_ms {
                    Some(t) if r.median_ms <= t => format!("≤ {t} ms ✓"),
                    Some(t) => format!("≤ {t} ms ✗"),
                    None => String::new(),
                },
                r.note.clone(),
            ]
        })
        .collect();
    let mut widths = header.map(|h| h.chars().count());
    for row in &cells {
        for (w, c) in widths.iter_mut().zip(row) {
            *w = (*w).max(c.chars().count());
        }
    }
    let line = |cols: &[String]| -> String {
        let mut s = String::new();
        for (i, (c, w)) in cols.iter().zip(widths).enumerate() {
            let pad = w - c.chars().count();
            // Numbers right-aligned, text left-aligned.
            if (3..=5).contains(&i) {
                s.push_str(&" ".repeat(pad));
                s.push_str(c);
            } else {
                s.push_str(c);
                s.push_str(&" ".repeat(pad));
            }
            s.push_str("  ");
        }
        s.trim_end().to_owned() + "\n"
    };
    let mut out = line(&header.map(String::from));
    out.push_str(&line(&widths.map(|w| "-".repeat(w))));
    for row in &cells {
        out.push_str(&line(row));
    }
    out
}

pub(crate) fn run(args: &Args) -> Result<(), Failure> {
    if cfg!(debug_assertions) {
        eprintln!(
            "warning: this is a debug build; run `cargo run --release -- bench` for real figures"
        );
    }
    let rows = rows(args.quick, args.filter.as_deref());
    if args.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        print!("{}", table(&rows));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thousands_separates_groups() {
        assert_eq!(thousands(0), "0");
        assert_eq!(thousands(999), "999");
        assert_eq!(thousands(1000), "1,000");
        assert_eq!(thousands(20_195), "20,195");
        assert_eq!(thousands(1_234_567), "1,234,567");
    }

    #[test]
    fn table_aligns_columns_and_marks_targets() {
        let row = |median_ms, target_ms| Row {
            stage: "generate".into(),
            input: "maple".into(),
            size: "10 branches".into(),
            median_ms,
            min_ms: 1.0,
            runs: 3,
            throughput: "1 branches/s".into(),
            target_ms,
            note: String::new(),
        };
        let text = table(&[row(5.0, Some(10.0)), row(50.0, Some(10.0)), row(1.0, None)]);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 5);
        assert!(lines[2].ends_with("≤ 10 ms ✓"), "{text}");
        assert!(lines[3].ends_with("≤ 10 ms ✗"), "{text}");
        assert!(lines[2].contains("maple"), "{text}");
        assert_eq!(lines[0].find("input"), lines[2].find("maple"));
    }
}
