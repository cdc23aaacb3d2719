-- Bytes of blobs each tree and job stores, for per-key storage quotas
-- (--max-stored-mb-per-key). Rows from before this migration count 0.
ALTER TABLE trees ADD COLUMN stored_bytes INTEGER NOT NULL DEFAULT 0;
ALTER TABLE jobs ADD COLUMN stored_bytes INTEGER NOT NULL DEFAULT 0;
