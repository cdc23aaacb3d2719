//! The sketch pipeline (Wang et al., *Sketch-based shape-preserving tree
//! animations*, CAVW 2018, §4–6): one leafy tree, a camera and a 2D outline
//! of the crown the artist wants in; an animation of the tree growing into
//! that crown out — every frame a connected tree with the input's topology.
//!
//! ```no_run
//! use treemorph_analysis::{Analysis, AnalysisOptions};
//! use treemorph_sketch::{SketchMetrics, SketchOptions, SketchPlan, Sketcher, parse_sketch_file};
//! # fn run(tree: &treemorph_tree::Tree, bytes: &[u8]) -> Result<(), Box<dyn std::error::Error>> {
//! let file = parse_sketch_file(bytes)?; // {"view": {…}, "points": […], "closed": true, "fit": "crown"}
//! let analysis = Analysis::of(tree, &AnalysisOptions::default())?;
//! let options = SketchOptions::default().with_fit(file.fit);
//! let plan = SketchPlan::new(tree, &analysis, &file.view, &file.sketch, &options)?;
//! let mut sketcher = Sketcher::new(&plan);
//! let mut metrics = SketchMetrics::new(&plan);
//! let mut frame = sketcher.frame(0.0); // the input tree, exactly
//! for i in 0..=60 {
//!     sketcher.deform(i as f32 / 60.0, &mut frame); // frames share plan.topology()
//!     let m = metrics.measure(&frame);
//!     assert_eq!((m.floating_branches, m.floating_leaves), (0, 0));
//! }
//! # Ok(()) }
//! ```
//!
//! The crate is synchronous and does no I/O. [`SketchPlan::new`] does the
//! per-sketch work once, on every core where its phases allow (`treemorph
//! bench`, 5,000 branches in release, a staged sketch's pacing included:
//! 30–43 ms on a 2-core machine whose figures drift by a fifth; the
//! foliage fit's four measured t = 1 frames are about half of it, and the
//! plan without them took 24–37 ms in the same runs, before its phases ran
//! in parallel); a [`Sketcher`] solves the end pose when made (≈ 1 ms) and
//! then makes any frame in ≈ 0.2 ms, reusing its buffers.
//!
//! # Glossary
//! - **chain**, **chain group**, **BPTT**, **IL / OL / GOL** (inner lobe,
//!   outer lobe, group outer lobe): as in `treemorph_analysis` (§4). The
//!   **crown** is the root group's GOL.
//! - **silhouette**: the outline of a lobe seen from the view, in normalised
//!   device coordinates (NDC).
//! - **cage**: a silhouette used to deform what it encloses by **mean value
//!   coordinates** (MVC). **Internal cages** (GOL, OL) carry finer cages;
//!   **leaf cages** (IL) carry chains.
//! - **MCT**, the multiscale cage tree (§5.2): the cages linked like the
//!   BPTT — crown → chain OLs → their IL and the GOLs growing on them → …
//! - **self-adaptive cage** (§5.4.1): a child cage stretched to cover the
//!   parts of its parent cage (**F** segments, uncovered) that no child
//!   covers (**O** segments, covered).
//! - **pruning / wilt** (§5.4.2): cages mostly outside the sketch are
//!   pruned; their chains **wilt** — shrink to nothing toward where they
//!   grow — during the animation.
//!
//! # Input: view and sketch (the HTTP/CLI contract)
//! A [`View`] is `{"eye": [x,y,z], "target": [x,y,z], "up": [x,y,z],
//! "fov_deg": f}` (perspective, vertical field of view in (0°, 180°)) or
//! `{"eye", "target", "up", "ortho_height": h}` (orthographic, metres
//! spanned vertically) — exactly one of the two, plus an optional
//! `"aspect"` (screen width / height, default 1). A [`Sketch`] is
//! `{"points": [[x, y], …], "closed": bool}` in NDC of that view: x, y in
//! [-1, 1] (a margin of 0.1 is tolerated), y up. A **closed** sketch is the
//! new crown outline; an **open** one oversketches the part of the crown's
//! silhouette between the silhouette points nearest to its ends. A sketch
//! file ([`parse_sketch_file`]) is `{"view": {…}, "points": […], "closed":
//! bool, "fit": "none" | "crown"}`; with `"fit": "crown"` ([`Fit::Crown`])
//! a closed sketch is scaled and translated so that its bounding box is the
//! crown silhouette's — one file then fits any tree at any distance.
//! Validation names every problem ([`SketchError`]): too few or too many
//! points, NaN/∞, points off screen, a self-intersecting sketch, a
//! degenerate view (eye at target, up along the view, fov out of range), a
//! sketch missing the crown (no overlap; an open sketch's ends more than
//! [`SketchOptions::open_snap_distance`] from the silhouette), a camera
//! inside the crown, a tree behind a perspective camera, a tree without
//! leaves.
//!
//! # Plan (once per sketch)
//! 1. **Silhouettes.** Lobes are convex hulls, and the projection of a
//!    convex polytope in front of the camera is convex, so a lobe's outline
//!    is the 2D convex hull of its projected vertices — exactly the
//!    projection of the object-space silhouette the paper detects, the hull
//!    vertices with `n · (p − C) = 0`. Every cage keeps, per corner, the
//!    hull vertex under it (for the lobe deformation); depth is the
//!    camera-space z of each point and is kept (below).
//! 2. **Crown correspondence** (screen-space arc-length parameterisation).
//!    Closed sketch: both polygons counter-clockwise, parameterised by
//!    normalised arc length from their topmost vertex, then the sketch's
//!    parameter shifted by the cyclic offset minimising the summed squared
//!    distance of 128 samples of the two shapes, each centred and scaled by
//!    its bounding-box diagonal (a heart has two tops; where the sketch is
//!    drawn does not matter). Open sketch: of the two silhouette arcs
//!    between the ends' nearest points, the one closer to the stroke is
//!    replaced by `end → stroke → end`, the other maps to itself. Samples:
//!    the union of both curves' corners and [`SketchOptions::crown_samples`]
//!    uniform parameters, so neither the silhouette's nor the sketch's
//!    corners are cut. The source samples are the crown cage.
//! 3. **MCT.** Top-down through the BPTT. A lobe whose silhouette equals its
//!    parent cage's (a single-chain group's GOL is its chain's OL; a chain
//!    without child groups has IL = OL) is represented by the parent cage;
//!    a lobe without leaves, or whose silhouette has < 3 corners or less
//!    area than [`SketchOptions::min_cage_area`] × the crown's, gets no
//!    cage and its children hang from the next cage up. Every cage corner
//!    gets its MVC in the parent cage (2D MVC of Hormann & Floater, valid
//!    inside and outside any polygon; on a vertex or an edge: the boundary
//!    interpolation; where the weights cancel: the nearest edge's).
//! 4. **Control cages.** Every chain node gets its MVC in its **control
//!    cage**: the first of its chain's IL, OL, then their ancestors, that
//!    holds the node (5 % tolerance); a tip held by none uses the crown;
//!    other nodes held by none (a bole below the crown) follow no cage.
//! 5. **Self-adaptive cages** (if [`SketchOptions::adaptive`]), on the
//!    final (t = 1) cages, top-down: the parent's boundary is sampled every
//!    τ = [`SketchOptions::coverage_threshold`] × crown diagonal (the
//!    paper's 10 px); samples within τ of a child are covered (O); every
//!    uncovered (F) sample within [`SketchOptions::adapt_reach`] belongs to
//!    its nearest child. *The paper stretches only the children matched to
//!    the O segments beside an F segment; a conifer's whorls all stop short
//!    of its convex outline, and stretching the two at the ends of such a
//!    segment tears them across it, so we apply the same rule per piece of
//!    the segment.* A child's facing side (its boundary nearest the run,
//!    widened to ≥ 3 corners) maps onto the run by arc length; those corners
//!    and the corners matched to the parent's boundary are hard constraints
//!    of a polygon Laplacian deformation (Eq. 1, 1/|edge| weights — the
//!    polygon analogue of cotangent weights), the other corners free and
//!    softly anchored (weight 0.2) so a child stretches instead of sliding
//!    away. The correction is applied `t ×` at time t.
//! 6. **Pruning** (if [`SketchOptions::prune`]): top-down from the crown's
//!    children, each final cage is clipped with the sketched crown (geo
//!    boolean operations, non-zero fill for folded cages) and its largest
//!    piece kept; r = piece / cage area < [`SketchOptions::prune_ratio`]
//!    (30 %) prunes the subtree, r ≥ [`SketchOptions::inside_ratio`] (0.95,
//!    "r ≈ 1") stops. *We clip the cages where the deformation puts them,
//!    not at rest: what pruning removes is branches that would end up
//!    outside the drawn crown.* A pruned GOL or OL wilts its chains with
//!    their whole substructure; a pruned IL whose chain carries other
//!    chains wilts only the IL's leaves (the chain stays for its children).
//!    The crown is never pruned.
//! 7. **Chain systems.** Eq. 1 on every chain polyline, one factorised
//!    sparse least-squares system per hybrid order (faer: normal equations,
//!    AMD-ordered Cholesky, factorised once; frames only change right-hand
//!    sides). The junction (on the parent, solved at the previous order)
//!    and the tip (at its control cage's target: *backward propagation*)
//!    are hard constraints; the inner nodes minimise the Laplacian (1/|edge|
//!    weights in 3D, rows normalised) plus — our addition, weight
//!    [`SketchOptions::node_weight`] — a soft pull of every caged node to
//!    its cage target. *With the tip alone (the paper taken literally) a
//!    limb running through the crown swings on a straight line between its
//!    ends while the cages of the branches it carries go elsewhere; the
//!    foliage then lands far from its cages.* The trunk alone keeps to its
//!    ends: its lower nodes sit in the bottom of the crown cage, which the
//!    foliage fit pulls down, and following it folded the bole into a J
//!    below the root.
//! 8. **Foliage fit** (our addition, [`SketchOptions::foliage_passes`]
//!    passes, multiscale closed sketches only). *The paper maps the crown's
//!    convex silhouette onto the sketch, but an artist draws the outline of
//!    the leaves, and leaves fill only part of that hull: they cluster at
//!    the twig ends, so the outline dips in between twigs and limbs, and
//!    the hull of a 3D crown bridges the recesses between limbs at
//!    different depths. Mapped hull onto sketch, the foliage keeps that
//!    margin and ends up inside the sketch — on open or big-leaved imported
//!    crowns by enough to fit the sketch worse than the tree did before.*
//!    So the t = 1 foliage outline is measured as the metrics measure it
//!    and the crown cage's t = 1 displacement corrected by a smooth field
//!    (least squares, polygon Laplacian), pass by pass: first the outline's
//!    envelope (convex hull) is matched with the sketch by arc length, the
//!    outline point nearest each envelope sample to reach its match
//!    (weighted down across bays between limbs); then, along the sketch,
//!    the foliage front moves out where the outline misses more of the
//!    sketch than it spills over, and in where it spills more — the dips
//!    between leaf clusters weighed against the lips, as the IoU weighs
//!    them. How a leaf follows the crown cage is its branch's mean value
//!    coordinates composed up the cage tree. The displacement whose
//!    foliage has the best IoU with the sketch is kept — the paper's when
//!    no pass improves on it (a thin concave sketch such as a crescent).
//!    Only the crown's displacement changes: cages, chains and leaves
//!    follow it as before.
//!    Details in the `foliage` module.
//!
//! # Frames ([`Sketcher::deform`])
//! [`Sketcher::new`] solves the **end pose** once, as the paper makes a
//! frame at t = 1. The cages and chain systems work in **displacements in
//! the view plane** (NDC): the crown cage moves to the sketched crown
//! `S1`; each cage follows its parent by MVC plus its self-adaptive
//! correction; chain targets follow their control cages; chains are
//! solved order by order, each junction where the parent chain put it
//! (*forward propagation*: chains stay connected by construction). A node
//! is placed at its displaced screen position, unprojected at a depth
//! that follows the crown's width (`depth` module). Then every chain is
//! re-solved, parents first, to reach its solved tip from its junction
//! with its rest segment lengths times its growth (its chord now over at
//! rest), so branches bend at their nodes rather than stretch (`rigid`
//! module).
//!
//! A frame at time t moves **along arcs** toward that pose (`arcs`
//! module): every segment turns from its rest direction to its end
//! direction along its own great circle, its length going linearly from
//! rest to end, on its chain's clock (`time` module: one clock `t`, or
//! staged — pruned subtrees first, trunks before twigs, eased, paced); a
//! chain's radii follow its length. Nodes of wilting subtrees shrink
//! toward their subtree's junction on the shed clock, radii too. Leaves
//! ride on the branch they grow on: anchor = the deformed branch point at
//! the leaf's parameter + its offset (moved out or in with the branch's
//! radius) rotated with the segment, orientation rotated likewise; a
//! wilting leaf's offset, width and height shrink with its subtree. t = 0
//! reproduces the input bit for bit and t = 1 is the end pose.
//!
//! [`Sketcher::deform_cages`] gives the cages of a frame (for drawing),
//! [`Sketcher::deform_lobes`] the lobes deformed with them (§5.3 step 2:
//! silhouette vertices on their cage, the rest by a cotangent Laplacian,
//! factorised on first use), [`Sketcher::result_tree`] the final tree
//! without its wilted parts.
//!
//! # Metrics ([`SketchMetrics`])
//! The in-between crown is measured on the foliage, not on our cages (which
//! match the reference by construction): the projected leaf blades are
//! rasterised into a [`SketchOptions::raster_size`]² grid over the joint
//! bounds of foliage and reference, closed morphologically (Euclidean
//! dilation then erosion by [`SketchOptions::closing_radius`] × the crown
//! diagonal) and hole-filled — the outline an artist would trace.
//! **Fréchet**: the discrete Fréchet distance (Eiter–Mannila, O(nm), one
//! rolling row; [`discrete_frechet`]) between the outline's outer boundary
//! and the reference crown `S(t)`, both resampled to 128 points from a
//! common start (the reference's topmost point, the outline's best-aligned
//! cyclic shift), normalised by the crown's screen diagonal (the paper's
//! Figure 12). **IoU** of outline and reference (at t = 1: the sketched
//! crown), with the **coverage** and **spill** it splits into. **Floating**
//! branches and leaves, with the morph pipeline's definitions (a chain's
//! junction off its parent's axis + radius + ε; a leaf farther from its
//! chain than its offset, moved with its branch's radius, + ε; ε = 10⁻⁴ ×
//! the tree height) — always 0 here.
//!
//! # Baseline
//! [`Method::SingleCage`] is the paper's Figure 13 comparison: the crown is
//! the only cage, every chain follows it, no self-adaptation, no pruning,
//! no foliage fit. Over the six presets × {heart, diamond, star} × three
//! seeds, the multiscale method's final IoU is 0.87–0.97 (mean 0.94;
//! 0.74–0.94, mean 0.88 without the foliage fit) against 0.62–0.89 (mean
//! 0.82) for the single cage, better in all 54 cases: self-adaptive cages
//! carry branches into the parts of the sketch the crown's branches do not
//! reach (a conifer's whorls stop short of its convex outline; a dome's
//! underside is bare). Without the foliage fit, where the crown is already
//! full (some maples) one global cage follows concave sketch features such
//! as a heart's notch a little more closely.

mod adapt;
mod arcs;
mod closing;
mod correspondence;
mod depth;
mod error;
mod foliage;
mod frechet;
mod grid;
mod laplacian;
mod lobes;
mod mct;
mod metrics;
mod mvc;
mod options;
mod plan;
mod polygon;
mod prune;
mod rigid;
mod sketch;
mod sketcher;
mod time;
mod view;

pub use error::{SketchEnd, SketchError};
pub use frechet::discrete_frechet;
pub use lobes::DeformedLobes;
pub use mct::{Cage, CageKind};
pub use metrics::{FrameMetrics, ShapeMetrics, SketchMetrics};
pub use options::{Method, SketchOptions};
pub use plan::SketchPlan;
pub use sketch::{Fit, Sketch, SketchFile, parse_sketch_file};
pub use sketcher::Sketcher;
pub use treemorph_tree::timing::{ScheduleKind, ScheduleOptions};
pub use view::{Camera, View};
