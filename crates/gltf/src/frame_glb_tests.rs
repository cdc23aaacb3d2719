use glam::{Quat, Vec3};
use treemorph_generate::LeafShape as Drawn;
use treemorph_tree::{
    Bark, Frame, FrameLeaf, FrameLeafTopology, FrameTopology, LeafMaterial, Limits, Strands,
};

use super::*;
use crate::frames::EncodeError;
use crate::mesh::{LeafShape, MeshOptions};
use crate::test_support::Parsed;

/// A stick with `n` leaves in a row fading from a palmate to a round leaf
/// (`blends[i]` for leaf `i`), one leaf keeping an untextured material,
/// and two barks.
fn row(blends: &[f32]) -> (FrameTopology, Frame) {
    let materials = vec![
        LeafMaterial {
            name: "palmate".into(),
            color: [1.0; 4],
            texture: Some(Drawn::Palmate.texture()),
        },
        LeafMaterial {
            name: "round".into(),
            color: [1.0, 0.5, 0.2, 1.0],
            texture: Some(Drawn::Round.texture()),
        },
        LeafMaterial {
            name: "plain".into(),
            color: [0.2, 0.6, 0.1, 1.0],
            texture: None,
        },
    ];
    let mut leaves: Vec<FrameLeafTopology> = blends
        .iter()
        .map(|_| FrameLeafTopology {
            node: 1,
            materials: [0, 1],
        })
        .collect();
    leaves.push(FrameLeafTopology {
        node: 1,
        materials: [2, 2],
    });
    let frame_leaves = (0..leaves.len())
        .map(|i| FrameLeaf {
            anchor: Vec3::new(i as f32 * 0.3, 1.0, 0.0),
            orientation: Quat::IDENTITY,
            width: 0.25,
            height: 0.25,
            blend: blends.get(i).copied().unwrap_or(0.0),
        })
        .collect();
    let topology = FrameTopology {
        parents: vec![None, Some(0)],
        strands: Strands::from_polylines([vec![0u32, 1]]),
        leaves,
        leaf_materials: materials,
        bark: [
            Bark {
                color: [0.2, 0.1, 0.0, 1.0],
                texture: None,
            },
            Bark {
                color: [0.6, 0.5, 0.4, 1.0],
                texture: None,
            },
        ],
    };
    let frame = Frame {
        t: 0.5,
        positions: vec![Vec3::ZERO, Vec3::Y * 2.0],
        radii: vec![0.05, 0.03],
        leaves: frame_leaves,
        bark_blend: 0.5,
    };
    (topology, frame)
}

fn primitives(parsed: &Parsed, name: &str) -> Vec<serde_json::Value> {
    parsed.mesh_of(name)["primitives"]
        .as_array()
        .unwrap()
        .clone()
}

#[test]
fn writes_the_meshers_output_under_the_static_names() {
    let (topology, frame) = row(&[0.0, 0.5, 1.0]);
    let mut writer =
        FrameGlbWriter::new(&topology, &frame.radii, &FrameGlbOptions::default()).unwrap();
    let glb = writer.write(&frame).unwrap();
    let parsed = Parsed::new(&glb);
    let names: Vec<&str> = parsed.json["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["branches", "leaves"]);
    assert_eq!(parsed.json["scenes"][0]["extras"]["frame"]["t"], 0.5);
    // Frames are not trees: nothing embedded.
    assert_eq!(
        crate::read_embedded_tree(&glb, &Limits::default()),
        Ok(None)
    );
    let (b, l) = (
        writer.meshes().branches().buffers(),
        writer.meshes().leaves().buffers(),
    );
    for (name, mesh) in [("branches", b), ("leaves", l)] {
        let prim = &primitives(&parsed, name)[0];
        let positions = parsed.vec3s(prim["attributes"]["POSITION"].as_u64().unwrap() as usize);
        assert!(positions == mesh.positions, "{name}");
        let uvs = parsed.vec2s(prim["attributes"]["TEXCOORD_0"].as_u64().unwrap() as usize);
        assert!(uvs == mesh.uvs, "{name}");
    }
    // Contour leaves by default: 12 rim points and a centre each.
    assert_eq!(l.vertex_count(), 4 * 13);
}

#[test]
fn one_leaf_primitive_per_pair_and_blend_step() {
    // Blends 0.5 and 0.52 share a step of 1/16; 0.0 and 1.0 are steps of
    // their own; the plain leaf keeps its material.
    let (topology, frame) = row(&[0.0, 0.5, 0.52, 1.0, 0.5]);
    let mut writer =
        FrameGlbWriter::new(&topology, &frame.radii, &FrameGlbOptions::default()).unwrap();
    let parsed = Parsed::new(&writer.write(&frame).unwrap());
    let prims = primitives(&parsed, "leaves");
    assert_eq!(prims.len(), 4);
    let per_leaf = 12 * 3;
    let per_vertex = 13;
    let mut seen = Vec::new();
    for prim in &prims {
        let indices = parsed.indices(prim["indices"].as_u64().unwrap() as usize);
        let mut leaves: Vec<u32> = indices
            .chunks(per_leaf)
            .map(|c| c[0] / per_vertex)
            .collect();
        leaves.sort_unstable();
        let material = &parsed.json["materials"][prim["material"].as_u64().unwrap() as usize];
        seen.push((leaves, material["name"].as_str().unwrap().to_owned()));
    }
    seen.sort();
    assert_eq!(
        seen,
        vec![
            (vec![0], "palmate".to_owned()),
            (vec![1, 2, 4], "palmate→round@0.500".to_owned()),
            (vec![3], "palmate→round@1.000".to_owned()),
            (vec![5], "plain".to_owned()),
        ]
    );
    // The blend-0 leaf uses the material's own PNG; blended leaves their
    // own texture, colour factor baked in.
    let texture_png = |material: &serde_json::Value| {
        let t = material["pbrMetallicRoughness"]["baseColorTexture"]["index"].as_u64()?;
        let image = parsed.json["textures"][t as usize]["source"]
            .as_u64()
            .unwrap();
        let view = parsed.json["images"][image as usize]["bufferView"]
            .as_u64()
            .unwrap();
        Some(parsed.view(view as usize))
    };
    for prim in &prims {
        let material = &parsed.json["materials"][prim["material"].as_u64().unwrap() as usize];
        match material["name"].as_str().unwrap() {
            "palmate" => assert!(texture_png(material).unwrap() == Drawn::Palmate.texture().png()),
            "plain" => {
                assert!(texture_png(material).is_none());
                assert_eq!(
                    material["pbrMetallicRoughness"]["baseColorFactor"][1].as_f64(),
                    Some(0.6f32 as f64)
                );
            }
            _ => {
                assert!(texture_png(material).is_some());
                assert_eq!(
                    material["pbrMetallicRoughness"]["baseColorFactor"],
                    serde_json::json!([1.0, 1.0, 1.0, 1.0])
                );
                assert_eq!(material["alphaMode"], "MASK");
            }
        }
    }
    // Bark: colours blended by the bark blend.
    let bark = &parsed.json["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"];
    let red = bark[0].as_f64().unwrap();
    assert!((red - 0.4).abs() < 1e-6, "{bark}");
}

#[test]
fn a_material_is_embedded_once_however_many_pairs_show_it() {
    // Leaf 0 fades palmate → round, leaf 1 palmate → plain, both at blend
    // 0: both show the palmate material, which appears once.
    let (mut topology, frame) = row(&[0.0, 0.0]);
    topology.leaves[1].materials = [0, 2];
    let mut writer =
        FrameGlbWriter::new(&topology, &frame.radii, &FrameGlbOptions::default()).unwrap();
    let parsed = Parsed::new(&writer.write(&frame).unwrap());
    let materials = parsed.json["materials"].as_array().unwrap();
    let names: Vec<&str> = materials
        .iter()
        .map(|m| m["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["bark", "palmate", "plain"]);
    assert_eq!(parsed.json["images"].as_array().unwrap().len(), 1);
    // Two primitives (two pairs) share the palmate material.
    let prims = primitives(&parsed, "leaves");
    assert_eq!(prims.len(), 3);
    let palmate = prims.iter().filter(|p| p["material"] == 1).count();
    assert_eq!(palmate, 2);
}

#[test]
fn frames_are_deterministic_and_reuse_their_buffer() {
    let (topology, mut frame) = row(&[0.3, 0.7]);
    let mut writer =
        FrameGlbWriter::new(&topology, &frame.radii, &FrameGlbOptions::default()).unwrap();
    let first = writer.write(&frame).unwrap();
    let mut out = Vec::new();
    writer.write_into(&frame, &mut out).unwrap();
    assert!(out == first);
    // A frame of a different size into the same buffer.
    frame.leaves[0].blend = 0.9;
    writer.write_into(&frame, &mut out).unwrap();
    let again = FrameGlbWriter::new(&topology, &frame.radii, &FrameGlbOptions::default())
        .unwrap()
        .write(&frame)
        .unwrap();
    // A fresh writer fixes bark UVs from this frame instead: same here
    // because only leaves changed.
    assert!(out == again);
}

#[test]
fn quad_leaves_blend_plain_textures() {
    let (topology, frame) = row(&[0.25]);
    let options = FrameGlbOptions::default().with_mesh(MeshOptions::default());
    assert_eq!(options.mesh.leaf_shape, LeafShape::Quad);
    let mut writer = FrameGlbWriter::new(&topology, &frame.radii, &options).unwrap();
    let parsed = Parsed::new(&writer.write(&frame).unwrap());
    let prims = primitives(&parsed, "leaves");
    assert_eq!(prims.len(), 2);
    assert_eq!(writer.meshes().leaves().vertex_count(), 2 * 4);
}

#[test]
fn bad_input_is_the_callers_mistake() {
    let (topology, frame) = row(&[0.5]);
    assert!(matches!(
        FrameGlbWriter::new(
            &topology,
            &frame.radii,
            &FrameGlbOptions::default().with_blend_steps(0)
        ),
        Err(EncodeError::InvalidOptions(_))
    ));
    assert!(matches!(
        FrameGlbWriter::new(&topology, &frame.radii[..1], &FrameGlbOptions::default()),
        Err(EncodeError::Frame(_))
    ));
    let mut bad = topology.clone();
    bad.leaves[0].materials[1] = 9;
    assert!(matches!(
        FrameGlbWriter::new(&bad, &frame.radii, &FrameGlbOptions::default()),
        Err(EncodeError::Topology(_))
    ));
    let mut odd = FrameGlbOptions::default();
    odd.mesh.leaf_shape = LeafShape::Contour { points: 7 };
    assert!(matches!(
        FrameGlbWriter::new(&topology, &frame.radii, &odd),
        Err(EncodeError::InvalidOptions(_))
    ));
    let mut writer =
        FrameGlbWriter::new(&topology, &frame.radii, &FrameGlbOptions::default()).unwrap();
    for mutate in [
        (|f: &mut Frame| f.leaves[0].blend = 1.5) as fn(&mut Frame),
        |f| f.t = -0.1,
        |f| f.bark_blend = f32::NAN,
        |f| f.positions[1].x = f32::INFINITY,
        |f| {
            f.leaves.pop();
        },
    ] {
        let mut f = frame.clone();
        mutate(&mut f);
        assert!(matches!(writer.write(&f), Err(EncodeError::Frame(_))));
    }
}

/// A frame written for one instant blends a few dozen looks at once, in
/// parallel (`Looks::prepare`): they are cached under the keys a writer
/// asks for, once each, and equal the looks made one at a time.
#[test]
fn looks_prepared_together_equal_looks_made_one_at_a_time() {
    let (mut topology, frame) = row(&[0.3, 0.6]);
    topology.bark[0].texture = Some(Drawn::Palmate.texture());
    topology.bark[1].texture = Some(Drawn::Round.texture());
    let meshes =
        crate::frames::FrameMeshes::new(&topology, &frame.radii, &MeshOptions::default()).unwrap();
    let keys = [
        [0, 1, 5],
        [0, 1, 17],
        [0, 2, 3],
        [2, 2, 9],
        [0, 1, 99],
        [0, 1, 5],
    ];
    let mut together = crate::frames::Looks::new(&topology, meshes.leaves(), 64);
    together.prepare(20, &keys);
    // Five distinct keys ([2, 2, q] is [2, 2, 0]; 99 is step 64) and one
    // bark.
    assert_eq!(together.cached(), (5, 1));
    let mut alone = crate::frames::Looks::new(&topology, meshes.leaves(), 64);
    for [a, b, q] in keys {
        assert_eq!(together.leaf_blend(a, b, q), alone.leaf_blend(a, b, q));
    }
    assert_eq!(together.bark(20), alone.bark(20));
    assert!(together.bark(20).texture.is_some(), "a blended bark");
    assert_eq!(together.cached(), (5, 1), "nothing computed twice");
}
