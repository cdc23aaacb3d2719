//! Leaf contours: the outline of a leaf texture's blade as a polygon with a
//! fixed number of points, so leaves of two different shapes morph into
//! each other point by point (the morphing paper's "interpolation of
//! leaves, including shapes and textures", §5–6).
//!
//! A [`LeafContour`] is extracted once per leaf material from the texture's
//! alpha channel and then used by the leaf mesher's
//! [`LeafShape::Contour`](crate::mesh::LeafShape::Contour) mode: each leaf is
//! a fan of `K` triangles around a centre point, its vertices the contour of
//! its first material interpolated toward its second material's contour by
//! the leaf's blend.
//!
//! # Blade coordinates
//! Contours live in **blade coordinates**: `x ∈ [-½, ½]` across the image
//! (left to right), `y ∈ [0, 1]` from the image's bottom row (the blade
//! base) to its top row (the tip). A leaf of width `w` and height `h` puts
//! blade point `(x, y)` at local `(x·w, y·h, 0)`, exactly where the
//! billboard quad puts that texel, so the texture coordinate of a contour
//! point is `(x + ½, 1 − y)` (glTF's `v = 0` is the top row).
//!
//! # Extraction
//! 1. **Marching squares** at alpha 0.5 over the pixel centres, with a
//!    transparent border so every loop closes; the crossings are linearly
//!    interpolated and ambiguous saddles resolved by the cell's mean.
//!    Loops are oriented with the blade on their left, so outer loops are
//!    counter-clockwise; the **largest outer loop** (by area) is the blade,
//!    islands and holes are dropped.
//! 2. The **centre** is the point on the midrib at mid-height: the middle
//!    of the blade's cross-section, at half the loop's height, that holds
//!    (or is nearest to) the image's centre column. (A centroid may lie
//!    outside a lobed maple leaf or a sickle-shaped eucalypt leaf.)
//! 3. **Star-shaped envelope.** From the centre, 720 rays sample the
//!    farthest crossing of the loop: the envelope is star-shaped with
//!    respect to the centre and contains the blade. For the generator's
//!    blade shapes (pinnate, palmate and round leaves) the loop already is
//!    star-shaped and the envelope is the loop; for a needle spray it
//!    closes the gaps between needles. The **base** (lowest loop point,
//!    nearest the centre column: the petiole's end at the bottom centre of
//!    an upright leaf image) and the **tip** (highest point) are cast
//!    exactly.
//! 4. **Simplify** each half (base → tip on the right, tip → base on the
//!    left) with Douglas–Peucker at 0.5 px, which removes the pixel
//!    staircase before arc lengths are measured.
//! 5. **Resample** each half by arc length to `K/2` points: point 0 is the
//!    base, point `K/2` the tip, counter-clockwise (the right side of the
//!    blade first). Anchoring base and tip makes the parameterisation
//!    consistent across shapes, so two contours interpolate pointwise
//!    without twisting; arc length spends the points where the outline is.
//!
//! # Why the fan cannot fold
//! Every resampled point lies on the star-shaped envelope, in angular
//! order about the centre, so the fan of a contour has only
//! counter-clockwise triangles. Interpolating two contours moves each
//! point on a straight line; because both share base, tip and the side of
//! each point, corresponding points stay within a quarter turn of each
//! other as seen from the interpolated centre, and the fan does not fold.
//! The tests check this for every pair of the generator's leaf shapes at
//! several blends. The interpolated contour also keeps its base lowest and
//! its tip highest (both are extremes of their own contours), which the
//! animated GLB's leaf swap relies on.
//!
//! # Texture warps
//! [`blend_textures`] maps texel positions between two contours through
//! their fans (an affine map per fan triangle, extended beyond the rim
//! along each sector), so a texture drawn for one outline can be sampled on
//! another's texture coordinates: a leaf keeps the UVs of its first
//! material's contour in every frame, and its second material's texture is
//! warped into that space before the texel-wise blend.

use std::f32::consts::{PI, TAU};

use glam::Vec2;
use thiserror::Error;
use treemorph_tree::geom::NONE;
use treemorph_tree::{LeafMaterial, RgbaImage};

/// Fewest contour points accepted.
pub const MIN_POINTS: u32 = 4;
/// Most contour points accepted.
pub const MAX_POINTS: u32 = 256;

/// Rays cast from the centre to sample the star-shaped envelope.
const RAYS: usize = 720;
/// Douglas–Peucker tolerance, pixels.
const SIMPLIFY_PX: f32 = 0.5;
/// Alpha level of the blade outline.
const ALPHA_LEVEL: f32 = 0.5;

/// Why a contour could not be extracted.
#[derive(Clone, Debug, Error, PartialEq, Eq)]
#[non_exhaustive]
pub enum ContourError {
    /// The point count is odd or outside [`MIN_POINTS`]..=[`MAX_POINTS`].
    #[error("a contour needs an even number of points in {MIN_POINTS}..={MAX_POINTS}; got {0}")]
    InvalidPoints(u32),
    /// No pixel reaches alpha 0.5: the image has no blade.
    #[error("the image has no pixel with alpha of at least 0.5")]
    NoBlade,
}

/// Checks a contour point count.
pub(crate) fn check_points(points: u32) -> Result<(), ContourError> {
    if (MIN_POINTS..=MAX_POINTS).contains(&points) && points.is_multiple_of(2) {
        Ok(())
    } else {
        Err(ContourError::InvalidPoints(points))
    }
}

/// A leaf outline with a fixed number of points, in blade coordinates (see
/// the [module docs](self)).
#[derive(Clone, Debug, PartialEq)]
pub struct LeafContour {
    rim: Vec<Vec2>,
    centre: Vec2,
}

impl LeafContour {
    /// The blade outline of `image` (rows top to bottom, blade base on the
    /// bottom row) with `points` points.
    pub fn from_image(image: &RgbaImage, points: u32) -> Result<LeafContour, ContourError> {
        check_points(points)?;
        let (w, h) = (image.width as usize, image.height as usize);
        let alpha = |x: usize, y: usize| f32::from(image.pixels[(y * w + x) * 4 + 3]) / 255.0;
        // Sample grid with a transparent border; row 0 is the bottom row
        // (y up), sample (i, j) sits at pixel coordinates (i − ½, j − ½).
        let (gw, gh) = (w + 2, h + 2);
        let mut grid = vec![0f32; gw * gh];
        for j in 0..h {
            for i in 0..w {
                grid[(j + 1) * gw + i + 1] = alpha(i, h - 1 - j);
            }
        }
        let blade = largest_outer_loop(&grid, gw, gh).ok_or(ContourError::NoBlade)?;
        Ok(Self::from_loop(&blade, w as f32, h as f32, points))
    }

    /// The full image rectangle: the outline of an untextured leaf (a solid
    /// quad).
    pub fn rectangle(points: u32) -> Result<LeafContour, ContourError> {
        check_points(points)?;
        // In "pixels" of a 64-pixel image, so the simplification
        // tolerance keeps its meaning.
        let side = 64.0;
        let square = [
            Vec2::new(0.0, 0.0),
            Vec2::new(side, 0.0),
            Vec2::new(side, side),
            Vec2::new(0.0, side),
        ];
        Ok(Self::from_loop(&square, side, side, points))
    }

    /// The contour of a leaf material: its texture's outline, or the
    /// rectangle when it has no texture, its texture does not decode or
    /// has no blade (so meshing never fails on a texture; the encoders
    /// still embed the texture as it is).
    pub fn of_material(material: &LeafMaterial, points: u32) -> Result<LeafContour, ContourError> {
        check_points(points)?;
        let from_texture = material
            .texture
            .as_ref()
            .and_then(|t| t.decode().ok())
            .and_then(|image| Self::from_image(&image, points).ok());
        match from_texture {
            Some(c) => Ok(c),
            None => Self::rectangle(points),
        }
    }

    /// The `K` rim points, counter-clockwise from the base; point `K/2` is
    /// the tip.
    pub fn rim(&self) -> &[Vec2] {
        &self.rim
    }

    /// The fan's centre (on the midrib at mid-height).
    pub fn centre(&self) -> Vec2 {
        self.centre
    }

    /// Number of rim points `K`.
    pub fn len(&self) -> usize {
        self.rim.len()
    }

    /// Whether the contour has no points (never, for a built contour).
    pub fn is_empty(&self) -> bool {
        self.rim.is_empty()
    }

    /// Fan vertices — the centre, then the rim — of this contour
    /// interpolated toward `other` by `s` (0: this, 1: `other`), written to
    /// `out` (`K + 1` points). Both contours must have the same `K`.
    pub fn lerp_fan(&self, other: &LeafContour, s: f32, out: &mut [Vec2]) {
        out[0] = self.centre.lerp(other.centre, s);
        for ((o, a), b) in out[1..].iter_mut().zip(&self.rim).zip(&other.rim) {
            *o = a.lerp(*b, s);
        }
    }

    /// The fan vertices of this contour (the centre, then the rim).
    pub fn fan(&self) -> impl Iterator<Item = Vec2> + '_ {
        std::iter::once(self.centre).chain(self.rim.iter().copied())
    }

    /// Texture coordinate (glTF convention) of blade point `p`.
    pub fn uv(p: Vec2) -> Vec2 {
        Vec2::new(p.x + 0.5, 1.0 - p.y)
    }

    /// Builds the contour from a blade loop in pixel coordinates (y up,
    /// counter-clockwise) of a `w × h` image.
    fn from_loop(blade: &[Vec2], w: f32, h: f32, points: u32) -> LeafContour {
        let centre = midrib_centre(blade, w);
        let lowest = extreme(blade, w, |p| -p.y);
        let highest = extreme(blade, w, |p| p.y);
        let envelope = Envelope::new(blade, centre);
        let theta_base = angle(lowest - centre);
        let theta_tip = angle(highest - centre);
        // Right half: base → tip counter-clockwise; left half: tip → base.
        let span_right = (theta_tip - theta_base).rem_euclid(TAU);
        let half = points as usize / 2;
        let mut rim = Vec::with_capacity(points as usize);
        for (start, span) in [(theta_base, span_right), (theta_tip, TAU - span_right)] {
            let mut line = envelope.arc(start, span);
            line = simplify(&line, SIMPLIFY_PX);
            rim.extend(resample(&line, half));
        }
        let to_blade = |p: Vec2| Vec2::new(p.x / w - 0.5, p.y / h);
        LeafContour {
            rim: rim.into_iter().map(to_blade).collect(),
            centre: to_blade(centre),
        }
    }
}

/// Angle of `v` in radians.
fn angle(v: Vec2) -> f32 {
    v.y.atan2(v.x)
}

/// The loop point maximising `key` (`±y`), ties (within 0.01 px) broken by
/// nearness to the image's centre column: on a flat extreme edge (a
/// petiole's cut end, a rectangle's side) that is the point of the edge on
/// the column.
fn extreme(blade: &[Vec2], w: f32, key: impl Fn(Vec2) -> f32) -> Vec2 {
    let best = blade.iter().map(|&p| key(p)).fold(f32::MIN, f32::max);
    let column = w * 0.5;
    let on = |p: Vec2| key(p) >= best - 0.01;
    let mut candidates: Vec<Vec2> = blade.iter().copied().filter(|&p| on(p)).collect();
    for (i, &a) in blade.iter().enumerate() {
        let b = blade[(i + 1) % blade.len()];
        if on(a) && on(b) && (a.x.min(b.x)..=a.x.max(b.x)).contains(&column) && a.x != b.x {
            candidates.push(a.lerp(b, (column - a.x) / (b.x - a.x)));
        }
    }
    candidates
        .into_iter()
        .min_by(|a, b| (a.x - column).abs().total_cmp(&(b.x - column).abs()))
        .unwrap_or(blade[0])
}

/// The middle of the blade's cross-section at mid-height that holds (or is
/// nearest to) the centre column `x = w/2`.
fn midrib_centre(blade: &[Vec2], w: f32) -> Vec2 {
    let (lo, hi) = blade.iter().fold((f32::MAX, f32::MIN), |(lo, hi), p| {
        (lo.min(p.y), hi.max(p.y))
    });
    let y = 0.5 * (lo + hi);
    let mut xs: Vec<f32> = Vec::new();
    for (i, &a) in blade.iter().enumerate() {
        let b = blade[(i + 1) % blade.len()];
        // Half-open so a vertex on the line counts once.
        if (a.y <= y) != (b.y <= y) {
            xs.push(a.x + (y - a.y) / (b.y - a.y) * (b.x - a.x));
        }
    }
    xs.sort_by(f32::total_cmp);
    let column = w * 0.5;
    let best = xs
        .chunks_exact(2)
        .min_by(|a, b| {
            let d = |s: &[f32]| {
                if (s[0]..=s[1]).contains(&column) {
                    0.0
                } else {
                    (s[0] - column).abs().min((s[1] - column).abs())
                }
            };
            d(a).total_cmp(&d(b))
        })
        .map(|s| 0.5 * (s[0] + s[1]));
    Vec2::new(best.unwrap_or(column), y)
}

/// The loop's farthest crossing along rays from a centre: the boundary of
/// the smallest star-shaped region about the centre that contains the loop.
struct Envelope<'a> {
    blade: &'a [Vec2],
    centre: Vec2,
    /// Farthest crossing distance of each of [`RAYS`] uniform rays.
    radius: Vec<f32>,
}

impl<'a> Envelope<'a> {
    fn new(blade: &'a [Vec2], centre: Vec2) -> Envelope<'a> {
        let mut radius = vec![0f32; RAYS];
        let step = TAU / RAYS as f32;
        for (i, &a) in blade.iter().enumerate() {
            let b = blade[(i + 1) % blade.len()];
            // The rays whose angles fall within the edge's angular span
            // (under half a turn, as seen from an interior point).
            let (ta, tb) = (angle(a - centre), angle(b - centre));
            let mut d = tb - ta;
            if d > PI {
                d -= TAU;
            } else if d < -PI {
                d += TAU;
            }
            let (from, to) = if d >= 0.0 { (ta, ta + d) } else { (ta + d, ta) };
            let first = (from / step).ceil() as i64;
            let last = (to / step).floor() as i64;
            for m in first..=last {
                let theta = m as f32 * step;
                if let Some(r) = crossing(centre, theta, a, b) {
                    let slot = &mut radius[m.rem_euclid(RAYS as i64) as usize];
                    *slot = slot.max(r);
                }
            }
        }
        Envelope {
            blade,
            centre,
            radius,
        }
    }

    /// The envelope from direction `start` counter-clockwise through
    /// `span` radians: the exact crossings at both ends and the sampled
    /// rays between them.
    fn arc(&self, start: f32, span: f32) -> Vec<Vec2> {
        let step = TAU / RAYS as f32;
        let mut line = vec![self.exact(start)];
        let mut m = (start / step).floor() as i64 + 1;
        // Leave a tenth of a ray's spacing before the end, so the end
        // point is not doubled.
        while (m as f32) * step < start + span - 0.1 * step {
            let slot = m.rem_euclid(RAYS as i64) as usize;
            if self.radius[slot] > 0.0 {
                line.push(self.at(m as f32 * step, self.radius[slot]));
            }
            m += 1;
        }
        line.push(self.exact(start + span));
        line
    }

    /// The farthest loop crossing in direction `theta`, cast over every
    /// loop edge (the centre itself if there is none, which a centre
    /// inside the loop rules out).
    fn exact(&self, theta: f32) -> Vec2 {
        let r = self
            .blade
            .iter()
            .enumerate()
            .filter_map(|(i, &a)| {
                crossing(
                    self.centre,
                    theta,
                    a,
                    self.blade[(i + 1) % self.blade.len()],
                )
            })
            .fold(0f32, f32::max);
        self.at(theta, r)
    }

    fn at(&self, theta: f32, r: f32) -> Vec2 {
        self.centre + Vec2::new(theta.cos(), theta.sin()) * r
    }
}

/// Distance along the ray from `c` in direction `theta` to segment `a b`,
/// if they cross.
fn crossing(c: Vec2, theta: f32, a: Vec2, b: Vec2) -> Option<f32> {
    let d = Vec2::new(theta.cos(), theta.sin());
    let e = b - a;
    let denom = d.perp_dot(e);
    if denom.abs() < 1e-12 {
        return None;
    }
    let ac = a - c;
    let r = ac.perp_dot(e) / denom;
    let u = ac.perp_dot(d) / denom;
    (r > 0.0 && (-1e-5..=1.0 + 1e-5).contains(&u)).then_some(r)
}

/// Douglas–Peucker simplification of an open polyline (ends kept).
fn simplify(line: &[Vec2], tolerance: f32) -> Vec<Vec2> {
    if line.len() <= 2 {
        return line.to_vec();
    }
    let mut keep = vec![false; line.len()];
    keep[0] = true;
    keep[line.len() - 1] = true;
    let mut stack = vec![(0usize, line.len() - 1)];
    while let Some((a, b)) = stack.pop() {
        let (pa, pb) = (line[a], line[b]);
        let e = pb - pa;
        let len = e.length();
        let (mut worst, mut at) = (0f32, a);
        for (i, &p) in line.iter().enumerate().take(b).skip(a + 1) {
            let d = if len > 1e-9 {
                (p - pa).perp_dot(e).abs() / len
            } else {
                p.distance(pa)
            };
            if d > worst {
                worst = d;
                at = i;
            }
        }
        if worst > tolerance {
            keep[at] = true;
            stack.push((a, at));
            stack.push((at, b));
        }
    }
    line.iter()
        .zip(keep)
        .filter_map(|(&p, k)| k.then_some(p))
        .collect()
}

/// `n` points along an open polyline at equal arc-length steps, from its
/// first point (included) to its last (excluded).
fn resample(line: &[Vec2], n: usize) -> Vec<Vec2> {
    let lengths: Vec<f32> = line.windows(2).map(|w| w[0].distance(w[1])).collect();
    let total: f32 = lengths.iter().sum();
    let mut out = Vec::with_capacity(n);
    let (mut seg, mut walked) = (0usize, 0f32);
    for i in 0..n {
        let target = total * i as f32 / n as f32;
        while seg + 1 < lengths.len() && walked + lengths[seg] < target {
            walked += lengths[seg];
            seg += 1;
        }
        let l = lengths.get(seg).copied().unwrap_or(0.0);
        let t = if l > 0.0 {
            ((target - walked) / l).clamp(0.0, 1.0)
        } else {
            0.0
        };
        out.push(line[seg].lerp(line[(seg + 1).min(line.len() - 1)], t));
    }
    out
}

/// Marching squares at [`ALPHA_LEVEL`] over a `gw × gh` grid (row 0 at the
/// bottom; sample `(i, j)` at pixel coordinates `(i − ½, j − ½)`, the
/// border all zero): the outer loop of largest area, counter-clockwise, in
/// pixel coordinates.
fn largest_outer_loop(grid: &[f32], gw: usize, gh: usize) -> Option<Vec<Vec2>> {
    let inside = |i: usize, j: usize| grid[j * gw + i] >= ALPHA_LEVEL;
    let pos = |i: usize, j: usize| Vec2::new(i as f32 - 0.5, j as f32 - 0.5);
    // Edge ids: horizontal edge from sample (i, j) to (i+1, j) is
    // `2·(j·gw + i)`, vertical edge from (i, j) to (i, j+1) is that + 1.
    let h_edge = |i: usize, j: usize| 2 * (j * gw + i);
    let v_edge = |i: usize, j: usize| 2 * (j * gw + i) + 1;
    let crossing = |edge: usize| -> Vec2 {
        let s = edge / 2;
        let (i, j) = (s % gw, s / gw);
        let (i2, j2) = if edge.is_multiple_of(2) {
            (i + 1, j)
        } else {
            (i, j + 1)
        };
        let (va, vb) = (grid[j * gw + i], grid[j2 * gw + i2]);
        let t = ((ALPHA_LEVEL - va) / (vb - va)).clamp(0.0, 1.0);
        pos(i, j).lerp(pos(i2, j2), t)
    };
    // next[edge] = the edge the contour leaves the cell through after
    // entering at `edge` (each crossed edge starts exactly one segment).
    let mut next = vec![NONE; 2 * gw * gh];
    for j in 0..gh - 1 {
        for i in 0..gw - 1 {
            // Cell boundary walked counter-clockwise from the bottom-left
            // corner: bottom, right, top, left edges.
            let corners = [
                inside(i, j),
                inside(i + 1, j),
                inside(i + 1, j + 1),
                inside(i, j + 1),
            ];
            let edges = [
                h_edge(i, j),
                v_edge(i + 1, j),
                h_edge(i, j + 1),
                v_edge(i, j),
            ];
            // Crossing k lies between corner k and corner k+1; it is
            // "leaving" when the walk goes from inside to outside.
            let mut leaving = [usize::MAX; 2];
            let mut entering = [usize::MAX; 2];
            let (mut nl, mut ne) = (0, 0);
            for k in 0..4 {
                let (a, b) = (corners[k], corners[(k + 1) % 4]);
                if a && !b {
                    leaving[nl] = k;
                    nl += 1;
                } else if !a && b {
                    entering[ne] = k;
                    ne += 1;
                }
            }
            // A segment runs from a leaving crossing to an entering one,
            // keeping the inside on its left. Two of each is a saddle:
            // pair with the following entering crossing when the cell's
            // centre is inside (the inside corners connect), else with the
            // preceding one (they stay apart).
            let centre_inside = (grid[j * gw + i]
                + grid[j * gw + i + 1]
                + grid[(j + 1) * gw + i + 1]
                + grid[(j + 1) * gw + i])
                * 0.25
                >= ALPHA_LEVEL;
            for &l in &leaving[..nl] {
                let target = if nl == 1 {
                    entering[0]
                } else {
                    let follow = (1..4).map(|d| (l + d) % 4).find(|k| entering.contains(k));
                    let precede = (1..4)
                        .map(|d| (l + 4 - d) % 4)
                        .find(|k| entering.contains(k));
                    let pick = if centre_inside { follow } else { precede };
                    match pick {
                        Some(k) => k,
                        None => continue,
                    }
                };
                next[edges[l]] = edges[target] as u32;
            }
        }
    }
    let mut best: Option<(f32, Vec<Vec2>)> = None;
    let mut seen = vec![false; next.len()];
    for start in 0..next.len() {
        if next[start] == NONE || seen[start] {
            continue;
        }
        let mut ring = Vec::new();
        let mut edge = start;
        while !seen[edge] && next[edge] != NONE {
            seen[edge] = true;
            ring.push(crossing(edge));
            edge = next[edge] as usize;
        }
        if edge != start || ring.len() < 3 {
            continue;
        }
        let area: f32 = ring
            .iter()
            .zip(ring.iter().cycle().skip(1))
            .map(|(a, b)| a.perp_dot(*b))
            .sum::<f32>()
            * 0.5;
        if area > 0.0 && best.as_ref().is_none_or(|(a, _)| area > *a) {
            best = Some((area, ring));
        }
    }
    best.map(|(_, ring)| ring)
}

/// Maps points of one contour's plane to another's through their fans: an
/// affine map per fan sector (the triangle centre, `rim[k]`, `rim[k+1]`,
/// extended beyond the rim), found by the point's angle about the source
/// centre. The source contour is star-shaped about its centre, so every
/// direction falls in exactly one sector.
struct FanMap {
    centre: Vec2,
    /// Rim angles about the source centre, unwrapped to increase from
    /// `angles[0]`.
    angles: Vec<f32>,
    /// Per sector: `p ↦ m · (p − centre) + t`.
    maps: Vec<([Vec2; 2], Vec2)>,
}

impl FanMap {
    fn new(from: &LeafContour, to: &LeafContour) -> FanMap {
        let k = from.rim.len();
        let c = from.centre;
        let mut angles = Vec::with_capacity(k);
        let mut previous = angle(from.rim[0] - c);
        angles.push(previous);
        for p in &from.rim[1..] {
            let mut a = angle(*p - c);
            while a <= previous {
                a += TAU;
            }
            angles.push(a);
            previous = a;
        }
        let maps = (0..k)
            .map(|s| {
                let (a, b) = (from.rim[s] - c, from.rim[(s + 1) % k] - c);
                let (a2, b2) = (to.rim[s] - to.centre, to.rim[(s + 1) % k] - to.centre);
                // Solve [a b] · λ = v, then p' = to.centre + [a2 b2] · λ.
                let det = a.perp_dot(b);
                let m = if det.abs() > 1e-12 {
                    // Columns of [a2 b2] · [a b]⁻¹.
                    let inv = [Vec2::new(b.y, -a.y) / det, Vec2::new(-b.x, a.x) / det];
                    [a2 * inv[0].x + b2 * inv[0].y, a2 * inv[1].x + b2 * inv[1].y]
                } else {
                    [Vec2::X, Vec2::Y]
                };
                (m, to.centre)
            })
            .collect();
        FanMap {
            centre: c,
            angles,
            maps,
        }
    }

    fn map(&self, p: Vec2) -> Vec2 {
        let v = p - self.centre;
        let mut a = angle(v);
        let first = self.angles[0];
        while a < first {
            a += TAU;
        }
        while a >= first + TAU {
            a -= TAU;
        }
        let s = self.angles.partition_point(|&x| x <= a).saturating_sub(1);
        let (m, t) = self.maps[s];
        t + m[0] * v.x + m[1] * v.y
    }
}

/// One side of a texture blend: an image (or none: opaque white), the
/// outline its blade fills, and a colour factor.
#[derive(Clone, Copy, Debug)]
pub struct BlendSource<'a> {
    /// The texture, decoded; `None` samples as opaque white.
    pub image: Option<&'a RgbaImage>,
    /// The outline of the texture's blade.
    pub contour: &'a LeafContour,
    /// Linear RGBA factor multiplied with every texel.
    pub color: [f32; 4],
}

impl BlendSource<'_> {
    /// The colour-multiplied texel at blade point `p`, bilinear, clamped
    /// to the edge.
    fn sample(&self, p: Vec2) -> [f32; 4] {
        let Some(image) = self.image else {
            return self.color;
        };
        let (w, h) = (image.width as f32, image.height as f32);
        let x = ((p.x + 0.5) * w - 0.5).clamp(0.0, w - 1.0);
        let y = ((1.0 - p.y) * h - 0.5).clamp(0.0, h - 1.0);
        let (x0, y0) = (x.floor() as u32, y.floor() as u32);
        let (x1, y1) = (
            (x0 + 1).min(image.width - 1),
            (y0 + 1).min(image.height - 1),
        );
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let px = |x: u32, y: u32| image.pixel(x, y).map(|c| f32::from(c) / 255.0);
        let (a, b, c, d) = (px(x0, y0), px(x1, y0), px(x0, y1), px(x1, y1));
        let mut out = [0f32; 4];
        for k in 0..4 {
            let top = a[k] + (b[k] - a[k]) * fx;
            let bottom = c[k] + (d[k] - c[k]) * fx;
            out[k] = (top + (bottom - top) * fy) * self.color[k];
        }
        out
    }

    fn size(&self) -> (u32, u32) {
        self.image.map_or((1, 1), |i| (i.width, i.height))
    }
}

/// The texel-wise blend `(1 − s)·a + s·b` of two colour-multiplied leaf
/// textures, in the texture space of `a`: texel `p` of the result samples
/// `a` at `p` and `b` at `p` mapped from `a`'s contour to `b`'s (see the
/// [module docs](self)), so drawing the result with `a`'s contour UVs shows
/// each texture on its own outline. The result has the larger of the two
/// widths and heights (the smaller image is resampled bilinearly); colour
/// factors are baked in, so the material using it needs a white factor.
/// [`BlendLayers`] makes many blends of one pair.
pub fn blend_textures(a: BlendSource<'_>, b: BlendSource<'_>, s: f32) -> RgbaImage {
    BlendLayers::new(a, b).blend(s)
}

/// The two layers every blend of textures `a` and `b` mixes
/// ([`blend_textures`]): per texel of the result, `a` sampled at it and `b`
/// sampled where the contours map it. Neither depends on the blend
/// factor, and sampling (bilinear, through the fan map's angle search) is
/// most of a blend's cost, so the blends of one pair at many factors (the
/// leaves of one frame, each at its own step) sample both textures once.
pub struct BlendLayers {
    width: u32,
    height: u32,
    /// `(a, b)` per texel, row by row.
    texels: Vec<([f32; 4], [f32; 4])>,
}

impl BlendLayers {
    /// Samples both layers.
    pub fn new(a: BlendSource<'_>, b: BlendSource<'_>) -> BlendLayers {
        let (wa, ha) = a.size();
        let (wb, hb) = b.size();
        let (width, height) = (wa.max(wb), ha.max(hb));
        let map = FanMap::new(a.contour, b.contour);
        let mut texels = Vec::with_capacity((width * height) as usize);
        for y in 0..height {
            for x in 0..width {
                let p = Vec2::new(
                    (x as f32 + 0.5) / width as f32 - 0.5,
                    1.0 - (y as f32 + 0.5) / height as f32,
                );
                texels.push((a.sample(p), b.sample(map.map(p))));
            }
        }
        BlendLayers {
            width,
            height,
            texels,
        }
    }

    /// The blend at factor `s` (clamped to [0, 1]; not finite: 0).
    pub fn blend(&self, s: f32) -> RgbaImage {
        let s = if s.is_finite() {
            s.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let mut pixels = Vec::with_capacity(self.texels.len() * 4);
        for (ca, cb) in &self.texels {
            for k in 0..4 {
                let v = ca[k] * (1.0 - s) + cb[k] * s;
                pixels.push((v.clamp(0.0, 1.0) * 255.0).round() as u8);
            }
        }
        RgbaImage::new(self.width, self.height, pixels).expect("the buffer matches the size")
    }
}

#[cfg(test)]
#[path = "contour_tests.rs"]
mod tests;
