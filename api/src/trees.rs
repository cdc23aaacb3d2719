//! Wire types of the `/v1/trees` resource.

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

/// Counts of chain groups by branching pattern.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct PatternCounts {
    /// Chain groups with one chain (alternate branching).
    pub alternate: u32,
    /// Chain groups with two opposite chains.
    pub opposite: u32,
    /// Chain groups with three or more chains around the parent (whorled).
    pub whorled: u32,
}

/// What the skeleton-lobe analysis found in a tree.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct TreeStats {
    /// Branches (skeleton edges).
    pub branches: u32,
    /// Chains found by the analysis.
    pub chains: u32,
    /// Chain groups found by the analysis.
    pub chain_groups: u32,
    /// Leaves.
    pub leaves: u32,
    /// Chain groups by branching pattern.
    pub patterns: PatternCounts,
    /// Height of the tree in metres (Y extent of the skeleton).
    pub height: f32,
}

/// A stored tree.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct TreeInfo {
    /// The tree's id (use it in job requests and URLs).
    pub id: String,
    /// A name for people (`?name=` at upload, or `preset-seed` when
    /// generated).
    pub name: String,
    /// How the tree arrived: `tree+json`, `glb`, `gltf` or `generated`.
    pub format: String,
    /// When the tree was stored (RFC 3339, UTC).
    pub created_at: String,
    /// Analysis summary.
    pub stats: TreeStats,
}

/// One page of trees, newest first.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct TreePage {
    /// The trees on this page.
    pub items: Vec<TreeInfo>,
    /// Pass as `?cursor=` for the next page; absent on the last page.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub next_cursor: Option<String>,
}

/// The seed of a generated tree when the request names none.
pub const DEFAULT_SEED: u64 = 1;

fn default_seed() -> u64 {
    DEFAULT_SEED
}

/// `POST /v1/trees/generate`: a procedural tree.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct GenerateRequest {
    /// Preset name (as `treemorph generate --list` prints them).
    #[schema(pattern = r"^(eucalyptus|maple|conifer|willow|shrub|dichotomous)$")]
    pub preset: String,
    /// Random seed (at most 2^63 - 1); 1 when absent.
    #[serde(default = "default_seed", deserialize_with = "crate::int::u63")]
    #[schema(default = 1)]
    pub seed: u64,
    /// Number of branches; 5,000 when absent.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "crate::int::opt_u32"
    )]
    #[schema(minimum = 50, maximum = 250000)]
    pub size: Option<u32>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_generate_request_may_leave_the_seed_out() {
        let r: GenerateRequest = serde_json::from_str(r#"{"preset": "maple"}"#).unwrap();
        assert_eq!(r.seed, DEFAULT_SEED);
        let r: GenerateRequest =
            serde_json::from_str(r#"{"preset": "maple", "seed": 7, "size": 300}"#).unwrap();
        assert_eq!((r.seed, r.size), (7, Some(300)));
        assert!(
            serde_json::from_str::<GenerateRequest>(r#"{"preset": "maple", "seed": -1}"#).is_err()
        );
    }
}
