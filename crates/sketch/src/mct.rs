//! The view-dependent multiscale cage tree (§5.2): lobe silhouettes as
//! cages, linked like the BPTT.
//!
//! # Silhouettes
//! A lobe is a convex hull (the analysis' default), and the perspective or
//! orthographic projection of a convex polytope in front of the camera is
//! convex, so the outline of its projection is the 2D convex hull of its
//! projected vertices. That outline is exactly the projection of the
//! object-space silhouette the paper detects — the hull vertices `p` whose
//! adjacent faces turn from front- to back-facing, `n · (p − C) = 0` — so
//! we compute it in screen space (NDC) without normals. (For the optional
//! non-convex radial hulls the same construction gives the silhouette of
//! their convex hull: a slightly looser cage.)
//!
//! # Tree shape
//! Nodes are created top-down, parents before children:
//! crown (the root group's GOL) → for each chain of a group its OL →
//! under an OL, the chain's IL (a **leaf cage**) and the GOLs of the chain
//! groups growing on it → their chains' OLs → … GOL, OL and IL are
//! **internal cages** when they have children.
//!
//! Merge and skip rules (the paper does not say how to treat lobes that
//! coincide or vanish):
//! - a lobe whose silhouette is identical to its parent cage's (the OL of
//!   the only chain of a group is its GOL; the IL of a chain without child
//!   groups is its OL) is represented by the parent cage;
//! - a lobe without leaves, or whose silhouette has fewer than 3 vertices
//!   or an area below [`crate::SketchOptions::min_cage_area`] × the crown's,
//!   gets no cage: its children hang from the nearest cage above.
//!
//! # What drives a chain
//! Every node of a chain is carried by the mean value coordinates of its
//! **control cage**: the first of the chain's IL cage, its OL's cage, then
//! that cage's ancestors, that contains the node (with a tolerance of 5 %
//! of the cage's diagonal). A tip held by none uses the crown; other nodes
//! held by none (a bole below the crown) follow no cage. The paper drives
//! the tip from the IL; a tip outside a small IL would be extrapolated far,
//! so we climb to a cage that holds it.

use glam::Vec2;
use rayon::prelude::*;
use serde::Serialize;
use treemorph_analysis::{Analysis, ChainId, GroupId, Hull};
use treemorph_tree::geom::NONE;

use crate::mvc;
use crate::polygon;
use crate::view::Camera;

/// What a cage is the silhouette of.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CageKind {
    /// The crown: the root group's GOL (the MCT root).
    Crown,
    /// A chain group's GOL.
    GroupOuter,
    /// A chain's OL.
    Outer,
    /// A chain's IL (a leaf cage).
    Inner,
}

/// One node of the multiscale cage tree.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Cage {
    pub(crate) kind: CageKind,
    pub(crate) group: Option<GroupId>,
    pub(crate) chain: Option<ChainId>,
    pub(crate) parent: Option<u32>,
    pub(crate) children: Vec<u32>,
    /// Rest polygon, NDC, CCW.
    pub(crate) rest: Vec<Vec2>,
    /// The lobe hull vertex under each cage vertex ([`NONE`] for the
    /// crown's inserted correspondence samples).
    pub(crate) hull_vertex: Vec<u32>,
    /// Mean value coordinates of each vertex in the parent's rest cage,
    /// row-major `rest.len() × parent.rest.len()`.
    pub(crate) weights: Vec<f32>,
    /// Self-adaptive correction of each vertex at t = 1 (empty: none).
    pub(crate) adapt: Vec<Vec2>,
    /// Marked for pruning (§5.4.2).
    pub(crate) pruned: bool,
    /// Offset of this cage's vertices in flat per-vertex buffers.
    pub(crate) offset: usize,
}

impl Cage {
    /// What the cage is the silhouette of (for merged cages: the coarsest
    /// lobe).
    pub fn kind(&self) -> CageKind {
        self.kind
    }

    /// The chain group whose GOL this is, if any.
    pub fn group(&self) -> Option<GroupId> {
        self.group
    }

    /// The chain whose OL or IL this is, if any.
    pub fn chain(&self) -> Option<ChainId> {
        self.chain
    }

    /// The parent cage; `None` for the crown.
    pub fn parent(&self) -> Option<u32> {
        self.parent
    }

    /// Child cages.
    pub fn children(&self) -> &[u32] {
        &self.children
    }

    /// The cage polygon at rest, in NDC, counter-clockwise.
    pub fn rest(&self) -> &[Vec2] {
        &self.rest
    }

    /// Whether pruning marked the cage (its chains or leaves wilt).
    pub fn pruned(&self) -> bool {
        self.pruned
    }

    /// Whether self-adaptation moves the cage.
    pub fn adapted(&self) -> bool {
        !self.adapt.is_empty()
    }
}

/// The cage tree and what drives each chain.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Mct {
    pub cages: Vec<Cage>,
    /// Control cage of each node (`NONE`: the node follows no cage).
    pub control: Vec<u32>,
    /// Mean value coordinates of each node in its control cage
    /// (`offsets[n]..offsets[n + 1]`).
    pub weights: Vec<f32>,
    pub offsets: Vec<usize>,
    /// Total cage vertices (the flat buffers' length).
    pub vertex_count: usize,
}

/// Sets the mean value coordinates of every cage vertex in its parent
/// cage, and every cage's offset in the flat per-vertex buffers. The
/// cages are independent of each other: computed in parallel.
fn cage_weights(cages: &mut [Cage]) {
    let mut offset = 0;
    for cage in cages.iter_mut() {
        cage.offset = offset;
        offset += cage.rest.len();
    }
    let weights: Vec<Vec<f32>> = cages
        .par_iter()
        .map(|cage| {
            let Some(p) = cage.parent else {
                return Vec::new();
            };
            let parent = &cages[p as usize].rest;
            let mut w = vec![0.0f32; cage.rest.len() * parent.len()];
            for (v, row) in cage.rest.iter().zip(w.chunks_exact_mut(parent.len())) {
                mvc::coordinates(parent, *v, row);
            }
            w
        })
        .collect();
    for (cage, w) in cages.iter_mut().zip(weights) {
        cage.weights = w;
    }
}

/// The mean value coordinates of every `(node, cage)` of `found` (sorted
/// by node) in its cage, flat in that order (`total` values): tens of
/// thousands of independent rows, computed in parallel.
fn node_weights(cages: &[Cage], found: &[(u32, u32)], ndc: &[Vec2], total: usize) -> Vec<f32> {
    let mut weights = vec![0.0f32; total];
    let mut rows: Vec<&mut [f32]> = Vec::with_capacity(found.len());
    let mut rest = weights.as_mut_slice();
    for &(_, cage) in found {
        let (row, tail) = rest.split_at_mut(cages[cage as usize].rest.len());
        rows.push(row);
        rest = tail;
    }
    rows.into_par_iter()
        .zip(found.par_iter())
        .for_each(|(row, &(node, cage))| {
            mvc::coordinates(&cages[cage as usize].rest, ndc[node as usize], row);
        });
    weights
}

/// A lobe silhouette: CCW polygon and the hull vertex of each corner.
pub(crate) struct Silhouette {
    pub points: Vec<Vec2>,
    pub hull_vertex: Vec<u32>,
}

/// The screen-space silhouette of a convex hull (see the module docs);
/// `None` when it spans no area.
pub(crate) fn silhouette(camera: &Camera, hull: &Hull) -> Option<Silhouette> {
    if hull.is_empty() {
        return None;
    }
    let projected: Vec<Vec2> = hull.vertices.iter().map(|&v| camera.project(v).0).collect();
    let mut idx = polygon::convex_hull(&projected);
    // Hulls of degenerate leaf sets are inflated octahedra whose vertices
    // can project a hair apart: merge corners closer than 1e-6 NDC, they
    // would only make mean value coordinates and Laplacians ill-conditioned.
    let mut k = 0;
    while idx.len() >= 3 && k < idx.len() {
        let next = idx[(k + 1) % idx.len()];
        if projected[idx[k]].distance(projected[next]) < 1e-6 {
            idx.remove((k + 1) % idx.len());
        } else {
            k += 1;
        }
    }
    if idx.len() < 3 {
        return None;
    }
    Some(Silhouette {
        points: idx.iter().map(|&i| projected[i]).collect(),
        hull_vertex: idx.iter().map(|&i| i as u32).collect(),
    })
}

/// Which lobe a cage would be.
#[derive(Clone, Copy)]
enum Lobe {
    Group(GroupId),
    Outer(ChainId),
    Inner(ChainId),
}

struct Builder<'a> {
    /// Every lobe's silhouette, taken as its cage is added.
    silhouettes: Silhouettes<'a>,
    min_area: f32,
    cages: Vec<Cage>,
    /// Raw silhouette of each cage, for the identity test.
    raw: Vec<Vec<Vec2>>,
}

/// The silhouette of every lobe the builder may add, computed up front in
/// parallel (projections and 2D hulls of a few thousand lobes): the
/// builder's walk itself is sequential. A chain alone in its group is
/// represented by its group's cage, so its outer lobe is computed only if
/// the walk asks for it (when the group got no cage).
struct Silhouettes<'a> {
    camera: &'a Camera,
    analysis: &'a Analysis,
    groups: Vec<Option<Silhouette>>,
    outer: Vec<Option<Silhouette>>,
    inner: Vec<Option<Silhouette>>,
}

impl<'a> Silhouettes<'a> {
    /// Groups' outer lobes, the outer lobes of chains that share their
    /// group, and the inner lobes of the chains that carry groups
    /// (`child_groups`).
    fn of(
        analysis: &'a Analysis,
        camera: &'a Camera,
        child_groups: &[Vec<GroupId>],
    ) -> Silhouettes<'a> {
        let of = |hull: &Hull| silhouette(camera, hull);
        let chains = analysis.chains();
        let mut shared = vec![false; chains.len()];
        for g in analysis.groups().iter().filter(|g| g.chains.len() > 1) {
            for &c in &g.chains {
                shared[c as usize] = true;
            }
        }
        Silhouettes {
            camera,
            analysis,
            groups: analysis
                .groups()
                .par_iter()
                .map(|g| of(&g.outer_lobe.hull))
                .collect(),
            outer: chains
                .par_iter()
                .zip(&shared)
                .map(|(c, &shared)| shared.then(|| of(&c.outer_lobe.hull)).flatten())
                .collect(),
            inner: chains
                .par_iter()
                .zip(child_groups)
                .map(|(c, kids)| {
                    if kids.is_empty() {
                        None
                    } else {
                        of(&c.inner_lobe.hull)
                    }
                })
                .collect(),
        }
    }

    /// No lobe: the single-cage baseline.
    fn none(analysis: &'a Analysis, camera: &'a Camera) -> Silhouettes<'a> {
        Silhouettes {
            camera,
            analysis,
            groups: Vec::new(),
            outer: Vec::new(),
            inner: Vec::new(),
        }
    }

    /// The silhouette of `lobe`, once.
    fn take(&mut self, lobe: Lobe) -> Option<Silhouette> {
        match lobe {
            Lobe::Group(g) => self.groups[g as usize].take(),
            Lobe::Outer(c) => self.outer[c as usize].take().or_else(|| {
                silhouette(
                    self.camera,
                    &self.analysis.chains()[c as usize].outer_lobe.hull,
                )
            }),
            Lobe::Inner(c) => self.inner[c as usize].take(),
        }
    }
}

impl Builder<'_> {
    /// Adds the cage of `lobe` under `parent`; returns the cage that
    /// represents the lobe (a new one, the parent when identical, or `None`
    /// when the lobe gets no cage).
    fn add(&mut self, lobe: Lobe, parent: u32) -> Option<u32> {
        let (kind, group, chain) = match lobe {
            Lobe::Group(g) => (CageKind::GroupOuter, Some(g), None),
            Lobe::Outer(c) => (CageKind::Outer, None, Some(c)),
            Lobe::Inner(c) => (CageKind::Inner, None, Some(c)),
        };
        let s = self.silhouettes.take(lobe)?;
        if polygon::signed_area(&s.points) < self.min_area {
            return None;
        }
        if s.points == self.raw[parent as usize] {
            // Same outline as the parent: merge. A single-chain group's GOL
            // also stands for its chain's OL.
            let p = &mut self.cages[parent as usize];
            if p.chain.is_none() {
                p.chain = chain;
            }
            return Some(parent);
        }
        let id = self.cages.len() as u32;
        self.cages[parent as usize].children.push(id);
        self.cages.push(Cage {
            kind,
            group,
            chain,
            parent: Some(parent),
            children: Vec::new(),
            rest: s.points.clone(),
            hull_vertex: s.hull_vertex,
            weights: Vec::new(),
            adapt: Vec::new(),
            pruned: false,
            offset: 0,
        });
        self.raw.push(s.points);
        Some(id)
    }
}

/// Builds the MCT. `crown` is the crown cage at rest (the correspondence
/// samples), `crown_hull_vertex` the crown hull vertex under each sample,
/// `crown_silhouette` the raw crown silhouette, `ndc` every node in NDC. With `multiscale == false` the tree is the crown alone (the
/// single-cage baseline).
#[allow(clippy::too_many_arguments)]
pub(crate) fn build(
    analysis: &Analysis,
    camera: &Camera,
    crown: &[Vec2],
    crown_hull_vertex: Vec<u32>,
    crown_silhouette: &[Vec2],
    ndc: &[Vec2],
    min_area: f32,
    multiscale: bool,
) -> Mct {
    let chains = analysis.chains();
    let mut child_groups: Vec<Vec<GroupId>> = vec![Vec::new(); chains.len()];
    for g in analysis.groups() {
        if let Some(p) = g.parent_chain {
            child_groups[p as usize].push(g.id);
        }
    }
    let silhouettes = if multiscale {
        Silhouettes::of(analysis, camera, &child_groups)
    } else {
        Silhouettes::none(analysis, camera)
    };
    let mut b = Builder {
        silhouettes,
        min_area,
        cages: vec![Cage {
            kind: CageKind::Crown,
            group: Some(0),
            chain: None,
            parent: None,
            children: Vec::new(),
            rest: crown.to_vec(),
            hull_vertex: crown_hull_vertex,
            weights: Vec::new(),
            adapt: Vec::new(),
            pruned: false,
            offset: 0,
        }],
        raw: vec![crown_silhouette.to_vec()],
    };
    // Per chain: its IL cage (if one was made) and the cage its OL is (or
    // hangs from).
    let mut inner: Vec<Option<u32>> = vec![None; chains.len()];
    let mut anchor: Vec<u32> = vec![0; chains.len()];
    if multiscale {
        enum Work {
            Group(GroupId, u32),
            Chain(ChainId, u32, Option<u32>),
        }
        let root = analysis.group(0);
        let mut stack: Vec<Work> = Vec::new();
        let single = root.chains.len() == 1;
        for &c in root.chains.iter().rev() {
            stack.push(Work::Chain(c, 0, single.then_some(0)));
        }
        if single {
            b.cages[0].chain = Some(root.chains[0]);
        }
        while let Some(w) = stack.pop() {
            match w {
                Work::Group(g, parent) => {
                    let node = b.add(Lobe::Group(g), parent);
                    let here = node.unwrap_or(parent);
                    let group = analysis.group(g);
                    let single = group.chains.len() == 1;
                    if single && node.is_some() && b.cages[here as usize].chain.is_none() {
                        b.cages[here as usize].chain = Some(group.chains[0]);
                    }
                    for &c in group.chains.iter().rev() {
                        stack.push(Work::Chain(c, here, if single { node } else { None }));
                    }
                }
                Work::Chain(c, parent, ol) => {
                    let here = match ol {
                        Some(n) => n,
                        None => b.add(Lobe::Outer(c), parent).unwrap_or(parent),
                    };
                    anchor[c as usize] = here;
                    let kids = &child_groups[c as usize];
                    if !kids.is_empty() {
                        let il = b.add(Lobe::Inner(c), here);
                        inner[c as usize] = il.filter(|&n| n != here);
                        for &g in kids.iter().rev() {
                            stack.push(Work::Group(g, here));
                        }
                    }
                }
            }
        }
    }
    let mut cages = b.cages;
    cage_weights(&mut cages);

    let node_count = ndc.len();
    let mut control = vec![NONE; node_count];
    let mut offsets = vec![0usize; node_count + 1];
    let mut found = control_cages(chains, &cages, &inner, &anchor, ndc);
    found.sort_unstable();
    let mut total = 0;
    let mut k = 0;
    for node in 0..node_count {
        offsets[node] = total;
        if k < found.len() && found[k].0 as usize == node {
            let cage = found[k].1;
            control[node] = cage;
            total += cages[cage as usize].rest.len();
            k += 1;
        }
    }
    offsets[node_count] = total;
    let weights = node_weights(&cages, &found, ndc, total);
    let vertex_count = cages.iter().map(|c| c.rest.len()).sum();
    Mct {
        cages,
        control,
        weights,
        offsets,
        vertex_count,
    }
}

/// Every chain node's control cage, as `(node, cage)` (the tip always
/// gets one): the chain's inner cage when it holds the node, else the
/// nearest cage up from the chain's own that does. Chains are independent:
/// in parallel.
fn control_cages(
    chains: &[treemorph_analysis::Chain],
    cages: &[Cage],
    inner: &[Option<u32>],
    anchor: &[u32],
    ndc: &[Vec2],
) -> Vec<(u32, u32)> {
    let diag: Vec<f32> = cages.iter().map(|c| polygon::diagonal(&c.rest)).collect();
    let holds = |n: u32, p: Vec2| {
        let cage = &cages[n as usize].rest;
        polygon::contains(cage, p)
            || polygon::distance_to_boundary(cage, p) <= 0.05 * diag[n as usize]
    };
    let chosen = |c: usize, p: Vec2| {
        if let Some(il) = inner[c]
            && holds(il, p)
        {
            return Some(il);
        }
        let mut n = anchor[c];
        loop {
            if holds(n, p) {
                return Some(n);
            }
            n = cages[n as usize].parent?;
        }
    };
    chains
        .par_iter()
        .enumerate()
        .flat_map_iter(|(c, chain)| {
            let last = chain.nodes.len() - 1;
            chain
                .nodes
                .iter()
                .enumerate()
                .skip(1)
                .filter_map(move |(i, &node)| {
                    let cage = chosen(c, ndc[node as usize]).or((i == last).then_some(0))?;
                    Some((node, cage))
                })
        })
        .collect()
}

impl Mct {
    /// Cage vertex displacements at time `t` into `out` (flat, by
    /// [`Cage::offset`]): the crown's from `crown_delta` (the full t = 1
    /// displacement of each crown sample, scaled by `t`), every other cage's
    /// by mean value coordinates in its parent plus `t` × its self-adaptive
    /// correction. In displacement form, so t = 0 gives exact zeros.
    pub(crate) fn displacements(&self, crown_delta: &[Vec2], t: f32, out: &mut Vec<Vec2>) {
        out.clear();
        out.resize(self.vertex_count, Vec2::ZERO);
        for (o, d) in out.iter_mut().zip(crown_delta) {
            *o = *d * t;
        }
        for cage in &self.cages[1..] {
            let p = &self.cages[cage.parent.expect("non-crown cages have parents") as usize];
            let m = p.rest.len();
            let (before, after) = out.split_at_mut(cage.offset);
            let parent = &before[p.offset..p.offset + m];
            let mine = &mut after[..cage.rest.len()];
            for (i, row) in cage.weights.chunks_exact(m).enumerate() {
                let mut d = mvc::apply(row, parent);
                if !cage.adapt.is_empty() {
                    d += cage.adapt[i] * t;
                }
                mine[i] = d;
            }
        }
    }

    /// How the cage-field displacement of node `n` (which must have a
    /// control cage) depends on the crown cage's: `out[j]` is the weight of
    /// crown vertex `j`'s displacement in it. A cage's corners follow their
    /// parent's by fixed mean value coordinates, so the node's coordinates
    /// in its control cage, composed up the cage tree, are the crown's
    /// weights; the self-adaptive corrections add constants.
    pub(crate) fn crown_weights(&self, n: usize, out: &mut Vec<f32>) {
        let mut c = self.control[n] as usize;
        out.clear();
        out.extend_from_slice(&self.weights[self.offsets[n]..self.offsets[n + 1]]);
        let mut next = Vec::new();
        while let Some(p) = self.cages[c].parent {
            let m = self.cages[p as usize].rest.len();
            next.clear();
            next.resize(m, 0.0);
            for (&v, row) in out.iter().zip(self.cages[c].weights.chunks_exact(m)) {
                for (o, &w) in next.iter_mut().zip(row) {
                    *o += v * w;
                }
            }
            std::mem::swap(out, &mut next);
            c = p as usize;
        }
    }

    /// The cage-field displacement of node `n` (which must have a
    /// control cage) given cage displacements.
    pub(crate) fn node_displacement(&self, n: usize, cage_disp: &[Vec2]) -> Vec2 {
        let cage = &self.cages[self.control[n] as usize];
        let w = &self.weights[self.offsets[n]..self.offsets[n + 1]];
        mvc::apply(w, &cage_disp[cage.offset..cage.offset + cage.rest.len()])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::view::View;
    use glam::Vec3;

    /// A node's cage target moves with the crown cage exactly as its
    /// crown weights say (the self-adaptive corrections are constants).
    #[test]
    fn crown_weights_are_how_targets_follow_the_crown() {
        let plan = crate::plan::tests::heart_plan(crate::SketchOptions::default());
        let mct = &plan.mct;
        let base = plan.crown_delta.clone();
        let nudge: Vec<Vec2> = (0..base.len())
            .map(|j| Vec2::new((j as f32).sin(), (j as f32 * 0.7).cos()) * 0.01)
            .collect();
        let moved: Vec<Vec2> = base.iter().zip(&nudge).map(|(&b, &e)| b + e).collect();
        let (mut at_base, mut at_moved, mut weights) = (Vec::new(), Vec::new(), Vec::new());
        mct.displacements(&base, 1.0, &mut at_base);
        mct.displacements(&moved, 1.0, &mut at_moved);
        let mut checked = 0;
        for n in (0..mct.control.len()).filter(|&n| mct.control[n] != NONE) {
            mct.crown_weights(n, &mut weights);
            let predicted = mvc::apply(&weights, &nudge);
            let seen = mct.node_displacement(n, &at_moved) - mct.node_displacement(n, &at_base);
            assert!(
                seen.distance(predicted) < 1e-5,
                "node {n}: {seen} vs {predicted}"
            );
            checked += 1;
        }
        assert!(checked > 100, "{checked} caged nodes");
    }

    /// Regression: an inflated lobe's corners project a hair apart; the
    /// silhouette merges them.
    #[test]
    fn silhouettes_merge_near_coincident_corners() {
        let camera = View::front(10.0).camera().unwrap();
        let hull = Hull::convex(
            &[
                Vec3::new(0.0, 5.0, 0.0),
                Vec3::new(1.0, 5.0, 0.0),
                Vec3::new(1.0, 5.0 + 1e-6, 1e-6),
                Vec3::new(0.0, 6.0, 0.0),
                Vec3::new(0.3, 5.3, 1.0),
            ],
            0.01,
        );
        let s = silhouette(&camera, &hull).unwrap();
        assert!(s.points.len() >= 3);
        let n = s.points.len();
        for i in 0..n {
            assert!(s.points[i].distance(s.points[(i + 1) % n]) >= 1e-6);
        }
        assert!(polygon::signed_area(&s.points) > 0.0);
        assert_eq!(s.points.len(), s.hull_vertex.len());
    }
}
