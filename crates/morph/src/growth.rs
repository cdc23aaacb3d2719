//! [`GrowthMeter`]: whether growing chains grow from the tip, measured on
//! the frames' node positions.
//!
//! A chain that grows tip-first has its segments at full length from its
//! junction up to the one being grown, and nothing beyond it; a chain that
//! scales about its junction has every segment part grown at once. The
//! full lengths are the input chain's (the target's for a growing chain,
//! the source's for a wilting one), which the plan reproduces at the
//! ends.

use treemorph_tree::Frame;

use crate::correspondence::Operation;
use crate::plan::MorphPlan;

/// Per growing or wilting union chain: its full segment lengths, and its
/// length in the previous measured frame.
#[derive(Debug)]
pub(crate) struct GrowthMeter {
    /// `(union chain, grows)` of every growing or wilting chain.
    chains: Vec<(u32, bool)>,
    /// Full segment lengths, `offsets[k]..offsets[k + 1]` for chain `k`.
    full: Vec<f32>,
    offsets: Vec<u32>,
    previous: Vec<f32>,
    has_previous: bool,
    /// Slack of the comparisons, metres.
    tolerance: f32,
}

/// What one frame shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Growth {
    /// Chains with a segment grown beyond one not yet at full length.
    pub out_of_order: u32,
    /// Growing chains shorter, or wilting chains longer, than in the
    /// previous measured frame.
    pub reversals: u32,
}

impl GrowthMeter {
    pub(crate) fn new(plan: &MorphPlan) -> GrowthMeter {
        let mut chains = Vec::new();
        let mut full = Vec::new();
        let mut offsets = vec![0];
        for (i, (c, cp)) in plan.chains().iter().zip(&plan.chain_plans).enumerate() {
            let side = match c.operation {
                Operation::Grow => 1,
                Operation::Wilt => 0,
                _ => continue,
            };
            let samples = &plan.samples[cp.first as usize..(cp.first + cp.len) as usize];
            full.extend(samples[..samples.len() - 1].iter().map(|s| s.len[side]));
            offsets.push(full.len() as u32);
            chains.push((i as u32, side == 1));
        }
        GrowthMeter {
            previous: vec![0.0; chains.len()],
            chains,
            full,
            offsets,
            has_previous: false,
            tolerance: 1e-5 * plan.height(),
        }
    }

    pub(crate) fn reset(&mut self) {
        self.has_previous = false;
    }

    pub(crate) fn measure(&mut self, plan: &MorphPlan, frame: &Frame) -> Growth {
        let mut growth = Growth::default();
        let tol = self.tolerance;
        for (k, &(chain, grows)) in self.chains.iter().enumerate() {
            let nodes = plan.chains()[chain as usize].nodes.clone();
            let pos = &frame.positions[nodes.start as usize..nodes.end as usize];
            let full = &self.full[self.offsets[k] as usize..self.offsets[k + 1] as usize];
            let (mut length, mut open, mut disorder) = (0.0f32, false, false);
            for (w, &l) in pos.windows(2).zip(full) {
                let s = w[0].distance(w[1]);
                length += s;
                disorder |= open && s > tol;
                open |= s < l - tol;
            }
            growth.out_of_order += u32::from(disorder);
            if self.has_previous {
                let before = self.previous[k];
                let reversed = if grows {
                    length < before - tol
                } else {
                    length > before + tol
                };
                growth.reversals += u32::from(reversed);
            }
            self.previous[k] = length;
        }
        self.has_previous = true;
        growth
    }
}
