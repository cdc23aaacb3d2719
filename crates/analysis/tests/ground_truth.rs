//! The analysis against the generator's ground truth.

use std::collections::BTreeSet;

use glam::Vec3;
use proptest::prelude::*;
use treemorph_analysis::{Analysis, AnalysisOptions, LobeClustering};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_tree::Tree;

/// Agreement of one analysis with its tree's ground truth.
#[derive(Debug, Default, Clone, Copy)]
struct Score {
    nodes: usize,
    orders_ok: usize,
    groups: usize,
    patterns_ok: usize,
    members_ok: usize,
    leaves: usize,
    il_on_own_chain: usize,
}

fn score(tree: &Tree, a: &Analysis) -> Score {
    let gt = tree
        .ground_truth()
        .expect("generated trees have ground truth");
    let mut s = Score {
        nodes: gt.orders.len(),
        ..Score::default()
    };
    s.orders_ok = gt
        .orders
        .iter()
        .zip(a.orders())
        .filter(|(x, y)| x == y)
        .count();
    for g in &gt.groups {
        s.groups += 1;
        let Some(c) = a.chain_of_node(g.chains[0]) else {
            continue;
        };
        let ours = a.group(a.chain(c).group);
        if ours.pattern == g.pattern {
            s.patterns_ok += 1;
        }
        let want: BTreeSet<u32> = g.chains.iter().copied().collect();
        let got: BTreeSet<u32> = ours
            .chains
            .iter()
            .map(|&c| a.chain(c).first_node())
            .collect();
        if want == got {
            s.members_ok += 1;
        }
    }
    s.leaves = a.leaves().len();
    s.il_on_own_chain = a
        .leaves()
        .iter()
        .filter(|p| p.inner_lobe == p.grows_on)
        .count();
    s
}

/// Invariants every analysis of every tree must hold.
fn check_invariants(tree: &Tree, a: &Analysis) {
    let sk = tree.skeleton();
    // Chains partition the skeleton's branches.
    let mut seen = vec![0u32; sk.len()];
    for c in a.chains() {
        for w in c.nodes.windows(2) {
            assert_eq!(sk.node(w[1]).parent, Some(w[0]));
        }
        for &n in &c.nodes[1..] {
            seen[n as usize] += 1;
        }
        if let Some(p) = c.parent {
            assert_eq!(c.order, a.chain(p).order + 1);
            assert!(a.chain(p).nodes.contains(&c.junction()));
        }
    }
    assert!(
        seen[1..].iter().all(|&s| s == 1),
        "chains partition the branches"
    );
    // Orders never decrease from root to tip.
    for (i, n) in sk.nodes().iter().enumerate() {
        if let Some(p) = n.parent {
            assert!(a.orders()[i] >= a.orders()[p as usize]);
        }
    }
    // BPTT edges respect parenthood; every chain in one group.
    let mut grouped = vec![0; a.chains().len()];
    for g in a.groups() {
        for &c in &g.chains {
            grouped[c as usize] += 1;
            assert_eq!(a.chain(c).parent, g.parent_chain);
        }
        for &k in a.bptt().children(g.id) {
            let pc = a
                .group(k)
                .parent_chain
                .expect("child groups have a parent chain");
            assert!(g.chains.contains(&pc));
            assert_eq!(a.group(k).level, g.level + 1);
        }
    }
    assert!(grouped.iter().all(|&n| n == 1));
    // Every leaf in exactly one IL, and each hull contains its lobe's
    // points (anchor and blade tip).
    let mut count = vec![0; tree.leaves().len()];
    for c in a.chains() {
        for &l in &c.inner_lobe.leaves {
            count[l as usize] += 1;
        }
    }
    assert!(
        count.iter().all(|&n| n == 1),
        "every leaf in exactly one IL"
    );
    let lobes = a
        .chains()
        .iter()
        .flat_map(|c| [&c.inner_lobe, &c.outer_lobe])
        .chain(a.groups().iter().map(|g| &g.outer_lobe));
    for lobe in lobes {
        for &l in &lobe.leaves {
            let leaf = &tree.leaves()[l as usize];
            let anchor = tree.leaf_anchor(leaf);
            let q = leaf.orientation;
            for p in [anchor, anchor + q * Vec3::new(0.0, leaf.height, 0.0)] {
                assert!(
                    lobe.hull.contains(p, 1e-3),
                    "hull contains leaf {l}'s point {p}"
                );
            }
        }
    }
}

#[test]
fn every_preset_matches_its_ground_truth() {
    let mut failures = Vec::new();
    for &preset in Preset::ALL {
        for seed in 0..3 {
            for (size, spread) in [(400, 0.0), (2500, 0.0), (2500, 0.5)] {
                let options = GenerateOptions::new(preset, seed)
                    .with_size(size)
                    .with_whorl_spread(spread);
                let tree = generate(&options).unwrap();
                let a = Analysis::of(&tree, &AnalysisOptions::default()).unwrap();
                check_invariants(&tree, &a);
                let s = score(&tree, &a);
                let what = format!(
                    "{} seed {seed} size {size} spread {spread}: {s:?}",
                    preset.name()
                );
                if s.orders_ok * 100 < s.nodes * 99 {
                    failures.push(format!("orders: {what}"));
                }
                if s.patterns_ok * 100 < s.groups * 95 {
                    failures.push(format!("patterns: {what}"));
                }
                if s.members_ok * 100 < s.groups * 95 {
                    failures.push(format!("group members: {what}"));
                }
                if s.il_on_own_chain * 100 < s.leaves * 95 {
                    failures.push(format!("inner lobes: {what}"));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn the_literal_centre_kmeans_keeps_every_invariant() {
    let mut options = AnalysisOptions::default();
    options.clustering = LobeClustering::CentreKMeans;
    for &preset in Preset::ALL {
        let tree = generate(&GenerateOptions::new(preset, 7).with_size(600)).unwrap();
        let a = Analysis::of(&tree, &options).unwrap();
        check_invariants(&tree, &a);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    #[test]
    fn invariants_hold_on_random_generated_trees(
        preset in 0..Preset::ALL.len(),
        seed in 0u64..10_000,
        size in 50u32..600,
        spread in prop::sample::select(vec![0.0f32, 0.25, 0.5]),
    ) {
        let options = GenerateOptions::new(Preset::ALL[preset], seed).with_size(size).with_whorl_spread(spread);
        let tree = generate(&options).unwrap();
        let a = Analysis::of(&tree, &AnalysisOptions::default()).unwrap();
        check_invariants(&tree, &a);
        let again = Analysis::of(&tree, &AnalysisOptions::default()).unwrap();
        prop_assert!(a == again, "deterministic");
    }
}

/// Whole-analysis timings for a `treemorph bench`-like table:
/// `cargo test --release -p treemorph-analysis --test ground_truth -- --ignored timing --nocapture`.
/// Keeps every `k`-th leaf so a tree's leaf count matches the paper's
/// examples (the generator grows 3–10 leaves per chain, the paper's trees
/// about one).
fn thinned(tree: &Tree, leaves: usize) -> Tree {
    let mut parts = tree.clone().into_parts();
    let k = parts.leaves.len().div_ceil(leaves.max(1)).max(1);
    parts.leaves = parts.leaves.into_iter().step_by(k).collect();
    Tree::new(parts, &treemorph_tree::Limits::default()).unwrap()
}

/// Whole-analysis timings for a `treemorph bench`-like table:
/// `cargo test --release -p treemorph-analysis --test ground_truth -- --ignored timing --nocapture`.
#[test]
#[ignore = "timing; run in release"]
fn timing() {
    let cases = [
        (Preset::Eucalyptus, 15_000, None),
        (Preset::Eucalyptus, 15_000, Some(4_436)),
        (Preset::Conifer, 15_000, Some(4_436)),
        (Preset::Eucalyptus, 70_000, None),
        (Preset::Eucalyptus, 70_000, Some(5_919)),
        (Preset::Dichotomous, 70_000, None),
        (Preset::Dichotomous, 70_000, Some(5_919)),
    ];
    for (preset, size, leaves) in cases {
        let mut tree = generate(&GenerateOptions::new(preset, 1).with_size(size)).unwrap();
        if let Some(n) = leaves {
            tree = thinned(&tree, n);
        }
        let options = AnalysisOptions::default();
        let _ = Analysis::of(&tree, &options).unwrap();
        let runs = 5;
        let start = std::time::Instant::now();
        let mut a = None;
        for _ in 0..runs {
            a = Some(Analysis::of(&tree, &options).unwrap());
        }
        let per = start.elapsed() / runs;
        let a = a.unwrap();
        println!(
            "{:12} branches {:6} chains {:6} leaves {:6}: {:?} per analysis",
            preset.name(),
            size,
            a.chains().len(),
            a.leaves().len(),
            per
        );
    }
}

#[test]
#[ignore = "diagnostic table"]
fn print_scores() {
    for &preset in Preset::ALL {
        for seed in 0..3 {
            for (size, spread) in [(300, 0.0), (3000, 0.0), (3000, 0.5)] {
                let tree = generate(
                    &GenerateOptions::new(preset, seed)
                        .with_size(size)
                        .with_whorl_spread(spread),
                )
                .unwrap();
                let a = Analysis::of(&tree, &AnalysisOptions::default()).unwrap();
                let s = score(&tree, &a);
                println!(
                    "{:12} seed {seed} size {size:5} spread {spread}: orders {:5}/{:5} patterns {:4}/{:4} members {:4}/{:4} il {:5}/{:5}",
                    preset.name(),
                    s.orders_ok,
                    s.nodes,
                    s.patterns_ok,
                    s.groups,
                    s.members_ok,
                    s.groups,
                    s.il_on_own_chain,
                    s.leaves
                );
            }
        }
    }
}

#[test]
#[ignore = "diagnostic"]
fn print_mismatches() {
    for &preset in Preset::ALL {
        let tree = generate(&GenerateOptions::new(preset, 0).with_size(3000)).unwrap();
        let a = Analysis::of(&tree, &AnalysisOptions::default()).unwrap();
        for g in &tree.ground_truth().unwrap().groups {
            let c = a.chain_of_node(g.chains[0]).unwrap();
            let ours = a.group(a.chain(c).group);
            if ours.pattern != g.pattern {
                let firsts: Vec<u32> = ours
                    .chains
                    .iter()
                    .map(|&c| a.chain(c).first_node())
                    .collect();
                let parent = ours.parent_chain.map(|p| a.chain(p));
                println!(
                    "{} gt {:?} {:?} ours {:?} {:?} div {} parent_len {:?} p {}",
                    preset.name(),
                    g.pattern,
                    g.chains,
                    ours.pattern,
                    firsts,
                    ours.divergence,
                    parent.map(|p| (p.length, p.nodes.len())),
                    ours.growth_location
                );
            }
        }
    }
}
