//! Chain groups, their branching patterns (Eq. 3) and the BPTT.

use std::ops::Range;

use glam::Vec3;
use serde::Serialize;
use treemorph_tree::{BranchingPattern, Skeleton};

use crate::chain::{Chain, ChainId, Ordering, tangent};
use crate::options::AnalysisOptions;
use crate::shape::Lobe;

/// Index of a chain group (BPTT node) in [`crate::Analysis::groups`].
/// Groups are numbered breadth-first through the BPTT, so the root group is
/// 0 and every level is a contiguous range.
pub type GroupId = u32;

/// A chain group — a BPTT node ⟨GC, GOL, GR, Gv, Gp⟩: chains of one order
/// growing at one location of one parent chain.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ChainGroup {
    /// This group's index.
    pub id: GroupId,
    /// GC: the group's chains, by azimuth-independent id order.
    pub chains: Vec<ChainId>,
    /// The chain the group grows on; `None` for the root group.
    pub parent_chain: Option<ChainId>,
    /// The BPTT parent (the group holding `parent_chain`).
    pub parent: Option<GroupId>,
    /// BPTT children: groups growing on this group's chains.
    pub children: Vec<GroupId>,
    /// BPTT level (root group: 0).
    pub level: u32,
    /// The chains' hybrid order.
    pub order: u32,
    /// Branching pattern by Eq. 3.
    pub pattern: BranchingPattern,
    /// Mean divergence angle in degrees (0 for a one-chain group): the mean,
    /// over azimuthally consecutive pairs of chains, of the angle between
    /// their branching vectors projected on the plane perpendicular to the
    /// parent axis at the growth location (+Y for the root group). For two
    /// chains this is simply the angle between them.
    pub divergence: f32,
    /// Gp: the mean growth location of the chains on the parent chain
    /// (arc-length fraction; 0 for the root group).
    pub growth_location: f32,
    /// Gv: the normalised mean branching vector of the chains.
    pub branching_vector: Vec3,
    /// GR, the group lobe ratio: the lowest OR over the group's chains —
    /// where the group's substructure starts, as a fraction of chain
    /// length.
    pub lobe_ratio: f32,
    /// GOL: the union of the chains' outer lobes.
    pub outer_lobe: Lobe,
}

/// Forms the groups, numbers them breadth-first, and writes each chain's
/// group id. Returns the groups and the BPTT level ranges.
pub(crate) fn build_groups(
    skeleton: &Skeleton,
    ordering: &Ordering,
    chains: &mut [Chain],
    options: &AnalysisOptions,
) -> (Vec<ChainGroup>, Vec<Range<GroupId>>) {
    // Members of each raw group, discovered per parent chain.
    let roots: Vec<ChainId> = chains
        .iter()
        .filter(|c| c.parent.is_none())
        .map(|c| c.id)
        .collect();
    let mut groups: Vec<ChainGroup> = Vec::new();
    let mut levels: Vec<Range<GroupId>> = Vec::new();
    groups.push(new_group(0, roots, None, None, 0, chains, Vec3::Y));
    let mut level_start = 0;
    while level_start < groups.len() {
        let level_end = groups.len();
        levels.push(level_start as GroupId..level_end as GroupId);
        for g in level_start..level_end {
            let members = groups[g].chains.clone();
            for parent in members {
                for (members, axis) in split_children(skeleton, ordering, chains, parent, options) {
                    let id = groups.len() as GroupId;
                    let level = groups[g].level + 1;
                    groups[g].children.push(id);
                    groups.push(new_group(
                        id,
                        members,
                        Some(parent),
                        Some(g as GroupId),
                        level,
                        chains,
                        axis,
                    ));
                }
            }
        }
        level_start = level_end;
    }
    for g in &mut groups {
        g.pattern = pattern(g.chains.len(), g.divergence, options.opposite_tolerance);
        for &c in &g.chains {
            chains[c as usize].group = g.id;
        }
    }
    (groups, levels)
}

/// Splits a chain's children into groups: the children of a symmetric fork
/// at its end are one group; laterals are swept by growth location, each
/// joining the current group while within the tolerance of its first
/// member. Returns each group with the parent axis at its growth location.
fn split_children(
    skeleton: &Skeleton,
    ordering: &Ordering,
    chains: &[Chain],
    parent: ChainId,
    options: &AnalysisOptions,
) -> Vec<(Vec<ChainId>, Vec3)> {
    let p = &chains[parent as usize];
    let mut out: Vec<(Vec<ChainId>, Vec3)> = Vec::new();
    let mut forks: Vec<ChainId> = Vec::new();
    let mut current: Option<(f32, f32, Vec<ChainId>, Vec3)> = None; // (start s, tolerance, members, axis)
    for &c in &p.children {
        let seed = &ordering.seeds[c as usize];
        let j = ordering.index_in_chain[seed.nodes[0] as usize] as usize;
        if seed.at_fork {
            forks.push(c);
            continue;
        }
        let s = p.arc_lengths[j];
        match &mut current {
            Some((start, tol, members, _)) if s - *start <= *tol => members.push(c),
            _ => {
                if let Some((_, _, members, axis)) = current.take() {
                    out.push((members, axis));
                }
                let radius = skeleton.node(seed.nodes[0]).radius;
                let entering = p.arc_lengths[j] - p.arc_lengths[j - 1];
                let tol = (options.group_tolerance_radii * radius)
                    .max(options.group_tolerance_segment * entering);
                current = Some((s, tol, vec![c], tangent(&p.points, j)));
            }
        }
    }
    if let Some((_, _, members, axis)) = current {
        out.push((members, axis));
    }
    if !forks.is_empty() {
        let last = p.points.len() - 1;
        out.push((forks, tangent(&p.points, last)));
    }
    out
}

#[allow(clippy::too_many_arguments)]
fn new_group(
    id: GroupId,
    members: Vec<ChainId>,
    parent_chain: Option<ChainId>,
    parent: Option<GroupId>,
    level: u32,
    chains: &[Chain],
    axis: Vec3,
) -> ChainGroup {
    let first = &chains[members[0] as usize];
    let n = members.len() as f32;
    let growth_location = members
        .iter()
        .map(|&c| chains[c as usize].growth_location)
        .sum::<f32>()
        / n;
    let mean_v: Vec3 = members
        .iter()
        .map(|&c| chains[c as usize].branching_vector)
        .sum();
    let branching_vector = (mean_v / n).normalize_or(first.branching_vector);
    let divergence = divergence(
        members.iter().map(|&c| chains[c as usize].branching_vector),
        axis,
    );
    ChainGroup {
        id,
        order: first.order,
        chains: members,
        parent_chain,
        parent,
        children: Vec::new(),
        level,
        pattern: BranchingPattern::Alternate,
        divergence,
        growth_location,
        branching_vector,
        lobe_ratio: 1.0,
        outer_lobe: Lobe::default(),
    }
}

/// Mean divergence angle in degrees (see [`ChainGroup::divergence`]).
/// Directions along the axis have no azimuth and are left out.
pub(crate) fn divergence(dirs: impl Iterator<Item = Vec3>, axis: Vec3) -> f32 {
    let axis = axis.normalize_or(Vec3::Y);
    let u = axis.any_orthonormal_vector();
    let w = axis.cross(u);
    let mut az: Vec<(f32, Vec3)> = dirs
        .filter_map(|d| {
            let proj = d - axis * d.dot(axis);
            (proj.length_squared() > 1e-8).then(|| {
                let proj = proj.normalize();
                (proj.dot(w).atan2(proj.dot(u)), proj)
            })
        })
        .collect();
    if az.len() < 2 {
        return 0.0;
    }
    az.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n = az.len();
    let sum: f32 = (0..n)
        .map(|i| {
            az[i]
                .1
                .dot(az[(i + 1) % n].1)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        })
        .sum();
    sum / n as f32
}

/// Eq. 3.
pub(crate) fn pattern(chains: usize, divergence: f32, tolerance: f32) -> BranchingPattern {
    match chains {
        1 => BranchingPattern::Alternate,
        2 if (divergence - 180.0).abs() < tolerance => BranchingPattern::Opposite,
        _ => BranchingPattern::Whorled,
    }
}
