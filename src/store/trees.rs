//! The `trees` table. Every query is scoped by `owner`: another API key's
//! tree is indistinguishable from a missing one.

use sqlx::Row;
use sqlx::any::AnyRow;
use treemorph_api::trees::{TreeInfo, TreeStats};

use super::{Db, rfc3339};

/// A stored tree's metadata.
#[derive(Clone, Debug, PartialEq)]
pub struct TreeRow {
    /// Id.
    pub id: String,
    /// Owner (API key fingerprint).
    pub owner: String,
    /// Name.
    pub name: String,
    /// `tree+json`, `glb`, `gltf` or `generated`.
    pub format: String,
    /// Analysis summary.
    pub stats: TreeStats,
    /// Creation time, ms.
    pub created_at: i64,
    /// Bytes of its blobs (per-key storage quota).
    pub stored_bytes: i64,
}

impl TreeRow {
    fn from_row(row: &AnyRow) -> Result<TreeRow, sqlx::Error> {
        let stats: String = row.try_get("stats")?;
        Ok(TreeRow {
            id: row.try_get("id")?,
            owner: row.try_get("owner")?,
            name: row.try_get("name")?,
            format: row.try_get("format")?,
            stats: serde_json::from_str(&stats).map_err(|e| sqlx::Error::Decode(e.into()))?,
            created_at: row.try_get("created_at")?,
            stored_bytes: row.try_get("stored_bytes")?,
        })
    }

    /// The wire document.
    pub fn info(&self) -> TreeInfo {
        TreeInfo {
            id: self.id.clone(),
            name: self.name.clone(),
            format: self.format.clone(),
            created_at: rfc3339(self.created_at),
            stats: self.stats.clone(),
        }
    }
}

/// The blob key prefix of a tree's files.
pub fn blob_prefix(id: &str) -> String {
    format!("trees/{id}")
}

impl Db {
    /// Inserts a tree row (after its blobs were written).
    pub async fn insert_tree(&self, tree: &TreeRow) -> Result<(), sqlx::Error> {
        sqlx::query(
            "INSERT INTO trees (id, owner, name, format, stats, created_at, stored_bytes) \
             VALUES ($1, $2, $3, $4, $5, $6, $7)",
        )
        .bind(&tree.id)
        .bind(&tree.owner)
        .bind(&tree.name)
        .bind(&tree.format)
        .bind(serde_json::to_string(&tree.stats).expect("stats serialise"))
        .bind(tree.created_at)
        .bind(tree.stored_bytes)
        .execute(&self.writer)
        .await?;
        Ok(())
    }

    /// Bytes `owner` stores: its trees' blobs and its jobs' outputs.
    pub async fn stored_bytes(&self, owner: &str) -> Result<i64, sqlx::Error> {
        let row = sqlx::query(
            "SELECT CAST((SELECT COALESCE(SUM(stored_bytes), 0) FROM trees WHERE owner = $1) \
                  + (SELECT COALESCE(SUM(stored_bytes), 0) FROM jobs WHERE owner = $1) AS BIGINT) AS total",
        )
        .bind(owner)
        .fetch_one(&self.pool)
        .await?;
        row.try_get("total")
    }

    /// The tree `id` of `owner`.
    pub async fn tree(&self, owner: &str, id: &str) -> Result<Option<TreeRow>, sqlx::Error> {
        sqlx::query("SELECT * FROM trees WHERE id = $1 AND owner = $2")
            .bind(id)
            .bind(owner)
            .fetch_optional(&self.pool)
            .await?
            .map(|r| TreeRow::from_row(&r))
            .transpose()
    }

    /// A page of `owner`'s trees, newest first, after the cursor position
    /// `(created_at, id)`; fetches `limit + 1` rows so the caller can tell
    /// whether another page exists.
    pub async fn list_trees(
        &self,
        owner: &str,
        after: Option<(i64, String)>,
        limit: u32,
    ) -> Result<Vec<TreeRow>, sqlx::Error> {
        let rows = match after {
            None => {
                sqlx::query(
                    "SELECT * FROM trees WHERE owner = $1 ORDER BY created_at DESC, id DESC LIMIT $2",
                )
                .bind(owner)
                .bind(i64::from(limit) + 1)
                .fetch_all(&self.pool)
                .await?
            }
            Some((at, id)) => {
                sqlx::query(
                    "SELECT * FROM trees WHERE owner = $1 AND (created_at < $2 OR (created_at = $2 AND id < $3)) \
                     ORDER BY created_at DESC, id DESC LIMIT $4",
                )
                .bind(owner)
                .bind(at)
                .bind(id)
                .bind(i64::from(limit) + 1)
                .fetch_all(&self.pool)
                .await?
            }
        };
        rows.iter().map(TreeRow::from_row).collect()
    }

    /// Deletes a tree unless a job that still exists uses it (a job renders
    /// frames at new instants from its trees) — in one statement, so a job
    /// cannot slip in between the check and the delete.
    pub async fn delete_tree(&self, owner: &str, id: &str) -> Result<DeleteTree, sqlx::Error> {
        let deleted = sqlx::query(
            "DELETE FROM trees WHERE id = $1 AND owner = $2 AND NOT EXISTS (\
               SELECT 1 FROM jobs WHERE tree_a = $1 OR tree_b = $1)",
        )
        .bind(id)
        .bind(owner)
        .execute(&self.writer)
        .await?
        .rows_affected();
        if deleted == 1 {
            Ok(DeleteTree::Deleted)
        } else if self.tree(owner, id).await?.is_some() {
            Ok(DeleteTree::InUse)
        } else {
            Ok(DeleteTree::NotFound)
        }
    }
}

/// What [`Db::delete_tree`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DeleteTree {
    /// The row is gone (its blobs may be deleted now).
    Deleted,
    /// A job that still exists uses the tree.
    InUse,
    /// No such tree for this owner.
    NotFound,
}
