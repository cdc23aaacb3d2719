//! Branch radii from the pipe model.
//!
//! Every twig tip carries one "pipe" of cross-section 1; a node's
//! cross-section is the sum of its children's plus a little wood per
//! internode (so bare stretches of a chain still taper):
//! `a(v) = Σ_c (a(c) + κ · len(c) / mean internode)`, and `r = unit · √a`,
//! i.e. `parent² ≈ Σ children²`. The unit is chosen so that the root gets
//! the species' base radius, bounded so twig tips stay between 0.6 mm and a
//! few millimetres.
//!
//! Two rules of the ground-truth convention are then enforced top-down, in
//! node order (parents first), so that they hold exactly:
//! - no child is thicker than its parent;
//! - at a node with a continuation, every lateral is at most
//!   [`LATERAL_RADIUS_RATIO`] × the continuation;
//! - the children of a symmetric fork (and the stems of a multi-stem root)
//!   get equal radii (their pipe areas are averaged before the sum).

use treemorph_tree::NodeId;

use crate::grow::Grown;
use crate::species::Species;

/// Largest lateral radius relative to the continuation at the same node.
pub(crate) const LATERAL_RADIUS_RATIO: f32 = 0.7;

/// Wood added per mean internode length, in tip cross-sections.
const KAPPA: f32 = 0.35;

/// Smallest twig-tip radius, metres.
const MIN_TIP_RADIUS: f32 = 0.0006;

/// Child lists of a parent-before-children node array.
pub(crate) struct Children {
    offsets: Vec<u32>,
    list: Vec<NodeId>,
}

impl Children {
    pub(crate) fn of(nodes: &[treemorph_tree::Node]) -> Children {
        let n = nodes.len();
        let mut offsets = vec![0u32; n + 1];
        for node in nodes {
            if let Some(p) = node.parent {
                offsets[p as usize + 1] += 1;
            }
        }
        for i in 0..n {
            offsets[i + 1] += offsets[i];
        }
        let mut fill = offsets.clone();
        let mut list = vec![0; n.saturating_sub(1)];
        for (i, node) in nodes.iter().enumerate() {
            if let Some(p) = node.parent {
                list[fill[p as usize] as usize] = i as NodeId;
                fill[p as usize] += 1;
            }
        }
        Children { offsets, list }
    }

    pub(crate) fn get(&self, v: usize) -> &[NodeId] {
        &self.list[self.offsets[v] as usize..self.offsets[v + 1] as usize]
    }
}

/// True when the children of `v` form a symmetric fork: several children
/// and none continues `v`'s chain (or `v` is a root with several stems).
pub(crate) fn is_fork(v: usize, kids: &[NodeId], orders: &[u32]) -> bool {
    kids.len() >= 2 && (v == 0 || kids.iter().all(|&c| orders[c as usize] != orders[v]))
}

/// The child continuing `v`'s chain, if any.
pub(crate) fn continuation(v: usize, kids: &[NodeId], orders: &[u32]) -> Option<NodeId> {
    if v == 0 {
        return (kids.len() == 1).then(|| kids[0]);
    }
    kids.iter()
        .copied()
        .find(|&c| orders[c as usize] == orders[v])
}

/// Sets every node's radius.
pub(crate) fn assign_radii(grown: &mut Grown, sp: &Species, children: &Children) {
    let nodes = &mut grown.nodes;
    let orders = &grown.orders;
    let n = nodes.len();
    if n < 2 {
        return;
    }
    let lengths: Vec<f32> = nodes
        .iter()
        .map(|node| match node.parent {
            Some(p) => node.position.distance(nodes[p as usize].position),
            None => 0.0,
        })
        .collect();
    let mean = lengths.iter().sum::<f32>() / (n - 1) as f32;
    let wood = KAPPA / mean.max(1e-6);
    let mut area = vec![0f32; n];
    for v in (0..n).rev() {
        let kids = children.get(v);
        if kids.is_empty() {
            area[v] = 1.0;
            continue;
        }
        if is_fork(v, kids, orders) {
            let m = kids.iter().map(|&c| area[c as usize]).sum::<f32>() / kids.len() as f32;
            for &c in kids {
                area[c as usize] = m;
            }
        }
        area[v] = kids
            .iter()
            .map(|&c| area[c as usize] + wood * lengths[c as usize])
            .sum();
    }
    let target = sp.base_radius * grown.height;
    let unit = (target / area[0].sqrt()).clamp(MIN_TIP_RADIUS, sp.tip_radius_max);
    for (node, a) in nodes.iter_mut().zip(&area) {
        node.radius = unit * a.sqrt();
    }
    for v in 0..n {
        let kids = children.get(v);
        let rv = nodes[v].radius;
        if is_fork(v, kids, orders) {
            // Equal areas were set above; clamp them together.
            let r = kids
                .iter()
                .map(|&c| nodes[c as usize].radius)
                .fold(rv, f32::min);
            for &c in kids {
                nodes[c as usize].radius = r;
            }
            continue;
        }
        match continuation(v, kids, orders) {
            Some(c0) => {
                let rc = nodes[c0 as usize].radius.min(rv);
                nodes[c0 as usize].radius = rc;
                for &c in kids {
                    if c != c0 {
                        let r = &mut nodes[c as usize].radius;
                        *r = r.min(LATERAL_RADIUS_RATIO * rc);
                    }
                }
            }
            None => {
                for &c in kids {
                    let r = &mut nodes[c as usize].radius;
                    *r = r.min(rv);
                }
            }
        }
    }
}
