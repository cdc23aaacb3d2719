//! Unit tests of the crate's internals: greedy matching, split and merge
//! weights, support-function Hausdorff distances, Rules 1–3, grow and wilt,
//! the union topology, and input errors.

use glam::Vec3;
use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_tree::{Frame, Tree};

use crate::correspondence::{
    DIRECTIONS, Directions, directions, greedy, hausdorff, support, support_distance,
};
use crate::*;

fn tree(preset: Preset, seed: u64, size: u32) -> (Tree, Analysis) {
    let t = generate(&GenerateOptions::new(preset, seed).with_size(size)).unwrap();
    let a = Analysis::of(&t, &AnalysisOptions::default()).unwrap();
    (t, a)
}

fn plan(a: &(Tree, Analysis), b: &(Tree, Analysis), options: &MorphOptions) -> MorphPlan {
    MorphPlan::new(&a.0, &a.1, &b.0, &b.1, options).unwrap()
}

// ---------------------------------------------------------------- greedy

#[test]
fn greedy_one_to_many_gives_every_element_a_partner() {
    // 2 rows, 4 columns: rows pick their cheapest free columns first, then
    // the two surplus columns attach to their cheapest row.
    let costs = [
        [0.1, 0.9, 0.5, 0.8], //
        [0.7, 0.2, 0.6, 0.3],
    ];
    let mut candidates: Vec<(u32, u32, f32)> = (0..2)
        .flat_map(|i| (0..4).map(move |j| (i as u32, j as u32, costs[i][j])))
        .collect();
    let mut pairs = greedy(&mut candidates, 2, 4, true);
    pairs.sort();
    assert_eq!(
        pairs,
        vec![(0, 0, true), (0, 2, false), (1, 1, true), (1, 3, false)]
    );
    let one = greedy(&mut candidates, 2, 4, false);
    assert_eq!(one.len(), 2);
    assert!(one.iter().all(|p| p.2));
}

#[test]
fn greedy_one_to_many_on_sparse_candidates_covers_both_sides() {
    // Windowed candidate lists may leave phase 1 short: phase 2 attaches
    // every free row and column.
    let mut candidates = vec![(0, 0, 0.5), (1, 0, 0.1), (2, 1, 0.3)];
    let pairs = greedy(&mut candidates, 3, 2, true);
    let rows: Vec<usize> = pairs.iter().map(|p| p.0).collect();
    let cols: Vec<usize> = pairs.iter().map(|p| p.1).collect();
    for r in 0..3 {
        assert!(rows.contains(&r), "row {r} unmatched in {pairs:?}");
    }
    for c in 0..2 {
        assert!(cols.contains(&c), "column {c} unmatched in {pairs:?}");
    }
}

// ------------------------------------------------------- split and merge

#[test]
fn split_and_merge_weights_at_the_key_times() {
    use Operation::*;
    for op in [Morph, Split, Merge, Grow, Wilt] {
        for u in [0.0, 0.1, 0.5, 0.9, 1.0] {
            assert_eq!(point_weight(op, true, u, 0.0), 0.0, "{op:?} u {u}");
            assert_eq!(point_weight(op, true, u, 1.0), 1.0, "{op:?} u {u}");
        }
    }
    // t = 0.5: the base part is u ≤ 0.5 and b = u / 0.5.
    let split = |u| point_weight(Split, true, u, 0.5);
    assert_eq!(split(0.0), 0.0);
    assert!((split(0.25) - 0.25).abs() < 1e-6); // b·t = 0.5·0.5
    assert!((split(0.5) - 0.5).abs() < 1e-6);
    assert!((split(0.8) - 0.5).abs() < 1e-6); // tip part: t
    let merge = |u| point_weight(Merge, true, u, 0.5);
    assert!((merge(0.0) - 1.0).abs() < 1e-6); // min(1, 2t)
    assert!((merge(0.25) - 0.75).abs() < 1e-6); // (2 − 0.5)·0.5
    assert!((merge(0.5) - 0.5).abs() < 1e-6);
    assert!((merge(0.8) - 0.5).abs() < 1e-6);
    // Without the slow-down every copy morphs uniformly.
    assert_eq!(point_weight(Split, false, 0.1, 0.3), 0.3);
    assert_eq!(point_weight(Morph, true, 0.1, 0.3), 0.3);
}

#[test]
fn split_and_merge_weights_are_continuous_and_split_is_monotone() {
    for op in [Operation::Split, Operation::Merge] {
        for k in 1..=40 {
            let u = k as f32 / 40.0;
            let mut last = point_weight(op, true, u, 0.0);
            for i in 1..=4000 {
                let t = i as f32 / 4000.0;
                let w = point_weight(op, true, u, t);
                assert!((0.0..=1.0).contains(&w));
                assert!(
                    (w - last).abs() < 0.02,
                    "{op:?} jumps at u {u} t {t}: {last} → {w}"
                );
                if op == Operation::Split {
                    assert!(w >= last - 1e-6, "split weight decreases at u {u} t {t}");
                }
                last = w;
            }
        }
    }
}

// --------------------------------------------------------------- lobes

#[test]
fn support_distance_is_the_hausdorff_distance_of_convex_sets() {
    let dirs = Directions::new();
    let support = |p: &[Vec3], d: &Directions| support(p, Vec3::ZERO, 1.0, d);
    let cube: Vec<Vec3> = (0..8)
        .map(|i| Vec3::new((i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32))
        .collect();
    let moved: Vec<Vec3> = cube
        .iter()
        .map(|p| *p + Vec3::new(0.3, -0.2, 0.1))
        .collect();
    let (a, b) = (
        support(&cube, &dirs).unwrap(),
        support(&moved, &dirs).unwrap(),
    );
    let exact = Vec3::new(0.3, -0.2, 0.1).length();
    let d = support_distance(&a, &b);
    assert!(d <= exact + 1e-5 && d >= 0.95 * exact, "{d} vs {exact}");
    assert!((hausdorff(&cube, &moved) - exact).abs() < 1e-5);
    // A scaled copy: the body distance never exceeds the vertex distance.
    let big: Vec<Vec3> = cube.iter().map(|p| *p * 1.5).collect();
    let d = support_distance(&a, &support(&big, &dirs).unwrap());
    assert!(d <= hausdorff(&cube, &big) + 1e-5);
    assert!(d > 0.5, "{d}");
    assert!(support(&[], &dirs).is_none());
    let dirs = directions();
    assert_eq!(DIRECTIONS, dirs.len());
    assert!(dirs.iter().all(|d| (d.length() - 1.0).abs() < 1e-5));
}

// ------------------------------------------------------------ rules 1–3

#[test]
fn correspondences_follow_rules_one_to_three() {
    let pairs = [
        (Preset::Eucalyptus, Preset::Shrub),
        (Preset::Maple, Preset::Conifer),
        (Preset::Dichotomous, Preset::Willow),
    ];
    for (x, y) in pairs {
        let a = tree(x, 3, 300);
        let b = tree(y, 4, 300);
        for options in [MorphOptions::default(), MorphOptions::one_to_one()] {
            let p = plan(&a, &b, &options);
            let c = p.correspondence();
            assert_eq!(c.groups[0], [0, 0], "the root groups match first");
            let chain_pair =
                |s: u32, t: u32| c.chains.iter().any(|m| m.source == s && m.target == t);
            let group_pair = |s: u32, t: u32| c.groups.contains(&[s, t]);
            for &[gs, gt] in &c.groups {
                let (g, h) = (a.1.group(gs), b.1.group(gt));
                // Rule 1: one BPTT level.
                assert_eq!(g.level, h.level, "{x:?}→{y:?}");
                // Rule 2: matched parents.
                match (g.parent_chain, h.parent_chain) {
                    (None, None) => {}
                    (Some(ps), Some(pt)) => assert!(chain_pair(ps, pt)),
                    _ => panic!("a root group matched with a non-root group"),
                }
            }
            // Rule 3: chains only inside matched groups.
            for m in &c.chains {
                let (gs, gt) = (a.1.chain(m.source).group, b.1.chain(m.target).group);
                assert!(group_pair(gs, gt), "{m:?} outside matched groups");
            }
            // Every chain is matched, grows or wilts — exactly once as
            // unmatched, and never both.
            for s in 0..a.1.chains().len() as u32 {
                let matched = c.chains.iter().any(|m| m.source == s);
                assert!(matched != c.wilting_chains.contains(&s), "source chain {s}");
            }
            for t in 0..b.1.chains().len() as u32 {
                let matched = c.chains.iter().any(|m| m.target == t);
                assert!(matched != c.growing_chains.contains(&t), "target chain {t}");
            }
            if options.chain_matching == ChainMatching::OneToOne {
                assert!(c.chains.iter().all(|m| m.operation == Operation::Morph));
            }
            // Operations agree with partner counts.
            for m in &c.chains {
                let ns = c.chains.iter().filter(|k| k.source == m.source).count();
                let nt = c.chains.iter().filter(|k| k.target == m.target).count();
                let want = match (ns, nt) {
                    (1, 1) => Operation::Morph,
                    (_, 1) => Operation::Split,
                    (1, _) => Operation::Merge,
                    _ => panic!("a many-to-many chain match {m:?}"),
                };
                assert_eq!(m.operation, want);
            }
        }
    }
}

#[test]
fn a_single_trunk_splits_into_the_stems_of_a_shrub() {
    let a = tree(Preset::Eucalyptus, 1, 600);
    let b = tree(Preset::Shrub, 2, 600);
    let stems = b.1.group(0).chains.len();
    assert!(stems >= 3);
    let ours = plan(&a, &b, &MorphOptions::default());
    let roots: Vec<&UnionChain> = ours
        .chains()
        .iter()
        .filter(|c| c.parent.is_none())
        .collect();
    assert_eq!(roots.len(), stems);
    assert!(
        roots
            .iter()
            .all(|c| c.operation == Operation::Split && c.source == Some(0))
    );
    let primaries = ours
        .correspondence()
        .chains
        .iter()
        .filter(|m| m.source == 0 && m.primary)
        .count();
    assert_eq!(primaries, 1);
    // The baseline grows the extra stems instead.
    let base = plan(&a, &b, &MorphOptions::one_to_one());
    let roots: Vec<Operation> = base
        .chains()
        .iter()
        .filter(|c| c.parent.is_none())
        .map(|c| c.operation)
        .collect();
    assert_eq!(roots.iter().filter(|&&o| o == Operation::Morph).count(), 1);
    assert_eq!(
        roots.iter().filter(|&&o| o == Operation::Grow).count(),
        stems - 1
    );
}

// ------------------------------------------------------ morph operations

/// The polyline of a union chain in a frame.
fn polyline<'f>(p: &MorphPlan, f: &'f Frame, c: usize) -> &'f [Vec3] {
    let r = &p.chains()[c].nodes;
    &f.positions[r.start as usize..r.end as usize]
}

fn length(points: &[Vec3]) -> f32 {
    points.windows(2).map(|w| w[0].distance(w[1])).sum()
}

#[test]
fn growing_and_wilting_chains_go_from_and_to_nothing() {
    let a = tree(Preset::Conifer, 5, 300);
    let b = tree(Preset::Maple, 6, 300);
    let linear = MorphOptions::default().with_schedule(ScheduleOptions::linear());
    let p = plan(&a, &b, &linear);
    let (f0, fh, f1) = (p.frame(0.0), p.frame(0.5), p.frame(1.0));
    let (mut grows, mut wilts) = (0, 0);
    for (i, c) in p.chains().iter().enumerate() {
        let r = c.nodes.start as usize..c.nodes.end as usize;
        let (l0, lh, l1) = (
            length(polyline(&p, &f0, i)),
            length(polyline(&p, &fh, i)),
            length(polyline(&p, &f1, i)),
        );
        match c.operation {
            Operation::Grow => {
                grows += 1;
                assert!(l0 < 1e-6 && f0.radii[r.clone()].iter().all(|&x| x == 0.0));
                let want = b.1.chain(c.target.unwrap()).length;
                assert!((l1 - want).abs() <= 1e-4 * want.max(1.0), "{l1} vs {want}");
                assert!(
                    (lh - 0.5 * want).abs() <= 1e-3 * want.max(1.0),
                    "half grown"
                );
            }
            Operation::Wilt => {
                wilts += 1;
                assert!(l1 < 1e-6 && f1.radii[r.clone()].iter().all(|&x| x == 0.0));
                let want = a.1.chain(c.source.unwrap()).length;
                assert!((l0 - want).abs() <= 1e-4 * want.max(1.0));
                assert!(
                    (lh - 0.5 * want).abs() <= 1e-3 * want.max(1.0),
                    "half wilted"
                );
            }
            _ => {}
        }
    }
    assert!(
        grows > 0 && wilts > 0,
        "the pair exercises both ({grows}, {wilts})"
    );
}

#[test]
fn split_copies_coincide_at_the_start_and_part_from_the_tip() {
    let a = tree(Preset::Eucalyptus, 1, 600);
    let b = tree(Preset::Shrub, 2, 600);
    let linear = MorphOptions::default().with_schedule(ScheduleOptions::linear());
    let p = plan(&a, &b, &linear);
    let copies: Vec<usize> = (0..p.chains().len())
        .filter(|&i| p.chains()[i].parent.is_none())
        .collect();
    let f0 = p.frame(0.0);
    let tip = |f: &Frame, c: usize| *polyline(&p, f, c).last().unwrap();
    for w in copies.windows(2) {
        assert!(tip(&f0, w[0]).distance(tip(&f0, w[1])) < 1e-4);
    }
    // At t = 0.5 the copies' tips have moved half way (weight t) while
    // points near the junction have barely moved (weight b·t ≈ 0).
    let fh = p.frame(0.5);
    let f1 = p.frame(1.0);
    for &c in &copies {
        let line0 = polyline(&p, &f0, c);
        let lineh = polyline(&p, &fh, c);
        let line1 = polyline(&p, &f1, c);
        let near = 1; // the first sample after the junction
        let moved_near =
            line0[near].distance(lineh[near]) / line0[near].distance(line1[near]).max(1e-6);
        assert!(
            moved_near < 0.35,
            "near the junction the copy moved {moved_near}"
        );
    }
    // Without the slow-down the same copies move uniformly.
    let options = MorphOptions {
        slow_down: false,
        ..linear
    };
    let q = plan(&a, &b, &options);
    let (g0, gh, g1) = (q.frame(0.0), q.frame(0.5), q.frame(1.0));
    let c = copies[0];
    let r = q.chains()[c].nodes.start as usize + 1;
    let ratio = g0.positions[r].distance(gh.positions[r])
        / g0.positions[r].distance(g1.positions[r]).max(1e-6);
    assert!(ratio > 0.35, "uniform morph moved the first sample {ratio}");
}

#[test]
fn a_tree_morphed_into_itself_stands_still() {
    let a = tree(Preset::Willow, 7, 250);
    let p = plan(&a, &a, &MorphOptions::default());
    let c = p.correspondence();
    assert!(c.wilting_chains.is_empty() && c.growing_chains.is_empty());
    assert!(
        c.chains
            .iter()
            .all(|m| m.operation == Operation::Morph && m.source == m.target)
    );
    assert!(c.leaves.iter().all(|l| l.source == l.target));
    let f0 = p.frame(0.0);
    let h = p.height();
    for t in [0.25, 0.5, 0.9] {
        let f = p.frame(t);
        for (x, y) in f.positions.iter().zip(&f0.positions) {
            assert!(x.distance(*y) < 1e-5 * h, "moved at t {t}");
        }
        for (x, y) in f.leaves.iter().zip(&f0.leaves) {
            assert!(x.anchor.distance(y.anchor) < 1e-5 * h);
            assert!(x.orientation.dot(y.orientation).abs() > 1.0 - 1e-5);
        }
    }
}

// ------------------------------------------------------ union topology

#[test]
fn the_union_topology_is_one_rooted_tree_of_strands() {
    let a = tree(Preset::Maple, 8, 300);
    let b = tree(Preset::Dichotomous, 9, 300);
    let p = plan(&a, &b, &MorphOptions::default());
    let topo = p.topology();
    let n = topo.node_count();
    assert_eq!(topo.parents[0], None);
    for (i, parent) in topo.parents.iter().enumerate().skip(1) {
        let parent = parent.expect("only the root has no parent") as usize;
        assert!(parent < i, "node {i}'s parent {parent} comes later");
    }
    // Strands are the union chains' node ranges and cover every node but
    // the root once.
    let mut seen = vec![0u32; n];
    assert_eq!(topo.strands.len(), p.chains().len());
    for (s, c) in topo.strands.iter().zip(p.chains()) {
        let want: Vec<u32> = c.nodes.clone().collect();
        assert_eq!(s, &want[..]);
        assert!(s.len() >= 2);
        for w in s.windows(2) {
            assert_eq!(
                topo.parents[w[1] as usize],
                Some(w[0]),
                "strand steps are edges"
            );
        }
        for &x in s {
            seen[x as usize] += 1;
        }
        // The junction hangs off the parent chain (or the root).
        let j = topo.parents[s[0] as usize].unwrap();
        match c.parent {
            None => assert_eq!(j, 0),
            Some(q) => assert!(p.chains()[q as usize].nodes.contains(&j)),
        }
    }
    assert_eq!(seen[0], 0);
    assert!(seen[1..].iter().all(|&k| k == 1));
    // Leaves name a non-junction node of their chain, and material pairs
    // index the union's materials: source first, then target.
    let ms = a.0.materials().leaves.len() as u32;
    for (l, m) in topo.leaves.iter().zip(p.leaf_origins()) {
        assert!(l.node > 0 && (l.node as usize) < n);
        if let Some(s) = m.source {
            assert_eq!(l.materials[0], a.0.leaves()[s as usize].material);
        }
        if let Some(t) = m.target {
            assert_eq!(l.materials[1], b.0.leaves()[t as usize].material + ms);
        }
    }
    assert_eq!(
        topo.leaf_materials.len(),
        a.0.materials().leaves.len() + b.0.materials().leaves.len()
    );
    assert_eq!(topo.bark[0], a.0.materials().bark);
    assert_eq!(topo.bark[1], b.0.materials().bark);
    // Every input leaf appears at least once.
    for (side, count) in [(0, a.0.leaves().len()), (1, b.0.leaves().len())] {
        let mut hit = vec![false; count];
        for m in p.leaf_origins() {
            if let Some(l) = if side == 0 { m.source } else { m.target } {
                hit[l as usize] = true;
            }
        }
        assert!(hit.iter().all(|&h| h), "side {side} lost a leaf");
    }
}

#[test]
fn node_origins_name_the_input_nodes_reproduced_at_the_ends() {
    let a = tree(Preset::Shrub, 10, 250);
    let b = tree(Preset::Eucalyptus, 11, 250);
    let p = plan(&a, &b, &MorphOptions::default());
    let (f0, f1) = (p.frame(0.0), p.frame(1.0));
    let mut covered = [
        vec![false; a.0.skeleton().len()],
        vec![false; b.0.skeleton().len()],
    ];
    for (i, o) in p.node_origins().iter().enumerate() {
        if let Some(n) = o.source {
            covered[0][n as usize] = true;
            let want = a.0.skeleton().node(n).position;
            assert!(f0.positions[i].distance(want) < 1e-5 * p.heights()[0]);
        }
        if let Some(n) = o.target {
            covered[1][n as usize] = true;
            let want = b.0.skeleton().node(n).position;
            assert!(f1.positions[i].distance(want) < 1e-5 * p.heights()[1]);
        }
    }
    assert!(
        covered[0].iter().all(|&c| c),
        "every source node is reproduced"
    );
    assert!(
        covered[1].iter().all(|&c| c),
        "every target node is reproduced"
    );
    let e = p.endpoint_error();
    assert!(e.source < 1e-5 && e.target < 1e-5, "{e:?}");
}

// -------------------------------------------------------------- errors

#[test]
fn bad_inputs_are_refused_with_the_callers_error() {
    let a = tree(Preset::Eucalyptus, 1, 120);
    let b = tree(Preset::Maple, 2, 120);
    let err = MorphPlan::new(&a.0, &b.1, &b.0, &b.1, &MorphOptions::default()).unwrap_err();
    assert!(
        matches!(
            err,
            MorphError::AnalysisMismatch {
                side: Side::Source,
                ..
            }
        ),
        "{err}"
    );
    let err = MorphPlan::new(&a.0, &a.1, &b.0, &a.1, &MorphOptions::default()).unwrap_err();
    assert!(
        matches!(
            err,
            MorphError::AnalysisMismatch {
                side: Side::Target,
                ..
            }
        ),
        "{err}"
    );
    let mut options = MorphOptions::default();
    options.group_weights.outer_lobe = f32::NAN;
    // (`MorphOptions` is non-exhaustive: callers set fields on a default.)
    let err = MorphPlan::new(&a.0, &a.1, &b.0, &b.1, &options).unwrap_err();
    assert_eq!(
        err,
        MorphError::InvalidOption {
            option: "group_weights.outer_lobe",
            reason: "must be a finite number ≥ 0, got NaN".into()
        }
    );
    options = MorphOptions::default();
    options.unmatched_group_cost = -1.0;
    assert!(matches!(
        MorphPlan::new(&a.0, &a.1, &b.0, &b.1, &options),
        Err(MorphError::InvalidOption {
            option: "unmatched_group_cost",
            ..
        })
    ));
}

#[test]
fn out_of_range_times_are_clamped_and_frames_are_resized() {
    let a = tree(Preset::Eucalyptus, 1, 120);
    let b = tree(Preset::Conifer, 2, 120);
    let p = plan(&a, &b, &MorphOptions::default());
    let mut m = Morpher::new(&p);
    let mut f = Frame::of_tree(&a.0); // the wrong size
    m.morph(f32::NAN, &mut f);
    assert_eq!(f.check(p.topology()), Ok(()));
    assert_eq!(f, p.frame(0.0));
    m.morph(7.0, &mut f);
    assert_eq!(f.t, 1.0);
    assert_eq!(f, p.frame(1.0));
    m.morph(-3.0, &mut f);
    assert_eq!(f, p.frame(0.0));
    // A frame of another topology is refused by the meter, not panicked on.
    let small = Frame::of_tree(&a.0);
    assert!(frame_metrics(&p, &small, &MetricsOptions::default()).is_err());
}

#[test]
fn leaf_orientations_stay_unit_quaternions() {
    let a = tree(Preset::Willow, 12, 300);
    let b = tree(Preset::Maple, 13, 300);
    let p = plan(&a, &b, &MorphOptions::default());
    for t in [0.0, 0.3, 0.61, 1.0] {
        for l in &p.frame(t).leaves {
            assert!(
                (l.orientation.length() - 1.0).abs() < 1e-4,
                "{}",
                l.orientation.length()
            );
        }
    }
}

// ------------------------------------------------------------- leaves

#[test]
fn huge_inner_lobes_match_within_a_window_and_cover_every_leaf() {
    use crate::correspondence::{LEAF_WINDOW, LeafFeatures, window_candidates};
    let leaf = |index: u32, param: f32| LeafFeatures {
        index,
        param,
        azimuth: Vec3::X,
        width: 0.05,
        height: 0.1,
        orientation: glam::Quat::IDENTITY,
    };
    // 400 × 300 leaves: beyond the dense limit, so each leaf only looks at
    // its window of nearest parameters.
    let a: Vec<LeafFeatures> = (0..400)
        .map(|i| leaf(i, (i as f32 * 0.618).fract()))
        .collect();
    let b: Vec<LeafFeatures> = (0..300)
        .map(|i| leaf(i, (i as f32 * 0.414).fract()))
        .collect();
    let o = MorphOptions::default();
    let mut candidates = Vec::new();
    window_candidates(&a, &b, false, &mut candidates, &o);
    window_candidates(&b, &a, true, &mut candidates, &o);
    assert!(candidates.len() <= (a.len() + b.len()) * LEAF_WINDOW);
    let pairs = greedy(&mut candidates, a.len(), b.len(), true);
    let mut hit = (vec![false; a.len()], vec![false; b.len()]);
    for &(i, j, _) in &pairs {
        hit.0[i] = true;
        hit.1[j] = true;
        // Partners are near each other along the chain.
        assert!(
            (a[i].param - b[j].param).abs() < 0.1,
            "{} vs {}",
            a[i].param,
            b[j].param
        );
    }
    assert!(hit.0.iter().all(|&h| h) && hit.1.iter().all(|&h| h));
}

#[test]
fn random_leaf_pairs_cover_both_trees() {
    use crate::correspondence::random_leaves;
    let m = random_leaves(5, 3, 1);
    assert_eq!(m.len(), 5);
    let mut s: Vec<u32> = m.iter().map(|x| x.source.unwrap()).collect();
    s.sort();
    assert_eq!(s, vec![0, 1, 2, 3, 4]);
    for t in 0..3 {
        assert!(m.iter().any(|x| x.target == Some(t)));
    }
    assert_ne!(m, random_leaves(5, 3, 2), "the seed matters");
    let lone = random_leaves(0, 2, 1);
    assert_eq!(lone.len(), 2);
    assert!(lone.iter().all(|x| x.source.is_none()));
}

// ----------------------------------------------------- regression tests

/// Regression: split copies used to count the shared trunk once per copy,
/// growing children set OR before they existed, and resampling changed
/// the wood weight, so the MTSW of the frame at t = 0 was not the source
/// tree's (0.74 instead of 0.50 for eucalyptus → shrub).
#[test]
fn mtsw_at_the_ends_is_the_inputs_mtsw() {
    let mtsw = |p: &MorphPlan, t: f32| {
        frame_metrics(p, &p.frame(t), &MetricsOptions::default())
            .unwrap()
            .mtsw
    };
    for (x, y) in [
        (Preset::Eucalyptus, Preset::Shrub),
        (Preset::Conifer, Preset::Maple),
    ] {
        let a = tree(x, 1, 400);
        let b = tree(y, 2, 400);
        let own_a = mtsw(&plan(&a, &a, &MorphOptions::default()), 0.0);
        let own_b = mtsw(&plan(&b, &b, &MorphOptions::default()), 0.0);
        for options in [MorphOptions::default(), MorphOptions::one_to_one()] {
            let p = plan(&a, &b, &options);
            assert!(
                (mtsw(&p, 0.0) - own_a).abs() < 1e-3,
                "{x:?}: {} vs {own_a}",
                mtsw(&p, 0.0)
            );
            assert!(
                (mtsw(&p, 1.0) - own_b).abs() < 1e-3,
                "{y:?}: {} vs {own_b}",
                mtsw(&p, 1.0)
            );
        }
    }
}

/// Regression: samples added inside a chain's first segment took a radius
/// interpolated from the junction node, whose radius is the *parent's*, so
/// resampled chains bulged near their base.
#[test]
fn resampled_chains_do_not_bulge_at_their_base() {
    let a = tree(Preset::Eucalyptus, 1, 400);
    let b = tree(Preset::Conifer, 2, 400);
    let p = plan(&a, &b, &MorphOptions::default());
    for (t, analysis) in [(0.0, &a.1), (1.0, &b.1)] {
        let f = p.frame(t);
        for c in p.chains() {
            let Some(id) = (if t == 0.0 { c.source } else { c.target }) else {
                continue;
            };
            let own = &analysis.chain(id).radii[1..];
            let thickest = own.iter().copied().fold(0.0f32, f32::max);
            let r = c.nodes.start as usize..c.nodes.end as usize;
            for &x in &f.radii[r] {
                assert!(
                    x <= thickest * (1.0 + 1e-5),
                    "radius {x} > the chain's own {thickest}"
                );
            }
        }
    }
}

#[test]
fn options_read_from_partial_json_and_plans_cross_threads() {
    let o: MorphOptions = serde_json::from_str(
        r#"{"chain_matching": "one_to_one", "leaf_morph": {"random_linear": {"seed": 3}},
            "group_weights": {"outer_lobe": 2.0}}"#,
    )
    .unwrap();
    assert_eq!(o.chain_matching, ChainMatching::OneToOne);
    assert_eq!(o.leaf_morph, LeafMorph::RandomLinear { seed: 3 });
    assert_eq!(o.group_weights.outer_lobe, 2.0);
    assert_eq!(
        o.group_weights.divergence,
        GroupCostWeights::default().divergence
    );
    assert!(serde_json::from_str::<MorphOptions>(r#"{"chain_matchin": "one_to_one"}"#).is_err());
    let m: MetricsOptions = serde_json::from_str("{}").unwrap();
    assert_eq!(m, MetricsOptions::default());
    fn send_sync<T: Send + Sync>() {}
    send_sync::<MorphPlan>();
    send_sync::<Morpher<'static>>();
    send_sync::<FrameMeter<'static>>();
}

/// Segment lengths are lerped and directions slerped in the parent's frame,
/// so a morphing chain's length is exactly the lerp of its input lengths —
/// a plain lerp of positions would shrink chains that turn.
#[test]
fn morphing_chains_keep_their_interpolated_length() {
    let a = tree(Preset::Willow, 3, 300);
    let b = tree(Preset::Conifer, 4, 300);
    let linear = MorphOptions::default().with_schedule(ScheduleOptions::linear());
    let p = plan(&a, &b, &linear);
    let mut checked = 0;
    for t in [0.25f32, 0.5, 0.8] {
        let f = p.frame(t);
        for (i, c) in p.chains().iter().enumerate() {
            if c.operation != Operation::Morph {
                continue;
            }
            let (ls, lt) = (
                a.1.chain(c.source.unwrap()).length,
                b.1.chain(c.target.unwrap()).length,
            );
            let want = ls + (lt - ls) * t;
            let got = length(polyline(&p, &f, i));
            assert!(
                (got - want).abs() <= 1e-4 * want.max(1e-3),
                "{got} vs {want}"
            );
            checked += 1;
        }
    }
    assert!(checked > 10);
}
