//! [`AnalysisSummary`] and the JSON export.

use glam::Vec3;
use serde::Serialize;
use treemorph_tree::{BranchingPattern, NodeId};

use crate::Analysis;
use crate::chain::ChainId;
use crate::group::GroupId;
use crate::hull::Hull;
use crate::leaf::LeafPlacement;
use crate::shape::Lobe;

/// Counts of the analysis, as `treemorph inspect --analysis` and
/// `GET /v1/trees/{id}/analysis` report them.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct AnalysisSummary {
    /// Number of chains.
    pub chains: usize,
    /// Number of chain groups (BPTT nodes).
    pub chain_groups: usize,
    /// Groups per branching pattern.
    pub patterns: PatternCounts,
    /// Chain orders.
    pub orders: OrderSummary,
    /// Number of BPTT levels (1 when only the root group exists).
    pub bptt_depth: usize,
    /// Non-empty lobes of each kind.
    pub lobes: LobeCounts,
}

/// Chain groups per branching pattern.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Default)]
pub struct PatternCounts {
    /// One-chain groups.
    pub alternate: usize,
    /// Two chains about 180° apart.
    pub opposite: usize,
    /// The rest.
    pub whorled: usize,
}

/// Chain orders.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct OrderSummary {
    /// Highest chain order.
    pub max: u32,
    /// Chains per order: `histogram[i]` counts chains of order `i + 1`.
    pub histogram: Vec<usize>,
}

/// Non-empty lobes.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct LobeCounts {
    /// Chains with a non-empty IL.
    pub inner: usize,
    /// Chains with a non-empty OL.
    pub outer: usize,
    /// Groups with a non-empty GOL.
    pub group_outer: usize,
}

/// The whole analysis in a compact serialisable form ([`Analysis::export`]).
/// OL and GOL leaf lists are left out (they are unions of ILs along the
/// BPTT); their counts, centres, radii and hulls are kept.
#[derive(Clone, Debug, Serialize)]
pub struct AnalysisExport<'a> {
    /// The counts.
    pub summary: AnalysisSummary,
    /// Hybrid order per node.
    pub orders: &'a [u32],
    /// Chains by id.
    pub chains: Vec<ChainExport<'a>>,
    /// Chain groups (BPTT nodes) by id.
    pub groups: Vec<GroupExport<'a>>,
    /// Leaves relative to their chains.
    pub leaves: &'a [LeafPlacement],
}

/// One chain in an [`AnalysisExport`].
#[derive(Clone, Debug, Serialize)]
pub struct ChainExport<'a> {
    /// Chain id.
    pub id: ChainId,
    /// Hybrid order.
    pub order: u32,
    /// Parent chain.
    pub parent: Option<ChainId>,
    /// Chain group.
    pub group: GroupId,
    /// Polyline node ids (junction first).
    pub nodes: &'a [NodeId],
    /// Arc length, metres.
    pub length: f32,
    /// p.
    pub growth_location: f32,
    /// v.
    pub branching_vector: Vec3,
    /// OR.
    pub outer_ratio: f32,
    /// IR.
    pub inner_ratio: f32,
    /// IL with its leaves.
    pub inner_lobe: &'a Lobe,
    /// OL without its leaf list.
    pub outer_lobe: LobeExport<'a>,
}

/// One chain group in an [`AnalysisExport`].
#[derive(Clone, Debug, Serialize)]
pub struct GroupExport<'a> {
    /// Group id.
    pub id: GroupId,
    /// BPTT level.
    pub level: u32,
    /// BPTT parent.
    pub parent: Option<GroupId>,
    /// BPTT children.
    pub children: &'a [GroupId],
    /// GC.
    pub chains: &'a [ChainId],
    /// Chain order.
    pub order: u32,
    /// Branching pattern.
    pub pattern: BranchingPattern,
    /// Mean divergence angle, degrees.
    pub divergence: f32,
    /// Gp.
    pub growth_location: f32,
    /// Gv.
    pub branching_vector: Vec3,
    /// GR.
    pub lobe_ratio: f32,
    /// GOL without its leaf list.
    pub outer_lobe: LobeExport<'a>,
}

/// A lobe without its leaf list.
#[derive(Clone, Debug, Serialize)]
pub struct LobeExport<'a> {
    /// Number of leaves.
    pub leaf_count: usize,
    /// Centre, metres.
    pub center: Vec3,
    /// Radius, metres.
    pub radius: f32,
    /// Closed shape.
    pub hull: &'a Hull,
}

impl<'a> From<&'a Lobe> for LobeExport<'a> {
    fn from(l: &'a Lobe) -> LobeExport<'a> {
        LobeExport {
            leaf_count: l.leaves.len(),
            center: l.center,
            radius: l.radius,
            hull: &l.hull,
        }
    }
}

impl Analysis {
    /// The counts.
    pub fn summary(&self) -> AnalysisSummary {
        let mut patterns = PatternCounts::default();
        for g in &self.groups {
            match g.pattern {
                BranchingPattern::Alternate => patterns.alternate += 1,
                BranchingPattern::Opposite => patterns.opposite += 1,
                BranchingPattern::Whorled => patterns.whorled += 1,
            }
        }
        let max = self.chains.iter().map(|c| c.order).max().unwrap_or(0);
        let mut histogram = vec![0; max as usize];
        for c in &self.chains {
            histogram[c.order as usize - 1] += 1;
        }
        AnalysisSummary {
            chains: self.chains.len(),
            chain_groups: self.groups.len(),
            patterns,
            orders: OrderSummary { max, histogram },
            bptt_depth: self.levels.len(),
            lobes: LobeCounts {
                inner: self
                    .chains
                    .iter()
                    .filter(|c| !c.inner_lobe.is_empty())
                    .count(),
                outer: self
                    .chains
                    .iter()
                    .filter(|c| !c.outer_lobe.is_empty())
                    .count(),
                group_outer: self
                    .groups
                    .iter()
                    .filter(|g| !g.outer_lobe.is_empty())
                    .count(),
            },
        }
    }

    /// A serialisable view of the whole analysis.
    pub fn export(&self) -> AnalysisExport<'_> {
        AnalysisExport {
            summary: self.summary(),
            orders: &self.orders,
            chains: self
                .chains
                .iter()
                .map(|c| ChainExport {
                    id: c.id,
                    order: c.order,
                    parent: c.parent,
                    group: c.group,
                    nodes: &c.nodes,
                    length: c.length,
                    growth_location: c.growth_location,
                    branching_vector: c.branching_vector,
                    outer_ratio: c.outer_ratio,
                    inner_ratio: c.inner_ratio,
                    inner_lobe: &c.inner_lobe,
                    outer_lobe: (&c.outer_lobe).into(),
                })
                .collect(),
            groups: self
                .groups
                .iter()
                .map(|g| GroupExport {
                    id: g.id,
                    level: g.level,
                    parent: g.parent,
                    children: &g.children,
                    chains: &g.chains,
                    order: g.order,
                    pattern: g.pattern,
                    divergence: g.divergence,
                    growth_location: g.growth_location,
                    branching_vector: g.branching_vector,
                    lobe_ratio: g.lobe_ratio,
                    outer_lobe: (&g.outer_lobe).into(),
                })
                .collect(),
            leaves: &self.leaves,
        }
    }

    /// [`Analysis::export`] as compact JSON.
    pub fn to_json(&self) -> Vec<u8> {
        serde_json::to_vec(&self.export())
            .expect("the export holds only finite numbers and strings")
    }
}
