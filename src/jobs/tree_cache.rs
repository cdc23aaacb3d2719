//! The tree cache: parsed input trees with their analyses, by tree id.
//!
//! Without it every job parses both trees' stored JSON and analyses them
//! again — about 45 ms per 5,000-branch tree on this machine, most of the
//! time between `POST /v1/jobs` and the first frame. A stored tree never
//! changes (a new upload gets a new id, and a tree in use by a job cannot be
//! deleted), so an entry never goes stale; deleting a tree drops its entry
//! only to free the memory early.
//!
//! The upload and generate routes seed the cache with the tree and the
//! analysis they computed anyway, so in a single-process deployment even the
//! first job on a fresh tree skips both steps. Workers in other processes
//! fill their own caches on first use.
//!
//! Entries are weighed by the byte length of the tree's stored JSON: text
//! floats take about three times the memory of the parsed tree, which
//! leaves room for the analysis, so the weight is a fair upper estimate of
//! an entry's memory. Eviction is quick_cache's scan-resistant policy
//! (CLOCK-Pro), which keeps a few hot trees resident while one-off jobs
//! stream through.

use std::sync::Arc;

use quick_cache::Weighter;
use quick_cache::sync::Cache;

use crate::pipeline::InputTree;

/// A cached tree and its weight.
#[derive(Clone, Debug)]
struct Entry {
    tree: Arc<InputTree>,
    bytes: u64,
}

#[derive(Clone, Debug)]
struct ByBytes;

impl Weighter<String, Entry> for ByBytes {
    fn weight(&self, _id: &String, entry: &Entry) -> u64 {
        // Zero-weight entries would never be evicted.
        entry.bytes.max(1)
    }
}

/// Parsed trees and their analyses, by tree id, within a memory budget.
pub struct TreeCache {
    entries: Option<Cache<String, Entry, ByBytes>>,
    budget: u64,
}

impl std::fmt::Debug for TreeCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TreeCache")
            .field("budget", &self.budget)
            .field("len", &self.len())
            .finish()
    }
}

impl TreeCache {
    /// A cache holding up to `budget` bytes of trees (by stored JSON
    /// length); 0 turns caching off.
    pub fn new(budget: u64) -> TreeCache {
        // quick_cache sizes its table from an estimate of the entry count;
        // a 5,000-branch tree stores about 1 MB of JSON.
        let estimated_items = (budget / 1_000_000).clamp(16, 4096) as usize;
        TreeCache {
            entries: (budget > 0).then(|| Cache::with_weighter(estimated_items, budget, ByBytes)),
            budget,
        }
    }

    /// The tree `id`, if cached.
    pub fn get(&self, id: &str) -> Option<Arc<InputTree>> {
        self.entries.as_ref()?.get(id).map(|e| e.tree)
    }

    /// Caches tree `id`, whose stored JSON is `bytes` long. A tree larger
    /// than the whole budget is not kept.
    pub fn insert(&self, id: &str, tree: Arc<InputTree>, bytes: u64) {
        if let Some(entries) = &self.entries
            && bytes <= self.budget
        {
            entries.insert(id.to_owned(), Entry { tree, bytes });
        }
    }

    /// Forgets tree `id` (after it is deleted).
    pub fn remove(&self, id: &str) {
        if let Some(entries) = &self.entries {
            entries.remove(id);
        }
    }

    /// Number of cached trees.
    pub fn len(&self) -> usize {
        self.entries.as_ref().map_or(0, Cache::len)
    }

    /// Whether nothing is cached.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Total weight of the cached trees, in bytes of stored JSON.
    pub fn weight(&self) -> u64 {
        self.entries.as_ref().map_or(0, Cache::weight)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use treemorph_tree::Tree;

    fn tree(seed: u64) -> Arc<InputTree> {
        let t: Tree = treemorph_generate::generate(
            &treemorph_generate::GenerateOptions::new(treemorph_generate::Preset::Shrub, seed)
                .with_size(60),
        )
        .expect("generated");
        Arc::new(InputTree::new(t))
    }

    #[test]
    fn a_cached_tree_is_the_same_shared_value() {
        let cache = TreeCache::new(10_000);
        let t = tree(1);
        cache.insert("a", t.clone(), 100);
        let got = cache.get("a").expect("cached");
        assert!(Arc::ptr_eq(&got, &t));
        assert!(cache.get("b").is_none());
        cache.remove("a");
        assert!(cache.get("a").is_none());
        assert!(cache.is_empty());
    }

    #[test]
    fn the_budget_bounds_the_total_weight() {
        let cache = TreeCache::new(1_000);
        let t = tree(1);
        for i in 0..50 {
            cache.insert(&format!("t{i}"), t.clone(), 100);
            assert!(cache.weight() <= 1_000, "weight {}", cache.weight());
        }
        assert!(cache.len() <= 10);
        assert!(!cache.is_empty());
        // Larger than the whole budget: not kept, and nothing else evicted
        // for it.
        let before = cache.len();
        cache.insert("huge", t, 1_001);
        assert!(cache.get("huge").is_none());
        assert_eq!(cache.len(), before);
    }

    #[test]
    fn a_zero_budget_caches_nothing() {
        let cache = TreeCache::new(0);
        cache.insert("a", tree(1), 10);
        assert!(cache.get("a").is_none());
        assert_eq!(cache.len(), 0);
    }
}
