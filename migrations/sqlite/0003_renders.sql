-- Renders kept in the blob store (--render-store-mb): one row per stored
-- render, for least-recently-used eviction under the cap.
CREATE TABLE renders (
    key TEXT PRIMARY KEY,
    job_id TEXT NOT NULL,
    bytes INTEGER NOT NULL,
    used_at INTEGER NOT NULL
);
CREATE INDEX renders_used_at ON renders (used_at);
