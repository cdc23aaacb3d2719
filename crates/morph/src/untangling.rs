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
//! new ones. So a staged plan, paced on its own motion, is played at
//! [`SAMPLES`] even instants of paced time, and the crossings between any
//! two union chains are found as the output-level meter defines them
//! ([`CrossingMeter`]: capsules that overlap at an inner instant and at
//! neither end) — at every instant between the first and the last, not
//! only at the samples: from one sample to the next every node is taken
//! to move on a straight line ([`CrossingMeter::passing_pairs`]). The pace
//! only reparametrises the plan's motion, so what the sweep clears is
//! clear at any frame count a job asks for, up to the bow of the motion
//! between two samples (which the even pace keeps small). For each
//! crossing pair the lesser blended chain — the one carrying the smaller
//! subtree, the deeper on a tie — is taken out of the matching: its
//! source side wilts in the shed phase and its target side grows in the
//! growth phase, each with its substructure, both tip-first like any
//! unmatched chain. For a split copy only its target leaves the matching
//! (the source keeps its other partners), for a merge copy only its
//! source. The plan is then matched, built, paced and played again (a
//! new partner can cross where the old one did not), until nothing is
//! shed, for at most [`ROUNDS`] rounds: when they run out, the last plan
//! is not played again, and what its new partners cross stays (the
//! preset pairs never get there).
//!
//! Root chains are never taken out (a trunk that wilts while another grows
//! is not a morph), and a pair of which neither chain blends (a growing or
//! wilting chain carried through another by its host's reshape) sheds
//! nothing.
//!
//! # Measured (the five preset pairs at 5,000 branches)
//! Most crossings in a frame of a 60-frame job, maple → conifer,
//! conifer → willow, willow → eucalyptus, eucalyptus → shrub,
//! shrub → maple: 43 / 40 / 30 / 24 / 50 tangled, 0 / 0 / 0 / 0 / 0
//! untangled, and 0 on every pair at 30, 120, 240 and 600 frames too.
//! The rounds end with nothing to shed after 2 to 4 rebuilds. Blends
//! kept: 228 / 67 / 218 / 129 / 77 of 854 / 402 / 805 / 586 / 605. Plans
//! take 750 ms (eucalyptus → conifer) and 2.5 s (eucalyptus → shrub,
//! 20,000 branches) in `treemorph bench`, and the default morph's CLI run
//! 1.0 s. The choices:
//! - **Swept, not sampled.** Touching at the 65 instants alone left
//!   6 / 1 / 1 / 0 / 1: passes shorter than an instant's spacing (the
//!   final plan touched in 106 pairs at some instant of 600 and in none
//!   of the 65). 129 instants left 1 / 0 / 0 / 0 / 1.
//! - **65 instants, not fewer.** The sweep's cost is its broad phase, the
//!   boxes of segments swept from one instant to the next: at 33 instants
//!   the 20,000-branch plan took 2.0 s, at 17 6.6 s, against 1.6 s at 65
//!   (then with two rounds on one pace), since each box grows with the
//!   step. Padding static capsules by the motion instead shed nearly
//!   every blend (12,267 pairs on the first round).
//! - **Each round paced on its own motion.** On the first plan's pace,
//!   later plans' bursts fell between far instants, where the straight
//!   line strays from the motion: a twig passing the trunk in one was
//!   missed (eucalyptus → shrub at 1,500 branches, in 1 frame of 97).
//! - **Until nothing is shed**, not a fixed count: two rounds left 2 on
//!   maple → conifer, from the last round's new partners.
//! - **No shedding for pairs of which neither chain blends.** Shedding
//!   their nearest blended ancestor instead kept 223 / 7 / 22 / 15 / 42
//!   blends for the same zero crossings, and on trees from other tools
//!   shed every limb.
//! - **A blend crossing a growing or wilting chain is shed too.** Shedding
//!   only for pairs of two blends kept more blends on trees from other
//!   tools (12–51 against 1–8 on seven ez-tree × Modular Tree pairs,
//!   whose plans blend 22–276 chains before untangling), but left 1
//!   crossing on eucalyptus → shrub and raised the worst-frame crossings
//!   summed over all 50 third-party pairs from 278 to 380.
//!
//! Hand-written: the loop over the existing matching, builder and meter.
use rayon::prelude::*;
use treemorph_analysis::ChainId;
use treemorph_tree::Frame;
use treemorph_tree::crossings::CrossingMeter;

use crate::correspondence::Operation;
use crate::morpher::Morpher;
use crate::plan::MorphPlan;

/// Instants played per round, ends included; the motion between two is
/// swept.
pub(crate) const SAMPLES: usize = 65;

/// Rounds of matching, building and playing at most (the preset pairs
/// need 2 to 4).
pub(crate) const ROUNDS: usize = 6;

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

/// Every pair of union chains that touches at some instant between the
/// first and the last of the [`SAMPLES`] instants, moving straight from
/// one instant to the next ([`CrossingMeter::passing_pairs`]), and at
/// neither end, each once.
fn crossing_pairs(plan: &MorphPlan) -> Vec<(u32, u32)> {
    let strands = &plan.topology.strands;
    let frames = played(plan);
    let last = frames.len() - 1;
    let mut meter = CrossingMeter::new();
    let ends = [&frames[0], &frames[last]].map(|f| meter.touching_pairs(strands, f));
    let mut known = [ends[0].as_slice(), ends[1].as_slice()].concat();
    known.sort_unstable();
    // Each step on its own meter in parallel, joined in order on one
    // between the two ends' touching pairs.
    let steps: Vec<Vec<(u32, u32)>> = (0..last)
        .into_par_iter()
        .map_init(CrossingMeter::new, |meter, k| {
            meter.passing_pairs(strands, [&frames[k], &frames[k + 1]], &known)
        })
        .collect();
    let [first, end] = ends;
    meter.push_touching(first);
    for pairs in steps {
        meter.push_touching(pairs);
    }
    meter.push_touching(end);
    let mut pairs: Vec<(u32, u32)> = (1..=last).flat_map(|i| meter.crossing_pairs(i)).collect();
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

/// The plan's branches at [`SAMPLES`] even instants.
fn played(plan: &MorphPlan) -> Vec<Frame> {
    (0..SAMPLES)
        .into_par_iter()
        .map_init(
            || Morpher::new(plan),
            |morpher, k| {
                let mut frame = Frame::default();
                morpher.morph_branches(k as f32 / (SAMPLES - 1) as f32, &mut frame);
                frame
            },
        )
        .collect()
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

/// The chain of a crossing pair to take out: the lesser blended one, if
/// either blends.
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
    [a, b]
        .into_iter()
        .filter(|&c| blended(c))
        .min_by_key(|&c| lesser(c))
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

    /// What it sheds is what crossed, not everything: on this pair a third
    /// of the blends stay at 1,500 branches (at 5,000, where more twig
    /// clouds meet, an eighth to a quarter on the five preset pairs), and
    /// the ends are the inputs. (The crossings themselves are measured on written
    /// frames in `treemorph_verify`'s `crossing_cost` tests.)
    #[test]
    fn untangling_keeps_a_share_of_the_blends_and_the_ends() {
        let tangled = conifer_to_willow(&MorphOptions::default().with_untangle(false));
        let untangled = conifer_to_willow(&MorphOptions::default());
        assert!(!to_shed(&tangled).is_empty());
        let (kept, had) = (blended(&untangled), blended(&tangled));
        assert!(kept < had && kept * 4 > had, "{kept} of {had} blends kept");
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
