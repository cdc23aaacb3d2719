use std::collections::HashMap;

use glam::Vec3;
use proptest::prelude::*;
use treemorph_tree::{BranchingPattern, NodeId, Tree, json};

use super::*;
use crate::grow::{MAX_TURN_DEG, height_factor};
use crate::pipe::LATERAL_RADIUS_RATIO;

const SEEDS: [u64; 3] = [1, 2, 3];
const SIZES: [u32; 3] = [
    GenerateOptions::MIN_SIZE,
    GenerateOptions::DEFAULT_SIZE,
    20_000,
];

fn gen_tree(preset: Preset, seed: u64, size: u32) -> Tree {
    generate(&GenerateOptions::new(preset, seed).with_size(size))
        .unwrap_or_else(|e| panic!("{preset} seed {seed} size {size}: {e}"))
}

/// Child lists of a tree's skeleton.
fn kids(tree: &Tree, v: NodeId) -> &[NodeId] {
    tree.skeleton().children(v)
}

/// Direction of the branch entering `v` (+Y for the root).
fn incoming(tree: &Tree, v: NodeId) -> Vec3 {
    let sk = tree.skeleton();
    match sk.node(v).parent {
        Some(p) => (sk.node(v).position - sk.node(p).position).normalize(),
        None => Vec3::Y,
    }
}

fn out_dir(tree: &Tree, v: NodeId, c: NodeId) -> Vec3 {
    let sk = tree.skeleton();
    (sk.node(c).position - sk.node(v).position).normalize()
}

/// Per node, the index of its chain; chains numbered from 0 in node order.
/// A chain starts at a child of the root or where the order changes.
fn chain_ids(tree: &Tree) -> (Vec<u32>, Vec<NodeId>) {
    let gt = tree.ground_truth().unwrap();
    let sk = tree.skeleton();
    let mut ids = vec![u32::MAX; sk.len()];
    let mut starts = Vec::new();
    for v in 1..sk.len() {
        let p = sk.node(v as NodeId).parent.unwrap() as usize;
        if p == 0 || gt.orders[v] != gt.orders[p] {
            ids[v] = starts.len() as u32;
            starts.push(v as NodeId);
        } else {
            ids[v] = ids[p];
        }
    }
    (ids, starts)
}

/// Angle between the projections of `a` and `b` onto the plane normal to
/// `axis`, degrees.
fn divergence(axis: Vec3, a: Vec3, b: Vec3) -> f32 {
    let pa = (a - axis * a.dot(axis)).normalize();
    let pb = (b - axis * b.dot(axis)).normalize();
    pa.angle_between(pb).to_degrees()
}

/// Checks every invariant the generator promises; `Err` says which broke.
fn check_tree(tree: &Tree, options: &GenerateOptions) -> Result<(), String> {
    let sk = tree.skeleton();
    let n = sk.len();
    let gt = tree.ground_truth().ok_or("no ground truth")?;
    if sk.branch_count() != options.size as usize {
        return Err(format!(
            "{} branches for size {}",
            sk.branch_count(),
            options.size
        ));
    }
    if sk.node(0).position != Vec3::ZERO {
        return Err("the root is not at the origin".into());
    }
    if gt.orders.len() != n || gt.orders[0] != 1 {
        return Err("orders do not start at 1 on the root".into());
    }
    // Orders never decrease and grow by at most one per branch.
    for v in 1..n {
        let p = sk.node(v as NodeId).parent.unwrap() as usize;
        let (o, po) = (gt.orders[v], gt.orders[p]);
        if p == 0 && o != 1 {
            return Err(format!("root child {v} has order {o}"));
        }
        if p != 0 && o != po && o != po + 1 {
            return Err(format!("node {v}: order {o} after parent order {po}"));
        }
        let node = sk.node(v as NodeId);
        if node.position.y < -1e-4 {
            return Err(format!("node {v} is underground at {}", node.position));
        }
        if node.radius > sk.node(p as NodeId).radius {
            return Err(format!("node {v} is thicker than its parent"));
        }
        if node.position.distance(sk.node(p as NodeId).position) < 1e-3 {
            return Err(format!("branch {v} is shorter than a millimetre"));
        }
    }
    // The continuation convention, node by node.
    for v in 0..n as NodeId {
        let ks = kids(tree, v);
        if ks.is_empty() {
            continue;
        }
        let inc = incoming(tree, v);
        let angle = |c: NodeId| inc.angle_between(out_dir(tree, v, c)).to_degrees();
        let radius = |c: NodeId| sk.node(c).radius;
        let o = gt.orders[v as usize];
        let same: Vec<NodeId> = if v == 0 {
            Vec::new()
        } else {
            ks.iter()
                .copied()
                .filter(|&c| gt.orders[c as usize] == o)
                .collect()
        };
        if v != 0 && ks.len() == 1 {
            if same.len() != 1 {
                return Err(format!("single child of {v} does not continue its chain"));
            }
            if angle(ks[0]) > MAX_TURN_DEG + 0.05 {
                return Err(format!("chain turns {:.1}° at node {v}", angle(ks[0])));
            }
            continue;
        }
        if v == 0 && ks.len() == 1 {
            continue;
        }
        if same.len() > 1 {
            return Err(format!(
                "node {v} continues its chain into {} children",
                same.len()
            ));
        }
        if let [c0] = same[..] {
            // Gravelius: the continuation is straightest and thickest.
            let a0 = angle(c0);
            if a0 > 15.0 {
                return Err(format!("continuation at {v} turns {a0:.1}°"));
            }
            for &c in ks.iter().filter(|&&c| c != c0) {
                if angle(c) < 30.0 || angle(c) > 75.0 || angle(c) <= a0 {
                    return Err(format!("lateral {c} at {v} leaves at {:.1}°", angle(c)));
                }
                if radius(c) > LATERAL_RADIUS_RATIO * radius(c0) * 1.0001 {
                    return Err(format!("lateral {c} at {v} is too thick"));
                }
                if gt.orders[c as usize] != o + 1 {
                    return Err(format!("lateral {c} at {v} is not of order {}", o + 1));
                }
            }
        } else {
            // Weibull: a symmetric fork (or the root's stems).
            let want = if v == 0 { 1 } else { o + 1 };
            let angles: Vec<f32> = ks.iter().map(|&c| angle(c)).collect();
            let radii: Vec<f32> = ks.iter().map(|&c| radius(c)).collect();
            let spread = |xs: &[f32]| {
                let lo = xs.iter().copied().fold(f32::MAX, f32::min);
                let hi = xs.iter().copied().fold(f32::MIN, f32::max);
                (hi - lo) / hi.max(1e-9)
            };
            if ks.iter().any(|&c| gt.orders[c as usize] != want) {
                return Err(format!("fork children of {v} are not of order {want}"));
            }
            if spread(&angles) > 0.03 || spread(&radii) > 0.03 {
                return Err(format!(
                    "fork at {v} is not symmetric: {angles:?} {radii:?}"
                ));
            }
        }
    }
    // Groups: every chain in exactly one, patterns as defined.
    let (chain_of, starts) = chain_ids(tree);
    let mut seen: HashMap<NodeId, usize> = HashMap::new();
    for (g, group) in gt.groups.iter().enumerate() {
        for &c in &group.chains {
            if seen.insert(c, g).is_some() {
                return Err(format!("chain {c} is in two groups"));
            }
        }
        let first = group.chains[0];
        let order = gt.orders[first as usize];
        let parents: Vec<NodeId> = group
            .chains
            .iter()
            .map(|&c| sk.node(c).parent.unwrap())
            .collect();
        if group.chains.iter().any(|&c| gt.orders[c as usize] != order) {
            return Err(format!("group {g} mixes orders"));
        }
        if g == 0 {
            if parents.iter().any(|&p| p != 0) || group.chains.len() != kids(tree, 0).len() {
                return Err("the first group is not the root group".into());
            }
        } else if options.whorl_spread == 0.0 {
            if parents.iter().any(|&p| p != parents[0]) {
                return Err(format!("group {g} grows from several nodes"));
            }
        } else {
            let pc = chain_of[parents[0] as usize];
            if parents.iter().any(|&p| chain_of[p as usize] != pc) {
                return Err(format!("group {g} grows from several parent chains"));
            }
        }
        let k = group.chains.len();
        let axis = incoming(tree, parents[0]);
        let dirs: Vec<Vec3> = group
            .chains
            .iter()
            .zip(&parents)
            .map(|(&c, &p)| out_dir(tree, p, c))
            .collect();
        let expected = match k {
            1 => BranchingPattern::Alternate,
            2 if (divergence(axis, dirs[0], dirs[1]) - 180.0).abs() < 30.0 => {
                BranchingPattern::Opposite
            }
            _ => BranchingPattern::Whorled,
        };
        if group.pattern != expected {
            return Err(format!(
                "group {g}: {:?}, expected {expected:?}",
                group.pattern
            ));
        }
        if k == 2 && group.pattern != BranchingPattern::Opposite {
            return Err(format!("group {g}: a pair that is not opposite"));
        }
        if k >= 3 {
            // Evenly spread: no gap around the axis much wider than 360°/k.
            let reference = (dirs[0] - axis * dirs[0].dot(axis)).normalize();
            let side = axis.cross(reference);
            let mut az: Vec<f32> = dirs
                .iter()
                .map(|d| {
                    d.dot(side)
                        .atan2(d.dot(reference))
                        .to_degrees()
                        .rem_euclid(360.0)
                })
                .collect();
            az.sort_by(f32::total_cmp);
            let gaps = az
                .windows(2)
                .map(|w| w[1] - w[0])
                .chain([360.0 + az[0] - az[k - 1]]);
            let widest = gaps.fold(0.0f32, f32::max);
            if widest > 360.0 / k as f32 + 30.0 {
                return Err(format!("group {g} leaves a {widest:.0}° gap"));
            }
        }
    }
    if seen.len() != starts.len() || starts.iter().any(|s| !seen.contains_key(s)) {
        return Err(format!(
            "{} chains but {} grouped chains",
            starts.len(),
            seen.len()
        ));
    }
    // Leaves: on order ≥ 2, anchored on the bark, sized in centimetres (a
    // few tens of centimetres where a billboard stands for a small cluster,
    // see `foliage::fill_crown`).
    for (i, leaf) in tree.leaves().iter().enumerate() {
        if gt.orders[leaf.branch as usize] < 2 {
            return Err(format!("leaf {i} grows on an order-1 branch"));
        }
        let (a, b) = sk.branch(leaf.branch).unwrap();
        let r = sk.point_on_branch(leaf.branch, leaf.t).1;
        let len = leaf.offset.length();
        if (len - r).abs() > 1e-3 * r.max(1e-3) {
            return Err(format!("leaf {i} is {len} from the axis, radius {r}"));
        }
        if leaf.offset.dot((b - a).normalize()).abs() > 1e-3 * len.max(1e-6) {
            return Err(format!("leaf {i}'s offset is not perpendicular"));
        }
        if !(0.005..0.6).contains(&leaf.height) || !(0.002..0.6).contains(&leaf.width) {
            return Err(format!("leaf {i} is {}×{} m", leaf.width, leaf.height));
        }
    }
    Ok(())
}

/// The checker itself must catch broken trees, or the tests above prove
/// nothing.
#[test]
fn check_tree_catches_tampering() {
    let options = GenerateOptions::new(Preset::Maple, 1).with_size(800);
    let good = generate(&options).unwrap();
    check_tree(&good, &options).unwrap();
    let rebuild = |f: &dyn Fn(&mut TreeParts)| {
        let mut parts = good.clone().into_parts();
        f(&mut parts);
        Tree::new(parts, &Limits::default()).unwrap()
    };
    let gt = good.ground_truth().unwrap();
    // A Gravelius node: the continuation and a lateral.
    let (v, c0, lat) = (1..good.skeleton().len() as NodeId)
        .find_map(|v| {
            let ks = kids(&good, v);
            let o = gt.orders[v as usize];
            let c0 = ks.iter().copied().find(|&c| gt.orders[c as usize] == o)?;
            let lat = ks
                .iter()
                .copied()
                .find(|&c| gt.orders[c as usize] == o + 1)?;
            Some((v, c0, lat))
        })
        .unwrap();
    let broken = [
        rebuild(&|p| {
            let o = p.ground_truth.as_ref().unwrap().orders[v as usize];
            p.ground_truth.as_mut().unwrap().orders[lat as usize] = o;
        }),
        rebuild(&|p| p.nodes[lat as usize].radius = p.nodes[c0 as usize].radius),
        rebuild(&|p| p.nodes[lat as usize].position.y += 5.0),
        rebuild(&|p| {
            let g = &mut p.ground_truth.as_mut().unwrap().groups[3];
            g.pattern = match g.pattern {
                BranchingPattern::Whorled => BranchingPattern::Alternate,
                _ => BranchingPattern::Whorled,
            };
        }),
        rebuild(&|p| {
            p.ground_truth.as_mut().unwrap().groups.pop();
        }),
        rebuild(&|p| p.leaves[0].branch = 1),
        rebuild(&|p| p.leaves[0].offset *= 2.0),
        rebuild(&|p| p.nodes[c0 as usize].radius = p.nodes[v as usize].radius * 1.5),
    ];
    assert!(check_tree(&good, &options.clone().with_size(801)).is_err());
    for (i, tree) in broken.iter().enumerate() {
        // Every tampered tree must still be a valid tree the checker refuses.
        assert!(check_tree(tree, &options).is_err(), "tampering {i} passed");
    }
}

#[test]
fn every_preset_seed_and_size_passes_every_invariant() {
    for &preset in Preset::ALL {
        for seed in SEEDS {
            for size in SIZES {
                let options = GenerateOptions::new(preset, seed).with_size(size);
                let tree = generate(&options).unwrap();
                if let Err(e) = check_tree(&tree, &options) {
                    panic!("{preset} seed {seed} size {size}: {e}");
                }
            }
        }
    }
}

#[test]
fn the_largest_size_is_valid() {
    for preset in [Preset::Conifer, Preset::Dichotomous] {
        let options = GenerateOptions::new(preset, 9).with_size(GenerateOptions::MAX_SIZE);
        let tree = generate(&options).unwrap();
        check_tree(&tree, &options).unwrap();
        assert!(
            tree.leaves().len() > 20_000,
            "{preset}: {}",
            tree.leaves().len()
        );
    }
}

#[test]
fn whorl_spread_puts_group_members_on_consecutive_nodes() {
    for &preset in Preset::ALL {
        let options = GenerateOptions::new(preset, 4)
            .with_size(3_000)
            .with_whorl_spread(0.3);
        let tree = generate(&options).unwrap();
        check_tree(&tree, &options).unwrap_or_else(|e| panic!("{preset}: {e}"));
        let sk = tree.skeleton();
        let gt = tree.ground_truth().unwrap();
        for group in gt.groups.iter().skip(1) {
            let parents: Vec<NodeId> = group
                .chains
                .iter()
                .map(|&c| sk.node(c).parent.unwrap())
                .collect();
            let forked = kids(&tree, parents[0]).len() == group.chains.len();
            if group.chains.len() >= 2 && !forked {
                // Each member on a node of its own, each the continuation of
                // the previous one.
                for w in parents.windows(2) {
                    assert_eq!(sk.node(w[1]).parent, Some(w[0]), "{preset}");
                }
            }
        }
    }
    // Without spreading, members share their node.
    let options = GenerateOptions::new(Preset::Conifer, 4).with_size(3_000);
    let tree = generate(&options).unwrap();
    let gt = tree.ground_truth().unwrap();
    let whorls = gt.groups.iter().filter(|g| g.chains.len() >= 3).count();
    assert!(whorls > 10);
}

#[test]
fn the_same_options_give_the_same_tree_bit_for_bit() {
    for &preset in Preset::ALL {
        for size in [GenerateOptions::MIN_SIZE, 4_000] {
            let options = GenerateOptions::new(preset, 77).with_size(size);
            let a = json::to_vec(&generate(&options).unwrap());
            let b = json::to_vec(&generate(&options).unwrap());
            assert!(a == b, "{preset} size {size} differs between runs");
            let other =
                json::to_vec(&generate(&GenerateOptions::new(preset, 78).with_size(size)).unwrap());
            assert!(a != other, "{preset}: seeds 77 and 78 give the same tree");
        }
    }
    let spread = GenerateOptions::new(Preset::Maple, 5).with_whorl_spread(0.2);
    assert_eq!(generate(&spread).unwrap(), generate(&spread).unwrap());
}

#[test]
fn size_is_exact_across_the_range() {
    for &preset in Preset::ALL {
        for size in [50, 51, 77, 130, 999, 2_345] {
            let tree = gen_tree(preset, 11, size);
            assert_eq!(tree.skeleton().branch_count(), size as usize, "{preset}");
            assert_eq!(tree.skeleton().len(), size as usize + 1);
        }
    }
}

#[test]
fn out_of_range_options_are_refused() {
    let too_small = GenerateOptions::new(Preset::Maple, 1).with_size(GenerateOptions::MIN_SIZE - 1);
    assert_eq!(
        generate(&too_small),
        Err(GenerateError::SizeOutOfRange {
            size: 49,
            min: 50,
            max: 250_000
        })
    );
    for size in [0, GenerateOptions::MAX_SIZE + 1, u32::MAX] {
        let options = GenerateOptions::new(Preset::Shrub, 1).with_size(size);
        assert!(matches!(
            generate(&options),
            Err(GenerateError::SizeOutOfRange { .. })
        ));
    }
    for spread in [-0.1, 0.51, f32::NAN, f32::INFINITY] {
        let options = GenerateOptions::new(Preset::Conifer, 1).with_whorl_spread(spread);
        assert!(
            matches!(
                generate(&options),
                Err(GenerateError::WhorlSpreadOutOfRange { .. })
            ),
            "{spread}"
        );
    }
    let message = too_small.validate().unwrap_err().to_string();
    assert!(message.contains("50..=250000"), "{message}");
}

#[test]
fn presets_parse_by_name_and_errors_list_the_names() {
    assert_eq!(Preset::ALL.len(), 6);
    for &p in Preset::ALL {
        assert_eq!(p.name().parse::<Preset>(), Ok(p));
        assert_eq!(p.name().to_uppercase().parse::<Preset>(), Ok(p));
        assert_eq!(format!(" {p} ").parse::<Preset>(), Ok(p));
        assert!(!p.description().is_empty() && !p.description().contains('\n'));
    }
    let names: Vec<&str> = Preset::ALL.iter().map(|p| p.name()).collect();
    assert_eq!(
        names,
        [
            "eucalyptus",
            "maple",
            "conifer",
            "willow",
            "shrub",
            "dichotomous"
        ]
    );
    let err = "oak".parse::<Preset>().unwrap_err();
    assert_eq!(
        err,
        GenerateError::UnknownPreset {
            name: "oak".into(),
            valid: "eucalyptus, maple, conifer, willow, shrub, dichotomous".into()
        }
    );
    assert!(err.to_string().contains("maple, conifer"), "{err}");
    assert_eq!(
        GenerateOptions::default().size,
        GenerateOptions::DEFAULT_SIZE
    );
}

#[test]
fn leaves_scale_with_size() {
    for &preset in Preset::ALL {
        let counts: Vec<usize> = [50, 1_000, 5_000, 40_000]
            .iter()
            .map(|&s| gen_tree(preset, 5, s).leaves().len())
            .collect();
        assert!(
            counts.windows(2).all(|w| w[0] < w[1]),
            "{preset}: {counts:?}"
        );
        assert!(
            counts[0] >= 25,
            "{preset}: a 50-branch tree has {} leaves",
            counts[0]
        );
        assert!(counts[3] >= 20_000, "{preset}: {counts:?}");
    }
}

#[test]
fn the_smallest_trees_branch_and_carry_leaves() {
    for &preset in Preset::ALL {
        for seed in 0..8 {
            let tree = gen_tree(preset, seed, GenerateOptions::MIN_SIZE);
            let gt = tree.ground_truth().unwrap();
            let max_order = *gt.orders.iter().max().unwrap();
            assert!(max_order >= 2, "{preset} seed {seed}: no laterals");
            assert!(
                gt.groups.len() >= 4,
                "{preset} seed {seed}: {} groups",
                gt.groups.len()
            );
            assert!(tree.leaves().len() >= 25, "{preset} seed {seed}");
            let h = tree.stats().height;
            assert!(h > 0.5, "{preset} seed {seed}: {h} m");
        }
    }
}

#[test]
fn both_leaf_materials_are_used_and_textured() {
    for &preset in Preset::ALL {
        let tree = gen_tree(preset, 6, 3_000);
        let m = tree.materials();
        assert_eq!(m.leaves.len(), 2, "{preset}");
        assert!(m.leaves.iter().all(|l| l.texture.is_some()));
        for k in 0..2 {
            assert!(
                tree.leaves().iter().any(|l| l.material == k),
                "{preset} {k}"
            );
        }
        // Billboards keep their texture's aspect ratio (±10 %).
        let tex = m.leaves[0].texture.as_ref().unwrap();
        let aspect = tex.width() as f32 / tex.height() as f32;
        for leaf in tree.leaves() {
            let a = leaf.width / leaf.height;
            assert!((a / aspect - 1.0).abs() < 0.1, "{preset}: {a} vs {aspect}");
        }
    }
}

/// Position of each leaf along its chain: (index of its branch in the chain
/// + t) / chain length, in (0, 1].
fn leaf_positions(tree: &Tree) -> Vec<f32> {
    let sk = tree.skeleton();
    let (chain_of, starts) = chain_ids(tree);
    let mut len = vec![0u32; starts.len()];
    let mut index = vec![0u32; sk.len()];
    for v in 1..sk.len() {
        let c = chain_of[v] as usize;
        index[v] = len[c];
        len[c] += 1;
    }
    tree.leaves()
        .iter()
        .map(|l| {
            let c = chain_of[l.branch as usize] as usize;
            (index[l.branch as usize] as f32 + l.t) / len[c] as f32
        })
        .collect()
}

#[test]
fn leaves_sit_on_the_outer_part_of_their_chains() {
    for &preset in Preset::ALL {
        let tree = gen_tree(preset, 8, 5_000);
        let pos = leaf_positions(&tree);
        let mean = pos.iter().sum::<f32>() / pos.len() as f32;
        let min = pos.iter().copied().fold(1.0f32, f32::min);
        assert!(min > 0.1, "{preset}: min {min}");
        assert!(mean > 0.65, "{preset}: mean position {mean}");
    }
}

fn height_of(tree: &Tree) -> f32 {
    tree.stats().height
}

#[test]
fn heights_are_those_of_the_species() {
    let expect = |preset: Preset| match preset {
        Preset::Eucalyptus => (14.0, 24.0),
        Preset::Maple => (9.0, 16.0),
        Preset::Conifer => (13.0, 22.0),
        Preset::Willow => (6.5, 12.0),
        Preset::Shrub => (1.8, 4.0),
        Preset::Dichotomous => (5.5, 11.0),
    };
    for &preset in Preset::ALL {
        let (lo, hi) = expect(preset);
        for seed in SEEDS {
            let tree = gen_tree(preset, seed, GenerateOptions::DEFAULT_SIZE);
            let h = height_of(&tree);
            assert!((lo..=hi).contains(&h), "{preset} seed {seed}: {h} m");
        }
        let small = height_of(&gen_tree(preset, 1, 50));
        let big = height_of(&gen_tree(preset, 1, 60_000));
        assert!(small < big, "{preset}: {small} m at 50, {big} m at 60k");
        let sp = species::species(preset);
        assert!(
            big <= sp.height * height_factor(60_000) * 1.3,
            "{preset}: {big}"
        );
    }
}

/// Lateral chains of order 2 growing on the order-1 chain(s): (height of
/// their attachment, chain length in metres).
fn first_laterals(tree: &Tree) -> Vec<(f32, f32)> {
    let sk = tree.skeleton();
    let gt = tree.ground_truth().unwrap();
    let (chain_of, starts) = chain_ids(tree);
    let mut length = vec![0f32; starts.len()];
    for v in 1..sk.len() {
        let (a, b) = sk.branch(v as NodeId).unwrap();
        length[chain_of[v] as usize] += a.distance(b);
    }
    starts
        .iter()
        .enumerate()
        .filter(|&(_, &s)| gt.orders[s as usize] == 2)
        .map(|(c, &s)| {
            let p = sk.node(s).parent.unwrap();
            (sk.node(p).position.y, length[c])
        })
        .collect()
}

#[test]
fn conifer_laterals_shorten_toward_the_top() {
    for seed in SEEDS {
        let tree = gen_tree(Preset::Conifer, seed, 8_000);
        let mut laterals = first_laterals(&tree);
        laterals.sort_by(|a, b| a.0.total_cmp(&b.0));
        let third = laterals.len() / 3;
        let mean = |xs: &[(f32, f32)]| xs.iter().map(|x| x.1).sum::<f32>() / xs.len() as f32;
        let (low, high) = (mean(&laterals[..third]), mean(&laterals[2 * third..]));
        assert!(low > 2.0 * high, "seed {seed}: {low} m low, {high} m high");
        // Whorls of 3–5 along the trunk.
        let gt = tree.ground_truth().unwrap();
        let sk = tree.skeleton();
        let trunk: Vec<_> = gt
            .groups
            .iter()
            .filter(|g| gt.orders[g.chains[0] as usize] == 2)
            .collect();
        assert!(trunk.iter().all(|g| (3..=5).contains(&g.chains.len())));
        assert!(trunk.iter().all(|g| g.pattern == BranchingPattern::Whorled));
        assert!(trunk.iter().all(|g| sk.node(g.chains[0]).parent.is_some()));
    }
}

#[test]
fn each_preset_shows_its_branching_pattern() {
    let histogram = |tree: &Tree, order: u32| {
        let gt = tree.ground_truth().unwrap();
        let mut h = [0usize; 3];
        for g in gt.groups.iter().skip(1) {
            if gt.orders[g.chains[0] as usize] == order {
                h[g.pattern as usize] += 1;
            }
        }
        h
    };
    for seed in SEEDS {
        let e = gen_tree(Preset::Eucalyptus, seed, 5_000);
        let h = histogram(&e, 2);
        assert!(h[0] > 10 && h[1] == 0 && h[2] == 0, "eucalyptus {h:?}");
        let m = gen_tree(Preset::Maple, seed, 5_000);
        let h = histogram(&m, 2);
        assert!(h[1] > 5 && h[0] == 0 && h[2] == 0, "maple {h:?}");
        let h = histogram(&m, 3);
        assert!(h[1] > 20 && h[0] == 0, "maple order 3 {h:?}");
        let c = gen_tree(Preset::Conifer, seed, 5_000);
        let h = histogram(&c, 2);
        assert!(h[2] > 10 && h[0] == 0 && h[1] == 0, "conifer {h:?}");
        let s = gen_tree(Preset::Shrub, seed, 5_000);
        let root = &s.ground_truth().unwrap().groups[0];
        assert!(
            (3..=7).contains(&root.chains.len()),
            "shrub stems {}",
            root.chains.len()
        );
        assert_eq!(root.pattern, BranchingPattern::Whorled);
        let d = gen_tree(Preset::Dichotomous, seed, 5_000);
        let gt = d.ground_truth().unwrap();
        for (v, ks) in (0..d.skeleton().len() as NodeId).map(|v| (v, kids(&d, v))) {
            // Every branching node is a symmetric fork.
            if ks.len() >= 2 {
                assert!(
                    ks.iter()
                        .all(|&c| gt.orders[c as usize] == gt.orders[v as usize] + 1)
                );
            }
        }
        assert!(gt.groups.iter().skip(1).all(|g| g.chains.len() >= 2));
    }
}

#[test]
fn willow_branchlets_hang() {
    for seed in SEEDS {
        let tree = gen_tree(Preset::Willow, seed, 5_000);
        let sk = tree.skeleton();
        let gt = tree.ground_truth().unwrap();
        let (chain_of, starts) = chain_ids(&tree);
        let mut tip = vec![0 as NodeId; starts.len()];
        for v in 1..sk.len() {
            tip[chain_of[v] as usize] = v as NodeId;
        }
        let hanging: Vec<bool> = starts
            .iter()
            .zip(&tip)
            .filter(|&(&s, _)| gt.orders[s as usize] >= 3)
            .map(|(&s, &t)| {
                let base = sk.node(sk.node(s).parent.unwrap()).position;
                let end = sk.node(t).position;
                // Ends below its base and its last branch points down.
                end.y < base.y && incoming(&tree, t).y < -0.5
            })
            .collect();
        let share = hanging.iter().filter(|&&h| h).count() as f32 / hanging.len() as f32;
        assert!(share > 0.8, "seed {seed}: {share} of the branchlets hang");
        // Most leaves point down.
        let down = tree
            .leaves()
            .iter()
            .filter(|l| (l.orientation * Vec3::Y).y < 0.0)
            .count();
        assert!(down as f32 > 0.8 * tree.leaves().len() as f32);
    }
}

#[test]
fn decurrent_crowns_are_wider_than_the_conifer() {
    let shape = |preset: Preset| {
        let s = gen_tree(preset, 2, 8_000).stats();
        let width = (s.bounds[1][0] - s.bounds[0][0]).max(s.bounds[1][2] - s.bounds[0][2]);
        width / s.height
    };
    let conifer = shape(Preset::Conifer);
    assert!(conifer < 0.75, "conifer {conifer}");
    for preset in [
        Preset::Maple,
        Preset::Shrub,
        Preset::Willow,
        Preset::Dichotomous,
    ] {
        let w = shape(preset);
        assert!(
            w > 1.0 && w > conifer * 1.5,
            "{preset}: {w} vs conifer {conifer}"
        );
    }
}

#[test]
fn chains_per_branch_fall_in_the_expected_band() {
    for &preset in Preset::ALL {
        let tree = gen_tree(preset, 3, 20_000);
        let ratio = chain_count(&tree) as f32 / tree.skeleton().branch_count() as f32;
        assert!((0.15..=0.45).contains(&ratio), "{preset}: {ratio}");
    }
}

fn chain_count(tree: &Tree) -> usize {
    tree.ground_truth()
        .unwrap()
        .groups
        .iter()
        .map(|g| g.chains.len())
        .sum()
}

#[test]
fn texture_cache_indices_follow_all() {
    for (i, s) in LeafShape::ALL.iter().enumerate() {
        assert_eq!(*s as usize, i);
        assert_eq!(s.texture().decode().unwrap(), s.draw());
    }
}

/// Regression (found by the property test below in CI): a tiny whorl
/// spread moved group members less than a millimetre along the parent,
/// giving branches shorter than a millimetre.
#[test]
fn a_tiny_whorl_spread_gives_no_sub_millimetre_branches() {
    let options = GenerateOptions::new(Preset::Maple, 0)
        .with_size(50)
        .with_whorl_spread(0.003_310_867_4);
    let tree = generate(&options).unwrap();
    check_tree(&tree, &options).unwrap();
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn random_options_give_valid_consistent_trees(
        preset in proptest::sample::select(Preset::ALL.to_vec()),
        seed in any::<u64>(),
        size in 50u32..2_500,
        spread in prop_oneof![Just(0.0f32), 0.0f32..=0.5],
    ) {
        let options = GenerateOptions::new(preset, seed).with_size(size).with_whorl_spread(spread);
        let tree = generate(&options).unwrap();
        if let Err(e) = check_tree(&tree, &options) {
            panic!("{preset} seed {seed} size {size} spread {spread}: {e}");
        }
    }
}

/// Release-build timings and chain ratios for the report:
/// `cargo test --release -p treemorph-generate -- --ignored --nocapture`.
#[test]
#[ignore]
fn timing() {
    // Warm the texture cache so it is not counted.
    for &p in Preset::ALL {
        let _ = gen_tree(p, 0, 50);
    }
    println!("preset        size   ms(best of 3)  chains  chains/branch  leaves  height");
    for size in [1_000, 5_000, 20_000, 100_000] {
        for &p in Preset::ALL {
            let mut best = f64::MAX;
            let mut tree = None;
            for _ in 0..3 {
                let t = std::time::Instant::now();
                let tr = gen_tree(p, 1, size);
                best = best.min(t.elapsed().as_secs_f64() * 1e3);
                tree = Some(tr);
            }
            let tree = tree.unwrap();
            let chains = chain_count(&tree);
            println!(
                "{:<12} {:>7} {:>10.2} {:>10} {:>10.3} {:>10} {:>7.1}",
                p.name(),
                size,
                best,
                chains,
                chains as f32 / size as f32,
                tree.leaves().len(),
                height_of(&tree)
            );
        }
    }
}

/// Regression: at botanical leaf size a few-thousand-branch crown rendered
/// bare (leaf area index below 1). Billboards are now scaled so the foliage
/// covers the crown.
#[test]
fn foliage_covers_the_crown() {
    for &preset in Preset::ALL {
        let tree = generate(&GenerateOptions::new(preset, 3)).unwrap();
        let shapes: Vec<LeafShape> = species::species(preset)
            .foliage
            .kinds
            .iter()
            .map(|k| k.shape)
            .collect();
        let (mut min, mut max) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let mut area = 0.0;
        for leaf in tree.leaves() {
            let anchor = tree.leaf_anchor(leaf);
            min = min.min(anchor);
            max = max.max(anchor);
            area += leaf.width * leaf.height * shapes[leaf.material as usize].coverage();
        }
        let crown = std::f32::consts::FRAC_PI_4 * (max.x - min.x) * (max.z - min.z);
        let lai = area / crown;
        // Unscaled, these crowns measured 0.1–0.9; weeping and open crowns stay
        // below the 2.5 target because the enlargement is capped.
        assert!(lai >= 0.7, "{preset}: leaf area index {lai}");
    }
}

/// Regression: the needle texture's thin needles covered a fifth of the
/// billboard, so conifers read as bare branches unless seen up close. A
/// spray of needles seen from the side covers most of its outline.
#[test]
fn the_needle_spray_covers_most_of_its_billboard() {
    let coverage = LeafShape::Needles.coverage();
    assert!(coverage >= 0.4, "needle spray coverage {coverage}");
}

/// Every blade keeps its cut-out shape at an eighth of the resolution (a
/// box filter, like the mipmap level a viewer samples for a leaf a few
/// pixels tall), so alpha-tested foliage does not thin out at a distance.
#[test]
fn leaf_textures_keep_their_shape_when_downsampled() {
    for shape in LeafShape::ALL {
        let image = shape.draw();
        let (w, h) = (image.width as usize, image.height as usize);
        let alpha = |x: usize, y: usize| f32::from(image.pixels[(y * w + x) * 4 + 3]) / 255.0;
        let full = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .filter(|&(x, y)| alpha(x, y) >= 0.5)
            .count() as f32
            / (w * h) as f32;
        const F: usize = 8;
        let (qw, qh) = (w / F, h / F);
        let mut kept = 0;
        for qy in 0..qh {
            for qx in 0..qw {
                let mean: f32 = (0..F * F)
                    .map(|k| alpha(qx * F + k % F, qy * F + k / F))
                    .sum::<f32>()
                    / (F * F) as f32;
                kept += usize::from(mean >= 0.5);
            }
        }
        let small = kept as f32 / (qw * qh) as f32;
        assert!(
            small >= 0.75 * full,
            "{}: {:.0} % of texels pass the alpha test at full size, {:.0} % at an eighth",
            shape.name(),
            100.0 * full,
            100.0 * small
        );
    }
}
