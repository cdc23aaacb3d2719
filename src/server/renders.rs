//! Renders on request (a plan-first job's per-frame GLBs and animated GLB,
//! `GET /v1/jobs/{id}/frame.glb?t=`, re-sampled sequences): each rendered
//! once, however many requests ask for it at the same time, and kept
//! within `--render-cache-mb`.
//!
//! # Choices
//! - **In memory, per process.** A render is a deterministic function of
//!   the job's attempt and the instant, and costs tens of milliseconds, so
//!   a cache here saves the CPU of repeated requests (a viewer scrubbing
//!   back and forth, several clients on one job) without writing a byte to
//!   the blob store; a process that restarts renders again. Nothing is
//!   cached before it is complete, so a kill -9 during a render leaves no
//!   partial entry.
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
        }
    }

    /// The render of `key`: cached, being rendered by another request
    /// (waits for it), or rendered now by `render`.
    pub async fn get_or_render(
        &self,
        key: &str,
        render: impl Future<Output = Result<Vec<u8>, ApiError>>,
    ) -> Result<Bytes, ApiError> {
        self.entries
            .get_or_insert_async(key, async { render.await.map(Bytes::from) })
            .await
    }
}
