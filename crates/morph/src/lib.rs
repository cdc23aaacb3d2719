//! The morph pipeline (morphing paper §5–7): two analysed leafy trees in, a
//! [`MorphPlan`] out, and from it the in-between tree at any `t ∈ [0, 1]`
//! as a [`Frame`](treemorph_tree::Frame) of one fixed **union topology**
//! ([`FrameTopology`](treemorph_tree::FrameTopology)).
//!
//! ```no_run
//! use treemorph_analysis::{Analysis, AnalysisOptions};
//! use treemorph_morph::{FrameMeter, MetricsOptions, MorphOptions, MorphPlan, Morpher};
//! # fn run(source: &treemorph_tree::Tree, target: &treemorph_tree::Tree) -> Result<(), Box<dyn std::error::Error>> {
//! let a = Analysis::of(source, &AnalysisOptions::default())?;
//! let b = Analysis::of(target, &AnalysisOptions::default())?;
//! let plan = MorphPlan::new(source, &a, target, &b, &MorphOptions::default())?;
//! let mut morpher = Morpher::new(&plan);
//! let mut meter = FrameMeter::new(&plan, &MetricsOptions::default());
//! let mut frame = morpher.new_frame();
//! for i in 0..=60 {
//!     morpher.morph(i as f32 / 60.0, &mut frame);
//!     let metrics = meter.measure(&frame)?;
//!     assert_eq!(metrics.floating_branches, 0);
//! }
//! # Ok(()) }
//! ```
//!
//! The crate is synchronous; rayon parallelises the plan's and each frame's
//! independent work (the union chains of one level of the union chain tree
//! at a time, then the leaves) on large trees.
//!
//! # Glossary
//! - **chain**, **chain group**, **BPTT**, **IL / OL / GOL**: as in
//!   `treemorph_analysis` (§4).
//! - **correspondence** ([`Correspondence`]): matched chain groups, matched
//!   chains (one-to-one or one-to-many), matched leaves, and what is left
//!   unmatched.
//! - **operations** ([`Operation`], §6.1): **morph** (a one-to-one pair),
//!   **split** (one source chain copied onto several targets), **merge**
//!   (several sources onto one target), **grow** (a target chain from zero
//!   size) and **wilt** (a source chain to zero size).
//! - **union chain** ([`UnionChain`]): one pair, split copy, merge copy,
//!   growing or wilting chain. The union chains form one rooted tree; each
//!   is one strand of the union topology.
//! - **schedule** ([`ScheduleOptions`]): when each operation happens.
//!   Staged (default): shed, reshape, grow, parents before twigs, growth
//!   from the tip, paced to even speed; linear: the paper's single clock
//!   (see `schedule.rs` for the choices). A staged plan also routes limbs
//!   round the siblings they would pass through and lifts junctions that
//!   slide past a sibling's off the parent's axis
//!   ([`MorphOptions::route_round`]; `routing.rs`). Blends that still
//!   pass through other branches after that are shed and regrown
//!   instead: their chains leave the matching
//!   ([`MorphOptions::untangle`]; `untangling.rs`).
//! - **MTSW** (§7): maximum main-trunk support weight, the pipe-model
//!   measure of how smoothly the weight of a crown moves between trunks.
//!
//! # Correspondences (§5)
//! Top-down from the root groups, which always match. For each matched
//! pair of groups:
//! 1. **Chains** are matched greedily inside the two groups (Rule 3): the
//!    cheapest pairs first while both ends are free, until every chain of
//!    the smaller group has a partner; then every surplus chain of the
//!    larger group attaches to its cheapest partner. A chain with several
//!    partners **splits** (source side) or **merges** (target side); the
//!    pair made in the first phase is its **primary** pair. With
//!    [`ChainMatching::OneToOne`] (the TVCG 2017 baseline) surplus chains
//!    grow or wilt instead.
//! 2. Each **star** — a chain with all its partners — then matches the
//!    child groups of its source chains with the child groups of its target
//!    chains by a **minimum-weight bipartite matching** in which a group may
//!    stay unmatched at [`MorphOptions::unmatched_group_cost`] (Hungarian
//!    algorithm, `assignment`). Groups are only compared inside a star, so
//!    matched groups are always at one BPTT level (Rule 1) on matched parent
//!    chains (Rule 2). An unmatched group wilts or grows with its whole
//!    substructure. In a one-to-one star the matching is then searched
//!    for **crossings**: two matched groups trade partners when that keeps
//!    more sibling limbs from passing through each other mid-morph, at
//!    [`GroupCostWeights::crossing`] each, than it adds cost (`crossing`
//!    module: the model, and how well it agrees with the written frames).
//! 3. **Leaves** are matched inside each star's inner lobes (the ILs of its
//!    source chains against those of its target chains) with the same
//!    greedy one-to-many scheme: every leaf of the smaller side gets a
//!    partner, surplus leaves attach to their most similar one. Leaves of
//!    unmatched chains, or facing an empty IL, grow or wilt in place.
//!
//! ## Costs
//! The paper's Eq. 4 sums weighted distances without saying how they are
//! scaled. We make every term dimensionless and roughly in `[0, 1]` so the
//! weights compare like with like: positions are first **normalised per
//! tree** — root node at the origin, divided by the tree's height — so a
//! 3 m shrub and a 25 m eucalyptus compare by where things are *in their
//! crowns*. Group cost ([`GroupCostWeights`]):
//! - the **Hausdorff distance between the GOLs**, computed from support
//!   functions: for convex sets it is `sup_n |h_A(n) − h_B(n)|` over unit
//!   directions, which we sample on 64 fixed directions (a Fibonacci
//!   lattice; a lower bound within about 1 % of the lobe size). Each GOL's
//!   support function is computed once, when first needed, so a pair costs
//!   64 subtractions instead of a vertex-to-vertex search — the root star
//!   of a 5k → 20k-chain morph compares ~18 trunk groups with ~500 stem
//!   groups of up to ~150 hull vertices. A GOL without leaves is compared
//!   by its bounding sphere (`|Δcentre| + |Δradius|`);
//! - half the distance between unit branching vectors, |ΔGR|,
//!   |Δ#chains| / max #chains;
//! - |Δdivergence| / 180° only when both groups have two or more chains (a
//!   one-chain group has no divergence angle; the chain-count term already
//!   prices a change of pattern);
//! - |ΔGp|: the growth location is part of the BPTT quintuple, and matching
//!   it keeps children from sliding far along their parent.
//!
//! Leaving a group unmatched costs [`MorphOptions::unmatched_group_cost`]
//! (1.5), so two groups are matched whenever their cost is below 3: a
//! dissimilar branch that morphs reads better than one crown wilting while
//! another grows. Chain cost ([`ChainCostWeights`]): v, p, normalised
//! length, OR, IR and the normalised OL bounding spheres. Leaf cost
//! ([`LeafCostWeights`]): arc-length position, offset direction around the
//! chain, relative width and height differences, and the angle between
//! chain-relative orientations. Leaf matching is dense inside a star up to
//! 65,536 candidate pairs; beyond that each leaf considers the 48 leaves of
//! the other side nearest along the chain.
//!
//! # Union topology
//! The set of chains and leaves is fixed for the whole morph, so every frame
//! has the same node and leaf counts: split and merge copies exist from the
//! first frame, growing chains exist at zero size, wilting chains shrink to
//! zero size. Union chains are ordered parents first, level by level.
//!
//! Each union chain is **resampled** once: its sample parameters (arc-length
//! fractions) are the union of its source chain's and its target chain's
//! node parameters, so every original node is a sample and the other side's
//! nodes add samples on the original polyline. The frame at t = 0 therefore
//! reproduces the source skeleton and the frame at t = 1 the target skeleton
//! (exactly up to f32 rounding; see [`MorphPlan::endpoint_error`]).
//!
//! A union chain's nodes are its **junction node** — a node of its own on
//! the parent chain's axis at the interpolated growth location (at the root
//! for root chains) — followed by one node per sample; the strand is exactly
//! that node range. The junction node's parent (for connectivity only; the
//! location moves along the parent during the morph) is the parent chain's
//! sample at or before the lower of the two growth locations; a root
//! chain's junction node has the root node 0 as parent. Node 0 itself is on
//! no strand. The junction node gets the chain's own thickness — each
//! side's `min(r_junction, r_first_node)`, interpolated — which is also
//! what meshers give a child tube at a shared junction, so its tube does
//! not flare to the parent's girth; samples added inside a chain's first
//! segment taper from that radius, not from the parent's. (A mesher sees a
//! strand starting at a node no other strand holds, so it closes the
//! tube's base with a cap; that cap sits inside the parent tube.)
//!
//! One-to-many matching duplicates: the copies of a split share their
//! source chain (they coincide at t = 0), the copies of a merge their target
//! chain (they coincide at t = 1), and a leaf matched to several leaves
//! appears once per partner. [`MorphPlan::node_origins`] and
//! [`MorphPlan::leaf_origins`] say which input node or leaf each union node
//! or leaf reproduces at either end.
//!
//! # Interpolation (§6.1): children ride on their parents
//! Every chain is interpolated **in its parent's frame**. At time `t` its
//! growth location is `p = lerp(p_s, p_t, t)` (a union parameter of the
//! parent chain); its junction is the parent's morphed polyline at `p` and
//! its **anchor frame** the parent's morphed frame there. Each segment is
//! stored in the anchor frame of its side as a length and a unit direction;
//! the in-between segment has the lerped length and the slerped direction,
//! and the chain is rebuilt from the junction segment by segment. Sample
//! frames (chain-local axes) are slerped the same way and radii lerped.
//! A rotation has two arcs (to `b` and to `−b`); the first sample of a
//! chain takes the shorter, and each next sample the one whose half-way
//! frame is nearer its predecessor's, so neighbouring frames turn the same
//! way even where a chain's frames turn by about a half turn between the
//! trees (third-party trees do; a junction or leaf between two frames
//! turning opposite ways jumped mid-morph).
//! A chain that turns keeps its length, and a chain is never detached from
//! its parent: the junction is *on* the parent's axis by construction, so
//! no branch floats at any t. Growing and wilting chains keep their shape
//! and scale lengths and radii from or to zero at their growth location
//! (`t` and `1 − t`), so they taper to nothing.
//!
//! Frames along a chain are interpolated between samples by normalised
//! lerp (samples added from the other side get their frame the same way
//! from the input chain's node frames). The plan computes every input-side
//! quantity (anchor frames, leaf offsets) with the very function the
//! morpher uses, so the end frames are the inputs. Slerp coefficients are
//! precomputed per sample in f64 with `atan2` (an f32 `acos` near 1 is
//! only good to ~3e-4 rad, which showed at t = 1), and a frame evaluates
//! `a cos(wθ) + a⊥ sin(wθ)` with an inlined half-angle polynomial
//! `sin_cos` (exact at 0, error < 4e-7; five times cheaper than libm).
//!
//! ## Split and merge
//! A split's copies, and a merge's, are morphed with per-point weights
//! `w(u, t)` instead of `t` ([`point_weight`]). The paper cuts each copy at
//! arc-length fraction `1 − t` into a base part `chn^(1−t)` (`u ≤ 1 − t`)
//! and a tip part `chn^t`, and calls `b ∈ (0, 1]` "proportional to the
//! arc-length parametric value". We take **`b = u / (1 − t)`**, the
//! position within the base part, which is the only proportional choice
//! that makes the weight continuous across the cut:
//! - split: `w = b·t` on the base part, `t` on the tip part — copies stay
//!   together near their junction and part from the tip down (a zipper
//!   opening towards the base);
//! - merge: `w = min(1, (2 − b)·t)` on the base part, `t` on the tip part —
//!   the copies' bases converge first (`w = min(1, 2t)` at the junction).
//!
//! Both are continuous in `t` for every `u > 0` and equal 0 at t = 0 and 1
//! at t = 1. The split weight grows monotonically in `t`; the paper's merge
//! formula does not quite (at `u = 0.4` it peaks at 0.611 near t = 0.55
//! before settling back onto `t` at t = 0.6), which we keep as written. At
//! `u = 0` the split weight would jump at t = 1, so each chain's junction
//! sample takes its neighbour's weight (the junction's position does not
//! depend on it). [`MorphOptions::slow_down`] turns the schedule off.
//!
//! # Foliage (§6.2)
//! A leaf is hosted by the union chain of its inner lobe (the pair of its
//! IL chain with its partner's IL chain; a growing or wilting leaf by its
//! IL chain's primary union chain). Its parameter along the chain is
//! lerped; its offset from the axis is stored in the chain's frame at that
//! parameter and lerped there (so the anchor never lies farther from the
//! axis than the lerped offset length — at most a little inside the bark
//! mid-morph); its orientation is slerped relative to the same frame;
//! width and height are lerped (from or to 0 for a leaf that grows or
//! wilts, which stays in place; on a growing or wilting chain its offset
//! scales to 0 with the chain). Leaves therefore move with their branches.
//!
//! **Shape and texture**: the topology's `leaf_materials` are the source
//! tree's materials followed by the target's; a matched leaf has material
//! pair `[source, target]`, an unmatched one its own material twice.
//! [`FrameLeaf::blend`](treemorph_tree::FrameLeaf) is the leaf's own
//! interpolation weight (`t` on the linear schedule, its own eased window
//! on the staged one); the output stage morphs contours and blends
//! textures from it. Bark is `[source bark, target bark]` with
//! `bark_blend` the reshape phase's clock (`t` when linear).
//!
//! On the staged schedule a leaf that grows or wilts on a chain that
//! reshapes opens from (or closes into) a bud on the bark, after its twig
//! has reshaped (before it starts): imported leaves often sit on their
//! twig's axis, and opening there while the branch is still thick would
//! bury them in the wood. Of the union leaves that share a source (or
//! target) leaf, the first keeps it and the others grow in (or wilt) as
//! leaves of their own: copies of one leaf would coincide at an end with
//! different material pairs and z-fight as they blend (the random-leaf
//! baseline keeps its copies).
//!
//! With [`LeafMorph::RandomLinear`] (the Figure 11 baseline) leaves are
//! paired at random over the whole tree and their world anchors and
//! orientations interpolated without regard to branches.
//!
//! # Metrics (§7)
//! [`FrameMeter::measure`] gives [`FrameMetrics`]:
//! - **ε** of the floating checks is `1e-4 × plan height`
//!   ([`MetricsOptions::floating_epsilon`]), the plan height being the
//!   larger of the two trees' heights (bounds above the root node).
//! - `floating_branches`: junction nodes farther than parent radius + ε
//!   from the parent chain's polyline in the frame (root chains: from node
//!   0).
//! - `floating_leaves`: anchors farther than their interpolated offset
//!   length + ε from their host chain's polyline. A random-baseline leaf has
//!   two hosts (the union chains of its source and of its target leaf) and
//!   floats when it is attached to neither.
//! - `mtsw`: branch weight `ρ_wood · V` per segment, `V` the frustum
//!   volume `π l (r_a² + r_a r_b + r_b²) / 3` (exactly additive, so
//!   resampled chains weigh what their inputs weigh; ρ_wood = 600 kg/m³),
//!   leaf weight `ρ_leaf · w · h` (ρ_leaf = 0.2 kg/m²). Parts the union
//!   duplicates are shared, not double counted: a union chain's wood is
//!   weighted by `(1 − t)/m_s + t/m_t` (`m` how many union chains share its
//!   source / target chain), a union leaf's likewise. T(z) of a root union
//!   chain is the weight of its substructure and leaves minus its own wood
//!   and leaves below `z`; `z` is its OR, the lowest growth location of its
//!   union children, where a growing child's location slides in from the
//!   tip as it grows (`lerp(1, p, t)`, a wilting one's out), so OR is
//!   continuous and equals the input's at both ends. **Trunks**: split
//!   copies of one root chain (merge copies of one target root chain)
//!   coincide at t = 0 (t = 1); there they are one trunk (T summed, cut at
//!   their common OR), apart they are separate trunks (the heaviest, each
//!   cut at its own OR), blended linearly in t. The **main trunks** are the
//!   trunks whose base radius is at least half the thickest one's
//!   ([`MetricsOptions::main_trunk_radius_ratio`]); thinner root chains —
//!   stems still growing — are carried by the thickest trunk, as the
//!   paper's re-ordering does until a grown stem becomes thick enough to
//!   count as a main stem. MTSW is the heaviest main trunk's support over
//!   the frame's total weight; the frames at t = 0 and 1 give the inputs'
//!   MTSW whatever the matching.
//! - `max_jump`: the largest displacement of a node or a leaf quad's
//!   corner since the previous measured frame, over the plan height.
//! - `coincident_leaves`: visible leaves drawn on top of another (same
//!   anchor, orientation and size to a millionth of the height) with a
//!   different material pair.
//! - `growth_out_of_order`, `growth_reversals`: growing and wilting chains
//!   not growing from the tip (a segment grown beyond one short of its
//!   full length), and growing chains that got shorter (wilting ones
//!   longer) since the previous frame, from the frame's nodes.
//! - `endpoint_error`: [`MorphPlan::endpoint_error`], the largest position,
//!   radius or leaf-size difference between the frame at t = 0 and the
//!   source (over its height) and at t = 1 and the target; nodes and leaves
//!   that have no counterpart on that side (grown or wilted parts, samples
//!   added from the other side) are excluded.
//!
//! # Performance
//! [`MorphPlan::new`] does the matching and precomputes, per union sample,
//! everything a frame needs; the build runs level by level with rayon and
//! reads chain data from compact copies (cache misses on the analysis'
//! per-chain vectors were once its main cost). A frame is two polynomial
//! `sin_cos` per sample and one per leaf, chains of one level and chunks of
//! leaves in parallel, with no allocation. `examples/timing.rs` prints plan
//! and frame times at the paper's Table 2 sizes:
//! `cargo run --release -p treemorph-morph --example timing`.

mod assignment;
mod builder;
mod correspondence;
mod crossing;
mod error;
mod growth;
mod metrics;
mod morpher;
mod options;
mod plan;
mod routing;
mod schedule;
mod staging;
mod untangling;

pub use assignment::{FORBIDDEN, match_or_leave};
pub use correspondence::{ChainMatch, Correspondence, LeafMatch, Operation};
pub use error::{MorphError, Side};
pub use metrics::{FrameMeter, FrameMetrics, frame_metrics};
pub use morpher::{Morpher, point_weight};
pub use options::{
    ChainCostWeights, ChainMatching, GroupCostWeights, LeafCostWeights, LeafMorph, MetricsOptions,
    MorphOptions, ScheduleKind, ScheduleOptions,
};
pub use plan::{EndpointError, MorphPlan, NodeOrigin, UnionChain};

#[cfg(test)]
#[path = "tests.rs"]
mod tests;

#[cfg(test)]
#[path = "schedule_tests.rs"]
mod schedule_tests;
