//! [`FrameMetrics`]: what makes an in-between tree plausible, measured.

use glam::Vec3;
use serde::Serialize;
use treemorph_tree::frame::FrameMismatch;
use treemorph_tree::geom::closest_on_segment;
use treemorph_tree::{Frame, JumpMeter};

use crate::correspondence::Operation;
use crate::growth::GrowthMeter;
use crate::options::MetricsOptions;
use crate::plan::{EndpointError, LeafMode, MorphPlan};
use crate::schedule::Paced;

/// Measurements of one frame (see the crate docs, *Metrics*).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct FrameMetrics {
    /// The frame's time.
    pub t: f32,
    /// Chains whose junction node is farther than ε from their parent
    /// chain's axis plus its radius there (root chains: from the root
    /// node). Always 0 for the paper's method.
    pub floating_branches: u32,
    /// Leaves whose anchor is farther than their interpolated offset + ε
    /// from the chain they belong to (for the random-leaf baseline: from
    /// both the chain they come from and the chain they go to).
    pub floating_leaves: u32,
    /// Maximum main-trunk support weight: the heaviest T(OR) over the main
    /// trunks, over the frame's total weight.
    pub mtsw: f32,
    /// Largest displacement of a node or a leaf quad's corner since the
    /// previous frame measured by the same [`FrameMeter`], over the plan's
    /// height (0 for the first frame): leaves that unfold or fold move
    /// their corners even where their anchors stand still.
    pub max_jump: f32,
    /// Growing or wilting chains with a segment grown beyond one that is
    /// not at its full length: not growing from the tip (measured on the
    /// frame's nodes against the input chain's segment lengths).
    pub growth_out_of_order: u32,
    /// Growing chains shorter, or wilting chains longer, than in the
    /// previous frame measured by the same [`FrameMeter`].
    pub growth_reversals: u32,
    /// Visible leaves drawn on top of another with a different material
    /// pair (same anchor, orientation and size): copies of one leaf that
    /// z-fight as they blend.
    pub coincident_leaves: u32,
    /// The plan's end-frame error (the same for every frame).
    pub endpoint_error: EndpointError,
}

/// Distance from `p` to the polyline through `nodes` and the radius there.
fn to_polyline(p: Vec3, positions: &[Vec3], radii: &[f32]) -> (f32, f32) {
    if positions.len() == 1 {
        return (p.distance(positions[0]), radii[0]);
    }
    let mut best = (f32::INFINITY, 0.0);
    for j in 0..positions.len() - 1 {
        let (a, b) = (positions[j], positions[j + 1]);
        let (q, f) = closest_on_segment(p, a, b);
        let d = p.distance_squared(q);
        if d < best.0 {
            best = (d, radii[j] + (radii[j + 1] - radii[j]) * f);
        }
    }
    (best.0.sqrt(), best.1)
}

/// Whether `p` lies within `reach` of segment `j` of the polyline through
/// `positions` (its one node when it has one): `to_polyline`'s distance on
/// that segment, so any segment within reach answers as `to_polyline(p,
/// ..).0 <= reach` does (the square root is monotone).
fn within_segment(p: Vec3, positions: &[Vec3], j: usize, reach: f32) -> bool {
    match positions.get(j..j + 2) {
        Some(&[a, b]) => p.distance_squared(closest_on_segment(p, a, b).0).sqrt() <= reach,
        _ => j == 0 && positions.len() == 1 && p.distance(positions[0]) <= reach,
    }
}

/// Whether a leaf at `p` lies within `reach` of one of its hosts' axes
/// (`hosts`: the chains' node ranges). `hint` is the host (by rank) and
/// segment that held it last frame, tried first, then every segment of
/// every host until one is within reach, which becomes the hint: a leaf
/// mostly stays by its segment from one frame to the next, so most leaves
/// cost one segment instead of a scan of their hosts.
fn leaf_within(
    p: Vec3,
    positions: &[Vec3],
    hosts: &[std::ops::Range<usize>],
    reach: f32,
    hint: &mut (u32, u32),
) -> bool {
    let (h, j) = (hint.0 as usize, hint.1 as usize);
    if hosts
        .get(h)
        .is_some_and(|r| within_segment(p, &positions[r.clone()], j, reach))
    {
        return true;
    }
    for (h, r) in hosts.iter().enumerate() {
        let axis = &positions[r.clone()];
        if let Some(j) = (0..axis.len().max(2) - 1).find(|&j| within_segment(p, axis, j, reach)) {
            *hint = (h as u32, j as u32);
            return true;
        }
    }
    false
}

/// Visible leaves of `frame` that coincide with another of a different
/// material pair: keyed by anchor, orientation and size rounded to a
/// millionth of the height (copies of one leaf are computed alike, so
/// they agree far closer than that).
///
/// The leaves are sorted by a hash of their key, and only runs of one
/// hash (almost always leaves with one key) are compared key by key,
/// rather than every frame sorting the 80-byte keys themselves.
fn coincident_leaves(plan: &MorphPlan, frame: &Frame) -> u32 {
    let scale = 1e6 / plan.height().max(f32::MIN_POSITIVE);
    let q = |x: f32, s: f32| (x * s).round() as i64;
    let keyed: Vec<([i64; 9], [u32; 2])> = frame
        .leaves
        .iter()
        .zip(&plan.topology().leaves)
        .filter(|(l, _)| l.width > 0.0 && l.height > 0.0)
        .map(|(l, t)| {
            let (a, o) = (l.anchor, l.orientation);
            let key = [
                q(a.x, scale),
                q(a.y, scale),
                q(a.z, scale),
                q(o.x, 1e5),
                q(o.y, 1e5),
                q(o.z, 1e5),
                q(o.w, 1e5),
                q(l.width, scale),
                q(l.height, scale),
            ];
            (key, t.materials)
        })
        .collect();
    count_coincident(&keyed)
}

/// How many of `keyed` (a leaf key and material pair each) share their key
/// with one of another material pair ([`coincident_leaves`]).
fn count_coincident(keyed: &[([i64; 9], [u32; 2])]) -> u32 {
    let mut hashed: Vec<(u64, u32)> = keyed
        .iter()
        .enumerate()
        .map(|(i, (key, _))| (key_hash(key), i as u32))
        .collect();
    hashed.sort_unstable();
    let mut count = 0u32;
    let mut run = Vec::new();
    for same_hash in hashed.chunk_by(|a, b| a.0 == b.0) {
        if same_hash.len() < 2 {
            continue;
        }
        run.clear();
        run.extend(same_hash.iter().map(|&(_, i)| keyed[i as usize]));
        run.sort_unstable();
        for group in run.chunk_by(|a, b| a.0 == b.0) {
            if group.iter().any(|g| g.1 != group[0].1) {
                count += group.len() as u32;
            }
        }
    }
    count
}

/// A 64-bit hash of a leaf key (a multiply-rotate mix, as FxHash does):
/// equal keys hash alike, and [`coincident_leaves`] compares the keys of
/// equal hashes, so a collision costs a comparison, never a miscount.
fn key_hash(key: &[i64; 9]) -> u64 {
    key.iter().fold(0u64, |h, &x| {
        (h.rotate_left(5) ^ x as u64).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95)
    })
}

/// Chains of `frame` whose junction is off their parent's axis by more
/// than the parent's radius there plus `eps` (roots: off the root node).
fn floating_branches(plan: &MorphPlan, frame: &Frame, eps: f32) -> u32 {
    let (pos, rad) = (&frame.positions, &frame.radii);
    let mut floating = 0u32;
    for c in plan.chains() {
        let junction = pos[c.nodes.start as usize];
        let off = match c.parent {
            None => junction.distance(pos[0]) > eps,
            Some(p) => {
                let r = plan.chains()[p as usize].nodes.clone();
                let r = r.start as usize..r.end as usize;
                let (d, radius) = to_polyline(junction, &pos[r.clone()], &rad[r]);
                d > radius + eps
            }
        };
        floating += u32::from(off);
    }
    floating
}

/// Per union chain, the leaves on it ([`LeafMode::OnChain`] with it as
/// host), in leaf order, flattened with offsets.
fn leaves_on_chains(plan: &MorphPlan) -> (Vec<u32>, Vec<u32>) {
    let n = plan.chains().len();
    let on = |l: &&crate::plan::LeafPlan| l.mode == LeafMode::OnChain && (l.host as usize) < n;
    let mut offsets = vec![0u32; n + 1];
    for l in plan.leaf_plans.iter().filter(on) {
        offsets[l.host as usize + 1] += 1;
    }
    for i in 0..n {
        offsets[i + 1] += offsets[i];
    }
    let mut fill = offsets.clone();
    let mut leaves = vec![0u32; offsets[n] as usize];
    for (k, l) in plan.leaf_plans.iter().enumerate() {
        if on(&l) {
            leaves[fill[l.host as usize] as usize] = k as u32;
            fill[l.host as usize] += 1;
        }
    }
    (leaves, offsets)
}

/// Volume over π of a frustum (a segment with linearly varying radius): it
/// adds up exactly when a segment is subdivided, so resampled chains weigh
/// what their inputs weigh.
fn frustum(ra: f64, rb: f64, len: f64) -> f64 {
    len * (ra * ra + ra * rb + rb * rb) / 3.0
}

/// Measures frames of one plan; keeps the previous frame for
/// [`FrameMetrics::max_jump`] and its scratch buffers between calls.
#[derive(Debug)]
pub struct FrameMeter<'p> {
    plan: &'p MorphPlan,
    options: MetricsOptions,
    jumps: JumpMeter,
    growth: GrowthMeter,
    /// Children of each union chain, flattened (`child_offsets`).
    children: Vec<u32>,
    child_offsets: Vec<u32>,
    subtree: Vec<f64>,
    leaf_weight: Vec<f64>,
    /// Per union chain: 1 / how many union chains share its source chain,
    /// and its target chain.
    chain_share: Vec<[f32; 2]>,
    /// Per union leaf: the same for its source and target leaf.
    leaf_share: Vec<[f32; 2]>,
    /// Root union chains grouped into trunks: split copies of one source
    /// chain, or merge copies of one target chain, form one group.
    trunks: Vec<Trunk>,
    /// Per trunk: its support weight and base radius (scratch).
    supports: Vec<(f64, f32)>,
    /// Per union leaf: the host (by rank) and segment that held it within
    /// reach last frame ([`leaf_within`]).
    leaf_hints: Vec<(u32, u32)>,
    /// Per union leaf: its schedule weight in the frame measured
    /// (scratch), found once for the three measures that read it.
    leaf_w: Vec<f32>,
    /// Per union chain, the leaves on it ([`LeafMode::OnChain`]), in
    /// leaf order, flattened (`on_chain_offsets`): a trunk's T(z) reads
    /// only those, where it scanned every leaf for them.
    on_chain: Vec<u32>,
    on_chain_offsets: Vec<u32>,
}

/// Root union chains that coincide at one end of the morph.
#[derive(Clone, Debug)]
struct Trunk {
    members: Vec<u32>,
    /// Whether the members coincide at t = 0 (split copies) or at t = 1
    /// (merge copies); irrelevant for one member.
    split: bool,
}

impl<'p> FrameMeter<'p> {
    /// A meter for frames of `plan`.
    pub fn new(plan: &'p MorphPlan, options: &MetricsOptions) -> FrameMeter<'p> {
        let n = plan.chains().len();
        let mut counts = vec![0u32; n + 1];
        for c in plan.chains() {
            if let Some(p) = c.parent {
                counts[p as usize + 1] += 1;
            }
        }
        for i in 0..n {
            counts[i + 1] += counts[i];
        }
        let mut fill = counts.clone();
        let mut children = vec![0u32; counts[n] as usize];
        for (i, c) in plan.chains().iter().enumerate() {
            if let Some(p) = c.parent {
                children[fill[p as usize] as usize] = i as u32;
                fill[p as usize] += 1;
            }
        }
        let chains = plan.chains();
        let count = |key: &dyn Fn(usize) -> Option<u32>, len: usize| {
            let mut m = vec![0u32; len];
            for i in 0..chains.len() {
                if let Some(k) = key(i) {
                    m[k as usize] += 1;
                }
            }
            m
        };
        let ns = chains
            .iter()
            .filter_map(|c| c.source)
            .max()
            .map_or(0, |m| m as usize + 1);
        let nt = chains
            .iter()
            .filter_map(|c| c.target)
            .max()
            .map_or(0, |m| m as usize + 1);
        let ms = count(&|i| chains[i].source, ns);
        let mt = count(&|i| chains[i].target, nt);
        let chain_share = chains
            .iter()
            .map(|c| {
                [
                    c.source.map_or(1.0, |s| 1.0 / ms[s as usize] as f32),
                    c.target.map_or(1.0, |t| 1.0 / mt[t as usize] as f32),
                ]
            })
            .collect();
        let origins = plan.leaf_origins();
        let ls = origins
            .iter()
            .filter_map(|m| m.source)
            .max()
            .map_or(0, |m| m as usize + 1);
        let lt = origins
            .iter()
            .filter_map(|m| m.target)
            .max()
            .map_or(0, |m| m as usize + 1);
        let mut mls = vec![0u32; ls];
        let mut mlt = vec![0u32; lt];
        for m in origins {
            if let Some(s) = m.source {
                mls[s as usize] += 1;
            }
            if let Some(t) = m.target {
                mlt[t as usize] += 1;
            }
        }
        let leaf_share = origins
            .iter()
            .map(|m| {
                [
                    m.source.map_or(1.0, |s| 1.0 / mls[s as usize] as f32),
                    m.target.map_or(1.0, |t| 1.0 / mlt[t as usize] as f32),
                ]
            })
            .collect();
        let mut trunks: Vec<Trunk> = Vec::new();
        for (i, c) in chains.iter().enumerate() {
            if c.parent.is_some() {
                continue;
            }
            let found = trunks.iter_mut().find(|g| {
                let m = &chains[g.members[0] as usize];
                match c.operation {
                    Operation::Split => m.operation == Operation::Split && m.source == c.source,
                    Operation::Merge => m.operation == Operation::Merge && m.target == c.target,
                    _ => false,
                }
            });
            match found {
                Some(g) => g.members.push(i as u32),
                None => trunks.push(Trunk {
                    members: vec![i as u32],
                    split: c.operation == Operation::Split,
                }),
            }
        }
        let (on_chain, on_chain_offsets) = leaves_on_chains(plan);
        FrameMeter {
            plan,
            options: options.clone(),
            jumps: JumpMeter::default(),
            growth: GrowthMeter::new(plan),
            children,
            child_offsets: counts,
            subtree: vec![0.0; n],
            leaf_weight: vec![0.0; n],
            chain_share,
            leaf_share,
            trunks,
            supports: Vec::new(),
            leaf_hints: vec![(0, 0); plan.leaf_hosts.len()],
            leaf_w: Vec::new(),
            on_chain,
            on_chain_offsets,
        }
    }

    /// Leaves of `frame` farther than their allowed offset (plus `eps`)
    /// from their hosts' axes.
    fn floating_leaves(&mut self, frame: &Frame, eps: f32) -> u32 {
        let plan = self.plan;
        let mut floating = 0u32;
        for (i, ((leaf, len), hosts)) in frame
            .leaves
            .iter()
            .zip(&plan.leaf_offset_len)
            .zip(&plan.leaf_hosts)
            .enumerate()
        {
            let w = self.leaf_w[i];
            let allowed = len[0] + (len[1] - len[0]) * w + eps;
            let ranges = hosts.map(|h| {
                let r = &plan.chains()[h as usize].nodes;
                r.start as usize..r.end as usize
            });
            let pos = &frame.positions;
            let near = leaf_within(leaf.anchor, pos, &ranges, allowed, &mut self.leaf_hints[i]);
            floating += u32::from(!near);
        }
        floating
    }

    /// Forgets the previous frame (the next `max_jump` is 0).
    pub fn reset(&mut self) {
        self.jumps.reset();
        self.growth.reset();
    }

    /// Measures `frame`, which must fit the plan's topology.
    pub fn measure(&mut self, frame: &Frame) -> Result<FrameMetrics, FrameMismatch> {
        let plan = self.plan;
        frame.check(plan.topology())?;
        let t = plan.schedule.paced(frame.t.clamp(0.0, 1.0));
        let height = plan.height();
        let eps = self.options.floating_epsilon * height;
        self.leaf_w.clear();
        self.leaf_w
            .extend((0..frame.leaves.len()).map(|i| plan.schedule.leaf(i, t)));
        let floating_branches = floating_branches(plan, frame, eps);
        let floating_leaves = self.floating_leaves(frame, eps);
        let mtsw = self.mtsw(frame, t);

        let max_jump = self.jumps.jump(frame) / height;
        let growth = self.growth.measure(plan, frame);

        Ok(FrameMetrics {
            t: frame.t,
            floating_branches,
            floating_leaves,
            mtsw,
            max_jump,
            growth_out_of_order: growth.out_of_order,
            coincident_leaves: coincident_leaves(plan, frame),
            growth_reversals: growth.reversals,
            endpoint_error: plan.endpoint_error(),
        })
    }

    /// §7's maximum main-trunk support weight (see the crate docs).
    fn mtsw(&mut self, frame: &Frame, t: Paced) -> f32 {
        let plan = self.plan;
        let chains = plan.chains();
        let wood = self.options.wood_density as f64 * std::f64::consts::PI;
        let leaf_density = self.options.leaf_area_density as f64;
        let pos = &frame.positions;
        let rad = &frame.radii;
        let schedule = &plan.schedule;
        let share = |s: [f32; 2], w: f32| ((1.0 - w) * s[0] + w * s[1]) as f64;
        let segment = |a: usize, b: usize| {
            frustum(rad[a] as f64, rad[b] as f64, pos[a].distance(pos[b]) as f64) * wood
        };
        self.leaf_weight.fill(0.0);
        for (i, leaf) in frame.leaves.iter().enumerate() {
            let w = self.leaf_w[i];
            let host = plan.leaf_hosts[i][usize::from(w >= 0.5)];
            self.leaf_weight[host as usize] += leaf_density
                * leaf.width as f64
                * leaf.height as f64
                * share(self.leaf_share[i], w);
        }
        for (i, c) in chains.iter().enumerate() {
            let r = c.nodes.start as usize..c.nodes.end as usize;
            let own: f64 = r.clone().zip(r.skip(1)).map(|(a, b)| segment(a, b)).sum();
            let w = schedule.chain_weight(i, t);
            self.subtree[i] = own * share(self.chain_share[i], w) + self.leaf_weight[i];
        }
        // Children follow their parents, so one backward pass sums subtrees.
        for i in (0..chains.len()).rev() {
            if let Some(p) = chains[i].parent {
                self.subtree[p as usize] += self.subtree[i];
            }
        }
        let total: f64 = (0..chains.len())
            .filter(|&i| chains[i].parent.is_none())
            .map(|i| self.subtree[i])
            .sum();
        if total <= 0.0 || self.trunks.is_empty() {
            return 0.0;
        }
        // Per trunk: coincident copies count as one trunk at the end where
        // they coincide and as separate trunks at the other, blended by t.
        let base_radius = |i: u32| rad[chains[i as usize].nodes.start as usize + 1];
        let mut supports = std::mem::take(&mut self.supports);
        supports.clear();
        for g in &self.trunks {
            let w = g
                .members
                .iter()
                .map(|&i| schedule.chain_weight(i as usize, t))
                .sum::<f32>()
                / g.members.len() as f32;
            let together = if g.members.len() < 2 {
                1.0
            } else if g.split {
                1.0 - w
            } else {
                w
            };
            // Coincident copies are one trunk cut at their common OR; apart,
            // each is cut at its own.
            let common = g
                .members
                .iter()
                .map(|&i| self.or_of(i as usize, t))
                .fold(1.0f32, f32::min);
            let (mut sum, mut max) = (0.0f64, 0.0f64);
            for &i in &g.members {
                let own = self.or_of(i as usize, t);
                let z = own + (common - own) * together;
                let v = self.t_at(frame, i as usize, z, t);
                sum += v;
                max = max.max(v);
            }
            let together = together as f64;
            let radius = g
                .members
                .iter()
                .map(|&i| base_radius(i))
                .fold(0.0f32, f32::max);
            supports.push((together * sum + (1.0 - together) * max, radius));
        }
        let thickest = (0..supports.len())
            .max_by(|&a, &b| supports[a].1.total_cmp(&supports[b].1))
            .expect("a trunk exists");
        let threshold = self.options.main_trunk_radius_ratio * supports[thickest].1;
        // Thin root chains (stems still growing) lean on the thickest trunk.
        let mut best = 0.0f64;
        let mut carried = 0.0f64;
        for (k, g) in self.trunks.iter().enumerate() {
            if k != thickest && supports[k].1 < threshold {
                carried += g
                    .members
                    .iter()
                    .map(|&i| self.subtree[i as usize])
                    .sum::<f64>();
            }
        }
        for (k, &(support, radius)) in supports.iter().enumerate() {
            if k == thickest {
                best = best.max(support + carried);
            } else if radius >= threshold {
                best = best.max(support);
            }
        }
        self.supports = supports;
        (best / total).clamp(0.0, 1.0) as f32
    }

    /// OR of union chain `i` at time `t`: the lowest growth location of its
    /// children (1 when it has none). A growing child's location slides in
    /// from the tip as it grows (`lerp(1, p, t)`; a wilting one's out,
    /// `lerp(1, p, 1 − t)`), so OR is continuous in `t` and equals the
    /// input's OR at both ends.
    fn or_of(&self, i: usize, t: Paced) -> f32 {
        let chains = self.plan.chains();
        self.children[self.child_offsets[i] as usize..self.child_offsets[i + 1] as usize]
            .iter()
            .map(|&k| {
                let p = self.plan.growth_at(k as usize, t);
                let w = self.plan.schedule.chain_weight(k as usize, t);
                let presence = match chains[k as usize].operation {
                    Operation::Grow => w,
                    Operation::Wilt => 1.0 - w,
                    _ => 1.0,
                };
                1.0 + (p - 1.0) * presence
            })
            .fold(1.0f32, f32::min)
    }

    /// T(z) of chain `i` at union parameter `z`: everything it supports
    /// from `z` up (its subtree minus its own wood and leaves below `z`).
    fn t_at(&self, frame: &Frame, i: usize, z: f32, t: Paced) -> f64 {
        let plan = self.plan;
        let cp = &plan.chain_plans[i];
        let u = &plan.sample_u[cp.first as usize..(cp.first + cp.len) as usize];
        let node0 = plan.chains()[i].nodes.start as usize;
        let pos = &frame.positions;
        let rad = &frame.radii;
        let wood = self.options.wood_density as f64 * std::f64::consts::PI;
        let s = self.chain_share[i];
        let w = plan.schedule.chain_weight(i, t);
        let share = ((1.0 - w) * s[0] + w * s[1]) as f64;
        let mut below = 0.0f64;
        for j in 0..u.len() - 1 {
            if u[j] >= z {
                break;
            }
            let span = u[j + 1] - u[j];
            let f = if span > 0.0 {
                ((z - u[j]) / span).clamp(0.0, 1.0)
            } else {
                1.0
            } as f64;
            let (a, b) = (node0 + j, node0 + j + 1);
            let (ra, rb) = (rad[a] as f64, rad[b] as f64);
            let cut = ra + (rb - ra) * f;
            below += frustum(ra, cut, f * pos[a].distance(pos[b]) as f64) * wood * share;
        }
        let leaf_density = self.options.leaf_area_density as f64;
        let on_chain = self.on_chain_offsets[i] as usize..self.on_chain_offsets[i + 1] as usize;
        for &k in &self.on_chain[on_chain] {
            let (k, leaf) = (k as usize, &frame.leaves[k as usize]);
            let l = &plan.leaf_plans[k];
            let w = self.leaf_w[k];
            let p = l.param[0] + (l.param[1] - l.param[0]) * w;
            if p < z {
                let s = self.leaf_share[k];
                below += leaf_density
                    * leaf.width as f64
                    * leaf.height as f64
                    * ((1.0 - w) * s[0] + w * s[1]) as f64;
            }
        }
        (self.subtree[i] - below).max(0.0)
    }
}

/// Measures one frame on its own (`max_jump` is 0); a [`FrameMeter`]
/// measures sequences.
pub fn frame_metrics(
    plan: &MorphPlan,
    frame: &Frame,
    options: &MetricsOptions,
) -> Result<FrameMetrics, FrameMismatch> {
    FrameMeter::new(plan, options).measure(frame)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// The hashed grouping counts what comparing every two leaves
        /// counts: leaves whose key another leaf of a different material
        /// pair shares.
        #[test]
        fn coincident_leaves_are_those_sharing_a_key_across_materials(
            leaves in prop::collection::vec((0i64..4, 0i64..3, 0u32..3), 0..40),
        ) {
            let keyed: Vec<([i64; 9], [u32; 2])> = leaves
                .iter()
                .map(|&(a, b, m)| ([a, b, 0, 0, 0, 0, 1, 2, 2], [m, m.min(1)]))
                .collect();
            let expected = keyed
                .iter()
                .filter(|(k, m)| keyed.iter().any(|(k2, m2)| k2 == k && m2 != m))
                .count() as u32;
            prop_assert_eq!(count_coincident(&keyed), expected);
        }

        /// With any hint, a leaf is within reach exactly when the nearest
        /// point of one of its hosts' axes is, as `to_polyline` measures.
        #[test]
        fn a_leaf_is_within_reach_as_its_nearest_axis_point_says(
            nodes in prop::collection::vec((-2.0f32..2.0, 0.0f32..4.0, -2.0f32..2.0), 0..9),
            split in 0usize..9,
            leaves in prop::collection::vec(((-3.0f32..3.0, -1.0f32..5.0, -3.0f32..3.0), 0.0f32..1.5), 1..20),
            hint in (0u32..3, 0u32..10),
        ) {
            let positions: Vec<Vec3> = nodes.iter().map(|&(x, y, z)| Vec3::new(x, y, z)).collect();
            let split = split.min(positions.len());
            let hosts = [0..split, split..positions.len()];
            let radii = vec![0.0; positions.len()];
            let mut hint = hint;
            for ((x, y, z), reach) in leaves {
                let p = Vec3::new(x, y, z);
                let expected = hosts.iter().any(|r| {
                    !r.is_empty() && to_polyline(p, &positions[r.clone()], &radii[r.clone()]).0 <= reach
                });
                prop_assert_eq!(leaf_within(p, &positions, &hosts, reach, &mut hint), expected);
            }
        }
    }
}
