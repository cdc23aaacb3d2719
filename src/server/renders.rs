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
//! - **Renders sent as they are made** ([`super::streamed`]) are tracked
//!   here too, by key, while they run: later requests join them, and the
//!   whole-file path waits for them rather than render the same key again
//!   (one whole-file render that has just begun can still race a first
//!   streamed request for the same key; both then render).

use std::collections::HashMap;
use std::future::Future;
use std::sync::{Arc, Mutex};

use bytes::Bytes;
use quick_cache::Weighter;
use quick_cache::sync::Cache;

use super::streamed::Live;
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
    /// Renders being sent as they are made, by key.
    live: Mutex<HashMap<String, Arc<Live>>>,
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
            live: Mutex::default(),
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
        let live = self.live_of(key);
        self.entries
            .get_or_insert_async(key, async {
                if let Some(stored) = match &store {
                    Some(store) => store.load(key).await,
                    None => None,
                } {
                    return Ok(stored);
                }
                if let Some(live) = live
                    && let Ok(bytes) = live.finished().await
                {
                    return Ok(bytes);
                }
                let bytes = Bytes::from(render.await?);
                self.save(key, &bytes);
                Ok(bytes)
            })
            .await
    }

    /// Keeps `bytes` in the store, in the background: the answer does not
    /// wait for the write.
    fn save(&self, key: &str, bytes: &Bytes) {
        if let Some(store) = self.store.clone() {
            let (key, bytes) = (key.to_owned(), bytes.clone());
            tokio::spawn(async move { store.save(&key, bytes).await });
        }
    }

    /// The render of `key` when either tier holds it.
    pub async fn cached(&self, key: &str) -> Option<Bytes> {
        if let Some(bytes) = self.entries.get(key) {
            return Some(bytes);
        }
        let stored = self.store.as_ref()?.load(key).await?;
        self.entries.insert(key.to_owned(), stored.clone());
        Some(stored)
    }

    fn lives(&self) -> std::sync::MutexGuard<'_, HashMap<String, Arc<Live>>> {
        // The map stays consistent if a holder panicked.
        self.live.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn live_of(&self, key: &str) -> Option<Arc<Live>> {
        self.lives().get(key).cloned()
    }

    /// The render of `key` being sent as it is made, and whether the
    /// caller has just created it (then it must run it and end it with
    /// [`RenderCache::finish_live`]).
    pub fn live(&self, key: &str) -> (Arc<Live>, bool) {
        let mut lives = self.lives();
        if let Some(live) = lives.get(key) {
            return (live.clone(), false);
        }
        let live = Live::new();
        lives.insert(key.to_owned(), live.clone());
        (live, true)
    }

    /// Ends the render of `key` that [`RenderCache::live`] created: a
    /// complete one enters both tiers before it leaves the map, so a new
    /// request finds it in one or the other.
    pub fn finish_live(&self, key: &str, live: &Live, whole: Result<Bytes, ApiError>) {
        if let Ok(bytes) = &whole {
            self.entries.insert(key.to_owned(), bytes.clone());
            self.save(key, bytes);
        }
        live.end(whole);
        self.lives().remove(key);
    }
}
