//! Welded branch meshes: one continuous surface for the whole skeleton
//! ([`BranchMeshMode::Welded`](crate::BranchMeshMode::Welded)).
//!
//! The tube soup of [`BranchMesher`](crate::BranchMesher) leaves every strand
//! a separate tube. Many modelling tools instead write one connected,
//! watertight surface in which each child branch grows out of a hole in its
//! parent. This module writes such meshes, mainly so the importer's
//! skeleton extraction by mesh contraction can be tested on them.
//!
//! # Construction
//! Strands, side counts, parallel-transport ring frames, apex caps, the
//! trunk's base cap, normals and bark UVs are as in [`crate::mesh`]. What
//! differs is the join of a child strand to the strand it grows from:
//!
//! - Right after the junction node the parent tube gets an extra ring at
//!   distance `δ = min(2 · r_child, 0.4 · segment length)` along its next
//!   segment (`r_child` the largest radius of the children growing there),
//!   so the band between the junction ring and the extra ring is about as
//!   tall as the child is thick.
//! - Each child takes one quad of that band: the sector its first segment
//!   points to (the direction projected onto the junction ring's plane),
//!   else the nearest free sector. The quad is left out of the parent and
//!   its four corners become the child's base loop.
//! - The base loop is stitched to the child's first own ring (at its second
//!   node) by a zipper of triangles that walks both loops in angular order
//!   around the child's first segment.
//!
//! Every edge is then shared by exactly two triangles once the duplicated
//! seam vertices (kept for the bark UVs) are merged by position: the mesh is
//! watertight and connected. A child that finds no free sector (more
//! children at one node than the parent has sides) is written as a separate
//! closed tube with its own base cap instead. Nothing prevents the surface
//! from intersecting itself where a child's first internode is shorter than
//! its parent is thick; renderers do not mind.

use std::f32::consts::TAU;

use glam::{Quat, Vec2, Vec3};
use treemorph_tree::geom::NONE;
use treemorph_tree::{Aabb, Frame, FrameTopology, NodeId};

use crate::mesh::{MeshBuffers, MeshError, MeshGroup, MeshOptions, check_nodes, to_u32};

/// One ring of a strand's augmented polyline (its nodes plus the extra
/// rings after junctions).
#[derive(Clone, Copy, Debug)]
struct Ring {
    center: Vec3,
    radius: f32,
    tangent: Vec3,
    normal: Vec3,
}

impl Ring {
    fn binormal(&self) -> Vec3 {
        self.tangent.cross(self.normal)
    }
}

#[derive(Clone, Debug, Default)]
struct Plan {
    /// Node ids of the strand.
    ids: Vec<NodeId>,
    /// Augmented ring index of each node of the strand.
    ring_of_node: Vec<u32>,
    rings: Vec<Ring>,
    sides: u32,
    /// Starts inside its parent (no ring 0, no base cap).
    child: bool,
    /// For a child: owner strand, owner ring index of the band's first ring,
    /// and the sector taken.
    hole: Option<(u32, u32, u32)>,
    first_vertex: u32,
}

impl Plan {
    fn first_ring(&self) -> usize {
        usize::from(self.hole.is_some())
    }

    fn vertex_count(&self) -> usize {
        let rings = self.rings.len() - self.first_ring();
        rings * (self.sides as usize + 1) + 1 + usize::from(self.hole.is_none())
    }

    fn vertex(&self, ring: usize, j: u32) -> u32 {
        self.first_vertex + (ring - self.first_ring()) as u32 * (self.sides + 1) + j
    }
}

/// Meshes the static frame `frame` of `topology` as one welded surface (see
/// the [module docs](self)). Side counts come from `frame.radii`.
pub fn welded_branch_mesh(
    topology: &FrameTopology,
    frame: &Frame,
    options: &MeshOptions,
) -> Result<MeshBuffers, MeshError> {
    options.check()?;
    let count = topology.node_count();
    check_nodes(frame, count)?;
    let strands = &topology.strands;
    let pos = |id: NodeId| frame.positions[id as usize];
    let rad = |id: NodeId| frame.radii[id as usize];

    // Owner strand and index of every node, as BranchMesher decides it.
    let mut owner = vec![(NONE, 0u32); count];
    for (s, ids) in strands.iter().enumerate() {
        for (i, &id) in ids.iter().enumerate() {
            if id as usize >= count {
                return Err(MeshError::StrandNodeOutOfRange {
                    strand: s,
                    node: id,
                    count,
                });
            }
            if i > 0 && owner[id as usize].0 == NONE {
                owner[id as usize] = (s as u32, i as u32);
            }
        }
    }
    let mut plans: Vec<Plan> = Vec::with_capacity(strands.len());
    let mut plan_of_strand = vec![NONE; strands.len()];
    for (s, ids) in strands.iter().enumerate() {
        if ids.len() < 2 {
            continue;
        }
        let first = ids[0] as usize;
        if owner[first].0 == NONE {
            owner[first] = (s as u32, 0);
        }
        plan_of_strand[s] = plans.len() as u32;
        plans.push(Plan {
            ids: ids.to_vec(),
            child: owner[first].0 != s as u32,
            ..Plan::default()
        });
    }

    // Side counts (as in BranchMesher) and, per junction, the tallest band
    // its children need.
    let mut thickest = 0.0f32;
    let mut strand_radius = Vec::with_capacity(plans.len());
    for plan in &plans {
        let skip = usize::from(plan.child);
        let r = plan.ids[skip..]
            .iter()
            .map(|&id| rad(id))
            .fold(0.0f32, f32::max);
        thickest = thickest.max(r);
        strand_radius.push(r);
    }
    let (lo, hi) = (options.min_sides, options.max_sides);
    for (plan, r) in plans.iter_mut().zip(&strand_radius) {
        let ratio = if thickest > 0.0 { r / thickest } else { 0.0 };
        plan.sides = (lo + ((hi - lo) as f32 * ratio.sqrt()).round() as u32).clamp(lo, hi);
    }
    // band[(plan, node index)] = δ, the extra ring's distance after the node.
    let mut band: Vec<Vec<f32>> = plans.iter().map(|p| vec![0.0; p.ids.len()]).collect();
    for plan in &plans {
        if !plan.child {
            continue;
        }
        let (s, i) = owner[plan.ids[0] as usize];
        let p = plan_of_strand[s as usize];
        if p == NONE {
            continue;
        }
        let owner_ids = &plans[p as usize].ids;
        let i = i as usize;
        if i + 1 < owner_ids.len() {
            let seg = pos(owner_ids[i]).distance(pos(owner_ids[i + 1]));
            let want = (2.0 * rad(plan.ids[1])).min(0.4 * seg);
            let slot = &mut band[p as usize][i];
            *slot = slot.max(want);
        }
    }

    // Augmented polylines and their ring frames (parallel transport).
    for (p, plan) in plans.iter_mut().enumerate() {
        let mut points: Vec<(Vec3, f32)> = Vec::with_capacity(plan.ids.len() + 4);
        plan.ring_of_node = Vec::with_capacity(plan.ids.len());
        for (i, &id) in plan.ids.iter().enumerate() {
            plan.ring_of_node.push(points.len() as u32);
            let r = if i == 0 && plan.child {
                rad(id).min(rad(plan.ids[1]))
            } else {
                rad(id)
            };
            points.push((pos(id), r));
            let delta = band[p][i];
            if delta > 0.0 && i + 1 < plan.ids.len() {
                let next = plan.ids[i + 1];
                let dir = (pos(next) - pos(id)).normalize_or_zero();
                let len = pos(id).distance(pos(next)).max(f32::MIN_POSITIVE);
                let t = (delta / len).clamp(0.0, 1.0);
                points.push((pos(id) + dir * delta, r + (rad(next) - r) * t));
            }
        }
        plan.rings = transport(&points);
    }

    // Holes: each child takes a free sector of its owner's band.
    let mut taken: Vec<Vec<u64>> = plans.iter().map(|p| vec![0; p.rings.len()]).collect();
    for c in 0..plans.len() {
        if !plans[c].child {
            continue;
        }
        let (s, i) = owner[plans[c].ids[0] as usize];
        let p = plan_of_strand[s as usize];
        if p == NONE || p as usize == c {
            continue;
        }
        let parent = &plans[p as usize];
        let mut a = parent.ring_of_node[i as usize] as usize;
        if a + 1 >= parent.rings.len() {
            a = a.saturating_sub(1);
        }
        if a < parent.first_ring() || a + 1 >= parent.rings.len() {
            continue;
        }
        let ring = parent.rings[a];
        let d = (pos(plans[c].ids[1]) - pos(plans[c].ids[0])).normalize_or(ring.normal);
        let theta = d
            .dot(ring.binormal())
            .atan2(d.dot(ring.normal))
            .rem_euclid(TAU);
        let sides = parent.sides;
        let j0 = ((theta / TAU * sides as f32) as u32).min(sides - 1);
        let mask = &mut taken[p as usize][a];
        let free = (0..sides as i64)
            .flat_map(|k| [k, -k])
            .map(|k| (j0 as i64 + k).rem_euclid(sides as i64) as u32)
            .find(|&j| *mask & (1u64 << j) == 0);
        if let Some(j) = free {
            *mask |= 1u64 << j;
            plans[c].hole = Some((p, a as u32, j));
        }
    }

    // Layout.
    let mut vertices = 0usize;
    let mut indices = 0usize;
    for plan in &mut plans {
        plan.first_vertex = to_u32(vertices, "vertices")?;
        vertices += plan.vertex_count();
        let s = plan.sides as usize;
        let rings = plan.rings.len() - plan.first_ring();
        indices += (rings - 1) * s * 6 + s * 3;
        if plan.hole.is_none() {
            indices += s * 3;
        } else {
            indices += (4 + s) * 3;
        }
    }
    to_u32(vertices, "vertices")?;
    to_u32(indices, "indices")?;

    let mut out = MeshBuffers {
        positions: vec![Vec3::ZERO; vertices],
        normals: vec![Vec3::Y; vertices],
        uvs: vec![Vec2::ZERO; vertices],
        indices: Vec::with_capacity(indices),
        groups: Vec::new(),
        bounds: Aabb::EMPTY,
    };
    let mut bounds = Aabb::EMPTY;
    for plan in &plans {
        write_vertices(plan, options.min_uv_radius, &mut out, &mut bounds);
    }
    for (p, plan) in plans.iter().enumerate() {
        write_tube_indices(plan, &taken[p], &mut out.indices);
        if let Some((owner, a, j)) = plan.hole {
            let parent = &plans[owner as usize];
            let a = a as usize;
            let corners = [
                parent.vertex(a, j),
                parent.vertex(a, j + 1),
                parent.vertex(a + 1, j + 1),
                parent.vertex(a + 1, j),
            ];
            zipper(plan, &corners, &mut out);
        }
    }
    out.bounds = bounds;
    out.groups.push(MeshGroup {
        materials: [0, 1],
        first_index: 0,
        index_count: out.indices.len() as u32,
    });
    Ok(out)
}

/// Ring frames along a polyline: tangents are segment bisectors, normals are
/// parallel-transported from world `+X` turned onto the first tangent.
fn transport(points: &[(Vec3, f32)]) -> Vec<Ring> {
    let k = points.len();
    let fallback = (0..k.saturating_sub(1))
        .find_map(|i| (points[i + 1].0 - points[i].0).try_normalize())
        .unwrap_or(Vec3::Y);
    let mut rings = Vec::with_capacity(k);
    let mut incoming: Option<Vec3> = None;
    let mut tangent_prev = fallback;
    let mut normal = Vec3::X;
    for i in 0..k {
        let point = points[i].0;
        let outgoing = (i + 1 < k).then(|| {
            (points[i + 1].0 - point)
                .try_normalize()
                .unwrap_or(incoming.unwrap_or(fallback))
        });
        let tangent = match (incoming, outgoing) {
            (Some(a), Some(b)) => (a + b).try_normalize().unwrap_or(b),
            (Some(a), None) => a,
            (None, Some(b)) => b,
            (None, None) => fallback,
        };
        let turned = if i == 0 {
            Quat::from_rotation_arc(Vec3::Y, tangent) * Vec3::X
        } else {
            Quat::from_rotation_arc(tangent_prev, tangent) * normal
        };
        normal = (turned - tangent * turned.dot(tangent))
            .try_normalize()
            .unwrap_or_else(|| tangent.any_orthonormal_vector());
        rings.push(Ring {
            center: point,
            radius: points[i].1,
            tangent,
            normal,
        });
        incoming = outgoing;
        tangent_prev = tangent;
    }
    rings
}

fn write_vertices(plan: &Plan, min_uv_radius: f32, out: &mut MeshBuffers, bounds: &mut Aabb) {
    let sides = plan.sides;
    let mut v = 0.0f32;
    let mut prev = (plan.rings[0].center, plan.rings[0].radius);
    for (a, ring) in plan.rings.iter().enumerate() {
        if a > 0 {
            let circumference = TAU * (0.5 * (prev.1 + ring.radius)).max(min_uv_radius);
            v += ring.center.distance(prev.0) / circumference;
        }
        prev = (ring.center, ring.radius);
        if a < plan.first_ring() {
            continue;
        }
        let binormal = ring.binormal();
        for j in 0..=sides {
            let angle = if j == sides {
                0.0
            } else {
                TAU * j as f32 / sides as f32
            };
            let (sin, cos) = angle.sin_cos();
            let dir = ring.normal * cos + binormal * sin;
            let at = plan.vertex(a, j) as usize;
            let p = ring.center + dir * ring.radius;
            out.positions[at] = p;
            out.normals[at] = dir;
            out.uvs[at] = Vec2::new(j as f32 / sides as f32, v);
            *bounds = bounds.with_point(p);
        }
    }
    let last = plan.rings[plan.rings.len() - 1];
    let apex = plan.vertex(plan.rings.len(), 0) as usize;
    let tip = last.center + last.tangent * last.radius;
    out.positions[apex] = tip;
    out.normals[apex] = last.tangent;
    out.uvs[apex] = Vec2::new(
        0.5,
        v + last.radius / (TAU * last.radius.max(min_uv_radius)),
    );
    *bounds = bounds.with_point(tip);
    if plan.hole.is_none() {
        let first = plan.rings[0];
        out.positions[apex + 1] = first.center;
        out.normals[apex + 1] = -first.tangent;
        out.uvs[apex + 1] = Vec2::new(0.5, 0.0);
        *bounds = bounds.with_point(first.center);
    }
}

fn write_tube_indices(plan: &Plan, taken: &[u64], out: &mut Vec<u32>) {
    let s = plan.sides;
    let first = plan.first_ring();
    let last = plan.rings.len() - 1;
    for (a, &holes) in taken.iter().enumerate().take(last).skip(first) {
        for j in 0..s {
            if holes & (1u64 << j) != 0 {
                continue;
            }
            let (v0, v1) = (plan.vertex(a, j), plan.vertex(a, j + 1));
            let (v2, v3) = (plan.vertex(a + 1, j), plan.vertex(a + 1, j + 1));
            out.extend_from_slice(&[v0, v1, v3, v0, v3, v2]);
        }
    }
    let apex = plan.vertex(plan.rings.len(), 0);
    for j in 0..s {
        out.extend_from_slice(&[plan.vertex(last, j), plan.vertex(last, j + 1), apex]);
    }
    if plan.hole.is_none() {
        let centre = apex + 1;
        for j in 0..s {
            out.extend_from_slice(&[plan.vertex(first, j + 1), plan.vertex(first, j), centre]);
        }
    }
}

/// Stitches a child's base loop (four corners on its parent) to its first
/// own ring, walking both in angular order around the child's base tangent.
fn zipper(plan: &Plan, corners: &[u32; 4], out: &mut MeshBuffers) {
    let base = plan.rings[0];
    let (n0, b0) = (base.normal, base.binormal());
    let angle_of = |p: Vec3, centre: Vec3| {
        let d = p - centre;
        d.dot(b0).atan2(d.dot(n0))
    };
    let ring = 1usize;
    let s = plan.sides as usize;
    let centre = plan.rings[ring].center;
    let mut beta = Vec::with_capacity(s + 1);
    for j in 0..=s {
        let a = angle_of(out.positions[plan.vertex(ring, j as u32) as usize], centre);
        let a = match beta.last() {
            None => a,
            Some(&prev) => {
                let mut a = a;
                while a <= prev {
                    a += TAU;
                }
                a
            }
        };
        beta.push(a);
    }
    // The seam duplicate closes the loop exactly one turn later.
    beta[s] = beta[0] + TAU;
    let loop_centre = corners
        .iter()
        .map(|&c| out.positions[c as usize])
        .sum::<Vec3>()
        / 4.0;
    let mut loop_: Vec<(f32, u32)> = corners
        .iter()
        .map(|&c| {
            let a = angle_of(out.positions[c as usize], loop_centre);
            let a = beta[0] + (a - beta[0]).rem_euclid(TAU);
            (a, c)
        })
        .collect();
    loop_.sort_by(|x, y| x.0.total_cmp(&y.0));
    let m = loop_.len();
    let alpha = |a: usize| {
        if a < m {
            loop_[a].0
        } else {
            loop_[a - m].0 + TAU
        }
    };
    let lv = |a: usize| loop_[a % m].1;
    let rv = |b: usize| plan.vertex(ring, b as u32);
    let (mut a, mut b) = (0usize, 0usize);
    while a < m || b < s {
        if a < m && (b == s || alpha(a + 1) <= beta[b + 1]) {
            out.indices.extend_from_slice(&[lv(a), lv(a + 1), rv(b)]);
            a += 1;
        } else {
            out.indices.extend_from_slice(&[lv(a), rv(b + 1), rv(b)]);
            b += 1;
        }
    }
}

#[cfg(test)]
#[path = "welded_tests.rs"]
mod tests;
