use glam::Vec2;
use treemorph_generate::LeafShape as Drawn;
use treemorph_tree::RgbaImage;

use super::*;

const K: u32 = 24;

/// An image whose alpha is 255 where `inside(x, y)` holds for the pixel
/// centre in blade coordinates, else 0.
fn image(w: u32, h: u32, inside: impl Fn(f32, f32) -> bool) -> RgbaImage {
    let mut pixels = Vec::new();
    for row in 0..h {
        for col in 0..w {
            let x = (col as f32 + 0.5) / w as f32 - 0.5;
            let y = 1.0 - (row as f32 + 0.5) / h as f32;
            pixels.extend_from_slice(&[40, 160, 40, if inside(x, y) { 255 } else { 0 }]);
        }
    }
    RgbaImage::new(w, h, pixels).unwrap()
}

/// Signed areas of the fan triangles (centre, rim k, rim k+1).
fn fan_areas(centre: Vec2, rim: &[Vec2]) -> Vec<f32> {
    (0..rim.len())
        .map(|k| {
            let (a, b) = (rim[k] - centre, rim[(k + 1) % rim.len()] - centre);
            0.5 * a.perp_dot(b)
        })
        .collect()
}

fn lerp(a: &LeafContour, b: &LeafContour, s: f32) -> (Vec2, Vec<Vec2>) {
    let mut fan = vec![Vec2::ZERO; a.len() + 1];
    a.lerp_fan(b, s, &mut fan);
    (fan[0], fan[1..].to_vec())
}

fn drawn_contours() -> Vec<(Drawn, LeafContour)> {
    Drawn::ALL
        .iter()
        .map(|&shape| (shape, LeafContour::from_image(&shape.draw(), K).unwrap()))
        .collect()
}

#[test]
fn the_rectangle_starts_at_the_base_and_runs_counter_clockwise() {
    let c = LeafContour::rectangle(8).unwrap();
    assert_eq!(c.len(), 8);
    assert!(c.centre().abs_diff_eq(Vec2::new(0.0, 0.5), 1e-5));
    assert!(
        c.rim()[0].abs_diff_eq(Vec2::new(0.0, 0.0), 1e-5),
        "{:?}",
        c.rim()
    );
    assert!(
        c.rim()[4].abs_diff_eq(Vec2::new(0.0, 1.0), 1e-5),
        "{:?}",
        c.rim()
    );
    // Counter-clockwise: the right side (+x) comes first.
    assert!(c.rim()[2].x > 0.49 && c.rim()[6].x < -0.49, "{:?}", c.rim());
    assert!(fan_areas(c.centre(), c.rim()).iter().all(|&a| a > 0.0));
    // The perimeter is 4 (in units of a unit square's side): 8 points
    // half a side apart.
    for k in 0..8 {
        let d = c.rim()[k].distance(c.rim()[(k + 1) % 8]);
        assert!(d <= 0.5 + 1e-4, "{k}: {d}");
    }
}

#[test]
fn a_disc_gives_a_circle_from_its_lowest_point() {
    let r = 0.4;
    let img = image(64, 64, |x, y| x * x + (y - 0.5) * (y - 0.5) < r * r);
    let c = LeafContour::from_image(&img, 32).unwrap();
    assert!(
        c.centre().abs_diff_eq(Vec2::new(0.0, 0.5), 0.02),
        "{:?}",
        c.centre()
    );
    for p in c.rim() {
        let d = p.distance(Vec2::new(0.0, 0.5));
        assert!((d - r).abs() < 0.02, "{p:?} at {d}");
    }
    assert!(
        c.rim()[0].abs_diff_eq(Vec2::new(0.0, 0.1), 0.02),
        "{:?}",
        c.rim()[0]
    );
    assert!(
        c.rim()[16].abs_diff_eq(Vec2::new(0.0, 0.9), 0.02),
        "{:?}",
        c.rim()[16]
    );
    // Evenly spaced by arc length.
    let step = std::f32::consts::TAU * r / 32.0;
    for k in 0..32 {
        let d = c.rim()[k].distance(c.rim()[(k + 1) % 32]);
        assert!((d - step).abs() < 0.15 * step, "{k}: {d} vs {step}");
    }
}

#[test]
fn an_opaque_image_is_its_rectangle() {
    let img = image(16, 32, |_, _| true);
    let c = LeafContour::from_image(&img, 8).unwrap();
    let on_border =
        |p: Vec2| (p.x.abs() - 0.5).abs() < 0.02 || p.y.abs() < 0.02 || (p.y - 1.0).abs() < 0.02;
    assert!(c.rim().iter().all(|&p| on_border(p)), "{:?}", c.rim());
    assert!(c.rim()[0].abs_diff_eq(Vec2::new(0.0, 0.0), 1e-4));
    assert!(c.rim()[4].abs_diff_eq(Vec2::new(0.0, 1.0), 1e-4));
    // Arc length is measured in pixels: the half perimeter is 8 + 32 + 8
    // pixels, so the first point after the base is 12 pixels along it
    // (give or take the half-pixel corners marching squares cuts).
    assert!(
        c.rim()[1].abs_diff_eq(Vec2::new(0.5, 4.0 / 32.0), 0.01),
        "{:?}",
        c.rim()[1]
    );
}

#[test]
fn islands_and_holes_are_ignored() {
    // A blade with a hole, and a speck far from it.
    let img = image(64, 64, |x, y| {
        let blade = x * x + (y - 0.4) * (y - 0.4) < 0.09 && x * x + (y - 0.4) * (y - 0.4) > 0.01;
        let speck = (x - 0.4).abs() < 0.05 && (y - 0.9).abs() < 0.05;
        blade || speck
    });
    let c = LeafContour::from_image(&img, 16).unwrap();
    for p in c.rim() {
        let d = p.distance(Vec2::new(0.0, 0.4));
        assert!((d - 0.3).abs() < 0.03, "{p:?} at {d}");
    }
}

#[test]
fn refuses_bad_point_counts_and_blank_images() {
    assert_eq!(
        LeafContour::rectangle(7),
        Err(ContourError::InvalidPoints(7))
    );
    assert_eq!(
        LeafContour::rectangle(2),
        Err(ContourError::InvalidPoints(2))
    );
    assert_eq!(
        LeafContour::rectangle(MAX_POINTS + 2),
        Err(ContourError::InvalidPoints(MAX_POINTS + 2))
    );
    let blank = image(8, 8, |_, _| false);
    assert_eq!(
        LeafContour::from_image(&blank, 8),
        Err(ContourError::NoBlade)
    );
    // A material whose texture has no blade falls back to the rectangle.
    let material = treemorph_tree::LeafMaterial {
        name: "blank".into(),
        color: [1.0; 4],
        texture: Some(treemorph_tree::Texture::from_rgba(&blank)),
    };
    assert_eq!(
        LeafContour::of_material(&material, 8),
        LeafContour::rectangle(8)
    );
}

#[test]
fn generator_shapes_are_star_shaped_from_base_to_tip() {
    for (shape, c) in drawn_contours() {
        assert_eq!(c.len(), K as usize);
        let areas = fan_areas(c.centre(), c.rim());
        assert!(areas.iter().all(|&a| a > 0.0), "{shape:?}: {areas:?}");
        let (lo, hi) = c.rim().iter().fold((f32::MAX, f32::MIN), |(lo, hi), p| {
            (lo.min(p.y), hi.max(p.y))
        });
        let base = c.rim()[0];
        let tip = c.rim()[K as usize / 2];
        assert_eq!(base.y, lo, "{shape:?}: the base is the lowest point");
        assert_eq!(tip.y, hi, "{shape:?}: the tip is the highest point");
        // Upright images: the petiole ends at the bottom centre.
        assert!(
            base.y < 0.01 && base.x.abs() < 0.03,
            "{shape:?}: base {base:?}"
        );
        assert!(hi > 0.9, "{shape:?}: tip {tip:?}");
    }
}

/// Share of the image's alpha that lies inside the contour polygon.
fn alpha_inside(img: &RgbaImage, c: &LeafContour) -> f32 {
    let inside = |p: Vec2| {
        // Star-shaped about the centre: inside the sector's triangle.
        let rim = c.rim();
        (0..rim.len()).any(|k| {
            let (a, b) = (rim[k], rim[(k + 1) % rim.len()]);
            let o = c.centre();
            let s1 = (a - o).perp_dot(p - o);
            let s2 = (b - a).perp_dot(p - a);
            let s3 = (o - b).perp_dot(p - b);
            s1 >= 0.0 && s2 >= 0.0 && s3 >= 0.0
        })
    };
    let (mut total, mut within) = (0f64, 0f64);
    for row in 0..img.height {
        for col in 0..img.width {
            let a = f64::from(img.pixel(col, row)[3]);
            let p = Vec2::new(
                (col as f32 + 0.5) / img.width as f32 - 0.5,
                1.0 - (row as f32 + 0.5) / img.height as f32,
            );
            total += a;
            if inside(p) {
                within += a;
            }
        }
    }
    (within / total) as f32
}

#[test]
fn contours_hold_most_of_the_blade() {
    for (shape, c) in drawn_contours() {
        let share = alpha_inside(&shape.draw(), &c);
        // 24 points cut the tips of needles and maple teeth a little.
        assert!(share > 0.88, "{shape:?}: {share}");
    }
}

#[test]
fn interpolating_any_two_generator_shapes_never_folds_the_fan() {
    let images: Vec<(Drawn, RgbaImage)> = Drawn::ALL.iter().map(|&s| (s, s.draw())).collect();
    for k in [8, 12, K, 48] {
        let contours: Vec<(Drawn, LeafContour)> = images
            .iter()
            .map(|(s, img)| (*s, LeafContour::from_image(img, k).unwrap()))
            .collect();
        for (sa, a) in &contours {
            for (sb, b) in &contours {
                for s in [0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0] {
                    let (centre, rim) = lerp(a, b, s);
                    let areas = fan_areas(centre, &rim);
                    let worst = areas.iter().copied().fold(f32::MAX, f32::min);
                    assert!(
                        worst > 0.0,
                        "{k} points, {sa:?} → {sb:?} at {s}: smallest fan area {worst}"
                    );
                    let (lo, hi) = rim.iter().fold((f32::MAX, f32::MIN), |(lo, hi), p| {
                        (lo.min(p.y), hi.max(p.y))
                    });
                    assert!(rim[0].y <= lo + 1e-6 && rim[k as usize / 2].y >= hi - 1e-6);
                }
            }
        }
    }
}

#[test]
fn fan_maps_carry_rims_onto_rims() {
    let contours = drawn_contours();
    let (a, b) = (&contours[1].1, &contours[4].1);
    let map = FanMap::new(a, b);
    assert!(map.map(a.centre()).abs_diff_eq(b.centre(), 1e-4));
    for (p, q) in a.rim().iter().zip(b.rim()) {
        assert!(
            map.map(*p).abs_diff_eq(*q, 1e-3),
            "{p:?} → {:?} vs {q:?}",
            map.map(*p)
        );
        // Halfway between the centre and the rim maps halfway too.
        let mid = a.centre().lerp(*p, 0.5);
        assert!(map.map(mid).abs_diff_eq(b.centre().lerp(*q, 0.5), 1e-3));
    }
}

#[test]
fn blends_are_texel_wise_and_keep_the_first_texture_at_zero() {
    let a_img = Drawn::Ovate.draw();
    let b_img = Drawn::Round.draw();
    let a_c = LeafContour::from_image(&a_img, K).unwrap();
    let b_c = LeafContour::from_image(&b_img, K).unwrap();
    let a = BlendSource {
        image: Some(&a_img),
        contour: &a_c,
        color: [1.0; 4],
    };
    let b = BlendSource {
        image: Some(&b_img),
        contour: &b_c,
        color: [0.5, 1.0, 1.0, 1.0],
    };
    // Round is 128 wide, ovate 96: the blend takes the larger size.
    let zero = blend_textures(a, b, 0.0);
    assert_eq!((zero.width, zero.height), (128, 128));
    // At blend 0 the result is the first texture resampled: same coverage.
    let coverage = |img: &RgbaImage| {
        img.pixels
            .chunks_exact(4)
            .map(|p| f64::from(p[3]))
            .sum::<f64>()
            / (255.0 * f64::from(img.width * img.height))
    };
    assert!((coverage(&zero) - coverage(&a_img)).abs() < 0.01);
    // At blend 1 the second texture is warped onto the first's outline:
    // the alpha mass follows the first contour's area, not the second's.
    let one = blend_textures(a, b, 1.0);
    assert!(
        (coverage(&one) - coverage(&a_img)).abs() < 0.06,
        "{} vs {}",
        coverage(&one),
        coverage(&a_img)
    );
    // The colour factor is baked in: red is halved at blend 1.
    let red = |img: &RgbaImage| {
        img.pixels
            .chunks_exact(4)
            .filter(|p| p[3] == 255)
            .map(|p| f64::from(p[0]))
            .sum::<f64>()
            / img.pixels.chunks_exact(4).filter(|p| p[3] == 255).count() as f64
    };
    let b_red = red(&b_img);
    assert!(
        (red(&one) - 0.5 * b_red).abs() < 0.1 * b_red,
        "{} vs {}",
        red(&one),
        b_red
    );
    // Halfway, every texel is the mean of the two ends.
    let half = blend_textures(a, b, 0.5);
    for ((h, z), o) in half.pixels.iter().zip(&zero.pixels).zip(&one.pixels) {
        let mean = (f32::from(*z) + f32::from(*o)) * 0.5;
        assert!((f32::from(*h) - mean).abs() <= 1.0, "{h} vs {z}, {o}");
    }
}

/// Writes every generator contour to an SVG for eyeballing:
/// `cargo test -p treemorph-gltf --lib -- --ignored contour_svg`.
#[test]
#[ignore = "writes a picture to the target directory"]
fn contour_svg() {
    let mut svg = String::from(
        "<svg xmlns='http://www.w3.org/2000/svg' viewBox='-0.1 -1.1 7.2 1.2' width='1440' height='240'>",
    );
    for (i, (_, c)) in drawn_contours().iter().enumerate() {
        let dx = i as f32 * 1.2 + 0.6;
        let points: Vec<String> = c
            .rim()
            .iter()
            .map(|p| format!("{},{}", p.x + dx, -p.y))
            .collect();
        svg += &format!(
            "<polygon points='{}' fill='#8c8' stroke='#060' stroke-width='0.005'/>",
            points.join(" ")
        );
        svg += &format!(
            "<circle cx='{}' cy='{}' r='0.015' fill='red'/><circle cx='{}' cy='{}' r='0.015' fill='blue'/>",
            c.centre().x + dx,
            -c.centre().y,
            c.rim()[0].x + dx,
            -c.rim()[0].y
        );
    }
    svg += "</svg>";
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/contours.svg");
    std::fs::write(&path, svg).unwrap();
    println!("{}", path.display());
}
