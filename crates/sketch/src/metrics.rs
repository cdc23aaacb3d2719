//! Per-frame measurements: how close the in-between crown is to the
//! reference (the paper's Figure 12), how well the final foliage fills the
//! sketch, and whether anything floats.
//!
//! # The foliage outline
//! The crown silhouette of a frame is measured from the foliage itself, not
//! from our cages (which match the reference by construction). Every leaf
//! blade with a non-zero size is projected as a quad and rasterised into a
//! square grid of [`crate::SketchOptions::raster_size`]² pixels over the
//! joint bounds of the projected blades and the reference polygon (padded
//! by the closing radius). A morphological **closing** (Euclidean dilation
//! then erosion by [`crate::SketchOptions::closing_radius`] × the crown's
//! screen diagonal, via exact distance transforms) bridges the gaps between
//! leaves, and enclosed holes are filled: the result is the foliage's
//! outline as an artist would trace it.
//!
//! - **IoU**: |outline ∩ R| / |outline ∪ R| in pixels, R the reference crown
//!   (at t = 1, the sketched crown) rasterised on the same grid.
//! - **Fréchet**: the outer boundary of the outline's largest 4-connected
//!   region is traced along pixel edges, and it and R are resampled to 128
//!   points each by arc length, counter-clockwise. R starts at its topmost
//!   point; the outline starts where the cyclic shift minimising the summed
//!   squared distances to R's samples puts it (the discrete Fréchet distance
//!   of closed curves needs a common start; we take the least of the
//!   distances at that shift and its ±3 neighbours). The distance is in NDC;
//!   normalised, it is divided by the crown's screen diagonal.
//!
//! # Natural deformation
//! - **growth**: per chain, `g` = its chord (junction to tip) now over at
//!   rest, each at least half the chain's rest length: the growth or shrinking the sketch asks of the chain (a limb
//!   whose tip must reach 1.5 × as far). `max |g − 1|` over chains that
//!   do not wilt (a wilting subtree shrinks on purpose, so it is exempt
//!   and counted apart by the plan).
//! - **stretch**: `max |len / (λ × rest) − 1|` over those chains'
//!   segments, `λ` the chain's arc length now over at rest: how far a
//!   segment grew or shrank beyond its chain as a whole. Bending rotates
//!   segments at their joints and leaves this near 0; a solve that pulls
//!   one segment and squeezes its neighbour shows here. (Measured against
//!   `g` instead, a chain curved at rest and straight mid-animation showed
//!   23 % stretch with every segment at its rest length: the chord is the
//!   growth the sketch asks at the end, not a length.)
//! - **crown depth/width**: the visible leaf anchors' 5–95th-percentile
//!   extent along the view direction over that along the camera's right
//!   axis. Compared before and after a job it shows a crown flattened into
//!   a slab facing the camera (the ratio falling) or squeezed sideways
//!   with its depth kept (the ratio rising).
//!
//! # Floating parts (the morph pipeline's definitions)
//! - a **floating branch**: a chain whose junction is farther than ε from
//!   its parent chain's polyline plus the radius there (a root chain: from
//!   the root node);
//! - a **floating leaf**: an anchor farther from the polyline of the chain
//!   it grows on than the leaf's rest offset (moved with its branch's
//!   radius change, as the sketcher moves it) + ε.
//!
//! ε is 10⁻⁴ × the tree's height.

use glam::{Vec2, Vec3};
use serde::Serialize;
use treemorph_tree::Frame;
use treemorph_tree::geom::closest_on_segment;

use crate::depth::spread;
use crate::frechet::discrete_frechet_with;
use crate::plan::SketchPlan;
use crate::polygon;
use crate::rigid::growth;
use crate::sketcher::on_bark;
use crate::view::Camera;

/// Samples per curve for the Fréchet distance.
const SAMPLES: usize = 128;

/// What one frame measures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FrameMetrics {
    /// Animation time.
    pub t: f32,
    /// Discrete Fréchet distance between the foliage outline and the
    /// reference crown at `t`, NDC units.
    pub frechet: f32,
    /// `frechet` divided by the crown's screen diagonal.
    pub frechet_normalised: f32,
    /// Intersection over union of the foliage outline and the reference
    /// crown at `t` (at t = 1: the sketched crown).
    pub iou: f32,
    /// Fraction of the reference crown the foliage outline covers.
    pub coverage: f32,
    /// Area of the foliage outline outside the reference crown, as a
    /// fraction of the reference's area.
    pub spill: f32,
    /// Branches whose root is off their parent's axis (must be 0).
    pub floating_branches: usize,
    /// Leaves off their branch (must be 0).
    pub floating_leaves: usize,
    /// Largest relative change of a branch segment's length beyond its
    /// chain's growth, over chains that do not wilt (see
    /// [`SketchMetrics::stretch`]).
    pub max_stretch: f32,
    /// Largest growth or shrinking of a chain the sketch asks for,
    /// `max |g − 1|` (see [`SketchMetrics::growth`]).
    pub max_growth: f32,
    /// The crown's depth over its width seen from the view (see
    /// [`SketchMetrics::crown_depth_width`]).
    pub crown_depth_width: f32,
}

/// Shape measurements of any frame seen from the plan's view (e.g. one of
/// another pipeline, for comparisons).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ShapeMetrics {
    /// Animation time the reference crown was taken at.
    pub t: f32,
    /// See [`FrameMetrics::frechet`].
    pub frechet: f32,
    /// See [`FrameMetrics::frechet_normalised`].
    pub frechet_normalised: f32,
    /// See [`FrameMetrics::iou`].
    pub iou: f32,
    /// See [`FrameMetrics::coverage`].
    pub coverage: f32,
    /// See [`FrameMetrics::spill`].
    pub spill: f32,
}

/// What the foliage fit measures of a trial pose
/// ([`SketchMetrics::fit_measure`]).
pub(crate) struct FitMeasure {
    /// IoU of the foliage outline with the reference crown.
    pub iou: f32,
    /// The outer boundary of every piece of the outline (NDC,
    /// counter-clockwise), when asked.
    pub outlines: Vec<Vec<Vec2>>,
    /// Per reference sample: the reference's area the outline misses minus
    /// the outline's area outside the reference, over the pixels nearest
    /// the sample (NDC²).
    pub balance: Vec<f32>,
}

/// Reusable metrics context for one plan (keeps its rasters).
pub struct SketchMetrics<'p> {
    plan: &'p SketchPlan,
    size: usize,
    mask: Vec<bool>,
    reference: Vec<bool>,
    row: Vec<f32>,
    stack: Vec<usize>,
    label: Vec<u32>,
}

impl<'p> SketchMetrics<'p> {
    /// A metrics context for `plan`.
    pub fn new(plan: &'p SketchPlan) -> SketchMetrics<'p> {
        SketchMetrics::with_raster(plan, plan.options.raster_size)
    }

    /// A metrics context for `plan` on a `size`² raster (the foliage fit
    /// measures its trial poses on a coarser one).
    pub(crate) fn with_raster(plan: &'p SketchPlan, size: u32) -> SketchMetrics<'p> {
        let size = size as usize;
        SketchMetrics {
            plan,
            size,
            mask: vec![false; size * size],
            reference: vec![false; size * size],
            row: Vec::new(),
            stack: Vec::new(),
            label: vec![0; size * size],
        }
    }

    /// Everything one of the plan's frames measures.
    pub fn measure(&mut self, frame: &Frame) -> FrameMetrics {
        let shape = self.shape(frame);
        let (floating_branches, floating_leaves) = self.floating(frame);
        let (max_stretch, max_growth) = self.stretch_and_growth(frame);
        FrameMetrics {
            t: shape.t,
            frechet: shape.frechet,
            frechet_normalised: shape.frechet_normalised,
            iou: shape.iou,
            coverage: shape.coverage,
            spill: shape.spill,
            floating_branches,
            floating_leaves,
            max_stretch,
            max_growth,
            crown_depth_width: self.crown_depth_width(frame),
        }
    }

    /// `max |len / (λ × rest) − 1|` over the frame's branch segments, `λ`
    /// the arc length of the segment's chain now over at rest: how far a
    /// segment stretched beyond its chain as a whole (bending at the
    /// joints leaves it near 0). Chains that wilt are skipped: wilting
    /// subtrees shrink to nothing on purpose ([`SketchPlan::wilting_nodes`]
    /// says which). Segments shorter than 10⁻⁶ × the tree height at rest
    /// are skipped. 0 for a frame of another topology.
    pub fn stretch(&self, frame: &Frame) -> f32 {
        self.stretch_and_growth(frame).0
    }

    /// `max |g − 1|` over the chains that do not wilt, `g` a chain's
    /// growth: its chord (junction to tip) in the frame over its chord at
    /// rest, each at least half the chain's rest length, within [1/8, 8]
    /// (a hooked twig uncurls before it grows). A sketch that reaches farther than the crown grows its
    /// limbs; one that pulls it in shrinks them. 0 for a frame of another
    /// topology.
    pub fn growth(&self, frame: &Frame) -> f32 {
        self.stretch_and_growth(frame).1
    }

    /// [`SketchMetrics::stretch`] and [`SketchMetrics::growth`] in one walk
    /// over the chains.
    fn stretch_and_growth(&self, frame: &Frame) -> (f32, f32) {
        self.chain_lengths(frame)
            .fold((0.0f32, 0.0f32), |(stretch, growth), (g, segments)| {
                let worst = stretch.max(segment_stretch(segments));
                (worst, growth.max((g - 1.0).abs()))
            })
    }

    /// Per chain that does not wilt: its growth and its segments' rest and
    /// frame lengths (segments of no rest length left out). Nothing for a
    /// frame of another topology.
    fn chain_lengths<'a>(
        &'a self,
        frame: &'a Frame,
    ) -> impl Iterator<Item = (f32, impl Iterator<Item = (f32, f32)> + Clone + 'a)> + 'a {
        let plan = self.plan;
        let rest = &plan.rest.positions;
        let at = &frame.positions;
        let same = at.len() == rest.len();
        let tiny = 1e-6 * plan.height;
        plan.chain_ranges
            .iter()
            .zip(&plan.chain_wilts)
            .filter(move |&(&(a, b), &wilts)| same && !wilts && b - a >= 2)
            .map(move |(&(a, b), _)| {
                let nodes = &plan.chain_nodes[a as usize..b as usize];
                let (j, tip) = (nodes[0] as usize, nodes[nodes.len() - 1] as usize);
                let length: f32 = nodes
                    .windows(2)
                    .map(|w| rest[w[0] as usize].distance(rest[w[1] as usize]))
                    .sum();
                let g = growth(rest[j].distance(rest[tip]), length, at[j].distance(at[tip]));
                let segments = nodes.windows(2).filter_map(move |w| {
                    let (p, q) = (w[0] as usize, w[1] as usize);
                    let r = rest[p].distance(rest[q]);
                    (r > tiny).then(|| (r, at[p].distance(at[q])))
                });
                (g, segments)
            })
    }

    /// The crown's depth over its width seen from the plan's view: the
    /// extents of the visible leaf anchors along the camera's forward and
    /// right axes, each from the 5th to the 95th percentile (a few stray
    /// leaves do not set the crown's size). A crown flattened into a slab
    /// facing the camera has a small ratio; an untouched round crown
    /// about 1. 0 when the frame has fewer than 2 visible leaves.
    pub fn crown_depth_width(&self, frame: &Frame) -> f32 {
        let cam = &self.plan.camera;
        let right = cam.world_delta(Vec2::X, 1.0).normalize_or_zero();
        let forward = cam.forward();
        let (mut along_right, mut along_forward): (Vec<f32>, Vec<f32>) = frame
            .leaves
            .iter()
            .filter(|l| l.width > 0.0 && l.height > 0.0)
            .map(|l| (l.anchor.dot(right), l.anchor.dot(forward)))
            .unzip();
        if along_right.len() < 2 {
            return 0.0;
        }
        let width = spread(&mut along_right);
        let depth = spread(&mut along_forward);
        if width > 0.0 { depth / width } else { 0.0 }
    }

    /// Fréchet distance and IoU of any frame's foliage against the
    /// reference crown at `frame.t`.
    pub fn shape(&mut self, frame: &Frame) -> ShapeMetrics {
        let t = crate::time::clamp_t(frame.t);
        let reference = self.plan.reference_crown(t);
        let (lo, px) = self.rasterise(frame, &reference);
        let (inter, iou) = self.overlap();
        let reference_px = self.reference.iter().filter(|&&r| r).count().max(1) as f32;
        let foliage_px = self.mask.iter().filter(|&&m| m).count() as f32;
        let coverage = inter as f32 / reference_px;
        let spill = (foliage_px - inter as f32) / reference_px;
        let outline = self.trace(lo, px);
        let frechet = closed_frechet(&outline, &reference, &mut self.row);
        ShapeMetrics {
            t,
            frechet,
            frechet_normalised: frechet / self.plan.crown_size,
            iou,
            coverage,
            spill,
        }
    }

    /// The foliage outline of a frame (NDC, counter-clockwise; empty when
    /// the frame has no visible leaves).
    pub fn outline(&mut self, frame: &Frame) -> Vec<Vec2> {
        let reference = self.plan.reference_crown(frame.t);
        let (lo, px) = self.rasterise(frame, &reference);
        self.trace(lo, px)
    }

    /// What the foliage fit measures of a frame against the reference
    /// crown at `frame.t` (`samples`: points along the reference), in one
    /// rasterisation: the IoU, the outer boundary of every piece of the
    /// outline when `outlines` is asked ([`SketchMetrics::outline`] keeps
    /// only the largest), and the area balance along the reference (none
    /// without samples).
    pub(crate) fn fit_measure(
        &mut self,
        frame: &Frame,
        samples: &[Vec2],
        outlines: bool,
    ) -> FitMeasure {
        let reference = self.plan.reference_crown(frame.t);
        let (lo, px) = self.rasterise(frame, &reference);
        let (_, iou) = self.overlap();
        let balance = self.balance(lo, px, samples);
        FitMeasure {
            iou,
            balance,
            outlines: if outlines {
                self.trace_all(lo, px)
            } else {
                Vec::new()
            },
        }
    }

    /// Per sample, over the pixels nearer to it than to any other sample:
    /// the reference's area the outline misses minus the outline's area
    /// outside the reference (NDC²).
    fn balance(&self, lo: Vec2, px: f32, samples: &[Vec2]) -> Vec<f32> {
        let g = self.size;
        let mut net = vec![0.0f32; samples.len()];
        if samples.is_empty() {
            return net;
        }
        let area = px * px;
        for (i, (&m, &r)) in self.mask.iter().zip(&self.reference).enumerate() {
            if m == r {
                continue;
            }
            let p = lo + Vec2::new((i % g) as f32 + 0.5, (i / g) as f32 + 0.5) * px;
            let nearest = samples
                .iter()
                .map(|s| s.distance_squared(p))
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map_or(0, |(k, _)| k);
            net[nearest] += if r { area } else { -area };
        }
        net
    }

    /// Pixels in both the outline and the reference, and their IoU (1 when
    /// both are empty).
    fn overlap(&self) -> (usize, f32) {
        let (mut inter, mut union) = (0usize, 0usize);
        for (&a, &b) in self.mask.iter().zip(&self.reference) {
            inter += usize::from(a && b);
            union += usize::from(a || b);
        }
        let iou = if union > 0 {
            inter as f32 / union as f32
        } else {
            1.0
        };
        (inter, iou)
    }

    /// Counts floating branches and leaves of one of the plan's frames
    /// (see the module docs).
    pub fn floating(&self, frame: &Frame) -> (usize, usize) {
        let plan = self.plan;
        let n = plan.rest.positions.len();
        if frame.positions.len() != n
            || frame.radii.len() != n
            || frame.leaves.len() != plan.leaf_chain.len()
        {
            return (plan.chain_ranges.len(), plan.leaf_chain.len());
        }
        let eps = 1e-4 * plan.height;
        let pos = &frame.positions;
        let chain = |c: u32| {
            let (a, b) = plan.chain_ranges[c as usize];
            &plan.chain_nodes[a as usize..b as usize]
        };
        let mut branches = 0;
        for (c, parent) in plan.chain_parent.iter().enumerate() {
            let junction = pos[chain(c as u32)[0] as usize];
            let floating = match parent {
                None => junction.distance(pos[0]) > eps,
                Some(p) => {
                    let (d, r) = to_polyline(junction, chain(*p), pos, &frame.radii);
                    d.is_nan() || d > r + eps
                }
            };
            branches += usize::from(floating);
        }
        let mut leaves = 0;
        for (l, leaf) in frame.leaves.iter().enumerate() {
            let (d, _) = to_polyline(leaf.anchor, chain(plan.leaf_chain[l]), pos, &frame.radii);
            let node = plan.topology.leaves[l].node as usize;
            let dr = frame.radii[node] - plan.rest.radii[node];
            let offset = on_bark(plan.leaf_offset[l], dr).length();
            leaves += usize::from(d.is_nan() || d > offset + eps);
        }
        (branches, leaves)
    }

    /// Rasterises the foliage outline into `mask` and the reference into
    /// `reference`; returns the grid's lower-left corner and pixel size.
    fn rasterise(&mut self, frame: &Frame, reference: &[Vec2]) -> (Vec2, f32) {
        let plan = self.plan;
        let cam = &plan.camera;
        let g = self.size;
        let quads = blades(cam, frame);
        let mut lo = polygon::bounds(reference).map_or(Vec2::ZERO, |b| b.0);
        let mut hi = polygon::bounds(reference).map_or(Vec2::ZERO, |b| b.1);
        for q in &quads {
            for p in q {
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
        }
        let radius = plan.options.closing_radius * plan.crown_size;
        let side = (hi - lo).max_element();
        let px = (side + 2.0 * radius) / (g as f32 - 4.0);
        let centre = 0.5 * (lo + hi);
        let lo = centre - Vec2::splat(0.5 * px * g as f32);
        let to_px = |p: Vec2| (p - lo) / px;

        self.mask.fill(false);
        for q in &quads {
            let q = q.map(to_px);
            // A blade between two rows or columns of pixel centres covers
            // none, and its triangles need no test (on the foliage fit's
            // coarse raster that is about one blade in twenty: most cover
            // a centre or two).
            let (qlo, qhi) = (
                q[0].min(q[1]).min(q[2]).min(q[3]),
                q[0].max(q[1]).max(q[2]).max(q[3]),
            );
            let centres = ceil2(qlo - 0.5).cmple(floor2(qhi - 0.5));
            if centres.all() {
                fill_quad(&mut self.mask, g, q);
            }
            // Blades smaller than a pixel still count.
            let c = (q[0] + q[1] + q[2] + q[3]) * 0.25;
            if c.x >= 0.0 && c.y >= 0.0 && (c.x as usize) < g && (c.y as usize) < g {
                self.mask[c.y as usize * g + c.x as usize] = true;
            }
        }
        let r_px = radius / px;
        if r_px > 0.0 {
            crate::closing::close(&mut self.mask, g, r_px * r_px);
        }
        self.fill_holes();
        let poly: Vec<Vec2> = reference.iter().map(|&p| to_px(p)).collect();
        fill_polygon(&mut self.reference, g, &poly);
        (lo, px)
    }

    /// Sets every background pixel not 4-connected to the border.
    fn fill_holes(&mut self) {
        let g = self.size;
        let mut outside = vec![false; g * g];
        self.stack.clear();
        for i in 0..g {
            for p in [i, (g - 1) * g + i, i * g, i * g + g - 1] {
                if !self.mask[p] && !outside[p] {
                    outside[p] = true;
                    self.stack.push(p);
                }
            }
        }
        while let Some(p) = self.stack.pop() {
            let (x, y) = (p % g, p / g);
            let mut visit = |q: usize| {
                if !self.mask[q] && !outside[q] {
                    outside[q] = true;
                    self.stack.push(q);
                }
            };
            if x > 0 {
                visit(p - 1);
            }
            if x + 1 < g {
                visit(p + 1);
            }
            if y > 0 {
                visit(p - g);
            }
            if y + 1 < g {
                visit(p + g);
            }
        }
        for (m, o) in self.mask.iter_mut().zip(outside) {
            *m = !o;
        }
    }

    /// The outer boundary of the mask's largest 4-connected region, in NDC.
    fn trace(&mut self, lo: Vec2, px: f32) -> Vec<Vec2> {
        let sizes = self.label_regions();
        let Some(best) = (1..sizes.len()).max_by_key(|&l| (sizes[l], std::cmp::Reverse(l))) else {
            return Vec::new();
        };
        let loops = self.boundary_loops(|l| l == best as u32);
        loops
            .iter()
            .max_by(|a, b| loop_area(a).total_cmp(&loop_area(b)))
            .map_or_else(Vec::new, |outer| corners(outer, lo, px))
    }

    /// The outer boundary of every 4-connected region of the mask, in NDC
    /// (counter-clockwise).
    fn trace_all(&mut self, lo: Vec2, px: f32) -> Vec<Vec<Vec2>> {
        self.label_regions();
        self.boundary_loops(|_| true)
            .iter()
            .filter(|l| loop_area(l) > 0.0)
            .map(|l| corners(l, lo, px))
            .collect()
    }

    /// Labels the mask's 4-connected regions 1, 2, … in `label`; returns
    /// each label's pixel count (index 0 unused).
    fn label_regions(&mut self) -> Vec<usize> {
        let g = self.size;
        self.label.fill(0);
        let mut sizes = vec![0usize];
        let mut next = 0u32;
        for start in 0..g * g {
            if !self.mask[start] || self.label[start] != 0 {
                continue;
            }
            next += 1;
            let mut count = 0;
            self.stack.clear();
            self.stack.push(start);
            self.label[start] = next;
            while let Some(p) = self.stack.pop() {
                count += 1;
                let (x, y) = (p % g, p / g);
                let nbrs = [
                    (x > 0).then(|| p - 1),
                    (x + 1 < g).then(|| p + 1),
                    (y > 0).then(|| p - g),
                    (y + 1 < g).then(|| p + g),
                ];
                for q in nbrs.into_iter().flatten() {
                    if self.mask[q] && self.label[q] == 0 {
                        self.label[q] = next;
                        self.stack.push(q);
                    }
                }
            }
            sizes.push(count);
        }
        sizes
    }

    /// The boundary loops (lattice vertices, region on the left) of the
    /// labelled regions `keep` accepts.
    fn boundary_loops(&self, keep: impl Fn(u32) -> bool) -> Vec<Vec<(i64, i64)>> {
        let g = self.size;
        let inside = |x: i64, y: i64| {
            x >= 0
                && y >= 0
                && (x as usize) < g
                && (y as usize) < g
                && self.label[y as usize * g + x as usize] != 0
                && keep(self.label[y as usize * g + x as usize])
        };
        // Directed boundary edges with the region on the left; per lattice
        // vertex a bit set of outgoing directions (E, N, W, S).
        let w = g + 1;
        let mut out = vec![0u8; w * w];
        for y in 0..g as i64 {
            for x in 0..g as i64 {
                if !inside(x, y) {
                    continue;
                }
                let (xu, yu) = (x as usize, y as usize);
                if !inside(x, y - 1) {
                    out[yu * w + xu] |= 1; // bottom edge, east
                }
                if !inside(x + 1, y) {
                    out[yu * w + xu + 1] |= 2; // right edge, north
                }
                if !inside(x, y + 1) {
                    out[(yu + 1) * w + xu + 1] |= 4; // top edge, west
                }
                if !inside(x - 1, y) {
                    out[(yu + 1) * w + xu] |= 8; // left edge, south
                }
            }
        }
        const STEP: [(i64, i64); 4] = [(1, 0), (0, 1), (-1, 0), (0, -1)];
        let mut loops: Vec<Vec<(i64, i64)>> = Vec::new();
        for v0 in 0..w * w {
            while out[v0] != 0 {
                let mut dir = out[v0].trailing_zeros() as usize;
                let (mut x, mut y) = ((v0 % w) as i64, (v0 / w) as i64);
                let mut lp = Vec::new();
                loop {
                    let v = y as usize * w + x as usize;
                    if out[v] & (1 << dir) == 0 {
                        break;
                    }
                    out[v] &= !(1 << dir);
                    lp.push((x, y));
                    x += STEP[dir].0;
                    y += STEP[dir].1;
                    let nv = y as usize * w + x as usize;
                    // Prefer a left turn, then straight, then right.
                    let choices = [(dir + 1) % 4, dir, (dir + 3) % 4];
                    match choices.iter().find(|&&d| out[nv] & (1 << d) != 0) {
                        Some(&d) => dir = d,
                        None => break,
                    }
                }
                loops.push(lp);
            }
        }
        loops
    }
}

/// Twice the signed area of a lattice loop.
fn loop_area(l: &[(i64, i64)]) -> f64 {
    let n = l.len();
    (0..n)
        .map(|i| {
            let (a, b) = (l[i], l[(i + 1) % n]);
            (a.0 * b.1 - b.0 * a.1) as f64
        })
        .sum()
}

/// The corners of a lattice loop, in NDC (`lo` + lattice × `px`).
fn corners(outer: &[(i64, i64)], lo: Vec2, px: f32) -> Vec<Vec2> {
    let n = outer.len();
    let mut poly = Vec::new();
    for i in 0..n {
        let (a, b, c) = (outer[(i + n - 1) % n], outer[i], outer[(i + 1) % n]);
        if (b.0 - a.0) * (c.1 - b.1) - (b.1 - a.1) * (c.0 - b.0) != 0 {
            poly.push(lo + Vec2::new(b.0 as f32, b.1 as f32) * px);
        }
    }
    poly
}

/// The leaves of `frame` as projected blades (NDC quads), in leaf order:
/// the leaves with no area, any corner behind a perspective eye, or off
/// to infinity are left out. Projected in parallel: a few thousand
/// leaves per measured frame.
fn blades(cam: &Camera, frame: &Frame) -> Vec<[Vec2; 4]> {
    use rayon::prelude::*;
    frame
        .leaves
        .par_iter()
        .filter_map(|leaf| {
            if !(leaf.width > 0.0 && leaf.height > 0.0) {
                return None;
            }
            let corners = [
                Vec3::new(-0.5 * leaf.width, 0.0, 0.0),
                Vec3::new(0.5 * leaf.width, 0.0, 0.0),
                Vec3::new(0.5 * leaf.width, leaf.height, 0.0),
                Vec3::new(-0.5 * leaf.width, leaf.height, 0.0),
            ]
            .map(|c| leaf.anchor + leaf.orientation * c);
            if cam.is_perspective() && corners.iter().any(|&c| cam.depth(c) <= 0.0) {
                return None;
            }
            let q = corners.map(|c| cam.project(c).0);
            q.iter().all(|p| p.is_finite()).then_some(q)
        })
        .collect()
}

/// `v.ceil()` per coordinate, without a call into libm: the x86-64
/// baseline has no rounding instruction, and a few thousand blades per
/// measured frame made those calls a third of the rasterisation. The same
/// values (a zero's sign aside), since every `f32` of magnitude 2²³ or more
/// is an integer and a smaller one truncates exactly.
fn ceil2(v: Vec2) -> Vec2 {
    v.map(|x| {
        if x.is_nan() || x.abs() >= 8_388_608.0 {
            return x;
        }
        let t = x as i32 as f32;
        if t < x { t + 1.0 } else { t }
    })
}

/// `v.floor()` per coordinate, as [`ceil2`].
fn floor2(v: Vec2) -> Vec2 {
    -ceil2(-v)
}

/// Marks the pixels whose centres are inside the quad `q` (pixel units):
/// inside its triangle `q0 q1 q2` or `q0 q2 q3` ([`Triangle::covers`]),
/// in one sweep of their pixel ranges. Pixels already marked are not
/// tested again: in a dense crown most blades fall on foliage an earlier
/// blade covered.
fn fill_quad(mask: &mut [bool], g: usize, q: [Vec2; 4]) {
    let tris = [
        Triangle::new(g, q[0], q[1], q[2]),
        Triangle::new(g, q[0], q[2], q[3]),
    ];
    let Some(([x0, y0], [x1, y1])) =
        tris.iter()
            .flatten()
            .map(|t| (t.from, t.to))
            .reduce(|a, b| {
                (
                    [a.0[0].min(b.0[0]), a.0[1].min(b.0[1])],
                    [a.1[0].max(b.1[0]), a.1[1].max(b.1[1])],
                )
            })
    else {
        return;
    };
    for y in y0..=y1 {
        for x in x0..=x1 {
            let i = y * g + x;
            if !mask[i] && tris.iter().flatten().any(|t| t.covers(x, y)) {
                mask[i] = true;
            }
        }
    }
}

/// A triangle to rasterise: its corners, the sign of its area and the
/// pixels its bounding box spans (inclusive, within the raster).
struct Triangle {
    a: Vec2,
    b: Vec2,
    c: Vec2,
    area: f32,
    from: [usize; 2],
    to: [usize; 2],
}

impl Triangle {
    /// Triangle `abc` on a `g`² raster; `None` when it spans no area or
    /// no pixel centre of the raster.
    fn new(g: usize, a: Vec2, b: Vec2, c: Vec2) -> Option<Triangle> {
        let lo = a.min(b).min(c);
        let hi = a.max(b).max(c);
        let (from, to) = (ceil2(lo - 0.5), floor2(hi - 0.5));
        let x1 = (to.x.min(g as f32 - 1.0)).max(-1.0);
        let y1 = (to.y.min(g as f32 - 1.0)).max(-1.0);
        let area = (b - a).perp_dot(c - a);
        if x1 < 0.0 || y1 < 0.0 || area == 0.0 {
            return None;
        }
        let from = [from.x.max(0.0) as usize, from.y.max(0.0) as usize];
        let to = [x1 as usize, y1 as usize];
        (from[0] <= to[0] && from[1] <= to[1]).then_some(Triangle {
            a,
            b,
            c,
            area,
            from,
            to,
        })
    }

    /// Whether the centre of pixel `(x, y)` is inside (edges included).
    fn covers(&self, x: usize, y: usize) -> bool {
        if x < self.from[0] || x > self.to[0] || y < self.from[1] || y > self.to[1] {
            return false;
        }
        let (a, b, c) = (self.a, self.b, self.c);
        let p = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
        let w0 = (b - a).perp_dot(p - a);
        let w1 = (c - b).perp_dot(p - b);
        let w2 = (a - c).perp_dot(p - c);
        if self.area > 0.0 {
            w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0
        } else {
            w0 <= 0.0 && w1 <= 0.0 && w2 <= 0.0
        }
    }
}

/// Sets `mask` to the pixels whose centres are inside `poly` (pixel units,
/// even–odd), clearing the rest.
fn fill_polygon(mask: &mut [bool], g: usize, poly: &[Vec2]) {
    mask.fill(false);
    let n = poly.len();
    let mut xs: Vec<f32> = Vec::new();
    for y in 0..g {
        let cy = y as f32 + 0.5;
        xs.clear();
        for i in 0..n {
            let (a, b) = (poly[i], poly[(i + 1) % n]);
            if (a.y > cy) != (b.y > cy) {
                xs.push(a.x + (cy - a.y) / (b.y - a.y) * (b.x - a.x));
            }
        }
        xs.sort_by(f32::total_cmp);
        for pair in xs.chunks_exact(2) {
            let x0 = (pair[0] - 0.5).ceil().max(0.0) as usize;
            let x1 = (pair[1] - 0.5).floor().min(g as f32 - 1.0);
            if x1 < 0.0 {
                continue;
            }
            for x in x0..=x1 as usize {
                mask[y * g + x] = true;
            }
        }
    }
}

/// Distance from `p` to the polyline through `nodes`, and the radius at
/// the closest point.
fn to_polyline(p: Vec3, nodes: &[u32], pos: &[Vec3], radii: &[f32]) -> (f32, f32) {
    if let [only] = nodes {
        return (p.distance(pos[*only as usize]), radii[*only as usize]);
    }
    let mut best = (f32::INFINITY, 0.0);
    for w in nodes.windows(2) {
        let (i, j) = (w[0] as usize, w[1] as usize);
        let (q, f) = closest_on_segment(p, pos[i], pos[j]);
        let d = p.distance(q);
        if d < best.0 {
            best = (d, radii[i] + (radii[j] - radii[i]) * f);
        }
    }
    best
}

/// Discrete Fréchet distance between two closed curves (see the module
/// docs for the common start).
fn closed_frechet(outline: &[Vec2], reference: &[Vec2], row: &mut Vec<f32>) -> f32 {
    if outline.len() < 3 || reference.len() < 3 {
        return f32::INFINITY;
    }
    let orient = |p: &[Vec2]| -> Vec<Vec2> {
        let mut v = p.to_vec();
        if polygon::signed_area(&v) < 0.0 {
            v.reverse();
        }
        v
    };
    let o = orient(outline);
    let r = orient(reference);
    let top = polygon::topmost(&r);
    let r: Vec<Vec2> = (0..r.len()).map(|k| r[(top + k) % r.len()]).collect();
    let rs = polygon::resample_closed(&r, SAMPLES);
    let os = polygon::resample_closed(&o, SAMPLES);
    let mut best = (f32::INFINITY, 0usize);
    for shift in 0..SAMPLES {
        let cost: f32 = (0..SAMPLES)
            .map(|k| os[(k + shift) % SAMPLES].distance_squared(rs[k]))
            .sum();
        if cost < best.0 {
            best = (cost, shift);
        }
    }
    let mut a: Vec<Vec2> = Vec::with_capacity(SAMPLES + 1);
    let mut b: Vec<Vec2> = rs.clone();
    b.push(rs[0]);
    let mut result = f32::INFINITY;
    for delta in -3i64..=3 {
        let shift = (best.1 as i64 + delta).rem_euclid(SAMPLES as i64) as usize;
        a.clear();
        a.extend((0..SAMPLES).map(|k| os[(k + shift) % SAMPLES]));
        a.push(os[shift]);
        result = result.min(discrete_frechet_with(&a, &b, row));
    }
    result
}

/// `max |len / (λ × rest) − 1|` over one chain's (rest, now) segment
/// lengths, `λ` their sum now over at rest (0 for a chain of no length).
fn segment_stretch(segments: impl Iterator<Item = (f32, f32)> + Clone) -> f32 {
    let (rest, now) = segments
        .clone()
        .fold((0.0f32, 0.0f32), |(r, n), (a, b)| (r + a, n + b));
    if rest <= 0.0 || now <= 0.0 {
        return 0.0;
    }
    let lambda = now / rest;
    segments
        .map(|(rest, len)| (len / (lambda * rest) - 1.0).abs())
        .fold(0.0, f32::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: measured against the chord's growth, a chain bending
    /// mid-animation with every segment at its rest length showed 23 %
    /// stretch. Against the chain's own arc, bending is no stretch and one
    /// segment pulled while its neighbour squeezes is.
    #[test]
    fn stretch_is_beyond_the_chains_own_growth() {
        let bent = [(1.0, 1.0), (2.0, 2.0), (1.0, 1.0)];
        assert_eq!(segment_stretch(bent.into_iter()), 0.0);
        let grown = [(1.0, 1.5), (2.0, 3.0)];
        assert!(segment_stretch(grown.into_iter()) < 1e-6);
        let pulled = [(1.0, 1.5), (1.0, 0.5)];
        assert!((segment_stretch(pulled.into_iter()) - 0.5).abs() < 1e-6);
        assert_eq!(segment_stretch([(0.0, 0.0)].into_iter()), 0.0);
    }

    /// A crown outline shifted left of the reference misses the
    /// reference on its right and spills over on its left: the balance
    /// is positive at the right-hand sample, negative at the left-hand one,
    /// and they cancel.
    #[test]
    fn the_balance_shows_where_the_outline_falls_short() {
        let plan = crate::plan::tests::heart_plan(crate::SketchOptions::default());
        let g = 20;
        let mut metrics = SketchMetrics::with_raster(&plan, g as u32);
        let square = |x0: f32| {
            [
                Vec2::new(x0, 4.0),
                Vec2::new(x0 + 12.0, 4.0),
                Vec2::new(x0 + 12.0, 16.0),
                Vec2::new(x0, 16.0),
            ]
        };
        fill_polygon(&mut metrics.reference, g, &square(4.0));
        fill_polygon(&mut metrics.mask, g, &square(2.0));
        let samples = [
            Vec2::new(16.0, 10.0),
            Vec2::new(10.0, 16.0),
            Vec2::new(4.0, 10.0),
            Vec2::new(10.0, 4.0),
        ];
        let net = metrics.balance(Vec2::ZERO, 1.0, &samples);
        // 24 pixels each way; the corner pixels are as near the top and
        // bottom samples.
        assert_eq!(net.iter().sum::<f32>(), 0.0, "{net:?}");
        assert_eq!(net[2], -24.0, "{net:?}");
        assert!(net[0] >= 22.0 && net[1] <= 1.0 && net[3] <= 1.0, "{net:?}");
    }

    /// The rounding without libm gives libm's values.
    #[test]
    fn rounding_matches_the_standard_library() {
        let values = [
            -1e30,
            -8_388_609.0,
            -8_388_607.5,
            -2.5,
            -1.0,
            -0.7,
            -0.0,
            0.0,
            0.3,
            0.5,
            1.0,
            1.000_001,
            127.5,
            8_388_607.5,
            3e9,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ];
        for &x in &values {
            let v = Vec2::new(x, -x);
            assert_eq!(ceil2(v), Vec2::new(x.ceil(), (-x).ceil()), "{x}");
            assert_eq!(floor2(v), Vec2::new(x.floor(), (-x).floor()), "{x}");
        }
        assert!(ceil2(Vec2::splat(f32::NAN)).is_nan());
    }

    #[test]
    fn polygon_fill_counts_pixel_centres() {
        let g = 10;
        let mut mask = vec![false; g * g];
        let sq = [
            Vec2::new(2.0, 2.0),
            Vec2::new(6.0, 2.0),
            Vec2::new(6.0, 5.0),
            Vec2::new(2.0, 5.0),
        ];
        fill_polygon(&mut mask, g, &sq);
        assert_eq!(mask.iter().filter(|&&m| m).count(), 12);
        let mut quad = vec![false; g * g];
        fill_quad(&mut quad, g, sq);
        assert_eq!(quad, mask);
    }
}
