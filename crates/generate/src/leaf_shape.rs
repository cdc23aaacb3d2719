//! Procedurally drawn leaf textures.
//!
//! Each [`LeafShape`] is drawn into an 8-bit RGBA image with anti-aliased
//! alpha (4×4 supersampling of the blade outline), a midrib and veins, and
//! some colour variation (a base-to-tip gradient, darker margins, smooth
//! value noise). Transparent pixels carry the blade colour, so bilinear
//! filtering and mipmaps do not bleed a dark fringe.
//!
//! # Orientation convention
//! Image rows go top to bottom. The blade **base** (petiole) is at the
//! **bottom** centre of the image and the tip at the top, so texture `v = 0`
//! — the blade base in the tree model's leaf frame — is the *bottom* row,
//! and `v = 1` the top row; `u` runs left to right. An encoder for a format
//! whose `v = 0` is the first (top) row, like glTF, must flip `v`.
//!
//! A leaf billboard's width : height should equal the image's aspect ratio
//! ([`LeafShape::aspect`]) so the blade is not distorted; the generator does
//! that.

use std::sync::OnceLock;

use treemorph_tree::{RgbaImage, Texture};

/// A leaf outline the generator can draw.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LeafShape {
    /// Long, narrow, slightly sickle-shaped blade, grey-green (eucalyptus).
    Lanceolate,
    /// Five pointed, toothed lobes with palmate veins (maple).
    Palmate,
    /// A spray of needles along a twig (conifer billboard).
    Needles,
    /// Very narrow, finely toothed blade, yellow-green (willow).
    Narrow,
    /// Egg-shaped blade, widest below the middle, pointed tip (shrub).
    Ovate,
    /// Nearly circular blade with a notched base (dichotomous tree).
    Round,
}

impl LeafShape {
    /// Every shape.
    pub const ALL: [LeafShape; 6] = [
        LeafShape::Lanceolate,
        LeafShape::Palmate,
        LeafShape::Needles,
        LeafShape::Narrow,
        LeafShape::Ovate,
        LeafShape::Round,
    ];

    /// Lower-case name, also the texture's name in [`leaf_textures`].
    pub fn name(self) -> &'static str {
        match self {
            LeafShape::Lanceolate => "lanceolate",
            LeafShape::Palmate => "palmate",
            LeafShape::Needles => "needles",
            LeafShape::Narrow => "narrow",
            LeafShape::Ovate => "ovate",
            LeafShape::Round => "round",
        }
    }

    /// Image size in pixels, (width, height).
    pub fn pixel_size(self) -> (u32, u32) {
        match self {
            LeafShape::Lanceolate | LeafShape::Needles => (64, 128),
            LeafShape::Narrow => (32, 128),
            LeafShape::Ovate => (96, 128),
            LeafShape::Palmate | LeafShape::Round => (128, 128),
        }
    }

    /// Width divided by height of the image (and of undistorted billboards).
    pub fn aspect(self) -> f32 {
        let (w, h) = self.pixel_size();
        w as f32 / h as f32
    }

    /// Draws the shape (blade base at the bottom row; see the module docs).
    pub fn draw(self) -> RgbaImage {
        draw(self)
    }

    /// The drawn shape as a PNG texture; drawn and encoded once per process
    /// and shape, on first use.
    pub fn texture(self) -> Texture {
        static CACHE: [OnceLock<Texture>; LeafShape::ALL.len()] =
            [const { OnceLock::new() }; LeafShape::ALL.len()];
        CACHE[self as usize]
            .get_or_init(|| Texture::from_rgba(&self.draw()))
            .clone()
    }

    /// Share of the quad the blade's alpha covers (mean alpha, 0..1);
    /// computed once per process and shape.
    pub fn coverage(self) -> f32 {
        static CACHE: [OnceLock<f32>; LeafShape::ALL.len()] =
            [const { OnceLock::new() }; LeafShape::ALL.len()];
        *CACHE[self as usize].get_or_init(|| {
            let image = self.draw();
            let sum: u64 = image.pixels.chunks_exact(4).map(|p| u64::from(p[3])).sum();
            sum as f32 / (255.0 * (image.width * image.height) as f32)
        })
    }
}

/// Every leaf texture the generator draws, by name.
pub fn leaf_textures() -> Vec<(&'static str, Texture)> {
    LeafShape::ALL
        .iter()
        .map(|s| (s.name(), s.texture()))
        .collect()
}

type Rgb = [f32; 3];

/// Supersamples per pixel side on the blade's outline.
const SS: u32 = 4;

/// Side of the square pixel cells the needle segments are binned into.
const CELL: u32 = 8;

/// Draws a shape. Each pixel is first sampled at its centre and corners;
/// only pixels where those disagree (the outline) are supersampled 4×4, so
/// drawing stays cheap while edges get 17 levels of alpha.
fn draw(shape: LeafShape) -> RgbaImage {
    let (w, h) = shape.pixel_size();
    let aspect = w as f32 / h as f32;
    // Leaf coordinates of an image point: y from the base (bottom row) to
    // the tip, x across, both in units of the image height.
    let to_leaf = |fx: f32, fy: f32| ((fx / w as f32 - 0.5) * aspect, 1.0 - fy / h as f32);
    let needles = (shape == LeafShape::Needles).then(|| NeedleBins::new(w, h, to_leaf));
    let sample_at = |fx: f32, fy: f32, colour: bool| {
        let (x, y) = to_leaf(fx, fy);
        match &needles {
            Some(bins) => {
                let cx = ((fx as u32).min(w - 1)) / CELL;
                let cy = ((fy as u32).min(h - 1)) / CELL;
                sample_needles(bins.cell(cx, cy), x, y, colour)
            }
            None => sample(shape, x, y, colour),
        }
    };
    let corners: Vec<bool> = (0..=h)
        .flat_map(|cy| (0..=w).map(move |cx| (cx, cy)))
        .map(|(cx, cy)| sample_at(cx as f32, cy as f32, false).is_some())
        .collect();
    let corner = |cx: u32, cy: u32| corners[(cy * (w + 1) + cx) as usize];
    let mut pixels = Vec::with_capacity((w * h * 4) as usize);
    for py in 0..h {
        for px in 0..w {
            let centre = sample_at(px as f32 + 0.5, py as f32 + 0.5, true);
            let inside = centre.is_some();
            let uniform = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .all(|&(dx, dy)| corner(px + dx, py + dy) == inside);
            let (rgb, alpha) = if uniform {
                match centre {
                    Some(c) => (c, 255),
                    None => (base_color(shape), 0),
                }
            } else {
                let mut hits = 0u32;
                let mut acc = [0f32; 3];
                for sy in 0..SS {
                    for sx in 0..SS {
                        let fx = px as f32 + (sx as f32 + 0.5) / SS as f32;
                        let fy = py as f32 + (sy as f32 + 0.5) / SS as f32;
                        if let Some(c) = sample_at(fx, fy, true) {
                            hits += 1;
                            for k in 0..3 {
                                acc[k] += c[k];
                            }
                        }
                    }
                }
                let rgb = if hits > 0 {
                    acc.map(|v| v / hits as f32)
                } else {
                    base_color(shape)
                };
                (rgb, ((hits * 255 + SS * SS / 2) / (SS * SS)) as u8)
            };
            for v in rgb {
                pixels.push((v.clamp(0.0, 1.0) * 255.0).round() as u8);
            }
            pixels.push(alpha);
        }
    }
    RgbaImage::new(w, h, pixels).expect("the buffer matches the size")
}

/// Needle segments binned into `CELL`-pixel cells by bounding box, so each
/// sample tests only the few needles near it.
struct NeedleBins {
    cols: u32,
    cells: Vec<Vec<Segment>>,
}

impl NeedleBins {
    fn new(w: u32, h: u32, to_leaf: impl Fn(f32, f32) -> (f32, f32)) -> NeedleBins {
        let segs = needle_segments();
        let cols = w.div_ceil(CELL);
        let rows = h.div_ceil(CELL);
        let mut cells = vec![Vec::new(); (cols * rows) as usize];
        for cy in 0..rows {
            for cx in 0..cols {
                // The cell's rectangle in leaf coordinates (y flips).
                let (x0, y1) = to_leaf((cx * CELL) as f32, (cy * CELL) as f32);
                let (x1, y0) = to_leaf(((cx + 1) * CELL) as f32, ((cy + 1) * CELL) as f32);
                let cell = &mut cells[(cy * cols + cx) as usize];
                for s in &segs {
                    let m = s.w0.max(s.w1);
                    let (sx0, sx1) = (s.a[0].min(s.b[0]) - m, s.a[0].max(s.b[0]) + m);
                    let (sy0, sy1) = (s.a[1].min(s.b[1]) - m, s.a[1].max(s.b[1]) + m);
                    if sx1 >= x0 && sx0 <= x1 && sy1 >= y0 && sy0 <= y1 {
                        cell.push(*s);
                    }
                }
            }
        }
        NeedleBins { cols, cells }
    }

    fn cell(&self, cx: u32, cy: u32) -> &[Segment] {
        &self.cells[(cy * self.cols + cx) as usize]
    }
}

/// The blade colour used for transparent pixels.
fn base_color(shape: LeafShape) -> Rgb {
    match shape {
        LeafShape::Lanceolate => [0.40, 0.53, 0.46],
        LeafShape::Palmate => [0.30, 0.52, 0.17],
        LeafShape::Needles => [0.14, 0.32, 0.16],
        LeafShape::Narrow => [0.50, 0.64, 0.28],
        LeafShape::Ovate => [0.27, 0.48, 0.18],
        LeafShape::Round => [0.36, 0.58, 0.22],
    }
}

fn mix(a: Rgb, b: Rgb, t: f32) -> Rgb {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

fn scale(c: Rgb, s: f32) -> Rgb {
    c.map(|v| v * s)
}

fn hash(x: i32, y: i32, seed: u32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x8da6_b343)
        ^ (y as u32).wrapping_mul(0xd816_3841)
        ^ seed.wrapping_mul(0xcb1a_b31f);
    h ^= h >> 13;
    h = h.wrapping_mul(0x5bd1_e995);
    h ^= h >> 15;
    (h & 0xffff) as f32 / 65535.0
}

/// Smooth value noise in [0, 1].
fn noise(x: f32, y: f32, seed: u32) -> f32 {
    let (xi, yi) = (x.floor(), y.floor());
    let (fx, fy) = (x - xi, y - yi);
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let (xi, yi) = (xi as i32, yi as i32);
    let a = hash(xi, yi, seed);
    let b = hash(xi + 1, yi, seed);
    let c = hash(xi, yi + 1, seed);
    let d = hash(xi + 1, yi + 1, seed);
    let top = a + (b - a) * sx;
    let bottom = c + (d - c) * sx;
    top + (bottom - top) * sy
}

/// Mottling factor around 1.
fn mottle(x: f32, y: f32, seed: u32) -> f32 {
    0.9 + 0.12 * noise(x * 18.0, y * 18.0, seed) + 0.08 * noise(x * 55.0, y * 55.0, seed + 1)
}

const PETIOLE: Rgb = [0.48, 0.50, 0.28];

/// A pinnate blade defined by a centre line `xc(t)` and half-width `hw(t)`
/// over `t` ∈ [0, 1] from `y0` to `y1`, with a petiole below `y0`.
struct Pinnate {
    y0: f32,
    y1: f32,
    petiole: f32,
    base: Rgb,
    tip: Rgb,
    vein: Rgb,
    /// Secondary veins per unit `t` and their slope toward the tip.
    veins: f32,
    slope: f32,
    seed: u32,
}

impl Pinnate {
    fn sample(
        &self,
        x: f32,
        y: f32,
        xc: impl Fn(f32) -> f32,
        hw: impl Fn(f32) -> f32,
        colour: bool,
    ) -> Option<Rgb> {
        if y < self.y0 + 0.01 && y >= 0.0 && (x - xc(0.0)).abs() < self.petiole {
            return Some(PETIOLE);
        }
        let t = (y - self.y0) / (self.y1 - self.y0);
        if !(0.0..=1.0).contains(&t) {
            return None;
        }
        let half = hw(t);
        let dx = x - xc(t);
        if dx.abs() > half || half <= 0.0 {
            return None;
        }
        if !colour {
            return Some(PETIOLE);
        }
        let e = dx.abs() / half;
        let mut c = mix(self.base, self.tip, t);
        c = scale(c, (1.0 - 0.16 * e * e) * mottle(x, y, self.seed));
        if dx.abs() < 0.0045 + 0.004 * (1.0 - t) {
            return Some(mix(c, self.vein, 0.7));
        }
        let phase = (t - dx.abs() * self.slope / (self.y1 - self.y0)) * self.veins;
        let f = phase - phase.floor();
        if e < 0.9 && f < 0.09 {
            return Some(mix(c, self.vein, 0.35));
        }
        Some(c)
    }
}

/// The colour of the blade at leaf point (x, y), `None` outside it. Without
/// `colour` only inside/outside is decided (the colour returned is
/// meaningless).
fn sample(shape: LeafShape, x: f32, y: f32, colour: bool) -> Option<Rgb> {
    use std::f32::consts::PI;
    match shape {
        LeafShape::Lanceolate => Pinnate {
            y0: 0.07,
            y1: 0.99,
            petiole: 0.009,
            base: [0.48, 0.60, 0.52],
            tip: [0.34, 0.46, 0.40],
            vein: [0.72, 0.74, 0.56],
            veins: 22.0,
            slope: 0.5,
            seed: 11,
        }
        .sample(
            x,
            y,
            |t| 0.035 * (PI * t).sin(),
            |t| 0.095 * (PI * t.powf(0.55)).sin().max(0.0).powf(0.85),
            colour,
        ),
        LeafShape::Narrow => Pinnate {
            y0: 0.05,
            y1: 0.99,
            petiole: 0.007,
            base: [0.58, 0.70, 0.32],
            tip: [0.44, 0.60, 0.25],
            vein: [0.78, 0.82, 0.55],
            veins: 30.0,
            slope: 0.4,
            seed: 23,
        }
        .sample(
            x,
            y,
            |_| 0.0,
            |t| {
                let teeth = 1.0 - 0.06 * ((t * 70.0).fract() - 0.5).abs();
                0.052 * (PI * t.powf(0.7)).sin().max(0.0).powf(0.7) * teeth
            },
            colour,
        ),
        LeafShape::Ovate => Pinnate {
            y0: 0.07,
            y1: 0.98,
            petiole: 0.012,
            base: [0.32, 0.54, 0.22],
            tip: [0.24, 0.44, 0.16],
            vein: [0.55, 0.70, 0.36],
            veins: 8.0,
            slope: 0.9,
            seed: 37,
        }
        .sample(
            x,
            y,
            |_| 0.0,
            |t| 0.3 * (PI * t.powf(0.8)).sin().max(0.0).powf(0.65),
            colour,
        ),
        LeafShape::Round => round(x, y, colour),
        LeafShape::Palmate => palmate(x, y, colour),
        LeafShape::Needles => None,
    }
}

fn round(x: f32, y: f32, colour: bool) -> Option<Rgb> {
    let (cx, cy, r0) = (0.0, 0.53, 0.42);
    let (dx, dy) = (x - cx, y - cy);
    let r = (dx * dx + dy * dy).sqrt();
    // Angle from the tip direction (+y): 0 at the tip, ±π at the base.
    let theta = dx.atan2(dy);
    let base_gap = (theta.abs() - std::f32::consts::PI).powi(2);
    let notch = 0.22 * (-base_gap / 0.03).exp();
    let tip = 0.05 * (-theta * theta / 0.01).exp();
    let rmax = r0 * (1.0 - notch) + tip;
    if r > rmax {
        let petiole_top = cy - r0 * 0.78;
        if (0.0..petiole_top).contains(&y) && x.abs() < 0.012 {
            return Some(PETIOLE);
        }
        return None;
    }
    if !colour {
        return Some(PETIOLE);
    }
    let e = r / rmax;
    let mut c = mix(
        [0.42, 0.64, 0.26],
        [0.32, 0.54, 0.20],
        (y - 0.1).clamp(0.0, 1.0),
    );
    c = scale(c, (1.0 - 0.15 * e * e) * mottle(x, y, 51));
    let vein = [0.62, 0.76, 0.42];
    // Veins radiate from the blade's base point.
    let (bx, by) = (x, y - (cy - r0 * 0.8));
    let ang = bx.atan2(by);
    let spokes = (ang / 0.42).round() * 0.42;
    let d_spoke = (ang - spokes).abs() * (bx * bx + by * by).sqrt();
    if (x.abs() < 0.005 && y > cy - r0) || (d_spoke < 0.004 && e < 0.92 && by > 0.0) {
        return Some(mix(c, vein, 0.5));
    }
    Some(c)
}

fn palmate(x: f32, y: f32, colour: bool) -> Option<Rgb> {
    let (cx, cy) = (0.0, 0.40);
    let (dx, dy) = (x - cx, y - cy);
    let r = (dx * dx + dy * dy).sqrt();
    let theta = dx.atan2(dy);
    // Lobes: (direction from +y, length).
    const LOBES: [(f32, f32); 5] = [
        (0.0, 0.56),
        (0.95, 0.48),
        (-0.95, 0.48),
        (1.85, 0.31),
        (-1.85, 0.31),
    ];
    let mut rmax: f32 = 0.16;
    for (dir, len) in LOBES {
        let mut delta = (theta - dir).abs();
        if delta > std::f32::consts::PI {
            delta = std::f32::consts::TAU - delta;
        }
        let f = (1.0 - delta / 0.62).max(0.0).powf(0.75);
        rmax = rmax.max(len * f);
    }
    let teeth = 1.0 - 0.06 * ((theta * 9.0).fract().abs() - 0.5).abs() * 2.0;
    let rmax = rmax * teeth;
    if r > rmax {
        if (0.0..cy).contains(&y) && x.abs() < 0.011 {
            return Some(PETIOLE);
        }
        return None;
    }
    if !colour {
        return Some(PETIOLE);
    }
    let e = r / rmax;
    let mut c = mix([0.36, 0.58, 0.20], [0.26, 0.48, 0.14], (r / 0.5).min(1.0));
    c = scale(c, (1.0 - 0.18 * e * e) * mottle(x, y, 67));
    let vein = [0.60, 0.74, 0.34];
    for (dir, len) in LOBES {
        let mut delta = (theta - dir).abs();
        if delta > std::f32::consts::PI {
            delta = std::f32::consts::TAU - delta;
        }
        if delta * r < 0.0055 && r < len * 0.92 {
            return Some(mix(c, vein, 0.6));
        }
    }
    Some(c)
}

/// A needle or the twig: a capsule from `a` to `b` with half-thickness
/// tapering from `w0` to `w1`, and its colour.
#[derive(Clone, Copy)]
struct Segment {
    a: [f32; 2],
    b: [f32; 2],
    w0: f32,
    w1: f32,
    color: Rgb,
}

fn needle_segments() -> Vec<Segment> {
    let mut segs = vec![Segment {
        a: [0.0, 0.0],
        b: [0.008, 0.97],
        w0: 0.009,
        w1: 0.005,
        color: [0.36, 0.30, 0.17],
    }];
    // A small fixed-seed generator: the texture is the same everywhere.
    let mut state = 0x2545_f491u32;
    let mut rnd = || {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        (state & 0xffff) as f32 / 65535.0
    };
    // Dense, fairly thick needles: the spray must keep most of its alpha
    // when a viewer samples a small mipmap level, or alpha-tested needles
    // vanish as soon as the tree is a few hundred pixels tall.
    let count = 40;
    for i in 0..count {
        let y = 0.04 + 0.92 * i as f32 / count as f32;
        for side in [-1.0f32, 1.0] {
            for layer in 0..2 {
                let spread = if layer == 0 { 52.0 } else { 32.0 };
                let angle = (spread + 12.0 * (rnd() - 0.5)).to_radians();
                let len = 0.22 * (1.0 - 0.4 * y) * (0.85 + 0.3 * rnd());
                let ax = 0.008 * y;
                let ay = y + 0.01 * (rnd() - 0.5);
                let shade = 0.8 + 0.35 * rnd();
                segs.push(Segment {
                    a: [ax, ay],
                    b: [ax + side * len * angle.sin(), ay + len * angle.cos()],
                    w0: 0.02,
                    w1: 0.011,
                    color: scale([0.15, 0.34, 0.17], shade),
                });
            }
        }
    }
    segs
}

fn sample_needles(segs: &[Segment], x: f32, y: f32, colour: bool) -> Option<Rgb> {
    // Later needles are drawn over earlier ones, the twig under everything.
    for s in segs.iter().rev() {
        let (ax, ay) = (s.a[0], s.a[1]);
        let (bx, by) = (s.b[0] - ax, s.b[1] - ay);
        let (px, py) = (x - ax, y - ay);
        let len2 = bx * bx + by * by;
        let h = ((px * bx + py * by) / len2).clamp(0.0, 1.0);
        let (dx, dy) = (px - bx * h, py - by * h);
        let w = s.w0 + (s.w1 - s.w0) * h;
        if dx * dx + dy * dy <= w * w {
            if !colour {
                return Some(s.color);
            }
            // A paler stripe along the needle.
            let centre = 1.0 - (dx * dx + dy * dy).sqrt() / w;
            return Some(scale(s.color, 0.9 + 0.25 * centre));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alpha(img: &RgbaImage, x: u32, y: u32) -> u8 {
        img.pixel(x, y)[3]
    }

    #[test]
    fn every_shape_has_a_blade_with_soft_edges() {
        for shape in LeafShape::ALL {
            let img = shape.draw();
            let (w, h) = shape.pixel_size();
            assert_eq!((img.width, img.height), (w, h));
            let alphas: Vec<u8> = img.pixels.chunks_exact(4).map(|p| p[3]).collect();
            let opaque = alphas.iter().filter(|&&a| a == 255).count();
            let clear = alphas.iter().filter(|&&a| a == 0).count();
            let partial = alphas.len() - opaque - clear;
            let n = alphas.len();
            assert!(opaque > n / 20, "{shape:?}: {opaque} opaque of {n}");
            assert!(clear > n / 5, "{shape:?}: {clear} clear of {n}");
            assert!(partial > 0, "{shape:?}: no anti-aliased edge pixels");
            // Corners are outside every blade.
            for (x, y) in [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)] {
                assert_eq!(alpha(&img, x, y), 0, "{shape:?} corner ({x},{y})");
            }
        }
    }

    #[test]
    fn the_blade_base_is_at_the_bottom_row() {
        for shape in LeafShape::ALL {
            let img = shape.draw();
            let (w, h) = shape.pixel_size();
            // The petiole (or needle twig) reaches the bottom-centre pixel,
            // and the top row's centre is transparent or thin: the blade
            // narrows to its tip at the top.
            let bottom = (w / 2 - 2..w / 2 + 2)
                .map(|x| alpha(&img, x, h - 1))
                .max()
                .unwrap();
            assert!(bottom > 0, "{shape:?}: nothing at the bottom centre");
            let bottom_row: usize = (0..w).filter(|&x| alpha(&img, x, h - 1) > 0).count();
            assert!(bottom_row < w as usize / 4, "{shape:?}: base row is wide");
        }
    }

    #[test]
    fn blades_have_veins_and_colour_variation() {
        for shape in LeafShape::ALL {
            let img = shape.draw();
            let greens: Vec<u8> = img
                .pixels
                .chunks_exact(4)
                .filter(|p| p[3] == 255)
                .map(|p| p[1])
                .collect();
            let min = *greens.iter().min().unwrap();
            let max = *greens.iter().max().unwrap();
            assert!(max - min > 25, "{shape:?}: green spans only {min}..{max}");
            // Leaves are green: G dominates R and B on average.
            let (mut r, mut g, mut b) = (0u64, 0u64, 0u64);
            for p in img.pixels.chunks_exact(4).filter(|p| p[3] == 255) {
                r += u64::from(p[0]);
                g += u64::from(p[1]);
                b += u64::from(p[2]);
            }
            assert!(g > r && g > b, "{shape:?}: not green ({r}, {g}, {b})");
        }
    }

    #[test]
    fn textures_decode_to_the_drawn_image() {
        let all = leaf_textures();
        assert_eq!(all.len(), LeafShape::ALL.len());
        for ((name, texture), shape) in all.iter().zip(LeafShape::ALL) {
            assert_eq!(*name, shape.name());
            assert_eq!(texture.decode().unwrap(), shape.draw());
        }
    }
}
