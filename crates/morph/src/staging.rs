//! Builds a plan's [`Schedule`] (see `schedule` for what it means): the
//! phases, each reshaping chain's delay, and the fronts of growing and
//! wilting subtrees.

use crate::correspondence::{LeafMatch, Operation};
use crate::morpher::{Morpher, fraction, locate};
use crate::options::{ScheduleKind, ScheduleOptions};
use crate::plan::{ChainPlan, LeafMode, LeafPlan, MorphPlan, Sample, UnionChain};
use crate::schedule::{ChainTiming, Front, GROW, LeafTiming, Schedule, UNFOLD};
use treemorph_tree::timing::{Ease, Pace, RESHAPE, SHED, Window};

/// Paces a staged plan's motion evenly (see `schedule`, *Pacing*); `None`
/// when nothing moves. A motion concentrated beyond what its samples
/// resolve ([`Pace::concentrated`]) is measured again [`Pace::REFINE`]
/// times as finely.
pub(crate) fn pace(plan: &MorphPlan, easing: f32) -> Option<Pace> {
    match coarse_pace(plan, easing) {
        (_, true) => refined_pace(plan, easing),
        (coarse, false) => coarse,
    }
}

/// [`pace`] without the refinement, and whether the motion is
/// concentrated enough for [`pace`] to refine it ([`refined_pace`]):
/// cheaper, for a plan that untangling may still change.
pub(crate) fn coarse_pace(plan: &MorphPlan, easing: f32) -> (Option<Pace>, bool) {
    let moved = moves(plan, PACE_SAMPLES);
    (Pace::of_moves(&moved, easing), Pace::concentrated(&moved))
}

/// [`pace`] of a plan whose motion [`coarse_pace`] found concentrated.
pub(crate) fn refined_pace(plan: &MorphPlan, easing: f32) -> Option<Pace> {
    Pace::of_moves(&moves(plan, PACE_SAMPLES * Pace::REFINE), easing)
}

/// How far `plan`'s motion moves between its `samples` even instants
/// ([`Pace::moves`]), measured in one run per core, each on its own
/// morpher (a run's first frame is its predecessor's last), and joined:
/// the same moves as one morpher measuring them in order.
fn moves(plan: &MorphPlan, samples: usize) -> Vec<f32> {
    use rayon::prelude::*;
    let runs = Pace::runs(samples, rayon::current_num_threads());
    runs.into_par_iter()
        .flat_map_iter(|span| {
            let mut morpher = Morpher::new(plan);
            Pace::moves(samples, span, |t, frame| morpher.morph(t, frame))
        })
        .collect()
}

/// Instants at which a staged plan samples its motion to pace it.
const PACE_SAMPLES: usize = 64;

/// Staged: of the union leaves that share a source leaf (a leaf with
/// several partners), the first keeps it and the others grow in as new
/// leaves at their targets; of those that share a target, the first
/// keeps it and the others wilt from their sources. Copies of one leaf
/// would otherwise coincide at t = 0 (t = 1) with different material
/// pairs and z-fight as they blend. Every leaf of both trees still
/// appears at least once.
pub(crate) fn separate_copies(leaves: &mut [LeafMatch]) {
    let size = |side: fn(&LeafMatch) -> Option<u32>| {
        leaves
            .iter()
            .filter_map(side)
            .max()
            .map_or(0, |m| m as usize + 1)
    };
    let mut seen = [
        vec![false; size(|m| m.source)],
        vec![false; size(|m| m.target)],
    ];
    for m in leaves.iter_mut() {
        if let (Some(s), Some(_)) = (m.source, m.target)
            && std::mem::replace(&mut seen[0][s as usize], true)
        {
            m.source = None;
        }
    }
    for m in leaves.iter_mut() {
        if let (Some(_), Some(t)) = (m.source, m.target)
            && std::mem::replace(&mut seen[1][t as usize], true)
        {
            m.target = None;
        }
    }
}

/// What [`schedule`] reads of a plan being built.
pub(crate) struct Timed<'a> {
    pub chain_plans: &'a [ChainPlan],
    pub chains: &'a [UnionChain],
    pub samples: &'a [Sample],
    pub sample_u: &'a [f32],
    pub sample_inv_span: &'a [f32],
    pub leaf_plans: &'a [LeafPlan],
    pub leaf_matches: &'a [LeafMatch],
}

/// The schedule `options` ask for.
pub(crate) fn schedule(options: &ScheduleOptions, plan: &Timed) -> Schedule {
    match options.kind {
        ScheduleKind::Linear => Schedule::linear(plan.chain_plans.len(), plan.leaf_plans.len()),
        ScheduleKind::Staged => staged(options, plan),
    }
}

fn staged(options: &ScheduleOptions, plan: &Timed) -> Schedule {
    let reshape = reshape_phase(plan);
    let delays = delays(plan);
    let fronts = fronts(plan);
    let mut chains = plan
        .chain_plans
        .iter()
        .enumerate()
        .map(|(i, c)| match c.operation {
            Operation::Grow => ChainTiming {
                window: Window::new(GROW[0], GROW[1]),
                front: Some(fronts.chain(i, true)),
            },
            Operation::Wilt => ChainTiming {
                window: Window::new(SHED[0], SHED[1]),
                front: Some(fronts.chain(i, false)),
            },
            _ => ChainTiming {
                window: Window::staggered(reshape, options.stagger, delays[i]),
                front: None,
            },
        })
        .collect::<Vec<_>>();
    clear_of_hosts(plan, &fronts, &mut chains);
    let leaves = plan
        .leaf_plans
        .iter()
        .zip(plan.leaf_matches)
        .map(|(l, m)| leaf_timing(plan, &chains, &fronts, &delays, options, l, m))
        .collect();
    Schedule {
        ease: Ease::new(options.easing),
        overall: Window::new(reshape[0], reshape[1]),
        chains,
        leaves,
        pace: None,
    }
}

/// The shortest window, as a share of `t`, a tip-first subtree gets when
/// its host's reshape squeezes it.
const TIP_FIRST_WINDOW: f32 = 0.2;

/// Keeps tip-first subtrees off their host's reshape (see `schedule`,
/// *Phases*): a wilting subtree has retracted when the chain it hangs on
/// starts to reshape, and a growing one starts once that chain has
/// reshaped, each within its phase and at least [`TIP_FIRST_WINDOW`]
/// long. Every chain of a subtree keeps the one clock of its front.
fn clear_of_hosts(plan: &Timed, fronts: &Fronts, chains: &mut [ChainTiming]) {
    for i in 0..chains.len() {
        let op = plan.chain_plans[i].operation;
        if !matches!(op, Operation::Grow | Operation::Wilt) {
            continue;
        }
        let Some(host) = plan.chains[fronts.root[i] as usize].parent else {
            continue;
        };
        let host = chains[host as usize].window;
        chains[i].window = if op == Operation::Wilt {
            let end = host.start().clamp(SHED[0] + TIP_FIRST_WINDOW, SHED[1]);
            Window::new(SHED[0], end)
        } else {
            let start = host.end().clamp(GROW[0], GROW[1] - TIP_FIRST_WINDOW);
            Window::new(start, GROW[1])
        };
    }
}

/// The reshape phase for one plan: it takes the time of an empty shed or
/// growth phase.
fn reshape_phase(plan: &Timed) -> [f32; 2] {
    let ops = |op| plan.chain_plans.iter().any(|c| c.operation == op);
    let sheds = ops(Operation::Wilt) || plan.leaf_matches.iter().any(|m| m.target.is_none());
    let grows = ops(Operation::Grow) || plan.leaf_matches.iter().any(|m| m.source.is_none());
    [
        if sheds { RESHAPE[0] } else { 0.0 },
        if grows { RESHAPE[1] } else { 1.0 },
    ]
}

/// Per union chain, its delay `d ∈ [0, 1]` within its phase:
/// `(level + mean growth location) / levels`.
fn delays(plan: &Timed) -> Vec<f32> {
    let levels = plan.chains.iter().map(|c| c.level).max().unwrap_or(0) + 1;
    plan.chains
        .iter()
        .zip(plan.chain_plans)
        .map(|(c, cp)| {
            let p = if c.parent.is_some() {
                0.5 * (cp.p[0] + cp.p[1])
            } else {
                0.0
            };
            (c.level as f32 + p.clamp(0.0, 1.0)) / levels as f32
        })
        .collect()
}

/// The fronts of tip-first chains: per union chain, metres from its
/// subtree's junction to its base (`base`), and per subtree root the
/// longest base-to-tip path (`longest`). Growing subtrees measure target
/// shapes, wilting ones source shapes.
struct Fronts {
    base: Vec<f32>,
    root: Vec<u32>,
    longest: Vec<f32>,
}

impl Fronts {
    fn chain(&self, i: usize, grows: bool) -> Front {
        Front {
            base: self.base[i],
            total: (1.0 + UNFOLD) * self.longest[self.root[i] as usize],
            grows,
        }
    }

    /// The front's position, on its clock, where it reaches union
    /// parameter `param` of chain `i`, and the clock's share of an unfold.
    fn leaf(&self, plan: &Timed, i: usize, side: usize, param: f32) -> (f32, f32) {
        let longest = self.longest[self.root[i] as usize];
        if longest <= 0.0 {
            return (0.0, 1.0);
        }
        let total = (1.0 + UNFOLD) * longest;
        let at = (self.base[i] + arc_length(plan, i, side, param)) / total;
        (at, total / (UNFOLD * longest))
    }
}

fn fronts(plan: &Timed) -> Fronts {
    let n = plan.chain_plans.len();
    let mut fronts = Fronts {
        base: vec![0.0; n],
        root: (0..n as u32).collect(),
        longest: vec![0.0; n],
    };
    // Parents come first, so one pass sees every parent's base.
    for (i, c) in plan.chain_plans.iter().enumerate() {
        let side = match c.operation {
            Operation::Grow => 1,
            Operation::Wilt => 0,
            _ => continue,
        };
        let parent = c.parent as usize;
        if plan.chains[i].parent.is_some() && plan.chain_plans[parent].operation == c.operation {
            fronts.base[i] = fronts.base[parent] + arc_length(plan, parent, side, c.p[side]);
            fronts.root[i] = fronts.root[parent];
        }
        let tip = fronts.base[i] + arc_length(plan, i, side, 1.0);
        let root = fronts.root[i] as usize;
        fronts.longest[root] = fronts.longest[root].max(tip);
    }
    fronts
}

/// Metres along union chain `i`'s shape on `side` from its base to union
/// parameter `param`.
fn arc_length(plan: &Timed, i: usize, side: usize, param: f32) -> f32 {
    let c = &plan.chain_plans[i];
    let r = c.first as usize..(c.first + c.len) as usize;
    let u = &plan.sample_u[r.clone()];
    let samples = &plan.samples[r.clone()];
    let j = locate(u, param);
    let before: f32 = samples[..j].iter().map(|s| s.len[side]).sum();
    before + fraction(u, &plan.sample_inv_span[r], j, param) * samples[j].len[side]
}

/// When leaf `l` (matched as `m`) moves: with its host's front on a
/// tip-first chain, in the growth or shed phase when it grows or wilts on
/// a reshaping chain, else with its host.
#[allow(clippy::too_many_arguments)]
fn leaf_timing(
    plan: &Timed,
    chains: &[ChainTiming],
    fronts: &Fronts,
    delays: &[f32],
    options: &ScheduleOptions,
    l: &LeafPlan,
    m: &LeafMatch,
) -> LeafTiming {
    let host = l.host as usize;
    let plain = |window| LeafTiming {
        window,
        at: 0.0,
        inv_unfold: 1.0,
        folds: false,
    };
    if l.mode == LeafMode::Linear {
        return plain(Window::FULL);
    }
    let op = plan.chain_plans[host].operation;
    match (op, m.source, m.target) {
        (Operation::Grow | Operation::Wilt, ..) => {
            let grows = op == Operation::Grow;
            let side = usize::from(grows);
            let (at, inv_unfold) = fronts.leaf(plan, host, side, l.param[side]);
            LeafTiming {
                window: chains[host].window,
                at,
                inv_unfold,
                folds: !grows,
            }
        }
        (_, None, _) => {
            let window = Window::staggered(GROW, options.stagger, delays[host]);
            plain(after(window, chains[host].window))
        }
        (_, _, None) => {
            let window = Window::staggered(SHED, options.stagger, 1.0 - delays[host]);
            plain(before(window, chains[host].window))
        }
        _ => plain(chains[host].window),
    }
}

/// Shortest window a leaf unfolds or folds in when its host's reshape
/// squeezes it.
const LEAF_WINDOW: f32 = 0.1;

/// `window`, starting no earlier than `host` ends: a leaf unfolds on the
/// bark its twig will have, not inside a branch still thinning.
pub(crate) fn after(window: Window, host: Window) -> Window {
    let start = window.start().max(host.end()).min(1.0 - LEAF_WINDOW);
    Window::new(start, window.end().max(start + LEAF_WINDOW).min(1.0))
}

/// `window`, ending no later than `host` starts: a leaf folds on the bark
/// its twig had.
pub(crate) fn before(window: Window, host: Window) -> Window {
    let end = window.end().min(host.start()).max(LEAF_WINDOW);
    Window::new(window.start().min(end - LEAF_WINDOW).max(0.0), end)
}
