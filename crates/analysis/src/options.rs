//! [`AnalysisOptions`]: the thresholds of the hybrid ordering, the grouping,
//! the lobe clustering and the lobe shapes.

use crate::error::AnalysisError;
use crate::hull::HullKind;

/// Thresholds of the analysis. Every default recovers the structure the
/// `treemorph-generate` presets are built with.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct AnalysisOptions {
    /// θ of Eq. 1, in degrees (default 10): a branching node is a symmetric
    /// (Weibull) fork when the standard deviation of its children's
    /// branching angles is at most this…
    pub weibull_angle: f32,
    /// …and r_t of Eq. 1, relative (default 0.1): the standard deviation of
    /// the children's radii divided by their mean radius is at most this.
    /// Relative so that it means the same on a trunk and on a twig.
    pub weibull_radius: f32,
    /// In degrees (default 90): the Gravelius continuation turns at most
    /// this far off the incoming branch. At a fork whose every child turns
    /// further, none continues the chain: it ends there and each child
    /// starts a chain of order + 1 (an axis does not turn back on itself).
    /// Of the ten third-party trees CI makes, Modular Tree's bushy tree has
    /// 8 forks whose every child turns back (one with six children at
    /// 149–154°), its weeping tree 2; the ez-tree trees none.
    pub continuation_angle: f32,
    /// θ of Eq. 3, in degrees (default 30): a two-chain group is opposite
    /// when its mean divergence angle is within this of 180°.
    pub opposite_tolerance: f32,
    /// Lateral chains of one parent chain join the current chain group while
    /// their growth locations lie within a tolerance of the group's first
    /// member: the larger of this many parent radii at that junction
    /// (default 0.5)…
    pub group_tolerance_radii: f32,
    /// …and this fraction of the parent branch entering that junction
    /// (default 0.75). Real skeletons rarely put a whorl on one node; a
    /// fraction of the internode before the group tolerates members spread
    /// over up to half an internode while keeping laterals one internode
    /// apart in separate groups.
    pub group_tolerance_segment: f32,
    /// How leaves are assigned to inner lobes (default
    /// [`LobeClustering::NearestBranch`]; the paper's literal centre-based
    /// clustering is [`LobeClustering::CentreKMeans`], which the next four
    /// fields tune).
    pub clustering: LobeClustering,
    /// Initial per-cluster distance threshold of the lobe clustering, as a
    /// fraction of the cluster's radius (default 0.35, paper §4.2).
    pub cluster_initial_threshold: f32,
    /// Growth of that threshold per iteration, as a fraction of the
    /// cluster's radius added each iteration (default 0.105).
    pub cluster_threshold_step: f32,
    /// Iterations after which leaves no cluster has reached go to the
    /// nearest cluster centre (default 64, when the threshold is ~7 radii).
    pub cluster_max_iterations: u32,
    /// Radius of a chain-tip cluster as a fraction of the chain's length
    /// (default 0.1, paper §4.2).
    pub tip_radius: f32,
    /// Shape of IL, OL and GOL hulls (default [`HullKind::Convex`]).
    pub hull: HullKind,
}

impl Default for AnalysisOptions {
    fn default() -> AnalysisOptions {
        AnalysisOptions {
            weibull_angle: 10.0,
            weibull_radius: 0.1,
            continuation_angle: 90.0,
            opposite_tolerance: 30.0,
            group_tolerance_radii: 0.5,
            group_tolerance_segment: 0.75,
            clustering: LobeClustering::NearestBranch,
            cluster_initial_threshold: 0.35,
            cluster_threshold_step: 0.105,
            cluster_max_iterations: 64,
            tip_radius: 0.1,
            hull: HullKind::Convex,
        }
    }
}

impl AnalysisOptions {
    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), AnalysisError> {
        let nonneg = [
            ("weibull_angle", self.weibull_angle),
            ("weibull_radius", self.weibull_radius),
            ("continuation_angle", self.continuation_angle),
            ("opposite_tolerance", self.opposite_tolerance),
            ("group_tolerance_radii", self.group_tolerance_radii),
            ("group_tolerance_segment", self.group_tolerance_segment),
            ("tip_radius", self.tip_radius),
        ];
        for (name, v) in nonneg {
            if !(v.is_finite() && v >= 0.0) {
                return Err(AnalysisError::InvalidOption {
                    option: name,
                    reason: format!("must be a finite number ≥ 0, got {v}"),
                });
            }
        }
        let positive = [
            ("cluster_initial_threshold", self.cluster_initial_threshold),
            ("cluster_threshold_step", self.cluster_threshold_step),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(AnalysisError::InvalidOption {
                    option: name,
                    reason: format!("must be a finite number > 0, got {v}"),
                });
            }
        }
        if let HullKind::Radial { rings, segments } = self.hull
            && (rings == 0 || segments < 3)
        {
            return Err(AnalysisError::InvalidOption {
                option: "hull",
                reason: format!(
                    "a radial hull needs ≥ 1 ring and ≥ 3 segments, got {rings} and {segments}"
                ),
            });
        }
        Ok(())
    }
}

/// How leaves are assigned to inner lobes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum LobeClustering {
    /// The default. A leaf's IL is the chain holding the skeleton branch
    /// nearest to its anchor (exact point-to-segment distance; a uniform
    /// grid keeps it fast). This is the paper's top-down threshold
    /// clustering with the distance to a cluster measured to the cluster's
    /// *skeleton* (chain `n` for a tip cluster, the child group's
    /// substructure for a crown cluster) instead of to its centre: the
    /// cluster owning the nearest branch is the nearest cluster, and it is
    /// within its first threshold for every leaf that sits on the bark, so
    /// the recursion reduces to this assignment. Only geometry is used (not
    /// [`Leaf::branch`](treemorph_tree::Leaf::branch)), so imported leaves
    /// that float near their twigs are handled the same way.
    #[default]
    NearestBranch,
    /// The paper's §4.2 clustering taken literally: distances to cluster
    /// centres (child-group crown centres and chain tips). On the
    /// generator's trees it puts only 10–75 % of the leaves in the IL of the
    /// chain they grow on, because the large crowns of child groups capture
    /// the leaves along their parent chain.
    CentreKMeans,
}
