-- treemorph schema, SQLite flavour. Ids are TEXT (32 hex digits), times are
-- INTEGER milliseconds since the Unix epoch, JSON documents are TEXT.

CREATE TABLE trees (
    id TEXT PRIMARY KEY,
    owner TEXT NOT NULL,
    name TEXT NOT NULL,
    format TEXT NOT NULL,
    stats TEXT NOT NULL,
    created_at INTEGER NOT NULL
);
CREATE INDEX trees_by_owner ON trees (owner, created_at DESC, id DESC);

CREATE TABLE jobs (
    id TEXT PRIMARY KEY,
    owner TEXT NOT NULL,
    kind TEXT NOT NULL,
    request TEXT NOT NULL,
    tree_a TEXT NOT NULL,
    tree_b TEXT,
    frames INTEGER NOT NULL,
    status TEXT NOT NULL,
    stage TEXT,
    progress DOUBLE PRECISION NOT NULL DEFAULT 0,
    attempt INTEGER NOT NULL DEFAULT 0,
    lease_token TEXT,
    lease_expires_at INTEGER,
    worker TEXT,
    run_after INTEGER NOT NULL,
    cancel_requested INTEGER NOT NULL DEFAULT 0,
    published_token TEXT,
    header_ready INTEGER NOT NULL DEFAULT 0,
    frames_ready INTEGER NOT NULL DEFAULT 0,
    result TEXT,
    error_code TEXT,
    error_message TEXT,
    idempotency_key TEXT,
    request_hash TEXT NOT NULL,
    callback_url TEXT,
    created_at INTEGER NOT NULL,
    updated_at INTEGER NOT NULL
);
CREATE INDEX jobs_by_owner ON jobs (owner, created_at DESC, id DESC);
CREATE INDEX jobs_claimable ON jobs (status, run_after, created_at);
CREATE INDEX jobs_by_tree_a ON jobs (tree_a, status);
CREATE INDEX jobs_by_tree_b ON jobs (tree_b, status);
CREATE UNIQUE INDEX jobs_idempotency ON jobs (owner, idempotency_key) WHERE idempotency_key IS NOT NULL;

CREATE TABLE webhook_deliveries (
    id TEXT PRIMARY KEY,
    job_id TEXT NOT NULL,
    url TEXT NOT NULL,
    body TEXT NOT NULL,
    state TEXT NOT NULL,
    attempts INTEGER NOT NULL DEFAULT 0,
    next_at INTEGER NOT NULL,
    last_error TEXT,
    created_at INTEGER NOT NULL
);
CREATE INDEX webhook_deliveries_due ON webhook_deliveries (state, next_at);
