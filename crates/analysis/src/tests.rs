//! Hand-built trees with known structure.

// Options are changed one field at a time, as callers outside the crate
// (where the struct is non-exhaustive) must.
#![allow(clippy::field_reassign_with_default)]

use glam::{Quat, Vec3};
use treemorph_tree::{
    BranchingPattern, Leaf, LeafMaterial, Limits, Materials, Node, Tree, TreeParts,
};

use super::*;

/// A small tree builder.
struct B {
    nodes: Vec<Node>,
    leaves: Vec<Leaf>,
}

impl B {
    fn new() -> B {
        B {
            nodes: vec![Node {
                position: Vec3::ZERO,
                radius: 0.2,
                parent: None,
            }],
            leaves: Vec::new(),
        }
    }

    fn add(&mut self, parent: u32, position: Vec3, radius: f32) -> u32 {
        self.nodes.push(Node {
            position,
            radius,
            parent: Some(parent),
        });
        (self.nodes.len() - 1) as u32
    }

    /// `n` nodes from `from` along `dir`, `step` apart, radius tapering from
    /// `r0`. Returns their ids.
    fn line(&mut self, from: u32, dir: Vec3, n: usize, step: f32, r0: f32) -> Vec<u32> {
        let mut at = from;
        let mut ids = Vec::new();
        for i in 0..n {
            let p = self.nodes[at as usize].position + dir.normalize() * step;
            at = self.add(at, p, r0 * (1.0 - 0.5 * i as f32 / n as f32));
            ids.push(at);
        }
        ids
    }

    fn leaf(&mut self, branch: u32, t: f32) {
        self.leaves.push(Leaf {
            branch,
            t,
            offset: Vec3::new(0.01, 0.0, 0.0),
            width: 0.04,
            height: 0.08,
            orientation: Quat::from_rotation_z(0.3),
            material: 0,
        });
    }

    /// Leaves on the last two branches of a line of nodes.
    fn tip_leaves(&mut self, line: &[u32], per_branch: usize) {
        for &b in &line[line.len().saturating_sub(2)..] {
            for k in 0..per_branch {
                self.leaf(b, (k as f32 + 0.5) / per_branch as f32);
            }
        }
    }

    fn build(self) -> Tree {
        Tree::new(
            TreeParts {
                name: "test".into(),
                nodes: self.nodes,
                leaves: self.leaves,
                materials: Materials {
                    leaves: vec![LeafMaterial {
                        name: "plain".into(),
                        color: [0.2, 0.6, 0.2, 1.0],
                        texture: None,
                    }],
                    ..Materials::default()
                },
                ..TreeParts::default()
            },
            &Limits::default(),
        )
        .expect("valid test tree")
    }
}

fn lateral_dir(azimuth_deg: f32) -> Vec3 {
    let a = azimuth_deg.to_radians();
    Vec3::new(a.cos(), 0.6, a.sin())
}

fn analyse(tree: &Tree) -> Analysis {
    Analysis::of(tree, &AnalysisOptions::default()).expect("analysis")
}

/// The group whose chains start with the given first nodes.
fn group_of(a: &Analysis, first_node: u32) -> &ChainGroup {
    let c = a.chain_of_node(first_node).expect("chain");
    a.group(a.chain(c).group)
}

/// Checks the invariants every analysis must hold.
fn check_invariants(tree: &Tree, a: &Analysis) {
    let sk = tree.skeleton();
    // Chains partition the branches.
    let mut seen = vec![0u32; sk.len()];
    for c in a.chains() {
        assert!(c.nodes.len() >= 2);
        for w in c.nodes.windows(2) {
            assert_eq!(
                sk.node(w[1]).parent,
                Some(w[0]),
                "consecutive chain nodes are parent and child"
            );
        }
        for &n in &c.nodes[1..] {
            seen[n as usize] += 1;
            assert_eq!(a.orders()[n as usize], c.order);
        }
        match c.parent {
            Some(p) => {
                let p = a.chain(p);
                assert_eq!(c.order, p.order + 1);
                assert!(
                    p.nodes.contains(&c.junction()),
                    "junction lies on the parent chain"
                );
                assert!(p.children.contains(&c.id));
            }
            None => {
                assert_eq!(c.junction(), 0);
                assert_eq!(c.order, 1);
            }
        }
        assert!((0.0..=1.0).contains(&c.growth_location));
        assert!((c.branching_vector.length() - 1.0).abs() < 1e-4);
        for q in &c.frames {
            assert!((q.length() - 1.0).abs() < 1e-4);
        }
    }
    assert_eq!(seen[0], 0);
    assert!(
        seen[1..].iter().all(|&s| s == 1),
        "every branch in exactly one chain"
    );
    // Orders never decrease from root to tip.
    for (i, n) in sk.nodes().iter().enumerate() {
        if let Some(p) = n.parent {
            assert!(a.orders()[i] >= a.orders()[p as usize]);
        }
    }
    // Groups and BPTT.
    let mut in_group = vec![0; a.chains().len()];
    for g in a.groups() {
        for &c in &g.chains {
            in_group[c as usize] += 1;
            assert_eq!(a.chain(c).group, g.id);
            assert_eq!(a.chain(c).parent, g.parent_chain);
            assert_eq!(a.chain(c).order, g.order);
        }
        for &k in &g.children {
            let child = a.group(k);
            assert_eq!(child.parent, Some(g.id));
            assert_eq!(child.level, g.level + 1);
            let pc = child
                .parent_chain
                .expect("non-root group has a parent chain");
            assert!(g.chains.contains(&pc), "BPTT edge respects parenthood");
        }
        assert!(a.bptt().level(g.level as usize).contains(&g.id));
    }
    assert!(
        in_group.iter().all(|&n| n == 1),
        "every chain in exactly one group"
    );
    // Every leaf in exactly one IL; OLs and GOLs are the unions.
    let mut count = vec![0; tree.leaves().len()];
    for c in a.chains() {
        for &l in &c.inner_lobe.leaves {
            count[l as usize] += 1;
            assert_eq!(a.leaves()[l as usize].inner_lobe, c.id);
        }
        let mut ol = c.inner_lobe.leaves.clone();
        for &k in &c.children {
            ol.extend(&a.chain(k).outer_lobe.leaves);
        }
        ol.sort_unstable();
        assert_eq!(ol, c.outer_lobe.leaves);
    }
    assert!(
        count.iter().all(|&n| n == 1),
        "every leaf in exactly one IL"
    );
    assert_eq!(a.crown().leaves.len(), tree.leaves().len());
    // Hulls contain their lobes' points and septuples reconstruct leaves.
    let lobes = a
        .chains()
        .iter()
        .flat_map(|c| [&c.inner_lobe, &c.outer_lobe])
        .chain(a.groups().iter().map(|g| &g.outer_lobe));
    for lobe in lobes {
        assert_eq!(lobe.hull.is_empty(), lobe.leaves.is_empty());
        for &l in &lobe.leaves {
            for p in lobe::blade_points(tree, &tree.leaves()[l as usize]) {
                assert!(
                    lobe.hull.contains(p, 1e-4),
                    "hull contains leaf {l}'s point {p}"
                );
            }
        }
    }
    for (leaf, p) in tree.leaves().iter().zip(a.leaves()) {
        let c = a.chain(p.inner_lobe);
        let frame = c.frame_at(p.param);
        let anchor = c.point_at(p.param).0 + frame * p.offset;
        assert!(
            anchor.distance(tree.leaf_anchor(leaf)) < 1e-4,
            "anchor reconstructs"
        );
        assert!(
            (frame * p.orientation).dot(leaf.orientation).abs() > 0.9999,
            "orientation reconstructs"
        );
        assert_eq!(a.chain_of_node(leaf.branch), Some(p.grows_on));
    }
}

/// A straight trunk with four alternate laterals spiralling up, leaves at
/// every chain's tip.
fn alternate_tree() -> (Tree, Vec<u32>, Vec<u32>) {
    let mut b = B::new();
    let trunk = b.line(0, Vec3::Y, 10, 0.5, 0.15);
    let mut firsts = Vec::new();
    for (k, &at) in [trunk[1], trunk[3], trunk[5], trunk[7]].iter().enumerate() {
        let lat = b.line(at, lateral_dir(137.5 * k as f32), 4, 0.4, 0.05);
        firsts.push(lat[0]);
        b.tip_leaves(&lat, 3);
    }
    b.tip_leaves(&trunk, 3);
    (b.build(), trunk, firsts)
}

#[test]
fn alternate_laterals_on_a_trunk() {
    let (tree, trunk, firsts) = alternate_tree();
    let a = analyse(&tree);
    check_invariants(&tree, &a);
    assert_eq!(a.chains().len(), 5);
    let tc = a.chain(a.chain_of_node(trunk[0]).unwrap());
    assert_eq!(tc.order, 1);
    assert_eq!(tc.nodes.len(), 11, "root plus ten trunk nodes");
    for &f in &firsts {
        let g = group_of(&a, f);
        assert_eq!(g.pattern, BranchingPattern::Alternate);
        assert_eq!(g.chains.len(), 1);
        assert_eq!(g.order, 2);
        assert_eq!(g.parent, Some(0));
    }
    assert_eq!(a.groups().len(), 5);
    assert_eq!(a.bptt().depth(), 2);
    assert_eq!(a.bptt().children(0).len(), 4);
    // OR: the first lateral grows at trunk node 2 of 10 → 0.2.
    assert!((tc.outer_ratio - 0.2).abs() < 1e-5, "{}", tc.outer_ratio);
    // Growth locations follow the junctions.
    let p: Vec<f32> = firsts
        .iter()
        .map(|&f| a.chain(a.chain_of_node(f).unwrap()).growth_location)
        .collect();
    for (got, want) in p.iter().zip([0.2, 0.4, 0.6, 0.8]) {
        assert!((got - want).abs() < 1e-5);
    }
    // Leaves at tips belong to the chain they grow on.
    for p in a.leaves() {
        assert_eq!(p.inner_lobe, p.grows_on);
    }
    let s = a.summary();
    assert_eq!(s.chains, 5);
    assert_eq!(s.orders.max, 2);
    assert_eq!(s.orders.histogram, vec![1, 4]);
    assert_eq!(s.patterns.alternate, 5);
    assert_eq!(s.lobes.inner, 5);
}

#[test]
fn opposite_pair_and_four_whorl() {
    let mut b = B::new();
    let trunk = b.line(0, Vec3::Y, 8, 0.5, 0.15);
    let l = b.line(trunk[2], lateral_dir(0.0), 3, 0.4, 0.05);
    let r = b.line(trunk[2], lateral_dir(180.0), 3, 0.4, 0.05);
    let whorl: Vec<u32> = (0..4)
        .map(|k| b.line(trunk[5], lateral_dir(90.0 * k as f32 + 10.0), 3, 0.4, 0.05)[0])
        .collect();
    let tree = b.build();
    let a = analyse(&tree);
    check_invariants(&tree, &a);
    let g = group_of(&a, l[0]);
    assert_eq!(g.pattern, BranchingPattern::Opposite);
    assert_eq!(g.chains.len(), 2);
    assert!(g.chains.contains(&a.chain_of_node(r[0]).unwrap()));
    assert!((g.divergence - 180.0).abs() < 1e-3, "{}", g.divergence);
    let w = group_of(&a, whorl[0]);
    assert_eq!(w.pattern, BranchingPattern::Whorled);
    assert_eq!(w.chains.len(), 4);
    assert!((w.divergence - 90.0).abs() < 1e-3, "{}", w.divergence);
    let s = a.summary();
    assert_eq!(
        (
            s.patterns.alternate,
            s.patterns.opposite,
            s.patterns.whorled
        ),
        (1, 1, 1)
    );
}

#[test]
fn two_laterals_on_one_side_are_whorled_not_opposite() {
    let mut b = B::new();
    let trunk = b.line(0, Vec3::Y, 6, 0.5, 0.15);
    let l = b.line(trunk[2], lateral_dir(0.0), 3, 0.4, 0.05);
    b.line(trunk[2], lateral_dir(60.0), 3, 0.4, 0.05);
    let tree = b.build();
    let a = analyse(&tree);
    let g = group_of(&a, l[0]);
    assert_eq!(g.chains.len(), 2);
    assert!((g.divergence - 60.0).abs() < 1e-3);
    assert_eq!(g.pattern, BranchingPattern::Whorled);
}

#[test]
fn a_whorl_split_over_close_nodes_is_one_group_but_spaced_laterals_are_not() {
    let mut b = B::new();
    let mut trunk = b.line(0, Vec3::Y, 3, 0.5, 0.15);
    // A skeletoniser split this junction: two nodes 5 cm apart (radius 0.1).
    let split = b.add(trunk[2], Vec3::new(0.0, 1.55, 0.0), 0.1);
    trunk.push(split);
    trunk.extend(b.line(split, Vec3::Y, 4, 0.5, 0.1));
    let w0 = b.line(trunk[2], lateral_dir(0.0), 3, 0.4, 0.04)[0];
    b.line(trunk[2], lateral_dir(120.0), 3, 0.4, 0.04);
    b.line(split, lateral_dir(240.0), 3, 0.4, 0.04);
    // Alternate laterals 0.5 m apart stay apart.
    let a0 = b.line(trunk[5], lateral_dir(30.0), 3, 0.4, 0.04)[0];
    let a1 = b.line(trunk[6], lateral_dir(200.0), 3, 0.4, 0.04)[0];
    let tree = b.build();
    let a = analyse(&tree);
    check_invariants(&tree, &a);
    let g = group_of(&a, w0);
    assert_eq!(g.chains.len(), 3);
    assert_eq!(g.pattern, BranchingPattern::Whorled);
    assert!((g.divergence - 120.0).abs() < 1.0, "{}", g.divergence);
    assert_ne!(group_of(&a, a0).id, group_of(&a, a1).id);
    assert_eq!(group_of(&a, a0).pattern, BranchingPattern::Alternate);
}

/// The analysis of `tree`, checked, whose three-node `trunk` chain ends
/// at the fork on its last node.
fn trunk_ends_at_its_fork(tree: &Tree, trunk: &[u32]) -> Analysis {
    let a = analyse(tree);
    check_invariants(tree, &a);
    let trunk_chain = a.chain(a.chain_of_node(trunk[0]).unwrap());
    assert_eq!(
        trunk_chain.nodes,
        vec![0, trunk[0], trunk[1], trunk[2]],
        "the trunk chain ends at the fork"
    );
    a
}

#[test]
fn a_symmetric_fork_ends_the_parent_chain() {
    let mut b = B::new();
    let trunk = b.line(0, Vec3::Y, 3, 0.5, 0.15);
    let left = b.line(trunk[2], Vec3::new(-0.5, 1.0, 0.0), 3, 0.4, 0.08);
    let right = b.line(trunk[2], Vec3::new(0.5, 1.0, 0.0), 3, 0.4, 0.08);
    // Each arm forks again.
    let ll = b.line(left[2], Vec3::new(-1.0, 1.0, 0.3), 2, 0.3, 0.04);
    let lr = b.line(left[2], Vec3::new(0.0, 1.0, -0.3), 2, 0.3, 0.04);
    b.tip_leaves(&ll, 2);
    b.tip_leaves(&lr, 2);
    b.tip_leaves(&right, 2);
    let tree = b.build();
    let a = trunk_ends_at_its_fork(&tree, &trunk);
    let g = group_of(&a, left[0]);
    assert_eq!(g.chains.len(), 2);
    assert_eq!(g.order, 2);
    assert_eq!(g.pattern, BranchingPattern::Opposite);
    assert_eq!(g.growth_location, 1.0);
    assert_eq!(a.orders()[ll[0] as usize], 3);
    assert_eq!(group_of(&a, ll[0]).chains.len(), 2);
    assert_eq!(a.bptt().depth(), 3);
    assert_eq!(a.bptt().nodes_at(2).len(), 1);
}

#[test]
fn an_asymmetric_fork_is_gravelius() {
    // Same angles but very different radii: Gravelius, the straighter (here
    // equally straight, so the thicker) child continues.
    let mut b = B::new();
    let trunk = b.line(0, Vec3::Y, 3, 0.5, 0.15);
    let thick = b.line(trunk[2], Vec3::new(-0.5, 1.0, 0.0), 3, 0.4, 0.12);
    let thin = b.line(trunk[2], Vec3::new(0.5, 1.0, 0.0), 3, 0.4, 0.04);
    let tree = b.build();
    let a = analyse(&tree);
    check_invariants(&tree, &a);
    assert_eq!(a.orders()[thick[0] as usize], 1);
    assert_eq!(a.orders()[thin[0] as usize], 2);
    assert_eq!(a.chain_of_node(thick[0]), a.chain_of_node(trunk[0]));
}

/// A trunk ending in drooping twigs: the one that turns back least would
/// continue it under Gravelius alone, hooking the trunk downwards (forks
/// like it are in Modular Tree's bushy and weeping trees), but no child
/// turning more than `continuation_angle` continues a chain.
#[test]
fn no_child_turning_back_continues_a_chain() {
    let mut b = B::new();
    let trunk = b.line(0, Vec3::Y, 3, 0.5, 0.15);
    let less = b.line(trunk[2], Vec3::new(-1.0, -0.5, 0.0), 3, 0.4, 0.08);
    let more = b.line(trunk[2], Vec3::new(1.0, -0.8, 0.0), 3, 0.4, 0.03);
    b.tip_leaves(&less, 2);
    b.tip_leaves(&more, 2);
    let tree = b.build();
    let a = trunk_ends_at_its_fork(&tree, &trunk);
    assert_eq!(a.orders()[less[0] as usize], 2);
    assert_eq!(a.orders()[more[0] as usize], 2);
    // Under a wider bound the straighter twig continues, as before.
    let mut wide = AnalysisOptions::default();
    wide.continuation_angle = 180.0;
    let a = Analysis::of(&tree, &wide).unwrap();
    assert_eq!(a.chain_of_node(less[0]), a.chain_of_node(trunk[0]));
}

#[test]
fn a_multi_stem_root_is_one_root_group() {
    let mut b = B::new();
    let firsts: Vec<u32> = (0..3)
        .map(|k| {
            let stem = b.line(
                0,
                lateral_dir(120.0 * k as f32) * Vec3::new(0.3, 1.0, 0.3),
                5,
                0.4,
                0.05,
            );
            b.tip_leaves(&stem, 2);
            stem[0]
        })
        .collect();
    let tree = b.build();
    let a = analyse(&tree);
    check_invariants(&tree, &a);
    let root = a.group(a.bptt().root());
    assert_eq!(root.chains.len(), 3);
    assert_eq!(root.parent_chain, None);
    assert_eq!(root.pattern, BranchingPattern::Whorled);
    assert!((root.divergence - 120.0).abs() < 1e-3);
    for f in firsts {
        assert_eq!(a.orders()[f as usize], 1);
        assert_eq!(a.chain(a.chain_of_node(f).unwrap()).group, 0);
    }
    assert_eq!(a.bptt().depth(), 1);
}

#[test]
fn leaves_go_to_the_tip_lobes_of_their_chains() {
    // Laterals with sub-laterals: leaves at every chain tip must land in the
    // IL of the chain they grow on, and OLs nest.
    let mut b = B::new();
    let trunk = b.line(0, Vec3::Y, 12, 0.5, 0.2);
    b.tip_leaves(&trunk, 4);
    for (k, &at) in [trunk[2], trunk[5], trunk[8]].iter().enumerate() {
        let lat = b.line(at, lateral_dir(120.0 * k as f32), 6, 0.4, 0.06);
        b.tip_leaves(&lat, 4);
        let sub = b.line(
            lat[2],
            lateral_dir(120.0 * k as f32 + 70.0) + Vec3::Y,
            3,
            0.3,
            0.02,
        );
        b.tip_leaves(&sub, 4);
    }
    let tree = b.build();
    let a = analyse(&tree);
    check_invariants(&tree, &a);
    let wrong: Vec<_> = a
        .leaves()
        .iter()
        .enumerate()
        .filter(|(_, p)| p.inner_lobe != p.grows_on)
        .collect();
    assert!(wrong.is_empty(), "{wrong:#?}");
    for c in a.chains() {
        assert!(!c.inner_lobe.is_empty(), "chain {} has leaves", c.id);
        // Leaves sit on the last two branches (of 3, 6 or 12).
        assert!(c.inner_ratio > 0.3, "tip leaves start late on the chain");
        let lowest = c
            .inner_lobe
            .leaves
            .iter()
            .map(|&l| a.leaves()[l as usize].param)
            .fold(1.0, f32::min);
        assert_eq!(c.inner_ratio, lowest);
        if let Some(p) = c.parent {
            let parent = &a.chain(p).outer_lobe;
            assert!(
                c.outer_lobe
                    .leaves
                    .iter()
                    .all(|l| parent.leaves.binary_search(l).is_ok())
            );
            assert!(parent.radius >= c.outer_lobe.radius * 0.5);
        }
    }
    assert_eq!(a.summary().bptt_depth, 3);
}

#[test]
fn a_tree_without_leaves_has_empty_lobes() {
    let (tree, _, _) = alternate_tree();
    let bare = Tree::new(
        TreeParts {
            leaves: Vec::new(),
            ..tree.into_parts()
        },
        &Limits::default(),
    )
    .unwrap();
    let a = analyse(&bare);
    check_invariants(&bare, &a);
    assert!(a.crown().is_empty());
    assert_eq!(a.crown().radius, 0.0);
    assert_eq!(a.summary().lobes.inner, 0);
    for c in a.chains() {
        assert_eq!(c.inner_ratio, 1.0);
        assert_eq!(c.inner_lobe.center, c.tip());
    }
}

#[test]
fn frames_are_rotation_minimising_on_a_straight_chain_and_follow_bends() {
    let mut b = B::new();
    let trunk = b.line(0, Vec3::Y, 4, 0.5, 0.15);
    let bent = b.line(trunk[3], Vec3::X, 4, 0.5, 0.1);
    b.line(trunk[1], lateral_dir(0.0), 2, 0.3, 0.03);
    let _ = bent;
    let tree = b.build();
    let a = analyse(&tree);
    let c = a.chain(a.chain_of_node(trunk[0]).unwrap());
    // The trunk bends into +X at its end; before the bend frames agree.
    assert!(c.frames[0].angle_between(c.frames[2]) < 1e-5);
    for (i, q) in c.frames.iter().enumerate() {
        let t = chain::tangent(&c.points, i);
        assert!(
            (*q * Vec3::Y).dot(t) > 0.9999,
            "frame y follows the tangent"
        );
    }
    // Root chains start with normal +X (projected off the tangent).
    assert!((c.frames[0] * Vec3::X).dot(Vec3::X) > 0.9999);
}

#[test]
fn lone_root_and_bad_options_are_refused() {
    let lone = B::new().build();
    assert_eq!(
        Analysis::of(&lone, &AnalysisOptions::default()),
        Err(AnalysisError::NoBranches)
    );
    let (tree, _, _) = alternate_tree();
    let mut o = AnalysisOptions::default();
    o.weibull_angle = f32::NAN;
    assert!(matches!(
        Analysis::of(&tree, &o),
        Err(AnalysisError::InvalidOption {
            option: "weibull_angle",
            ..
        })
    ));
    let mut o = AnalysisOptions::default();
    o.cluster_threshold_step = 0.0;
    assert!(matches!(
        Analysis::of(&tree, &o),
        Err(AnalysisError::InvalidOption {
            option: "cluster_threshold_step",
            ..
        })
    ));
    let mut o = AnalysisOptions::default();
    o.hull = HullKind::Radial {
        rings: 0,
        segments: 8,
    };
    assert!(matches!(
        Analysis::of(&tree, &o),
        Err(AnalysisError::InvalidOption { option: "hull", .. })
    ));
}

#[test]
fn radial_hulls_keep_every_invariant() {
    let (tree, _, _) = alternate_tree();
    let mut o = AnalysisOptions::default();
    o.hull = HullKind::Radial {
        rings: 6,
        segments: 12,
    };
    let a = Analysis::of(&tree, &o).unwrap();
    check_invariants(&tree, &a);
    assert_eq!(a.crown().hull.vertices.len(), 6 * 12 + 2);
}

#[test]
fn analysis_is_deterministic() {
    let (tree, _, _) = alternate_tree();
    assert_eq!(analyse(&tree), analyse(&tree));
    assert_eq!(analyse(&tree).to_json(), analyse(&tree).to_json());
}

#[test]
fn summary_and_export_serialise_with_the_agreed_names() {
    let (tree, _, _) = alternate_tree();
    let a = analyse(&tree);
    let json = serde_json::to_string(&a.summary()).unwrap();
    assert_eq!(
        json,
        concat!(
            r#"{"chains":5,"chain_groups":5,"patterns":{"alternate":5,"opposite":0,"whorled":0},"#,
            r#""orders":{"max":2,"histogram":[1,4]},"bptt_depth":2,"lobes":{"inner":5,"outer":5,"group_outer":5}}"#
        )
    );
    let export: serde_json::Value = serde_json::from_slice(&a.to_json()).unwrap();
    assert_eq!(export["chains"].as_array().unwrap().len(), 5);
    assert_eq!(export["groups"][0]["pattern"], "alternate");
    assert_eq!(
        export["leaves"].as_array().unwrap().len(),
        tree.leaves().len()
    );
    let tris = export["groups"][0]["outer_lobe"]["hull"]["triangles"]
        .as_array()
        .unwrap();
    assert!(tris.len() >= 4);
}

#[test]
fn the_literal_centre_kmeans_finds_tip_lobes_on_a_simple_tree() {
    let (tree, _, _) = alternate_tree();
    let mut o = AnalysisOptions::default();
    o.clustering = LobeClustering::CentreKMeans;
    let a = Analysis::of(&tree, &o).unwrap();
    check_invariants(&tree, &a);
    for p in a.leaves() {
        assert_eq!(p.inner_lobe, p.grows_on);
    }
}

#[test]
fn nearest_branch_ignores_the_leaf_branch_field() {
    // A leaf recorded on the trunk but floating at a lateral's tip goes to
    // the lateral: the assignment is geometric.
    let mut b = B::new();
    let trunk = b.line(0, Vec3::Y, 6, 0.5, 0.15);
    let lat = b.line(trunk[2], lateral_dir(0.0), 4, 0.4, 0.05);
    b.leaf(trunk[5], 0.5);
    let mut tree = b.build().into_parts();
    let tip = tree.nodes[lat[3] as usize].position;
    let on_trunk = tree.nodes[trunk[4] as usize]
        .position
        .lerp(tree.nodes[trunk[5] as usize].position, 0.5);
    tree.leaves[0].offset = tip - on_trunk + Vec3::new(0.0, 0.01, 0.0);
    let tree = Tree::new(tree, &Limits::default()).unwrap();
    let a = analyse(&tree);
    check_invariants(&tree, &a);
    assert_eq!(a.leaves()[0].grows_on, a.chain_of_node(trunk[0]).unwrap());
    assert_eq!(a.leaves()[0].inner_lobe, a.chain_of_node(lat[0]).unwrap());
    assert!(a.leaves()[0].param > 0.99);
}
