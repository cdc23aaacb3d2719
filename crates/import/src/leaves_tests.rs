use glam::{Quat, Vec2, Vec3};

use super::*;
use crate::read::{AlphaMode, EncodedImage, MaterialInfo};

/// A quad as the exporter writes it: base corners at v = 1, tip at v = 0.
fn quad(anchor: Vec3, q: Quat, w: f32, h: f32, uv: [f32; 4]) -> (Vec<Vec3>, Vec<Vec2>) {
    let half = q * Vec3::X * (0.5 * w);
    let up = q * Vec3::Y * h;
    let [u0, v0, u1, v1] = uv;
    (
        vec![
            anchor - half,
            anchor + half,
            anchor + half + up,
            anchor - half + up,
        ],
        vec![
            Vec2::new(u0, v1),
            Vec2::new(u1, v1),
            Vec2::new(u1, v0),
            Vec2::new(u0, v0),
        ],
    )
}

fn primitive(quads: &[(Vec<Vec3>, Vec<Vec2>)], uvs: bool) -> Primitive {
    let mut p = Primitive {
        material: Some(0),
        ..Primitive::default()
    };
    let mut all_uvs = Vec::new();
    for (pos, uv) in quads {
        let b = p.positions.len() as u32;
        p.positions.extend_from_slice(pos);
        all_uvs.extend_from_slice(uv);
        p.triangles.push([b, b + 1, b + 2]);
        p.triangles.push([b, b + 2, b + 3]);
    }
    p.uvs = uvs.then_some(all_uvs);
    p
}

fn doc_with_texture(p: Primitive) -> Document {
    let pixels: Vec<u8> = (0..8 * 4 * 4).map(|i| (i * 13 % 251) as u8).collect();
    let image = RgbaImage::new(8, 4, pixels).unwrap();
    Document {
        primitives: vec![p],
        materials: vec![MaterialInfo {
            name: "leafy".into(),
            alpha: AlphaMode::Mask,
            color: [0.5, 1.0, 0.5, 1.0],
            image: Some(0),
        }],
        images: vec![Some(EncodedImage {
            bytes: Texture::from_rgba(&image).png().to_vec(),
            mime: Some("image/png".into()),
        })],
        warnings: Vec::new(),
    }
}

fn extract_all(doc: &Document) -> Leaves {
    let prims: Vec<&Primitive> = doc.primitives.iter().collect();
    extract(
        doc,
        &prims,
        &ImportOptions::default(),
        &mut ImageCache::default(),
        &mut Vec::new(),
    )
}

#[test]
fn uv_frames_give_back_the_billboard() {
    let q = Quat::from_rotation_x(0.7) * Quat::from_rotation_y(1.9);
    let anchor = Vec3::new(1.0, 2.0, 3.0);
    let doc = doc_with_texture(primitive(
        &[quad(anchor, q, 0.2, 0.5, [0.0, 0.0, 1.0, 1.0])],
        true,
    ));
    let leaves = extract_all(&doc);
    assert_eq!(leaves.leaves.len(), 1);
    let l = leaves.leaves[0];
    assert!(l.anchor.distance(anchor) < 1e-5);
    assert!((l.width - 0.2).abs() < 1e-5 && (l.height - 0.5).abs() < 1e-5);
    assert!(l.orientation.angle_between(q) < 1e-3);
    assert!(!l.base_unknown);
    assert_eq!(leaves.materials.len(), 1);
    assert_eq!(leaves.materials[0].name, "leafy");
    assert_eq!(leaves.materials[0].color, [0.5, 1.0, 0.5, 1.0]);
    assert_eq!(leaves.materials[0].texture.as_ref().unwrap().width(), 8);
}

#[test]
fn crossed_and_double_sided_quads_count_once() {
    let a = Vec3::new(0.0, 1.0, 0.0);
    let q = Quat::from_rotation_z(0.3);
    let full = [0.0, 0.0, 1.0, 1.0];
    let crossed = [
        quad(a, q, 0.2, 0.4, full),
        quad(
            a,
            q * Quat::from_rotation_y(std::f32::consts::FRAC_PI_2),
            0.2,
            0.4,
            full,
        ),
        quad(a, q, 0.2, 0.4, full),
        // A different leaf next to it: same size, centre 5 % away.
        quad(a + Vec3::X * 0.02, q, 0.2, 0.4, full),
    ];
    let doc = doc_with_texture(primitive(&crossed, true));
    assert_eq!(extract_all(&doc).leaves.len(), 2);
}

#[test]
fn atlas_regions_get_cropped_materials() {
    let left = quad(Vec3::ZERO, Quat::IDENTITY, 0.1, 0.2, [0.0, 0.0, 0.5, 1.0]);
    let right = quad(Vec3::X, Quat::IDENTITY, 0.1, 0.2, [0.5, 0.0, 1.0, 1.0]);
    let again = quad(Vec3::Z, Quat::IDENTITY, 0.1, 0.2, [0.0, 0.0, 0.5, 1.0]);
    let doc = doc_with_texture(primitive(&[left, right, again], true));
    let leaves = extract_all(&doc);
    assert_eq!(leaves.materials.len(), 2);
    assert_eq!(leaves.leaves[0].material, leaves.leaves[2].material);
    let t = leaves.materials[0].texture.as_ref().unwrap();
    assert_eq!((t.width(), t.height()), (4, 4));
    // The blade is the region: width and height are the quad's.
    assert!((leaves.leaves[0].width - 0.1).abs() < 1e-5);
}

#[test]
fn leaves_without_uvs_use_their_shape_and_zero_area_is_skipped() {
    let q = Quat::from_rotation_z(0.2);
    let good = quad(Vec3::ZERO, q, 0.1, 0.4, [0.0; 4]);
    let flat = (
        vec![Vec3::X, Vec3::X * 2.0, Vec3::X * 3.0, Vec3::X * 4.0],
        vec![Vec2::ZERO; 4],
    );
    let doc = doc_with_texture(primitive(&[good, flat], false));
    let leaves = extract_all(&doc);
    assert_eq!(leaves.skipped, 1);
    assert_eq!(leaves.leaves.len(), 1);
    let l = leaves.leaves[0];
    assert!(l.base_unknown);
    assert!((l.height - 0.4).abs() < 1e-4 && (l.width - 0.1).abs() < 1e-4);
    // The blade axis is the quad's, pointing either way.
    assert!((l.orientation * Vec3::Y).dot(q * Vec3::Y).abs() > 0.999);
    let flipped = l.flipped();
    assert!((flipped.anchor - l.anchor).length() - 0.4 < 1e-4);
}
