//! Procedural leafy trees with ground truth.
//!
//! [`generate`] takes [`GenerateOptions`] — a [`Preset`], a seed and a size
//! (the number of branches, i.e. skeleton edges) — and returns a valid
//! [`Tree`]: a skeleton in metres (Y up, root at the origin), billboard
//! leaves with procedurally drawn textures ([`LeafShape`]), bark and leaf
//! materials, and a [`GroundTruth`] saying which hybrid order every branch
//! was meant to have and which chain groups were meant to exist. The
//! analysis stage (the morphing paper's §4.1, BPTT construction) is tested
//! against that ground truth rather than against itself.
//!
//! The same options always give the same tree, bit for bit: all randomness
//! comes from one `ChaCha8Rng` seeded with [`GenerateOptions::seed`].
//!
//! # Presets
//! The presets cover the branching variety the morphing paper morphs
//! between (its Figure 3 inset: alternate, opposite and whorled branching)
//! plus weeping, multi-stem and dichotomous forms:
//!
//! - [`Preset::Eucalyptus`] — monopodial: a straight trunk (order 1) to the
//!   top with a clear bole over its lower 40 %; **alternate** laterals in a
//!   137.5° spiral, ascending at 38–58°, longest a third of the way up the
//!   crown (ovoid, irregular: a quarter of the sites stay bare and vigour
//!   varies ±35 %). Lanceolate, slightly sickle-shaped grey-green leaves that
//!   hang (eucalypt leaves are pendulous).
//! - [`Preset::Maple`] — **opposite**, decussate: pairs of laterals 180°
//!   apart, successive pairs turned 90°, on the trunk and on every branch.
//!   The leader stops at ~70 % of the height and the long laterals (dome
//!   profile, 47–61°) bend up and outward into a broad rounded decurrent
//!   crown. Palmate five-lobed leaves in opposite pairs, facing up.
//! - [`Preset::Conifer`] — excurrent: a straight leader to the top with
//!   **whorls** of 3–5 near-horizontal laterals (67–73°) at every node above
//!   the lowest 10 %, evenly spread and turned between whorls; lateral length
//!   falls linearly toward the top (cone). Side branches are flat sprays
//!   (left/right alternate) that sag and turn up at the tips. Needle-spray
//!   billboards along the sprays.
//! - [`Preset::Willow`] — weeping: a short clear trunk, alternate scaffold
//!   limbs that rise at ~40° then arch over (gravitropism turning negative
//!   along the limb), and long pendulous branchlets (order ≥ 3) that leave
//!   the limbs sideways-down and hang vertically, stopping short of the
//!   ground. Narrow leaves that hang.
//! - [`Preset::Shrub`] — **multi-stem**: 3–7 stems (more on bigger shrubs)
//!   leave the root at one common tilt (14–26°), evenly spread around it
//!   (the root group is whorled), curve outward and carry alternate laterals;
//!   a spreading crown 1–4.5 m tall. Ovate leaves.
//! - [`Preset::Dichotomous`] — sympodial: every chain ends in a **symmetric
//!   fork** of 2 children (the first fork sometimes 3) at one common angle
//!   (28–36°), successive fork planes turned ~90°; chain length shrinks as
//!   `budget^⅓`, so each level is ~0.79 × the previous. No laterals. Round
//!   leaves on the terminal chains.
//!
//! # Size, height and the chains : branches ratio
//! `size` is the exact number of branches (skeleton edges; the skeleton has
//! `size + 1` nodes). Growth is budget driven: each chain gets the number of
//! branches of its substructure, keeps `n ≈ a · budget^⅓` internodes (fewer
//! for the dichotomous form) and splits the rest among its laterals by
//! vigour, never giving a lateral fewer than 3 branches (2 for forks). Larger
//! sizes therefore branch more finely and to higher orders, while the crown
//! silhouette stays that of the species. Height grows with size like a tree
//! grows older: 18 % of the species height at 50 branches, ~60 % at the
//! default 5,000 and the full height (4.5 m shrub … 30 m eucalyptus) near
//! 250,000. Chains average 3–4 branches: chains ≈ 0.24–0.32 × branches for
//! the monopodial presets (maple and willow, with longer chains, at the low
//! end) and 0.31–0.44 for the dichotomous one, whose last forks are only 2–3
//! branches long. So ~20,000 chains take 65,000–80,000 branches.
//!
//! Leaves grow with size too, but more slowly than branches (see
//! `foliage`): ~2 per branch up to 5,000 branches, ~1.1 at 20,000, ~0.75 at
//! 100,000 (70,000–100,000 leaves).
//!
//! # Ground truth and the conventions the geometry follows
//! [`GroundTruth::orders`] holds the intended hybrid (Gravelius/Weibull)
//! order of the branch ending at each node; [`GroundTruth::groups`] lists
//! every chain group, the root group first, each chain named by the node
//! that ends its first branch. The conventions — chosen where the paper's
//! Eq. 1–3 leave room — are:
//!
//! - Orders start at 1. The root node carries no branch; its entry is 1 and
//!   **every branch leaving the root has order 1**: the trunk, or each stem
//!   of a multi-stem shrub. The chains leaving the root form the **root
//!   group** (one trunk → alternate; the shrub's 3–7 stems → whorled).
//! - At a node with an asymmetric set of children (Gravelius), the child
//!   with the smallest branching angle — measured between a child's first
//!   branch and the branch entering the node — continues the parent's order
//!   and chain; the others start chains of order + 1. The generator keeps
//!   every continuation within 9° of the incoming direction and every
//!   lateral at 32–72°, and makes laterals at most 0.7 × as thick as the
//!   continuation.
//! - At a symmetric fork (Weibull: the dichotomous preset's forks and the
//!   shrub's root), the parent chain ends and every child starts a chain of
//!   order + 1 (order 1 at the root); the children form one group. Fork
//!   children share one branching angle exactly and get equal radii. *The
//!   paper's Eq. 2 gives Weibull children the parent's order; we follow the
//!   project's convention (order + 1) so that a chain never continues into
//!   two children.*
//! - A node with a single child continues its chain.
//! - A chain group is the chains of one order starting at one location of
//!   one parent chain: **alternate** = 1 chain, **opposite** = 2 chains whose
//!   divergence (the angle between their first branches projected onto the
//!   plane normal to the parent's incoming branch) is within 30° of 180°,
//!   **whorled** = anything else (here: 3–5 chains spread evenly, or 3 fork
//!   children). Members of a group leave from one node unless
//!   [`GenerateOptions::whorl_spread`] spreads them along the parent.
//!
//! # Radii, bending and leaves
//! Radii follow the pipe model (`parent² ≈ Σ children²` plus a little wood
//! per internode, so chains taper), scaled to the species' base radius, then
//! clamped so that no child is thicker than its parent. Chains bend by
//! gravitropism, phototropism away from the trunk axis, a little wobble and
//! (willow) a droop that grows along the chain, never turning more than 9°
//! per node. Leaves grow only on chains of order ≥ 2, on the distal part of
//! each chain and in a cluster at its tip, anchored on the bark
//! (`offset` = radius × the radial direction). Each preset uses two leaf
//! materials (one shape, two tints).
//!
//! # Performance
//! In a release build a 20,000-branch tree takes 7–10 ms and a
//! 100,000-branch tree ~30 ms. Each leaf texture is drawn and PNG-encoded once
//! per process, on first use (1–10 ms per shape), then shared. The crate's
//! ignored `timing` test prints the figures:
//! `cargo test --release -p treemorph-generate -- --ignored --nocapture`.

mod foliage;
mod grow;
mod leaf_shape;
mod pipe;
mod species;

use std::fmt;
use std::str::FromStr;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use thiserror::Error;
use treemorph_tree::{Bark, GroundTruth, LeafMaterial, Limits, Materials, Tree, TreeParts};

pub use leaf_shape::{LeafShape, leaf_textures};

/// A kind of tree the generator can grow. See the crate docs for each
/// preset's botanical model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Preset {
    /// Monopodial, alternate spiral branching, pendulous lanceolate leaves.
    Eucalyptus,
    /// Opposite decussate branching, broad rounded crown, palmate leaves.
    Maple,
    /// Excurrent cone with whorls of 3–5 laterals, needle sprays.
    Conifer,
    /// Weeping: arching limbs and hanging branchlets, narrow leaves.
    Willow,
    /// Several stems from the base, spreading crown, ovate leaves.
    Shrub,
    /// Sympodial: symmetric forks all the way, round leaves.
    Dichotomous,
}

impl Preset {
    /// Every preset, in the order of `treemorph generate --list`.
    pub const ALL: &'static [Preset] = &[
        Preset::Eucalyptus,
        Preset::Maple,
        Preset::Conifer,
        Preset::Willow,
        Preset::Shrub,
        Preset::Dichotomous,
    ];

    /// The preset's lower-case name, as parsed by [`Preset::from_str`].
    pub fn name(self) -> &'static str {
        match self {
            Preset::Eucalyptus => "eucalyptus",
            Preset::Maple => "maple",
            Preset::Conifer => "conifer",
            Preset::Willow => "willow",
            Preset::Shrub => "shrub",
            Preset::Dichotomous => "dichotomous",
        }
    }

    /// One line for listings and help.
    pub fn description(self) -> &'static str {
        match self {
            Preset::Eucalyptus => {
                "monopodial tree with alternate (spiral) branching and hanging lanceolate leaves"
            }
            Preset::Maple => {
                "opposite, decussate branching in a broad rounded crown with palmate leaves"
            }
            Preset::Conifer => "excurrent cone with whorls of 3-5 branches and needle sprays",
            Preset::Willow => "weeping tree: arching limbs with long hanging branchlets",
            Preset::Shrub => "multi-stem shrub: 3-7 stems from the base, spreading crown",
            Preset::Dichotomous => "sympodial tree of symmetric forks with round leaves",
        }
    }
}

impl fmt::Display for Preset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Preset {
    type Err = GenerateError;

    /// Parses a preset name, ignoring case and surrounding white space.
    fn from_str(s: &str) -> Result<Preset, GenerateError> {
        let wanted = s.trim();
        Preset::ALL
            .iter()
            .copied()
            .find(|p| p.name().eq_ignore_ascii_case(wanted))
            .ok_or_else(|| GenerateError::UnknownPreset {
                name: s.to_owned(),
                valid: valid_names(),
            })
    }
}

fn valid_names() -> String {
    Preset::ALL
        .iter()
        .map(|p| p.name())
        .collect::<Vec<_>>()
        .join(", ")
}

/// What to generate.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct GenerateOptions {
    /// The kind of tree. Default [`Preset::Eucalyptus`].
    pub preset: Preset,
    /// Seed of the random generator; equal options give identical trees.
    /// Default 0.
    pub seed: u64,
    /// Number of branches (skeleton edges), exactly; within
    /// [`GenerateOptions::MIN_SIZE`]`..=`[`GenerateOptions::MAX_SIZE`].
    /// Default [`GenerateOptions::DEFAULT_SIZE`].
    pub size: u32,
    /// Spreads the members of an opposite or whorled group along their
    /// parent chain instead of attaching them all to one node: member `j` of
    /// `k` sits `j / k × whorl_spread` of an internode further along, on a
    /// node of its own. A fraction of an internode in `0.0..=0.5`; default 0
    /// (all members on one node). Symmetric forks and the root group are
    /// never spread. Meant for testing tolerant chain grouping.
    pub whorl_spread: f32,
}

impl GenerateOptions {
    /// Default number of branches: 1,250–1,600 chains and 7,500–13,500
    /// leaves depending on the preset; quick to export and view.
    pub const DEFAULT_SIZE: u32 = 5_000;
    /// Smallest size: still a recognisable little tree with leaves.
    pub const MIN_SIZE: u32 = 50;
    /// Largest size.
    pub const MAX_SIZE: u32 = 250_000;
    /// Largest [`GenerateOptions::whorl_spread`].
    pub const MAX_WHORL_SPREAD: f32 = 0.5;

    /// Options for `preset` and `seed` with the default size.
    pub fn new(preset: Preset, seed: u64) -> GenerateOptions {
        GenerateOptions {
            preset,
            seed,
            size: GenerateOptions::DEFAULT_SIZE,
            whorl_spread: 0.0,
        }
    }

    /// Sets the number of branches.
    pub fn with_size(self, size: u32) -> GenerateOptions {
        GenerateOptions { size, ..self }
    }

    /// Sets [`GenerateOptions::whorl_spread`].
    pub fn with_whorl_spread(self, whorl_spread: f32) -> GenerateOptions {
        GenerateOptions {
            whorl_spread,
            ..self
        }
    }

    /// Checks the options.
    pub fn validate(&self) -> Result<(), GenerateError> {
        if !(GenerateOptions::MIN_SIZE..=GenerateOptions::MAX_SIZE).contains(&self.size) {
            return Err(GenerateError::SizeOutOfRange {
                size: self.size,
                min: GenerateOptions::MIN_SIZE,
                max: GenerateOptions::MAX_SIZE,
            });
        }
        if !(0.0..=GenerateOptions::MAX_WHORL_SPREAD).contains(&self.whorl_spread) {
            return Err(GenerateError::WhorlSpreadOutOfRange {
                value: self.whorl_spread,
                max: GenerateOptions::MAX_WHORL_SPREAD,
            });
        }
        Ok(())
    }
}

impl Default for GenerateOptions {
    fn default() -> GenerateOptions {
        GenerateOptions::new(Preset::Eucalyptus, 0)
    }
}

/// Why a tree could not be generated.
#[derive(Clone, Debug, Error, PartialEq)]
#[non_exhaustive]
pub enum GenerateError {
    /// The caller asked for a size outside the supported range.
    #[error("size {size} is out of range: the number of branches must be within {min}..={max}")]
    SizeOutOfRange {
        /// The size asked for.
        size: u32,
        /// Smallest size.
        min: u32,
        /// Largest size.
        max: u32,
    },
    /// The caller named no preset.
    #[error("unknown preset {name:?}; valid presets are: {valid}")]
    UnknownPreset {
        /// The name given.
        name: String,
        /// The valid names, comma separated.
        valid: String,
    },
    /// The caller asked for a whorl spread outside `0..=max` (or NaN).
    #[error("whorl_spread {value} is out of range: it must be within 0..={max} internodes")]
    WhorlSpreadOutOfRange {
        /// The value given.
        value: f32,
        /// Largest value.
        max: f32,
    },
    /// A bug: the generator made a tree the model refuses.
    #[error("internal error: the generated tree is invalid: {0}")]
    Internal(String),
}

/// Grows a tree. Errors only for out-of-range options (and internal bugs).
pub fn generate(options: &GenerateOptions) -> Result<Tree, GenerateError> {
    options.validate()?;
    let sp = species::species(options.preset);
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let mut grown = grow::grow(&sp, options.size, options.whorl_spread, &mut rng);
    let children = pipe::Children::of(&grown.nodes);
    pipe::assign_radii(&mut grown, &sp, &children);
    let leaves = foliage::place(&grown, &sp, &mut rng);
    let materials = Materials {
        bark: Bark {
            color: sp.bark,
            texture: None,
        },
        leaves: sp
            .foliage
            .kinds
            .iter()
            .map(|k| LeafMaterial {
                name: k.name.to_owned(),
                color: k.color,
                texture: Some(k.shape.texture()),
            })
            .collect(),
    };
    let parts = TreeParts {
        name: format!("{}-{}", options.preset.name(), options.seed),
        nodes: grown.nodes,
        leaves,
        materials,
        ground_truth: Some(GroundTruth {
            orders: grown.orders,
            groups: grown.groups,
        }),
    };
    Tree::new(parts, &Limits::default()).map_err(|e| GenerateError::Internal(e.to_string()))
}

#[cfg(test)]
#[path = "generate_tests.rs"]
mod tests;
