//! Acceptance on trees from other tools (ez-tree and Modular Tree, written
//! at test time by `tools/third-party-trees` from pinned packages): what a
//! user receives, measured on the meshes we write.
//!
//! - every tree imports with 2,000–15,000 branches;
//! - the imported tree, as written, covers the original bark and no more:
//!   both ways, the 95th percentile of the distances between the two
//!   surfaces is at most 1 % of the tree's height;
//! - every original GLB, frame 0 of every imported tree, every frame of
//!   cross-family morphs and every frame of sketches into six crown shapes:
//!   0 floating leaves and 0 floating branch pieces by the output-level
//!   check (`treemorph_verify`), on the meshes written as the runner
//!   writes them;
//! - morph endpoints equal their inputs: both ways, the 95th percentile of
//!   the written vertices' distances to the input's written vertices is at
//!   most 0.5 % of the tree's height;
//! - morphs keep limbs of one parent apart: in no frame do more than 1 %
//!   of the pairs of pieces that share a parent piece cross
//!   (`CrossingMeter::sibling_crossings`; issue 19);
//! - every sketch's final crown: IoU ≥ 0.8 with the sketch, median ≥ 0.85,
//!   and above the IoU before the job;
//! - every sketch keeps its branches natural: no segment of a chain that
//!   does not wilt stretches by more than 15 % beyond the growth the
//!   sketch asks of its chain (`SketchMetrics::stretch`; the growth is
//!   printed) in any frame, and the
//!   crown's depth/width ratio after the job is within a factor 1.5 of
//!   before (no slab, no wall). The IoU is the sketch pipeline's
//!   measure: the projected leaf blades rasterised on 400 × 400 pixels,
//!   closed and hole-filled, against the filled sketch polygon.
//!
//! Sketches are drawn as an artist would, relative to the crown seen from
//! a camera framing it: a cone, a column, an umbrella, an ellipse, a crown
//! leaning to one side and a heart, each placed over the crown's screen
//! box (the column narrower, the umbrella wider and flatter).
//!
//! ```sh
//! scripts/test third-party   # generates the trees, then runs this test
//! ```
//!
//! `THIRD_PARTY_FRAMES` sets frames per sequence (default 30: every
//! frame's checks and the crossings between frames need the in-betweens;
//! 7 frames missed a sibling share above 1 % that 30 find, and cost
//! 7–14 s less),
//! `THIRD_PARTY_ONLY` limits the run to trees whose name contains it,
//! `THIRD_PARTY_DUMP=DIR` writes each sketch there as a sketch file
//! (`<tree>-<shape>.json`, for `treemorph sketch --sketch`).

mod support;

use std::f32::consts::PI;
use std::fmt::Write as _;
use std::sync::OnceLock;

use glam::{Vec2, Vec3};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use support::{
    Loaded, check_frames, check_frames_and, load_all, max_floating, third_party_dir, write_frames,
};
use treemorph_morph::{MorphOptions, MorphPlan, Morpher};
use treemorph_sketch::{Sketch, SketchMetrics, SketchOptions, SketchPlan, Sketcher, View};
use treemorph_tree::{Frame, FrameTopology, JumpMeter, jump_ratio};
use treemorph_verify::geometry::point_triangle_sq;
use treemorph_verify::{
    CrossingMeter, Plausibility, PlausibilityOptions, Report, SiblingCrossings, read_glb,
};

/// The largest share of pairs of limbs on one parent that may cross in a
/// frame of a morph (issue 19).
const SIBLING_SHARE: f64 = 0.01;

/// The crown shapes every tree is sketched into.
const SHAPES: [&str; 6] = ["cone", "column", "umbrella", "ellipse", "lean", "heart"];

fn frames() -> u32 {
    std::env::var("THIRD_PARTY_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(30)
}

/// Acceptance figures not met yet, one key per line (`tree check` or
/// `source → target check`; `#` starts a comment). A listed failure is
/// reported and tolerated; an unlisted one fails the test, and a listed
/// check that passes is reported so the line can go. The list only
/// shrinks: it is how the issue's remaining work stays visible in CI
/// without turning CI red for figures that were never met.
const SHORTFALLS: &str = include_str!("third_party_shortfalls.txt");

/// What went wrong, keyed, collected so the whole table prints before the
/// test fails.
#[derive(Default)]
struct Failures {
    failed: Vec<(String, String)>,
    passed: Vec<String>,
}

impl Failures {
    /// Records check `key` (see [`SHORTFALLS`]) with `what` describing a
    /// failure.
    fn check(&mut self, key: String, ok: bool, what: impl FnOnce() -> String) {
        if ok {
            self.passed.push(key);
        } else {
            self.failed.push((key, what()));
        }
    }

    /// Records check `<label> floating`: no floating leaf or piece in any
    /// of the sequence's `reports`. Returns the most of each in a frame.
    fn check_floating(&mut self, label: &str, reports: &[Report]) -> (u32, u32) {
        let (fl, fb, gap) = max_floating(reports);
        self.check(format!("{label} floating"), fl == 0 && fb == 0, || {
            let per: Vec<String> = reports
                .iter()
                .map(|r| format!("{}/{}", r.floating_leaves, r.floating_branches))
                .collect();
            format!(
                "{label}: floating leaves/pieces per frame {} (worst gap {gap:.3} m)",
                per.join(" ")
            )
        });
        (fl, fb)
    }

    /// Prints the known shortfalls and the fixed ones; panics listing the
    /// failures the list does not name.
    fn assert_none_new(self) {
        let known: Vec<&str> = SHORTFALLS
            .lines()
            .map(|l| l.split('#').next().unwrap_or("").trim())
            .filter(|l| !l.is_empty())
            .collect();
        let (tolerated, new): (Vec<_>, Vec<_>) = self
            .failed
            .into_iter()
            .partition(|(key, _)| known.contains(&key.as_str()));
        for (_, what) in &tolerated {
            eprintln!("known shortfall: {what}");
        }
        for key in self.passed.iter().filter(|k| known.contains(&k.as_str())) {
            eprintln!("now met, remove from third_party_shortfalls.txt: {key}");
        }
        let new: Vec<String> = new
            .into_iter()
            .map(|(key, what)| format!("[{key}] {what}"))
            .collect();
        assert!(
            new.is_empty(),
            "{} failures:\n{}",
            new.len(),
            new.join("\n")
        );
    }
}

#[test]
#[ignore = "needs TREEMORPH_THIRD_PARTY_DIR written by tools/third-party-trees"]
fn third_party_trees_meet_the_acceptance_figures() {
    let only = std::env::var("THIRD_PARTY_ONLY").unwrap_or_default();
    let trees: Vec<Loaded> = load_all(&third_party_dir())
        .into_iter()
        .filter(|t| t.name.contains(&only))
        .collect();
    assert!(!trees.is_empty(), "no trees in TREEMORPH_THIRD_PARTY_DIR");
    let mut failures = Failures::default();
    let mut table = String::new();
    writeln!(
        table,
        "| tree | family | branches | leaves | import p95 wood→bark / bark→wood (% h) | frame 0 fl/fb | morph → | morph max fl/fb | endpoint p95 (% h) | sibling crossings (%) | jump ratio | skinned error (% h) | second morph → | max fl/fb | endpoint p95 (% h) | sibling crossings (%) | jump ratio | skinned error (% h) | {} |",
        SHAPES.join(" IoU before → after (max fl/fb) | ")
    )
    .unwrap();
    // One tree per task: the trees are independent, and CI has two cores.
    let own: OwnSurfaces = trees.iter().map(|_| OnceLock::new()).collect();
    let rows: Vec<(String, Failures, Vec<f32>)> = (0..trees.len())
        .into_par_iter()
        .map(|k| tree_results(&trees, &own, k))
        .collect();
    let mut ious = Vec::new();
    for (row, tree_failures, tree_ious) in rows {
        writeln!(table, "{row}").unwrap();
        failures.failed.extend(tree_failures.failed);
        failures.passed.extend(tree_failures.passed);
        ious.extend(tree_ious);
    }
    eprintln!("{table}");
    ious.sort_by(f32::total_cmp);
    if !ious.is_empty() {
        let median = ious[ious.len() / 2];
        eprintln!(
            "final IoU over {} sketches: min {:.3}, median {median:.3}",
            ious.len(),
            ious[0]
        );
        failures.check("median iou".into(), median >= 0.85, || {
            format!("median final IoU {median:.3} < 0.85")
        });
    }
    failures.assert_none_new();
}

/// Tree `k`'s table row, its checks and its sketches' final IoUs.
fn tree_results(trees: &[Loaded], own: &OwnSurfaces, k: usize) -> (String, Failures, Vec<f32>) {
    let tree = &trees[k];
    let mut failures = Failures::default();
    let mut row = tree_row(tree, own_surface(tree, &own[k]), &mut failures);
    let ends = |j: usize| Ends {
        source: (tree, own_surface(tree, &own[k])),
        target: (&trees[j], own_surface(&trees[j], &own[j])),
    };
    row += &morph_cell(partner(trees, k, 0).map(ends), true, &mut failures);
    row += &morph_cell(partner(trees, k, 3).map(ends), false, &mut failures);
    let mut ious = Vec::new();
    for shape in SHAPES {
        let (cell, iou) = sketch_cell(tree, shape, &mut failures);
        row += &cell;
        ious.extend(iou);
    }
    (row, failures, ious)
}

/// The tree's own columns: its size, its original GLB's check and frame 0
/// of the imported tree, written.
fn tree_row(t: &Loaded, own: &OwnSurface, failures: &mut Failures) -> String {
    let branches = t.tree.stats().branches;
    failures.check(
        format!("{} size", t.name),
        (2_000..=15_000).contains(&branches),
        || {
            format!(
                "{}: {branches} branches, not 2,000–15,000: the set does not test the sizes asked for",
                t.name
            )
        },
    );
    let options = PlausibilityOptions::default();
    let original = Plausibility::of(&read_glb(&t.bytes).unwrap().view(), &options).unwrap();
    failures.check(
        format!("{} original floating", t.name),
        original.floating_leaves == 0 && original.floating_branches == 0,
        || {
            format!(
                "{}: the generator's own GLB floats {} leaves / {} pieces: the set is not a fair test",
                t.name, original.floating_leaves, original.floating_branches
            )
        },
    );
    let zero = check_frames(&FrameTopology::of_tree(&t.tree), 1, |time, f| {
        *f = Frame::of_tree(&t.tree);
        f.t = time;
    });
    let (fl, fb, gap) = max_floating(&zero);
    let (extra, lost) = import_fidelity(t, own);
    failures.check(
        format!("{} import fidelity", t.name),
        extra <= 1.0 && lost <= 1.0,
        || {
            format!(
                "{}: the imported tree's written wood is {extra:.2} % of its height from the original bark, \
                 the bark {lost:.2} % from the wood (p95)",
                t.name
            )
        },
    );
    failures.check(
        format!("{} frame 0 floating", t.name),
        fl == 0 && fb == 0,
        || {
            format!(
                "{}: frame 0 floats {fl} leaves (worst gap {gap:.3} m) / {fb} pieces",
                t.name
            )
        },
    );
    format!(
        "| {} | {} | {} | {} | {extra:.2} / {lost:.2} | {fl}/{fb} |",
        t.name,
        t.family.name(),
        t.tree.skeleton().len() - 1,
        t.tree.leaves().len()
    )
}

/// How far the imported tree's wood, as written, is from the original
/// GLB's bark (tubes fatter than the bark, or wood where there was none)
/// and the bark from the wood (bark the skeleton lost): the directed
/// 95th-percentile surface distances, in percent of the tree's height.
fn import_fidelity(t: &Loaded, own: &OwnSurface) -> (f32, f32) {
    let original = read_glb(&t.bytes).unwrap();
    let bark = triangles(&original.branch_positions, &original.branch_indices);
    let bark_to_wood = p95_distance(&bark, &own.branches);
    let wood_to_bark = p95_distance(&own.branches.triangles, &Sampled::new(bark, own.step));
    (
        100.0 * wood_to_bark / own.height,
        100.0 * bark_to_wood / own.height,
    )
}

/// A morph partner of tree `k`: a tree of the other family, `shift`
/// places along, so every tree is a source once per shift and the pairs
/// are cross-family. Two shifts: a staged morph once floated leaves only
/// on pairs the first shift did not make (mt-sparse → oak-large).
fn partner(trees: &[Loaded], k: usize, shift: usize) -> Option<usize> {
    let others: Vec<usize> = (0..trees.len())
        .filter(|&j| trees[j].family != trees[k].family)
        .collect();
    (!others.is_empty()).then(|| others[(k + shift) % others.len()])
}

/// A morph cell's two trees, each with its own written surface.
struct Ends<'a> {
    source: (&'a Loaded, &'a OwnSurface),
    target: (&'a Loaded, &'a OwnSurface),
}

/// Morphs the source of `ends` into its target: floating parts on every
/// frame and the endpoints against the inputs, and with `skinned` the skinned
/// animation's error. The skinned check runs on the first shift's pairs
/// only: every tree is a source there once, and its fit and encoding
/// cost as much as the rest of the cell (the check took about 90 s of CI
/// on all 20 pairs).
fn morph_cell(ends: Option<Ends>, skinned: bool, failures: &mut Failures) -> String {
    let Some(Ends {
        source: (source, source_surface),
        target: (target, target_surface),
    }) = ends
    else {
        return " — | — | — | — | — | — |".into();
    };
    let label = format!("{} → {}", source.name, target.name);
    let plan = MorphPlan::new(
        &source.tree,
        &source.analysis,
        &target.tree,
        &target.analysis,
        &MorphOptions::default(),
    );
    let plan = match plan {
        Ok(plan) => plan,
        Err(e) => {
            failures.check(format!("{label} plan"), false, || {
                format!("{label}: plan failed: {e}")
            });
            return format!(" {} | plan failed | — |", target.name);
        }
    };
    let mut morpher = Morpher::new(&plan);
    let (reports, siblings, jumps) = check_and_cross(plan.topology(), &mut morpher);
    let (fl, fb) = failures.check_floating(&label, &reports);
    let start = endpoint_p95(plan.topology(), &mut morpher, 0.0, source_surface);
    let end = endpoint_p95(plan.topology(), &mut morpher, 1.0, target_surface);
    for (which, p) in [("start", start), ("end", end)] {
        failures.check(format!("{label} {which} endpoint"), p <= 0.5, || {
            format!("{label}: {which} frame's p95 distance to its input is {p:.2} % of height")
        });
    }
    let siblings_cell = format!(
        "{:.3} ({} of {})",
        100.0 * siblings.share(),
        siblings.most(),
        siblings.pairs
    );
    failures.check(
        format!("{label} sibling crossings"),
        siblings.share() <= SIBLING_SHARE,
        || format!("{label}: sibling crossings {siblings_cell} %, above 1 % of the pairs"),
    );
    let jumps = jump_ratio(&jumps);
    failures.check(
        format!("{label} jump ratio"),
        jumps <= MAX_JUMP_RATIO,
        || format!("{label}: the largest move in a frame is {jumps:.2} times the median one"),
    );
    let skin = if skinned {
        skinned_cell(&label, plan.topology(), &mut morpher, failures)
    } else {
        "—".into()
    };
    format!(
        " {} | {fl}/{fb} | {start:.3} / {end:.3} | {siblings_cell} | {jumps:.2} | {skin} |",
        target.name
    )
}

/// The plausibility reports of every frame of a morph, written as the
/// runner writes them, the crossings between limbs of one parent in the
/// same frames (checked against [`SIBLING_SHARE`]) and how far each frame
/// moved from the one before ([`JumpMeter`]).
fn check_and_cross(
    topology: &FrameTopology,
    morpher: &mut Morpher,
) -> (Vec<Report>, SiblingCrossings, Vec<f32>) {
    let mut meter = CrossingMeter::new();
    let (mut jump, mut jumps) = (JumpMeter::default(), Vec::new());
    let reports = check_frames_and(
        topology,
        frames(),
        |t, f| morpher.morph(t, f),
        |frame| {
            meter.push(&topology.strands, frame);
            jumps.push(jump.jump(frame));
        },
    );
    let siblings = meter.sibling_crossings(&topology.strand_parents());
    (reports, siblings, jumps)
}

/// The largest move of a node or leaf corner in one frame, over the
/// median one, accepted on a morph between trees of the two families:
/// issue 19's 2. In the 60 frames of a job, 15 of the 50 pairs between
/// the families were above it (bush-1 → mt-bushy at 11.2): a limb
/// anchored between two sample frames that turned opposite ways jumped
/// (now they turn alike, `frame_arc` in the morph crate), and bursts of
/// motion narrower than the pace's 64 samples bunched into a few frames
/// (now such a motion is sampled 4 times as finely, `Pace::concentrated`).
/// With tip-first subtrees kept off their hosts' reshape, all 50 are at
/// 1.05–1.50, and this test's 20 pairs (30 frames) at 1.12–1.34.
const MAX_JUMP_RATIO: f32 = 2.0;

/// The skinned animation's error as a table cell, checked against
/// [`MAX_SKINNED_ERROR`].
fn skinned_cell(
    label: &str,
    topology: &FrameTopology,
    morpher: &mut Morpher,
    failures: &mut Failures,
) -> String {
    let skin = skinned_error(topology, morpher);
    failures.check(
        format!("{label} skinned"),
        skin <= MAX_SKINNED_ERROR,
        || {
            format!(
                "{label}: the skinned animation's largest vertex error is {:.1} % of height",
                100.0 * skin
            )
        },
    );
    format!("{:.1} %", 100.0 * skin)
}

/// The largest skinned-animation error (fraction of height) accepted on
/// a morph between trees of the two families. A regression bound, not
/// the 1 % aim: 256 rigid joints and 16 residual targets do not follow
/// every such morph that closely (0.5–4.7 % measured on the CI set).
/// Before residual targets were chosen by the error a player shows,
/// ash-large → mt-broadleaf reached 41 %; before a residual was fitted
/// with 12 targets when 4 miss the budget, bush-1 → mt-sparse and
/// mt-weeping → bush-1 reached 15.8 % and 14.5 %; while the samples
/// where a joint's scale was below 0.05 were left out of the residual's
/// fit, the CI set was at 1.4–9.3 % (this bound was 12 %), and then at
/// 0.6–2.4 % (4 %) until untangling shed and regrew the blends that
/// cross: bush-1 → mt-sparse went 2.4 → 4.7 % (its twigs that wilt and
/// those that regrow share joints; 3.5 % at 1,024 joints, 2.3 % with one
/// per chain), while six of the ten pairs came nearer.
const MAX_SKINNED_ERROR: f32 = 0.05;

/// The error the default skinned animation (256 joints, meshopt) of the
/// morph's 60 frames reports: measured as a player composes the file.
fn skinned_error(topology: &FrameTopology, morpher: &mut Morpher) -> f32 {
    let frames: Vec<Frame> = (0..60)
        .map(|i| {
            let mut f = Frame::default();
            morpher.morph(i as f32 / 59.0, &mut f);
            f
        })
        .collect();
    let radii = treemorph_gltf::frames::max_radii(&frames);
    let bounds = frames.iter().fold(treemorph_tree::Aabb::EMPTY, |b, f| {
        b.union(
            treemorph_tree::Aabb::of_points(f.points())
                .inflated(radii.iter().copied().fold(0.0, f32::max)),
        )
    });
    let options = treemorph_gltf::animated::AnimatedOptions::default()
        .with_keyframes(frames.len())
        .with_encoding(treemorph_gltf::animated::AnimatedEncoding::Meshopt);
    let mut builder =
        treemorph_gltf::basis::BasisGlbBuilder::new(topology, &radii, bounds, &options)
            .expect("a skinned animation of a plan's topology")
            .skinned();
    for f in &frames {
        builder.push(f).expect("a morph's frame");
    }
    builder.finish().expect("the skinned animation").1.max_error
}

/// The larger of the directed 95th-percentile distances between the
/// morph's frame at `t` and `input`'s own frame, both as written: from
/// each non-degenerate triangle's centroid to the other mesh's surface,
/// branches to branches and leaves to leaves, in percent of the input's
/// height. Degenerate triangles are the collapsed parts a morph keeps for
/// the other tree; they are not surface either tree shows.
fn endpoint_p95(topology: &FrameTopology, morpher: &mut Morpher, t: f32, own: &OwnSurface) -> f32 {
    let morphed = written_surface(topology, t, &mut |time, f| morpher.morph(time, f));
    let step = own.step;
    let worst = [(morphed.0, &own.branches), (morphed.1, &own.leaves)]
        .into_iter()
        .flat_map(|(a, b)| {
            let there = p95_distance(&a, b);
            [there, p95_distance(&b.triangles, &Sampled::new(a, step))]
        })
        .fold(0.0f32, f32::max);
    100.0 * worst / own.height
}

type Triangles = Vec<[Vec3; 3]>;

/// An input tree's own frame as written, branches and leaves sampled for
/// [`p95_distance`]. A tree alone is still, so its frame is the same at
/// both ends of a sequence; it is built once per tree and shared by every
/// morph that starts or ends on it. Each cell sampled and indexed both
/// of its trees again before: three trees' rows took 55 s then, 47 s now,
/// with the same figures.
struct OwnSurface {
    branches: Sampled,
    leaves: Sampled,
    height: f32,
    /// The sampling step, 0.25 % of the height.
    step: f32,
}

/// Per tree, its [`OwnSurface`] once a morph needs it.
type OwnSurfaces = Vec<OnceLock<OwnSurface>>;

/// `input`'s own surface, built on first use.
fn own_surface<'a>(input: &Loaded, slot: &'a OnceLock<OwnSurface>) -> &'a OwnSurface {
    slot.get_or_init(|| {
        let (branches, leaves) =
            written_surface(&FrameTopology::of_tree(&input.tree), 0.0, &mut |time, f| {
                *f = Frame::of_tree(&input.tree);
                f.t = time;
            });
        let height = input.tree.stats().height;
        let step = 0.0025 * height;
        OwnSurface {
            branches: Sampled::new(branches, step),
            leaves: Sampled::new(leaves, step),
            height,
            step,
        }
    })
}

/// A surface with points sampled over it at most `step` apart, indexed
/// for nearest-point queries, each point with its triangle.
struct Sampled {
    triangles: Triangles,
    owner: Vec<u32>,
    /// `None` for an empty surface.
    index: Option<ImmutableKdTree<f32, 3>>,
}

impl Sampled {
    fn new(triangles: Triangles, step: f32) -> Sampled {
        let (points, owner) = surface_samples(&triangles, step);
        let index = (!points.is_empty()).then(|| ImmutableKdTree::new_from_slice(&points));
        Sampled {
            triangles,
            owner,
            index,
        }
    }
}

/// The non-degenerate triangles of a mesh.
fn triangles(positions: &[Vec3], indices: &[u32]) -> Triangles {
    indices
        .chunks_exact(3)
        .map(|c| [0, 1, 2].map(|k| positions[c[k] as usize]))
        .filter(|[a, b, c]| (*b - *a).cross(*c - *a).length_squared() > 1e-14)
        .collect()
}

/// The non-degenerate branch and leaf triangles of a sequence's frame at
/// `t` (0 or 1), written as the runner writes it.
fn written_surface(
    topology: &FrameTopology,
    t: f32,
    eval: &mut dyn FnMut(f32, &mut Frame),
) -> (Triangles, Triangles) {
    let mut surface = (Vec::new(), Vec::new());
    write_frames(
        topology,
        2,
        |time, f| eval(time, f),
        |frame, view| {
            if frame.t == t {
                surface = (
                    triangles(view.branch_positions, view.branch_indices),
                    triangles(view.leaf_positions, view.leaf_indices),
                );
            }
        },
    );
    surface
}

/// The 95th percentile over the centroids of `from` of the distance to
/// the surface `to`: exact to the triangles owning the 16 nearest of
/// points sampled over `to` at most `step` apart (vertices, and a
/// barycentric grid on large triangles: a long tube segment's centroid is
/// far from most of its surface). An upper bound only where a triangle
/// with none of those samples would be nearer.
fn p95_distance(from: &[[Vec3; 3]], to: &Sampled) -> f32 {
    let index = match &to.index {
        Some(index) if !from.is_empty() => index,
        _ if from.is_empty() && to.triangles.is_empty() => return 0.0,
        _ => return f32::INFINITY,
    };
    let (owner, to) = (&to.owner, &to.triangles);
    let k = std::num::NonZero::new(16).unwrap();
    let mut d: Vec<f32> = from
        .iter()
        .map(|t| {
            let p = (t[0] + t[1] + t[2]) / 3.0;
            index
                .nearest_n::<SquaredEuclidean>(&p.to_array(), k)
                .iter()
                .map(|n| point_triangle_sq(p, to[owner[n.item as usize] as usize]))
                .fold(f32::INFINITY, f32::min)
                .sqrt()
        })
        .collect();
    d.sort_by(f32::total_cmp);
    d[(d.len() - 1) * 95 / 100]
}

/// Points on every triangle at most about `step` apart (at most 8
/// divisions per edge), each with its triangle's index.
fn surface_samples(triangles: &[[Vec3; 3]], step: f32) -> (Vec<[f32; 3]>, Vec<u32>) {
    let (mut points, mut owner) = (Vec::new(), Vec::new());
    for (i, t) in triangles.iter().enumerate() {
        let longest = t[0]
            .distance(t[1])
            .max(t[1].distance(t[2]))
            .max(t[2].distance(t[0]));
        let n = ((longest / step).ceil() as usize).clamp(1, 8);
        for a in 0..=n {
            for b in 0..=n - a {
                let (u, v) = (a as f32 / n as f32, b as f32 / n as f32);
                points.push((t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v).to_array());
                owner.push(i as u32);
            }
        }
        points.push(((t[0] + t[1] + t[2]) / 3.0).to_array());
        owner.push(i as u32);
    }
    (points, owner)
}

/// Sketches `t` into `shape`: floating parts on every frame and the crown
/// fit before and after. Returns the cell and the final IoU.
fn sketch_cell(t: &Loaded, shape: &str, failures: &mut Failures) -> (String, Option<f32>) {
    let label = format!("{} {shape}", t.name);
    let (view, sketch) = crown_sketch(t, shape);
    if let Ok(dir) = std::env::var("THIRD_PARTY_DUMP") {
        dump_sketch(&dir, &label.replace(' ', "-"), &view, &sketch);
    }
    let mut options = SketchOptions::default();
    options.raster_size = 400;
    let plan = match SketchPlan::new(&t.tree, &t.analysis, &view, &sketch, &options) {
        Ok(plan) => plan,
        Err(e) => {
            failures.check(format!("{label} plan"), false, || {
                format!("{label}: plan failed: {e}")
            });
            return (" plan failed |".into(), None);
        }
    };
    let mut sketcher = Sketcher::new(&plan);
    let reports = check_frames(plan.topology(), frames(), |time, f| {
        sketcher.deform(time, f)
    });
    let (fl, fb) = failures.check_floating(&label, &reports);
    let lows: Vec<f32> = support::times(frames())
        .map(|time| {
            let frame = sketcher.frame(time);
            frame
                .positions
                .iter()
                .map(|p| p.y)
                .fold(f32::INFINITY, f32::min)
        })
        .collect();
    check_sweep(&label, &lows, t.tree.stats().height, failures);
    let mut metrics = SketchMetrics::new(&plan);
    // The rest frame measured against the sketched crown: the fit before.
    let mut before = sketcher.frame(0.0);
    before.t = 1.0;
    let before = metrics.shape(&before).iou;
    let last = sketcher.frame(1.0);
    let after = metrics.shape(&last).iou;
    let stretch = support::times(frames())
        .map(|time| metrics.stretch(&sketcher.frame(time)))
        .fold(0.0f32, f32::max);
    let growth = metrics.growth(&last);
    let depth_width = (
        metrics.crown_depth_width(plan.rest_frame()),
        metrics.crown_depth_width(&last),
    );
    eprintln!(
        "{label}: max_stretch {:.1} %, chain growth {:.0} %, crown depth/width {:.2} → {:.2}",
        100.0 * stretch,
        100.0 * growth,
        depth_width.0,
        depth_width.1
    );
    failures.check(format!("{label} stretch"), stretch <= 0.15, || {
        format!(
            "{label}: a branch segment stretched by {:.0} %",
            100.0 * stretch
        )
    });
    let depth_change = depth_width.1 / depth_width.0;
    failures.check(
        format!("{label} depth"),
        (1.0 / 1.5..=1.5).contains(&depth_change),
        || {
            format!(
                "{label}: crown depth/width {:.2} → {:.2}",
                depth_width.0, depth_width.1
            )
        },
    );
    failures.check(format!("{label} iou"), after >= 0.8, || {
        format!("{label}: final IoU {after:.3} < 0.8")
    });
    failures.check(format!("{label} iou gain"), after > before, || {
        format!("{label}: IoU fell from {before:.3} to {after:.3}")
    });
    (
        format!(" {before:.2} → {after:.2} ({fl}/{fb}) |"),
        Some(after),
    )
}

/// Regression: segments turned in their parent's frame compounded their
/// turns down deep chains of short segments: a twig of `mt-tall` sketched
/// into a heart swept 20.7 % of the height below the ground at t = 0.4,
/// though neither end put it lower than 18.5 %. No frame's lowest node
/// (`lows`, per frame, ends included) may be more than 1 % of the
/// `height` below both ends' (an arc between two directions can dip a
/// little below both).
fn check_sweep(label: &str, lows: &[f32], height: f32, failures: &mut Failures) {
    let (Some(first), Some(last)) = (lows.first(), lows.last()) else {
        return;
    };
    let lowest = lows.iter().copied().fold(f32::INFINITY, f32::min);
    let sweep = (first.min(*last) - lowest) / height;
    failures.check(format!("{label} sweep"), sweep <= 0.01, || {
        format!(
            "{label}: a frame in between reaches {:.1} % of the height below both ends",
            100.0 * sweep
        )
    });
}

/// A camera framing the tree's crown from the front (+Z, Y up, 35°
/// perspective, the crown filling about 60 % of the screen), and `shape`
/// drawn over the crown's screen box.
/// Writes a sketch file (the CLI's `--sketch` format) to `dir/name.json`.
fn dump_sketch(dir: &str, name: &str, view: &View, sketch: &Sketch) {
    let points: Vec<[f32; 2]> = sketch.points.iter().map(|p| [p.x, p.y]).collect();
    let file = serde_json::json!({ "view": view, "closed": sketch.closed, "points": points });
    std::fs::write(format!("{dir}/{name}.json"), file.to_string()).unwrap();
}

fn crown_sketch(t: &Loaded, shape: &str) -> (View, Sketch) {
    let rest = Frame::of_tree(&t.tree);
    let (lo, hi) = rest.leaves.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), l| (lo.min(l.anchor), hi.max(l.anchor)),
    );
    let centre = 0.5 * (lo + hi);
    let extent = (hi - lo).max_element().max(1e-3);
    let fov = 35.0f32;
    let distance = 0.5 * extent / 0.6 / (0.5 * fov.to_radians()).tan() + 0.5 * (hi.z - lo.z);
    let view = View::perspective(centre + Vec3::Z * distance, centre, Vec3::Y, fov);
    let camera = view.camera().unwrap();
    let (blo, bhi) = rest.leaves.iter().fold(
        (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
        |(lo, hi), l| {
            let p = camera.project(l.anchor).0;
            (lo.min(p), hi.max(p))
        },
    );
    let points = unit_shape(shape)
        .into_iter()
        .map(|u| place(shape, u, blo, bhi))
        .collect();
    (
        view,
        Sketch {
            points,
            closed: true,
        },
    )
}

/// `shape` as a counter-clockwise polygon in the unit box [-1, 1]².
fn unit_shape(shape: &str) -> Vec<Vec2> {
    let ring = |n: usize, f: &dyn Fn(f32) -> Vec2| -> Vec<Vec2> {
        (0..n).map(|i| f(2.0 * PI * i as f32 / n as f32)).collect()
    };
    match shape {
        "cone" => vec![
            Vec2::new(-1.0, -1.0),
            Vec2::new(1.0, -1.0),
            Vec2::new(0.0, 1.0),
        ],
        "column" => vec![
            Vec2::new(-1.0, -1.0),
            Vec2::new(1.0, -1.0),
            Vec2::new(1.0, 0.75),
            Vec2::new(0.5, 1.0),
            Vec2::new(-0.5, 1.0),
            Vec2::new(-1.0, 0.75),
        ],
        "umbrella" => {
            let mut dome = ring(64, &|a| Vec2::new(a.cos(), a.sin()))
                .into_iter()
                .filter(|p| p.y >= 0.0)
                .map(|p| Vec2::new(p.x, 2.0 * p.y - 1.0))
                .collect::<Vec<_>>();
            dome.push(Vec2::new(-1.0, -1.0));
            dome.insert(0, Vec2::new(1.0, -1.0));
            dome
        }
        "ellipse" => ring(64, &|a| Vec2::new(a.cos(), a.sin())),
        "lean" => ring(64, &|a| {
            let p = Vec2::new(a.cos(), a.sin());
            Vec2::new(0.7 * p.x + 0.3 * p.y, p.y)
        }),
        "heart" => {
            let h = ring(96, &|a| {
                let s = a.sin();
                Vec2::new(
                    16.0 * s * s * s,
                    13.0 * a.cos()
                        - 5.0 * (2.0 * a).cos()
                        - 2.0 * (3.0 * a).cos()
                        - (4.0 * a).cos(),
                )
            });
            // Parametrised clockwise; reversed, and normalised to the unit box.
            let (lo, hi) = h.iter().fold(
                (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
                |(lo, hi), p| (lo.min(*p), hi.max(*p)),
            );
            h.into_iter()
                .rev()
                .map(|p| 2.0 * (p - lo) / (hi - lo) - Vec2::ONE)
                .collect()
        }
        other => panic!("unknown shape {other}"),
    }
}

/// Maps a unit-box point of `shape` onto the crown's screen box
/// `lo..hi`: the column is 55 % as wide as the crown, the umbrella 115 %
/// as wide and the upper 70 % of its height; the others fill the box.
fn place(shape: &str, u: Vec2, lo: Vec2, hi: Vec2) -> Vec2 {
    let (sx, top, bottom) = match shape {
        "column" => (0.55, 1.0, 0.0),
        "umbrella" => (1.15, 1.0, 0.3),
        _ => (1.0, 1.0, 0.0),
    };
    let centre_x = 0.5 * (lo.x + hi.x);
    let half_w = 0.5 * (hi.x - lo.x) * sx;
    let y0 = lo.y + bottom * (hi.y - lo.y);
    let y1 = lo.y + top * (hi.y - lo.y);
    Vec2::new(centre_x + u.x * half_w, y0 + 0.5 * (u.y + 1.0) * (y1 - y0))
}
