use glam::{Vec2, Vec3};
use serde_json::{Value, json};

use super::*;

/// A GLB from a JSON document whose single buffer is `bin`.
fn glb(mut doc: Value, bin: &[u8]) -> Vec<u8> {
    doc["asset"] = json!({"version": "2.0"});
    doc["buffers"] = json!([{"byteLength": bin.len()}]);
    let json = serde_json::to_vec(&doc).unwrap();
    treemorph_gltf::Glb {
        json: &json,
        bin: Some(bin),
    }
    .to_vec()
    .unwrap()
}

fn bytes<T: Copy>(values: &[T], f: impl Fn(T) -> Vec<u8>) -> Vec<u8> {
    values.iter().flat_map(|&v| f(v)).collect()
}

fn read_ok(bytes: &[u8]) -> Document {
    read(bytes, &ImportOptions::default()).unwrap()
}

#[test]
fn quantised_positions_and_uvs_are_normalised_and_transformed() {
    // u16-normalised positions scaled back by the node (KHR_mesh_quantization
    // style) and u8-normalised UVs; u8 indices.
    let pos = bytes(&[0u16, 0, 0, 0, 65535, 65535, 0, 0, 0, 0, 0, 65535], |v| {
        v.to_le_bytes().to_vec()
    });
    let uv = [0u8, 255, 255, 255, 255, 0, 0, 0];
    let idx = [0u8, 1, 2];
    let mut bin = pos.clone();
    bin.extend_from_slice(&uv);
    bin.extend_from_slice(&idx);
    bin.push(0);
    let doc = json!({
        "extensionsRequired": ["KHR_mesh_quantization"],
        "nodes": [{"mesh": 0, "scale": [2.0, 4.0, 8.0], "translation": [1.0, 0.0, 0.0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5123, "normalized": true, "count": 3, "type": "VEC3", "byteOffset": 0},
            {"bufferView": 1, "componentType": 5121, "normalized": true, "count": 3, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5121, "count": 3, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 24, "byteStride": 8},
            {"buffer": 0, "byteOffset": 24, "byteLength": 6},
            {"buffer": 0, "byteOffset": 32, "byteLength": 3}
        ]
    });
    // The view holds 4-component-strided u16 positions: only 3 used per
    // element, stride 8.
    let doc_bytes = glb(doc, &bin);
    let d = read_ok(&doc_bytes);
    let p = &d.primitives[0];
    assert_eq!(p.positions[0], Vec3::new(1.0, 0.0, 0.0));
    assert_eq!(p.positions[1], Vec3::new(3.0, 4.0, 0.0));
    assert_eq!(p.positions[2], Vec3::new(1.0, 0.0, 0.0));
    let uvs = p.uvs.as_ref().unwrap();
    assert_eq!(uvs[0], Vec2::new(0.0, 1.0));
    assert_eq!(uvs[1], Vec2::new(1.0, 1.0));
    assert_eq!(p.triangles, vec![[0, 1, 2]]);
}

#[test]
fn strips_fans_and_unindexed_primitives_become_triangles() {
    assert_eq!(
        triangulate(&[0, 1, 2, 3, 4], 5),
        vec![[0, 1, 2], [2, 1, 3], [2, 3, 4]]
    );
    assert_eq!(triangulate(&[0, 1, 2, 3], 6), vec![[0, 1, 2], [0, 2, 3]]);
    assert_eq!(triangulate(&[0, 1, 1, 2, 3, 4], 4), vec![[2, 3, 4]]);
    let pos = bytes(
        &[
            0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0,
        ],
        |v| v.to_le_bytes().to_vec(),
    );
    let doc = json!({
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "mode": 5}]}],
        "nodes": [{"mesh": 0}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"}],
        "bufferViews": [{"buffer": 0, "byteLength": 48}]
    });
    let d = read_ok(&glb(doc, &pos));
    assert_eq!(d.primitives[0].triangles, vec![[0, 1, 2], [2, 1, 3]]);
}

#[test]
fn node_transforms_compose_and_lines_are_skipped() {
    let pos = bytes(&[0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], |v| {
        v.to_le_bytes().to_vec()
    });
    // Parent: matrix translating by (0, 10, 0); child: 90° about Z.
    let s = std::f32::consts::FRAC_1_SQRT_2;
    let doc = json!({
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [
            {"matrix": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,10,0,1], "children": [1]},
            {"rotation": [0, 0, s, s], "mesh": 0}
        ],
        "meshes": [{"primitives": [
            {"attributes": {"POSITION": 0}},
            {"attributes": {"POSITION": 0}, "mode": 1}
        ]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}]
    });
    let d = read_ok(&glb(doc, &pos));
    assert_eq!(d.primitives.len(), 1);
    assert!(d.warnings.iter().any(|w| w.contains("points or lines")));
    let p = &d.primitives[0].positions;
    assert!(p[1].distance(Vec3::new(0.0, 11.0, 0.0)) < 1e-5);
    assert!(p[2].distance(Vec3::new(-1.0, 10.0, 0.0)) < 1e-5);
}

#[test]
fn sparse_accessors_override_base_values_and_zeros() {
    let base = bytes(&[0.0f32; 9], |v| v.to_le_bytes().to_vec());
    let mut bin = base.clone();
    bin.extend_from_slice(&2u16.to_le_bytes());
    bin.extend_from_slice(&[0, 0]);
    bin.extend(bytes(&[5.0f32, 6.0, 7.0], |v| v.to_le_bytes().to_vec()));
    let doc = |with_view: bool| {
        let mut a = json!({"componentType": 5126, "count": 3, "type": "VEC3",
            "sparse": {"count": 1,
                "indices": {"bufferView": 1, "componentType": 5123},
                "values": {"bufferView": 2}}});
        if with_view {
            a["bufferView"] = json!(0);
        }
        json!({
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "accessors": [a],
            "bufferViews": [
                {"buffer": 0, "byteLength": 36},
                {"buffer": 0, "byteOffset": 36, "byteLength": 2},
                {"buffer": 0, "byteOffset": 40, "byteLength": 12}
            ]
        })
    };
    for with_view in [true, false] {
        let d = read_ok(&glb(doc(with_view), &bin));
        assert_eq!(d.primitives[0].positions[2], Vec3::new(5.0, 6.0, 7.0));
        assert_eq!(d.primitives[0].positions[0], Vec3::ZERO);
    }
}

#[test]
fn gltf_json_with_data_uris_reads_like_glb() {
    use base64::Engine as _;
    let pos = bytes(&[0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], |v| {
        v.to_le_bytes().to_vec()
    });
    let uri = format!(
        "data:application/gltf-buffer;base64,{}",
        base64::engine::general_purpose::STANDARD_NO_PAD.encode(&pos)
    );
    let doc = json!({
        "asset": {"version": "2.0"},
        "nodes": [{"mesh": 0, "name": "trunk node"}],
        "meshes": [{"name": "trunk", "primitives": [{"attributes": {"POSITION": 0}, "material": 0}]}],
        "materials": [{"name": "Bark", "alphaMode": "OPAQUE",
            "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.4, 0.3, 1.0]}}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "buffers": [{"byteLength": 36, "uri": uri}]
    });
    let mut text = b"\xEF\xBB\xBF  ".to_vec();
    text.extend(serde_json::to_vec(&doc).unwrap());
    let d = read_ok(&text);
    assert_eq!(d.primitives[0].mesh_name, "trunk");
    assert_eq!(d.primitives[0].node_name, "trunk node");
    assert_eq!(d.materials[0].name, "Bark");
    assert_eq!(d.materials[0].alpha, AlphaMode::Opaque);
    assert_eq!(d.materials[0].color, [0.5, 0.4, 0.3, 1.0]);
    assert_eq!(d.primitives[0].positions[1], Vec3::X);
}

#[test]
fn texture_transform_applies_to_base_colour_uvs() {
    let mut bin = bytes(&[0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], |v| {
        v.to_le_bytes().to_vec()
    });
    bin.extend(bytes(&[0.0f32, 0.0, 1.0, 0.0, 0.0, 1.0], |v| {
        v.to_le_bytes().to_vec()
    }));
    let doc = json!({
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0,
            "extensions": {"KHR_texture_transform": {"offset": [0.5, 0.0], "scale": [0.5, 1.0]}}}}}],
        "textures": [{}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
            {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"}
        ],
        "bufferViews": [{"buffer": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 24}]
    });
    let d = read_ok(&glb(doc, &bin));
    let uvs = d.primitives[0].uvs.as_ref().unwrap();
    assert_eq!(uvs[1], Vec2::new(1.0, 0.0));
    assert_eq!(uvs[0], Vec2::new(0.5, 0.0));
}

#[test]
fn png_images_decode_and_other_formats_are_reported() {
    let image = treemorph_tree::RgbaImage::new(2, 2, vec![255; 16]).unwrap();
    let png = treemorph_tree::Texture::from_rgba(&image);
    let encoded = EncodedImage {
        bytes: png.png().to_vec(),
        mime: Some("image/png".into()),
    };
    let (_, rgba) = decode_image(&encoded, 4096).unwrap();
    assert_eq!(rgba, image);
    assert!(decode_image(&encoded, 1).unwrap_err().contains("at most 1"));
    let webp = EncodedImage {
        bytes: b"RIFF....WEBP".to_vec(),
        mime: Some("image/webp".into()),
    };
    assert!(
        decode_image(&webp, 4096)
            .unwrap_err()
            .contains("image/webp")
    );
    let broken_jpeg = EncodedImage {
        bytes: vec![0xFF, 0xD8, 0xFF, 0x00],
        mime: None,
    };
    assert!(
        decode_image(&broken_jpeg, 4096)
            .unwrap_err()
            .contains("JPEG")
    );
}
