//! Closed lobe shapes: the 3D convex hull (quickhull), the tighter radial
//! hull, and the Hausdorff distance between hulls.
//!
//! # Convex hull
//! Hand-written quickhull (Barber, Dobkin & Huhdanpaa 1996) in `f64`: an
//! initial tetrahedron from extreme points, one conflict list per face, and
//! for the farthest conflict point the connected set of faces it sees, whose
//! horizon is re-triangulated to the point. We write it ourselves rather than
//! take `chull`/`quickhull` from crates.io because lobes need precise control
//! of the degenerate cases (a single leaf's blade points are coplanar, a
//! one-leaf lobe is a handful of points) and a tolerance tied to the point
//! set's scale; both crates are small, lightly maintained and panic or return
//! errors on exactly those inputs. Points within `1e-9 × extent` of a face
//! count as inside.
//!
//! A point set that spans no volume (fewer than four non-coplanar points) is
//! **inflated**: every point is replaced by the six vertices of an octahedron
//! of radius `inflate` around it, so the result is always a closed,
//! outward-oriented triangle mesh that contains the input.
//!
//! # Radial hull
//! The tighter option ([`HullKind::Radial`]) is a star-shaped mesh around the
//! points' centroid with a fixed latitude–longitude topology (every radial
//! hull of one resolution has the same triangles, which suits cages). Each
//! vertex first reaches as far as the points whose directions fall in its
//! triangles, weighted by their cone coordinates `μ` towards it; directions
//! no point reaches take the smallest radius of a neighbour that has one (a
//! few rounds, so gaps fill from their rim), and no radius is below the
//! inflation radius. Then containment is enforced: along a direction with
//! cone coordinates `μ` a triangle's surface lies at `1 / Σ μ_i / r_i`, and
//! where that falls short of a point the triangle's smallest radii are
//! raised to the least common level that reaches it. Raising radii never uncovers a point, so one pass makes
//! the mesh contain every point while following concavities the convex hull
//! bridges.

use glam::{DVec3, Mat3, Vec3};
use serde::Serialize;
use treemorph_tree::geom::NONE;

/// A closed triangle mesh around a lobe: outward-facing, counter-clockwise
/// triangles seen from outside. Empty when the lobe has no leaves.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Hull {
    /// Mesh vertices in metres.
    pub vertices: Vec<Vec3>,
    /// Triangles as indices into `vertices`.
    pub triangles: Vec<[u32; 3]>,
}

/// Which closed shape lobes get.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum HullKind {
    /// The 3D convex hull of the lobe's points (the default).
    #[default]
    Convex,
    /// A star-shaped latitude–longitude mesh around the points' centroid,
    /// tighter than the convex hull on concave lobes. `rings` latitude rings
    /// of `segments` vertices plus two poles.
    Radial {
        /// Latitude rings (≥ 1; e.g. 8).
        rings: u16,
        /// Vertices per ring (≥ 3; e.g. 16).
        segments: u16,
    },
}

impl Hull {
    /// Whether the hull has no triangles (an empty lobe).
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// The convex hull of `points`; point sets spanning no volume are
    /// inflated by `inflate` metres first (see the module docs). An empty
    /// slice gives an empty hull.
    pub fn convex(points: &[Vec3], inflate: f32) -> Hull {
        if points.is_empty() {
            return Hull::default();
        }
        let pts: Vec<DVec3> = points.iter().map(|p| p.as_dvec3()).collect();
        if let Some(h) = quickhull(&pts) {
            return h;
        }
        let r = f64::from(inflate.max(1e-6));
        let mut inflated = Vec::with_capacity(pts.len() * 6);
        for &p in &pts {
            for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
                inflated.push(p + axis * r);
                inflated.push(p - axis * r);
            }
        }
        quickhull(&inflated).unwrap_or_default()
    }

    /// The radial hull of `points` (see the module docs) with `rings`
    /// latitude rings of `segments` vertices; radii never below `inflate`.
    pub fn radial(points: &[Vec3], inflate: f32, rings: u16, segments: u16) -> Hull {
        if points.is_empty() {
            return Hull::default();
        }
        RadialTemplate::new(rings, segments).hull(points, inflate)
    }

    /// Whether `p` lies inside the hull or within `tolerance` metres of its
    /// surface. Exact for any closed mesh: a point behind every face plane
    /// is inside a convex hull; otherwise the parity of ray crossings
    /// (majority of three generic directions) decides, and points outside
    /// are accepted when their distance to the surface is within
    /// `tolerance`.
    pub fn contains(&self, p: Vec3, tolerance: f32) -> bool {
        if self.is_empty() {
            return false;
        }
        let tri = |t: &[u32; 3]| t.map(|i| self.vertices[i as usize]);
        let behind_all = self.triangles.iter().all(|t| {
            let [a, b, c] = tri(t);
            (b - a).cross(c - a).normalize_or_zero().dot(p - a) <= tolerance
        });
        if behind_all {
            return true;
        }
        let dirs = [
            Vec3::new(0.573_1, 0.618_4, 0.537_9).normalize(),
            Vec3::new(-0.311_7, 0.871_2, -0.379_3).normalize(),
            Vec3::new(0.137_3, -0.412_9, 0.900_3).normalize(),
        ];
        let inside_votes = dirs
            .iter()
            .filter(|&&d| {
                self.triangles
                    .iter()
                    .filter(|t| {
                        let [a, b, c] = tri(t);
                        ray_triangle(p, d, a, b, c).is_some()
                    })
                    .count()
                    % 2
                    == 1
            })
            .count();
        if inside_votes >= 2 {
            return true;
        }
        self.triangles.iter().any(|t| {
            let [a, b, c] = tri(t);
            closest_on_triangle(p, a, b, c).distance(p) <= tolerance
        })
    }

    /// Volume enclosed, in cubic metres (divergence theorem; 0 when empty).
    pub fn volume(&self) -> f32 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// Symmetric Hausdorff distance between the two hulls' vertex sets, in
    /// metres: the largest distance from a vertex of either hull to the
    /// nearest vertex of the other. 0 when both are empty, infinite when
    /// exactly one is. Uses a kd-tree (kiddo) when both sets are large.
    pub fn hausdorff(&self, other: &Hull) -> f32 {
        match (self.vertices.is_empty(), other.vertices.is_empty()) {
            (true, true) => 0.0,
            (true, false) | (false, true) => f32::INFINITY,
            _ => directed_hausdorff(&self.vertices, &other.vertices)
                .max(directed_hausdorff(&other.vertices, &self.vertices)),
        }
    }
}

/// Möller–Trumbore; the ray parameter of a hit strictly ahead, if any.
fn ray_triangle(o: Vec3, d: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Option<f32> {
    let e1 = b - a;
    let e2 = c - a;
    let h = d.cross(e2);
    let det = e1.dot(h);
    if det.abs() < 1e-20 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(h) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0).then_some(t)
}

/// The point of triangle `abc` closest to `p` (Ericson, *Real-Time
/// Collision Detection*, 5.1.5).
pub(crate) fn closest_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// Point-count product above which the Hausdorff distance uses a kd-tree.
const KDTREE_WORK: usize = 64 * 64;

fn directed_hausdorff(from: &[Vec3], to: &[Vec3]) -> f32 {
    if from.len() * to.len() <= KDTREE_WORK || to.len() < 32 {
        return from
            .iter()
            .map(|p| {
                to.iter()
                    .map(|q| p.distance_squared(*q))
                    .fold(f32::INFINITY, f32::min)
            })
            .fold(0.0f32, f32::max)
            .sqrt();
    }
    let pts: Vec<[f32; 3]> = to.iter().map(|p| p.to_array()).collect();
    let tree: kiddo::ImmutableKdTree<f32, 3> = kiddo::ImmutableKdTree::new_from_slice(&pts);
    from.iter()
        .map(|p| {
            tree.nearest_one::<kiddo::SquaredEuclidean>(&p.to_array())
                .distance
        })
        .fold(0.0f32, f32::max)
        .sqrt()
}

// ---------------------------------------------------------------- quickhull

struct Face {
    v: [u32; 3],
    normal: DVec3,
    offset: f64,
    outside: Vec<u32>,
    alive: bool,
    /// Face across edge (v[i], v[(i+1)%3]).
    adj: [u32; 3],
}

impl Face {
    fn new(points: &[DVec3], v: [u32; 3]) -> Face {
        let [a, b, c] = v.map(|i| points[i as usize]);
        let normal = (b - a).cross(c - a).normalize_or_zero();
        Face {
            v,
            normal,
            offset: normal.dot(a),
            outside: Vec::new(),
            alive: true,
            adj: [NONE; 3],
        }
    }

    fn distance(&self, p: DVec3) -> f64 {
        self.normal.dot(p) - self.offset
    }

    fn edge_index(&self, a: u32, b: u32) -> Option<usize> {
        (0..3).find(|&i| self.v[i] == a && self.v[(i + 1) % 3] == b)
    }
}

/// Convex hull of points spanning a volume; `None` when they do not.
fn quickhull(points: &[DVec3]) -> Option<Hull> {
    if points.len() < 4 {
        return None;
    }
    let (mut lo, mut hi) = (points[0], points[0]);
    let mut ext = [0usize; 6];
    for (i, &p) in points.iter().enumerate() {
        for k in 0..3 {
            if p[k] < points[ext[2 * k]][k] {
                ext[2 * k] = i;
            }
            if p[k] > points[ext[2 * k + 1]][k] {
                ext[2 * k + 1] = i;
            }
        }
        lo = lo.min(p);
        hi = hi.max(p);
    }
    let scale = lo.abs().max(hi.abs()).element_sum() + (hi - lo).element_sum();
    let eps = scale.max(1e-30) * 1e-9;

    // Initial simplex: the farthest pair of axis extremes, the point
    // farthest from their line, the point farthest from their plane.
    let (mut i0, mut i1, mut best) = (ext[0], ext[1], -1.0);
    for a in 0..6 {
        for b in a + 1..6 {
            let d = points[ext[a]].distance_squared(points[ext[b]]);
            if d > best {
                best = d;
                i0 = ext[a];
                i1 = ext[b];
            }
        }
    }
    if best.sqrt() <= eps {
        return None;
    }
    let dir = (points[i1] - points[i0]).normalize();
    let (mut i2, mut best) = (0, -1.0);
    for (i, &p) in points.iter().enumerate() {
        let v = p - points[i0];
        let d = (v - dir * v.dot(dir)).length_squared();
        if d > best {
            best = d;
            i2 = i;
        }
    }
    if best.sqrt() <= eps {
        return None;
    }
    let n = (points[i1] - points[i0])
        .cross(points[i2] - points[i0])
        .normalize();
    let (mut i3, mut best) = (0, -1.0);
    for (i, &p) in points.iter().enumerate() {
        let d = n.dot(p - points[i0]).abs();
        if d > best {
            best = d;
            i3 = i;
        }
    }
    if best <= eps {
        return None;
    }
    let [i0, i1, i2, i3] = [i0, i1, i2, i3].map(|i| i as u32);
    // Orient the base so the apex lies behind it.
    let (a, b, c) = if n.dot(points[i3 as usize] - points[i0 as usize]) > 0.0 {
        (i0, i2, i1)
    } else {
        (i0, i1, i2)
    };
    let mut faces = vec![
        Face::new(points, [a, b, c]),
        Face::new(points, [a, i3, b]),
        Face::new(points, [b, i3, c]),
        Face::new(points, [c, i3, a]),
    ];
    link_all(&mut faces);

    for (i, &p) in points.iter().enumerate() {
        let i = i as u32;
        if [i0, i1, i2, i3].contains(&i) {
            continue;
        }
        if let Some(f) = faces.iter_mut().find(|f| f.distance(p) > eps) {
            f.outside.push(i);
        }
    }

    let mut stack: Vec<u32> = (0..faces.len() as u32).collect();
    let mut visible: Vec<u32> = Vec::new();
    let mut horizon: Vec<(u32, u32, u32)> = Vec::new(); // (a, b, face beyond)
    let mut orphans: Vec<u32> = Vec::new();
    let mut visit_mark: Vec<u32> = vec![NONE; faces.len()];
    // Conflict lists of dead faces, reused by new ones (allocation was a
    // third of the hull time on leaf lobes).
    let mut pool: Vec<Vec<u32>> = Vec::new();
    let mut round = 0u32;

    while let Some(fi) = stack.pop() {
        let f = &faces[fi as usize];
        if !f.alive || f.outside.is_empty() {
            continue;
        }
        round += 1;
        let eye = *f
            .outside
            .iter()
            .max_by(|&&x, &&y| {
                f.distance(points[x as usize])
                    .total_cmp(&f.distance(points[y as usize]))
            })
            .expect("non-empty");
        let ep = points[eye as usize];

        // Visible faces: connected region around `fi` seeing the eye.
        visible.clear();
        horizon.clear();
        visible.push(fi);
        visit_mark[fi as usize] = round;
        let mut k = 0;
        while k < visible.len() {
            let cur = visible[k];
            k += 1;
            for e in 0..3 {
                let nb = faces[cur as usize].adj[e];
                if visit_mark[nb as usize] == round {
                    continue;
                }
                if faces[nb as usize].distance(ep) > eps {
                    visit_mark[nb as usize] = round;
                    visible.push(nb);
                }
            }
        }
        // Horizon edges: edges of visible faces whose neighbour is hidden.
        for &vf in &visible {
            let face = &faces[vf as usize];
            for e in 0..3 {
                let nb = face.adj[e];
                if visit_mark[nb as usize] != round || !faces[nb as usize].alive {
                    horizon.push((face.v[e], face.v[(e + 1) % 3], nb));
                }
            }
        }
        orphans.clear();
        for &vf in &visible {
            let face = &mut faces[vf as usize];
            face.alive = false;
            orphans.append(&mut face.outside);
            pool.push(std::mem::take(&mut face.outside));
        }
        let first_new = faces.len() as u32;
        for (j, &(a, b, beyond)) in horizon.iter().enumerate() {
            let id = first_new + j as u32;
            let mut nf = Face::new(points, [a, b, eye]);
            nf.outside = pool.pop().unwrap_or_default();
            nf.adj[0] = beyond;
            // Edge (b, eye) borders the new face whose horizon edge starts at
            // b, edge (eye, a) the one whose horizon edge ends at a.
            let next = horizon.iter().position(|e| e.0 == b).unwrap_or(j);
            let prev = horizon.iter().position(|e| e.1 == a).unwrap_or(j);
            nf.adj[1] = first_new + next as u32;
            nf.adj[2] = first_new + prev as u32;
            faces.push(nf);
            visit_mark.push(0);
            let bf = &mut faces[beyond as usize];
            if let Some(e) = bf.edge_index(b, a) {
                bf.adj[e] = id;
            }
        }
        for &o in &orphans {
            if o == eye {
                continue;
            }
            let p = points[o as usize];
            if let Some(nf) = faces[first_new as usize..]
                .iter_mut()
                .find(|f| f.distance(p) > eps)
            {
                nf.outside.push(o);
            }
        }
        for id in first_new..faces.len() as u32 {
            if !faces[id as usize].outside.is_empty() {
                stack.push(id);
            }
        }
    }

    let mut remap = vec![NONE; points.len()];
    let mut hull = Hull::default();
    for f in faces.iter().filter(|f| f.alive) {
        let tri = f.v.map(|v| {
            let slot = &mut remap[v as usize];
            if *slot == NONE {
                *slot = hull.vertices.len() as u32;
                hull.vertices.push(points[v as usize].as_vec3());
            }
            *slot
        });
        hull.triangles.push(tri);
    }
    Some(hull)
}

/// Links the four faces of the initial tetrahedron through shared edges.
fn link_all(faces: &mut [Face]) {
    for i in 0..faces.len() {
        for e in 0..3 {
            let (a, b) = (faces[i].v[e], faces[i].v[(e + 1) % 3]);
            for j in 0..faces.len() {
                if j != i && faces[j].edge_index(b, a).is_some() {
                    faces[i].adj[e] = j as u32;
                }
            }
        }
    }
}

// ------------------------------------------------------------- radial hull

/// The fixed topology of radial hulls at one resolution, with per-triangle
/// inverse direction matrices for cone coordinates. Build once, reuse for
/// every lobe.
#[derive(Clone, Debug)]
pub(crate) struct RadialTemplate {
    rings: usize,
    segments: usize,
    dirs: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    inverse: Vec<Mat3>,
    neighbours: Vec<Vec<u32>>,
}

impl RadialTemplate {
    pub(crate) fn new(rings: u16, segments: u16) -> RadialTemplate {
        let rings = usize::from(rings.max(1));
        let segments = usize::from(segments.max(3));
        let mut dirs = vec![Vec3::Y];
        for i in 1..=rings {
            let theta = std::f32::consts::PI * i as f32 / (rings + 1) as f32;
            for j in 0..segments {
                let phi = std::f32::consts::TAU * j as f32 / segments as f32;
                dirs.push(Vec3::new(
                    theta.sin() * phi.cos(),
                    theta.cos(),
                    theta.sin() * phi.sin(),
                ));
            }
        }
        dirs.push(-Vec3::Y);
        let south = (dirs.len() - 1) as u32;
        let ring = |i: usize, j: usize| (1 + (i - 1) * segments + j % segments) as u32;
        let mut triangles = Vec::new();
        // Outward orientation: with Y up and φ turning from +X to +Z,
        // (pole, next, this) is counter-clockwise from outside at the north.
        for j in 0..segments {
            triangles.push([0, ring(1, j + 1), ring(1, j)]);
        }
        for i in 1..rings {
            for j in 0..segments {
                let (a, b) = (ring(i, j), ring(i, j + 1));
                let (c, d) = (ring(i + 1, j), ring(i + 1, j + 1));
                triangles.push([a, b, d]);
                triangles.push([a, d, c]);
            }
        }
        for j in 0..segments {
            triangles.push([south, ring(rings, j), ring(rings, j + 1)]);
        }
        let inverse = triangles
            .iter()
            .map(|t| {
                Mat3::from_cols(
                    dirs[t[0] as usize],
                    dirs[t[1] as usize],
                    dirs[t[2] as usize],
                )
                .inverse()
            })
            .collect();
        let mut neighbours = vec![Vec::new(); dirs.len()];
        for t in &triangles {
            for k in 0..3 {
                for m in 0..3 {
                    if k != m && !neighbours[t[k] as usize].contains(&t[m]) {
                        neighbours[t[k] as usize].push(t[m]);
                    }
                }
            }
        }
        RadialTemplate {
            rings,
            segments,
            dirs,
            triangles,
            inverse,
            neighbours,
        }
    }

    /// The triangle whose cone holds `d` and `d`'s cone coordinates in it.
    fn locate(&self, d: Vec3) -> (usize, Vec3) {
        let theta = d.y.clamp(-1.0, 1.0).acos();
        let band = (theta / std::f32::consts::PI * (self.rings + 1) as f32) as isize;
        let phi = d.z.atan2(d.x).rem_euclid(std::f32::consts::TAU);
        let col = (phi / std::f32::consts::TAU * self.segments as f32) as isize;
        let mut best = (0, Vec3::ZERO, f32::NEG_INFINITY);
        for db in -1..=1 {
            let b = band + db;
            if b < 0 || b > self.rings as isize {
                continue;
            }
            for dc in -1..=1 {
                let c = (col + dc).rem_euclid(self.segments as isize) as usize;
                for t in self.band_triangles(b as usize, c) {
                    let mu = self.inverse[t] * d;
                    let worst = mu.min_element();
                    if worst > best.2 {
                        best = (t, mu, worst);
                    }
                }
            }
        }
        (best.0, best.1.max(Vec3::ZERO))
    }

    fn band_triangles(&self, band: usize, col: usize) -> std::ops::Range<usize> {
        let s = self.segments;
        if band == 0 {
            col..col + 1
        } else if band == self.rings {
            let start = s + 2 * s * (self.rings - 1);
            start + col..start + col + 1
        } else {
            let start = s + 2 * s * (band - 1) + 2 * col;
            start..start + 2
        }
    }

    pub(crate) fn hull(&self, points: &[Vec3], inflate: f32) -> Hull {
        if points.is_empty() {
            return Hull::default();
        }
        let c = points.iter().copied().sum::<Vec3>() / points.len() as f32;
        // First guess: each vertex as far as the points near its direction
        // reach, weighted by how close to the vertex they are.
        let mut located = Vec::with_capacity(points.len());
        let mut need = vec![0.0f32; self.dirs.len()];
        for &p in points {
            let v = p - c;
            let rho = v.length();
            if rho <= f32::EPSILON * 16.0 {
                continue;
            }
            let (t, mu) = self.locate(v / rho);
            for (k, &vi) in self.triangles[t].iter().enumerate() {
                need[vi as usize] = need[vi as usize].max(rho * mu[k].min(1.0));
            }
            located.push((t, mu, rho));
        }
        let mut radius = need.clone();
        for _ in 0..3 {
            let prev = radius.clone();
            for (v, nb) in self.neighbours.iter().enumerate() {
                if need[v] > 0.0 {
                    continue;
                }
                radius[v] = nb
                    .iter()
                    .map(|&n| prev[n as usize])
                    .filter(|&r| r > 0.0)
                    .fold(f32::INFINITY, f32::min);
                if radius[v].is_infinite() {
                    radius[v] = 0.0;
                }
            }
        }
        let floor = inflate.max(1e-6);
        for r in &mut radius {
            *r = r.max(floor);
        }
        // Containment: the triangle's surface along a direction with cone
        // coordinates μ lies at 1 / Σ(μ_i / r_i); where that falls short of
        // a point, scale the triangle's radii up just enough. Raising radii
        // never uncovers a point handled earlier, so one pass suffices.
        for &(t, mu, rho) in &located {
            let tri = self.triangles[t];
            let inv: f32 = (0..3).map(|k| mu[k] / radius[tri[k] as usize]).sum();
            let reach = 1.0 / inv;
            // 0.1 % slack against rounding.
            let need_rho = rho * 1.001;
            if reach < need_rho {
                // Water-fill: raise the smallest radii to a common level x,
                // the least x that reaches the point (bisection; x = ρΣμ
                // always does).
                let r = tri.map(|v| radius[v as usize]);
                let reaches =
                    |x: f32| (0..3).map(|k| mu[k] / r[k].max(x)).sum::<f32>() * need_rho <= 1.0;
                let (mut lo, mut hi) = (0.0f32, need_rho * mu.element_sum().max(1.0));
                for _ in 0..24 {
                    let mid = 0.5 * (lo + hi);
                    if reaches(mid) {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                for &vi in &tri {
                    radius[vi as usize] = radius[vi as usize].max(hi);
                }
            }
        }
        Hull {
            vertices: self
                .dirs
                .iter()
                .zip(&radius)
                .map(|(d, &r)| c + *d * r)
                .collect(),
            triangles: self.triangles.clone(),
        }
    }
}

#[cfg(test)]
#[path = "hull_tests.rs"]
mod tests;
