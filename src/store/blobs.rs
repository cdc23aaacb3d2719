//! The blob store: `object_store` over a local directory (`file://`) or S3
//! (`s3://bucket/prefix`, credentials and region from the usual `AWS_*`
//! environment variables).
//!
//! Puts are atomic: the local store writes a staging file and renames it
//! into place; on S3 every blob is one `PutObject`, which becomes visible
//! whole or not at all. A blob written in parts as a job makes it
//! ([`BlobWriter`], the local store only) is renamed into place the same
//! way once its last part is written.
//!
//! Durability on the local store comes in two steps:
//! [`Blobs::put_deferred`] returns once the rename is done (safe against a
//! killed process, not yet against power loss) and [`Blobs::sync`] makes a
//! batch of such blobs durable later. [`Blobs::put`] is both at once, like
//! an S3 PUT. Jobs publish their frames with
//! deferred puts and sync them all before the commit that ends the attempt:
//! a 40 MB frame GLB fsynced on the way out took as long as meshing it, and
//! one job's fsyncs queued behind another's. The window this opens is
//! power loss during a running attempt, whose frames may then read back
//! short; that attempt is rerun under a new token once its lease expires,
//! and its outputs are never served again. We never use
//! multipart uploads (whose parts are invisible until the completing call,
//! but which leave orphaned parts behind a crash and need a lifecycle rule
//! to clean up): our largest outputs are tens of megabytes, far below the
//! 5 GiB single-put limit. A reader therefore never sees a partial blob.
//!
//! # S3 settings
//! `s3://bucket/prefix` with the usual environment: `AWS_ACCESS_KEY_ID`,
//! `AWS_SECRET_ACCESS_KEY` (and `AWS_SESSION_TOKEN`), `AWS_REGION` or
//! `AWS_DEFAULT_REGION` (default `us-east-1`), and for an S3-compatible
//! server `AWS_ENDPOINT_URL` (e.g. `http://127.0.0.1:9000`). Requests are
//! path-style (`endpoint/bucket/key`, what MinIO, moto and s3s expect) unless
//! `AWS_VIRTUAL_HOSTED_STYLE_REQUEST=true`. Naming an `http://` endpoint
//! allows plain HTTP (object_store refuses it unless told; naming the
//! endpoint is consent enough) unless `AWS_ALLOW_HTTP` says otherwise.

use std::ops::Range;
use std::path::Path as FsPath;
use std::sync::Arc;

use bytes::Bytes;
use futures_util::StreamExt;
use futures_util::stream::BoxStream;
use object_store::aws::{AmazonS3Builder, AmazonS3ConfigKey};
use object_store::local::LocalFileSystem;
use object_store::path::Path;
use object_store::{ObjectStore, ObjectStoreExt, PutPayload};

/// A blob-store failure (the cause is kept for the logs).
#[derive(Debug, thiserror::Error)]
#[error("blob store: {0}")]
pub struct BlobError(#[from] pub object_store::Error);

/// The blob store.
#[derive(Clone, Debug)]
pub struct Blobs {
    /// Puts return when the blob is visible; on the local store, durable
    /// after [`Blobs::sync`].
    store: Arc<dyn ObjectStore>,
    /// The same local store (`None` on S3), for [`Blobs::sync`] to find a
    /// key's file, and its directory.
    local: Option<(Arc<LocalFileSystem>, std::path::PathBuf)>,
}

impl Blobs {
    /// Opens the store named by `url`: `file:///abs/dir` (created if
    /// missing) or `s3://bucket[/prefix]`.
    pub fn open(url: &str) -> anyhow::Result<Blobs> {
        let parsed =
            url::Url::parse(url).map_err(|e| anyhow::anyhow!("invalid blob URL {url:?}: {e}"))?;
        match parsed.scheme() {
            "file" => {
                let dir = parsed
                    .to_file_path()
                    .map_err(|()| anyhow::anyhow!("invalid file URL {url:?}"))?;
                std::fs::create_dir_all(&dir)?;
                let local =
                    Arc::new(LocalFileSystem::new_with_prefix(&dir)?.with_automatic_cleanup(true));
                Ok(Blobs {
                    store: local.clone(),
                    local: Some((local, std::fs::canonicalize(&dir)?)),
                })
            }
            "s3" => {
                let bucket = parsed
                    .host_str()
                    .ok_or_else(|| anyhow::anyhow!("s3 URL {url:?} names no bucket"))?;
                let s3 = s3_builder(bucket, std::env::vars()).build()?;
                let prefix = parsed.path().trim_matches('/');
                let store: Arc<dyn ObjectStore> = if prefix.is_empty() {
                    Arc::new(s3)
                } else {
                    Arc::new(object_store::prefix::PrefixStore::new(s3, prefix))
                };
                Ok(Blobs { store, local: None })
            }
            other => anyhow::bail!("unsupported blob store scheme {other:?}: use file:// or s3://"),
        }
    }

    /// A store in a local directory.
    pub fn local(dir: &FsPath) -> anyhow::Result<Blobs> {
        std::fs::create_dir_all(dir)?;
        let dir = std::fs::canonicalize(dir)?;
        let url = url::Url::from_directory_path(&dir)
            .map_err(|()| anyhow::anyhow!("bad directory {}", dir.display()))?;
        Blobs::open(url.as_str())
    }

    /// Writes a blob atomically and durably.
    pub async fn put(&self, key: &str, bytes: impl Into<Bytes>) -> Result<(), BlobError> {
        self.put_deferred(key, bytes).await?;
        self.sync(vec![key.to_owned()]).await
    }

    /// Writes a blob atomically; it is durable after [`Blobs::sync`] (at
    /// once on S3).
    pub async fn put_deferred(&self, key: &str, bytes: impl Into<Bytes>) -> Result<(), BlobError> {
        self.store
            .put(&Path::from(key), PutPayload::from(bytes.into()))
            .await?;
        Ok(())
    }

    /// [`Blobs::put_deferred`] for a job thread (never a runtime thread):
    /// on the local store the file is written on the calling thread, so the
    /// copy of a 40 MB frame into the page cache runs at the job thread's
    /// lowered priority (see [`crate::jobs::priority`]) instead of on the
    /// runtime's blocking pool at full priority, where it delayed API
    /// requests by tens of milliseconds. object_store's local store does
    /// its file work inline when no runtime is entered, so one poll
    /// finishes it; S3 puts go through `rt`.
    pub fn put_deferred_here(
        &self,
        rt: &tokio::runtime::Handle,
        key: &str,
        bytes: impl Into<Bytes>,
    ) -> Result<(), BlobError> {
        let path = Path::from(key);
        let payload = PutPayload::from(bytes.into());
        let mut put = std::pin::pin!(self.store.put(&path, payload));
        if self.local.is_some() && tokio::runtime::Handle::try_current().is_err() {
            let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
            if let std::task::Poll::Ready(r) = put.as_mut().poll(&mut cx) {
                return r.map(drop).map_err(BlobError);
            }
        }
        rt.block_on(put).map(drop).map_err(BlobError)
    }

    /// Makes blobs written with [`Blobs::put_deferred`] durable: fsyncs
    /// each file, then each directory holding them (the renames). A no-op
    /// on S3. object_store offers no flush of earlier puts, so this is
    /// written here, with object_store's own mapping of keys to files.
    pub async fn sync(&self, keys: Vec<String>) -> Result<(), BlobError> {
        let Some(paths) = self.local_paths(&keys)? else {
            return Ok(());
        };
        let synced = tokio::task::spawn_blocking(move || sync_paths(&paths)).await;
        synced
            .unwrap_or_else(|e| Err(std::io::Error::other(e)))
            .map_err(file_error)
    }

    /// [`Blobs::sync`] on the calling thread (a job thread).
    pub fn sync_here(&self, keys: &[String]) -> Result<(), BlobError> {
        match self.local_paths(keys)? {
            Some(paths) => sync_paths(&paths).map_err(file_error),
            None => Ok(()),
        }
    }

    /// Writes the local blob `key` back to the disk now, on the calling
    /// thread (nothing on S3), so that the [`Blobs::sync`] that makes it
    /// durable later finds it written; whether this succeeds does not
    /// matter, since that sync reports any failure.
    pub fn write_back_here(&self, key: &str) {
        if let Ok(Some((paths, _))) = self.local_paths(&[key.to_owned()]) {
            for path in paths {
                let _ = std::fs::File::open(path).and_then(|f| f.sync_data());
            }
        }
    }

    /// The files of `keys` and the store's root (`None` on S3 or when there
    /// is nothing to do).
    fn local_paths(
        &self,
        keys: &[String],
    ) -> Result<Option<(Vec<std::path::PathBuf>, std::path::PathBuf)>, BlobError> {
        let Some((local, root)) = &self.local else {
            return Ok(None);
        };
        if keys.is_empty() {
            return Ok(None);
        }
        let paths = keys
            .iter()
            .map(|k| local.path_to_filesystem(&Path::from(k.as_str())))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Some((paths, root.clone())))
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

    /// Deletes the blob `key` (nothing when it does not exist).
    pub async fn delete(&self, key: &str) -> Result<(), BlobError> {
        match self.store.delete(&Path::from(key)).await {
            Ok(()) | Err(object_store::Error::NotFound { .. }) => Ok(()),
            Err(e) => Err(e.into()),
        }
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

    /// When the newest blob under `prefix` was written, in ms since the
    /// epoch; `None` when there is none.
    pub async fn last_modified(&self, prefix: &str) -> Result<Option<i64>, BlobError> {
        let mut listing = self.store.list(Some(&Path::from(prefix)));
        let mut newest = None;
        while let Some(meta) = listing.next().await {
            let at = meta?.last_modified.timestamp_millis();
            newest = Some(newest.map_or(at, |n: i64| n.max(at)));
        }
        Ok(newest)
    }

    /// How many blobs are under `prefix` and their total size in bytes.
    pub async fn usage(&self, prefix: &str) -> Result<(u64, u64), BlobError> {
        let mut listing = self.store.list(Some(&Path::from(prefix)));
        let (mut count, mut bytes) = (0, 0);
        while let Some(meta) = listing.next().await {
            count += 1;
            bytes += meta?.size;
        }
        Ok((count, bytes))
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

/// A blob of the local store written in parts as they are made
/// ([`Blobs::writer`]): the parts go into `<file>.partial` beside the
/// blob's file, which [`BlobWriter::finish`] renames into place, so the
/// blob appears whole, as a put's does. The partial file is an ordinary
/// key (no route names it), so a crash leaves it under its job's prefix,
/// where deleting the job or the orphan sweep removes it; dropping an
/// unfinished writer removes it at once.
#[derive(Debug)]
pub struct BlobWriter {
    file: std::fs::File,
    partial: std::path::PathBuf,
    path: std::path::PathBuf,
    finished: bool,
    /// Bytes appended since the last write-back was started.
    unsynced: usize,
}

/// How many bytes a [`BlobWriter`] takes before it starts writing them
/// back to the disk behind the job ([`BlobWriter::append`]).
const WRITE_BACK_BYTES: usize = 4 << 20;

impl Blobs {
    /// A writer of the blob `key` in parts ([`BlobWriter`]) on the local
    /// store; `None` on S3, where a blob is put whole (see the module docs
    /// on multipart uploads).
    pub fn writer(&self, key: &str) -> Result<Option<BlobWriter>, BlobError> {
        let Some((local, _)) = &self.local else {
            return Ok(None);
        };
        let path = local.path_to_filesystem(&Path::from(key))?;
        let mut name = path.file_name().unwrap_or_default().to_owned();
        name.push(".partial");
        let partial = path.with_file_name(name);
        let create = || {
            if let Some(dir) = partial.parent() {
                std::fs::create_dir_all(dir)?;
            }
            std::fs::File::create(&partial)
        };
        let file = create().map_err(file_error)?;
        Ok(Some(BlobWriter {
            file,
            partial,
            path,
            finished: false,
            unsynced: 0,
        }))
    }
}

impl BlobWriter {
    /// Appends the next part. Every few megabytes it starts writing the
    /// file back to the disk on a thread of its own, whose result does not
    /// matter: the sync that makes the blob durable ([`Blobs::sync`])
    /// then finds most of it written. A job's stream (17 MB on the
    /// default job) was all written back by that sync, after the last
    /// frame.
    pub fn append(&mut self, bytes: &[u8]) -> Result<(), BlobError> {
        use std::io::Write;
        self.file.write_all(bytes).map_err(file_error)?;
        self.unsynced += bytes.len();
        if self.unsynced >= WRITE_BACK_BYTES {
            self.unsynced = 0;
            // A thread that cannot start leaves the work to that sync.
            if let Ok(file) = self.file.try_clone() {
                let _ = std::thread::Builder::new()
                    .name("write-back".into())
                    .spawn(move || file.sync_data());
            }
        }
        Ok(())
    }

    /// Ends the blob: it is visible whole at its key once this returns,
    /// durable after [`Blobs::sync`], like a deferred put.
    pub fn finish(mut self) -> Result<(), BlobError> {
        std::fs::rename(&self.partial, &self.path).map_err(file_error)?;
        self.finished = true;
        Ok(())
    }
}

impl Drop for BlobWriter {
    fn drop(&mut self) {
        if !self.finished {
            let _ = std::fs::remove_file(&self.partial);
        }
    }
}

/// Fsyncs each file, then each directory from theirs up to `root` (new
/// directories' entries live in their parents).
fn sync_paths(
    (paths, root): &(Vec<std::path::PathBuf>, std::path::PathBuf),
) -> std::io::Result<()> {
    let mut dirs = std::collections::BTreeSet::new();
    for path in paths {
        std::fs::File::open(path)?.sync_all()?;
        let mut dir = path.parent();
        while let Some(d) = dir
            && d.starts_with(root)
            && dirs.insert(d.to_owned())
        {
            dir = d.parent();
        }
    }
    for dir in dirs {
        std::fs::File::open(&dir)?.sync_all()?;
    }
    Ok(())
}

fn file_error(source: std::io::Error) -> BlobError {
    BlobError(object_store::Error::Generic {
        store: "LocalFileSystem",
        source: Box::new(source),
    })
}

/// An S3 builder for `bucket` configured from the `AWS_*` variables among
/// `env` (see the module docs).
fn s3_builder(bucket: &str, env: impl IntoIterator<Item = (String, String)>) -> AmazonS3Builder {
    crate::tls::install_crypto_provider();
    let mut builder = AmazonS3Builder::new().with_bucket_name(bucket);
    let mut http_decided = false;
    for (key, value) in env {
        if !key.starts_with("AWS_") {
            continue;
        }
        if let Ok(config) = key.to_ascii_lowercase().parse::<AmazonS3ConfigKey>() {
            http_decided |= key == "AWS_ALLOW_HTTP";
            builder = builder.with_config(config, value);
        }
    }
    let plain_http = builder
        .get_config_value(&AmazonS3ConfigKey::Endpoint)
        .is_some_and(|e| e.starts_with("http://"));
    if plain_http && !http_decided {
        builder = builder.with_allow_http(true);
    }
    builder
}

#[cfg(test)]
mod tests {
    use object_store::ClientConfigKey;

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
        assert_eq!(blobs.usage("jobs/a").await.unwrap(), (2, 10));
        let newest = blobs.last_modified("jobs/a").await.unwrap().unwrap();
        assert!(
            (newest - crate::store::now_ms()).abs() < 600_000,
            "{newest}"
        );
        assert_eq!(blobs.last_modified("jobs/none").await.unwrap(), None);
        let mut s = blobs.stream("jobs/a/t1/x", Some(1..4)).await.unwrap();
        assert_eq!(s.next().await.unwrap().unwrap(), "ell");
        blobs.delete_prefix("jobs/a/t1").await.unwrap();
        assert_eq!(blobs.get("jobs/a/t1/x").await.unwrap(), None);
        assert!(blobs.get("jobs/a/t2/y").await.unwrap().is_some());
        blobs.ping().await.unwrap();
    }

    #[tokio::test]
    async fn deferred_puts_are_visible_at_once_and_sync_by_key() {
        let dir = tempfile::tempdir().unwrap();
        let blobs = Blobs::local(dir.path()).unwrap();
        // A key object_store escapes on disk.
        let keys = [
            "jobs/b/t1/frames/000000.glb",
            "jobs/b/t1/files/odd name%.json",
        ];
        for key in keys {
            blobs
                .put_deferred(key, Bytes::from_static(b"frame"))
                .await
                .unwrap();
            assert_eq!(blobs.get(key).await.unwrap().unwrap(), "frame");
        }
        blobs
            .sync(keys.iter().map(|k| k.to_string()).collect())
            .await
            .unwrap();
        blobs.sync(Vec::new()).await.unwrap();
        // From a thread outside the runtime (a job thread): written there.
        let (b, rt) = (blobs.clone(), tokio::runtime::Handle::current());
        std::thread::spawn(move || {
            b.put_deferred_here(&rt, "jobs/b/t1/frames/000002.glb", vec![7u8; 3])
                .unwrap();
            b.sync_here(&["jobs/b/t1/frames/000002.glb".to_owned()])
                .unwrap();
        })
        .join()
        .unwrap();
        assert_eq!(
            blobs
                .get("jobs/b/t1/frames/000002.glb")
                .await
                .unwrap()
                .unwrap(),
            vec![7u8; 3]
        );
        // A blob that is not there cannot be made durable: an error, never
        // a silent success.
        let err = blobs
            .sync(vec!["jobs/b/t1/frames/000001.glb".into()])
            .await
            .unwrap_err();
        assert!(err.to_string().contains("No such file"), "{err}");
    }

    #[test]
    fn s3_settings_come_from_the_aws_environment() {
        let env = |pairs: &[(&str, &str)]| {
            pairs
                .iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect::<Vec<_>>()
        };
        let allow_http = AmazonS3ConfigKey::Client(ClientConfigKey::AllowHttp);
        let local = s3_builder(
            "b",
            env(&[
                ("AWS_ENDPOINT_URL", "http://127.0.0.1:9000"),
                ("AWS_DEFAULT_REGION", "eu-west-3"),
                ("AWS_ACCESS_KEY_ID", "id"),
                ("HOME", "/root"),
            ]),
        );
        assert_eq!(local.get_config_value(&allow_http).as_deref(), Some("true"));
        assert_eq!(
            local
                .get_config_value(&AmazonS3ConfigKey::Region)
                .as_deref(),
            Some("eu-west-3")
        );
        assert_eq!(
            local
                .get_config_value(&AmazonS3ConfigKey::AccessKeyId)
                .as_deref(),
            Some("id")
        );
        assert_eq!(
            local
                .get_config_value(&AmazonS3ConfigKey::VirtualHostedStyleRequest)
                .as_deref(),
            Some("false"),
            "path-style by default"
        );
        // AWS_REGION wins over AWS_DEFAULT_REGION in either order.
        for pairs in [
            [("AWS_REGION", "r1"), ("AWS_DEFAULT_REGION", "r2")],
            [("AWS_DEFAULT_REGION", "r2"), ("AWS_REGION", "r1")],
        ] {
            let b = s3_builder("b", env(&pairs));
            assert_eq!(
                b.get_config_value(&AmazonS3ConfigKey::Region).as_deref(),
                Some("r1")
            );
        }
        let refused = s3_builder(
            "b",
            env(&[
                ("AWS_ALLOW_HTTP", "false"),
                ("AWS_ENDPOINT_URL", "http://127.0.0.1:9000"),
            ]),
        );
        assert_eq!(
            refused.get_config_value(&allow_http).as_deref(),
            Some("false")
        );
        let https = s3_builder("b", env(&[("AWS_ENDPOINT_URL", "https://s3.example")]));
        assert_eq!(
            https.get_config_value(&allow_http).as_deref(),
            Some("false")
        );
    }

    /// Against a real S3-compatible server: `TREEMORPH_TEST_S3_URL`
    /// (`s3://bucket`, the bucket must exist) with the `AWS_*` environment
    /// (`scripts/ci/scaleout.sh` runs it against moto).
    #[tokio::test]
    #[ignore = "needs TREEMORPH_TEST_S3_URL and an S3 server"]
    async fn s3_blobs_round_trip_and_delete_by_prefix() {
        let url = std::env::var("TREEMORPH_TEST_S3_URL").expect("TREEMORPH_TEST_S3_URL");
        let run = crate::store::new_id();
        let blobs =
            Blobs::open(&format!("{}/blobs-test-{run}", url.trim_end_matches('/'))).unwrap();
        blobs.ping().await.unwrap();
        let big = vec![7u8; 12 * 1024 * 1024];
        blobs.put("jobs/a/t1/big", big.clone()).await.unwrap();
        blobs
            .put("jobs/a/t2/y", Bytes::from_static(b"world"))
            .await
            .unwrap();
        assert_eq!(blobs.get("jobs/a/t1/big").await.unwrap().unwrap(), big);
        assert_eq!(blobs.size("jobs/a/t2/y").await.unwrap(), Some(5));
        assert_eq!(blobs.get("missing").await.unwrap(), None);
        assert_eq!(blobs.size("missing").await.unwrap(), None);
        let mut kids = blobs.children("jobs/a").await.unwrap();
        kids.sort();
        assert_eq!(kids, ["t1", "t2"]);
        assert_eq!(
            blobs.usage("jobs/a").await.unwrap(),
            (2, 12 * 1024 * 1024 + 5)
        );
        let newest = blobs.last_modified("jobs/a").await.unwrap().unwrap();
        assert!(
            (newest - crate::store::now_ms()).abs() < 600_000,
            "{newest}"
        );
        assert_eq!(blobs.last_modified("jobs/none").await.unwrap(), None);
        let mut s = blobs.stream("jobs/a/t2/y", Some(1..4)).await.unwrap();
        assert_eq!(s.next().await.unwrap().unwrap(), "orl");
        blobs.delete_prefix("jobs/a/t1").await.unwrap();
        assert_eq!(blobs.get("jobs/a/t1/big").await.unwrap(), None);
        blobs.delete_prefix("jobs").await.unwrap();
        assert!(blobs.children("jobs").await.unwrap().is_empty());
        assert_eq!(blobs.usage("jobs").await.unwrap(), (0, 0));
    }

    #[test]
    fn urls_are_parsed() {
        assert!(Blobs::open("ftp://x").is_err());
        assert!(Blobs::open("not a url").is_err());
    }
}
