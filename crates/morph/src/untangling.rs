//! Untangling: blends that still pass through other branches are shed and
//! regrown instead.
//!
//! The crossing cost in the matching (`crossing`) and the routing
//! (`routing`) keep sibling limbs apart. What they do not see are the twig
//! clouds of neighbouring limbs: while two limbs reshape, the twigs two or
//! three orders below them sweep through each other (issue 19's preset
//! morphs had 24–50 crossing piece pairs in their worst frame, nearly all
//! of them such twigs, mid-reshape). No turn of one twig clears a cloud
//! that moves with another limb.
//!
//! A tree does not pass one twig through another; it sheds twigs and grows
//! new ones. So a staged plan is played at [`SAMPLES`] even instants of
//! paced time, as a job's frames are (on the first plan's pace in every
//! round: the final pace is only known at the end), the crossings between any two union chains are
//! counted as the output-level meter counts them ([`CrossingMeter`]:
//! capsules that overlap at an inner instant and at neither end), and for
//! each crossing pair the lesser blended chain — the one carrying the
//! smaller subtree, the deeper on a tie — is taken out of the matching:
//! its source side wilts in the shed phase and its target side grows in
//! the growth phase, each with its substructure, both tip-first like any
//! unmatched chain. For a split copy only its target leaves the matching
//! (the source keeps its other partners), for a merge copy only its
//! source. The plan is then matched, built and played again, for at most
//! [`ROUNDS`] rounds (a new partner can cross where the old one did not),
//! and paced once more on its own motion. The plan of the last round is
//! not played again: what its new partners cross, stays.
//!
//! Root chains are never taken out (a trunk that wilts while another grows
//! is not a morph). A pair of which neither chain blends (a growing or
//! wilting chain carried through another by its host's reshape) takes its
//! nearest blended ancestor below the root chains instead, if there is
//! one.
//!
//! # Measured (the five preset pairs at 5,000 branches, 60 frames)
//! Most crossings in a frame: 43 / 40 / 30 / 24 / 50 → 6 / 1 / 1 / 0 / 1
//! (maple → conifer, conifer → willow, willow → eucalyptus,
//! eucalyptus → shrub, shrub → maple); the default morph's CLI run
//! 0.33 s → 0.6 s. The choices:
//! - **65 instants, not 33**: 33 (three rounds, each paced anew) left
//!   6 / 3 / 1 / 1 / 5 on the five pairs, 65 leaves 6 / 1 / 1 / 0 / 1;
//!   129 with three rounds leaves 1 / 0 / 0 / 0 / 1 but takes plans from
//!   420 ms to 700 ms (`treemorph bench`, eucalyptus → conifer). Unpaced
//!   instants (the schedule's own clock) left
//!   2–4 at 65 and at 129: the pace stretches short bursts of the clock
//!   over many frames, so the instants must be the paced ones.
//! - **Two rounds, not four**: four took the default morph to 0.76 s
//!   for the same sum over the five pairs (9).
//! - **No padding for the motion between instants.** Capsules grown by
//!   half of each node's move to the next instant shed nearly every
//!   blend (12,267 pairs on the first round), and a bound on the two
//!   segments' relative motion left one blended chain: limbs turn, and a
//!   turn moves a twig cloud's ends apart. A fixed margin of 0.1–0.3 %
//!   of the height shed more and left as many.
//! - **What is left** are passes shorter than an instant's spacing (with
//!   four rounds, the final default plan touched in 106 pairs at some
//!   instant of 600 and in none of the 65), and what the last round's new
//!   partners cross.
//!
//! Hand-written: the loop over the existing matching, builder and meter.
use rayon::prelude::*;
use treemorph_analysis::ChainId;
use treemorph_tree::Frame;
use treemorph_tree::crossings::CrossingMeter;

use crate::correspondence::Operation;
use crate::morpher::Morpher;
use crate::plan::MorphPlan;

/// Instants played per round, ends included.
pub(crate) const SAMPLES: usize = 65;

/// Rounds of matching, building and playing at most.
pub(crate) const ROUNDS: usize = 2;

/// The chains of `plan` to take out of the matching so its crossing
/// blends shed and regrow (see the module docs), as `(side, chain)`; none
/// when nothing crosses.
pub(crate) fn to_shed(plan: &MorphPlan) -> Vec<(usize, ChainId)> {
    let pairs = crossing_pairs(plan);
    let sizes = subtree_sizes(plan);
    let mut out = Vec::new();
    let mut taken = vec![false; plan.chains.len()];
    for (a, b) in pairs {
        let Some(v) = lesser_blend(plan, &sizes, a, b) else {
            continue;
        };
        if std::mem::replace(&mut taken[v as usize], true) {
            continue;
        }
        let c = &plan.chains[v as usize];
        match c.operation {
            Operation::Split => out.extend(c.target.map(|t| (1, t))),
            Operation::Merge => out.extend(c.source.map(|s| (0, s))),
            _ => {
                out.extend(c.source.map(|s| (0, s)));
                out.extend(c.target.map(|t| (1, t)));
            }
        }
    }
    out
}

/// Every pair of union chains that touches at one of the [`SAMPLES`]
/// instants and at neither end, each once.
fn crossing_pairs(plan: &MorphPlan) -> Vec<(u32, u32)> {
    let strands = &plan.topology.strands;
    // Each sample on its own meter in parallel, joined in order on one.
    let touching: Vec<Vec<(u32, u32)>> = (0..SAMPLES)
        .into_par_iter()
        .map_init(
            || (CrossingMeter::new(), Frame::default(), Morpher::new(plan)),
            |(meter, frame, morpher), k| {
                let t = k as f32 / (SAMPLES - 1) as f32;
                morpher.morph_branches(t, frame);
                meter.touching_pairs(strands, frame)
            },
        )
        .collect();
    let mut meter = CrossingMeter::new();
    for pairs in touching {
        meter.push_touching(pairs);
    }
    let mut pairs: Vec<(u32, u32)> = (0..SAMPLES).flat_map(|i| meter.crossing_pairs(i)).collect();
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

/// Per union chain, how many union chains its subtree holds (itself
/// included).
fn subtree_sizes(plan: &MorphPlan) -> Vec<u32> {
    let mut size = vec![1u32; plan.chains.len()];
    // Parents come first, so one backward pass sums every subtree.
    for i in (0..plan.chains.len()).rev() {
        if let Some(p) = plan.chains[i].parent {
            size[p as usize] += size[i];
        }
    }
    size
}

/// The chain of a crossing pair to take out: the lesser blended one, or
/// the lesser nearest blended ancestor when neither blends.
fn lesser_blend(plan: &MorphPlan, size: &[u32], a: u32, b: u32) -> Option<u32> {
    let blended = |c: u32| {
        let chain = &plan.chains[c as usize];
        chain.parent.is_some()
            && chain.operation != Operation::Grow
            && chain.operation != Operation::Wilt
    };
    let lesser = |c: u32| {
        (
            size[c as usize],
            std::cmp::Reverse(plan.chains[c as usize].level),
        )
    };
    let direct = [a, b]
        .into_iter()
        .filter(|&c| blended(c))
        .min_by_key(|&c| lesser(c));
    direct.or_else(|| {
        [a, b]
            .into_iter()
            .filter_map(|c| blended_ancestor(plan, c, &blended))
            .min_by_key(|&c| lesser(c))
    })
}

/// The nearest ancestor of `c` that blends, below the root chains.
fn blended_ancestor(plan: &MorphPlan, c: u32, blended: &impl Fn(u32) -> bool) -> Option<u32> {
    let mut at = plan.chains[c as usize].parent;
    while let Some(p) = at {
        if blended(p) {
            return Some(p);
        }
        at = plan.chains[p as usize].parent;
    }
    None
}

#[cfg(test)]
mod tests {
    use treemorph_analysis::{Analysis, AnalysisOptions};
    use treemorph_generate::{GenerateOptions, Preset, generate};

    use super::*;
    use crate::MorphOptions;

    /// Conifer → willow at 1,500 branches, whose twig clouds pass through
    /// each other while the limbs reshape.
    fn conifer_to_willow(options: &MorphOptions) -> MorphPlan {
        let tree = |preset, seed| {
            let t = generate(&GenerateOptions::new(preset, seed).with_size(1500)).unwrap();
            let a = Analysis::of(&t, &AnalysisOptions::default()).unwrap();
            (t, a)
        };
        let (a, b) = (tree(Preset::Conifer, 2), tree(Preset::Willow, 3));
        MorphPlan::new(&a.0, &a.1, &b.0, &b.1, options).unwrap()
    }

    /// The frames of a 60-frame job (instants `i / 59`, not the planner's
    /// `k / 64`), branches only.
    fn job_frames(plan: &MorphPlan) -> Vec<Frame> {
        let mut morpher = Morpher::new(plan);
        (0..60)
            .map(|i| {
                let mut frame = Frame::default();
                morpher.morph_branches(i as f32 / 59.0, &mut frame);
                frame
            })
            .collect()
    }

    fn blended(plan: &MorphPlan) -> usize {
        let shed =
            |c: &&crate::UnionChain| matches!(c.operation, Operation::Grow | Operation::Wilt);
        plan.chains.len() - plan.chains.iter().filter(shed).count()
    }

    /// What it sheds is what crossed: at 1,500 branches more than half of
    /// the blends stay (at 5,000, where more twig clouds meet, a quarter to
    /// a half), and the ends are the inputs. (The crossings themselves are measured on written
    /// frames in `treemorph_verify`'s `crossing_cost` tests.)
    #[test]
    fn untangling_keeps_most_blends_and_the_ends() {
        let tangled = conifer_to_willow(&MorphOptions::default().with_untangle(false));
        let untangled = conifer_to_willow(&MorphOptions::default());
        assert!(!to_shed(&tangled).is_empty());
        let (kept, had) = (blended(&untangled), blended(&tangled));
        assert!(kept < had && kept * 2 > had, "{kept} of {had} blends kept");
        let ends = untangled.endpoint_error();
        assert!(ends.source < 1e-5 && ends.target < 1e-5, "{ends:?}");
    }

    /// A chain kept out of the matching wilts (grows) with everything on
    /// it, and the rest of the matching still pairs chains.
    #[test]
    fn an_excluded_chain_leaves_the_matching_with_its_substructure() {
        use crate::correspondence::{Excluded, Input, correspond};
        let tree = |preset, seed| {
            let t = generate(&GenerateOptions::new(preset, seed).with_size(400)).unwrap();
            let a = Analysis::of(&t, &AnalysisOptions::default()).unwrap();
            (t, a)
        };
        let ((s, sa), (t, ta)) = (tree(Preset::Maple, 1), tree(Preset::Conifer, 2));
        let (si, ti) = (Input::new(&s, &sa, 1.0), Input::new(&t, &ta, 1.0));
        let options = MorphOptions::default();
        let all = correspond(&si, &ti, &options, &Excluded::default());
        let limb = all
            .chains
            .iter()
            .map(|m| m.source)
            .find(|&c| sa.chain(c).parent.is_some() && !sa.chain(c).children.is_empty())
            .expect("a matched limb with twigs");
        let mut excluded = Excluded::default();
        excluded.add(0, limb, sa.chains().len());
        let out = correspond(&si, &ti, &options, &excluded);
        let mut below = vec![limb];
        let mut i = 0;
        while i < below.len() {
            below.extend_from_slice(&sa.chain(below[i]).children);
            i += 1;
        }
        for c in below {
            assert!(out.wilting_chains.contains(&c), "chain {c} should wilt");
            assert!(
                out.chains.iter().all(|m| m.source != c),
                "chain {c} is matched"
            );
        }
        assert!(
            out.chains.len() + 1 >= all.chains.len() / 2,
            "{} of {}",
            out.chains.len(),
            all.chains.len()
        );
    }

    /// Regression: the untangled plan was paced on its motion as the
    /// first plan's pace played it, which bunched the shed phase into a
    /// few frames (the default morph's jump ratio went 1.12 → 2.37; here
    /// the largest move was twice the median).
    #[test]
    fn an_untangled_plan_moves_evenly() {
        let plan = conifer_to_willow(&MorphOptions::default());
        let frames = job_frames(&plan);
        let mut jumps: Vec<f32> = frames
            .windows(2)
            .map(|w| {
                let pairs = w[0].positions.iter().zip(&w[1].positions);
                pairs.map(|(a, b)| a.distance(*b)).fold(0.0, f32::max)
            })
            .collect();
        let largest = jumps.iter().copied().fold(0.0, f32::max);
        jumps.sort_by(f32::total_cmp);
        let median = jumps[jumps.len() / 2];
        assert!(
            largest <= 2.0 * median,
            "{largest} against a median of {median}"
        );
    }
}
