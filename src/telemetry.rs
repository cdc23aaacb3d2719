//! Logs (tracing, `RUST_LOG`, default `info`) and Prometheus metrics
//! (`GET /metrics`, OpenMetrics text).
//!
//! Metrics:
//! - `treemorph_http_request_duration_seconds{method, route, status}` —
//!   latency histogram by matched route template (never the raw path, so
//!   ids do not explode the label space).
//! - `treemorph_jobs{status}` — jobs per status (queue depth = `queued`),
//!   read from the database at scrape time, so it is right in every process.
//! - `treemorph_job_duration_seconds{kind, outcome}` and
//!   `treemorph_job_stage_duration_seconds{kind, stage}` — observed by the
//!   worker process that ran the attempt.
//! - `treemorph_jobs_in_flight` — attempts running in this process.
//! - `treemorph_tree_cache_lookups_total{result}` — input trees a worker
//!   found in its tree cache (`hit`) or loaded from the blob store
//!   (`miss`).

use std::time::Duration;

use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::Registry;

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct HttpLabels {
    method: String,
    route: String,
    status: u16,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct StatusLabels {
    status: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct JobLabels {
    kind: String,
    outcome: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct StageLabels {
    kind: String,
    stage: String,
}

#[derive(Clone, Debug, Hash, PartialEq, Eq, EncodeLabelSet)]
struct CacheLabels {
    result: &'static str,
}

type HistogramFamily<L> = Family<L, Histogram, fn() -> Histogram>;

fn http_histogram() -> Histogram {
    Histogram::new(exponential_buckets(0.000_25, 2.0, 16))
}

fn job_histogram() -> Histogram {
    Histogram::new(exponential_buckets(0.01, 2.0, 16))
}

/// The process's metrics.
#[derive(Debug)]
pub struct Metrics {
    registry: Registry,
    http: HistogramFamily<HttpLabels>,
    jobs: Family<StatusLabels, Gauge>,
    job_duration: HistogramFamily<JobLabels>,
    stage_duration: HistogramFamily<StageLabels>,
    /// Attempts running in this process.
    pub jobs_in_flight: Gauge,
    tree_cache: Family<CacheLabels, Counter>,
}

impl Default for Metrics {
    fn default() -> Self {
        let mut registry = Registry::with_prefix("treemorph");
        let http = HistogramFamily::<HttpLabels>::new_with_constructor(
            http_histogram as fn() -> Histogram,
        );
        let jobs = Family::<StatusLabels, Gauge>::default();
        let job_duration =
            HistogramFamily::<JobLabels>::new_with_constructor(job_histogram as fn() -> Histogram);
        let stage_duration = HistogramFamily::<StageLabels>::new_with_constructor(
            job_histogram as fn() -> Histogram,
        );
        let jobs_in_flight = Gauge::default();
        let tree_cache = Family::<CacheLabels, Counter>::default();
        registry.register(
            "http_request_duration_seconds",
            "HTTP request latency by route template and status",
            http.clone(),
        );
        registry.register(
            "jobs",
            "Jobs by status (queued = queue depth)",
            jobs.clone(),
        );
        registry.register(
            "job_duration_seconds",
            "Duration of job attempts by kind and outcome",
            job_duration.clone(),
        );
        registry.register(
            "job_stage_duration_seconds",
            "Time spent in each pipeline stage by kind",
            stage_duration.clone(),
        );
        registry.register(
            "jobs_in_flight",
            "Job attempts running in this process",
            jobs_in_flight.clone(),
        );
        registry.register(
            "tree_cache_lookups",
            "Input trees found in the tree cache (hit) or loaded from the blob store (miss)",
            tree_cache.clone(),
        );
        Metrics {
            registry,
            http,
            jobs,
            job_duration,
            stage_duration,
            jobs_in_flight,
            tree_cache,
        }
    }
}

impl Metrics {
    /// Records one HTTP request.
    pub fn observe_http(&self, method: &str, route: &str, status: u16, elapsed: Duration) {
        self.http
            .get_or_create(&HttpLabels {
                method: method.to_owned(),
                route: route.to_owned(),
                status,
            })
            .observe(elapsed.as_secs_f64());
    }

    /// Records one job attempt.
    pub fn observe_job(&self, kind: &str, outcome: &str, elapsed: Duration) {
        self.job_duration
            .get_or_create(&JobLabels {
                kind: kind.to_owned(),
                outcome: outcome.to_owned(),
            })
            .observe(elapsed.as_secs_f64());
    }

    /// Records the time spent in one stage.
    pub fn observe_stage(&self, kind: &str, stage: &str, elapsed: Duration) {
        self.stage_duration
            .get_or_create(&StageLabels {
                kind: kind.to_owned(),
                stage: stage.to_owned(),
            })
            .observe(elapsed.as_secs_f64());
    }

    /// Records one tree-cache lookup by a worker.
    pub fn observe_tree_cache(&self, hit: bool) {
        let result = if hit { "hit" } else { "miss" };
        self.tree_cache.get_or_create(&CacheLabels { result }).inc();
    }

    /// Encodes every metric, with the job counts given (from the database).
    pub fn encode(&self, job_counts: &[(String, i64)]) -> String {
        for status in treemorph_api::jobs::JobStatus::ALL {
            let n = job_counts
                .iter()
                .find(|(s, _)| s == status.as_str())
                .map_or(0, |(_, n)| *n);
            self.jobs
                .get_or_create(&StatusLabels {
                    status: status.as_str().to_owned(),
                })
                .set(n);
        }
        let mut out = String::new();
        prometheus_client::encoding::text::encode(&mut out, &self.registry)
            .expect("writing to a String cannot fail");
        out
    }
}

/// Installs the log subscriber (`RUST_LOG`, default `info`); a second call
/// is harmless.
pub fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,sqlx=warn"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_encode_with_the_documented_names() {
        let m = Metrics::default();
        m.observe_http("GET", "/v1/jobs/{id}", 200, Duration::from_millis(3));
        m.observe_job("morph", "succeeded", Duration::from_secs(2));
        m.observe_stage("morph", "frames", Duration::from_secs(1));
        m.jobs_in_flight.inc();
        let text = m.encode(&[("queued".into(), 4)]);
        for needle in [
            "treemorph_http_request_duration_seconds_count{method=\"GET\",route=\"/v1/jobs/{id}\",status=\"200\"} 1",
            "treemorph_http_request_duration_seconds_bucket{",
            "treemorph_jobs{status=\"queued\"} 4",
            "treemorph_jobs{status=\"running\"} 0",
            "treemorph_job_duration_seconds_count{kind=\"morph\",outcome=\"succeeded\"} 1",
            "treemorph_job_stage_duration_seconds_sum{kind=\"morph\",stage=\"frames\"}",
            "treemorph_jobs_in_flight 1",
        ] {
            assert!(text.contains(needle), "{needle} missing from\n{text}");
        }
    }
}
