//! Skeleton growth: chains, their internodes and their lateral groups, with
//! the ground truth recorded as the chains are made.
//!
//! Growth is budget driven. Every chain receives a budget — the exact number
//! of branches (skeleton edges) of its whole substructure. It keeps some for
//! its own internodes (`n = clamp(round(a · budget^e))`, so bigger
//! substructures get longer, more finely divided chains) and hands the rest
//! to its lateral chains (monopodial forms) or its fork children
//! (dichotomous form) in proportion to their vigour; a lateral that would get
//! less than the level's minimum is not grown and its site stays bare. The
//! total therefore equals the requested size exactly.
//!
//! Geometry is decided top-down: a lateral's length is its parent's length
//! times the level's ratio times the crown profile at its site, so the
//! silhouette of a species does not depend on the size, only the fineness
//! of its branching does.

use std::f32::consts::{PI, TAU};

use glam::{Quat, Vec3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use treemorph_tree::{BranchingPattern, GroundTruthGroup, Node, NodeId};

use crate::species::{Form, Level, Phyllotaxis, RootForm, Species};

/// Largest turn of a chain between two consecutive internodes. Continuations
/// stay well under the 15° that the analysis allows for a continuation.
pub(crate) const MAX_TURN_DEG: f32 = 9.0;

/// Smallest and largest branching angle of a lateral, degrees: the analysis
/// expects laterals clearly off the continuation.
pub(crate) const LATERAL_ANGLE_DEG: (f32, f32) = (32.0, 72.0);

/// Exponent of the dichotomous chain length in its budget:
/// `length = c · budget^γ`, so a fork child holding half the budget is
/// `2^-γ ≈ 0.79` as long as its parent.
const FORK_LENGTH_EXPONENT: f32 = 1.0 / 3.0;

/// Lateral budgets are proportional to `vigour^BUDGET_EXPONENT`: a longer
/// lateral carries disproportionately more branching.
const BUDGET_EXPONENT: f32 = 1.5;

/// One chain as grown.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Chain {
    /// Hybrid order of the chain.
    pub order: u32,
    /// First entry in [`Grown::chain_nodes`].
    pub start: u32,
    /// Number of nodes (= own branches).
    pub len: u32,
    /// Number of the chain's nodes up to and including the last one that
    /// carries children (laterals or a fork); 0 when the chain carries none.
    pub last_site: u32,
}

/// The grown skeleton with its ground truth, before radii and leaves.
#[derive(Debug, Default)]
pub(crate) struct Grown {
    pub nodes: Vec<Node>,
    pub orders: Vec<u32>,
    pub groups: Vec<GroundTruthGroup>,
    pub chains: Vec<Chain>,
    /// The nodes of every chain, chain after chain, base to tip.
    pub chain_nodes: Vec<NodeId>,
    /// Tree height the growth aimed at, metres.
    pub height: f32,
}

/// A chain waiting to be grown.
#[derive(Clone, Copy, Debug)]
struct Pending {
    /// Node the chain grows from.
    attach: NodeId,
    order: u32,
    budget: u32,
    length: f32,
    /// Direction of the first internode (exact: it defines the branching
    /// angle).
    dir: Vec3,
    /// Azimuth reference, perpendicular to `dir`.
    normal: Vec3,
    /// Ground-truth group and member index to fill with the first node.
    group: u32,
    member: u32,
    /// Dichotomous form: azimuth of this chain's fork relative to `normal`.
    fork_phase: f32,
}

/// Which reference an azimuth is measured from.
#[derive(Clone, Copy, Debug, PartialEq)]
enum AzimuthFrame {
    /// The chain's parallel-transported normal (spiral, decussate, whorled).
    Transported,
    /// The vertical projected onto the plane normal to the chain (left/right
    /// arrangements), falling back to the transported normal on vertical
    /// chains.
    Up,
}

#[derive(Clone, Copy, Debug)]
struct Member {
    azimuth: f32,
    frame: AzimuthFrame,
    angle: f32,
    /// Length weight (profile × vigour).
    weight: f32,
}

#[derive(Clone, Copy, Debug)]
struct Site {
    /// Internode (1-based) whose end node carries the group.
    at: u32,
    /// Range in `members`.
    start: u32,
    len: u32,
}

/// Fraction of the species' full height reached at `size` branches: small
/// sizes are saplings, the full height is reached around 250,000 branches.
pub(crate) fn height_factor(size: u32) -> f32 {
    (0.18 + 0.22 * (size.max(1) as f32 / 50.0).log10()).clamp(0.18, 1.0)
}

struct Grower<'a> {
    sp: &'a Species,
    rng: &'a mut ChaCha8Rng,
    spread: f32,
    height: f32,
    fork_c: f32,
    out: Grown,
    stack: Vec<Pending>,
    sites: Vec<Site>,
    members: Vec<Member>,
    budgets: Vec<u32>,
    weights: Vec<f32>,
}

/// Grows the skeleton of `size` branches.
/// Shortest step, in metres, between the nodes of a spread whorl.
const MIN_SPREAD_STEP: f32 = 0.002;

pub(crate) fn grow(sp: &Species, size: u32, spread: f32, rng: &mut ChaCha8Rng) -> Grown {
    let height = sp.height * height_factor(size);
    let fork_c = match sp.root {
        RootForm::Trunk { length } => height * length / (size as f32).powf(FORK_LENGTH_EXPONENT),
        RootForm::Stems { .. } => 0.0,
    };
    let mut g = Grower {
        sp,
        rng,
        spread,
        height,
        fork_c,
        out: Grown {
            height,
            ..Grown::default()
        },
        stack: Vec::new(),
        sites: Vec::new(),
        members: Vec::new(),
        budgets: Vec::new(),
        weights: Vec::new(),
    };
    let n = size as usize + 1;
    g.out.nodes.reserve(n);
    g.out.orders.reserve(n);
    g.out.chain_nodes.reserve(n);
    g.out.nodes.push(Node {
        position: Vec3::ZERO,
        radius: 1.0,
        parent: None,
    });
    g.out.orders.push(1);
    g.plant(size);
    while let Some(p) = g.stack.pop() {
        g.grow_chain(p);
    }
    g.out
}

impl Grower<'_> {
    fn jitter(&mut self, amount: f32) -> f32 {
        amount * (self.rng.random::<f32>() * 2.0 - 1.0)
    }

    /// The root group: one trunk, or several stems.
    fn plant(&mut self, size: u32) {
        match self.sp.root {
            RootForm::Trunk { length } => {
                let tilt = self.rng.random_range(0.0..2.5f32).to_radians();
                let az = self.rng.random_range(0.0..TAU);
                let side = Vec3::new(az.cos(), 0.0, az.sin());
                let dir = Vec3::Y * tilt.cos() + side * tilt.sin();
                let length = match self.sp.form {
                    Form::Dichotomous { .. } => {
                        self.fork_c * (size as f32).powf(FORK_LENGTH_EXPONENT)
                    }
                    Form::Monopodial => self.height * length,
                };
                self.out.groups.push(GroundTruthGroup {
                    chains: vec![0],
                    pattern: BranchingPattern::Alternate,
                });
                let normal = transport(Vec3::new(-az.sin(), 0.0, az.cos()), dir);
                self.stack.push(Pending {
                    attach: 0,
                    order: 1,
                    budget: size,
                    length,
                    dir,
                    normal,
                    group: 0,
                    member: 0,
                    fork_phase: self.rng.random_range(0.0..TAU),
                });
            }
            RootForm::Stems {
                min,
                max,
                tilt,
                length,
            } => {
                // More stems on bigger shrubs, but each stem keeps a
                // budget large enough to carry laterals.
                let by_size = ((size as f32 / 50.0).log10() * 1.5).floor() as u32;
                let level = self.sp.level(1);
                let affordable = size / (level.n_min + 3 * level.min_child).max(1);
                let hi = (min + by_size)
                    .min(max)
                    .min(affordable)
                    .max(min.min(affordable));
                let lo = min.min(hi).max(1);
                let k = self.rng.random_range(lo..=hi.max(lo));
                // One tilt for every stem: the root is a symmetric fork.
                let tilt = self.rng.random_range(tilt.0..=tilt.1).to_radians();
                let phase = self.rng.random_range(0.0..TAU);
                self.weights.clear();
                for _ in 0..k {
                    let w = 1.0 + self.jitter(0.15);
                    self.weights.push(w);
                }
                let weights = std::mem::take(&mut self.weights);
                let min_budget = (size / k).min(level.n_min);
                allocate(size, min_budget, &weights, &mut self.budgets);
                let group = self.out.groups.len() as u32;
                self.out.groups.push(GroundTruthGroup {
                    chains: vec![0; k as usize],
                    pattern: match k {
                        1 => BranchingPattern::Alternate,
                        2 => BranchingPattern::Opposite,
                        _ => BranchingPattern::Whorled,
                    },
                });
                for j in (0..k).rev() {
                    let az = phase + j as f32 * TAU / k as f32 + self.jitter(8f32.to_radians());
                    let side = Vec3::new(az.cos(), 0.0, az.sin());
                    let dir = Vec3::Y * tilt.cos() + side * tilt.sin();
                    let normal = side * tilt.cos() - Vec3::Y * tilt.sin();
                    let w = weights[j as usize];
                    self.stack.push(Pending {
                        attach: 0,
                        order: 1,
                        budget: self.budgets[j as usize],
                        length: self.height * length / tilt.cos() * w.powf(0.3),
                        dir,
                        normal,
                        group,
                        member: j,
                        fork_phase: 0.0,
                    });
                }
                self.weights = weights;
            }
        }
    }

    fn push_node(&mut self, position: Vec3, parent: NodeId, order: u32) -> NodeId {
        let id = self.out.nodes.len() as NodeId;
        self.out.nodes.push(Node {
            position,
            radius: 1.0,
            parent: Some(parent),
        });
        self.out.orders.push(order);
        self.out.chain_nodes.push(id);
        id
    }

    /// Lays out the lateral sites of a monopodial chain and settles its own
    /// internode count so that own + laterals = budget.
    fn plan_monopodial(&mut self, p: &Pending, level: &Level) -> u32 {
        let mut n = internodes(level, p.budget);
        // A small budget that cannot feed a lateral at every site gets a
        // shorter chain with fewer, still evenly spread, sites rather than
        // bare stretches (a sapling conifer keeps whorls up to its top).
        loop {
            self.place_sites(n, p.budget, level);
            if n <= 2 || p.budget >= n + self.spread_nodes() + self.members_needed(level) {
                break;
            }
            n -= (n / 8).max(1);
        }
        // Then drop the weakest groups until every lateral gets its minimum.
        loop {
            let members: u32 = self.sites.iter().map(|s| s.len).sum();
            let extra = self.spread_nodes();
            if self.sites.is_empty() || p.budget >= n + extra + members * level.min_child {
                break;
            }
            let weakest = (0..self.sites.len())
                .min_by(|&a, &b| {
                    self.site_weight(a)
                        .total_cmp(&self.site_weight(b))
                        .then(b.cmp(&a))
                })
                .expect("sites is not empty");
            self.sites.remove(weakest);
        }
        if self.sites.is_empty() {
            n = p.budget;
        } else {
            let rest = p.budget - n - self.spread_nodes();
            self.weights.clear();
            for s in &self.sites {
                for m in &self.members[s.start as usize..(s.start + s.len) as usize] {
                    self.weights.push(m.weight.powf(BUDGET_EXPONENT));
                }
            }
            allocate(rest, level.min_child, &self.weights, &mut self.budgets);
        }
        n
    }

    /// Chooses the lateral sites of a chain of `n` internodes.
    fn place_sites(&mut self, n: u32, budget: u32, level: &Level) {
        self.sites.clear();
        self.members.clear();
        let mut phase = self.rng.random_range(0.0..TAU);
        let mut k = 0;
        for i in 1..n {
            let s = i as f32 / n as f32;
            if s < level.bare || self.rng.random::<f32>() < level.skip {
                continue;
            }
            self.add_site(i, s, level, &mut phase, k);
            k += 1;
        }
        if self.sites.is_empty() && n >= 2 && budget >= n + level.min_child {
            // A chain that can afford a lateral gets at least one, so that
            // even the smallest trees branch.
            let i = ((level.bare * n as f32).ceil() as u32).clamp(1, n - 1);
            self.add_site(i, i as f32 / n as f32, level, &mut phase, 0);
        }
    }

    /// Budget the current sites need at the least.
    fn members_needed(&self, level: &Level) -> u32 {
        self.sites.iter().map(|s| s.len).sum::<u32>() * level.min_child
    }

    /// Extra nodes inserted on the parent chain when group members are
    /// spread along it.
    fn spread_nodes(&self) -> u32 {
        if self.spread > 0.0 {
            self.sites.iter().map(|s| s.len - 1).sum()
        } else {
            0
        }
    }

    fn site_weight(&self, i: usize) -> f32 {
        let s = self.sites[i];
        self.members[s.start as usize..(s.start + s.len) as usize]
            .iter()
            .map(|m| m.weight)
            .sum()
    }

    fn add_site(&mut self, at: u32, s: f32, level: &Level, phase: &mut f32, k: u32) {
        let u = ((s - level.bare) / (1.0 - level.bare).max(1e-3)).clamp(0.0, 1.0);
        let w = level.profile.eval(u);
        let start = self.members.len() as u32;
        let deg = f32::to_radians;
        let push = |g: &mut Self, azimuth: f32, frame: AzimuthFrame| {
            let vigor = 1.0 + g.jitter(level.vigor);
            let angle = (level.angle.0 + g.jitter(level.angle.1))
                .clamp(LATERAL_ANGLE_DEG.0, LATERAL_ANGLE_DEG.1)
                .to_radians();
            g.members.push(Member {
                azimuth,
                frame,
                angle,
                weight: (w * vigor).max(0.05),
            });
        };
        match level.phyllotaxis {
            Phyllotaxis::Spiral => {
                *phase += deg(137.5) + self.jitter(deg(12.0));
                push(self, *phase, AzimuthFrame::Transported);
            }
            Phyllotaxis::Distichous => {
                let side = if k.is_multiple_of(2) {
                    PI / 2.0
                } else {
                    -PI / 2.0
                };
                let az = side + self.jitter(deg(15.0));
                push(self, az, AzimuthFrame::Up);
            }
            Phyllotaxis::Pendant => {
                let side = if k.is_multiple_of(2) { 1.0 } else { -1.0 };
                let az = side * (deg(115.0) + self.jitter(deg(12.0)));
                push(self, az, AzimuthFrame::Up);
            }
            Phyllotaxis::Decussate => {
                // Successive pairs cross at about 90°; the play keeps a
                // straight leader from building a "+"-shaped crown.
                if k > 0 {
                    *phase += deg(90.0) + self.jitter(deg(30.0));
                }
                let a = *phase + self.jitter(deg(5.0));
                let b = *phase + PI + self.jitter(deg(5.0));
                push(self, a, AzimuthFrame::Transported);
                push(self, b, AzimuthFrame::Transported);
            }
            Phyllotaxis::Whorled { min, max } => {
                let g = self.rng.random_range(min..=max);
                *phase += PI / g as f32 + self.jitter(deg(15.0));
                for j in 0..g {
                    let az = *phase + j as f32 * TAU / g as f32 + self.jitter(deg(6.0));
                    push(self, az, AzimuthFrame::Transported);
                }
            }
        }
        let len = self.members.len() as u32 - start;
        self.sites.push(Site { at, start, len });
    }

    /// Random bending of a chain between two internodes: gravitropism,
    /// phototropism away from the trunk axis, wobble, ground avoidance;
    /// never more than [`MAX_TURN_DEG`].
    fn bend(&mut self, d: Vec3, pos: Vec3, s: f32, level: &Level) -> Vec3 {
        let grav = level.grav.0 + level.grav.1 * s;
        let out = Vec3::new(pos.x, 0.0, pos.z);
        let out = if out.length_squared() > 1e-6 {
            out.normalize()
        } else {
            Vec3::ZERO
        };
        let wobble = Vec3::new(self.jitter(1.0), self.jitter(1.0), self.jitter(1.0)) * level.wobble;
        let mut delta = Vec3::Y * grav + out * level.photo + wobble;
        if pos.y < 0.05 * self.height + 0.1 && d.y < 0.2 {
            delta += Vec3::Y * 0.5;
        }
        limit_turn(d, (d + delta).normalize_or(d), MAX_TURN_DEG.to_radians())
    }

    fn grow_chain(&mut self, mut p: Pending) {
        let level = *self.sp.level(p.order);
        let start_pos = self.out.nodes[p.attach as usize].position;
        if level.hang {
            // Pendulous chains stop short of the ground.
            let room = (start_pos.y - 0.06 * self.height).max(0.1);
            p.length = p.length.min(0.9 * room);
        }
        let (n, fork) = match self.sp.form {
            Form::Monopodial => (self.plan_monopodial(&p, &level), 0),
            Form::Dichotomous { three_way, .. } => {
                self.sites.clear();
                self.members.clear();
                let n0 = internodes(&level, p.budget);
                let min = level.min_child;
                let three = self.rng.random::<f32>() < three_way;
                let k = if p.budget >= n0 + 3 * min && p.order == 1 && three {
                    3
                } else if p.budget >= n0 + 2 * min {
                    2
                } else {
                    0
                };
                if k == 0 {
                    (p.budget, 0)
                } else {
                    self.weights.clear();
                    for _ in 0..k {
                        let w = 1.0 + self.jitter(0.05);
                        self.weights.push(w);
                    }
                    allocate(p.budget - n0, min, &self.weights, &mut self.budgets);
                    (n0, k)
                }
            }
        };
        let length = p.length.max(0.012 * n as f32);
        let seg = length / n as f32;
        let mut pos = start_pos;
        let mut d = p.dir;
        let mut normal = p.normal;
        let mut prev = p.attach;
        let start = self.out.chain_nodes.len() as u32;
        let mut next_dir: Option<Vec3> = None;
        let mut consumed = 0.0;
        let mut last_site = 0;
        let mut site_i = 0;
        let mut budget_i = 0;
        for i in 1..=n {
            if i > 1 {
                d = match next_dir.take() {
                    Some(d) => d,
                    None => self.bend(d, pos, (i - 1) as f32 / n as f32, &level),
                };
                normal = transport(normal, d);
            }
            let len = (seg * self.rng.random_range(0.85..1.15f32) - consumed).max(0.25 * seg);
            consumed = 0.0;
            pos += d * len;
            let id = self.push_node(pos, prev, p.order);
            if i == 1 {
                self.out.groups[p.group as usize].chains[p.member as usize] = id;
            }
            prev = id;
            if site_i < self.sites.len() && self.sites[site_i].at == i {
                let site = self.sites[site_i];
                site_i += 1;
                let group = self.out.groups.len() as u32;
                self.out.groups.push(GroundTruthGroup {
                    chains: vec![0; site.len as usize],
                    pattern: match site.len {
                        1 => BranchingPattern::Alternate,
                        2 => BranchingPattern::Opposite,
                        _ => BranchingPattern::Whorled,
                    },
                });
                let spread = self.spread > 0.0 && site.len >= 2;
                let mut attach = id;
                let mut d_in = d;
                for j in 0..site.len {
                    if j > 0 && spread {
                        // Spread the group along the next internode.
                        let dn = match next_dir {
                            Some(dn) => dn,
                            None => {
                                let dn = self.bend(d, pos, i as f32 / n as f32, &level);
                                next_dir = Some(dn);
                                dn
                            }
                        };
                        // At least 2 mm: a tiny spread would otherwise
                        // make sub-millimetre branches, which no mesh
                        // resolves and analysis would treat as noise.
                        let step = (self.spread * seg / site.len as f32).max(MIN_SPREAD_STEP);
                        pos += dn * step;
                        consumed += step;
                        attach = self.push_node(pos, prev, p.order);
                        prev = attach;
                        d_in = dn;
                    }
                    let m = self.members[(site.start + j) as usize];
                    let reference = match m.frame {
                        AzimuthFrame::Transported => transport(normal, d_in),
                        AzimuthFrame::Up => up_frame(d_in, transport(normal, d_in)),
                    };
                    let (dir, u) = lateral(d_in, reference, m.azimuth, m.angle);
                    let child_normal = (u * m.angle.cos() - d_in * m.angle.sin()).normalize_or(u);
                    let budget = self.budgets[budget_i];
                    budget_i += 1;
                    self.stack.push(Pending {
                        attach,
                        order: p.order + 1,
                        budget,
                        length: length * level.ratio * m.weight,
                        dir,
                        normal: child_normal,
                        group,
                        member: j,
                        fork_phase: 0.0,
                    });
                }
                last_site = self.out.chain_nodes.len() as u32 - start;
            }
        }
        if fork > 0 {
            self.fork(&p, prev, d, normal, fork);
            last_site = n;
        }
        self.out.chains.push(Chain {
            order: p.order,
            start,
            len: self.out.chain_nodes.len() as u32 - start,
            last_site,
        });
    }

    /// Ends a chain in a symmetric fork of `k` children at `node`.
    fn fork(&mut self, p: &Pending, node: NodeId, d: Vec3, normal: Vec3, k: u32) {
        let Form::Dichotomous { angle, .. } = self.sp.form else {
            return;
        };
        // One angle for every child: the fork is symmetric by construction.
        let alpha = self.rng.random_range(angle.0..=angle.1).to_radians();
        let group = self.out.groups.len() as u32;
        self.out.groups.push(GroundTruthGroup {
            chains: vec![0; k as usize],
            pattern: if k == 2 {
                BranchingPattern::Opposite
            } else {
                BranchingPattern::Whorled
            },
        });
        for j in 0..k {
            let az = p.fork_phase + j as f32 * TAU / k as f32;
            let (dir, u) = lateral(d, normal, az, alpha);
            // The child's fork plane is turned 90° from this one
            // (decussate forks), with a little play.
            let child_normal = d.cross(u).normalize_or(normal);
            let budget = self.budgets[j as usize];
            let fork_phase = self.jitter(20f32.to_radians());
            self.stack.push(Pending {
                attach: node,
                order: p.order + 1,
                budget,
                length: self.fork_c * (budget as f32).powf(FORK_LENGTH_EXPONENT),
                dir,
                normal: child_normal,
                group,
                member: j,
                fork_phase,
            });
        }
    }
}

/// Own internodes of a chain with `budget` branches.
fn internodes(level: &Level, budget: u32) -> u32 {
    let n = (level.a * (budget as f32).powf(level.e)).round() as u32;
    n.clamp(level.n_min, level.n_max).min(budget).max(1)
}

/// Splits `total` into integer shares of at least `min`, the rest in
/// proportion to `weights` by largest remainder (ties to the lower index).
/// Callers guarantee `total >= min * weights.len()`.
pub(crate) fn allocate(total: u32, min: u32, weights: &[f32], out: &mut Vec<u32>) {
    out.clear();
    if weights.is_empty() {
        return;
    }
    let base = min.min(total / weights.len() as u32);
    let pool = total - base * weights.len() as u32;
    let sum: f32 = weights.iter().sum();
    let mut given = 0;
    let mut rema: Vec<(f32, usize)> = Vec::with_capacity(weights.len());
    for (i, &w) in weights.iter().enumerate() {
        let share = if sum > 0.0 {
            pool as f32 * w / sum
        } else {
            pool as f32 / weights.len() as f32
        };
        let whole = (share.floor() as u32).min(pool - given);
        given += whole;
        out.push(base + whole);
        rema.push((share - whole as f32, i));
    }
    rema.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut left = pool - given;
    let mut k = 0;
    while left > 0 {
        out[rema[k % rema.len()].1] += 1;
        left -= 1;
        k += 1;
    }
}

/// Re-projects `n` onto the plane normal to `d` (parallel transport of the
/// azimuth reference along a chain).
pub(crate) fn transport(n: Vec3, d: Vec3) -> Vec3 {
    (n - d * n.dot(d))
        .try_normalize()
        .unwrap_or_else(|| d.any_orthonormal_vector())
}

/// The vertical projected onto the plane normal to `d`, or `fallback` when
/// `d` is (nearly) vertical.
pub(crate) fn up_frame(d: Vec3, fallback: Vec3) -> Vec3 {
    let v = Vec3::Y - d * d.y;
    if v.length_squared() > 0.01 {
        v.normalize()
    } else {
        fallback
    }
}

/// Direction at `angle` from `d`, towards azimuth `azimuth` measured from
/// `reference` (⟂ `d`); also returns the radial unit vector of that azimuth.
pub(crate) fn lateral(d: Vec3, reference: Vec3, azimuth: f32, angle: f32) -> (Vec3, Vec3) {
    let b = d.cross(reference);
    let u = reference * azimuth.cos() + b * azimuth.sin();
    ((d * angle.cos() + u * angle.sin()).normalize(), u)
}

/// Turns `d` towards `target` by at most `max` radians.
fn limit_turn(d: Vec3, target: Vec3, max: f32) -> Vec3 {
    let angle = d.dot(target).clamp(-1.0, 1.0).acos();
    if angle <= max {
        return target;
    }
    let axis = d.cross(target);
    if axis.length_squared() < 1e-12 {
        return d;
    }
    (Quat::from_axis_angle(axis.normalize(), max) * d).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn allocate_is_exact_and_respects_the_minimum() {
        let mut out = Vec::new();
        allocate(100, 3, &[1.0, 2.0, 0.5, 0.01], &mut out);
        assert_eq!(out.iter().sum::<u32>(), 100);
        assert!(out.iter().all(|&b| b >= 3), "{out:?}");
        assert!(out[1] > out[0] && out[0] > out[2], "{out:?}");
        allocate(9, 3, &[1.0, 1.0, 1.0], &mut out);
        assert_eq!(out, vec![3, 3, 3]);
        allocate(10, 3, &[0.0, 0.0], &mut out);
        assert_eq!(out.iter().sum::<u32>(), 10);
    }

    #[test]
    fn height_grows_with_size_and_saturates() {
        assert!(height_factor(50) < height_factor(5_000));
        assert!(height_factor(5_000) < height_factor(100_000));
        assert_eq!(height_factor(10_000_000), 1.0);
        assert!((height_factor(50) - 0.18).abs() < 1e-6);
    }

    #[test]
    fn limit_turn_caps_the_angle() {
        let d = Vec3::Y;
        let t = Vec3::X;
        let r = limit_turn(d, t, 0.1);
        assert!((r.angle_between(d) - 0.1).abs() < 1e-4);
        assert_eq!(limit_turn(d, d, 0.1), d);
    }

    #[test]
    fn lateral_has_the_requested_angle() {
        let d = Vec3::new(0.3, 1.0, 0.1).normalize();
        let n = transport(Vec3::X, d);
        for az in [0.0, 1.0, 2.5, 4.0] {
            let (dir, u) = lateral(d, n, az, 0.8);
            assert!((dir.angle_between(d) - 0.8).abs() < 1e-4);
            assert!(u.dot(d).abs() < 1e-5);
        }
    }
}
