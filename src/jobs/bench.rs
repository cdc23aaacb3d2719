//! The queue's claim latency under contention, for `treemorph bench` and
//! `benches/scaleout.sh`.
//!
//! [`claim_latency`] connects `processes` independent pools to one database
//! (as that many worker processes would), queues `jobs` rows and lets
//! `claimers` tasks per pool [`queue::claim`] until the queue is empty,
//! timing every successful claim. On SQLite the claimers of one pool queue
//! for its single writer connection and the pools contend for the file's
//! write lock (`busy_timeout`); on PostgreSQL every claimer has its own
//! connection and `FOR UPDATE SKIP LOCKED` lets them pass each other.

use std::time::{Duration, Instant};

use treemorph_api::jobs::JobKind;

use super::queue::{self, Created, NewJob};
use crate::store::{Db, new_id};

/// What [`claim_latency`] measured.
#[derive(Clone, Debug, PartialEq)]
pub struct ClaimLatency {
    /// Successful claims (equals the jobs queued).
    pub claims: usize,
    /// Median time of one claim (both statements: the due-job read and the
    /// claiming update).
    pub p50: Duration,
    /// 99th percentile.
    pub p99: Duration,
    /// Claims per second over the whole run, all claimers together.
    pub per_second: f64,
}

/// Queues `jobs` jobs in the (migrated) database at `url` and claims them
/// all with `claimers` concurrent tasks in each of `processes` pools.
///
/// Errors: database errors, and [`sqlx::Error::Protocol`] when a job was
/// claimed twice or not at all (a broken queue).
pub async fn claim_latency(
    url: &str,
    jobs: usize,
    processes: usize,
    claimers: usize,
) -> Result<ClaimLatency, sqlx::Error> {
    let first = Db::connect(url).await?;
    first.migrate().await?;
    for _ in 0..jobs {
        let job = NewJob {
            id: new_id(),
            owner: "bench".into(),
            kind: JobKind::Morph,
            request: "{}".into(),
            tree_a: "a".into(),
            tree_b: Some("b".into()),
            frames: 2,
            idempotency_key: None,
            request_hash: "bench".into(),
            callback_url: None,
        };
        if !matches!(queue::create(&first, &job).await?, Created::New(_)) {
            return Err(sqlx::Error::Protocol("a bench job was not created".into()));
        }
    }
    let mut pools = vec![first];
    for _ in 1..processes.max(1) {
        pools.push(Db::connect(url).await?);
    }
    let started = Instant::now();
    let mut tasks = tokio::task::JoinSet::new();
    for (p, db) in pools.iter().enumerate() {
        for c in 0..claimers.max(1) {
            let db = db.clone();
            let name = format!("bench-{p}-{c}");
            tasks.spawn(async move {
                let mut times = Vec::new();
                let mut ids = Vec::new();
                loop {
                    let t = Instant::now();
                    match queue::claim(&db, &name, 60_000).await? {
                        Some(claim) => {
                            times.push(t.elapsed());
                            ids.push(claim.row.id);
                        }
                        None => return Ok::<_, sqlx::Error>((times, ids)),
                    }
                }
            });
        }
    }
    let (mut times, mut ids) = (Vec::new(), Vec::new());
    while let Some(joined) = tasks.join_next().await {
        let (t, i) = joined.map_err(|e| sqlx::Error::Protocol(e.to_string()))??;
        times.extend(t);
        ids.extend(i);
    }
    let elapsed = started.elapsed();
    ids.sort();
    ids.dedup();
    if ids.len() != jobs || times.len() != jobs {
        return Err(sqlx::Error::Protocol(format!(
            "{jobs} jobs queued, {} claims of {} distinct jobs",
            times.len(),
            ids.len()
        )));
    }
    times.sort();
    let at = |q: f64| {
        times
            .get(((times.len() as f64 * q).ceil() as usize).saturating_sub(1))
            .copied()
            .unwrap_or_default()
    };
    Ok(ClaimLatency {
        claims: times.len(),
        p50: at(0.5),
        p99: at(0.99),
        per_second: times.len() as f64 / elapsed.as_secs_f64().max(1e-9),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn every_job_is_claimed_once_by_contending_pools() {
        let dir = tempfile::tempdir().unwrap();
        let url = format!("sqlite://{}/q.db?mode=rwc", dir.path().display());
        let r = claim_latency(&url, 40, 3, 2).await.unwrap();
        assert_eq!(r.claims, 40);
        assert!(r.p50 <= r.p99);
        assert!(r.per_second > 0.0);
    }

    /// Prints the claim latency on SQLite and, with
    /// `TREEMORPH_TEST_POSTGRES_URL`, PostgreSQL:
    /// `cargo test --release -p treemorph --lib claim_latency_report -- --ignored --nocapture`.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    #[ignore = "timing report; run in release with --nocapture"]
    async fn claim_latency_report() {
        let (jobs, processes, claimers) = (2000, 3, 4);
        let dir = tempfile::tempdir().unwrap();
        let mut targets = vec![(
            "sqlite",
            format!("sqlite://{}/q.db?mode=rwc", dir.path().display()),
        )];
        if let Ok(admin) = std::env::var("TREEMORPH_TEST_POSTGRES_URL") {
            let admin = admin.trim_end_matches('/').to_owned();
            let name = format!("treemorph_claims_{}", new_id());
            let server = Db::connect(&format!("{admin}/postgres")).await.unwrap();
            sqlx::query(sqlx::AssertSqlSafe(format!("CREATE DATABASE {name}")))
                .execute(&server.pool)
                .await
                .unwrap();
            targets.push(("postgres", format!("{admin}/{name}")));
        }
        for (name, url) in targets {
            let r = claim_latency(&url, jobs, processes, claimers)
                .await
                .unwrap();
            println!(
                "claim latency, {name}: {jobs} jobs, {processes} pools x {claimers} claimers: \
                 p50 {:.2} ms, p99 {:.2} ms, {:.0} claims/s",
                r.p50.as_secs_f64() * 1e3,
                r.p99.as_secs_f64() * 1e3,
                r.per_second
            );
        }
    }
}
