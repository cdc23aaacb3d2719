//! Renders on request (a plan-first job's per-frame GLBs and animated GLB,
//! `GET /v1/jobs/{id}/frame.glb?t=`, re-sampled sequences): each rendered
//! once, however many requests ask for it at the same time, and kept
//! within `--render-cache-mb`.
//!
//! # Choices
//! - **Two tiers.** A render is a deterministic function of the job's
//!   attempt and its key, and costs tens of milliseconds (a frame) to
//!   seconds (an animated GLB). Memory, per process, serves repeated
//!   requests (a viewer scrubbing back and forth, several clients on one
//!   job); behind it the blob store ([`RenderStore`], `--render-store-mb`)
//!   keeps renders across restarts and for every API process of a fleet.
//!   A render is stored in the background once made. Nothing is cached
//!   before it is complete, so a kill -9 during a render leaves no partial
//!   entry in either tier.
//! - **One render per key at a time.** The first request for a key renders;
//!   concurrent requests for it wait for that render instead of starting
//!   their own (quick_cache's placeholder guards). A failed render caches
//!   nothing and the next waiter renders.
//! - **Eviction** is quick_cache's scan-resistant policy by byte weight,
//!   as in the tree cache. With `--render-cache-mb 0` nothing is kept, and
//!   concurrent requests for one key still render once.
//! - Entries of a deleted job stay until evicted but are never served: the
//!   route checks the job's row before it looks here.

use std::future::Future;

use bytes::Bytes;
use quick_cache::Weighter;
use quick_cache::sync::Cache;

use crate::error::ApiError;
use crate::store::renders::RenderStore;

#[derive(Clone, Debug)]
struct ByLen;

impl Weighter<String, Bytes> for ByLen {
    fn weight(&self, _key: &String, glb: &Bytes) -> u64 {
        // Zero-weight entries would never be evicted.
        (glb.len() as u64).max(1)
    }
}

/// Typical size of a render, for sizing the cache's tables.
const TYPICAL_RENDER_BYTES: u64 = 8 << 20;

/// Renders by key (the job's attempt and the instant).
pub struct RenderCache {
    entries: Cache<String, Bytes, ByLen>,
    budget: u64,
    store: Option<RenderStore>,
}

impl std::fmt::Debug for RenderCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RenderCache")
            .field("budget", &self.budget)
            .field("len", &self.entries.len())
            .finish()
    }
}

impl RenderCache {
    /// A cache keeping up to `budget` bytes of renders.
    pub fn new(budget: u64) -> RenderCache {
        let items = (budget / TYPICAL_RENDER_BYTES).clamp(16, 4096) as usize;
        RenderCache {
            // quick_cache needs a capacity of at least one unit; a zero
            // budget keeps nothing past the placeholder's life.
            entries: Cache::with_weighter(items, budget.max(1), ByLen),
            budget,
            store: None,
        }
    }

    /// This cache with `store` as its second tier.
    pub fn with_store(mut self, store: RenderStore) -> RenderCache {
        self.store = Some(store);
        self
    }

    /// The render of `key`: cached, being rendered by another request
    /// (waits for it), or rendered now by `render`.
    pub async fn get_or_render(
        &self,
        key: &str,
        render: impl Future<Output = Result<Vec<u8>, ApiError>>,
    ) -> Result<Bytes, ApiError> {
        let store = self.store.clone();
        self.entries
            .get_or_insert_async(key, async {
                if let Some(stored) = match &store {
                    Some(store) => store.load(key).await,
                    None => None,
                } {
                    return Ok(stored);
                }
                let bytes = Bytes::from(render.await?);
                if let Some(store) = store {
                    // In the background: the answer does not wait for
                    // the write.
                    let (key, bytes) = (key.to_owned(), bytes.clone());
                    tokio::spawn(async move { store.save(&key, bytes).await });
                }
                Ok(bytes)
            })
            .await
    }
}
