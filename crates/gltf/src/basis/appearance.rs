//! Which node draws which triangles, in which material, when: the
//! dissolves of [`super`]'s module docs, planned from the samples' leaf
//! swaps and bark blends.

use std::collections::{BTreeMap, BTreeSet};

use glam::Vec3;
use treemorph_tree::FrameTopology;

use super::{BARK_BANDS, MAX_LEAF_GROUPS};

/// When a node is drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Show {
    Always,
    /// Until this time (seconds), then hidden.
    Until(f32),
    /// From this time on, hidden before.
    From(f32),
}

/// One node: its triangles by (glTF material, texture coordinate set,
/// the material on the other side of the swap). The third part splits
/// both sides of a swap alike, so they draw the same vertex sets and
/// share them.
#[derive(Clone, Debug)]
pub(crate) struct NodePlan {
    pub(crate) name: String,
    /// Leaf triangles (else bark).
    pub(crate) leaves: bool,
    pub(crate) show: Show,
    pub(crate) primitives: BTreeMap<(usize, usize, usize), Vec<u32>>,
}

/// What the plan is made from.
pub(crate) struct Inputs<'a> {
    /// The first sample's branch vertex positions.
    pub(crate) base: &'a [Vec3],
    pub(crate) branch_indices: &'a [u32],
    pub(crate) leaf_indices: &'a [u32],
    pub(crate) per_leaf: usize,
    pub(crate) topology: &'a FrameTopology,
    /// Leaves whose materials differ, and the sample at which each swaps.
    pub(crate) fading: &'a [u32],
    pub(crate) swaps: &'a [Option<u32>],
    /// Sample times (seconds) and bark blends.
    pub(crate) times: &'a [f32],
    pub(crate) bark_blends: &'a [f32],
    /// Bark materials: 1 (one look throughout) or 2 (first and last).
    pub(crate) bark_looks: usize,
}

/// Every node of the file: bark first, then leaves; the always-shown node
/// of each first.
pub(crate) fn plan(inputs: &Inputs) -> Vec<NodePlan> {
    let mut plans = bark_plans(inputs);
    plans.extend(leaf_plans(inputs));
    plans
}

/// Where each triangle goes: always shown, or swapping at a sample.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Slot {
    /// Always shown, with this (material, uv set).
    Static(usize, usize),
    /// Swaps at this sample from the first (material, uv set) to the
    /// second.
    Swap(u32, (usize, usize), (usize, usize)),
}

fn bark_plans(i: &Inputs) -> Vec<NodePlan> {
    let swaps = bark_band_swaps(i);
    let (lo, hi) = i
        .base
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.y), hi.max(p.y))
        });
    let span = (hi - lo).max(1e-6);
    let slots = i.branch_indices.chunks_exact(3).map(|tri| {
        let Some(swaps) = &swaps else {
            return Slot::Static(0, 0);
        };
        let y = i.base[tri[0] as usize].y;
        let band = (((y - lo) / span) * BARK_BANDS as f32) as usize;
        match swaps[band.min(BARK_BANDS - 1)] {
            0 => Slot::Static(1, 0),
            s => Slot::Swap(s, (0, 0), (1, 0)),
        }
    });
    nodes("branches", false, i.branch_indices, slots, i.times)
}

/// The sample at which each bark band swaps, or `None` when the bark
/// keeps one look.
fn bark_band_swaps(i: &Inputs) -> Option<[u32; BARK_BANDS]> {
    if i.bark_looks < 2 {
        return None;
    }
    let first = i.bark_blends[0];
    let span = i.bark_blends[i.bark_blends.len() - 1] - first;
    let last = (i.times.len() - 1) as u32;
    Some(std::array::from_fn(|g| {
        let want = (g as f32 + 0.5) / BARK_BANDS as f32;
        i.bark_blends
            .iter()
            .position(|&b| (b - first) / span >= want)
            .map_or(last, |s| s as u32)
    }))
}

fn leaf_plans(i: &Inputs) -> Vec<NodePlan> {
    let offset = i.bark_looks;
    let swap_of: std::collections::HashMap<u32, Option<u32>> = i
        .fading
        .iter()
        .zip(i.swaps)
        .map(|(&leaf, &s)| (leaf, s))
        .collect();
    let groups = leaf_groups(i.swaps);
    let per = i.per_leaf.max(1) as u32;
    let slots = i.leaf_indices.chunks_exact(3).map(|tri| {
        let leaf = tri[0] / per;
        let [a, b] = i.topology.leaves[leaf as usize].materials;
        let (a, b) = ((offset + a as usize, 0), (offset + b as usize, 1));
        match swap_of.get(&leaf) {
            None | Some(None) => Slot::Static(a.0, a.1),
            Some(Some(0)) => Slot::Static(b.0, b.1),
            Some(Some(s)) => Slot::Swap(groups[s], a, b),
        }
    });
    nodes("leaves", true, i.leaf_indices, slots, i.times)
}

/// The sample each swap sample is merged into: at most
/// [`MAX_LEAF_GROUPS`] distinct ones, each the earliest of its group.
fn leaf_groups(swaps: &[Option<u32>]) -> BTreeMap<u32, u32> {
    let distinct: Vec<u32> = swaps
        .iter()
        .flatten()
        .copied()
        .filter(|&s| s > 0)
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    let m = distinct.len();
    distinct
        .iter()
        .enumerate()
        .map(|(rank, &s)| {
            let group = rank * MAX_LEAF_GROUPS.min(m) / m.max(1);
            let first = (group * m).div_ceil(MAX_LEAF_GROUPS.min(m));
            (s, distinct[first])
        })
        .collect()
}

/// The always-shown node `name` and a pair of nodes per swap sample.
fn nodes(
    name: &str,
    leaves: bool,
    indices: &[u32],
    slots: impl Iterator<Item = Slot>,
    times: &[f32],
) -> Vec<NodePlan> {
    let mut by_slot: BTreeMap<Slot, Vec<u32>> = BTreeMap::new();
    for (tri, slot) in indices.chunks_exact(3).zip(slots) {
        by_slot.entry(slot).or_default().extend_from_slice(tri);
    }
    let mut always = NodePlan {
        name: name.into(),
        leaves,
        show: Show::Always,
        primitives: BTreeMap::new(),
    };
    let mut swapping: BTreeMap<u32, [NodePlan; 2]> = BTreeMap::new();
    for (slot, tris) in by_slot {
        match slot {
            Slot::Static(m, uv) => always
                .primitives
                .entry((m, uv, m))
                .or_default()
                .extend(tris),
            Slot::Swap(s, before, after) => {
                let t = times[s as usize];
                let pair = swapping.entry(s).or_insert_with(|| {
                    let node = |label: &str, show| NodePlan {
                        // Players rename nodes with spaces or dots
                        // (three.js's sanitizeNodeName): none here.
                        name: format!("{name}_{label}_{}ms", (t * 1000.0).round()),
                        leaves,
                        show,
                        primitives: BTreeMap::new(),
                    };
                    [node("until", Show::Until(t)), node("from", Show::From(t))]
                });
                let (b, a) = (before.0, after.0);
                pair[0]
                    .primitives
                    .entry((b, before.1, a))
                    .or_default()
                    .extend_from_slice(&tris);
                pair[1]
                    .primitives
                    .entry((a, after.1, b))
                    .or_default()
                    .extend(tris);
            }
        }
    }
    std::iter::once(always)
        .chain(swapping.into_values().flatten())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn swap_samples_merge_into_at_most_the_group_count() {
        let swaps: Vec<Option<u32>> = (0..100).map(|s| Some(s % 40)).chain([None]).collect();
        let groups = leaf_groups(&swaps);
        assert_eq!(groups.len(), 39);
        let distinct: BTreeSet<u32> = groups.values().copied().collect();
        assert_eq!(distinct.len(), MAX_LEAF_GROUPS);
        // Each sample merges into an earlier or equal one, in order.
        let mut last = 0;
        for (&s, &g) in &groups {
            assert!(g <= s && g >= last);
            last = g;
        }
        let few = leaf_groups(&[Some(3), Some(7), Some(0), None]);
        assert_eq!(few, BTreeMap::from([(3, 3), (7, 7)]));
    }
}
