//! Correspondences (§5): chain groups by minimum-weight bipartite matching
//! level by level down the BPTTs, chains greedily one-to-many inside matched
//! groups, leaves greedily one-to-many inside matched inner lobes.

use std::collections::VecDeque;
use std::sync::OnceLock;

use glam::{Quat, Vec3};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;
use treemorph_analysis::{Analysis, ChainId, GroupId};
use treemorph_tree::Tree;

use crate::assignment::{FORBIDDEN, match_or_leave};
use crate::crossing::{Pose, Swing, Swings, Track, uncross};
use crate::options::{ChainMatching, LeafMorph, MorphOptions};

/// The transformation that carries a union chain from source to target
/// (§6.1, Figure 5).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Operation {
    /// A one-to-one matched chain.
    Morph,
    /// One copy of a source chain matched to several target chains.
    Split,
    /// One of several source chains matched to one target chain.
    Merge,
    /// A target chain without a source: grows from zero length.
    Grow,
    /// A source chain without a target: wilts to zero length.
    Wilt,
}

/// A matched pair of chains.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct ChainMatch {
    /// Source chain.
    pub source: ChainId,
    /// Target chain.
    pub target: ChainId,
    /// [`Operation::Morph`], [`Operation::Split`] or [`Operation::Merge`].
    pub operation: Operation,
    /// Whether this is the pair the greedy matching made first for the chain
    /// that has several partners (the split source's or merge target's most
    /// similar partner). Unmatched children and leaves of that chain ride on
    /// its primary pair. Always true for [`Operation::Morph`].
    pub primary: bool,
}

/// A leaf pair, or a leaf that grows or wilts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct LeafMatch {
    /// Source leaf index (into [`Tree::leaves`]); `None` for a leaf that
    /// grows.
    pub source: Option<u32>,
    /// Target leaf index; `None` for a leaf that wilts.
    pub target: Option<u32>,
}

/// All correspondences between the source and the target tree.
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct Correspondence {
    /// Matched chain groups `[source, target]`, top-down (the root groups
    /// first). A matched pair may match none of its chains when they were
    /// kept out of the matching (untangling): they then wilt and grow.
    pub groups: Vec<[GroupId; 2]>,
    /// Source groups left unmatched, each with its BPTT subtree (they wilt).
    pub wilting_groups: Vec<GroupId>,
    /// Target groups left unmatched, each with its BPTT subtree (they grow).
    pub growing_groups: Vec<GroupId>,
    /// Matched chains.
    pub chains: Vec<ChainMatch>,
    /// Source chains without a partner.
    pub wilting_chains: Vec<ChainId>,
    /// Target chains without a partner.
    pub growing_chains: Vec<ChainId>,
    /// Leaf pairs and unmatched leaves: every leaf of both trees appears at
    /// least once.
    pub leaves: Vec<LeafMatch>,
}

/// One tree with its analysis and the derived facts the costs need.
pub(crate) struct Input<'a> {
    pub tree: &'a Tree,
    pub analysis: &'a Analysis,
    /// Root node position: the origin of the normalised coordinates.
    pub origin: Vec3,
    /// 1 / tree height (metres⁻¹): normalised coordinates have unit height.
    pub inv_height: f32,
    /// Child groups of each chain.
    pub child_groups: Vec<Vec<GroupId>>,
    /// Each group's GOL support function on [`DIRECTIONS`] in normalised
    /// coordinates (`None` for an empty GOL), computed when first needed:
    /// groups under unmatched groups are never compared.
    pub gol: Vec<OnceLock<Option<[f32; DIRECTIONS]>>>,
    dirs: Directions,
}

/// [`directions`] as structure of arrays, for a vectorisable inner loop.
pub(crate) struct Directions {
    x: [f32; DIRECTIONS],
    y: [f32; DIRECTIONS],
    z: [f32; DIRECTIONS],
}

impl Directions {
    pub(crate) fn new() -> Directions {
        let d = directions();
        Directions {
            x: d.map(|v| v.x),
            y: d.map(|v| v.y),
            z: d.map(|v| v.z),
        }
    }
}

/// Directions on which GOL support functions are sampled.
pub(crate) const DIRECTIONS: usize = 64;

/// [`DIRECTIONS`] unit vectors spread evenly over the sphere (a Fibonacci
/// lattice).
pub(crate) fn directions() -> [Vec3; DIRECTIONS] {
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    std::array::from_fn(|i| {
        let y = 1.0 - 2.0 * (i as f32 + 0.5) / DIRECTIONS as f32;
        let r = (1.0 - y * y).max(0.0).sqrt();
        let a = golden * i as f32;
        Vec3::new(r * a.cos(), y, r * a.sin())
    })
}

/// The support function `h(n) = max_p (p − origin)·n / height` of a point
/// set on [`directions`], i.e. in normalised coordinates; `None` for an
/// empty set.
pub(crate) fn support(
    points: &[Vec3],
    origin: Vec3,
    inv_height: f32,
    dirs: &Directions,
) -> Option<[f32; DIRECTIONS]> {
    if points.is_empty() {
        return None;
    }
    let mut h = [f32::NEG_INFINITY; DIRECTIONS];
    for &p in points {
        let p = (p - origin) * inv_height;
        for (k, h) in h.iter_mut().enumerate() {
            let d = p.x * dirs.x[k] + p.y * dirs.y[k] + p.z * dirs.z[k];
            *h = if d > *h { d } else { *h };
        }
    }
    Some(h)
}

/// The Hausdorff distance between the convex hulls of two point sets from
/// their support functions: `sup_n |h_A(n) − h_B(n)|`, exact for convex
/// bodies as the directions get dense, here sampled on 64 (a lower bound
/// within about 1 % of the lobes' size).
pub(crate) fn support_distance(a: &[f32; DIRECTIONS], b: &[f32; DIRECTIONS]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

impl<'a> Input<'a> {
    pub fn new(tree: &'a Tree, analysis: &'a Analysis, height: f32) -> Input<'a> {
        let origin = tree.skeleton().node(0).position;
        let inv_height = 1.0 / height;
        let mut child_groups = vec![Vec::new(); analysis.chains().len()];
        for g in analysis.groups() {
            if let Some(c) = g.parent_chain {
                child_groups[c as usize].push(g.id);
            }
        }
        let gol = (0..analysis.groups().len())
            .map(|_| OnceLock::new())
            .collect();
        Input {
            tree,
            analysis,
            origin,
            inv_height,
            child_groups,
            gol,
            dirs: Directions::new(),
        }
    }

    fn gol(&self, g: GroupId) -> Option<&[f32; DIRECTIONS]> {
        self.gol[g as usize]
            .get_or_init(|| {
                let hull = &self.analysis.group(g).outer_lobe.hull;
                support(&hull.vertices, self.origin, self.inv_height, &self.dirs)
            })
            .as_ref()
    }

    fn normalised(&self, p: Vec3) -> Vec3 {
        (p - self.origin) * self.inv_height
    }
}

/// Symmetric Hausdorff distance between two point sets, brute force (the
/// reference for [`support_distance`] in tests).
#[cfg(test)]
pub(crate) fn hausdorff(a: &[Vec3], b: &[Vec3]) -> f32 {
    fn directed(a: &[Vec3], b: &[Vec3]) -> f32 {
        let mut worst = 0.0f32;
        for &p in a {
            let mut best = f32::INFINITY;
            for &q in b {
                best = best.min(p.distance_squared(q));
                if best <= worst {
                    break; // cannot raise the maximum
                }
            }
            worst = worst.max(best);
        }
        worst.sqrt()
    }
    directed(a, b).max(directed(b, a))
}

/// The group cost (Eq. 4).
fn group_cost(s: &Input, t: &Input, gs: GroupId, gt: GroupId, o: &MorphOptions) -> f64 {
    let w = &o.group_weights;
    let (a, b) = (s.analysis.group(gs), t.analysis.group(gt));
    let lobe = if let (Some(ha), Some(hb)) = (s.gol(gs), t.gol(gt)) {
        support_distance(ha, hb)
    } else {
        // An empty GOL has a centre (its chains' tips) but no hull: compare
        // bounding spheres, whose Hausdorff distance is |Δc| + |Δr|.
        let (ca, cb) = (
            s.normalised(a.outer_lobe.center),
            t.normalised(b.outer_lobe.center),
        );
        ca.distance(cb)
            + (a.outer_lobe.radius * s.inv_height - b.outer_lobe.radius * t.inv_height).abs()
    };
    let (na, nb) = (a.chains.len() as f32, b.chains.len() as f32);
    // A one-chain group has no divergence angle (the analysis reports 0);
    // the chain-count term already prices a change of pattern.
    let divergence = if na >= 2.0 && nb >= 2.0 {
        (a.divergence - b.divergence).abs() / 180.0
    } else {
        0.0
    };
    let cost = w.outer_lobe * lobe
        + w.branching_vector * 0.5 * a.branching_vector.distance(b.branching_vector)
        + w.lobe_ratio * (a.lobe_ratio - b.lobe_ratio).abs()
        + w.chain_count * (na - nb).abs() / na.max(nb)
        + w.divergence * divergence
        + w.growth_location * (a.growth_location - b.growth_location).abs();
    if cost.is_finite() {
        cost as f64
    } else {
        FORBIDDEN
    }
}

fn chain_cost(s: &Input, t: &Input, cs: ChainId, ct: ChainId, o: &MorphOptions) -> f32 {
    let w = &o.chain_weights;
    let (a, b) = (s.analysis.chain(cs), t.analysis.chain(ct));
    let lobe = s
        .normalised(a.outer_lobe.center)
        .distance(t.normalised(b.outer_lobe.center))
        + (a.outer_lobe.radius * s.inv_height - b.outer_lobe.radius * t.inv_height).abs();
    let cost = w.branching_vector * 0.5 * a.branching_vector.distance(b.branching_vector)
        + w.growth_location * (a.growth_location - b.growth_location).abs()
        + w.length * (a.length * s.inv_height - b.length * t.inv_height).abs()
        + w.outer_ratio * (a.outer_ratio - b.outer_ratio).abs()
        + w.inner_ratio * (a.inner_ratio - b.inner_ratio).abs()
        + w.outer_lobe * lobe;
    if cost.is_finite() { cost } else { f32::MAX }
}

/// A leaf's matching features, relative to its IL chain.
#[derive(Clone, Copy)]
pub(crate) struct LeafFeatures {
    pub index: u32,
    pub param: f32,
    pub azimuth: Vec3,
    pub width: f32,
    pub height: f32,
    pub orientation: Quat,
}

fn leaf_features(input: &Input, leaf: u32) -> LeafFeatures {
    let p = &input.analysis.leaves()[leaf as usize];
    LeafFeatures {
        index: leaf,
        param: p.param,
        azimuth: p.offset.normalize_or_zero(),
        width: p.width,
        height: p.height,
        orientation: p.orientation,
    }
}

fn leaf_cost(a: &LeafFeatures, b: &LeafFeatures, o: &MorphOptions) -> f32 {
    let w = &o.leaf_weights;
    let angle = 2.0 * a.orientation.dot(b.orientation).abs().min(1.0).acos();
    let cost = w.position * (a.param - b.param).abs()
        + w.azimuth * 0.5 * a.azimuth.distance(b.azimuth)
        + w.size
            * ((a.width - b.width).abs() / (a.width + b.width).max(1e-12)
                + (a.height - b.height).abs() / (a.height + b.height).max(1e-12))
        + w.orientation * angle / std::f32::consts::PI;
    if cost.is_finite() { cost } else { f32::MAX }
}

/// A pair chosen by [`greedy`]: row, column, and whether it was made in the
/// one-to-one phase.
pub(crate) type GreedyPair = (usize, usize, bool);

/// Greedy matching over candidate pairs `(row, column, cost)` of a
/// `rows × cols` problem. Phase 1 takes pairs cheapest first while both
/// ends are free (a one-to-one matching). With `one_to_many`, phase 2 then
/// attaches every element still free — on a dense problem only surplus
/// elements of the larger side — to its cheapest candidate partner.
pub(crate) fn greedy(
    candidates: &mut [(u32, u32, f32)],
    rows: usize,
    cols: usize,
    one_to_many: bool,
) -> Vec<GreedyPair> {
    candidates.sort_by(|a, b| a.2.total_cmp(&b.2).then(a.0.cmp(&b.0)).then(a.1.cmp(&b.1)));
    let mut row_done = vec![false; rows];
    let mut col_done = vec![false; cols];
    let mut pairs = Vec::with_capacity(rows.max(cols));
    let target = rows.min(cols);
    for &(i, j, _) in candidates.iter() {
        if pairs.len() == target {
            break;
        }
        let (i, j) = (i as usize, j as usize);
        if !row_done[i] && !col_done[j] {
            row_done[i] = true;
            col_done[j] = true;
            pairs.push((i, j, true));
        }
    }
    if one_to_many {
        // Candidates are sorted, so the first one seen is the cheapest.
        let mut row_seen = row_done.clone();
        let mut col_seen = col_done.clone();
        for &(i, j, _) in candidates.iter() {
            let (i, j) = (i as usize, j as usize);
            if !row_seen[i] {
                row_seen[i] = true;
                pairs.push((i, j, false));
            } else if !col_seen[j] {
                col_seen[j] = true;
                pairs.push((i, j, false));
            }
        }
    }
    pairs
}

/// Chains of one star: one chain on one side matched to one or more on the
/// other (every pair of a one-to-many matching belongs to exactly one star).
struct Star {
    sources: Vec<ChainId>,
    targets: Vec<ChainId>,
}

/// Group pairs above which a block's costs are computed with rayon.
const PARALLEL_BLOCK: usize = 1024;

/// Chains kept out of the matching: each wilts (source side) or grows
/// (target side) with its whole substructure. The untangling step fills it
/// with chains whose blends cross (`untangling`).
#[derive(Clone, Debug, Default)]
pub(crate) struct Excluded {
    /// Per side, per chain: excluded when true (an empty list excludes
    /// nothing).
    pub chains: [Vec<bool>; 2],
}

impl Excluded {
    /// Whether chain `c` of side `side` (0 source, 1 target) is excluded.
    pub fn has(&self, side: usize, c: ChainId) -> bool {
        self.chains[side].get(c as usize).copied().unwrap_or(false)
    }

    /// Excludes chain `c` of side `side` of a tree with `chains` chains.
    pub fn add(&mut self, side: usize, c: ChainId, chains: usize) {
        let marks = &mut self.chains[side];
        marks.resize(chains, false);
        marks[c as usize] = true;
    }
}

/// Builds every correspondence, `excluded` chains left out of it.
pub(crate) fn correspond(
    s: &Input,
    t: &Input,
    options: &MorphOptions,
    excluded: &Excluded,
) -> Correspondence {
    let sa = s.analysis;
    let ta = t.analysis;
    let mut out = Correspondence::default();
    let mut stars: Vec<Star> = Vec::new();
    let mut src_unmatched = vec![false; sa.chains().len()];
    let mut tgt_unmatched = vec![false; ta.chains().len()];
    let u = options.unmatched_group_cost as f64;

    // Rules 1 and 2 hold by construction: the root groups match, and the
    // child groups of a star's chains are matched only among themselves, so
    // matched groups always sit at one BPTT level on matched parent chains.
    let mut queue: VecDeque<[GroupId; 2]> = VecDeque::from([[0, 0]]);
    let mut candidates: Vec<(u32, u32, f32)> = Vec::new();
    let mut block: Vec<f64> = Vec::new();
    while let Some([gs, gt]) = queue.pop_front() {
        out.groups.push([gs, gt]);
        // Rule 3: chains are matched only inside matched groups.
        let (cs, ct) = (
            kept(sa, gs, 0, excluded, &mut src_unmatched),
            kept(ta, gt, 1, excluded, &mut tgt_unmatched),
        );
        let (cs, ct) = (cs.as_slice(), ct.as_slice());
        let pairs = match_chains(s, t, (cs, ct), options, &mut candidates);
        let mut src_partners = vec![0u32; cs.len()];
        let mut tgt_partners = vec![0u32; ct.len()];
        for &(i, j, _) in &pairs {
            src_partners[i] += 1;
            tgt_partners[j] += 1;
        }
        for &(i, j, primary) in &pairs {
            let operation = if src_partners[i] > 1 {
                Operation::Split
            } else if tgt_partners[j] > 1 {
                Operation::Merge
            } else {
                Operation::Morph
            };
            out.chains.push(ChainMatch {
                source: cs[i],
                target: ct[j],
                operation,
                primary: primary || operation == Operation::Morph,
            });
        }
        for (i, &a) in cs.iter().enumerate() {
            if src_partners[i] == 0 {
                mark_substructure(sa, a, &mut src_unmatched);
            }
        }
        for (j, &b) in ct.iter().enumerate() {
            if tgt_partners[j] == 0 {
                mark_substructure(ta, b, &mut tgt_unmatched);
            }
        }
        // Stars: centred on the chain with several partners (a split source
        // or a merge target), or a one-to-one pair.
        let first_star = stars.len();
        for (i, &a) in cs.iter().enumerate() {
            let mine = pairs.iter().filter(|p| p.0 == i);
            if src_partners[i] > 1 || mine.clone().any(|p| tgt_partners[p.1] == 1) {
                stars.push(Star {
                    sources: vec![a],
                    targets: mine.map(|p| ct[p.1]).collect(),
                });
            }
        }
        for (j, &b) in ct.iter().enumerate() {
            if tgt_partners[j] > 1 {
                stars.push(Star {
                    sources: pairs.iter().filter(|p| p.1 == j).map(|p| cs[p.0]).collect(),
                    targets: vec![b],
                });
            }
        }
        // The child groups of each star: a minimum-weight bipartite matching
        // in which a group may stay unmatched at `unmatched_group_cost`.
        for star in &stars[first_star..] {
            let gs_kids: Vec<GroupId> = star
                .sources
                .iter()
                .flat_map(|&c| s.child_groups[c as usize].iter().copied())
                .collect();
            let gt_kids: Vec<GroupId> = star
                .targets
                .iter()
                .flat_map(|&c| t.child_groups[c as usize].iter().copied())
                .collect();
            block.clear();
            if gs_kids.len() * gt_kids.len() >= PARALLEL_BLOCK {
                block.resize(gs_kids.len() * gt_kids.len(), 0.0);
                block
                    .par_chunks_mut(gt_kids.len())
                    .zip(&gs_kids)
                    .for_each(|(row, &a)| {
                        for (c, &b) in row.iter_mut().zip(&gt_kids) {
                            *c = group_cost(s, t, a, b, options);
                        }
                    });
            } else {
                for &a in &gs_kids {
                    for &b in &gt_kids {
                        block.push(group_cost(s, t, a, b, options));
                    }
                }
            }
            let mut matching =
                match_or_leave(&block, &vec![u; gs_kids.len()], &vec![u; gt_kids.len()]);
            if star.sources.len() == 1 && star.targets.len() == 1 {
                // Siblings on one parent each side: their motions compare.
                let swing = |i: usize, j: usize| group_swing(s, t, gs_kids[i], gt_kids[j], options);
                let swings = Swings {
                    cost: &block,
                    cols: gt_kids.len(),
                    weight: f64::from(options.group_weights.crossing),
                    swing: &swing,
                };
                uncross(&swings, &mut matching);
            }
            let mut target_used = vec![false; gt_kids.len()];
            for (i, m) in matching.iter().enumerate() {
                match m {
                    Some(j) => {
                        target_used[*j] = true;
                        queue.push_back([gs_kids[i], gt_kids[*j]]);
                    }
                    None => {
                        out.wilting_groups.push(gs_kids[i]);
                        for &c in &sa.group(gs_kids[i]).chains {
                            mark_substructure(sa, c, &mut src_unmatched);
                        }
                    }
                }
            }
            for (j, used) in target_used.iter().enumerate() {
                if !used {
                    out.growing_groups.push(gt_kids[j]);
                    for &c in &ta.group(gt_kids[j]).chains {
                        mark_substructure(ta, c, &mut tgt_unmatched);
                    }
                }
            }
        }
    }
    out.wilting_chains = (0..sa.chains().len() as ChainId)
        .filter(|&c| src_unmatched[c as usize])
        .collect();
    out.growing_chains = (0..ta.chains().len() as ChainId)
        .filter(|&c| tgt_unmatched[c as usize])
        .collect();

    out.leaves = match options.leaf_morph {
        LeafMorph::OnChains => match_leaves(s, t, &stars, &src_unmatched, &tgt_unmatched, options),
        LeafMorph::RandomLinear { seed } => {
            random_leaves(s.tree.leaves().len(), t.tree.leaves().len(), seed)
        }
    };
    out
}

/// The union chains groups `gs` and `gt` make when matched: their chains
/// matched as [`correspond`] matches them with nothing excluded, as pose
/// pairs (the crossing cost compares sibling limbs before untangling
/// sheds any of their chains).
fn group_swing(s: &Input, t: &Input, gs: GroupId, gt: GroupId, options: &MorphOptions) -> Swing {
    let cs = &s.analysis.group(gs).chains;
    let ct = &t.analysis.group(gt).chains;
    match_chains(s, t, (cs, ct), options, &mut Vec::new())
        .into_iter()
        .map(|(i, j, _)| Track::new(&Pose::of(s, cs[i]), &Pose::of(t, ct[j])))
        .collect()
}

/// The chains of two matched groups matched greedily (Rule 3), one to
/// many unless the options say one to one; `candidates` is scratch space.
fn match_chains(
    s: &Input,
    t: &Input,
    (cs, ct): (&[ChainId], &[ChainId]),
    options: &MorphOptions,
    candidates: &mut Vec<(u32, u32, f32)>,
) -> Vec<GreedyPair> {
    candidates.clear();
    for (i, &a) in cs.iter().enumerate() {
        for (j, &b) in ct.iter().enumerate() {
            candidates.push((i as u32, j as u32, chain_cost(s, t, a, b, options)));
        }
    }
    let one_to_many = options.chain_matching == ChainMatching::OneToMany;
    greedy(candidates, cs.len(), ct.len(), one_to_many)
}

/// The chains of group `g` of side `side` that are not excluded; the
/// excluded ones are marked unmatched with their substructure.
fn kept(
    analysis: &Analysis,
    g: GroupId,
    side: usize,
    excluded: &Excluded,
    unmatched: &mut [bool],
) -> Vec<ChainId> {
    let mut kept = Vec::with_capacity(analysis.group(g).chains.len());
    for &c in &analysis.group(g).chains {
        if excluded.has(side, c) {
            mark_substructure(analysis, c, unmatched);
        } else {
            kept.push(c);
        }
    }
    kept
}

/// Marks a chain and its whole substructure.
fn mark_substructure(analysis: &Analysis, chain: ChainId, marks: &mut [bool]) {
    let mut stack = vec![chain];
    while let Some(c) = stack.pop() {
        if !marks[c as usize] {
            marks[c as usize] = true;
            stack.extend_from_slice(&analysis.chain(c).children);
        }
    }
}

/// Above this many candidate pairs, a leaf only considers the
/// [`LEAF_WINDOW`] leaves of the other side nearest to it along the chain.
const DENSE_LEAF_PAIRS: usize = 1 << 16;
pub(crate) const LEAF_WINDOW: usize = 48;

/// Greedy one-to-many leaf matching inside each star's inner lobes; leaves
/// of unmatched chains, or facing an empty IL, grow or wilt.
fn match_leaves(
    s: &Input,
    t: &Input,
    stars: &[Star],
    src_unmatched: &[bool],
    tgt_unmatched: &[bool],
    options: &MorphOptions,
) -> Vec<LeafMatch> {
    // Stars are independent: match them in parallel, then concatenate in
    // star order (deterministic).
    let per_star: Vec<Vec<LeafMatch>> = stars
        .par_iter()
        .with_min_len(64)
        .map(|star| star_leaves(s, t, star, options))
        .collect();
    let mut out: Vec<LeafMatch> = per_star.into_iter().flatten().collect();
    for (c, _) in src_unmatched.iter().enumerate().filter(|x| *x.1) {
        out.extend(
            s.analysis.chains()[c]
                .inner_lobe
                .leaves
                .iter()
                .map(|&l| LeafMatch {
                    source: Some(l),
                    target: None,
                }),
        );
    }
    for (c, _) in tgt_unmatched.iter().enumerate().filter(|x| *x.1) {
        out.extend(
            t.analysis.chains()[c]
                .inner_lobe
                .leaves
                .iter()
                .map(|&l| LeafMatch {
                    source: None,
                    target: Some(l),
                }),
        );
    }
    out
}

fn star_leaves(s: &Input, t: &Input, star: &Star, options: &MorphOptions) -> Vec<LeafMatch> {
    let a: Vec<LeafFeatures> = star
        .sources
        .iter()
        .flat_map(|&c| s.analysis.chain(c).inner_lobe.leaves.iter())
        .map(|&l| leaf_features(s, l))
        .collect();
    let b: Vec<LeafFeatures> = star
        .targets
        .iter()
        .flat_map(|&c| t.analysis.chain(c).inner_lobe.leaves.iter())
        .map(|&l| leaf_features(t, l))
        .collect();
    if a.is_empty() || b.is_empty() {
        let grow = b.iter().map(|l| LeafMatch {
            source: None,
            target: Some(l.index),
        });
        return a
            .iter()
            .map(|l| LeafMatch {
                source: Some(l.index),
                target: None,
            })
            .chain(grow)
            .collect();
    }
    let mut candidates = Vec::new();
    if a.len() * b.len() <= DENSE_LEAF_PAIRS {
        candidates.reserve(a.len() * b.len());
        for (i, x) in a.iter().enumerate() {
            for (j, y) in b.iter().enumerate() {
                candidates.push((i as u32, j as u32, leaf_cost(x, y, options)));
            }
        }
    } else {
        // Huge inner lobes: each leaf only looks at the leaves of the other
        // side nearest along the chain (both directions, so every leaf has
        // candidates).
        window_candidates(&a, &b, false, &mut candidates, options);
        window_candidates(&b, &a, true, &mut candidates, options);
        candidates.sort_by_key(|c| (c.0, c.1));
        candidates.dedup_by_key(|c| (c.0, c.1));
    }
    greedy(&mut candidates, a.len(), b.len(), true)
        .into_iter()
        .map(|(i, j, _)| LeafMatch {
            source: Some(a[i].index),
            target: Some(b[j].index),
        })
        .collect()
}

pub(crate) fn window_candidates(
    a: &[LeafFeatures],
    b: &[LeafFeatures],
    swapped: bool,
    out: &mut Vec<(u32, u32, f32)>,
    options: &MorphOptions,
) {
    let mut order: Vec<u32> = (0..b.len() as u32).collect();
    order.sort_by(|&x, &y| b[x as usize].param.total_cmp(&b[y as usize].param));
    for (i, x) in a.iter().enumerate() {
        let at = order.partition_point(|&k| b[k as usize].param < x.param);
        let lo = at.saturating_sub(LEAF_WINDOW / 2);
        let hi = (lo + LEAF_WINDOW).min(order.len());
        for &k in &order[lo..hi] {
            let c = leaf_cost(x, &b[k as usize], options);
            out.push(if swapped {
                (k, i as u32, c)
            } else {
                (i as u32, k, c)
            });
        }
    }
}

/// The Figure 11 baseline: a random one-to-many pairing of all leaves.
pub(crate) fn random_leaves(sources: usize, targets: usize, seed: u64) -> Vec<LeafMatch> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut a: Vec<u32> = (0..sources as u32).collect();
    let mut b: Vec<u32> = (0..targets as u32).collect();
    a.shuffle(&mut rng);
    b.shuffle(&mut rng);
    if a.is_empty() || b.is_empty() {
        return a
            .iter()
            .map(|&l| LeafMatch {
                source: Some(l),
                target: None,
            })
            .chain(b.iter().map(|&l| LeafMatch {
                source: None,
                target: Some(l),
            }))
            .collect();
    }
    (0..a.len().max(b.len()))
        .map(|k| LeafMatch {
            source: Some(a[k % a.len()]),
            target: Some(b[k % b.len()]),
        })
        .collect()
}
