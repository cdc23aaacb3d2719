//! The blob store: `object_store` over a local directory (`file://`) or S3
//! (`s3://bucket/prefix`, credentials and region from the usual `AWS_*`
//! environment variables).
//!
//! Puts are atomic: the local store writes a staging file and renames it
//! into place (with fsync of the file and its directory, so a blob named
//! by a committed row survives power loss); S3 puts are atomic by
//! definition. A reader therefore never sees a partial blob.

use std::ops::Range;
use std::path::Path as FsPath;
use std::sync::Arc;

use bytes::Bytes;
use futures_util::StreamExt;
use futures_util::stream::BoxStream;
use object_store::path::Path;
use object_store::{ObjectStore, ObjectStoreExt, PutPayload};

/// A blob-store failure (the cause is kept for the logs).
#[derive(Debug, thiserror::Error)]
#[error("blob store: {0}")]
pub struct BlobError(#[from] pub object_store::Error);

/// The blob store.
#[derive(Clone, Debug)]
pub struct Blobs {
    store: Arc<dyn ObjectStore>,
}

impl Blobs {
    /// Opens the store named by `url`: `file:///abs/dir` (created if
    /// missing) or `s3://bucket[/prefix]`.
    pub fn open(url: &str) -> anyhow::Result<Blobs> {
        let parsed =
            url::Url::parse(url).map_err(|e| anyhow::anyhow!("invalid blob URL {url:?}: {e}"))?;
        let store: Arc<dyn ObjectStore> = match parsed.scheme() {
            "file" => {
                let dir = parsed
                    .to_file_path()
                    .map_err(|()| anyhow::anyhow!("invalid file URL {url:?}"))?;
                std::fs::create_dir_all(&dir)?;
                Arc::new(
                    object_store::local::LocalFileSystem::new_with_prefix(&dir)?
                        .with_fsync(true)
                        .with_automatic_cleanup(true),
                )
            }
            "s3" => {
                let bucket = parsed
                    .host_str()
                    .ok_or_else(|| anyhow::anyhow!("s3 URL {url:?} names no bucket"))?;
                let s3 = object_store::aws::AmazonS3Builder::from_env()
                    .with_bucket_name(bucket)
                    .build()?;
                let prefix = parsed.path().trim_matches('/');
                if prefix.is_empty() {
                    Arc::new(s3)
                } else {
                    Arc::new(object_store::prefix::PrefixStore::new(s3, prefix))
                }
            }
            other => anyhow::bail!("unsupported blob store scheme {other:?}: use file:// or s3://"),
        };
        Ok(Blobs { store })
    }

    /// A store in a local directory.
    pub fn local(dir: &FsPath) -> anyhow::Result<Blobs> {
        std::fs::create_dir_all(dir)?;
        let dir = std::fs::canonicalize(dir)?;
        let url = url::Url::from_directory_path(&dir)
            .map_err(|()| anyhow::anyhow!("bad directory {}", dir.display()))?;
        Blobs::open(url.as_str())
    }

    /// Writes a blob atomically.
    pub async fn put(&self, key: &str, bytes: impl Into<Bytes>) -> Result<(), BlobError> {
        self.store
            .put(&Path::from(key), PutPayload::from(bytes.into()))
            .await?;
        Ok(())
    }

    /// Reads a whole blob; `None` when it does not exist.
    pub async fn get(&self, key: &str) -> Result<Option<Bytes>, BlobError> {
        match self.store.get(&Path::from(key)).await {
            Ok(r) => Ok(Some(r.bytes().await?)),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(e.into()),
        }
    }

    /// A blob's size; `None` when it does not exist.
    pub async fn size(&self, key: &str) -> Result<Option<u64>, BlobError> {
        match self.store.head(&Path::from(key)).await {
            Ok(meta) => Ok(Some(meta.size)),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(e.into()),
        }
    }

    /// Streams a byte range of a blob (the whole blob when `range` is
    /// `None`).
    pub async fn stream(
        &self,
        key: &str,
        range: Option<Range<u64>>,
    ) -> Result<BoxStream<'static, Result<Bytes, BlobError>>, BlobError> {
        let path = Path::from(key);
        let options = object_store::GetOptions {
            range: range.map(Into::into),
            ..Default::default()
        };
        let result = self.store.get_opts(&path, options).await?;
        Ok(result.into_stream().map(|r| r.map_err(BlobError)).boxed())
    }

    /// Deletes every blob under `prefix` (a "directory" key).
    pub async fn delete_prefix(&self, prefix: &str) -> Result<(), BlobError> {
        let mut listing = self.store.list(Some(&Path::from(prefix)));
        while let Some(meta) = listing.next().await {
            match self.store.delete(&meta?.location).await {
                Ok(()) | Err(object_store::Error::NotFound { .. }) => {}
                Err(e) => return Err(e.into()),
            }
        }
        Ok(())
    }

    /// The immediate child "directories" of `prefix` (e.g. the attempt
    /// tokens under `jobs/{id}`).
    pub async fn children(&self, prefix: &str) -> Result<Vec<String>, BlobError> {
        let listing = self
            .store
            .list_with_delimiter(Some(&Path::from(prefix)))
            .await?;
        Ok(listing
            .common_prefixes
            .into_iter()
            .filter_map(|p| p.filename().map(str::to_owned))
            .collect())
    }

    /// Readiness: the store answers a listing.
    pub async fn ping(&self) -> Result<(), BlobError> {
        self.store
            .list_with_delimiter(Some(&Path::from("health")))
            .await?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn local_blobs_round_trip_and_delete_by_prefix() {
        let dir = tempfile::tempdir().unwrap();
        let blobs = Blobs::local(dir.path()).unwrap();
        blobs
            .put("jobs/a/t1/x", Bytes::from_static(b"hello"))
            .await
            .unwrap();
        blobs
            .put("jobs/a/t2/y", Bytes::from_static(b"world"))
            .await
            .unwrap();
        assert_eq!(blobs.get("jobs/a/t1/x").await.unwrap().unwrap(), "hello");
        assert_eq!(blobs.size("jobs/a/t2/y").await.unwrap(), Some(5));
        assert_eq!(blobs.get("missing").await.unwrap(), None);
        let mut kids = blobs.children("jobs/a").await.unwrap();
        kids.sort();
        assert_eq!(kids, ["t1", "t2"]);
        let mut s = blobs.stream("jobs/a/t1/x", Some(1..4)).await.unwrap();
        assert_eq!(s.next().await.unwrap().unwrap(), "ell");
        blobs.delete_prefix("jobs/a/t1").await.unwrap();
        assert_eq!(blobs.get("jobs/a/t1/x").await.unwrap(), None);
        assert!(blobs.get("jobs/a/t2/y").await.unwrap().is_some());
        blobs.ping().await.unwrap();
    }

    #[test]
    fn urls_are_parsed() {
        assert!(Blobs::open("ftp://x").is_err());
        assert!(Blobs::open("not a url").is_err());
    }
}
