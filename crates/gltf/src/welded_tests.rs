use std::collections::HashMap;

use glam::Vec3;
use treemorph_generate::{GenerateOptions, Preset, generate};
use treemorph_tree::{Frame, FrameTopology, Limits, Node, Tree, TreeParts};

use super::*;
use crate::export::{BranchMeshMode, ExportOptions, export_glb};
use crate::sample::sample_tree;

/// Vertex ids merged by exact position (the seam duplicates coincide).
fn weld(mesh: &MeshBuffers) -> Vec<u32> {
    let mut ids = HashMap::new();
    mesh.positions
        .iter()
        .map(|p| {
            let key = p.to_array().map(f32::to_bits);
            let next = ids.len() as u32;
            *ids.entry(key).or_insert(next)
        })
        .collect()
}

/// How many triangles use each undirected welded edge.
fn edge_uses(mesh: &MeshBuffers) -> HashMap<(u32, u32), u32> {
    let w = weld(mesh);
    let mut uses = HashMap::new();
    for t in mesh.indices.chunks_exact(3) {
        for k in 0..3 {
            let (a, b) = (w[t[k] as usize], w[t[(k + 1) % 3] as usize]);
            if a != b {
                *uses.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
    }
    uses
}

fn components(mesh: &MeshBuffers) -> usize {
    let w = weld(mesh);
    let n = w.iter().copied().max().map_or(0, |m| m as usize + 1);
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn find(p: &mut [u32], mut x: u32) -> u32 {
        while p[x as usize] != x {
            p[x as usize] = p[p[x as usize] as usize];
            x = p[x as usize];
        }
        x
    }
    let mut used = vec![false; n];
    for t in mesh.indices.chunks_exact(3) {
        for k in 0..3 {
            let (a, b) = (w[t[k] as usize], w[t[(k + 1) % 3] as usize]);
            used[a as usize] = true;
            let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
            parent[ra as usize] = rb;
        }
    }
    (0..n as u32)
        .filter(|&v| used[v as usize] && find(&mut parent, v) == v)
        .count()
}

/// Six times the enclosed volume: positive when faces point outward.
fn signed_volume(mesh: &MeshBuffers) -> f64 {
    mesh.indices
        .chunks_exact(3)
        .map(|t| {
            let [a, b, c] = [0, 1, 2].map(|k| mesh.positions[t[k] as usize].as_dvec3());
            a.dot(b.cross(c))
        })
        .sum()
}

fn welded(tree: &Tree) -> MeshBuffers {
    let topology = FrameTopology::of_tree(tree);
    let frame = Frame::of_tree(tree);
    welded_branch_mesh(&topology, &frame, &MeshOptions::default()).unwrap()
}

fn assert_watertight(mesh: &MeshBuffers, what: &str) {
    let uses = edge_uses(mesh);
    let bad: Vec<_> = uses.iter().filter(|(_, n)| **n != 2).take(5).collect();
    assert!(
        bad.is_empty(),
        "{what}: edges not shared by two triangles: {bad:?}"
    );
    assert!(mesh.positions.iter().all(|p| p.is_finite()), "{what}");
    assert!(
        mesh.normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-3),
        "{what}: normals must be unit"
    );
    assert!(
        mesh.indices
            .iter()
            .all(|&i| (i as usize) < mesh.positions.len())
    );
    assert_eq!(mesh.groups.len(), 1);
    assert_eq!(mesh.groups[0].index_count as usize, mesh.indices.len());
}

#[test]
fn generated_trees_become_one_watertight_outward_surface() {
    for &preset in Preset::ALL {
        let tree = generate(&GenerateOptions::new(preset, 3).with_size(400)).unwrap();
        let mesh = welded(&tree);
        let what = preset.name();
        assert_watertight(&mesh, what);
        assert_eq!(components(&mesh), 1, "{what}: one connected surface");
        assert!(signed_volume(&mesh) > 0.0, "{what}: faces point outward");
    }
}

#[test]
fn sample_tree_is_welded_and_bounded() {
    let tree = sample_tree(200);
    let mesh = welded(&tree);
    assert_watertight(&mesh, "sample");
    assert_eq!(components(&mesh), 1);
    let mut b = treemorph_tree::Aabb::EMPTY;
    for p in &mesh.positions {
        b = b.with_point(*p);
    }
    assert_eq!(b, mesh.bounds);
}

/// A node with more children than its parent tube has sides: the extra
/// children become separate closed tubes.
#[test]
fn children_without_a_free_sector_become_closed_tubes() {
    let mut nodes = vec![
        Node {
            position: Vec3::ZERO,
            radius: 0.1,
            parent: None,
        },
        Node {
            position: Vec3::Y,
            radius: 0.1,
            parent: Some(0),
        },
        Node {
            position: Vec3::Y * 2.0,
            radius: 0.08,
            parent: Some(1),
        },
    ];
    for k in 0..6 {
        let a = k as f32 * std::f32::consts::TAU / 6.0;
        nodes.push(Node {
            position: Vec3::Y + Vec3::new(a.cos(), 0.6, a.sin()),
            radius: 0.05,
            parent: Some(1),
        });
    }
    let tree = Tree::new(
        TreeParts {
            nodes,
            ..TreeParts::default()
        },
        &Limits::default(),
    )
    .unwrap();
    let topology = FrameTopology::of_tree(&tree);
    let frame = Frame::of_tree(&tree);
    let options = MeshOptions::default().with_sides(4, 4);
    let mesh = welded_branch_mesh(&topology, &frame, &options).unwrap();
    assert_watertight(&mesh, "crowded junction");
    // The trunk has 4 sides: four children weld in, two stand alone (their
    // base caps meet at the junction node, so they touch each other).
    assert_eq!(components(&mesh), 2);
    assert!(signed_volume(&mesh) > 0.0);
}

#[test]
fn export_writes_the_welded_mesh() {
    let tree = generate(&GenerateOptions::new(Preset::Maple, 1).with_size(200)).unwrap();
    let soup = export_glb(&tree, &ExportOptions::default()).unwrap();
    let glb = export_glb(
        &tree,
        &ExportOptions::default().with_branch_mode(BranchMeshMode::Welded),
    )
    .unwrap();
    assert_ne!(soup, glb);
    let doc = gltf::Gltf::from_slice(&glb).unwrap();
    let blob = doc.blob.as_deref().unwrap();
    let mesh = doc.meshes().find(|m| m.name() == Some("branches")).unwrap();
    let primitive = mesh.primitives().next().unwrap();
    let reader = primitive.reader(|_| Some(blob));
    let count = reader.read_positions().unwrap().count();
    assert_eq!(count, welded(&tree).vertex_count());
    let back = crate::read_embedded_tree(&glb, &Limits::default()).unwrap();
    assert_eq!(back.as_ref(), Some(&tree));
}
