//! Queue semantics: claims, fencing of stale attempts, reclaim, release,
//! cancel and idempotency — against a SQLite file, and (the `postgres_*`
//! twins, ignored by default) against the PostgreSQL server named by
//! `TREEMORPH_TEST_POSTGRES_URL` (e.g. `postgres://postgres@127.0.0.1:5432`;
//! each test creates its own database there).

use super::*;
use crate::store::new_id;

/// A fresh migrated database (the guard keeps a SQLite file alive).
async fn fresh(backend: Backend) -> (Option<tempfile::TempDir>, Db) {
    let (dir, url) = match backend {
        Backend::Sqlite => {
            let dir = tempfile::tempdir().unwrap();
            let url = format!("sqlite://{}/q.db?mode=rwc", dir.path().display());
            (Some(dir), url)
        }
        Backend::Postgres => {
            let admin = std::env::var("TREEMORPH_TEST_POSTGRES_URL")
                .expect("set TREEMORPH_TEST_POSTGRES_URL to run the PostgreSQL tests");
            let admin = admin.trim_end_matches('/').to_owned();
            let name = format!("treemorph_test_{}", new_id());
            let db = Db::connect(&format!("{admin}/postgres")).await.unwrap();
            sqlx::query(sqlx::AssertSqlSafe(format!("CREATE DATABASE {name}")))
                .execute(&db.pool)
                .await
                .unwrap();
            (None, format!("{admin}/{name}"))
        }
    };
    let db = Db::connect(&url).await.unwrap();
    assert_eq!(db.backend, backend);
    db.migrate().await.unwrap();
    (dir, db)
}

/// Declares a queue test for SQLite and its ignored PostgreSQL twin.
macro_rules! on_both {
    ($name:ident, $pg:ident, $body:ident) => {
        #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
        async fn $name() {
            let (_dir, db) = fresh(Backend::Sqlite).await;
            $body(db).await;
        }

        #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
        #[ignore = "needs TREEMORPH_TEST_POSTGRES_URL"]
        async fn $pg() {
            let (_dir, db) = fresh(Backend::Postgres).await;
            $body(db).await;
        }
    };
}

on_both!(
    a_stale_attempt_cannot_publish_or_finish_after_a_newer_claim,
    postgres_a_stale_attempt_cannot_publish_or_finish_after_a_newer_claim,
    stale_attempt
);
on_both!(
    claims_are_exclusive_and_oldest_first,
    postgres_claims_are_exclusive_and_oldest_first,
    exclusive_claims
);
on_both!(
    expired_leases_fail_when_attempts_are_used_up,
    postgres_expired_leases_fail_when_attempts_are_used_up,
    attempts_used_up
);
on_both!(
    release_does_not_count_the_attempt,
    postgres_release_does_not_count_the_attempt,
    release_uncounted
);
on_both!(
    cancel_queued_running_and_finished,
    postgres_cancel_queued_running_and_finished,
    cancels
);
on_both!(
    idempotency_keys_return_the_first_job_or_refuse_a_different_body,
    postgres_idempotency_keys_return_the_first_job_or_refuse_a_different_body,
    idempotency
);

fn job(key: Option<&str>, hash: &str) -> NewJob {
    NewJob {
        id: new_id(),
        owner: "o".into(),
        kind: JobKind::Morph,
        request: "{}".into(),
        tree_a: new_id(),
        tree_b: None,
        frames: 4,
        idempotency_key: key.map(str::to_owned),
        request_hash: hash.into(),
        callback_url: None,
    }
}

async fn expire_lease(db: &Db, id: &str) {
    sqlx::query("UPDATE jobs SET lease_expires_at = 0 WHERE id = $1")
        .bind(id)
        .execute(&db.pool)
        .await
        .unwrap();
}

async fn stale_attempt(db: Db) {
    let Created::New(row) = create(&db, &job(None, "h")).await.unwrap() else {
        panic!("not created")
    };
    let first = claim(&db, "w1", 60_000).await.unwrap().unwrap();
    assert_eq!(first.row.id, row.id);
    assert_eq!(first.row.attempt, 1);
    assert!(publish_header(&db, &row.id, &first.token).await.unwrap());
    assert!(
        publish_frames(&db, &row.id, &first.token, 1, 0.2)
            .await
            .unwrap()
    );

    // Attempt 1 stalls; its lease expires and attempt 2 claims the job.
    expire_lease(&db, &row.id).await;
    assert_eq!(reclaim_expired(&db, 5).await.unwrap(), 1);
    let second = claim(&db, "w2", 60_000).await.unwrap().unwrap();
    assert_eq!(second.row.attempt, 2);
    assert_ne!(second.token, first.token);
    // The claim names the new attempt and resets what is published.
    assert_eq!(
        second.row.published_token.as_deref(),
        Some(second.token.as_str())
    );
    assert_eq!(second.row.frames_ready, 0);

    // Attempt 1 wakes up: every write is fenced.
    assert!(
        !publish_frames(&db, &row.id, &first.token, 2, 0.5)
            .await
            .unwrap()
    );
    assert!(!publish_header(&db, &row.id, &first.token).await.unwrap());
    assert!(
        !set_progress(&db, &row.id, &first.token, "frames", 0.9)
            .await
            .unwrap()
    );
    assert_eq!(
        renew(&db, &row.id, &first.token, 1000).await.unwrap(),
        Lease::Lost
    );
    assert!(
        !retry_later(&db, &row.id, &first.token, 0, "x")
            .await
            .unwrap()
    );
    assert!(!release(&db, &row.id, &first.token).await.unwrap());
    let done = StoredResult {
        frames: 4,
        metrics: serde_json::json!({}),
        files: vec![],
        frame_glbs: false,
        render_version: crate::pipeline::RENDER_VERSION,
    };
    assert!(
        finish(&db, &row.id, &first.token, End::Succeeded(done.clone()))
            .await
            .unwrap()
            .is_none()
    );
    let now = get_any(&db, &row.id).await.unwrap().unwrap();
    assert_eq!(now.status, JobStatus::Running);
    assert_eq!(now.frames_ready, 0);

    // Attempt 2 proceeds normally.
    assert!(
        publish_frames(&db, &row.id, &second.token, 1, 0.3)
            .await
            .unwrap()
    );
    let end = finish(&db, &row.id, &second.token, End::Succeeded(done))
        .await
        .unwrap()
        .unwrap();
    assert_eq!(end.status, JobStatus::Succeeded);
    assert_eq!(end.attempt, 2);
    assert_eq!(end.lease_token, None);
}

async fn exclusive_claims(db: Db) {
    let mut ids = vec![];
    for _ in 0..6 {
        let Created::New(r) = create(&db, &job(None, "h")).await.unwrap() else {
            panic!()
        };
        ids.push(r.id);
    }
    let mut handles = vec![];
    for w in 0..6 {
        let db = db.clone();
        handles.push(tokio::spawn(async move {
            claim(&db, &format!("w{w}"), 60_000)
                .await
                .unwrap()
                .map(|c| c.row.id)
        }));
    }
    let mut claimed = vec![];
    for h in handles {
        claimed.push(h.await.unwrap().unwrap());
    }
    claimed.sort();
    let mut expected = ids.clone();
    expected.sort();
    assert_eq!(claimed, expected, "every job claimed exactly once");
    assert!(claim(&db, "w", 60_000).await.unwrap().is_none());
    assert_eq!(queued_count(&db).await.unwrap(), 0);
}

async fn attempts_used_up(db: Db) {
    let Created::New(row) = create(&db, &job(None, "h")).await.unwrap() else {
        panic!()
    };
    for attempt in 1..=2 {
        let c = claim(&db, "w", 60_000).await.unwrap().unwrap();
        assert_eq!(c.row.attempt, attempt);
        expire_lease(&db, &row.id).await;
        reclaim_expired(&db, 2).await.unwrap();
    }
    let end = get_any(&db, &row.id).await.unwrap().unwrap();
    assert_eq!(end.status, JobStatus::Failed);
    assert_eq!(end.error_code.as_deref(), Some("internal"));
}

async fn release_uncounted(db: Db) {
    let Created::New(row) = create(&db, &job(None, "h")).await.unwrap() else {
        panic!()
    };
    let c = claim(&db, "w", 60_000).await.unwrap().unwrap();
    assert!(release(&db, &row.id, &c.token).await.unwrap());
    let r = get_any(&db, &row.id).await.unwrap().unwrap();
    assert_eq!((r.status, r.attempt), (JobStatus::Queued, 0));
    let c = claim(&db, "w", 60_000).await.unwrap().unwrap();
    assert_eq!(c.row.attempt, 1);
}

async fn cancels(db: Db) {
    let Created::New(a) = create(&db, &job(None, "h")).await.unwrap() else {
        panic!()
    };
    assert!(matches!(
        cancel(&db, "o", &a.id).await.unwrap(),
        Cancel::Cancelled(_)
    ));
    assert!(matches!(
        cancel(&db, "o", &a.id).await.unwrap(),
        Cancel::AlreadyCancelled(_)
    ));
    assert!(matches!(
        cancel(&db, "other", &a.id).await.unwrap(),
        Cancel::NotFound
    ));
    let Created::New(b) = create(&db, &job(None, "h")).await.unwrap() else {
        panic!()
    };
    let c = claim(&db, "w", 60_000).await.unwrap().unwrap();
    assert!(matches!(
        cancel(&db, "o", &b.id).await.unwrap(),
        Cancel::Requested(_)
    ));
    assert_eq!(
        renew(&db, &b.id, &c.token, 1000).await.unwrap(),
        Lease::Held {
            cancel_requested: true
        }
    );
    let end = End::Failed {
        code: ErrorCode::Internal,
        message: "x".into(),
    };
    finish(&db, &b.id, &c.token, end).await.unwrap().unwrap();
    assert!(matches!(
        cancel(&db, "o", &b.id).await.unwrap(),
        Cancel::Finished(_)
    ));
}

async fn idempotency(db: Db) {
    let Created::New(first) = create(&db, &job(Some("k"), "h1")).await.unwrap() else {
        panic!()
    };
    match create(&db, &job(Some("k"), "h1")).await.unwrap() {
        Created::Existing(r) => assert_eq!(r.id, first.id),
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        create(&db, &job(Some("k"), "h2")).await.unwrap(),
        Created::KeyReused
    ));
    // Another owner may use the same key.
    let mut other = job(Some("k"), "h2");
    other.owner = "p".into();
    assert!(matches!(
        create(&db, &other).await.unwrap(),
        Created::New(_)
    ));
}

#[test]
fn progress_reads_rounded_to_four_decimals() {
    // Regression: progress computed in f32 and stored as f64 read back as
    // 0.07999999821186066 in the job document and SSE.
    assert_eq!(rounded_progress(f64::from(0.08f32)), 0.08);
    assert_eq!(rounded_progress(f64::from(0.1f32 + 0.85 / 3.0)), 0.3833);
    assert_eq!(rounded_progress(-0.5), 0.0);
    assert_eq!(rounded_progress(1.2), 1.0);
    let json = serde_json::to_string(&(rounded_progress(f64::from(0.08f32)) as f32)).unwrap();
    assert_eq!(json, "0.08");
}
