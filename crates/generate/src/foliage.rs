//! Leaf placement.
//!
//! Leaves grow on chains of order ≥ 2 only, in a **leaf zone** at the chain's
//! distal end: the outer [`Foliage::twig_zone`] of a chain without laterals
//! (a twig), the outer [`Foliage::branch_zone`] of a chain with laterals,
//! plus a terminal cluster at every leafy chain's tip. So each chain's leaves
//! sit around its tip, which is where the morphing paper's lobe extraction
//! (§4.2) seeds a chain's inner lobe.
//!
//! A leaf's anchor is on the bark: `offset` is the radial direction of its
//! azimuth times the branch radius at `t`. The blade points away from the
//! twig at the species' spread angle, biased up (or down for hanging
//! leaves), and faces roughly upward/outward with a random roll.

use std::f32::consts::{PI, TAU};

use glam::{Mat3, Quat, Vec3};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use treemorph_tree::{Leaf, NodeId};

use crate::grow::{Grown, lateral, transport, up_frame};
use crate::species::{Foliage, LeafArrangement, Species};

/// Chains below this order carry no leaves.
pub(crate) const MIN_LEAF_ORDER: u32 = 2;

/// Up to this many branches every candidate leaf is kept.
const FULL_DENSITY_SIZE: f32 = 5_000.0;

/// Share of the candidate leaves kept on a tree of `branches` branches.
///
/// Bigger trees have more, finer twigs over a crown that grows more slowly
/// than their branch count, so keeping every leaf would pack the crown ever
/// denser (and reach the model's leaf limit). Past 5,000 branches the share
/// falls as `(5000 / branches)^0.4`: ~2 leaves per branch at 5,000, ~1.1 at
/// 20,000, ~0.75 at 100,000. The first leaf of each tip cluster is always
/// kept, so every leafy chain keeps its inner lobe.
pub(crate) fn keep_share(branches: usize) -> f32 {
    (FULL_DENSITY_SIZE / branches.max(1) as f32)
        .powf(0.4)
        .clamp(0.15, 1.0)
}

struct Placer<'a> {
    grown: &'a Grown,
    foliage: &'a Foliage,
    rng: &'a mut ChaCha8Rng,
    keep: f32,
    leaves: Vec<Leaf>,
}

/// Places every leaf.
pub(crate) fn place(grown: &Grown, sp: &Species, rng: &mut ChaCha8Rng) -> Vec<Leaf> {
    let mut p = Placer {
        grown,
        foliage: &sp.foliage,
        rng,
        keep: keep_share(grown.nodes.len() - 1),
        leaves: Vec::with_capacity(2 * grown.nodes.len()),
    };
    for chain in &grown.chains {
        if chain.order < MIN_LEAF_ORDER {
            continue;
        }
        let f = p.foliage;
        let len = chain.len as usize;
        let zone = if chain.last_site == 0 {
            f.twig_zone
        } else {
            f.branch_zone
        };
        if zone <= 0.0 {
            continue;
        }
        let first = ((len as f32 * (1.0 - zone)).floor() as usize).min(len - 1);
        let nodes = &grown.chain_nodes[chain.start as usize..chain.start as usize + len];
        let material = if f.kinds.len() > 1 && p.rng.random::<f32>() < f.second_share {
            1
        } else {
            0
        };
        let mut phase = p.rng.random_range(0.0..TAU);
        for (j, &id) in nodes.iter().enumerate().skip(first) {
            p.internode(id, j, &mut phase, material);
        }
        p.tip(nodes[len - 1], material);
    }
    let mut leaves = p.leaves;
    fill_crown(&mut leaves, grown, &sp.foliage);
    leaves
}

/// Leaf area index (blade area per unit of crown ground area) the billboards
/// are scaled up to. Broadleaf crowns in leaf reach 3–6; 2.5 reads as a full
/// crown without hiding every branch.
const TARGET_LEAF_AREA_INDEX: f32 = 2.5;

/// Largest factor a billboard is enlarged by.
const MAX_LEAF_SCALE: f32 = 2.5;

/// Scales billboards up so the foliage covers the crown.
///
/// A tree of a few thousand branches carries a few thousand leaves, where
/// the real tree has tens of thousands: at botanical size the crown looks
/// bare. Like the papers' billboard clouds, each billboard then stands for a
/// small cluster of leaves: sizes are multiplied by one factor (at most
/// [`MAX_LEAF_SCALE`]) chosen so that the blade area per unit of the crown's
/// ground area reaches [`TARGET_LEAF_AREA_INDEX`]. Trees that already reach
/// it keep their leaves at botanical size. Anchors don't move, so leaves stay
/// on their twigs.
fn fill_crown(leaves: &mut [Leaf], grown: &Grown, foliage: &Foliage) {
    if leaves.is_empty() {
        return;
    }
    let (mut min, mut max) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    let mut area = 0.0f32;
    for leaf in leaves.iter() {
        let node = &grown.nodes[leaf.branch as usize];
        let parent = &grown.nodes[node.parent.expect("leaves grow on branches") as usize];
        let anchor = parent.position.lerp(node.position, leaf.t) + leaf.offset;
        min = min.min(anchor);
        max = max.max(anchor);
        area += leaf.width * leaf.height * foliage.kinds[leaf.material as usize].shape.coverage();
    }
    let extent = max - min;
    // The crown's ground footprint as the ellipse inscribed in the anchors'
    // horizontal bounds.
    let crown = std::f32::consts::FRAC_PI_4 * extent.x.max(0.1) * extent.z.max(0.1);
    let lai = area / crown;
    if lai >= TARGET_LEAF_AREA_INDEX || lai <= 0.0 {
        return;
    }
    let scale = (TARGET_LEAF_AREA_INDEX / lai).sqrt().min(MAX_LEAF_SCALE);
    for leaf in leaves.iter_mut() {
        leaf.width *= scale;
        leaf.height *= scale;
    }
}

impl Placer<'_> {
    fn jitter(&mut self, amount: f32) -> f32 {
        amount * (self.rng.random::<f32>() * 2.0 - 1.0)
    }

    /// Draws whether a candidate leaf is kept (see [`keep_share`]).
    fn kept(&mut self) -> bool {
        self.keep >= 1.0 || self.rng.random::<f32>() < self.keep
    }

    fn direction(&self, id: NodeId) -> Vec3 {
        let node = &self.grown.nodes[id as usize];
        let parent = node.parent.expect("leaves grow on branches") as usize;
        (node.position - self.grown.nodes[parent].position).normalize_or(Vec3::Y)
    }

    fn internode(&mut self, id: NodeId, j: usize, phase: &mut f32, material: u32) {
        let f = *self.foliage;
        let d = self.direction(id);
        let reference = up_frame(d, transport(Vec3::X, d));
        let per = f.per_internode.max(1);
        let spread = f.spread.to_radians();
        match f.arrangement {
            LeafArrangement::Alternate => {
                for q in 0..per {
                    *phase += 137.5f32.to_radians() + self.jitter(0.2);
                    let t = 1.0 - 0.75 * q as f32 / per as f32;
                    let (_, u) = lateral(d, reference, *phase, 0.0);
                    if self.kept() {
                        self.leaf(id, t, d, u, spread, material);
                    }
                }
            }
            LeafArrangement::Opposite => {
                *phase += PI / 2.0;
                for q in 0..per {
                    let az = *phase + PI * q as f32 + self.jitter(0.1);
                    let t = 0.92 - 0.5 * (q / 2) as f32 / per as f32;
                    let (_, u) = lateral(d, reference, az, 0.0);
                    if self.kept() {
                        self.leaf(id, t, d, u, spread, material);
                    }
                }
            }
            LeafArrangement::Sides => {
                for q in 0..per {
                    let side = if (j as u32 * per + q).is_multiple_of(2) {
                        PI / 2.0
                    } else {
                        -PI / 2.0
                    };
                    // Needle sprays lie in the plane of the branchlet, a
                    // little raised.
                    let az = side * 0.8 + self.jitter(0.25);
                    let t = (q as f32 + 0.7) / per as f32;
                    let (_, u) = lateral(d, reference, az, 0.0);
                    if self.kept() {
                        self.leaf(id, t.min(1.0), d, u, spread, material);
                    }
                }
            }
        }
    }

    fn tip(&mut self, id: NodeId, material: u32) {
        let f = *self.foliage;
        let d = self.direction(id);
        let reference = up_frame(d, transport(Vec3::X, d));
        let phase = self.rng.random_range(0.0..TAU);
        let spread = if f.tip == 1 {
            0.15
        } else {
            0.6 * f.spread.to_radians()
        };
        for q in 0..f.tip {
            let az = phase + q as f32 * TAU / f.tip as f32;
            let (_, u) = lateral(d, reference, az, 0.0);
            if q == 0 || self.kept() {
                self.leaf(id, 1.0, d, u, spread, material);
            }
        }
    }

    /// One leaf on branch `id` at `t`, on the side `u` (⟂ `d`).
    fn leaf(&mut self, id: NodeId, t: f32, d: Vec3, u: Vec3, spread: f32, material: u32) {
        let f = self.foliage;
        let node = &self.grown.nodes[id as usize];
        let parent = &self.grown.nodes[node.parent.expect("leaves grow on branches") as usize];
        let radius = parent.radius + (node.radius - parent.radius) * t;
        let spread = spread + self.jitter(0.15);
        let b0 = d * spread.cos() + u * spread.sin();
        let b = (b0 + Vec3::Y * f.lift).normalize_or(b0);
        // Face the sky and the outside, rolled a little at random.
        let z0 = (Vec3::Y + u * 0.6).normalize();
        let mut z = z0 - b * b.dot(z0);
        if z.length_squared() < 1e-4 {
            z = u - b * b.dot(u);
        }
        let z = z
            .try_normalize()
            .unwrap_or_else(|| b.any_orthonormal_vector());
        let roll = self.jitter(0.5);
        let z = (Quat::from_axis_angle(b, roll) * z).normalize();
        let x = b.cross(z).normalize();
        let orientation = Quat::from_mat3(&Mat3::from_cols(x, b, z)).normalize();
        let kind = f.kinds[material as usize];
        let height = f.length * self.rng.random_range(0.85..1.15f32);
        let width = height * kind.shape.aspect() * self.rng.random_range(0.92..1.08f32);
        self.leaves.push(Leaf {
            branch: id,
            t,
            offset: u * radius,
            width,
            height,
            orientation,
            material,
        });
    }
}
