//! Welded triangle meshes: vertices merged by position, adjacency, edges
//! and connected components — the graph structure every later step walks.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use glam::Vec3;
use treemorph_tree::geom::NONE;

/// A small, fast hasher for integer keys (FxHash's multiply-rotate).
#[derive(Default, Clone, Copy)]
pub(crate) struct FxHasher(u64);

impl Hasher for FxHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }
    fn write_u64(&mut self, x: u64) {
        self.0 = (self.0.rotate_left(5) ^ x).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_u32(&mut self, x: u32) {
        self.write_u64(u64::from(x));
    }
    fn write_usize(&mut self, x: usize) {
        self.write_u64(x as u64);
    }
}

/// A `HashMap` with [`FxHasher`].
pub(crate) type FxMap<K, V> = HashMap<K, V, BuildHasherDefault<FxHasher>>;

/// A triangle mesh whose vertices are unique positions.
#[derive(Clone, Debug, Default)]
pub(crate) struct Mesh {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// Position key: bit patterns, with `-0.0` folded onto `0.0`.
fn key(p: Vec3) -> [u32; 3] {
    p.to_array().map(|c| (c + 0.0).to_bits())
}

impl Mesh {
    /// Merges vertices with identical positions (UV seams, duplicated
    /// normals) and drops triangles that become degenerate. Returns the mesh
    /// and, per input vertex, its welded id.
    pub(crate) fn weld(positions: &[Vec3], triangles: &[[u32; 3]]) -> (Mesh, Vec<u32>) {
        let mut ids: FxMap<[u32; 3], u32> = FxMap::default();
        ids.reserve(positions.len());
        let mut out = Vec::new();
        let remap: Vec<u32> = positions
            .iter()
            .map(|&p| {
                *ids.entry(key(p)).or_insert_with(|| {
                    out.push(p);
                    out.len() as u32 - 1
                })
            })
            .collect();
        let triangles = triangles
            .iter()
            .map(|t| t.map(|v| remap[v as usize]))
            .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
            .collect();
        (
            Mesh {
                positions: out,
                triangles,
            },
            remap,
        )
    }

    /// Number of vertices.
    pub(crate) fn len(&self) -> usize {
        self.positions.len()
    }
}

/// Undirected edges with the number of triangles using each.
pub(crate) struct Edges {
    /// `(a, b)` with `a < b`, sorted.
    pub list: Vec<(u32, u32)>,
    /// Triangles using each edge.
    pub uses: Vec<u32>,
}

impl Edges {
    pub(crate) fn of(mesh: &Mesh) -> Edges {
        let mut keys: Vec<u64> = Vec::with_capacity(mesh.triangles.len() * 3);
        for t in &mesh.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let (a, b) = (a.min(b), a.max(b));
                keys.push((u64::from(a) << 32) | u64::from(b));
            }
        }
        keys.sort_unstable();
        let mut list = Vec::with_capacity(keys.len() / 2);
        let mut uses: Vec<u32> = Vec::with_capacity(keys.len() / 2);
        let mut last = u64::MAX;
        for k in keys {
            if k == last {
                *uses.last_mut().expect("an edge was pushed") += 1;
            } else {
                list.push(((k >> 32) as u32, k as u32));
                uses.push(1);
                last = k;
            }
        }
        Edges { list, uses }
    }
}

/// Compressed adjacency lists.
#[derive(Clone, Debug, Default)]
pub(crate) struct Adjacency {
    offsets: Vec<u32>,
    targets: Vec<u32>,
}

impl Adjacency {
    pub(crate) fn of_edges(n: usize, edges: impl Iterator<Item = (u32, u32)> + Clone) -> Adjacency {
        let mut offsets = vec![0u32; n + 1];
        for (a, b) in edges.clone() {
            offsets[a as usize + 1] += 1;
            offsets[b as usize + 1] += 1;
        }
        for i in 0..n {
            offsets[i + 1] += offsets[i];
        }
        let mut fill = offsets.clone();
        let mut targets = vec![0u32; offsets[n] as usize];
        for (a, b) in edges {
            targets[fill[a as usize] as usize] = b;
            fill[a as usize] += 1;
            targets[fill[b as usize] as usize] = a;
            fill[b as usize] += 1;
        }
        Adjacency { offsets, targets }
    }

    pub(crate) fn neighbours(&self, v: u32) -> &[u32] {
        &self.targets[self.offsets[v as usize] as usize..self.offsets[v as usize + 1] as usize]
    }

    pub(crate) fn len(&self) -> usize {
        self.offsets.len() - 1
    }
}

/// Union-find with path halving.
pub(crate) struct UnionFind {
    parent: Vec<u32>,
}

impl UnionFind {
    pub(crate) fn new(n: usize) -> UnionFind {
        UnionFind {
            parent: (0..n as u32).collect(),
        }
    }

    pub(crate) fn find(&mut self, mut x: u32) -> u32 {
        while self.parent[x as usize] != x {
            let p = self.parent[self.parent[x as usize] as usize];
            self.parent[x as usize] = p;
            x = p;
        }
        x
    }

    pub(crate) fn union(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            // Smaller id wins, so results do not depend on edge order.
            let (lo, hi) = (ra.min(rb), ra.max(rb));
            self.parent[hi as usize] = lo;
        }
    }

    /// Dense component labels `0..k` in order of each component's smallest
    /// element, and `k`.
    pub(crate) fn labels(&mut self) -> (Vec<u32>, usize) {
        let n = self.parent.len();
        let mut label = vec![NONE; n];
        let mut k = 0u32;
        let mut out = vec![0u32; n];
        for i in 0..n as u32 {
            let r = self.find(i);
            if label[r as usize] == NONE {
                label[r as usize] = k;
                k += 1;
            }
            out[i as usize] = label[r as usize];
        }
        (out, k as usize)
    }
}

/// Connected components of a mesh's triangles: a label per vertex (vertices
/// used by no triangle get their own components) and the count.
pub(crate) fn components(mesh: &Mesh) -> (Vec<u32>, usize) {
    let mut uf = UnionFind::new(mesh.len());
    for t in &mesh.triangles {
        uf.union(t[0], t[1]);
        uf.union(t[1], t[2]);
    }
    uf.labels()
}

/// Splits a mesh into one mesh per connected component (components with no
/// triangle are dropped). Returns each part with the original ids of its
/// vertices.
pub(crate) fn split(mesh: &Mesh) -> Vec<(Mesh, Vec<u32>)> {
    let (label, k) = components(mesh);
    let mut local = vec![0u32; mesh.len()];
    let mut parts: Vec<(Mesh, Vec<u32>)> = (0..k).map(|_| (Mesh::default(), Vec::new())).collect();
    for (v, &l) in label.iter().enumerate() {
        let part = &mut parts[l as usize];
        local[v] = part.1.len() as u32;
        part.1.push(v as u32);
        part.0.positions.push(mesh.positions[v]);
    }
    for t in &mesh.triangles {
        let part = &mut parts[label[t[0] as usize] as usize];
        part.0.triangles.push(t.map(|v| local[v as usize]));
    }
    parts.retain(|p| !p.0.triangles.is_empty());
    parts
}

/// Area of a triangle.
pub(crate) fn triangle_area(p: &[Vec3], t: [u32; 3]) -> f32 {
    let [a, b, c] = t.map(|v| p[v as usize]);
    0.5 * (b - a).cross(c - a).length()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weld_merges_equal_positions_and_drops_degenerate_triangles() {
        let p = [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::X, -0.0 * Vec3::ONE];
        let (mesh, remap) = Mesh::weld(&p, &[[0, 1, 2], [2, 3, 1], [0, 4, 1]]);
        assert_eq!(mesh.len(), 3);
        assert_eq!(remap, vec![0, 1, 2, 1, 0]);
        assert_eq!(mesh.triangles, vec![[0, 1, 2]]);
    }

    #[test]
    fn edges_count_uses_and_components_split() {
        let p = vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            Vec3::Z,
            Vec3::ONE * 5.0,
            Vec3::ONE * 6.0,
            Vec3::ONE * 7.0,
        ];
        let mesh = Mesh {
            positions: p,
            triangles: vec![[0, 1, 2], [1, 3, 2], [4, 5, 6]],
        };
        let e = Edges::of(&mesh);
        assert_eq!(e.list.len(), 8);
        let shared = e.list.iter().position(|&x| x == (1, 2)).unwrap();
        assert_eq!(e.uses[shared], 2);
        let parts = split(&mesh);
        assert_eq!(parts.len(), 2);
        assert_eq!(parts[0].1, vec![0, 1, 2, 3]);
        assert_eq!(parts[1].0.triangles, vec![[0, 1, 2]]);
        let adj = Adjacency::of_edges(mesh.len(), e.list.iter().copied());
        assert_eq!(adj.neighbours(1).len(), 3);
    }
}
