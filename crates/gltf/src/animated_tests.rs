use glam::Vec3;
use treemorph_tree::{Aabb, Frame};

use super::*;
use crate::bench::Sway;
use crate::frames::FrameMeshes;
use crate::test_support::{Parsed, canonical_triangles};

/// What a keyframes animation is built with by default.
fn keyframes_options() -> AnimatedOptions {
    AnimatedOptions::default().with_mesh(KEYFRAMES_MESH)
}

fn sway(frames: usize) -> Sway {
    crate::test_support::maple_sway(frames)
}

fn build(sway: &Sway, options: &AnimatedOptions) -> Vec<u8> {
    let mut b = AnimatedGlbBuilder::new(
        sway.topology(),
        sway.reference_radii(),
        sway.bounds(),
        options,
    )
    .unwrap();
    for i in 0..sway.len() {
        b.push(&sway.frame(i)).unwrap();
    }
    assert_eq!(b.keyframe_count(), sway.len());
    b.finish().unwrap()
}

/// The layered leaf positions and branch positions the builder stores for
/// keyframe `i`, recomputed independently of the file.
fn expected(sway: &Sway, options: &AnimatedOptions, i: usize) -> [Vec<Vec3>; 2] {
    let mut meshes =
        FrameMeshes::new(sway.topology(), sway.reference_radii(), &options.mesh).unwrap();
    let frame = sway.frame(i);
    let shape = meshes.leaves().shape();
    let (b, l) = meshes.mesh(&frame).unwrap();
    let fading: Vec<u32> = sway
        .topology()
        .leaves
        .iter()
        .enumerate()
        .filter(|(_, l)| l.materials[0] != l.materials[1])
        .map(|(i, _)| i as u32)
        .collect();
    let thresholds: Vec<f32> = fading.iter().map(|&i| threshold(i)).collect();
    let (mut p, mut n) = (Vec::new(), Vec::new());
    layer_leaves(
        l,
        sway.topology(),
        shape,
        &fading,
        &thresholds,
        &frame,
        &mut p,
        &mut n,
    );
    [b.positions.clone(), p]
}

/// Weights at keyframe `k` of `count`.
fn one_hot(k: usize, count: usize) -> Vec<f32> {
    let mut w = vec![0.0; count - 1];
    if k > 0 {
        w[k - 1] = 1.0;
    }
    w
}

#[test]
fn keyframes_are_the_base_and_one_target_each() {
    let sway = sway(5);
    let options = keyframes_options();
    let parsed = Parsed::new(&build(&sway, &options));
    let json = &parsed.json;
    assert!(json.get("extensionsUsed").is_none());
    for (m, name) in ["branches", "leaves"].iter().enumerate() {
        let mesh = parsed.mesh_of(name);
        assert_eq!(mesh["name"], *name);
        for prim in mesh["primitives"].as_array().unwrap() {
            assert_eq!(prim["targets"].as_array().unwrap().len(), 4);
        }
        for k in 0..5 {
            let got = parsed.morphed(name, &parsed.keyframe_weights(k));
            let want = &expected(&sway, &options, k)[m];
            assert_eq!(got.len(), want.len());
            for (g, w) in got.iter().zip(want) {
                assert!(
                    g.abs_diff_eq(*w, 1e-5 * (1.0 + w.length())),
                    "{name} keyframe {k}: {g} vs {w}"
                );
            }
        }
    }
    // One sampler over both nodes' weights: times t·duration, one-hot
    // outputs, linear.
    let anim = &json["animations"][0];
    let sampler = &anim["samplers"][0];
    assert_eq!(sampler["interpolation"], "LINEAR");
    let (times, _) = parsed.floats(sampler["input"].as_u64().unwrap() as usize);
    assert_eq!(times, vec![0.0, 1.0, 2.0, 3.0, 4.0]);
    for k in 0..5 {
        assert_eq!(parsed.keyframe_weights(k), one_hot(k, 5));
    }
    let channels = anim["channels"].as_array().unwrap();
    assert_eq!(channels.len(), 2);
    assert!(channels.iter().all(|c| c["target"]["path"] == "weights"));
}

#[test]
fn fading_leaves_show_exactly_one_layer_per_keyframe() {
    let sway = sway(7);
    let options = keyframes_options();
    let parsed = Parsed::new(&build(&sway, &options));
    let topology = sway.topology();
    let per = options.mesh.leaf_shape.vertices_per_leaf();
    let n = topology.leaves.len();
    // Every leaf of the maple fades between its two tints.
    assert!(
        topology
            .leaves
            .iter()
            .all(|l| l.materials[0] != l.materials[1])
    );
    // Primitives: per pair, a first and a second layer.
    let prims = parsed.mesh_of("leaves")["primitives"]
        .as_array()
        .unwrap()
        .len();
    assert_eq!(prims % 2, 0);
    let collapsed = |v: &[Vec3]| v.iter().all(|p| p.abs_diff_eq(v[0], 1e-5));
    let mut swaps = 0;
    let mut previous: Option<Vec<bool>> = None;
    for k in 0..7 {
        let p = parsed.morphed("leaves", &parsed.keyframe_weights(k));
        assert_eq!(p.len(), 2 * n * per);
        let second: Vec<bool> = (0..n)
            .map(|leaf| {
                let a = collapsed(&p[leaf * per..(leaf + 1) * per]);
                let b = collapsed(&p[(n + leaf) * per..(n + leaf + 1) * per]);
                assert!(a != b, "keyframe {k}, leaf {leaf}: exactly one layer shows");
                a
            })
            .collect();
        if let Some(prev) = &previous {
            // Blends only grow: a leaf swaps once, to its second layer.
            for (was, is) in prev.iter().zip(&second) {
                assert!(!was || *is);
                swaps += usize::from(*is && !was);
            }
        }
        previous = Some(second);
    }
    // The first keyframe shows first layers, the last second layers:
    // every leaf swapped once, and the swaps are spread over keyframes.
    assert_eq!(swaps, n);
}

#[test]
fn a_swapping_leaf_never_overlaps_itself() {
    // Halfway through the interval where a leaf swaps, the shrinking old
    // layer and the growing new one are separated across the leaf's axis.
    let sway = sway(7);
    let options = keyframes_options();
    let parsed = Parsed::new(&build(&sway, &options));
    let topology = sway.topology();
    let per = options.mesh.leaf_shape.vertices_per_leaf();
    let n = topology.leaves.len();
    let mut checked = 0;
    for k in 1..7 {
        let before = parsed.morphed("leaves", &parsed.keyframe_weights(k - 1));
        let after = parsed.morphed("leaves", &parsed.keyframe_weights(k));
        let mid_w: Vec<f32> = parsed
            .keyframe_weights(k - 1)
            .iter()
            .zip(parsed.keyframe_weights(k))
            .map(|(a, b)| 0.5 * (a + b))
            .collect();
        let mid = parsed.morphed("leaves", &mid_w);
        let frame = sway.frame(k);
        for leaf in 0..n {
            let first = |p: &[Vec3]| p[leaf * per..(leaf + 1) * per].to_vec();
            let second = |p: &[Vec3]| p[(n + leaf) * per..(n + leaf + 1) * per].to_vec();
            let swapped_now = first(&after)
                .iter()
                .all(|p| p.abs_diff_eq(first(&after)[0], 1e-5))
                && !first(&before)
                    .iter()
                    .all(|p| p.abs_diff_eq(first(&before)[0], 1e-5));
            if !swapped_now {
                continue;
            }
            // The leaf's own up axis at the keyframe.
            let up = frame.leaves[leaf].orientation * Vec3::Y;
            let (a, b) = (first(&mid), second(&mid));
            let a_lo = a.iter().map(|p| p.dot(up)).fold(f32::MAX, f32::min);
            let b_hi = b.iter().map(|p| p.dot(up)).fold(f32::MIN, f32::max);
            // Motion between keyframes adds a little slack.
            let size = frame.leaves[leaf].height;
            assert!(b_hi <= a_lo + 0.05 * size, "leaf {leaf}: {b_hi} > {a_lo}");
            checked += 1;
        }
    }
    assert!(checked > 0);
}

#[test]
fn quantised_keyframes_stay_within_the_grid_step() {
    let sway = sway(4);
    let options = keyframes_options().with_encoding(AnimatedEncoding::Quantized);
    let parsed = Parsed::new(&build(&sway, &options));
    assert_eq!(
        parsed.json["extensionsRequired"],
        serde_json::json!([KHR_MESH_QUANTIZATION])
    );
    let extent = sway.bounds().size().max_element();
    let step = extent / (2.0 * HALF_RANGE);
    for (m, name) in ["branches", "leaves"].iter().enumerate() {
        for k in 0..4 {
            let got = parsed.morphed(name, &parsed.keyframe_weights(k));
            let want = &expected(&sway, &options, k)[m];
            for (g, w) in got.iter().zip(want) {
                assert!(g.distance(*w) <= step, "{name} keyframe {k}: {g} vs {w}");
            }
        }
        // Normals: morphed directions within the i8 precision, however far
        // they turned (the quantised encodings store them absolute).
        assert_eq!(parsed.keyframe_weights(3), vec![-1.0, 0.0, 0.0, 1.0]);
        let mut meshes =
            FrameMeshes::new(sway.topology(), sway.reference_radii(), &options.mesh).unwrap();
        meshes.set_uv_frame(&sway.frame(0)).unwrap();
        for k in 0..4 {
            let (b, l) = meshes.mesh(&sway.frame(k)).unwrap();
            let want = if m == 0 { &b.normals } else { &l.normals };
            let got = parsed.morphed_normals(name, &parsed.keyframe_weights(k));
            for (i, w) in want.iter().enumerate() {
                assert!(
                    got[i].dot(*w) > 0.999,
                    "{name} keyframe {k} normal {i}: {} vs {w}",
                    got[i]
                );
            }
        }
    }
}

#[test]
fn meshopt_views_decode_to_the_quantised_bytes() {
    let sway = sway(4);
    let quantised = Parsed::new(&build(
        &sway,
        &keyframes_options().with_encoding(AnimatedEncoding::Quantized),
    ));
    let glb = build(
        &sway,
        &keyframes_options().with_encoding(AnimatedEncoding::Meshopt),
    );
    let meshopt = Parsed::new(&glb);
    assert_eq!(
        meshopt.json["extensionsRequired"],
        serde_json::json!([KHR_MESH_QUANTIZATION, EXT_MESHOPT_COMPRESSION])
    );
    let buffers = meshopt.json["buffers"].as_array().unwrap();
    assert_eq!(buffers.len(), 2);
    assert_eq!(
        buffers[1]["extensions"][EXT_MESHOPT_COMPRESSION]["fallback"],
        true
    );
    assert!(buffers[1].get("uri").is_none());
    // Same document structure; every accessor's data identical.
    let (qa, ma) = (
        quantised.json["accessors"].as_array().unwrap(),
        meshopt.json["accessors"].as_array().unwrap(),
    );
    assert_eq!(qa.len(), ma.len());
    for (i, accessor) in qa.iter().enumerate() {
        let (q, m) = (quantised.floats(i), meshopt.floats(i));
        if accessor["type"] == "SCALAR" && accessor["componentType"] != FLOAT {
            // Index buffers: the same triangles, possibly rotated.
            let (q, m) = (quantised.indices(i), meshopt.indices(i));
            assert!(
                canonical_triangles(&q) == canonical_triangles(&m),
                "accessor {i}"
            );
        } else {
            assert!(q == m, "accessor {i}");
        }
    }
    // Every vertex and index view is compressed and far smaller.
    let compressed: usize = meshopt.json["bufferViews"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|v| v["extensions"][EXT_MESHOPT_COMPRESSION]["byteLength"].as_u64())
        .map(|l| l as usize)
        .sum();
    let plain = buffers[1]["byteLength"].as_u64().unwrap() as usize;
    assert!(compressed * 2 < plain, "{compressed} vs {plain}");
    assert!(glb.len() < quantised.bin.len());
}

#[test]
fn keyframe_indices_spread_over_the_sequence() {
    assert_eq!(keyframe_indices(10, 4), vec![0, 3, 6, 9]);
    assert_eq!(keyframe_indices(3, 24), vec![0, 1, 2]);
    assert_eq!(keyframe_indices(1, 24), vec![0]);
    assert!(keyframe_indices(0, 24).is_empty());
    assert_eq!(keyframe_indices(100, 2), vec![0, 99]);
}

#[test]
fn misuse_is_refused() {
    let sway = sway(3);
    let (topology, radii) = (sway.topology(), sway.reference_radii());
    let bounds = sway.bounds();
    let options = keyframes_options();
    let mut b = AnimatedGlbBuilder::new(topology, radii, bounds, &options).unwrap();
    b.push(&sway.frame(1)).unwrap();
    // Time must increase.
    assert!(matches!(b.push(&sway.frame(0)), Err(EncodeError::Usage(_))));
    assert!(matches!(b.push(&sway.frame(1)), Err(EncodeError::Usage(_))));
    // One keyframe is not an animation.
    assert!(matches!(b.finish(), Err(EncodeError::Usage(_))));
    let b = AnimatedGlbBuilder::new(topology, radii, bounds, &options).unwrap();
    assert!(matches!(b.finish(), Err(EncodeError::Usage(_))));
    // Bad options and frames.
    for bad in [
        options.clone().with_duration(0.0),
        options.clone().with_keyframes(1),
    ] {
        assert!(matches!(
            AnimatedGlbBuilder::new(topology, radii, bounds, &bad),
            Err(EncodeError::InvalidOptions(_))
        ));
    }
    let quantised = options.clone().with_encoding(AnimatedEncoding::Quantized);
    assert!(matches!(
        AnimatedGlbBuilder::new(topology, radii, Aabb::EMPTY, &quantised),
        Err(EncodeError::InvalidOptions(_))
    ));
    // A frame far outside the quantisation bounds.
    let tiny = Aabb::of_points([Vec3::ZERO, Vec3::splat(0.01)]);
    let mut b = AnimatedGlbBuilder::new(topology, radii, tiny, &quantised).unwrap();
    assert!(matches!(b.push(&sway.frame(0)), Err(EncodeError::Frame(_))));
    let mut b = AnimatedGlbBuilder::new(topology, radii, bounds, &options).unwrap();
    let mut short = sway.frame(0);
    short.positions.pop();
    assert!(matches!(b.push(&short), Err(EncodeError::Frame(_))));
    let mut late: Frame = sway.frame(0);
    late.t = 1.5;
    assert!(matches!(b.push(&late), Err(EncodeError::Frame(_))));
}

#[test]
fn streaming_writes_the_same_file() {
    let sway = sway(3);
    let options = keyframes_options().with_encoding(AnimatedEncoding::Quantized);
    let whole = build(&sway, &options);
    let mut b = AnimatedGlbBuilder::new(
        sway.topology(),
        sway.reference_radii(),
        sway.bounds(),
        &options,
    )
    .unwrap();
    for i in 0..3 {
        b.push(&sway.frame(i)).unwrap();
    }
    let mut streamed = Vec::new();
    let len = b.finish_to(&mut streamed).unwrap();
    assert_eq!(len as usize, streamed.len());
    assert!(streamed == whole);
}

/// Writes animated GLBs (every encoding) and what three.js must make of
/// them, and runs `tools/render/check-animated.mjs` on each: three.js's
/// GLTFLoader and AnimationMixer must reproduce the vertex count, the
/// morph target count and the keyframe-interpolated positions.
///
/// `npm ci --prefix tools/render` first (and Chromium installed), then
/// `cargo test -p treemorph-gltf --lib -- --ignored threejs`.
#[test]
#[ignore = "needs node, chromium and `npm ci --prefix tools/render`"]
fn threejs_plays_the_animation_as_written() {
    let sway = sway(5);
    let duration = 4.0;
    for encoding in [
        AnimatedEncoding::Float,
        AnimatedEncoding::Quantized,
        AnimatedEncoding::Meshopt,
    ] {
        let options = keyframes_options()
            .with_encoding(encoding)
            .with_duration(duration);
        let glb = build(&sway, &options);
        let keyframes: Vec<[Vec<Vec3>; 2]> = (0..5).map(|k| expected(&sway, &options, k)).collect();
        let parsed = Parsed::new(&glb);
        let step = sway.bounds().size().max_element() / (2.0 * HALF_RANGE);
        let tolerance = match encoding {
            AnimatedEncoding::Float => 1e-4,
            _ => step * 1.01 + 1e-4,
        };
        // Keyframe times and points between them.
        let times = [0.0, 0.5, 1.0, 1.75, 2.0, 3.3, 4.0];
        let meshes: Vec<serde_json::Value> = ["branches", "leaves"]
            .iter()
            .enumerate()
            .map(|(m, name)| {
                let n = keyframes[0][m].len();
                let indices: Vec<usize> = (0..200).map(|i| i * n / 200).chain([n - 1]).collect();
                let targets = parsed.mesh_of(name)["primitives"][0]["targets"]
                    .as_array()
                    .unwrap()
                    .len();
                let samples: Vec<serde_json::Value> = times
                    .iter()
                    .map(|&time| {
                        let x = time / duration * 4.0;
                        let k = (x.floor() as usize).min(3);
                        let a = x - k as f32;
                        let positions: Vec<[f32; 3]> = indices
                            .iter()
                            .map(|&i| keyframes[k][m][i].lerp(keyframes[k + 1][m][i], a).to_array())
                            .collect();
                        serde_json::json!({ "time": time, "indices": indices, "positions": positions })
                    })
                    .collect();
                serde_json::json!({
                    "name": name, "vertices": n, "morphTargets": targets, "samples": samples,
                })
            })
            .collect();
        let name = format!("animated-{encoding:?}").to_lowercase();
        let expected = serde_json::json!({ "tolerance": tolerance, "meshes": meshes });
        crate::test_support::check_with_threejs(&name, &glb, &expected);
    }
}
