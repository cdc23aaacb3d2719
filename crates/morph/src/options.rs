//! [`MorphOptions`]: the weights of the correspondence costs (Eq. 4), the
//! baselines, and the split schedule.

use serde::{Deserialize, Serialize};

use crate::error::MorphError;
pub use treemorph_tree::timing::{ScheduleKind, ScheduleOptions};

/// Weights of the chain-group (BPTT node) cost, the morphing paper's Eq. 4.
///
/// Every term is normalised to roughly `[0, 1]` so that the weights compare
/// like with like (see the crate docs, *Costs*).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[non_exhaustive]
pub struct GroupCostWeights {
    /// GOL: symmetric Hausdorff distance between the two group outer lobes,
    /// each tree scaled to unit height (default 1).
    pub outer_lobe: f32,
    /// Gv: distance between the unit mean branching vectors, halved so it
    /// lies in `[0, 1]` (default 1).
    pub branching_vector: f32,
    /// GR: difference of the group lobe ratios (arc-length fractions;
    /// default 0.5).
    pub lobe_ratio: f32,
    /// `|#GC_s − #GC_t| / max(#GC_s, #GC_t)`: chain counts (default 0.5).
    pub chain_count: f32,
    /// Difference of the mean divergence angles divided by 180°, when both
    /// groups have two or more chains (default 0.5).
    pub divergence: f32,
    /// Gp: difference of the growth locations on the parent chains
    /// (arc-length fractions; default 1).
    pub growth_location: f32,
    /// The group cost one crossing is worth: after the minimum-weight
    /// matching of a star's child groups, partners are swapped where that
    /// removes sibling limbs passing through each other mid-morph for less
    /// added cost, and never for more than this (`crossing.rs`; default
    /// 0.5; 0 keeps the matching).
    pub crossing: f32,
}

impl Default for GroupCostWeights {
    fn default() -> GroupCostWeights {
        GroupCostWeights {
            outer_lobe: 1.0,
            branching_vector: 1.0,
            lobe_ratio: 0.5,
            chain_count: 0.5,
            divergence: 0.5,
            growth_location: 1.0,
            crossing: 0.5,
        }
    }
}

/// Weights of the chain cost (the paper: "the weighted sum of similarities
/// between their feature parameters in Table 1").
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[non_exhaustive]
pub struct ChainCostWeights {
    /// v: distance between the unit branching vectors, halved (default 1).
    pub branching_vector: f32,
    /// p: difference of the growth locations (default 1).
    pub growth_location: f32,
    /// chn: difference of the chain lengths, each divided by its tree's
    /// height (default 0.5).
    pub length: f32,
    /// OR: difference of the outer lobe ratios (default 0.25).
    pub outer_ratio: f32,
    /// IR: difference of the inner lobe ratios (default 0.25).
    pub inner_ratio: f32,
    /// OL: Hausdorff distance between the outer lobes' bounding spheres
    /// (`|Δcentre| + |Δradius|`), each tree scaled to unit height
    /// (default 0.5).
    pub outer_lobe: f32,
}

impl Default for ChainCostWeights {
    fn default() -> ChainCostWeights {
        ChainCostWeights {
            branching_vector: 1.0,
            growth_location: 1.0,
            length: 0.5,
            outer_ratio: 0.25,
            inner_ratio: 0.25,
            outer_lobe: 0.5,
        }
    }
}

/// Weights of the leaf cost (the paper: "the weighted sum of similarities
/// between their leaf positions, widths, heights, and orientations").
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[non_exhaustive]
pub struct LeafCostWeights {
    /// Difference of the arc-length positions along the chains (default 1).
    pub position: f32,
    /// Distance between the unit offset directions around the chain, in the
    /// chain frames, halved (default 0.25).
    pub azimuth: f32,
    /// `|Δw| / (w_s + w_t) + |Δh| / (h_s + h_t)`: blade sizes (default
    /// 0.25).
    pub size: f32,
    /// Angle between the orientations relative to the chain frames, divided
    /// by 180° (default 0.25).
    pub orientation: f32,
}

impl Default for LeafCostWeights {
    fn default() -> LeafCostWeights {
        LeafCostWeights {
            position: 1.0,
            azimuth: 0.25,
            size: 0.25,
            orientation: 0.25,
        }
    }
}

/// How chains inside matched chain groups are matched.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum ChainMatching {
    /// The paper (§5): greedy one-to-many, so surplus chains **split** from
    /// or **merge** into their most similar partner (default).
    #[default]
    OneToMany,
    /// Baseline: one-to-one only, as in the topology-aware tree blending
    /// the paper compares with (Wang et al., TVCG 2017): surplus chains
    /// **grow** or **wilt** instead.
    OneToOne,
}

/// How leaves are matched and moved.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum LeafMorph {
    /// The paper (§6.2): leaves matched greedily inside matched inner lobes
    /// and carried by their morphed chains (default).
    #[default]
    OnChains,
    /// Baseline (the paper's Figure 11): leaves matched at random over the
    /// whole tree and their world positions and orientations interpolated
    /// independently of the chains.
    RandomLinear {
        /// Seed of the random matching.
        seed: u64,
    },
}

/// What [`MorphPlan::new`](crate::MorphPlan::new) builds. Every default is
/// the paper's method; the baselines are options. Deserialises from JSON
/// with every field optional (e.g. `{"chain_matching": "one_to_one"}`);
/// [`MorphPlan::new`](crate::MorphPlan::new) validates it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[non_exhaustive]
pub struct MorphOptions {
    /// Weights of the chain-group cost (Eq. 4).
    pub group_weights: GroupCostWeights,
    /// Cost, in the units of the weighted group cost, of leaving one chain
    /// group unmatched (it wilts or grows with its substructure). Two groups
    /// are matched only when their cost is below twice this (default 1.5:
    /// morphing a dissimilar branch reads better than one crown wilting
    /// while another grows, so only very different groups stay unmatched).
    pub unmatched_group_cost: f32,
    /// Weights of the chain cost.
    pub chain_weights: ChainCostWeights,
    /// Weights of the leaf cost.
    pub leaf_weights: LeafCostWeights,
    /// One-to-many (paper, default) or one-to-one (baseline) chain matching.
    pub chain_matching: ChainMatching,
    /// Leaves on chains (paper, default) or random and linear (baseline).
    pub leaf_morph: LeafMorph,
    /// Apply the paper's slow-down coefficient to split and merge copies
    /// (default true); when false they morph uniformly like one-to-one
    /// chains.
    pub slow_down: bool,
    /// When each operation happens (default staged).
    pub schedule: ScheduleOptions,
    /// Staged: a limb that still swings through a sibling after the
    /// matching bows round it mid-window, and junctions that slide past
    /// each other stand off the parent's axis (`routing.rs`; default
    /// true).
    pub route_round: bool,
    /// Staged: a blend that still passes through another branch is shed
    /// and regrown instead, its chains taken out of the matching
    /// (`untangling.rs`; default true).
    pub untangle: bool,
    /// Union nodes plus leaves above which a frame is computed with rayon
    /// (default 20,000); smaller trees run on the calling thread.
    pub parallel_threshold: usize,
}

impl Default for MorphOptions {
    fn default() -> MorphOptions {
        MorphOptions {
            group_weights: GroupCostWeights::default(),
            unmatched_group_cost: 1.5,
            chain_weights: ChainCostWeights::default(),
            leaf_weights: LeafCostWeights::default(),
            chain_matching: ChainMatching::OneToMany,
            leaf_morph: LeafMorph::OnChains,
            slow_down: true,
            schedule: ScheduleOptions::default(),
            route_round: true,
            untangle: true,
            parallel_threshold: 20_000,
        }
    }
}

impl MorphOptions {
    /// The TVCG 2017 baseline: one-to-one chain matching, everything else
    /// as the paper.
    pub fn one_to_one() -> MorphOptions {
        MorphOptions {
            chain_matching: ChainMatching::OneToOne,
            ..MorphOptions::default()
        }
    }

    /// The Figure 11 baseline: random leaf matching with linear world
    /// positions, everything else as the paper.
    pub fn random_leaves(seed: u64) -> MorphOptions {
        MorphOptions {
            leaf_morph: LeafMorph::RandomLinear { seed },
            ..MorphOptions::default()
        }
    }

    /// These options with another chain matching. The presets above are
    /// shorthands for these setters; setters compose (one-to-one matching
    /// with random leaves is
    /// `MorphOptions::default().with_chain_matching(…).with_leaf_morph(…)`).
    pub fn with_chain_matching(self, chain_matching: ChainMatching) -> MorphOptions {
        MorphOptions {
            chain_matching,
            ..self
        }
    }

    /// These options with another leaf morph.
    pub fn with_leaf_morph(self, leaf_morph: LeafMorph) -> MorphOptions {
        MorphOptions { leaf_morph, ..self }
    }

    /// These options with the slow-down coefficient on or off.
    pub fn with_slow_down(self, slow_down: bool) -> MorphOptions {
        MorphOptions { slow_down, ..self }
    }

    /// These options with routing round siblings on or off.
    pub fn with_route_round(self, route_round: bool) -> MorphOptions {
        MorphOptions {
            route_round,
            ..self
        }
    }

    /// These options with untangling crossing blends on or off.
    pub fn with_untangle(self, untangle: bool) -> MorphOptions {
        MorphOptions { untangle, ..self }
    }

    /// These options with another schedule.
    pub fn with_schedule(self, schedule: ScheduleOptions) -> MorphOptions {
        MorphOptions { schedule, ..self }
    }

    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), MorphError> {
        if let Some((option, reason)) = self.schedule.invalid_field() {
            return Err(MorphError::InvalidOption { option, reason });
        }
        let g = &self.group_weights;
        let c = &self.chain_weights;
        let l = &self.leaf_weights;
        let fields = [
            ("group_weights.outer_lobe", g.outer_lobe),
            ("group_weights.branching_vector", g.branching_vector),
            ("group_weights.lobe_ratio", g.lobe_ratio),
            ("group_weights.chain_count", g.chain_count),
            ("group_weights.divergence", g.divergence),
            ("group_weights.growth_location", g.growth_location),
            ("group_weights.crossing", g.crossing),
            ("unmatched_group_cost", self.unmatched_group_cost),
            ("chain_weights.branching_vector", c.branching_vector),
            ("chain_weights.growth_location", c.growth_location),
            ("chain_weights.length", c.length),
            ("chain_weights.outer_ratio", c.outer_ratio),
            ("chain_weights.inner_ratio", c.inner_ratio),
            ("chain_weights.outer_lobe", c.outer_lobe),
            ("leaf_weights.position", l.position),
            ("leaf_weights.azimuth", l.azimuth),
            ("leaf_weights.size", l.size),
            ("leaf_weights.orientation", l.orientation),
        ];
        for (option, v) in fields {
            if !(v.is_finite() && v >= 0.0) {
                return Err(MorphError::InvalidOption {
                    option,
                    reason: format!("must be a finite number ≥ 0, got {v}"),
                });
            }
        }
        Ok(())
    }
}

/// Constants of [`FrameMetrics`](crate::FrameMetrics).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[non_exhaustive]
pub struct MetricsOptions {
    /// Wood density for branch weights, kg/m³ (default 600, a mid value for
    /// green hardwood). Only the ratio to `leaf_area_density` matters to
    /// MTSW.
    pub wood_density: f32,
    /// Leaf weight per blade area (width × height), kg/m² (default 0.2: a
    /// fresh leaf of ~100 g/m² dry mass over a blade covering about half its
    /// billboard).
    pub leaf_area_density: f32,
    /// ε of the floating checks, as a fraction of the plan's height
    /// (default 1e-4).
    pub floating_epsilon: f32,
    /// A root chain counts as a main trunk of the in-between tree when its
    /// base radius is at least this fraction of the thickest root chain's
    /// (default 0.5); thinner root chains are carried by the thickest one.
    pub main_trunk_radius_ratio: f32,
}

impl Default for MetricsOptions {
    fn default() -> MetricsOptions {
        MetricsOptions {
            wood_density: 600.0,
            leaf_area_density: 0.2,
            floating_epsilon: 1e-4,
            main_trunk_radius_ratio: 0.5,
        }
    }
}
