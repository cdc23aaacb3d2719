//! [`SketchPlan`]: everything computed once per (tree, view, sketch).

use geo::{Area, BooleanOps};
use glam::{Quat, Vec2, Vec3};
use treemorph_analysis::Analysis;
use treemorph_tree::geom::NONE;
use treemorph_tree::timing::{Pace, ScheduleKind};
use treemorph_tree::{Frame, FrameTopology, NodeId, Tree};

use crate::adapt;
use crate::correspondence::{self, Correspondence};
use crate::error::SketchError;
use crate::foliage;
use crate::laplacian::LeastSquares;
use crate::mct::{self, Cage, CageKind, Mct};
use crate::options::{Method, SketchOptions};
use crate::polygon;
use crate::prune;
use crate::sketch::{Fit, Sketch};
use crate::sketcher::Sketcher;
use crate::time::clamp_t;
use crate::view::{Camera, View};

/// Where a right-hand-side value of a chain system comes from.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) enum Source {
    /// The displacement of a node solved at an earlier level (a junction).
    Node(NodeId),
    /// The cage-field displacement of a node (its target).
    Target(NodeId),
}

/// The chains of one hybrid order: one factorised least-squares system
/// (block diagonal, one block per chain).
#[derive(Debug, serde::Serialize, serde::Deserialize)]
pub(crate) struct Level {
    pub ls: LeastSquares,
    /// The node each unknown is (the chains' inner nodes).
    pub unknowns: Vec<NodeId>,
    /// The chains' tips, placed at their cage targets before the solve.
    pub tips: Vec<NodeId>,
    /// `(row, source, coefficient)`: `b[row] += coefficient × value`.
    pub rhs: Vec<(u32, Source, f32)>,
}

/// A chain subtree that wilts: its nodes shrink toward the junction.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Wilt {
    /// The node the subtree grows from (on a living chain, or the root).
    pub junction: NodeId,
    /// Every node of the subtree.
    pub nodes: Vec<NodeId>,
}

/// Instants at which a staged sketch samples its branches' motion to pace
/// it (the leaves ride on them): 24 keep the largest frame-to-frame move
/// of a 60-frame sketch within 1.25 × the median one on the maple
/// examples, and planning within 20 % of its time unpaced (`treemorph
/// bench`: 47 ms against 43 ms at 5,000 branches, 125 ms against 108 ms
/// at 20,000; 64 samples of whole frames took 67 ms and 200 ms).
const PACE_SAMPLES: usize = 24;

/// A sketch animation, planned once: the crown correspondence, the
/// multiscale cage tree with its mean value coordinates, self-adaptive
/// corrections and pruning, and the factorised Laplacian systems of the
/// chains. Frames are then made by a [`crate::Sketcher`].
#[derive(Debug, serde::Serialize, serde::Deserialize)]
pub struct SketchPlan {
    pub(crate) options: SketchOptions,
    pub(crate) camera: Camera,
    pub(crate) topology: FrameTopology,
    pub(crate) rest: Frame,
    /// Rest node depths (camera space).
    pub(crate) depth: Vec<f32>,
    /// Rest leaf offsets and orientations (world), and branch t.
    pub(crate) leaf_t: Vec<f32>,
    pub(crate) leaf_offset: Vec<Vec3>,
    pub(crate) leaf_orientation: Vec<Quat>,
    /// The crown correspondence and its t = 1 displacements.
    pub(crate) crown: Correspondence,
    pub(crate) crown_delta: Vec<Vec2>,
    /// The crown silhouette S0 (NDC, CCW) and the sketched crown S1.
    pub(crate) silhouette: Vec<Vec2>,
    pub(crate) sketched: Vec<Vec2>,
    /// Diagonal of the crown silhouette's NDC bounding box.
    pub(crate) crown_size: f32,
    pub(crate) mct: Mct,
    pub(crate) levels: Vec<Level>,
    /// Every chain's polyline (junction first), flat, with ranges, and its
    /// parent chain — for the floating-branch metric.
    pub(crate) chain_nodes: Vec<NodeId>,
    pub(crate) chain_ranges: Vec<(u32, u32)>,
    pub(crate) chain_parent: Vec<Option<u32>>,
    /// The chain each leaf grows on.
    pub(crate) leaf_chain: Vec<u32>,
    /// Tree height above the root, metres (metric tolerances).
    pub(crate) height: f32,
    pub(crate) wilts: Vec<Wilt>,
    /// Per node: whether it wilts.
    pub(crate) node_wilts: Vec<bool>,
    /// Per leaf: whether it wilts.
    pub(crate) leaf_wilts: Vec<bool>,
    /// Per chain: whether it wilts.
    pub(crate) chain_wilts: Vec<bool>,
    /// The analysis' lobes, kept for the lobe deformation.
    pub(crate) lobes: crate::lobes::LobeSource,
    /// How a staged sketch's `t` is paced (`None`: unpaced; see `time`).
    pub(crate) pace: Option<Pace>,
}

fn fit_to(points: &[Vec2], target: &[Vec2]) -> Result<Vec<Vec2>, SketchError> {
    let (lo, hi) = polygon::bounds(points).ok_or(SketchError::DegenerateSketch)?;
    let (tlo, thi) = polygon::bounds(target).ok_or(SketchError::DegenerateCrown)?;
    let size = hi - lo;
    if size.x <= 0.0 || size.y <= 0.0 {
        return Err(SketchError::DegenerateSketch);
    }
    let scale = (thi - tlo) / size;
    Ok(points.iter().map(|&p| tlo + (p - lo) * scale).collect())
}

impl SketchPlan {
    /// Plans the animation of `tree` (analysed as `analysis`) into the crown
    /// `sketch` drawn from `view`. Fails with the caller's mistake named
    /// (see [`SketchError`]).
    pub fn new(
        tree: &Tree,
        analysis: &Analysis,
        view: &View,
        sketch: &Sketch,
        options: &SketchOptions,
    ) -> Result<SketchPlan, SketchError> {
        let (camera, points) = checked_inputs(tree, analysis, view, sketch, options)?;
        let depth = checked_depths(tree, analysis, view, &camera)?;
        let s0 =
            mct::silhouette(&camera, &analysis.crown().hull).ok_or(SketchError::DegenerateCrown)?;
        let crown_size = polygon::diagonal(&s0.points);
        let crown_area = polygon::signed_area(&s0.points);
        if !(crown_size > 0.0 && crown_area > 1e-9 * crown_size * crown_size) {
            return Err(SketchError::DegenerateCrown);
        }
        let crown = crown_correspondence(points, &s0.points, sketch, options, crown_size)?;
        let crown_delta: Vec<Vec2> = crown
            .target
            .iter()
            .zip(&crown.source)
            .map(|(&t, &s)| t - s)
            .collect();
        let (mct, levels) = cage_tree(
            tree,
            analysis,
            &camera,
            &crown,
            &crown_delta,
            &s0,
            options,
            [crown_size, crown_area],
        )?;
        let wilting = Wilting::of(tree, analysis, &mct);
        let chains = analysis.chains();
        let mut plan = SketchPlan {
            options: options.clone(),
            camera,
            topology: FrameTopology::of_tree(tree),
            rest: Frame::of_tree(tree),
            depth,
            leaf_t: tree.leaves().iter().map(|l| l.t).collect(),
            leaf_offset: tree.leaves().iter().map(|l| l.offset).collect(),
            leaf_orientation: tree.leaves().iter().map(|l| l.orientation).collect(),
            sketched: crown.target.clone(),
            silhouette: s0.points,
            crown,
            crown_delta,
            crown_size,
            mct,
            levels,
            chain_nodes: chains
                .iter()
                .flat_map(|c| c.nodes.iter().copied())
                .collect(),
            chain_ranges: chain_ranges(chains),
            chain_parent: chains.iter().map(|c| c.parent).collect(),
            leaf_chain: analysis.leaves().iter().map(|l| l.grows_on).collect(),
            height: tree.stats().height.max(1e-6),
            wilts: wilting.wilts,
            node_wilts: wilting.nodes,
            leaf_wilts: wilting.leaves,
            chain_wilts: wilting.chains,
            lobes: Default::default(),
            pace: None,
        };
        // The lobes serve only the lobe deformation, not frames: they are
        // gathered while the crown is fitted and the schedule paced.
        let (fitted, lobes) = rayon::join(
            || fitted_and_paced(&plan, sketch.closed),
            || crate::lobes::LobeSource::new(analysis, &plan.mct, &plan.camera),
        );
        let (delta, pace) = fitted?;
        if let Some(delta) = delta {
            plan.crown_delta = delta;
        }
        plan.pace = pace;
        plan.lobes = lobes;
        Ok(plan)
    }

    /// The union topology every frame shares (the input tree's).
    pub fn topology(&self) -> &FrameTopology {
        &self.topology
    }

    /// The tree's height above its root, metres.
    pub fn height(&self) -> f32 {
        self.height
    }

    /// The input tree as a frame (what t = 0 gives).
    pub fn rest_frame(&self) -> &Frame {
        &self.rest
    }

    /// The validated camera.
    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    /// The options the plan was built with.
    pub fn options(&self) -> &SketchOptions {
        &self.options
    }

    /// The crown's silhouette from the view (NDC, counter-clockwise).
    pub fn crown_silhouette(&self) -> &[Vec2] {
        &self.silhouette
    }

    /// The sketched crown (NDC, counter-clockwise): the sketch for a closed
    /// one (after fitting), the spliced outline for an open one.
    pub fn sketched_crown(&self) -> &[Vec2] {
        &self.sketched
    }

    /// The crown outline at time `t`: the linear interpolation of
    /// corresponding silhouette and sketch points — the paper's reference
    /// in-between silhouette.
    pub fn reference_crown(&self, t: f32) -> Vec<Vec2> {
        let t = clamp_t(t);
        self.crown
            .source
            .iter()
            .zip(&self.crown.target)
            .map(|(&s, &e)| s.lerp(e, t))
            .collect()
    }

    /// Diagonal of the crown silhouette's NDC bounding box: the unit of the
    /// normalised metrics.
    pub fn crown_size(&self) -> f32 {
        self.crown_size
    }

    /// The multiscale cage tree, crown first, parents before children.
    pub fn cages(&self) -> &[Cage] {
        &self.mct.cages
    }

    /// Which chains wilt (indexed like the analysis' chains).
    pub fn wilting_chains(&self) -> &[bool] {
        &self.chain_wilts
    }

    /// Which leaves wilt (indexed like the tree's leaves).
    pub fn wilting_leaves(&self) -> &[bool] {
        &self.leaf_wilts
    }

    /// Which nodes belong to wilting chains (indexed like the tree's
    /// nodes): they shrink toward their subtree's junction, so their depth
    /// changes.
    pub fn wilting_nodes(&self) -> &[bool] {
        &self.node_wilts
    }
}

/// The foliage fit's crown displacement (`None` when the fit does not
/// apply: the single-cage baseline, an open sketch, no passes) and the
/// staged schedule's pace (`None` when unpaced).
fn fitted_and_paced(
    plan: &SketchPlan,
    closed: bool,
) -> Result<(Option<Vec<Vec2>>, Option<Pace>), SketchError> {
    let options = &plan.options;
    let staged = options.schedule.kind == ScheduleKind::Staged;
    if options.method == Method::Multiscale && closed && options.foliage_passes > 0 {
        // The fit's sketcher ends solved for the fitted crown: the pacing
        // measures on it rather than solving it again.
        let (delta, sketcher) = foliage::fit(plan, options.foliage_passes)?;
        Ok((Some(delta), staged.then(|| pace(&sketcher)).flatten()))
    } else if staged {
        Ok((None, pace(&Sketcher::new(plan))))
    } else {
        Ok((None, None))
    }
}

/// How a staged sketch's `t` is paced, measured on a `sketcher` of its
/// plan made before the plan had a pace (in parallel runs:
/// [`Sketcher::branch_moves`]).
fn pace(sketcher: &Sketcher) -> Option<Pace> {
    let easing = sketcher.plan().options.schedule.easing;
    Pace::of_moves(&sketcher.branch_moves(PACE_SAMPLES), easing)
}

/// The options, the view's camera and the sketch's points, checked in
/// that order, and whether the tree and its analysis agree.
fn checked_inputs(
    tree: &Tree,
    analysis: &Analysis,
    view: &View,
    sketch: &Sketch,
    options: &SketchOptions,
) -> Result<(Camera, Vec<Vec2>), SketchError> {
    options.validate()?;
    let camera = view.camera()?;
    let points = sketch.validate()?;
    if options.fit == Fit::Crown && !sketch.closed {
        return Err(SketchError::FitNeedsClosedSketch);
    }
    let nodes = tree.skeleton().nodes();
    if tree.leaves().is_empty() {
        return Err(SketchError::NoCrown);
    }
    if analysis.orders().len() != nodes.len() || analysis.leaves().len() != tree.leaves().len() {
        return Err(SketchError::AnalysisMismatch(format!(
            "the analysis has {} nodes and {} leaves, the tree {} and {}",
            analysis.orders().len(),
            analysis.leaves().len(),
            nodes.len(),
            tree.leaves().len()
        )));
    }
    Ok((camera, points))
}

/// Every node's depth from the camera, after checking that the camera is
/// outside the crown and, for a perspective camera, that every node, leaf
/// and crown corner is in front of it.
fn checked_depths(
    tree: &Tree,
    analysis: &Analysis,
    view: &View,
    camera: &Camera,
) -> Result<Vec<f32>, SketchError> {
    let crown_lobe = analysis.crown();
    if crown_lobe.hull.is_empty() {
        return Err(SketchError::NoCrown);
    }
    if crown_lobe.hull.contains(camera.eye(), 0.0) {
        return Err(SketchError::CameraInsideCrown);
    }
    // Everything must be in front of a perspective camera.
    let near = 1e-4 * (view.target - view.eye).length();
    let nodes = tree.skeleton().nodes();
    let depth: Vec<f32> = nodes.iter().map(|n| camera.depth(n.position)).collect();
    if camera.is_perspective() {
        if let Some(i) = depth.iter().position(|&d| d.is_nan() || d <= near) {
            return Err(SketchError::BehindCamera { node: i as u32 });
        }
        for leaf in tree.leaves() {
            let anchor = tree.leaf_anchor(leaf);
            let tip = anchor + leaf.orientation * Vec3::new(0.0, leaf.height, 0.0);
            for p in [anchor, tip] {
                let d = camera.depth(p);
                if d.is_nan() || d <= near {
                    return Err(SketchError::BehindCamera { node: leaf.branch });
                }
            }
        }
        // Every leaf is in front, yet a crown hull corner is not: the
        // eye is within a leaf's length of the foliage.
        if crown_lobe
            .hull
            .vertices
            .iter()
            .any(|&v| camera.depth(v).is_nan() || camera.depth(v) <= near)
        {
            return Err(SketchError::CameraInsideCrown);
        }
    }
    Ok(depth)
}

/// The sketched crown (fitted when asked) and its correspondence with the
/// crown silhouette `s0`.
fn crown_correspondence(
    points: Vec<Vec2>,
    s0: &[Vec2],
    sketch: &Sketch,
    options: &SketchOptions,
    crown_size: f32,
) -> Result<Correspondence, SketchError> {
    let points = match options.fit {
        Fit::Crown => fit_to(&points, s0)?,
        Fit::None => points,
    };
    let tolerance = 1e-3 * crown_size;
    if sketch.closed {
        let points = polygon::simplify_closed(&points, tolerance);
        let overlap = prune::to_geo(&points)
            .intersection(&prune::to_geo(s0))
            .unsigned_area();
        if overlap <= 0.0 {
            return Err(SketchError::SketchMissesCrown);
        }
        Ok(correspondence::closed(s0, &points, options.crown_samples))
    } else {
        let points = polygon::simplify_open(&points, tolerance);
        correspondence::open(
            s0,
            &points,
            options.crown_samples,
            options.open_snap_distance * crown_size,
        )
    }
}

/// The multiscale cage tree, self-adapted and pruned as the options ask,
/// and the chains' systems (which need only the cages' control nodes, so
/// they are factorised while the cages adapt).
#[allow(clippy::too_many_arguments)]
fn cage_tree(
    tree: &Tree,
    analysis: &Analysis,
    camera: &Camera,
    crown: &Correspondence,
    crown_delta: &[Vec2],
    s0: &mct::Silhouette,
    options: &SketchOptions,
    [crown_size, crown_area]: [f32; 2],
) -> Result<(Mct, Vec<Level>), SketchError> {
    let crown_hull_vertex: Vec<u32> = crown
        .source_vertex
        .iter()
        .map(|v| v.map_or(NONE, |i| s0.hull_vertex[i as usize]))
        .collect();
    let ndc: Vec<Vec2> = tree
        .skeleton()
        .nodes()
        .iter()
        .map(|n| camera.project(n.position).0)
        .collect();
    let multiscale = options.method == Method::Multiscale;
    let mut mct = mct::build(
        analysis,
        camera,
        &crown.source,
        crown_hull_vertex,
        &s0.points,
        &ndc,
        options.min_cage_area * crown_area,
        multiscale,
    );
    let control = mct.control.clone();
    let (adapted, levels) = rayon::join(
        || adapt_and_prune(&mut mct, crown, crown_delta, options, crown_size),
        || chain_levels(tree, analysis, &control, options.node_weight),
    );
    adapted?;
    Ok((mct, levels?))
}

/// Self-adapts and prunes `mct` as the options ask.
fn adapt_and_prune(
    mct: &mut Mct,
    crown: &Correspondence,
    crown_delta: &[Vec2],
    options: &SketchOptions,
    crown_size: f32,
) -> Result<(), SketchError> {
    let multiscale = options.method == Method::Multiscale;
    let tau = options.coverage_threshold * crown_size;
    if multiscale && options.adaptive {
        adapt::adapt(mct, crown_delta, tau, options.adapt_reach * crown_size)?;
    }
    if multiscale && options.prune {
        let mut disp = Vec::new();
        mct.displacements(crown_delta, 1.0, &mut disp);
        let finals: Vec<Vec2> = mct
            .cages
            .iter()
            .flat_map(|c| c.rest.iter())
            .zip(&disp)
            .map(|(&r, &d)| r + d)
            .collect();
        prune::prune(
            mct,
            &finals,
            &crown.target,
            options.prune_ratio,
            options.inside_ratio,
        );
    }
    Ok(())
}

/// What wilts: the parts of the tree whose cages were pruned.
struct Wilting {
    wilts: Vec<Wilt>,
    /// Per chain, leaf and node: whether it wilts.
    chains: Vec<bool>,
    leaves: Vec<bool>,
    nodes: Vec<bool>,
}

impl Wilting {
    fn of(tree: &Tree, analysis: &Analysis, mct: &Mct) -> Wilting {
        let chains = analysis.chains();
        let (mut chain_wilts, mut leaf_wilts) = pruned_parts(tree, analysis, mct);
        for c in chains {
            if let Some(p) = c.parent
                && chain_wilts[p as usize]
            {
                chain_wilts[c.id as usize] = true;
            }
        }
        let wilts = wilt_subtrees(analysis, &chain_wilts);
        for (l, leaf) in tree.leaves().iter().enumerate() {
            if let Some(c) = analysis.chain_of_node(leaf.branch)
                && chain_wilts[c as usize]
            {
                leaf_wilts[l] = true;
            }
        }
        let mut node_wilts = vec![false; tree.skeleton().nodes().len()];
        for w in &wilts {
            for &n in &w.nodes {
                node_wilts[n as usize] = true;
            }
        }
        Wilting {
            wilts,
            chains: chain_wilts,
            leaves: leaf_wilts,
            nodes: node_wilts,
        }
    }
}

/// The chains and leaves of pruned cages (before wilting spreads to
/// their descendants).
fn pruned_parts(tree: &Tree, analysis: &Analysis, mct: &Mct) -> (Vec<bool>, Vec<bool>) {
    let mut chain_wilts = vec![false; analysis.chains().len()];
    let mut leaf_wilts = vec![false; tree.leaves().len()];
    for cage in &mct.cages {
        if !cage.pruned {
            continue;
        }
        match cage.kind {
            CageKind::Crown => {}
            CageKind::GroupOuter => {
                if let Some(g) = cage.group {
                    for &c in &analysis.group(g).chains {
                        chain_wilts[c as usize] = true;
                    }
                }
            }
            CageKind::Outer => {
                if let Some(c) = cage.chain {
                    chain_wilts[c as usize] = true;
                }
            }
            CageKind::Inner => {
                if let Some(c) = cage.chain {
                    for &l in &analysis.chain(c).inner_lobe.leaves {
                        leaf_wilts[l as usize] = true;
                    }
                }
            }
        }
    }
    (chain_wilts, leaf_wilts)
}

/// The wilting subtrees: each wilting chain joins its parent's subtree,
/// or starts one at its junction.
fn wilt_subtrees(analysis: &Analysis, chain_wilts: &[bool]) -> Vec<Wilt> {
    let chains = analysis.chains();
    let mut wilts = Vec::new();
    let mut wilt_of_chain = vec![NONE; chains.len()];
    for c in chains {
        if !chain_wilts[c.id as usize] {
            continue;
        }
        let w = match c.parent.map(|p| wilt_of_chain[p as usize]) {
            Some(w) if w != NONE => w,
            _ => {
                wilts.push(Wilt {
                    junction: c.junction(),
                    nodes: Vec::new(),
                });
                (wilts.len() - 1) as u32
            }
        };
        wilt_of_chain[c.id as usize] = w;
        wilts[w as usize].nodes.extend_from_slice(&c.nodes[1..]);
    }
    wilts
}

/// Each chain's range in the flat list of every chain's nodes.
fn chain_ranges(chains: &[treemorph_analysis::Chain]) -> Vec<(u32, u32)> {
    let mut start = 0u32;
    chains
        .iter()
        .map(|c| {
            let r = (start, start + c.nodes.len() as u32);
            start = r.1;
            r
        })
        .collect()
}

/// The chains' Laplacian systems (Eq. 1 on each chain polyline), one per
/// hybrid order. A chain's junction (on its parent, solved at the previous
/// level) and its tip (at its cage target) are hard constraints; its inner
/// nodes are unknowns. Rows: the Laplacian of every inner node, with
/// weights 1/|edge| in 3D — the polyline analogue of cotangent weights, so
/// the rest shape's arc-length spacing is kept — normalised by the row's
/// diagonal; and, for every inner node inside a cage, a soft constraint of
/// weight `node_weight` toward its cage target — except on the trunk
/// (order 1), which bends smoothly from the root to its tip's target.
///
/// *Why not the trunk:* its lower nodes lie in the crown cage's bottom,
/// which the foliage fit pulls down to carry the foliage into a sketch's
/// lower tip; a maple's trunk followed it 0.25 m below its root, and
/// keeping its lengths folded the bole into a J at the ground (the
/// README's sketch pictures). Held by its ends only, the trunk stays
/// straight; over the 60 third-party sketches the final IoU moved by
/// −0.02 to +0.03 (mean +0.002, worst 0.750 → 0.754).
fn chain_levels(
    tree: &Tree,
    analysis: &Analysis,
    control: &[u32],
    node_weight: f32,
) -> Result<Vec<Level>, SketchError> {
    use rayon::prelude::*;
    let max_order = analysis.chains().iter().map(|c| c.order).max().unwrap_or(1);
    // Each order's system is its own: factorised in parallel.
    (1..=max_order)
        .into_par_iter()
        .map(|order| chain_level(tree, analysis, control, node_weight, order))
        .collect()
}

/// The chains of one `order` as one least-squares system (see
/// [`chain_levels`]).
fn chain_level(
    tree: &Tree,
    analysis: &Analysis,
    control: &[u32],
    node_weight: f32,
    order: u32,
) -> Result<Level, SketchError> {
    let skeleton = tree.skeleton();
    let chains = analysis.chains();
    let omega = f64::from(node_weight);
    let mut unknowns: Vec<NodeId> = Vec::new();
    let mut tips: Vec<NodeId> = Vec::new();
    let mut entries: Vec<(usize, usize, f64)> = Vec::new();
    let mut rhs: Vec<(u32, Source, f32)> = Vec::new();
    let mut rows = 0usize;
    for c in chains.iter().filter(|c| c.order == order) {
        let k = c.nodes.len() - 1;
        let tip = c.nodes[k];
        tips.push(tip);
        // Unknown j ↔ own node j + 1 (inner nodes 1..k).
        let base = unknowns.len();
        unknowns.extend_from_slice(&c.nodes[1..k]);
        let len = |i: usize| {
            let a = skeleton.node(c.nodes[i - 1]).position;
            let b = skeleton.node(c.nodes[i]).position;
            f64::from(a.distance(b)).max(1e-9)
        };
        for i in 1..k {
            let (w0, w1) = (1.0 / len(i), 1.0 / len(i + 1));
            let a = w0 / (w0 + w1);
            let row = rows;
            rows += 1;
            entries.push((row, base + i - 1, 1.0));
            if i == 1 {
                rhs.push((row as u32, Source::Node(c.nodes[0]), a as f32));
            } else {
                entries.push((row, base + i - 2, -a));
            }
            if i + 1 == k {
                rhs.push((row as u32, Source::Node(tip), (1.0 - a) as f32));
            } else {
                entries.push((row, base + i, -(1.0 - a)));
            }
            let node = c.nodes[i];
            if omega > 0.0 && control[node as usize] != NONE && c.order > 1 {
                let row = rows;
                rows += 1;
                entries.push((row, base + i - 1, omega));
                rhs.push((row as u32, Source::Target(node), omega as f32));
            }
        }
    }
    let ls = LeastSquares::new(unknowns.len(), rows, &entries)?;
    Ok(Level {
        ls,
        unknowns,
        tips,
        rhs,
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use treemorph_analysis::AnalysisOptions;
    use treemorph_generate::{GenerateOptions, Preset, generate};

    use super::*;
    use crate::sketch::parse_sketch_file;

    /// A small maple planned into the heart example (fitted to its crown)
    /// with `options` otherwise.
    pub(crate) fn heart_plan(options: SketchOptions) -> SketchPlan {
        let tree = generate(&GenerateOptions::new(Preset::Maple, 1).with_size(1_500)).unwrap();
        let analysis = Analysis::of(&tree, &AnalysisOptions::default()).unwrap();
        let file =
            parse_sketch_file(include_bytes!("../../../examples/sketches/heart.json")).unwrap();
        let options = options.with_fit(file.fit);
        SketchPlan::new(&tree, &analysis, &file.view, &file.sketch, &options).unwrap()
    }

    /// The staged schedule is paced on the foliage fit's own sketcher: the
    /// pace is the one a sketcher made afresh for the fitted plan measures.
    #[test]
    fn the_pace_is_measured_on_the_fitted_crown() {
        let mut plan = heart_plan(SketchOptions::default());
        let kept = plan.pace.take();
        assert!(kept.is_some());
        assert_eq!(kept, pace(&Sketcher::new(&plan)));
    }

    /// The pace's samples, placed in parallel, are the frames one sketcher
    /// places in order: the same pace, bit for bit.
    #[test]
    fn parallel_pace_samples_equal_sequential_ones() {
        let plan = heart_plan(SketchOptions::default());
        let mut sketcher = Sketcher::new(&plan);
        let easing = plan.options.schedule.easing;
        let sequential = Pace::measure(PACE_SAMPLES, easing, |t, frame| {
            sketcher.place_branches(t, frame);
        });
        assert!(sequential.is_some());
        assert_eq!(pace(&Sketcher::new(&plan)), sequential);
    }
}
