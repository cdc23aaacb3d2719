//! [`Sketcher`]: makes frames from a plan, reusing its buffers.

use faer::Mat;
use faer::dyn_stack::MemBuffer;
use glam::{Quat, Vec2, Vec3};
use treemorph_tree::geom::NONE;
use treemorph_tree::timing::Pace;
use treemorph_tree::{Frame, FrameLeaf, Leaf, LeafMaterial, Materials, Node, Tree, TreeParts};

use crate::arcs::Arcs;
use crate::depth::DepthScale;
use crate::error::SketchError;
use crate::laplacian::{COLS, scratch_for};
use crate::lobes::{DeformedLobes, LobeBuffers};
use crate::plan::{Level, SketchPlan, Source};
use crate::rigid::Rigid;
use crate::time::{Clocks, clamp_t};

/// Reusable context that solves the planned tree's end pose once (the
/// paper's Step 1–3) and turns the tree toward it at any time t ∈ [0, 1].
/// Keeps its buffers between frames.
pub struct Sketcher<'p> {
    plan: &'p SketchPlan,
    cage_disp: Vec<Vec2>,
    target_disp: Vec<Vec2>,
    node_disp: Vec<Vec2>,
    b: Vec<[f64; COLS]>,
    x: Mat<f64>,
    mem: MemBuffer,
    arcs: Arcs,
    clocks: Clocks,
    lobes: LobeBuffers,
    rigid: Rigid,
    depth: DepthScale,
}

impl<'p> Sketcher<'p> {
    /// A sketcher for `plan`: solves the end pose once (≈ 1 ms for
    /// 5,000 branches); every frame then turns toward it.
    pub fn new(plan: &'p SketchPlan) -> Sketcher<'p> {
        let n = plan.rest.positions.len();
        let mut sketcher = Sketcher {
            plan,
            cage_disp: Vec::with_capacity(plan.mct.vertex_count),
            target_disp: vec![Vec2::ZERO; n],
            node_disp: vec![Vec2::ZERO; n],
            b: Vec::new(),
            x: Mat::zeros(0, 0),
            mem: scratch_for(plan.levels.iter().map(|l| &l.ls)),
            arcs: Arcs::of(plan),
            clocks: Clocks::new(plan, &plan.options.schedule),
            lobes: Default::default(),
            rigid: Rigid::new(plan),
            depth: DepthScale::new(plan),
        };
        sketcher.resolve(&plan.crown_delta);
        sketcher
    }

    /// Solves the end pose again for the crown cage moving by
    /// `crown_delta` at t = 1, keeping the per-plan tables: the foliage
    /// fit tries several crown displacements on one sketcher.
    pub(crate) fn resolve(&mut self, crown_delta: &[Vec2]) {
        let end = self.solve(crown_delta);
        self.arcs.aim(self.plan, end);
    }

    /// The plan.
    pub fn plan(&self) -> &'p SketchPlan {
        self.plan
    }

    /// Writes the tree at time `t` (clamped to [0, 1]; NaN is 0) into
    /// `frame`, resizing it to the plan's topology. t = 0 reproduces the
    /// input tree exactly, t = 1 is the solved end pose ([`Sketcher::new`]).
    ///
    /// In between, every segment turns about its joint toward its end
    /// direction on its chain's clock, its length and its chain's radii
    /// following (the `arcs` module); pruned subtrees shrink toward their
    /// junction (radii too) on the shed clock, and their leaves with them
    /// (the `time` module); leaves ride on their branch, rotated with it,
    /// their offset from its axis following its radius.
    pub fn deform(&mut self, t: f32, frame: &mut Frame) {
        let t = clamp_t(t);
        let left = self.place_branches(t, frame);
        self.place_leaves(t, left, frame);
    }

    /// The nodes and radii of `frame` at `t` (in [0, 1]), its leaves
    /// cleared; returns how much of the wilting subtrees is left.
    pub(crate) fn place_branches(&mut self, t: f32, frame: &mut Frame) -> f32 {
        branches_at(self.plan, &self.clocks, &mut self.arcs, t, frame)
    }

    /// How far the branches move between each of `samples` even instants
    /// and the next ([`Pace::moves`]), as [`Sketcher::place_branches`]
    /// places them: what the pacing measures. The instants are measured
    /// in one run per core, each on its own copy of the turn tables, and
    /// joined.
    pub(crate) fn branch_moves(&self, samples: usize) -> Vec<f32> {
        use rayon::prelude::*;
        Pace::runs(samples, rayon::current_num_threads())
            .into_par_iter()
            .flat_map_iter(|span| {
                let mut arcs = self.arcs.clone();
                Pace::moves(samples, span, |t, frame| {
                    branches_at(self.plan, &self.clocks, &mut arcs, t, frame);
                })
            })
            .collect()
    }

    /// The end pose, as the paper makes a frame (Step 1–3):
    ///
    /// 1. The crown cage moves by `crown_delta` (along the correspondence
    ///    to `S1`, plus the foliage fit's correction); every
    ///    other cage follows its parent by mean value coordinates, plus
    ///    its self-adaptive correction.
    /// 2. Each chain's tip target is its control cage's mean value
    ///    combination; chains are solved order by order (Eq. 1, backward
    ///    propagation from the tip), each chain's junction fixed where its
    ///    parent put it (forward propagation) — chains stay connected by
    ///    construction.
    /// 3. Nodes go where the solve put them on screen, their depth scaled
    ///    with the crown's width (`depth` module); every chain is then
    ///    re-solved to keep its segment lengths (`rigid` module).
    fn solve(&mut self, crown_delta: &[Vec2]) -> Vec<Vec3> {
        let plan = self.plan;
        plan.mct
            .displacements(crown_delta, 1.0, &mut self.cage_disp);
        for (n, &c) in plan.mct.control.iter().enumerate() {
            if c != NONE {
                self.target_disp[n] = plan.mct.node_displacement(n, &self.cage_disp);
            }
        }
        self.node_disp[0] = Vec2::ZERO;
        for level in &plan.levels {
            self.solve_level(level);
        }
        let mut positions = Vec::new();
        self.depth.place(plan, &self.node_disp, &mut positions);
        self.rigid.apply(plan, &mut positions);
        positions
    }

    /// Solves one order's chains (Eq. 1) for their nodes' displacements.
    fn solve_level(&mut self, level: &Level) {
        for &tip in &level.tips {
            self.node_disp[tip as usize] = self.target_disp[tip as usize];
        }
        if level.unknowns.is_empty() {
            return;
        }
        self.b.clear();
        self.b.resize(level.ls.rows(), [0.0; COLS]);
        for &(row, source, coef) in &level.rhs {
            let v = match source {
                Source::Node(n) => self.node_disp[n as usize],
                Source::Target(n) => self.target_disp[n as usize],
            };
            let r = &mut self.b[row as usize];
            r[0] += f64::from(coef * v.x);
            r[1] += f64::from(coef * v.y);
        }
        level.ls.solve(&self.b, &mut self.x, &mut self.mem);
        for (k, &n) in level.unknowns.iter().enumerate() {
            self.node_disp[n as usize] = Vec2::new(self.x[(k, 0)] as f32, self.x[(k, 1)] as f32);
        }
    }

    /// Every leaf of `frame` on its branch, rotated with it (`left`: how
    /// much of the wilting leaves is left).
    fn place_leaves(&self, t: f32, left: f32, frame: &mut Frame) {
        let plan = self.plan;
        let rest = &plan.rest;
        let parents = &plan.topology.parents;
        for (l, top) in plan.topology.leaves.iter().enumerate() {
            let node = top.node as usize;
            let parent = parents[node].map_or(node, |p| p as usize);
            let ls = if plan.leaf_wilts[l] { left } else { 1.0 };
            let base = frame.positions[parent].lerp(frame.positions[node], plan.leaf_t[l]);
            let offset = on_bark(plan.leaf_offset[l], frame.radii[node] - rest.radii[node]) * ls;
            let rot = if t > 0.0 {
                self.arcs.rotation(node)
            } else {
                Quat::IDENTITY
            };
            let rest_leaf = &rest.leaves[l];
            let (offset, orientation) = if rot == Quat::IDENTITY {
                (offset, plan.leaf_orientation[l])
            } else {
                (rot * offset, (rot * plan.leaf_orientation[l]).normalize())
            };
            frame.leaves.push(FrameLeaf {
                anchor: base + offset,
                orientation,
                width: rest_leaf.width * ls,
                height: rest_leaf.height * ls,
                blend: 0.0,
            });
        }
    }

    /// The lobes of every cage at time `t`, deformed with their cages (see
    /// the `lobes` module docs). The first call factorises the lobe system;
    /// later calls only solve.
    pub fn deform_lobes(&mut self, t: f32) -> Result<DeformedLobes<'_>, SketchError> {
        let t = clamp_t(t);
        let plan = self.plan;
        let source = &plan.lobes;
        let system = source.system()?;
        plan.mct
            .displacements(&plan.crown_delta, t, &mut self.cage_disp);
        Ok(self
            .lobes
            .deform(source, system, &self.cage_disp, &plan.camera))
    }

    /// Every cage's polygon at time `t` (NDC, indexed like
    /// [`SketchPlan::cages`]), e.g. for drawing the cages over a view.
    pub fn deform_cages(&mut self, t: f32) -> Vec<Vec<Vec2>> {
        let plan = self.plan;
        plan.mct
            .displacements(&plan.crown_delta, clamp_t(t), &mut self.cage_disp);
        plan.mct
            .cages
            .iter()
            .map(|c| {
                c.rest
                    .iter()
                    .zip(&self.cage_disp[c.offset..c.offset + c.rest.len()])
                    .map(|(&r, &d)| r + d)
                    .collect()
            })
            .collect()
    }

    /// A new frame at time `t`.
    pub fn frame(&mut self, t: f32) -> Frame {
        let mut frame = Frame::default();
        self.deform(t, &mut frame);
        frame
    }

    /// The sketched result as a [`Tree`]: the t = 1 frame with wilted
    /// chains and leaves removed (the input of, e.g., a morph comparison).
    pub fn result_tree(&mut self, tree: &Tree) -> Result<Tree, SketchError> {
        let frame = self.frame(1.0);
        let plan = self.plan;
        let n = frame.positions.len();
        let mut keep = vec![true; n];
        for w in &plan.wilts {
            for &node in &w.nodes {
                keep[node as usize] = false;
            }
        }
        let mut new_id = vec![NONE; n];
        let mut nodes = Vec::new();
        for i in 0..n {
            if !keep[i] {
                continue;
            }
            new_id[i] = nodes.len() as u32;
            nodes.push(Node {
                position: frame.positions[i],
                radius: frame.radii[i],
                parent: plan.topology.parents[i].map(|p| new_id[p as usize]),
            });
        }
        let mut leaves = Vec::new();
        for (l, leaf) in tree.leaves().iter().enumerate() {
            if plan.leaf_wilts[l] || new_id[leaf.branch as usize] == NONE {
                continue;
            }
            let fl = &frame.leaves[l];
            let node = leaf.branch as usize;
            let parent = plan.topology.parents[node].map_or(node, |p| p as usize);
            let base = frame.positions[parent].lerp(frame.positions[node], leaf.t);
            leaves.push(Leaf {
                branch: new_id[node],
                offset: fl.anchor - base,
                orientation: fl.orientation,
                ..*leaf
            });
        }
        let parts = TreeParts {
            name: format!("{}-sketched", tree.name()),
            nodes,
            leaves,
            materials: Materials {
                bark: tree.materials().bark.clone(),
                leaves: tree
                    .materials()
                    .leaves
                    .iter()
                    .map(LeafMaterial::clone)
                    .collect(),
            },
            ground_truth: None,
        };
        Tree::new(parts, &treemorph_tree::Limits::default())
            .map_err(|e| SketchError::Internal(format!("the sketched tree is invalid: {e}")))
    }
}

/// The nodes and radii of `frame` at `t` (see [`Sketcher::place_branches`]).
fn branches_at(
    plan: &SketchPlan,
    clocks: &Clocks,
    arcs: &mut Arcs,
    t: f32,
    frame: &mut Frame,
) -> f32 {
    let rest = &plan.rest;
    frame.t = t;
    frame.bark_blend = 0.0;
    frame.positions.clear();
    frame.positions.extend_from_slice(&rest.positions);
    frame.radii.clear();
    frame.radii.extend_from_slice(&rest.radii);
    frame.leaves.clear();
    let paced = clocks.paced(t);
    if t > 0.0 {
        arcs.place(plan, clocks, paced, &mut frame.positions, &mut frame.radii);
    }
    let left = 1.0 - clocks.shed(paced);
    shrink_wilts(plan, left, frame);
    left
}

/// Shrinks the pruned subtrees of `frame` toward their junctions, to
/// `left` of their size (radii too).
fn shrink_wilts(plan: &SketchPlan, left: f32, frame: &mut Frame) {
    if left == 1.0 {
        return;
    }
    for w in &plan.wilts {
        let j = frame.positions[w.junction as usize];
        for &node in &w.nodes {
            let p = &mut frame.positions[node as usize];
            *p = j + (*p - j) * left;
            frame.radii[node as usize] *= left;
        }
    }
}

/// A leaf's rest `offset` from its branch's axis, moved out (or in) by the
/// branch's radius change `dr`, so that it stays as far from the bark as
/// at rest; never through the axis.
pub(crate) fn on_bark(offset: Vec3, dr: f32) -> Vec3 {
    if dr == 0.0 {
        return offset;
    }
    let len = offset.length();
    if len > 0.0 {
        offset * ((len + dr).max(0.0) / len)
    } else {
        offset
    }
}
