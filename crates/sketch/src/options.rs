//! [`SketchOptions`].

use serde::{Deserialize, Serialize};

use treemorph_tree::timing::ScheduleOptions;

use crate::error::SketchError;
use crate::sketch::Fit;

/// How the crown's deformation reaches the branches.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// The paper's method: the multiscale cage tree (§5.2–5.4), with
    /// self-adaptive cages and pruning when enabled.
    #[default]
    Multiscale,
    /// The paper's Figure 13 baseline: one global cage, the crown
    /// silhouette, moves every chain tip by its mean value coordinates; no
    /// self-adaptive cages, no pruning.
    SingleCage,
}

/// Tuning of the sketch pipeline. Screen-space lengths are fractions of the
/// crown silhouette's screen diagonal (the diagonal of its NDC bounding
/// box), so the same options work at any camera distance.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[non_exhaustive]
pub struct SketchOptions {
    /// Multiscale cage tree or single global cage (default
    /// [`Method::Multiscale`]).
    pub method: Method,
    /// How the sketch is placed relative to the crown (default
    /// [`Fit::None`]: as drawn).
    pub fit: Fit,
    /// Self-adaptive cages (§5.4.1): child cages stretch to cover the parts
    /// of their parent no child covers (default true; multiscale only).
    pub adaptive: bool,
    /// Branch pruning (§5.4.2): cages mostly outside the sketch wilt with
    /// their chains (default true; multiscale only).
    pub prune: bool,
    /// How strongly a branch's inner nodes follow the cage field (the mean
    /// value combination of the cage holding each node), relative to the
    /// Laplacian term of Eq. 1 (default 1; the trunk's inner nodes follow
    /// only its ends). 0 is the paper taken
    /// literally — only the tip is constrained — which lets a long chain
    /// carrying many others (a trunk through the crown) swing on a straight
    /// line between its ends while its children's cages go elsewhere.
    pub node_weight: f32,
    /// The paper's 10-pixel coverage threshold, as a fraction of the crown's
    /// screen diagonal (default 0.02 — 10 px of a crown ~500 px across).
    pub coverage_threshold: f32,
    /// How far a self-adaptive cage may stretch to cover an uncovered
    /// segment, as a fraction of the crown's screen diagonal (default
    /// 0.25): farther segments stay uncovered rather than tear a cage.
    pub adapt_reach: f32,
    /// Foliage-fit passes (see the `foliage` module docs): after planning,
    /// the t = 1 foliage outline is measured and the crown cage corrected
    /// so that the outline, rather than the crown's convex silhouette,
    /// lands on the sketch; each pass is one more correction and one more
    /// measured t = 1 frame (default 3; 0: the paper's crown mapping alone;
    /// at most 8; multiscale closed sketches only).
    pub foliage_passes: u32,
    /// Pruning threshold on the area ratio r = area(cage ∩ sketch) /
    /// area(cage) (default 0.3, the paper's 30 %).
    pub prune_ratio: f32,
    /// r at or above which a cage counts as inside the sketch and its
    /// subtree is not tested further (default 0.95 — the paper's "r ≈ 1").
    pub inside_ratio: f32,
    /// Uniform arc-length samples of the crown correspondence, on top of the
    /// silhouette's and sketch's own corners (default 128, at least 16).
    pub crown_samples: usize,
    /// Cages whose silhouette area is below this fraction of the crown
    /// silhouette's area are skipped: their children hang from the next
    /// cage up (default 1e-5).
    pub min_cage_area: f32,
    /// Largest distance from an open sketch's end to the crown silhouette,
    /// as a fraction of the crown's screen diagonal (default 0.15).
    pub open_snap_distance: f32,
    /// Side of the square raster the metrics draw foliage into, pixels
    /// (default 256, at least 32).
    pub raster_size: u32,
    /// Radius of the morphological closing that turns the projected leaf
    /// blades into the foliage's outline, as a fraction of the crown's
    /// screen diagonal (default 0.03).
    pub closing_radius: f32,
    /// When each chain moves (default staged: pruned subtrees wilt
    /// first, parents lead their twigs, each eased; see the `time`
    /// module). `linear` runs every chain on `t` itself.
    pub schedule: ScheduleOptions,
}

impl Default for SketchOptions {
    fn default() -> SketchOptions {
        SketchOptions {
            method: Method::Multiscale,
            fit: Fit::None,
            adaptive: true,
            prune: true,
            node_weight: 1.0,
            coverage_threshold: 0.02,
            adapt_reach: 0.25,
            foliage_passes: 3,
            prune_ratio: 0.3,
            inside_ratio: 0.95,
            crown_samples: 128,
            min_cage_area: 1e-5,
            open_snap_distance: 0.15,
            raster_size: 256,
            closing_radius: 0.03,
            schedule: ScheduleOptions::default(),
        }
    }
}

impl SketchOptions {
    /// Options for `method`, defaults otherwise.
    pub fn with_method(self, method: Method) -> SketchOptions {
        SketchOptions { method, ..self }
    }

    /// Options with `fit`.
    pub fn with_fit(self, fit: Fit) -> SketchOptions {
        SketchOptions { fit, ..self }
    }

    /// Options with another schedule.
    pub fn with_schedule(self, schedule: ScheduleOptions) -> SketchOptions {
        SketchOptions { schedule, ..self }
    }

    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), SketchError> {
        if let Some((option, reason)) = self.schedule.invalid_field() {
            return Err(SketchError::InvalidOption { option, reason });
        }
        let fractions = [
            ("node_weight", self.node_weight, 0.0, 1000.0),
            ("coverage_threshold", self.coverage_threshold, 0.0, 1.0),
            ("adapt_reach", self.adapt_reach, 0.0, 10.0),
            ("prune_ratio", self.prune_ratio, 0.0, 1.0),
            ("inside_ratio", self.inside_ratio, 0.0, 1.0),
            ("min_cage_area", self.min_cage_area, 0.0, 1.0),
            ("open_snap_distance", self.open_snap_distance, 0.0, 10.0),
            ("closing_radius", self.closing_radius, 0.0, 1.0),
        ];
        for (option, v, lo, hi) in fractions {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err(SketchError::InvalidOption {
                    option,
                    reason: format!("must be a finite number within [{lo}, {hi}], got {v}"),
                });
            }
        }
        if self.prune_ratio > self.inside_ratio {
            return Err(SketchError::InvalidOption {
                option: "prune_ratio",
                reason: format!(
                    "must not exceed inside_ratio ({}), got {}",
                    self.inside_ratio, self.prune_ratio
                ),
            });
        }
        if self.foliage_passes > 8 {
            return Err(SketchError::InvalidOption {
                option: "foliage_passes",
                reason: format!("must be at most 8, got {}", self.foliage_passes),
            });
        }
        if !(16..=4096).contains(&self.crown_samples) {
            return Err(SketchError::InvalidOption {
                option: "crown_samples",
                reason: format!("must be within 16..=4096, got {}", self.crown_samples),
            });
        }
        if !(32..=4096).contains(&self.raster_size) {
            return Err(SketchError::InvalidOption {
                option: "raster_size",
                reason: format!("must be within 32..=4096, got {}", self.raster_size),
            });
        }
        Ok(())
    }
}
