//! Per-preset botanical parameters.
//!
//! Every preset is a [`Species`]: a root form (one trunk or several stems), a
//! growth form (monopodial or dichotomous), three [`Level`]s of chain
//! parameters (order 1, order 2, order ≥ 3) and a [`Foliage`] description.
//! The numbers were tuned by looking at renders; the comments say what each
//! one does to the silhouette.

use crate::Preset;
use crate::leaf_shape::LeafShape;

/// How chains leave the root node.
#[derive(Clone, Copy, Debug)]
pub(crate) enum RootForm {
    /// One trunk chain; `length` is its length as a fraction of the tree
    /// height.
    Trunk { length: f32 },
    /// `min..=max` stems (scaled with the size), all tilted by the same angle
    /// from the vertical, drawn from `tilt` (degrees) once per tree.
    Stems {
        min: u32,
        max: u32,
        tilt: (f32, f32),
        length: f32,
    },
}

/// How a chain ends and where its children grow.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Form {
    /// Laterals along the chain, the chain itself continues to its tip.
    Monopodial,
    /// No laterals: the chain ends in a symmetric fork of 2 (sometimes 3)
    /// chains. `angle` is the branching angle of every fork child (degrees,
    /// drawn once per fork), `three_way` the chance that the first fork has
    /// three children.
    Dichotomous { angle: (f32, f32), three_way: f32 },
}

/// Arrangement of the lateral chain groups along a parent chain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Phyllotaxis {
    /// One lateral per site, successive sites 137.5° apart (alternate).
    Spiral,
    /// One lateral per site, alternately left and right of the chain in the
    /// plane of the vertical (flat sprays; alternate).
    Distichous,
    /// One lateral per site, alternately left and right and tilted downward
    /// (willow branchlets; alternate).
    Pendant,
    /// Two laterals 180° apart per site, successive pairs rotated by 90°
    /// (opposite).
    Decussate,
    /// `min..=max` laterals evenly spread per site (whorled).
    Whorled { min: u32, max: u32 },
}

/// Length weight of the laterals along their parent chain, as a function of
/// `u` ∈ [0, 1]: 0 at the lowest site, 1 at the chain tip.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Profile {
    /// Longest at the base, shrinking linearly to `tip` (excurrent cone).
    Cone { tip: f32 },
    /// `base` at the bottom, 1 at `peak`, `tip` at the top (ovoid crown).
    Ovoid { base: f32, peak: f32, tip: f32 },
    /// A half ellipse: broad rounded dome (decurrent crowns).
    Dome,
    /// Linear from `base` to `tip`.
    Linear { base: f32, tip: f32 },
}

impl Profile {
    pub(crate) fn eval(self, u: f32) -> f32 {
        let u = u.clamp(0.0, 1.0);
        match self {
            Profile::Cone { tip } => tip + (1.0 - tip) * (1.0 - u),
            Profile::Ovoid { base, peak, tip } => {
                if u < peak {
                    let s = smoothstep(u / peak);
                    base + (1.0 - base) * s
                } else {
                    let s = smoothstep((u - peak) / (1.0 - peak));
                    1.0 + (tip - 1.0) * s
                }
            }
            Profile::Dome => 0.25 + 0.75 * (1.0 - u * u).max(0.0).sqrt(),
            Profile::Linear { base, tip } => base + (tip - base) * u,
        }
    }
}

fn smoothstep(x: f32) -> f32 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// Parameters of the chains of one order (level 0 = order 1, level 1 =
/// order 2, level 2 = every higher order).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Level {
    /// Own internodes `n = clamp(round(a · budget^e), n_min, n_max)`.
    pub a: f32,
    pub e: f32,
    pub n_min: u32,
    pub n_max: u32,
    /// Smallest budget (branches) a lateral of this chain receives.
    pub min_child: u32,
    /// Fraction of the chain at its base without laterals (clear bole).
    pub bare: f32,
    /// Probability that a site carries no lateral group.
    pub skip: f32,
    /// Arrangement of this chain's laterals.
    pub phyllotaxis: Phyllotaxis,
    /// Length weight of this chain's laterals along it.
    pub profile: Profile,
    /// Branching angle of this chain's laterals: mean and jitter, degrees.
    pub angle: (f32, f32),
    /// Length of a lateral relative to this chain's length at profile 1.
    pub ratio: f32,
    /// Relative random variation of each lateral's vigour (length, budget).
    pub vigor: f32,
    /// Gravitropism of this chain: `grav.0 + grav.1 · s` along the chain
    /// (s ∈ [0, 1]); positive bends up, negative droops.
    pub grav: (f32, f32),
    /// Phototropism: bends away from the trunk axis, horizontally.
    pub photo: f32,
    /// Random bending per internode.
    pub wobble: f32,
    /// Hanging chains are kept short enough not to reach the ground.
    pub hang: bool,
}

/// How leaves sit on the twigs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum LeafArrangement {
    /// One leaf per position, spiralling 137.5°.
    Alternate,
    /// Pairs 180° apart, successive pairs rotated 90°.
    Opposite,
    /// Billboards alternately left and right along the twig (needle sprays).
    Sides,
}

/// Leaf material: the shape drawn and a colour multiplier.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LeafKind {
    pub name: &'static str,
    pub shape: LeafShape,
    pub color: [f32; 4],
}

/// Foliage parameters.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Foliage {
    /// One or two materials; a chain uses the second with `second_share`
    /// probability.
    pub kinds: &'static [LeafKind],
    pub second_share: f32,
    /// Blade height (base to tip) in metres; width follows the texture's
    /// aspect ratio.
    pub length: f32,
    /// Leaves per internode in a leaf zone.
    pub per_internode: u32,
    pub arrangement: LeafArrangement,
    /// Leaves in the terminal cluster of every leafy chain.
    pub tip: u32,
    /// Distal fraction of a chain without laterals that bears leaves.
    pub twig_zone: f32,
    /// Distal fraction of a chain with laterals that bears leaves.
    pub branch_zone: f32,
    /// Angle between the blade and the twig axis, degrees.
    pub spread: f32,
    /// Vertical bias of the blade direction: positive points the blades up,
    /// negative makes them hang.
    pub lift: f32,
}

/// A preset's complete parameter set.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Species {
    /// Height in metres at the largest sizes; smaller sizes are younger,
    /// shorter trees.
    pub height: f32,
    /// Radius at the root as a fraction of the height.
    pub base_radius: f32,
    /// Largest twig-tip radius in metres (small trees).
    pub tip_radius_max: f32,
    pub bark: [f32; 4],
    pub root: RootForm,
    pub form: Form,
    pub levels: [Level; 3],
    pub foliage: Foliage,
}

impl Species {
    /// The parameters of the chains of `order` (1-based).
    pub(crate) fn level(&self, order: u32) -> &Level {
        &self.levels[(order.saturating_sub(1) as usize).min(2)]
    }
}

const fn lvl(a: f32, n_min: u32, n_max: u32) -> Level {
    Level {
        a,
        e: 1.0 / 3.0,
        n_min,
        n_max,
        min_child: 3,
        bare: 0.15,
        skip: 0.15,
        phyllotaxis: Phyllotaxis::Spiral,
        profile: Profile::Linear {
            base: 1.0,
            tip: 0.45,
        },
        angle: (45.0, 8.0),
        ratio: 0.5,
        vigor: 0.25,
        grav: (0.04, 0.0),
        photo: 0.03,
        wobble: 0.05,
        hang: false,
    }
}

const WHITE: [f32; 4] = [1.0, 1.0, 1.0, 1.0];

static EUCALYPTUS_LEAVES: [LeafKind; 2] = [
    LeafKind {
        name: "eucalyptus adult",
        shape: LeafShape::Lanceolate,
        color: WHITE,
    },
    LeafKind {
        name: "eucalyptus young",
        shape: LeafShape::Lanceolate,
        color: [1.0, 0.86, 0.74, 1.0],
    },
];
static MAPLE_LEAVES: [LeafKind; 2] = [
    LeafKind {
        name: "maple",
        shape: LeafShape::Palmate,
        color: WHITE,
    },
    LeafKind {
        name: "maple sunlit",
        shape: LeafShape::Palmate,
        color: [1.0, 1.0, 0.72, 1.0],
    },
];
static CONIFER_LEAVES: [LeafKind; 2] = [
    LeafKind {
        name: "needles",
        shape: LeafShape::Needles,
        color: WHITE,
    },
    LeafKind {
        name: "needles new growth",
        shape: LeafShape::Needles,
        color: [0.92, 1.0, 0.8, 1.0],
    },
];
static WILLOW_LEAVES: [LeafKind; 2] = [
    LeafKind {
        name: "willow",
        shape: LeafShape::Narrow,
        color: WHITE,
    },
    LeafKind {
        name: "willow pale",
        shape: LeafShape::Narrow,
        color: [1.0, 1.0, 0.8, 1.0],
    },
];
static SHRUB_LEAVES: [LeafKind; 2] = [
    LeafKind {
        name: "ovate",
        shape: LeafShape::Ovate,
        color: WHITE,
    },
    LeafKind {
        name: "ovate shade",
        shape: LeafShape::Ovate,
        color: [0.78, 0.88, 0.8, 1.0],
    },
];
static DICHOTOMOUS_LEAVES: [LeafKind; 2] = [
    LeafKind {
        name: "round",
        shape: LeafShape::Round,
        color: WHITE,
    },
    LeafKind {
        name: "round light",
        shape: LeafShape::Round,
        color: [0.95, 1.0, 0.78, 1.0],
    },
];

/// The parameters of a preset.
pub(crate) fn species(preset: Preset) -> Species {
    match preset {
        Preset::Eucalyptus => Species {
            height: 30.0,
            base_radius: 1.0 / 70.0,
            tip_radius_max: 0.006,
            bark: [0.58, 0.54, 0.47, 1.0],
            root: RootForm::Trunk { length: 0.93 },
            form: Form::Monopodial,
            levels: [
                Level {
                    bare: 0.4,
                    skip: 0.25,
                    profile: Profile::Ovoid {
                        base: 0.7,
                        peak: 0.3,
                        tip: 0.3,
                    },
                    angle: (48.0, 10.0),
                    ratio: 0.42,
                    vigor: 0.35,
                    grav: (0.04, 0.0),
                    photo: 0.0,
                    wobble: 0.035,
                    ..lvl(2.0, 8, 70)
                },
                Level {
                    bare: 0.2,
                    skip: 0.2,
                    angle: (45.0, 10.0),
                    ratio: 0.5,
                    vigor: 0.3,
                    grav: (0.06, 0.0),
                    photo: 0.04,
                    wobble: 0.06,
                    ..lvl(1.6, 4, 40)
                },
                Level {
                    angle: (42.0, 8.0),
                    ratio: 0.55,
                    grav: (0.03, 0.0),
                    wobble: 0.07,
                    ..lvl(1.4, 3, 24)
                },
            ],
            foliage: Foliage {
                kinds: &EUCALYPTUS_LEAVES,
                second_share: 0.25,
                length: 0.15,
                per_internode: 1,
                arrangement: LeafArrangement::Alternate,
                tip: 3,
                twig_zone: 0.7,
                branch_zone: 0.3,
                spread: 50.0,
                lift: -0.6,
            },
        },
        Preset::Maple => Species {
            height: 20.0,
            base_radius: 1.0 / 55.0,
            tip_radius_max: 0.006,
            bark: [0.36, 0.32, 0.28, 1.0],
            root: RootForm::Trunk { length: 0.72 },
            form: Form::Monopodial,
            levels: [
                Level {
                    bare: 0.3,
                    skip: 0.1,
                    phyllotaxis: Phyllotaxis::Decussate,
                    profile: Profile::Dome,
                    angle: (55.0, 6.0),
                    ratio: 0.78,
                    vigor: 0.2,
                    grav: (0.03, 0.0),
                    photo: 0.0,
                    wobble: 0.03,
                    ..lvl(1.8, 6, 50)
                },
                Level {
                    skip: 0.15,
                    phyllotaxis: Phyllotaxis::Decussate,
                    angle: (50.0, 8.0),
                    ratio: 0.55,
                    grav: (0.07, -0.04),
                    photo: 0.07,
                    ..lvl(1.5, 4, 30)
                },
                Level {
                    phyllotaxis: Phyllotaxis::Decussate,
                    angle: (48.0, 8.0),
                    grav: (0.03, 0.0),
                    photo: 0.04,
                    wobble: 0.06,
                    ..lvl(1.4, 3, 20)
                },
            ],
            foliage: Foliage {
                kinds: &MAPLE_LEAVES,
                second_share: 0.3,
                length: 0.13,
                per_internode: 2,
                arrangement: LeafArrangement::Opposite,
                tip: 2,
                twig_zone: 0.7,
                branch_zone: 0.3,
                spread: 55.0,
                lift: 0.35,
            },
        },
        Preset::Conifer => Species {
            height: 28.0,
            base_radius: 1.0 / 65.0,
            tip_radius_max: 0.005,
            bark: [0.38, 0.24, 0.16, 1.0],
            root: RootForm::Trunk { length: 0.98 },
            form: Form::Monopodial,
            levels: [
                Level {
                    bare: 0.1,
                    skip: 0.0,
                    phyllotaxis: Phyllotaxis::Whorled { min: 3, max: 5 },
                    profile: Profile::Cone { tip: 0.06 },
                    angle: (70.0, 3.0),
                    ratio: 0.3,
                    vigor: 0.12,
                    grav: (0.05, 0.0),
                    photo: 0.0,
                    wobble: 0.01,
                    ..lvl(1.7, 8, 60)
                },
                Level {
                    bare: 0.1,
                    skip: 0.1,
                    phyllotaxis: Phyllotaxis::Distichous,
                    profile: Profile::Linear {
                        base: 1.0,
                        tip: 0.3,
                    },
                    angle: (55.0, 8.0),
                    ratio: 0.45,
                    vigor: 0.2,
                    grav: (-0.05, 0.12),
                    photo: 0.0,
                    wobble: 0.03,
                    ..lvl(1.5, 4, 40)
                },
                Level {
                    bare: 0.1,
                    phyllotaxis: Phyllotaxis::Distichous,
                    profile: Profile::Linear {
                        base: 1.0,
                        tip: 0.4,
                    },
                    angle: (50.0, 8.0),
                    grav: (0.0, 0.0),
                    photo: 0.0,
                    wobble: 0.04,
                    ..lvl(1.4, 3, 20)
                },
            ],
            foliage: Foliage {
                kinds: &CONIFER_LEAVES,
                second_share: 0.2,
                // Needle sprays: each billboard stands for a shoot's
                // needles, so it is longer than one needle and there are
                // several per internode.
                length: 0.2,
                per_internode: 2,
                arrangement: LeafArrangement::Sides,
                tip: 1,
                twig_zone: 0.75,
                branch_zone: 0.5,
                spread: 30.0,
                lift: 0.15,
            },
        },
        Preset::Willow => Species {
            height: 16.0,
            base_radius: 1.0 / 40.0,
            tip_radius_max: 0.005,
            bark: [0.3, 0.27, 0.22, 1.0],
            root: RootForm::Trunk { length: 0.78 },
            form: Form::Monopodial,
            levels: [
                Level {
                    bare: 0.38,
                    skip: 0.2,
                    profile: Profile::Ovoid {
                        base: 0.85,
                        peak: 0.3,
                        tip: 0.4,
                    },
                    angle: (40.0, 8.0),
                    ratio: 0.8,
                    vigor: 0.25,
                    grav: (0.03, -0.04),
                    photo: 0.0,
                    wobble: 0.04,
                    ..lvl(1.7, 6, 45)
                },
                Level {
                    skip: 0.15,
                    phyllotaxis: Phyllotaxis::Pendant,
                    profile: Profile::Linear {
                        base: 1.0,
                        tip: 0.7,
                    },
                    angle: (38.0, 6.0),
                    ratio: 0.75,
                    grav: (0.05, -0.4),
                    photo: 0.07,
                    wobble: 0.04,
                    ..lvl(1.6, 6, 40)
                },
                Level {
                    bare: 0.3,
                    skip: 0.25,
                    phyllotaxis: Phyllotaxis::Pendant,
                    profile: Profile::Linear {
                        base: 1.0,
                        tip: 0.6,
                    },
                    angle: (34.0, 5.0),
                    ratio: 0.35,
                    grav: (-0.35, -0.2),
                    photo: 0.02,
                    wobble: 0.03,
                    hang: true,
                    ..lvl(1.9, 6, 30)
                },
            ],
            foliage: Foliage {
                kinds: &WILLOW_LEAVES,
                second_share: 0.3,
                length: 0.13,
                per_internode: 3,
                arrangement: LeafArrangement::Alternate,
                tip: 2,
                twig_zone: 0.75,
                branch_zone: 0.5,
                spread: 30.0,
                lift: -1.0,
            },
        },
        Preset::Shrub => Species {
            height: 4.5,
            base_radius: 1.0 / 45.0,
            tip_radius_max: 0.004,
            bark: [0.3, 0.24, 0.18, 1.0],
            root: RootForm::Stems {
                min: 3,
                max: 7,
                tilt: (14.0, 26.0),
                length: 0.9,
            },
            form: Form::Monopodial,
            levels: [
                Level {
                    bare: 0.22,
                    skip: 0.2,
                    profile: Profile::Ovoid {
                        base: 0.8,
                        peak: 0.4,
                        tip: 0.35,
                    },
                    angle: (50.0, 10.0),
                    ratio: 0.5,
                    grav: (0.0, 0.02),
                    photo: 0.05,
                    ..lvl(1.6, 6, 40)
                },
                Level {
                    skip: 0.2,
                    angle: (45.0, 10.0),
                    photo: 0.05,
                    wobble: 0.07,
                    ..lvl(1.4, 3, 24)
                },
                Level {
                    skip: 0.2,
                    angle: (45.0, 10.0),
                    grav: (0.03, 0.0),
                    photo: 0.04,
                    wobble: 0.07,
                    ..lvl(1.4, 3, 20)
                },
            ],
            foliage: Foliage {
                kinds: &SHRUB_LEAVES,
                second_share: 0.3,
                length: 0.065,
                per_internode: 2,
                arrangement: LeafArrangement::Alternate,
                tip: 3,
                twig_zone: 0.75,
                branch_zone: 0.35,
                spread: 55.0,
                lift: 0.4,
            },
        },
        Preset::Dichotomous => {
            let fork = Level {
                e: 0.2,
                min_child: 2,
                grav: (0.05, 0.0),
                photo: 0.04,
                wobble: 0.03,
                ..lvl(1.0, 2, 6)
            };
            Species {
                height: 13.0,
                base_radius: 1.0 / 45.0,
                tip_radius_max: 0.005,
                bark: [0.45, 0.42, 0.38, 1.0],
                root: RootForm::Trunk { length: 0.24 },
                form: Form::Dichotomous {
                    angle: (28.0, 36.0),
                    three_way: 0.35,
                },
                levels: [
                    Level {
                        n_min: 3,
                        n_max: 8,
                        a: 1.3,
                        ..fork
                    },
                    fork,
                    fork,
                ],
                foliage: Foliage {
                    kinds: &DICHOTOMOUS_LEAVES,
                    second_share: 0.3,
                    length: 0.09,
                    per_internode: 2,
                    arrangement: LeafArrangement::Alternate,
                    tip: 4,
                    twig_zone: 0.8,
                    branch_zone: 0.0,
                    spread: 50.0,
                    lift: 0.4,
                },
            }
        }
    }
}
