//! The sketch moves along arcs: joints turn, lengths and radii follow.
//!
//! The solve (chain systems, `depth`, `rigid`) makes the sketched tree,
//! the **end pose**. Placing every frame by that solve at `t` — the cage
//! moving on straight lines, `S(t) = S0 + t (S1 − S0)` — moved every node
//! on a near-straight line on screen: a limb swinging 90° cut through
//! its own arc, its twigs sliding rather than turning. Instead each
//! segment (a node and its parent) turns about its joint:
//!
//! - **Along its own arc.** With `Q_i` the shortest-arc rotation of the
//!   segment's rest direction onto its end direction (the rotation its
//!   leaves have always ridden with), the segment's rotation at its
//!   chain's clock `s` is `slerp(1, Q_i, s)`: its direction moves along
//!   the great circle from where it pointed to where it will point, never
//!   outside that arc, and a chain that turns as a whole turns rigidly.
//!   Composing turns in the parent's frame instead (a skeleton's way,
//!   `W_parent · slerp(1, Q_parent⁻¹ Q_i, s)`) compounds down deep chains
//!   of short segments: on a Modular Tree poplar sketched into a heart, a
//!   twig swept 20.7 % of the height below the ground at t = 0.4 and came
//!   back to 3 % at t = 0.6, though neither end pose has it lower than
//!   18.5 %; along their own arcs the lowest point goes down steadily
//!   (0.1 %, 0.7 %, 3.4 %, … 18.5 %), as the planar path did.
//! - **Lengths hold in between.** A segment's length goes linearly from
//!   its rest length to its end length, so it is never longer or shorter
//!   than at its two ends, by construction rather than by re-solving
//!   every frame (as the planar path had to, at 3–4 × the cost of a
//!   frame). A segment of no rest length has no direction: it turns with
//!   its parent and its end offset fades in.
//! - **Radii follow a length change.** A chain's radii scale with its
//!   arc length, end over rest (geometric similarity: a limb the sketch
//!   lengthens 1.5× thickens 1.5×, a shortened one thins), blended by its
//!   clock — but a chain never ends thicker at its base than its parent
//!   at its junction unless it scales no more than its parent (pipe
//!   model: children are thinner than the branch they grow on).
//! - **Depth.** The end pose has the crown's depth scaled with its width
//!   (`depth`); turning toward it moves the depth with the rest of the 3D
//!   deformation at every `t`, not only at the end.
//!
//! Nodes are placed parents first (every parent precedes its children in
//! a tree). At t = 1 the end pose is copied, so the sketched tree is
//! exactly the solve's, crown fit included.

use glam::{Quat, Vec3};

use crate::plan::SketchPlan;
use crate::rigid::parents_first;
use crate::time::Clocks;

/// The end pose and per-node turns of a plan, and the rotations of the
/// last frame placed.
#[derive(Clone, Debug, Default)]
pub(crate) struct Arcs {
    /// The solved end pose.
    end: Vec<Vec3>,
    /// Per node: its rest offset from its parent.
    rest_offset: Vec<Vec3>,
    /// Per node: its end offset from its parent.
    end_offset: Vec<Vec3>,
    /// Per node: its segment's rotation, rest direction → end
    /// direction, `Q_i`.
    turn: Vec<Quat>,
    /// Per node: its rotation at its clock's end, `slerp(1, Q_i, 1)`,
    /// computed once per end pose: on a staged clock the chains that have
    /// not started or have finished turning need no slerp (theirs is the
    /// identity, exactly, at `s = 0`, or this one), and the foliage fit's
    /// t = 1 frames need none at all.
    turned: Vec<Quat>,
    /// Per node: end length over rest length; `None` for a segment of no
    /// rest length.
    scale: Vec<Option<f32>>,
    /// Per node: the chain whose clock moves it (`u32::MAX`: the root).
    node_chain: Vec<u32>,
    /// The chains, each after its parent.
    chain_order: Vec<u32>,
    /// Per chain: the scale of its radii at the end.
    thicken: Vec<f32>,
    /// Scratch: per chain, its clock; per node, its rotation (rest
    /// direction → now).
    clock: Vec<f32>,
    world: Vec<Quat>,
}

/// Nodes aimed in one parallel task.
const NODES_PER_TASK: usize = 1024;

/// Rest segments shorter than this fraction of the tree's height have no
/// direction.
const TINY: f32 = 1e-7;

impl Arcs {
    /// The per-plan tables of `plan`'s turns, aimed at no end pose yet
    /// ([`Arcs::aim`]).
    pub(crate) fn of(plan: &SketchPlan) -> Arcs {
        Arcs {
            node_chain: node_chains(plan),
            chain_order: parents_first(&plan.chain_parent),
            ..Arcs::default()
        }
    }

    /// The turns from `plan`'s rest pose to the solved `end` pose (aimed
    /// again, the tables and buffers are kept: the foliage fit tries
    /// several end poses).
    pub(crate) fn aim(&mut self, plan: &SketchPlan, end: Vec<Vec3>) {
        use rayon::prelude::*;
        let rest = &plan.rest.positions;
        let n = rest.len();
        for v in [&mut self.rest_offset, &mut self.end_offset] {
            v.clear();
            v.resize(n, Vec3::ZERO);
        }
        for v in [&mut self.turn, &mut self.turned, &mut self.world] {
            v.clear();
            v.resize(n, Quat::IDENTITY);
        }
        self.scale.clear();
        self.scale.resize(n, Some(1.0));
        let tiny = TINY * plan.height.max(f32::MIN_POSITIVE);
        let parents = &plan.topology.parents;
        (
            &mut self.rest_offset,
            &mut self.end_offset,
            &mut self.turn,
            &mut self.turned,
            &mut self.scale,
        )
            .into_par_iter()
            .enumerate()
            .with_min_len(NODES_PER_TASK)
            .for_each(|(i, (rest_offset, end_offset, turn, turned, scale))| {
                let Some(p) = parents[i].map(|p| p as usize) else {
                    return;
                };
                let (a, b) = (rest[i] - rest[p], end[i] - end[p]);
                *rest_offset = a;
                *end_offset = b;
                let len = a.length();
                if len <= tiny {
                    *scale = None;
                    return;
                }
                *scale = Some(b.length() / len);
                *turn = match b.try_normalize() {
                    Some(b) => Quat::from_rotation_arc(a / len, b),
                    None => Quat::IDENTITY,
                };
                *turned = Quat::IDENTITY.slerp(*turn, 1.0);
            });
        self.thicken = thickening(plan, &end, &self.node_chain, &self.chain_order);
        self.clock.clear();
        self.clock.resize(self.thicken.len(), 0.0);
        self.end = end;
    }

    /// Writes the nodes and radii at `t` (`t > 0`) into `positions` and
    /// `radii` (both sized like the rest pose).
    pub(crate) fn place(
        &mut self,
        plan: &SketchPlan,
        clocks: &Clocks,
        t: f32,
        positions: &mut [Vec3],
        radii: &mut [f32],
    ) {
        for (c, clock) in self.clock.iter_mut().enumerate() {
            *clock = clocks.chain(c, t);
        }
        let rest = &plan.rest;
        let root = clocks.root(t);
        positions[0] = rest.positions[0].lerp(self.end[0], root);
        radii[0] = rest.radii[0];
        for (i, parent) in plan.topology.parents.iter().enumerate().skip(1) {
            let p = parent.map_or(0, |p| p as usize);
            let c = self.node_chain[i] as usize;
            let s = self.clock.get(c).copied().unwrap_or(root);
            let offset = match self.scale[i] {
                Some(scale) => {
                    let w = self.turn_at(i, s);
                    self.world[i] = w;
                    w * (self.rest_offset[i] * (1.0 + s * (scale - 1.0)))
                }
                None => {
                    self.world[i] = self.world[p];
                    self.end_offset[i] * s
                }
            };
            positions[i] = positions[p] + offset;
            let k = self.thicken.get(c).copied().unwrap_or(1.0);
            radii[i] = rest.radii[i] * (1.0 + s * (k - 1.0));
        }
        if t >= 1.0 {
            positions.copy_from_slice(&self.end);
        }
    }

    /// Node `i`'s segment's rotation at its clock `s`,
    /// `slerp(1, Q_i, s)`: the same quaternion, bit for bit, without the
    /// slerp at either end of the clock.
    fn turn_at(&self, i: usize, s: f32) -> Quat {
        if s == 0.0 {
            Quat::IDENTITY
        } else if s == 1.0 {
            self.turned[i]
        } else {
            Quat::IDENTITY.slerp(self.turn[i], s)
        }
    }

    /// Node `i`'s rotation (rest direction → now) in the last frame
    /// placed.
    pub(crate) fn rotation(&self, i: usize) -> Quat {
        self.world[i]
    }
}

/// Per node: the chain it belongs to (a junction belongs to the chain it
/// lies on; `u32::MAX` for the root).
fn node_chains(plan: &SketchPlan) -> Vec<u32> {
    let mut chain = vec![u32::MAX; plan.rest.positions.len()];
    for (c, &(a, b)) in plan.chain_ranges.iter().enumerate() {
        for &n in &plan.chain_nodes[a as usize + 1..b as usize] {
            chain[n as usize] = c as u32;
        }
    }
    chain
}

/// Per chain: its arc length at the end over at rest, capped so that its
/// base ends no thicker than its parent at its junction (unless it scales
/// no more than its parent). Parents first (`order`), so each cap sees its
/// parent's final radius. `chains`: each node's chain ([`node_chains`]).
fn thickening(plan: &SketchPlan, end: &[Vec3], chains: &[u32], order: &[u32]) -> Vec<f32> {
    let rest = &plan.rest;
    let mut k = vec![1.0f32; plan.chain_ranges.len()];
    for &c in order {
        let c = c as usize;
        let (a, b) = plan.chain_ranges[c];
        let nodes = &plan.chain_nodes[a as usize..b as usize];
        if nodes.len() < 2 {
            continue;
        }
        let arc = |p: &[Vec3]| -> f32 {
            nodes
                .windows(2)
                .map(|w| p[w[0] as usize].distance(p[w[1] as usize]))
                .sum()
        };
        let rest_arc = arc(&rest.positions);
        let mut scale = if rest_arc > 0.0 {
            arc(end) / rest_arc
        } else {
            1.0
        };
        if plan.chain_parent[c].is_some() {
            let junction = nodes[0] as usize;
            let parent_k = k.get(chains[junction] as usize).copied().unwrap_or(1.0);
            let base = rest.radii[nodes[1] as usize];
            if base > 0.0 {
                let cap = (rest.radii[junction] * parent_k / base).max(parent_k);
                scale = scale.min(cap);
            }
        }
        k[c] = scale;
    }
    k
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Shortest-arc turns of every kind: tiny ones (the slerp's linear
    /// path), half turns and everything between, in all directions.
    fn turns() -> Vec<Quat> {
        let mut out = Vec::new();
        for i in 0..400u32 {
            let f = i as f32;
            let a = Vec3::new((f * 0.37).sin(), (f * 0.91).cos(), (f * 0.13).sin()).normalize();
            let tilt =
                [1e-7, 1e-4, 0.01, 0.5, 1.5, 3.0, std::f32::consts::PI - 1e-6][i as usize % 7];
            let b = Quat::from_axis_angle(a.any_orthonormal_vector(), tilt) * a;
            out.push(Quat::from_rotation_arc(a, b.normalize()));
        }
        out
    }

    /// The shortcut at either end of a clock is the slerp itself, bit for
    /// bit: frames placed with it are the same bytes as before it.
    #[test]
    fn turns_at_the_clock_ends_are_the_slerps() {
        let bits = |q: Quat| q.to_array().map(f32::to_bits);
        for q in turns() {
            let arcs = Arcs {
                turn: vec![q],
                turned: vec![Quat::IDENTITY.slerp(q, 1.0)],
                ..Arcs::default()
            };
            for s in [0.0, 0.25, 1.0] {
                let slerp = Quat::IDENTITY.slerp(q, s);
                assert_eq!(bits(arcs.turn_at(0, s)), bits(slerp), "{q:?} at {s}");
            }
        }
    }
}
