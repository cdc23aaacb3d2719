//! The metadata database: one sqlx `Any` pool for SQLite or PostgreSQL, and
//! the embedded migrations.
//!
//! # SQLite settings
//! WAL journal (readers never block the writer, so `GET /v1/jobs/{id}`
//! stays fast while workers publish frames) with `synchronous = FULL`:
//! every commit is fsynced before it returns. `NORMAL` is safe against a
//! process crash but may lose the last commits on power loss — and a lost
//! commit here is a `202` whose job vanished, or a published frame whose row
//! rolled back. WAL makes FULL cheap (one sequential fsync per commit), and
//! progress writes are throttled, so we pay it. `busy_timeout` lets
//! concurrent writers (API and workers share the file) queue instead of
//! failing; every write is a single statement or a transaction that writes
//! first, so no connection ever needs to upgrade a read lock (the case
//! `busy_timeout` cannot help with).

use std::time::Duration;

use sqlx::any::{AnyPoolOptions, AnyQueryResult};
use sqlx::{AnyPool, Executor};

/// Which database the pool talks to (the SQL differs in a few places).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    /// SQLite (a file under the data directory).
    Sqlite,
    /// PostgreSQL.
    Postgres,
}

/// The metadata database.
#[derive(Clone, Debug)]
pub struct Db {
    /// The pool for reads (and everything on PostgreSQL).
    pub pool: AnyPool,
    /// The pool for writes. On SQLite it has one connection, so the
    /// writers of this process queue in the pool (first come, first
    /// served) instead of in SQLite's busy handler, whose sleeps grow to
    /// 100 ms; on PostgreSQL it is the same pool as [`Db::pool`].
    pub writer: AnyPool,
    /// The backend.
    pub backend: Backend,
}

const SQLITE_MIGRATIONS: &[(i64, &str)] = &[
    (1, include_str!("../../migrations/sqlite/0001_init.sql")),
    (
        2,
        include_str!("../../migrations/sqlite/0002_stored_bytes.sql"),
    ),
    (3, include_str!("../../migrations/sqlite/0003_renders.sql")),
];
const POSTGRES_MIGRATIONS: &[(i64, &str)] = &[
    (1, include_str!("../../migrations/postgres/0001_init.sql")),
    (
        2,
        include_str!("../../migrations/postgres/0002_stored_bytes.sql"),
    ),
    (
        3,
        include_str!("../../migrations/postgres/0003_renders.sql"),
    ),
];

impl Db {
    /// Connects (creating the SQLite file if the URL says `mode=rwc`).
    pub async fn connect(url: &str) -> Result<Db, sqlx::Error> {
        sqlx::any::install_default_drivers();
        let backend = if url.starts_with("sqlite:") {
            Backend::Sqlite
        } else if url.starts_with("postgres:") || url.starts_with("postgresql:") {
            Backend::Postgres
        } else {
            return Err(sqlx::Error::Configuration(
                format!("unsupported database URL {url:?}: use sqlite:// or postgres://").into(),
            ));
        };
        let options = |max: u32| {
            let options = AnyPoolOptions::new()
                .max_connections(max)
                .acquire_timeout(Duration::from_secs(30));
            if backend != Backend::Sqlite {
                return options;
            }
            options.after_connect(|conn, _| {
                Box::pin(async move {
                    conn.execute("PRAGMA journal_mode = WAL").await?;
                    conn.execute("PRAGMA synchronous = FULL").await?;
                    conn.execute("PRAGMA busy_timeout = 10000").await?;
                    Ok(())
                })
            })
        };
        match backend {
            Backend::Sqlite => {
                // The writer connects first: it creates the file and turns
                // on WAL before any reader opens it.
                let writer = options(1).connect(url).await?;
                let pool = options(8).connect(url).await?;
                Ok(Db {
                    pool,
                    writer,
                    backend,
                })
            }
            Backend::Postgres => {
                let pool = options(16).connect(url).await?;
                Ok(Db {
                    writer: pool.clone(),
                    pool,
                    backend,
                })
            }
        }
    }

    /// Applies the migrations that have not been applied yet, each in its
    /// own transaction. Safe to run from several processes at once (a
    /// fleet starting together against a fresh database): on PostgreSQL an
    /// advisory lock, taken before anything else, serialises them — even
    /// `CREATE TABLE IF NOT EXISTS` is not safe unserialised there (two
    /// creators race on the catalogue's unique index); on SQLite the first
    /// write takes the database lock.
    pub async fn migrate(&self) -> Result<(), sqlx::Error> {
        let migrations = match self.backend {
            Backend::Sqlite => SQLITE_MIGRATIONS,
            Backend::Postgres => POSTGRES_MIGRATIONS,
        };
        const CREATE: &str = "CREATE TABLE IF NOT EXISTS schema_migrations \
             (version BIGINT PRIMARY KEY, applied_at BIGINT NOT NULL)";
        let mut conn = self.writer.acquire().await?;
        if self.backend == Backend::Sqlite {
            // Outside the transaction below, whose first statement must be
            // a write (a read first would need a lock upgrade later).
            sqlx::query(CREATE).execute(&mut *conn).await?;
        }
        for &(version, sql) in migrations {
            let mut tx = sqlx::Connection::begin(&mut *conn).await?;
            match self.backend {
                Backend::Postgres => {
                    sqlx::query("SELECT pg_advisory_xact_lock(7311)")
                        .execute(&mut *tx)
                        .await?;
                    sqlx::query(CREATE).execute(&mut *tx).await?;
                }
                Backend::Sqlite => {
                    // Take the write lock now, before reading the version.
                    sqlx::query("DELETE FROM schema_migrations WHERE version < 0")
                        .execute(&mut *tx)
                        .await?;
                }
            }
            let done: Option<(i64,)> =
                sqlx::query_as("SELECT version FROM schema_migrations WHERE version = $1")
                    .bind(version)
                    .fetch_optional(&mut *tx)
                    .await?;
            if done.is_none() {
                for statement in split_statements(sql) {
                    sqlx::query(sqlx::AssertSqlSafe(statement))
                        .execute(&mut *tx)
                        .await?;
                }
                sqlx::query("INSERT INTO schema_migrations (version, applied_at) VALUES ($1, $2)")
                    .bind(version)
                    .bind(super::now_ms())
                    .execute(&mut *tx)
                    .await?;
                tracing::info!(version, "applied database migration");
            }
            tx.commit().await?;
        }
        Ok(())
    }

    /// A cheap round trip, for readiness checks.
    pub async fn ping(&self) -> Result<(), sqlx::Error> {
        sqlx::query("SELECT 1")
            .execute(&self.pool)
            .await
            .map(|_: AnyQueryResult| ())
    }
}

/// Splits a migration file into statements (on `;` at the end of a line),
/// dropping `--` comment lines.
fn split_statements(sql: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut current = String::new();
    for line in sql.lines() {
        let trimmed = line.trim();
        if trimmed.starts_with("--") || trimmed.is_empty() {
            continue;
        }
        current.push_str(line);
        current.push('\n');
        if trimmed.ends_with(';') {
            out.push(std::mem::take(&mut current));
        }
    }
    if !current.trim().is_empty() {
        out.push(current);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn migrations_split_into_statements() {
        let s = split_statements("-- c\nCREATE TABLE a (x INTEGER);\n\nCREATE INDEX i ON a (x);\n");
        assert_eq!(s.len(), 2);
        assert!(s[1].starts_with("CREATE INDEX"));
        for (version, sql) in SQLITE_MIGRATIONS.iter().chain(POSTGRES_MIGRATIONS) {
            let least = if *version == 1 { 5 } else { 1 };
            assert!(split_statements(sql).len() >= least, "migration {version}");
        }
    }

    /// Several processes starting at once against a fresh PostgreSQL
    /// database (`TREEMORPH_TEST_POSTGRES_URL`, the server's URL without a
    /// database name): every one migrates, none fails, the schema is applied
    /// once.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    #[ignore = "needs TREEMORPH_TEST_POSTGRES_URL"]
    async fn concurrent_migrations_on_postgres_all_succeed() {
        let admin =
            std::env::var("TREEMORPH_TEST_POSTGRES_URL").expect("TREEMORPH_TEST_POSTGRES_URL");
        let admin = admin.trim_end_matches('/').to_owned();
        for round in 0..5 {
            let name = format!("treemorph_migrate_{}", crate::store::new_id());
            let db = Db::connect(&format!("{admin}/postgres")).await.unwrap();
            sqlx::query(sqlx::AssertSqlSafe(format!("CREATE DATABASE {name}")))
                .execute(&db.pool)
                .await
                .unwrap();
            let url = format!("{admin}/{name}");
            let mut tasks = tokio::task::JoinSet::new();
            for _ in 0..8 {
                let url = url.clone();
                tasks.spawn(async move { Db::connect(&url).await?.migrate().await });
            }
            while let Some(r) = tasks.join_next().await {
                r.unwrap().unwrap_or_else(|e| {
                    panic!("round {round}: a concurrent migration failed: {e}")
                });
            }
            let fresh = Db::connect(&url).await.unwrap();
            let (n,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM schema_migrations")
                .fetch_one(&fresh.pool)
                .await
                .unwrap();
            assert_eq!(n as usize, POSTGRES_MIGRATIONS.len());
        }
    }

    #[tokio::test]
    async fn migrations_apply_twice_without_harm() {
        let dir = tempfile::tempdir().unwrap();
        let url = format!("sqlite://{}/t.db?mode=rwc", dir.path().display());
        let db = Db::connect(&url).await.unwrap();
        db.migrate().await.unwrap();
        db.migrate().await.unwrap();
        let (n,): (i64,) = sqlx::query_as("SELECT COUNT(*) FROM schema_migrations")
            .fetch_one(&db.pool)
            .await
            .unwrap();
        assert_eq!(n as usize, SQLITE_MIGRATIONS.len());
        db.ping().await.unwrap();
    }
}
