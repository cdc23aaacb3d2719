//! Lobes (§4.2): the top-down threshold K-means that gives every leaf an
//! inner lobe, and the IL / OL / GOL shapes.

use std::ops::Range;

use glam::{IVec3, Quat, Vec3};
use rayon::prelude::*;
use treemorph_tree::geom::{CellMap, NONE, closest_on_segment};
use treemorph_tree::{Leaf, NodeId, Skeleton, Tree};

use crate::chain::{Chain, ChainId};
use crate::group::{ChainGroup, GroupId};
use crate::hull::{Hull, HullKind, RadialTemplate};
use crate::options::AnalysisOptions;
use crate::shape::Lobe;

/// Points of a leaf that lobes enclose: the anchor and the blade tip, so
/// lobes cover the foliage's extent, not just where it attaches. (Adding
/// the blade's side edges doubled the hull work for a barely wider lobe.)
pub(crate) fn blade_points(tree: &Tree, leaf: &Leaf) -> [Vec3; 2] {
    let anchor = tree.leaf_anchor(leaf);
    let q: Quat = leaf.orientation;
    [anchor, anchor + q * Vec3::new(0.0, leaf.height, 0.0)]
}

/// Centre and radius of the crown-like shape each group's substructure
/// forms: the length-weighted centroid of the substructure's branches, and
/// the largest distance from it to a substructure node.
fn crowns(chains: &[Chain], groups: &[ChainGroup]) -> Vec<(Vec3, f32)> {
    // Bottom-up sums of length × segment midpoint (children have larger ids).
    let mut sum = vec![Vec3::ZERO; chains.len()];
    let mut weight = vec![0.0f32; chains.len()];
    for c in chains.iter().rev() {
        let i = c.id as usize;
        for w in c.points.windows(2) {
            let len = w[0].distance(w[1]);
            sum[i] += (w[0] + w[1]) * 0.5 * len;
            weight[i] += len;
        }
        for &k in &c.children {
            let (s, w) = (sum[k as usize], weight[k as usize]);
            sum[i] += s;
            weight[i] += w;
        }
    }
    groups
        .par_iter()
        .map(|g| {
            let s: Vec3 = g.chains.iter().map(|&c| sum[c as usize]).sum();
            let w: f32 = g.chains.iter().map(|&c| weight[c as usize]).sum();
            let center = if w > 0.0 {
                s / w
            } else {
                let tips: Vec3 = g.chains.iter().map(|&c| chains[c as usize].tip()).sum();
                tips / g.chains.len() as f32
            };
            let mut radius = 0.0f32;
            let mut stack: Vec<ChainId> = g.chains.clone();
            while let Some(c) = stack.pop() {
                let chain = &chains[c as usize];
                for p in &chain.points[1..] {
                    radius = radius.max(p.distance(center));
                }
                stack.extend(&chain.children);
            }
            (center, radius)
        })
        .collect()
}

/// Where the clustering of one group sends a leaf.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Target {
    /// Into a child group's GOL (clustered again one level down).
    Group(GroupId),
    /// Into a chain's IL.
    Chain(ChainId),
}

/// Threshold K-means of one set of leaf points (§4.2 step 2): each cluster
/// has a radius; a leaf joins the nearest cluster closer than
/// `radius × (initial + step × iteration)`; centres move to the mean of
/// their leaves after every iteration. Assignments are final. Iterations in
/// which nothing would be assigned are skipped in one jump (the outcome is
/// the same since the centres do not move). After `max_iterations`, leftover
/// leaves go to the nearest centre.
fn threshold_kmeans(
    points: &[Vec3],
    mut centers: Vec<Vec3>,
    radii: &[f32],
    options: &AnalysisOptions,
) -> Vec<u32> {
    let k = centers.len();
    let mut assign = vec![NONE; points.len()];
    let mut sums = vec![Vec3::ZERO; k];
    let mut counts = vec![0u32; k];
    let mut pending: Vec<u32> = (0..points.len() as u32).collect();
    let init = options.cluster_initial_threshold;
    let step = options.cluster_threshold_step;
    let mut iteration = 0u32;
    let inv_r: Vec<f32> = radii.iter().map(|r| 1.0 / r).collect();
    while !pending.is_empty() && iteration < options.cluster_max_iterations {
        let factor = init + step * iteration as f32;
        // Per leaf: the nearest cluster within its threshold, and the
        // smallest distance/radius ratio over all clusters.
        let probe = |&i: &u32| -> (u32, f32) {
            let p = points[i as usize];
            let mut best = (NONE, f32::INFINITY);
            let mut min_ratio = f32::INFINITY;
            for c in 0..k {
                let d = p.distance(centers[c]);
                let ratio = d * inv_r[c];
                min_ratio = min_ratio.min(ratio);
                if ratio < factor && d < best.1 {
                    best = (c as u32, d);
                }
            }
            (best.0, min_ratio)
        };
        let results: Vec<(u32, f32)> = if pending.len() * k > 16_384 {
            pending.par_iter().map(probe).collect()
        } else {
            pending.iter().map(probe).collect()
        };
        let mut next = Vec::with_capacity(pending.len());
        let mut min_ratio = f32::INFINITY;
        for (&i, &(c, r)) in pending.iter().zip(&results) {
            if c == NONE {
                next.push(i);
                min_ratio = min_ratio.min(r);
            } else {
                assign[i as usize] = c;
                sums[c as usize] += points[i as usize];
                counts[c as usize] += 1;
            }
        }
        let assigned_any = next.len() < pending.len();
        pending = next;
        for c in 0..k {
            if counts[c] > 0 {
                centers[c] = sums[c] / counts[c] as f32;
            }
        }
        iteration += 1;
        if !assigned_any && min_ratio.is_finite() {
            // First iteration whose factor exceeds the best ratio.
            let jump = ((min_ratio - init) / step).floor() as i64 + 1;
            iteration = iteration.max(jump.clamp(0, i64::from(u32::MAX)) as u32);
        }
    }
    for &i in &pending {
        let p = points[i as usize];
        let nearest = (0..k)
            .min_by(|&a, &b| {
                p.distance_squared(centers[a])
                    .total_cmp(&p.distance_squared(centers[b]))
            })
            .unwrap_or(0);
        assign[i as usize] = nearest as u32;
    }
    assign
}

/// Each leaf's IL chain by
/// [`LobeClustering::NearestBranch`](crate::LobeClustering::NearestBranch).
pub(crate) fn nearest_branch(
    anchors: &[Vec3],
    hints: &[NodeId],
    skeleton: &Skeleton,
    chain_of: &[ChainId],
) -> Vec<ChainId> {
    let nodes = skeleton.nodes();
    let seg = |i: usize| -> (Vec3, Vec3) {
        let n = &nodes[i];
        (
            nodes[n.parent.expect("non-root") as usize].position,
            n.position,
        )
    };
    let mut lengths: Vec<f32> = (1..nodes.len())
        .map(|i| {
            let (a, b) = seg(i);
            a.distance(b)
        })
        .collect();
    let mid = lengths.len() / 2;
    let cell = lengths
        .select_nth_unstable_by(mid, f32::total_cmp)
        .1
        .max(1e-4)
        * 2.0;
    let key = |p: Vec3| (p / cell).floor().as_ivec3();
    let mut grid: CellMap<Vec<u32>> = CellMap::default();
    for i in 1..nodes.len() {
        let (a, b) = seg(i);
        let (lo, hi) = (key(a.min(b)), key(a.max(b)));
        for x in lo.x..=hi.x {
            for y in lo.y..=hi.y {
                for z in lo.z..=hi.z {
                    grid.entry(IVec3::new(x, y, z)).or_default().push(i as u32);
                }
            }
        }
    }
    let dist2 = |p: Vec3, i: usize| -> f32 {
        let (a, b) = seg(i);
        p.distance_squared(closest_on_segment(p, a, b).0)
    };
    anchors
        .par_iter()
        .zip(hints)
        .map(|(&p, &hint)| {
            // The hinted branch bounds the search; ties keep the lower id
            // unless the hint is among them.
            let mut best = (dist2(p, hint as usize), hint);
            let c = key(p);
            let max_ring = (best.0.sqrt() / cell).ceil() as i32 + 1;
            for ring in 0..=max_ring {
                // Every cell in this ring is at least (ring - 1) cells away.
                let bound = (ring - 1).max(0) as f32 * cell;
                if bound * bound > best.0 {
                    break;
                }
                for x in -ring..=ring {
                    for y in -ring..=ring {
                        for z in -ring..=ring {
                            if x.abs().max(y.abs()).max(z.abs()) != ring {
                                continue;
                            }
                            let Some(list) = grid.get(&(c + IVec3::new(x, y, z))) else {
                                continue;
                            };
                            for &i in list {
                                let d = dist2(p, i as usize);
                                if d < best.0 || (d == best.0 && i < best.1 && best.1 != hint) {
                                    best = (d, i);
                                }
                            }
                        }
                    }
                }
            }
            chain_of[best.1 as usize]
        })
        .collect()
}

/// Top-down through the BPTT (§4.2 steps 1–3) with centre distances
/// ([`LobeClustering::CentreKMeans`](crate::LobeClustering::CentreKMeans)):
/// returns each leaf's IL chain.
pub(crate) fn cluster(
    anchors: &[Vec3],
    chains: &[Chain],
    groups: &[ChainGroup],
    levels: &[Range<GroupId>],
    min_radius: f32,
    options: &AnalysisOptions,
) -> Vec<ChainId> {
    let crowns = crowns(chains, groups);
    let mut input: Vec<Vec<u32>> = vec![Vec::new(); groups.len()];
    input[0] = (0..anchors.len() as u32).collect();
    let mut il = vec![NONE; anchors.len()];
    for level in levels {
        let work: Vec<(GroupId, Vec<u32>)> = level
            .clone()
            .map(|g| (g, std::mem::take(&mut input[g as usize])))
            .filter(|(_, leaves)| !leaves.is_empty())
            .collect();
        let out: Vec<(Vec<u32>, Vec<Target>)> = work
            .into_par_iter()
            .map(|(g, leaves)| {
                let group = &groups[g as usize];
                let mut targets = Vec::new();
                let mut centers = Vec::new();
                let mut radii = Vec::new();
                for &child in &group.children {
                    let (c, r) = crowns[child as usize];
                    targets.push(Target::Group(child));
                    centers.push(c);
                    radii.push(r.max(min_radius));
                }
                for &c in &group.chains {
                    let chain = &chains[c as usize];
                    targets.push(Target::Chain(c));
                    centers.push(chain.tip());
                    radii.push((options.tip_radius * chain.length).max(min_radius));
                }
                let points: Vec<Vec3> = leaves.iter().map(|&l| anchors[l as usize]).collect();
                let assign = threshold_kmeans(&points, centers, &radii, options);
                let t = assign.iter().map(|&a| targets[a as usize]).collect();
                (leaves, t)
            })
            .collect();
        for (leaves, targets) in out {
            for (l, t) in leaves.into_iter().zip(targets) {
                match t {
                    Target::Group(g) => input[g as usize].push(l),
                    Target::Chain(c) => il[l as usize] = c,
                }
            }
        }
    }
    il
}

/// Fills every chain's IL and OL and every group's GOL: leaf lists,
/// centres, radii and hulls.
pub(crate) fn build(
    tree: &Tree,
    il_of_leaf: &[ChainId],
    chains: &mut [Chain],
    groups: &mut [ChainGroup],
    inflate: f32,
    options: &AnalysisOptions,
) {
    let points: Vec<[Vec3; 2]> = tree
        .leaves()
        .iter()
        .map(|l| blade_points(tree, l))
        .collect();
    for (leaf, &c) in il_of_leaf.iter().enumerate() {
        chains[c as usize].inner_lobe.leaves.push(leaf as u32);
    }
    for i in (0..chains.len()).rev() {
        let mut ol = chains[i].inner_lobe.leaves.clone();
        for k in chains[i].children.clone() {
            ol.extend_from_slice(&chains[k as usize].outer_lobe.leaves);
        }
        ol.sort_unstable();
        chains[i].outer_lobe.leaves = ol;
    }
    for g in groups.iter_mut() {
        let mut gol: Vec<u32> = g
            .chains
            .iter()
            .flat_map(|&c| chains[c as usize].outer_lobe.leaves.iter().copied())
            .collect();
        gol.sort_unstable();
        g.outer_lobe.leaves = gol;
    }

    let gather =
        |leaves: &[u32]| -> Vec<Vec3> { leaves.iter().flat_map(|&l| points[l as usize]).collect() };
    match options.hull {
        HullKind::Convex => {
            // Exact and cheap bottom-up: hull(OL) = hull(IL points ∪ the
            // GOL hull vertices of the groups growing on the chain), and
            // hull(GOL) = hull(its chains' OL hull vertices) (just the OL for
            // a one-chain group). Child orders are parent order + 1, so we
            // go from the highest order down: GOLs of order k + 1, then the
            // chains of order k.
            let max_order = chains.iter().map(|c| c.order).max().unwrap_or(1) as usize;
            let mut chains_by_order: Vec<Vec<ChainId>> = vec![Vec::new(); max_order + 2];
            for c in chains.iter() {
                chains_by_order[c.order as usize].push(c.id);
            }
            let mut groups_by_order: Vec<Vec<GroupId>> = vec![Vec::new(); max_order + 2];
            for g in groups.iter() {
                groups_by_order[g.order as usize].push(g.id);
            }
            let mut child_groups: Vec<Vec<GroupId>> = vec![Vec::new(); chains.len()];
            for g in groups.iter() {
                if let Some(p) = g.parent_chain {
                    child_groups[p as usize].push(g.id);
                }
            }
            for order in (1..=max_order).rev() {
                let gols: Vec<Hull> = groups_by_order[order + 1]
                    .par_iter()
                    .map(|&g| gol_hull(&groups[g as usize], chains, inflate))
                    .collect();
                for (&g, h) in groups_by_order[order + 1].iter().zip(gols) {
                    groups[g as usize].outer_lobe.hull = h;
                }
                let ids = &chains_by_order[order];
                let hulls: Vec<(Hull, Hull)> = ids
                    .par_iter()
                    .map(|&c| {
                        let chain = &chains[c as usize];
                        let il = Hull::convex(&gather(&chain.inner_lobe.leaves), inflate);
                        if child_groups[c as usize].is_empty() {
                            return (il.clone(), il);
                        }
                        let mut ol_pts = il.vertices.clone();
                        for &g in &child_groups[c as usize] {
                            ol_pts.extend_from_slice(&groups[g as usize].outer_lobe.hull.vertices);
                        }
                        (il, Hull::convex(&ol_pts, inflate))
                    })
                    .collect();
                for (&c, (il, ol)) in ids.iter().zip(hulls) {
                    chains[c as usize].inner_lobe.hull = il;
                    chains[c as usize].outer_lobe.hull = ol;
                }
            }
            for &g in &groups_by_order[1] {
                groups[g as usize].outer_lobe.hull = gol_hull(&groups[g as usize], chains, inflate);
            }
        }
        HullKind::Radial { rings, segments } => {
            let template = RadialTemplate::new(rings, segments);
            let hulls: Vec<(Hull, Hull)> = chains
                .par_iter()
                .map(|c| {
                    (
                        template.hull(&gather(&c.inner_lobe.leaves), inflate),
                        template.hull(&gather(&c.outer_lobe.leaves), inflate),
                    )
                })
                .collect();
            for (c, (il, ol)) in chains.iter_mut().zip(hulls) {
                c.inner_lobe.hull = il;
                c.outer_lobe.hull = ol;
            }
            let gols: Vec<Hull> = groups
                .par_iter()
                .map(|g| template.hull(&gather(&g.outer_lobe.leaves), inflate))
                .collect();
            for (g, h) in groups.iter_mut().zip(gols) {
                g.outer_lobe.hull = h;
            }
        }
    }

    let finish = |lobe: &mut Lobe, fallback: Vec3| {
        if lobe.leaves.is_empty() {
            lobe.center = fallback;
            lobe.radius = 0.0;
            return;
        }
        let sum: Vec3 = lobe.leaves.iter().flat_map(|&l| points[l as usize]).sum();
        lobe.center = sum / (2 * lobe.leaves.len()) as f32;
        lobe.radius = lobe
            .hull
            .vertices
            .iter()
            .map(|v| v.distance(lobe.center))
            .fold(0.0, f32::max);
    };
    chains.par_iter_mut().for_each(|c| {
        let tip = c.tip();
        finish(&mut c.inner_lobe, tip);
        finish(&mut c.outer_lobe, tip);
    });
    let tips: Vec<Vec3> = groups
        .iter()
        .map(|g| {
            g.chains
                .iter()
                .map(|&c| chains[c as usize].tip())
                .sum::<Vec3>()
                / g.chains.len() as f32
        })
        .collect();
    groups
        .par_iter_mut()
        .zip(tips)
        .for_each(|(g, tip)| finish(&mut g.outer_lobe, tip));
}

fn gol_hull(g: &ChainGroup, chains: &[Chain], inflate: f32) -> Hull {
    if let [only] = g.chains[..] {
        return chains[only as usize].outer_lobe.hull.clone();
    }
    let pts: Vec<Vec3> = g
        .chains
        .iter()
        .flat_map(|&c| chains[c as usize].outer_lobe.hull.vertices.iter().copied())
        .collect();
    Hull::convex(&pts, inflate)
}
