//! [`Settings`]: every knob of `treemorph serve`, as flags with environment
//! variables (`TREEMORPH_*`). The defaults run on one machine with no
//! external service: SQLite and local blobs under `--data-dir`.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use clap::{Parser, ValueEnum};

/// What a process does.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Role {
    /// Serve the HTTP API only (no job is run here).
    Api,
    /// Run jobs only (and deliver webhooks); serves only `/healthz`,
    /// `/readyz` and `/metrics`.
    Worker,
    /// Both (the default: one process does everything).
    All,
}

impl Role {
    /// Whether this process runs workers.
    pub fn runs_workers(self) -> bool {
        matches!(self, Role::Worker | Role::All)
    }

    /// Whether this process serves the `/v1` API.
    pub fn serves_api(self) -> bool {
        matches!(self, Role::Api | Role::All)
    }
}

/// Settings of `treemorph serve`.
#[derive(Clone, Debug, Parser)]
#[command(name = "treemorph-serve")]
pub struct Settings {
    /// Address to listen on (port 0 picks a free port; the bound address is
    /// printed on stdout as `listening on http://ADDR`).
    #[arg(long, env = "TREEMORPH_LISTEN", default_value = "127.0.0.1:8080")]
    pub listen: SocketAddr,
    /// Directory for the default database, blobs, temporary uploads and the
    /// generated webhook secret.
    #[arg(long, env = "TREEMORPH_DATA_DIR", default_value = "treemorph-data")]
    pub data_dir: PathBuf,
    /// Database URL [default: sqlite://{data_dir}/treemorph.db?mode=rwc];
    /// `postgres://…` for several processes on several machines.
    #[arg(long, env = "TREEMORPH_DATABASE_URL")]
    pub database_url: Option<String>,
    /// Blob store URL [default: file://{data_dir}/blobs]; `s3://bucket/prefix`
    /// takes credentials and region from the `AWS_*` environment.
    #[arg(long, env = "TREEMORPH_BLOB_URL")]
    pub blob_url: Option<String>,
    /// What this process does.
    #[arg(long, env = "TREEMORPH_ROLE", value_enum, default_value = "all")]
    pub role: Role,
    /// Concurrent jobs in this process [default: the number of cores].
    #[arg(long, env = "TREEMORPH_WORKERS")]
    pub workers: Option<usize>,
    /// Most jobs waiting in the queue; more get 429 `queue_full`.
    #[arg(long, env = "TREEMORPH_MAX_QUEUED", default_value_t = 1000)]
    pub max_queued: u64,
    /// Attempts per job before a transient failure becomes final.
    #[arg(long, env = "TREEMORPH_MAX_ATTEMPTS", default_value_t = 3)]
    pub max_attempts: u32,
    /// Lease duration in seconds: a worker that has not renewed its lease
    /// for this long is presumed dead and its job is run again.
    #[arg(long, env = "TREEMORPH_LEASE_SECS", default_value_t = 30)]
    pub lease_secs: u64,
    /// Seconds in-flight jobs get to finish after SIGTERM before they are
    /// released back to the queue.
    #[arg(long, env = "TREEMORPH_SHUTDOWN_GRACE", default_value_t = 30)]
    pub shutdown_grace: u64,
    /// Webhook signing secret (`whsec_` + base64) [default: generated at
    /// first start and kept in {data_dir}/webhook-secret].
    #[arg(long, env = "TREEMORPH_WEBHOOK_SECRET", hide_env_values = true)]
    pub webhook_secret: Option<String>,
    /// Accept callback URLs on loopback and private networks (tests and
    /// closed deployments).
    #[arg(long, env = "TREEMORPH_ALLOW_PRIVATE_CALLBACKS")]
    pub allow_private_callbacks: bool,
    /// API keys (comma-separated). Without keys (and no keys file) the API
    /// is open and everything belongs to one anonymous owner.
    #[arg(
        long,
        env = "TREEMORPH_API_KEYS",
        value_delimiter = ',',
        hide_env_values = true
    )]
    pub api_keys: Vec<String>,
    /// File with one API key per line (`#` comments allowed).
    #[arg(long, env = "TREEMORPH_API_KEYS_FILE")]
    pub api_keys_file: Option<PathBuf>,
    /// Requests per second per API key (token bucket); 0 disables.
    #[arg(long, env = "TREEMORPH_RATE_LIMIT", default_value_t = 0.0)]
    pub rate_limit: f64,
    /// Burst size of the rate limit (bucket capacity).
    #[arg(long, env = "TREEMORPH_RATE_BURST", default_value_t = 50)]
    pub rate_burst: u32,
    /// Directory of the web viewer (`index.html`, its modules and, after
    /// `npm ci --prefix web`, `node_modules/` with three.js), served at `/`.
    #[arg(long, env = "TREEMORPH_WEB_DIR", default_value = "web")]
    pub web_dir: PathBuf,
    /// Origins allowed by CORS (comma-separated; `*` for any). None by
    /// default.
    #[arg(long, env = "TREEMORPH_CORS_ORIGINS", value_delimiter = ',')]
    pub cors_origins: Vec<String>,
    /// Seconds a request may take (not the SSE and stream routes, which
    /// last as long as their job, nor a tree upload's body, which may take
    /// as long as it keeps arriving above `--min-body-rate`).
    #[arg(long, env = "TREEMORPH_REQUEST_TIMEOUT", default_value_t = 60)]
    pub request_timeout: u64,
    /// Seconds a client has to send a request's headers (slow-client
    /// protection).
    #[arg(long, env = "TREEMORPH_HEADER_READ_TIMEOUT", default_value_t = 10)]
    pub header_read_timeout: u64,
    /// Least average rate, in bytes per second, at which a request body
    /// must arrive once the header timeout has passed (and no gap in it
    /// may last longer than the header timeout): slow-body protection.
    /// 0 turns the rate check off.
    #[arg(long, env = "TREEMORPH_MIN_BODY_RATE", default_value_t = 1024)]
    pub min_body_rate: u64,
    /// Largest tree upload in bytes.
    #[arg(long, env = "TREEMORPH_MAX_UPLOAD_BYTES", default_value_t = 64 * 1024 * 1024)]
    pub max_upload_bytes: u64,
    /// Memory for outputs rendered on request (per-frame GLBs, the
    /// animated GLB, `frame.glb?t=`, re-sampled sequences), in MiB; 0
    /// keeps none (concurrent requests for one output still render it
    /// once).
    #[arg(long, env = "TREEMORPH_RENDER_CACHE_MB", default_value_t = 256)]
    pub render_cache_mb: u64,
    /// Blob-store space for outputs rendered on request, in MiB, over the
    /// whole store: renders survive restarts and are shared by every API
    /// process; the least recently used go first. 0 stores none.
    #[arg(long, env = "TREEMORPH_RENDER_STORE_MB", default_value_t = 4096)]
    pub render_store_mb: u64,
    /// Storage quota per API key, in MiB: the bytes its trees and job
    /// outputs take. An upload that would exceed it, or a job while the
    /// key is at it, answers 507 `quota_exceeded`. 0: no quota.
    #[arg(long, env = "TREEMORPH_MAX_STORED_MB_PER_KEY", default_value_t = 0)]
    pub max_stored_mb_per_key: u64,
    /// Most frames a job may request.
    #[arg(long, env = "TREEMORPH_MAX_FRAMES", default_value_t = 600)]
    pub max_frames: u32,
    /// Memory for parsed and analysed input trees kept between jobs and
    /// renders on request, in MiB (measured by the trees' stored JSON
    /// size); 0 turns the cache off.
    #[arg(long, env = "TREEMORPH_TREE_CACHE_MB", default_value_t = 256)]
    pub tree_cache_mb: u64,
    /// Milliseconds between database polls of SSE and stream subscribers
    /// and idle workers (the cross-process path; in-process changes are
    /// pushed at once).
    #[arg(long, env = "TREEMORPH_POLL_MS", default_value_t = 150)]
    pub poll_ms: u64,
    /// How long an ended job (succeeded, failed or cancelled) and its
    /// outputs are kept, counted from its end: seconds, or a duration
    /// such as `7d`, `12h`, `30m`; 0 keeps them forever.
    #[arg(long, env = "TREEMORPH_RESULT_TTL", default_value = "7d")]
    pub result_ttl: Ttl,
    /// Seconds between sweeps: expiring ended jobs past `--result-ttl`
    /// and removing what a crash left behind (upload spool files, blobs
    /// without a row). Every process also sweeps when it starts.
    #[arg(long, env = "TREEMORPH_SWEEP_SECS", default_value_t = 600)]
    pub sweep_secs: u64,
    /// TEST ONLY: replace the pipeline by a synthetic runner
    /// (`slow:MS_PER_FRAME`). Used by the crash and shutdown tests, which
    /// run the real binary.
    #[arg(long, env = "TREEMORPH_TEST_RUNNER", hide = true)]
    pub test_runner: Option<String>,
}

/// A retention period; `None` keeps forever.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ttl(pub Option<Duration>);

impl std::str::FromStr for Ttl {
    type Err = String;

    /// `0` (forever), whole seconds, or a duration such as `7d`, `1h 30m`.
    fn from_str(s: &str) -> Result<Ttl, String> {
        let s = s.trim();
        let duration = match s.parse::<u64>() {
            Ok(secs) => Duration::from_secs(secs),
            Err(_) => humantime::parse_duration(s)
                .map_err(|e| format!("{s:?} is not a duration (e.g. 7d, 12h, 3600): {e}"))?,
        };
        Ok(Ttl((!duration.is_zero()).then_some(duration)))
    }
}

impl Settings {
    /// Defaults with the data directory `dir` (for tests and embedding).
    pub fn with_data_dir(dir: impl Into<PathBuf>) -> Settings {
        let mut s = Settings::parse_from(["treemorph-serve"]);
        s.data_dir = dir.into();
        s
    }

    /// The limits job requests are checked against.
    pub fn limits(&self) -> crate::pipeline::Limits {
        crate::pipeline::Limits::default().with_max_frames(self.max_frames)
    }

    /// The database URL in effect.
    pub fn database_url(&self) -> String {
        self.database_url.clone().unwrap_or_else(|| {
            format!("sqlite://{}/treemorph.db?mode=rwc", self.data_dir.display())
        })
    }

    /// The blob store URL in effect.
    pub fn blob_url(&self) -> anyhow::Result<String> {
        match &self.blob_url {
            Some(u) => Ok(u.clone()),
            None => {
                let dir = self.data_dir.join("blobs");
                std::fs::create_dir_all(&dir)?;
                let dir = std::fs::canonicalize(dir)?;
                Ok(url::Url::from_directory_path(&dir)
                    .map_err(|()| anyhow::anyhow!("bad data directory {}", dir.display()))?
                    .to_string())
            }
        }
    }

    /// Worker count in effect.
    pub fn worker_count(&self) -> usize {
        self.workers.unwrap_or_else(|| {
            std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(2)
        })
    }

    /// The lease duration.
    pub fn lease(&self) -> Duration {
        Duration::from_secs(self.lease_secs.max(1))
    }

    /// The poll interval.
    pub fn poll(&self) -> Duration {
        Duration::from_millis(self.poll_ms.clamp(10, 5000))
    }

    /// All configured API keys (flag, environment and keys file).
    pub fn all_api_keys(&self) -> anyhow::Result<Vec<String>> {
        let mut keys: Vec<String> = self
            .api_keys
            .iter()
            .map(|k| k.trim().to_owned())
            .filter(|k| !k.is_empty())
            .collect();
        if let Some(file) = &self.api_keys_file {
            let text = std::fs::read_to_string(file)
                .map_err(|e| anyhow::anyhow!("reading {}: {e}", file.display()))?;
            keys.extend(
                text.lines()
                    .map(str::trim)
                    .filter(|l| !l.is_empty() && !l.starts_with('#'))
                    .map(str::to_owned),
            );
        }
        Ok(keys)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_run_locally() {
        let s = Settings::with_data_dir("/tmp/x");
        assert_eq!(s.database_url(), "sqlite:///tmp/x/treemorph.db?mode=rwc");
        assert_eq!(s.role, Role::All);
        assert_eq!(s.max_frames, 600);
        assert!(s.worker_count() >= 1);
        assert_eq!(s.result_ttl, Ttl(Some(Duration::from_secs(7 * 86_400))));
    }

    #[test]
    fn result_ttls_parse() {
        let ttl = |s: &str| s.parse::<Ttl>().map(|t| t.0);
        assert_eq!(ttl("0"), Ok(None));
        assert_eq!(ttl("90"), Ok(Some(Duration::from_secs(90))));
        assert_eq!(ttl("12h"), Ok(Some(Duration::from_secs(12 * 3600))));
        assert_eq!(ttl("1h 30m"), Ok(Some(Duration::from_secs(5400))));
        assert!(
            ttl("soon")
                .unwrap_err()
                .contains("\"soon\" is not a duration")
        );
        assert!(ttl("-5").is_err());
    }

    #[test]
    fn flags_parse() {
        let s = Settings::parse_from([
            "x",
            "--api-keys",
            "a, b",
            "--role",
            "worker",
            "--cors-origins",
            "https://a.example,https://b.example",
        ]);
        assert_eq!(s.all_api_keys().unwrap(), ["a", "b"]);
        assert_eq!(s.role, Role::Worker);
        assert_eq!(s.cors_origins.len(), 2);
    }
}
