use glam::{Quat, Vec3};

use super::*;
use crate::model::GroundTruthGroup;
use crate::{RgbaImage, SizeKind};

fn sample_tree() -> Tree {
    let leaf_texture = {
        let mut pixels = Vec::new();
        for y in 0..8u32 {
            for x in 0..8u32 {
                let inside = (x as i32 - 4).pow(2) + (y as i32 - 4).pow(2) < 12;
                pixels.extend([40, 140, 30, if inside { 255 } else { 0 }]);
            }
        }
        Texture::from_rgba(&RgbaImage::new(8, 8, pixels).unwrap())
    };
    let parts = TreeParts {
        name: "sample \"tree\" ✓".into(),
        nodes: vec![
            Node {
                position: Vec3::ZERO,
                radius: 0.2,
                parent: None,
            },
            Node {
                position: Vec3::new(0.1, 1.0, -0.0),
                radius: 0.15,
                parent: Some(0),
            },
            Node {
                position: Vec3::new(0.123_456_79, 2.0, 1e-7),
                radius: 0.1,
                parent: Some(1),
            },
        ],
        leaves: vec![Leaf {
            branch: 2,
            t: 1.0 / 3.0,
            offset: Vec3::new(0.1, 0.0, 0.0),
            width: 0.05,
            height: 0.1,
            orientation: Quat::from_rotation_z(0.3).normalize(),
            material: 0,
        }],
        materials: Materials {
            bark: Bark {
                color: [0.3, 0.2, 0.1, 1.0],
                texture: Some(leaf_texture.clone()),
            },
            leaves: vec![LeafMaterial {
                name: "round".into(),
                color: [1.0, 0.9, 0.8, 1.0],
                texture: Some(leaf_texture),
            }],
        },
        ground_truth: Some(GroundTruth {
            orders: vec![1, 1, 2],
            groups: vec![
                GroundTruthGroup {
                    chains: vec![1],
                    pattern: BranchingPattern::Alternate,
                },
                GroundTruthGroup {
                    chains: vec![2],
                    pattern: BranchingPattern::Alternate,
                },
            ],
        }),
    };
    Tree::new(parts, &Limits::default()).unwrap()
}

#[test]
fn round_trips_exactly() {
    let tree = sample_tree();
    let bytes = to_vec(&tree);
    let back = from_slice(&bytes, &Limits::default()).unwrap();
    assert_eq!(back, tree);
    // Bit-exact floats, including the signed zero.
    assert_eq!(
        back.skeleton().node(1).position.z.to_bits(),
        (-0.0f32).to_bits()
    );
    // Writing again gives the same bytes.
    assert_eq!(to_vec(&back), bytes);
    let pretty = to_vec_pretty(&tree);
    assert_eq!(from_slice(&pretty, &Limits::default()).unwrap(), tree);
}

#[test]
fn textures_are_data_uris() {
    let text = String::from_utf8(to_vec(&sample_tree())).unwrap();
    assert!(text.contains("\"texture\":\"data:image/png;base64,iVBORw0KGgo"));
    assert!(text.starts_with("{\"format\":\"treemorph.tree/1\""));
}

#[test]
fn reports_syntax_errors_with_their_position() {
    let err = from_slice(
        b"{\"format\": \"treemorph.tree/1\",\n \"nodes\": [}",
        &Limits::default(),
    )
    .unwrap_err();
    assert!(
        matches!(err, FormatError::Syntax { line: 2, .. }),
        "{err:?}"
    );
}

#[test]
fn refuses_unknown_fields() {
    let doc = br#"{"format":"treemorph.tree/1","nodes":[{"position":[0,0,0],"radius":1,"parent":null,"radiu":2}]}"#;
    let err = from_slice(doc, &Limits::default()).unwrap_err();
    let FormatError::Syntax { message, .. } = err else {
        panic!("{err:?}")
    };
    assert!(message.contains("unknown field `radiu`"), "{message}");
}

#[test]
fn refuses_other_format_versions_even_with_new_fields() {
    let doc = br#"{"format":"treemorph.tree/2","nodes":[],"wind":1}"#;
    assert_eq!(
        from_slice(doc, &Limits::default()),
        Err(FormatError::UnsupportedFormat {
            found: "treemorph.tree/2".into()
        })
    );
    let doc = br#"{"format":"x","nodes":[]}"#;
    assert!(matches!(
        from_slice(doc, &Limits::default()),
        Err(FormatError::UnsupportedFormat { .. })
    ));
}

#[test]
fn reports_huge_indices_precisely() {
    let doc = br#"{"format":"treemorph.tree/1","nodes":[{"position":[0,0,0],"radius":1,"parent":null},{"position":[0,1,0],"radius":1,"parent":1099511627776}]}"#;
    assert_eq!(
        from_slice(doc, &Limits::default()),
        Err(FormatError::Invalid(InvalidTree::DanglingParent {
            node: 1,
            parent: 1 << 40,
            count: 2
        }))
    );
}

#[test]
fn refuses_bad_textures() {
    let mut text = String::from_utf8(to_vec(&sample_tree())).unwrap();
    text = text.replacen(
        "data:image/png;base64,iVBOR",
        "data:image/png;base64,!!!",
        1,
    );
    let err = from_slice(text.as_bytes(), &Limits::default()).unwrap_err();
    assert!(
        matches!(&err, FormatError::Invalid(InvalidTree::InvalidTexture { material, reason })
            if material == "bark" && reason.contains("base64")),
        "{err:?}"
    );
    let mut text = String::from_utf8(to_vec(&sample_tree())).unwrap();
    text = text.replacen("data:image/png;base64,", "https://example.com/a.png#", 1);
    let err = from_slice(text.as_bytes(), &Limits::default()).unwrap_err();
    assert!(
        matches!(&err, FormatError::Invalid(InvalidTree::InvalidTexture { reason, .. })
            if reason.contains("data:image/png;base64,")),
        "{err:?}"
    );
}

#[test]
fn applies_limits_before_building() {
    let bytes = to_vec(&sample_tree());
    assert_eq!(
        from_slice(&bytes, &Limits::with_sizes(2, 10)),
        Err(FormatError::Invalid(InvalidTree::TooLarge {
            kind: SizeKind::Nodes,
            count: 3,
            limit: 2
        }))
    );
}

#[test]
fn minimal_documents_get_defaults() {
    let doc = br#"{"format":"treemorph.tree/1","nodes":[{"position":[0,0,0],"radius":0.1,"parent":null},{"position":[0,1,0],"radius":0.1,"parent":0}]}"#;
    let tree = from_slice(doc, &Limits::default()).unwrap();
    assert_eq!(tree.name(), "");
    assert_eq!(tree.materials().bark, Bark::default());
    assert!(tree.leaves().is_empty());
}
