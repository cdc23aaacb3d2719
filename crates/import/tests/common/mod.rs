//! Fidelity measures shared by the integration tests: a recovered tree
//! against the generator's tree it came from.

#![allow(dead_code)]

use std::num::NonZero;
use std::path::PathBuf;

use glam::Vec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use treemorph_analysis::{Analysis, AnalysisOptions};
use treemorph_tree::{NodeId, Tree};

/// Nearest-segment queries over a tree's branches.
pub struct Segments {
    tree: ImmutableKdTree<f32, 3>,
    /// (branch, sample) per kd item.
    branch: Vec<NodeId>,
    ends: Vec<(Vec3, Vec3)>,
}

impl Segments {
    pub fn of(tree: &Tree) -> Segments {
        let sk = tree.skeleton();
        let mut samples = Vec::new();
        let mut branch = Vec::new();
        let mut ends = vec![(Vec3::ZERO, Vec3::ZERO); sk.len()];
        let lengths: Vec<f32> = (1..sk.len() as u32)
            .map(|i| {
                let (a, b) = sk.branch(i).unwrap();
                a.distance(b)
            })
            .collect();
        let mut sorted = lengths.clone();
        sorted.sort_by(f32::total_cmp);
        let step = (0.5 * sorted[sorted.len() / 2]).max(1e-4);
        for i in 1..sk.len() as u32 {
            let (a, b) = sk.branch(i).unwrap();
            ends[i as usize] = (a, b);
            let k = ((a.distance(b) / step).ceil() as usize).clamp(1, 2000);
            for j in 0..=k {
                samples.push(a.lerp(b, j as f32 / k as f32).to_array());
                branch.push(i);
            }
        }
        Segments {
            tree: ImmutableKdTree::new_from_slice(&samples),
            branch,
            ends,
        }
    }

    /// Nearest branch to `p` and the distance to it.
    pub fn nearest(&self, p: Vec3) -> (NodeId, f32) {
        let mut best = (0, f32::INFINITY);
        for n in self
            .tree
            .nearest_n::<SquaredEuclidean>(&p.to_array(), NonZero::new(16).unwrap())
        {
            let b = self.branch[n.item as usize];
            let (a, e) = self.ends[b as usize];
            let ab = e - a;
            let s = ((p - a).dot(ab) / ab.length_squared().max(1e-20)).clamp(0.0, 1.0);
            let d = p.distance(a + ab * s);
            if d < best.1 {
                best = (b, d);
            }
        }
        best
    }
}

/// Fraction of the ground truth's branch length that lies within
/// `max(local radius, eps)` of the recovered skeleton.
pub fn coverage(truth: &Tree, recovered: &Tree, eps: f32) -> f32 {
    let index = Segments::of(recovered);
    let sk = truth.skeleton();
    let (mut inside, mut total) = (0.0f64, 0.0f64);
    for i in 1..sk.len() as u32 {
        let (a, b) = sk.branch(i).unwrap();
        let len = a.distance(b);
        let k = 16;
        for j in 0..k {
            let t = (j as f32 + 0.5) / k as f32;
            let (p, r) = sk.point_on_branch(i, t);
            let w = f64::from(len / k as f32);
            total += w;
            if index.nearest(p).1 <= r.max(eps) {
                inside += w;
            }
        }
    }
    (inside / total) as f32
}

/// Chains of the analysis.
pub fn chains(tree: &Tree) -> usize {
    Analysis::of(tree, &AnalysisOptions::default())
        .expect("analysis runs")
        .chains()
        .len()
}

/// Fraction of recovered leaves attached to the right branch: the point
/// the recovered leaf hangs from, mapped to the nearest ground-truth
/// branch, lies on the ground-truth chain of the leaf's own branch (leaves
/// are matched to ground-truth leaves by anchor).
pub fn leaves_on_right_chain(truth: &Tree, recovered: &Tree) -> f32 {
    let analysis = Analysis::of(truth, &AnalysisOptions::default()).expect("analysis runs");
    let anchors: Vec<[f32; 3]> = truth
        .leaves()
        .iter()
        .map(|l| truth.leaf_anchor(l).to_array())
        .collect();
    let leaf_index: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice(&anchors);
    let truth_segments = Segments::of(truth);
    let mut right = 0usize;
    for leaf in recovered.leaves() {
        let anchor = recovered.leaf_anchor(leaf);
        let matched = leaf_index.nearest_one::<SquaredEuclidean>(&anchor.to_array());
        let truth_leaf = &truth.leaves()[matched.item as usize];
        let (hang, _) = recovered.skeleton().point_on_branch(leaf.branch, leaf.t);
        let (branch, _) = truth_segments.nearest(hang);
        if analysis.chain_of_node(branch) == analysis.chain_of_node(truth_leaf.branch) {
            right += 1;
        }
    }
    right as f32 / recovered.leaves().len().max(1) as f32
}

/// Fraction of recovered nodes that lie inside the ground truth's wood (within
/// the local radius of a ground-truth branch, with slack `eps`).
pub fn nodes_inside(truth: &Tree, recovered: &Tree, slack: f32) -> f32 {
    let index = Segments::of(truth);
    let sk = truth.skeleton();
    let inside = recovered
        .skeleton()
        .nodes()
        .iter()
        .filter(|n| {
            let (b, d) = index.nearest(n.position);
            let r = sk
                .node(b)
                .radius
                .max(sk.node(sk.node(b).parent.unwrap()).radius);
            d <= r * (1.0 + slack) + 1e-4
        })
        .count();
    inside as f32 / recovered.skeleton().len() as f32
}

/// The GLB files in `TREEMORPH_THIRD_PARTY_DIR` (the output of
/// `tools/third-party-trees`), sorted by name.
pub fn third_party_files() -> Vec<PathBuf> {
    let dir = PathBuf::from(
        std::env::var("TREEMORPH_THIRD_PARTY_DIR")
            .expect("set TREEMORPH_THIRD_PARTY_DIR to the output of tools/third-party-trees"),
    );
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "glb"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no GLB files in {}", dir.display());
    files
}
