//! The crown's depth follows its width.
//!
//! The deformation works in the view plane: left alone, a crown squeezed
//! into a column keeps its full depth (seen from 90° to the camera it is
//! wider than it is from the front: depth/width 1.01 → 1.88 on one
//! third-party bush), and one stretched into an umbrella turns toward a
//! slab facing the camera (0.95 → 0.62). A tree grows or shrinks its crown
//! all around its axis, so the crown's depth scales as its width does:
//! `k = W_t / W_0`, the horizontal spread on screen of the caged chain
//! tips (5th to 95th percentile) now over at rest, clamped to [1/4, 4] —
//! how much the crown the solve made actually widened, which is what the
//! foliage follows (the sketched outline's own width overstates it where
//! the foliage falls short of the sketch). A
//! node's depth is its chain junction's new depth plus its rest depth
//! offset from the junction times `k`, parents before children, so every
//! chain stays on its parent and its segments scale alike. Chains whose
//! tip follows no cage (a bole below the crown) keep their depth.
//!
//! *Chosen over two local scales, both measured:* the crown's width ratio
//! at each chain tip's height blew up where the sketch and the silhouette
//! differ in profile (a rectangle over a hull narrow at the bottom, where
//! a willow's tips hang: three times as deep as wide), and each tip's
//! distance from the crown's axis, now over at rest, blew up for tips near
//! the axis pulled outward. One scale per frame does neither; a cone drawn
//! over a round crown keeps its depth where it narrows, which reads as a
//! full crown from the side.
//!
//! Each node is then placed at its screen position at the new depth
//! (unprojected), so the silhouette — and the crown fit — are exactly what
//! the view-plane deformation made.

use glam::{Vec2, Vec3};
use treemorph_tree::geom::NONE;

use crate::plan::SketchPlan;

/// Bounds of the depth scale.
const MAX_SCALE: f32 = 4.0;

/// The 5th-to-95th-percentile spread of `x` (reordered; 0 for fewer than
/// two values). Also the crown depth/width metric's.
pub(crate) fn spread(x: &mut [f32]) -> f32 {
    if x.len() < 2 {
        return 0.0;
    }
    let n = x.len() - 1;
    let (lo, hi) = (
        (n as f32 * 0.05).round() as usize,
        (n as f32 * 0.95).round() as usize,
    );
    let high = *x.select_nth_unstable_by(hi, f32::total_cmp).1;
    let low = *x[..=hi].select_nth_unstable_by(lo, f32::total_cmp).1;
    high - low
}

/// Per-plan tables of the depth scaling.
#[derive(Debug)]
pub(crate) struct DepthScale {
    /// Rest screen position of every node.
    ndc: Vec<Vec2>,
    /// Per node, its chain ([`NONE`] for the root).
    node_chain: Vec<u32>,
    /// Per chain: its junction node and whether its tip follows a cage.
    chains: Vec<(u32, bool)>,
    /// The caged chain tips' horizontal spread on screen at rest.
    rest_width: f32,
    /// Scratch: this frame's node depths, the tips' screen x.
    depth: Vec<f32>,
    x: Vec<f32>,
}

impl DepthScale {
    /// The tables of `plan`.
    pub(crate) fn new(plan: &SketchPlan) -> DepthScale {
        let cam = &plan.camera;
        let mut node_chain = vec![NONE; plan.rest.positions.len()];
        let chains = plan
            .chain_ranges
            .iter()
            .enumerate()
            .map(|(c, &(a, b))| {
                let nodes = &plan.chain_nodes[a as usize..b as usize];
                for &n in &nodes[1..] {
                    node_chain[n as usize] = c as u32;
                }
                let tip = nodes[nodes.len() - 1];
                (nodes[0], plan.mct.control[tip as usize] != NONE)
            })
            .collect();
        let mut scale = DepthScale {
            ndc: plan
                .rest
                .positions
                .iter()
                .map(|&p| cam.project(p).0)
                .collect(),
            node_chain,
            chains,
            rest_width: 0.0,
            depth: Vec::new(),
            x: Vec::new(),
        };
        scale.rest_width = scale.tip_spread(plan, &[]);
        scale
    }

    /// The caged chain tips' horizontal spread on screen, displaced by
    /// `disp` (none: at rest).
    fn tip_spread(&mut self, plan: &SketchPlan, disp: &[Vec2]) -> f32 {
        self.x.clear();
        for (&(_, b), &(_, caged)) in plan.chain_ranges.iter().zip(&self.chains) {
            if caged {
                let tip = plan.chain_nodes[b as usize - 1] as usize;
                self.x
                    .push(self.ndc[tip].x + disp.get(tip).map_or(0.0, |d| d.x));
            }
        }
        spread(&mut self.x)
    }

    /// Places every node at its rest screen position plus `disp` (NDC),
    /// its depth offset from its chain's junction scaled as the crown
    /// widened on screen.
    pub(crate) fn place(&mut self, plan: &SketchPlan, disp: &[Vec2], out: &mut Vec<Vec3>) {
        let k = if self.rest_width > 0.0 {
            (self.tip_spread(plan, disp) / self.rest_width).clamp(1.0 / MAX_SCALE, MAX_SCALE)
        } else {
            1.0
        };
        let rest = &plan.depth;
        self.depth.clear();
        self.depth.extend_from_slice(rest);
        for (n, &c) in self.node_chain.iter().enumerate() {
            if c != NONE {
                let (j, caged) = self.chains[c as usize];
                let j = j as usize;
                let k = if caged { k } else { 1.0 };
                self.depth[n] = self.depth[j] + (rest[n] - rest[j]) * k;
            }
        }
        out.clear();
        out.extend(
            self.ndc
                .iter()
                .zip(disp)
                .zip(&self.depth)
                .map(|((&ndc, &d), &z)| plan.camera.unproject(ndc + d, z)),
        );
    }
}
