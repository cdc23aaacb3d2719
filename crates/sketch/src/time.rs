//! Animation time, shared by the plan, the sketcher and the metrics: `t`
//! clamped, and when each chain moves ([`Clocks`]).
//!
//! A sketch reshapes every chain and wilts the pruned ones; nothing grows
//! (a chain's growth toward a wider crown is part of its reshape). Under
//! [`ScheduleKind::Linear`] every chain and every wilt runs on `t` itself.
//! Under [`ScheduleKind::Staged`] (default), as in a staged morph:
//! - **Shed first.** Pruned subtrees wilt (shrink into their junctions,
//!   their leaves with them) in `SHED` = [0, 0.45] of `t`.
//! - **Parents lead.** Chains reshape in [0.1, 1] ([0, 1] when nothing
//!   wilts), each in a window starting `stagger × d` of that phase late
//!   and lasting `1 − stagger` of it, `d = (level + p) / levels` with `p`
//!   where the chain grows along its parent (0 at the parent's junction,
//!   1 at its tip): trunks settle first, twigs near a limb's base before
//!   those near its tip. A child's `d` is never below its parent's.
//! - **Easing.** Each window eases in and out ([`Ease`]), exact at its
//!   ends: t = 0 is the input and t = 1 the sketched tree.
//! - **Pacing.** The staggered, eased windows still leave some stretches
//!   of `t` busier than others (60 frames on a maple: the largest
//!   frame-to-frame move 1.59 × the median one for a heart, 2.47 × for a
//!   crescent, whose pruned branches all wilt early), so the plan samples
//!   its staged motion and paces it evenly, as a staged morph does
//!   ([`Pace`]): 1.08 and 1.23 (linear: 1.04 and 1.81).

use treemorph_tree::timing::{Ease, Pace, RESHAPE, SHED, ScheduleKind, ScheduleOptions, Window};

use crate::plan::SketchPlan;

/// Clamps an animation time into [0, 1]; NaN is 0.
pub(crate) fn clamp_t(t: f32) -> f32 {
    if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) }
}

/// Each chain's and the wilt's eased clock (see the module docs).
#[derive(Clone, Debug)]
pub(crate) struct Clocks {
    ease: Ease,
    /// Per chain: its reshape window.
    chains: Vec<Window>,
    /// The wilting subtrees' window.
    shed: Window,
    /// The reshape phase without stagger: the root's window.
    reshape: Window,
    /// How `t` is paced (`None`: `t` itself).
    pace: Option<Pace>,
}

impl Clocks {
    /// The clocks of `plan`'s chains under `options`.
    pub(crate) fn new(plan: &SketchPlan, options: &ScheduleOptions) -> Clocks {
        let chains = plan.chain_ranges.len();
        if options.kind == ScheduleKind::Linear {
            return Clocks {
                ease: Ease::NONE,
                chains: vec![Window::FULL; chains],
                shed: Window::FULL,
                reshape: Window::FULL,
                pace: None,
            };
        }
        let phase = if plan.wilts.is_empty() {
            [0.0, 1.0]
        } else {
            [RESHAPE[0], 1.0]
        };
        Clocks {
            ease: Ease::new(options.easing),
            chains: delays(plan)
                .into_iter()
                .map(|d| Window::staggered(phase, options.stagger, d))
                .collect(),
            shed: Window::new(SHED[0], SHED[1]),
            reshape: Window::new(phase[0], phase[1]),
            pace: plan.pace.clone(),
        }
    }

    /// The paced `t`.
    pub(crate) fn paced(&self, t: f32) -> f32 {
        self.pace.as_ref().map_or(t, |p| p.at(t))
    }

    /// Chain `c`'s clock at the paced `t`: 0 at rest, 1 reshaped.
    pub(crate) fn chain(&self, c: usize, t: f32) -> f32 {
        self.ease.at(self.chains[c].local(t))
    }

    /// The root's clock at the paced `t`.
    pub(crate) fn root(&self, t: f32) -> f32 {
        self.ease.at(self.reshape.local(t))
    }

    /// How far the pruned subtrees have wilted at the paced `t`: 0
    /// whole, 1 gone.
    pub(crate) fn shed(&self, t: f32) -> f32 {
        self.ease.at(self.shed.local(t))
    }
}

/// Per chain: `d = (level + p) / levels`, parents before children.
fn delays(plan: &SketchPlan) -> Vec<f32> {
    let n = plan.chain_ranges.len();
    let along = arc_fractions(plan);
    let mut level = vec![0u32; n];
    let mut p = vec![0.0f32; n];
    for c in crate::rigid::parents_first(&plan.chain_parent) {
        let c = c as usize;
        if let Some(parent) = plan.chain_parent[c] {
            level[c] = level[parent as usize] + 1;
            let junction = plan.chain_nodes[plan.chain_ranges[c].0 as usize];
            p[c] = along[junction as usize];
        }
    }
    let levels = level.iter().max().map_or(1, |&l| l + 1) as f32;
    level
        .iter()
        .zip(&p)
        .map(|(&l, &p)| (l as f32 + p) / levels)
        .collect()
}

/// Per node: how far along its chain it lies at rest, as a fraction of
/// the chain's arc length (0 at its junction, 1 at its tip).
fn arc_fractions(plan: &SketchPlan) -> Vec<f32> {
    let rest = &plan.rest.positions;
    let mut along = vec![0.0f32; rest.len()];
    for &(a, b) in &plan.chain_ranges {
        let nodes = &plan.chain_nodes[a as usize..b as usize];
        let total: f32 = nodes
            .windows(2)
            .map(|w| rest[w[0] as usize].distance(rest[w[1] as usize]))
            .sum();
        let mut run = 0.0;
        for w in nodes.windows(2) {
            run += rest[w[0] as usize].distance(rest[w[1] as usize]);
            along[w[1] as usize] = if total > 0.0 { run / total } else { 1.0 };
        }
    }
    along
}
