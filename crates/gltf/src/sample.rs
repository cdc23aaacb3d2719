//! A deterministic synthetic tree for tests, examples and benchmarks.
//!
//! [`sample_tree`] grows chains breadth-first from a trunk — each chain a
//! few tapering branches, each chain node (after the first) starting a
//! lateral chain at a golden-angle spiral — until the requested number of
//! branches exists, then puts two leaves on every thin branch. It is not
//! botanical (`treemorph-generate` makes real trees); it only has the shapes
//! the mesh and export code must handle: junctions, tapering, many strands,
//! leaves with a textured material and a textured bark.

use std::collections::VecDeque;

use glam::{Quat, Vec3};
use treemorph_tree::{
    Bark, Leaf, LeafMaterial, Limits, Materials, Node, NodeId, RgbaImage, Texture, Tree, TreeParts,
};

/// Branches per chain.
const CHAIN_BRANCHES: usize = 5;
/// Radius of the trunk at the root, metres.
const ROOT_RADIUS: f32 = 0.25;

/// A small xorshift generator: deterministic, dependency-free.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in [-1, 1).
    fn signed(&mut self) -> f32 {
        self.next() * 2.0 - 1.0
    }
}

struct Seed {
    parent: NodeId,
    direction: Vec3,
    length: f32,
    radius: f32,
}

/// A tree with exactly `branches` branches (at least 1), two leaves on each
/// branch thinner than 3 cm, a textured leaf material and a textured bark.
pub fn sample_tree(branches: usize) -> Tree {
    let branches = branches.max(1);
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let mut nodes = vec![Node {
        position: Vec3::ZERO,
        radius: ROOT_RADIUS,
        parent: None,
    }];
    let mut queue = VecDeque::from([Seed {
        parent: 0,
        direction: Vec3::Y,
        length: 1.2,
        radius: ROOT_RADIUS,
    }]);
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let mut spiral = 0.0f32;
    while let Some(seed) = queue.pop_front() {
        let mut at = seed.parent;
        let mut direction = seed.direction;
        for i in 0..CHAIN_BRANCHES {
            if nodes.len() > branches {
                return finish(nodes, &mut rng);
            }
            let f = (i + 1) as f32 / CHAIN_BRANCHES as f32;
            let jitter = Vec3::new(rng.signed(), rng.signed() * 0.3, rng.signed()) * 0.15;
            direction = (direction + jitter + Vec3::Y * 0.05).normalize();
            let position = nodes[at as usize].position + direction * seed.length;
            let radius = (seed.radius * (1.0 - 0.6 * f)).max(0.002);
            nodes.push(Node {
                position,
                radius,
                parent: Some(at),
            });
            at = (nodes.len() - 1) as NodeId;
            if i + 1 < CHAIN_BRANCHES {
                spiral += golden;
                let side =
                    Quat::from_axis_angle(direction, spiral) * direction.any_orthonormal_vector();
                queue.push_back(Seed {
                    parent: at,
                    direction: (direction * 0.5 + side).normalize(),
                    length: seed.length * 0.72,
                    radius: radius * 0.6,
                });
            }
        }
    }
    finish(nodes, &mut rng)
}

fn finish(nodes: Vec<Node>, rng: &mut Rng) -> Tree {
    let mut leaves = Vec::new();
    for (id, node) in nodes.iter().enumerate().skip(1) {
        if node.radius >= 0.03 {
            continue;
        }
        let parent = &nodes[node.parent.unwrap_or(0) as usize];
        let axis = (node.position - parent.position).normalize_or(Vec3::Y);
        for k in 0..2 {
            let around =
                Quat::from_axis_angle(axis, std::f32::consts::PI * k as f32 + rng.signed());
            let out = around * axis.any_orthonormal_vector();
            let t = 0.3 + 0.5 * rng.next();
            let radius = parent.radius + (node.radius - parent.radius) * t;
            let blade = (out + axis * 0.5 + Vec3::Y * 0.2).normalize();
            let orientation = Quat::from_rotation_arc(Vec3::Y, blade)
                * Quat::from_rotation_y(rng.signed() * std::f32::consts::PI);
            leaves.push(Leaf {
                branch: id as NodeId,
                t,
                offset: out * radius,
                width: 0.06 + 0.02 * rng.next(),
                height: 0.09 + 0.03 * rng.next(),
                orientation: orientation.normalize(),
                material: 0,
            });
        }
    }
    let parts = TreeParts {
        name: "sample".into(),
        nodes,
        leaves,
        materials: Materials {
            bark: Bark {
                color: [0.35, 0.25, 0.18, 1.0],
                texture: Some(bark_texture()),
            },
            leaves: vec![LeafMaterial {
                name: "ovate".into(),
                color: [1.0, 1.0, 1.0, 1.0],
                texture: Some(leaf_texture()),
            }],
        },
        ground_truth: None,
    };
    Tree::new(parts, &Limits::default()).expect("the sample tree is valid by construction")
}

/// A 32×32 ovate blade: opaque green inside an ellipse, transparent outside.
/// Drawn upright like every leaf image: the base is the bottom row.
pub fn leaf_texture() -> Texture {
    let n = 32u32;
    let mut pixels = Vec::with_capacity((n * n * 4) as usize);
    for y in 0..n {
        for x in 0..n {
            let u = (x as f32 + 0.5) / n as f32 * 2.0 - 1.0;
            let v = (y as f32 + 0.5) / n as f32 * 2.0 - 1.0;
            let inside = u * u + v * v * 0.9 < 0.9;
            let shade = (120.0 + 60.0 * (1.0 - v.abs())) as u8;
            pixels.extend_from_slice(&[40, shade, 30, if inside { 255 } else { 0 }]);
        }
    }
    Texture::from_rgba(&RgbaImage::new(n, n, pixels).expect("buffer size matches"))
}

/// A 16×16 grey-brown bark pattern with vertical furrows.
pub fn bark_texture() -> Texture {
    let n = 16u32;
    let mut pixels = Vec::with_capacity((n * n * 4) as usize);
    for y in 0..n {
        for x in 0..n {
            let furrow = if x.is_multiple_of(4) { 40 } else { 0 };
            let grain = ((x * 7 + y * 3) % 5 * 6) as u8;
            pixels.extend_from_slice(&[
                150 - furrow + grain,
                120 - furrow + grain,
                100 - furrow,
                255,
            ]);
        }
    }
    Texture::from_rgba(&RgbaImage::new(n, n, pixels).expect("buffer size matches"))
}
