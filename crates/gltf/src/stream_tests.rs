use glam::Vec3;
use treemorph_api::delta::{DecoderOptions, EncoderOptions, decode_all};
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_tree::Aabb;

use super::*;
use crate::bench::Sway;
use crate::frame_glb::{FrameGlbOptions, FrameGlbWriter};
use crate::frames::FrameMeshes;
use crate::mesh::LeafShape;

fn sway(frames: usize) -> Sway {
    let tree = generate(&GenerateOptions::new(Preset::Shrub, 2).with_size(400)).unwrap();
    Sway::new(&tree, frames)
}

fn encode(sway: &Sway, options: &StreamOptions) -> (Vec<u8>, DeltaStreamWriter) {
    let mut writer = DeltaStreamWriter::new(
        sway.topology(),
        sway.reference_radii(),
        sway.bounds(),
        options,
    )
    .unwrap();
    let mut stream = Vec::new();
    for i in 0..sway.len() {
        writer.write_frame(&sway.frame(i), &mut stream).unwrap();
    }
    writer.finish(&mut stream).unwrap();
    (stream, writer)
}

#[test]
fn decoded_frames_are_the_meshes_within_the_grid_error() {
    let sway = sway(6);
    let options = StreamOptions::default().with_frame_count(6);
    let (stream, writer) = encode(&sway, &options);
    let (header, frames) = decode_all(&stream, &DecoderOptions::default()).unwrap();
    assert_eq!(header, *writer.header().unwrap());
    assert_eq!(header.frame_count, 6);
    assert_eq!(frames.len(), 6);
    let names: Vec<&str> = header.meshes.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(names, ["branches", "leaves"]);
    let height = f64::from(sway.bounds().size().y);
    let mut meshes =
        FrameMeshes::new(sway.topology(), sway.reference_radii(), &options.mesh).unwrap();
    for (i, decoded) in frames.iter().enumerate() {
        let frame = sway.frame(i);
        let (b, l) = meshes.mesh(&frame).unwrap();
        for (got, want) in decoded.positions.iter().zip([b, l]) {
            assert_eq!(got.len(), want.positions.len());
            for (g, w) in got.iter().zip(&want.positions) {
                let e = f64::from((Vec3::from_array(*g) - *w).length());
                assert!(e <= 0.001 * height, "frame {i}: error {e}");
            }
        }
        assert_eq!(decoded.t, frame.t);
        // Every leaf of the sway fades with the same blend.
        assert!((decoded.leaf_blend - frame.leaves[0].blend).abs() < 1e-6);
    }
    // Indices and UVs are the meshers'.
    assert_eq!(
        header.meshes[0].indices,
        meshes.branches().buffers().indices
    );
    assert_eq!(
        header.meshes[1].uvs,
        meshes
            .leaves()
            .buffers()
            .uvs
            .iter()
            .map(|v| v.to_array())
            .collect::<Vec<_>>()
    );
}

#[test]
fn fading_groups_fade_to_the_second_material_on_the_first_outline() {
    let sway = sway(2);
    let (stream, _) = encode(&sway, &StreamOptions::default());
    let (header, _) = decode_all(&stream, &DecoderOptions::default()).unwrap();
    let topology = sway.topology();
    let leaves = &header.meshes[1];
    assert!(!leaves.groups.is_empty());
    for g in &leaves.groups {
        let material = &header.materials[g.material as usize];
        let fade = &header.materials[g.fade_to.expect("every sway leaf fades") as usize];
        assert!(material.double_sided && fade.double_sided);
        assert!(matches!(fade.alpha_mode, AlphaMode::Mask { cutoff } if cutoff == 0.5));
        // The fade material shows the second look (its texture warped onto
        // the first outline, colour baked in), not the first: the shrub's
        // materials share one texture, so their tints tell them apart.
        assert_ne!(
            (material.texture, material.base_color),
            (fade.texture, fade.base_color)
        );
        assert_eq!(fade.base_color, [1.0; 4]);
        assert!(
            topology
                .leaf_materials
                .iter()
                .any(|m| m.name == material.name)
        );
        assert!(fade.name.contains('→'), "{}", fade.name);
    }
    // The bark does not change in a sway.
    assert_eq!(header.meshes[0].groups[0].fade_to, None);
    assert!(
        header
            .textures
            .iter()
            .all(|t| t.png.starts_with(b"\x89PNG"))
    );
}

#[test]
fn frames_are_a_small_fraction_of_a_frame_glb() {
    let sway = sway(4);
    let (stream, writer) = encode(&sway, &StreamOptions::default());
    let header = writer.header().unwrap();
    let _ = header;
    let mut glb_writer = FrameGlbWriter::new(
        sway.topology(),
        sway.reference_radii(),
        &FrameGlbOptions::default(),
    )
    .unwrap();
    let glb = glb_writer.write(&sway.frame(2)).unwrap().len();
    // The stream of 4 frames without its header, per frame.
    let mut header_only = DeltaStreamWriter::new(
        sway.topology(),
        sway.reference_radii(),
        sway.bounds(),
        &StreamOptions::default(),
    )
    .unwrap();
    let mut first = Vec::new();
    header_only.write_frame(&sway.frame(0), &mut first).unwrap();
    let per_frame = (stream.len() - first.len()) / 3;
    assert!(
        per_frame * 4 <= glb,
        "{per_frame} bytes per frame vs a {glb}-byte GLB"
    );
}

#[test]
fn the_stream_works_compressed_and_with_contours() {
    let sway = sway(3);
    let options = StreamOptions::default()
        .with_mesh(MeshOptions::default().with_leaf_shape(LeafShape::Contour { points: 8 }))
        .with_encoder(EncoderOptions::default());
    let (stream, writer) = encode(&sway, &options);
    let (header, frames) = decode_all(&stream, &DecoderOptions::default()).unwrap();
    assert_eq!(frames.len(), 3);
    assert_eq!(
        header.meshes[1].vertex_count(),
        9 * sway.topology().leaves.len()
    );
    assert_eq!(header, *writer.header().unwrap());
    // The default is quads, uncompressed.
    let (plain, _) = encode(&sway, &StreamOptions::default());
    let (header, _) = decode_all(&plain, &DecoderOptions::default()).unwrap();
    assert_eq!(
        header.meshes[1].vertex_count(),
        4 * sway.topology().leaves.len()
    );
}

#[test]
fn misuse_is_refused() {
    let sway = sway(2);
    let (topology, radii) = (sway.topology(), sway.reference_radii());
    let mut writer =
        DeltaStreamWriter::new(topology, radii, sway.bounds(), &StreamOptions::default()).unwrap();
    let mut out = Vec::new();
    assert!(matches!(
        writer.finish(&mut out),
        Err(EncodeError::Usage(_))
    ));
    assert!(out.is_empty());
    for bounds in [Aabb::EMPTY, Aabb::of_points([Vec3::splat(f32::NAN)])] {
        assert!(matches!(
            DeltaStreamWriter::new(topology, radii, bounds, &StreamOptions::default()),
            Err(EncodeError::InvalidOptions(_))
        ));
    }
    let bad = StreamOptions {
        max_error_fraction: 0.0,
        ..StreamOptions::default()
    };
    assert!(matches!(
        DeltaStreamWriter::new(topology, radii, sway.bounds(), &bad),
        Err(EncodeError::InvalidOptions(_))
    ));
    // An announced frame count must be reached.
    let mut writer = DeltaStreamWriter::new(
        topology,
        radii,
        sway.bounds(),
        &StreamOptions::default().with_frame_count(2),
    )
    .unwrap();
    writer.write_frame(&sway.frame(0), &mut out).unwrap();
    assert!(matches!(
        writer.finish(&mut out),
        Err(EncodeError::Stream(_))
    ));
    // A frame that does not fit.
    let mut short = sway.frame(1);
    short.leaves.pop();
    assert!(matches!(
        writer.write_frame(&short, &mut out),
        Err(EncodeError::Frame(_))
    ));
}

/// A restarted writer writes the header it wrote first, then what a new
/// writer of the same first frame writes: one-frame streams of one
/// sequence, rendered in any order, are the bytes of fresh writers.
#[test]
fn a_restarted_writer_writes_what_a_new_one_writes() {
    let sway = sway(5);
    let options = StreamOptions::default().with_frame_count(1);
    let new = || {
        let mut w = DeltaStreamWriter::new(
            sway.topology(),
            sway.reference_radii(),
            sway.bounds(),
            &options,
        )
        .unwrap();
        let mut out = Vec::new();
        w.write_header(&sway.frame(0), &mut out).unwrap();
        (w, out)
    };
    let one = |w: &mut DeltaStreamWriter, mut out: Vec<u8>, i: usize| {
        w.write_frame(&sway.frame(i), &mut out).unwrap();
        w.finish(&mut out).unwrap();
        out
    };
    let (mut kept, header) = new();
    let mut reused = vec![one(&mut kept, header, 4)];
    for i in [1, 3, 4] {
        let mut out = Vec::new();
        kept.restart(&mut out).unwrap();
        reused.push(one(&mut kept, out, i));
    }
    for (got, i) in reused.iter().zip([4, 1, 3, 4]) {
        let (w, out) = &mut new();
        assert!(*got == one(w, std::mem::take(out), i), "instant {i}");
    }
    let mut fresh = DeltaStreamWriter::new(
        sway.topology(),
        sway.reference_radii(),
        sway.bounds(),
        &options,
    )
    .unwrap();
    assert!(matches!(
        fresh.restart(&mut Vec::new()),
        Err(EncodeError::Usage(_))
    ));
}
