//! Leaf primitives → billboard leaves (the papers' septuple, before they are
//! attached to a branch).
//!
//! Each connected component of a leaf primitive (connected through shared
//! vertex indices, so leaves that merely touch stay apart) is one blade.
//! Components whose centres lie within [`MERGE_DISTANCE`] of the smaller
//! one's size (twice its largest vertex distance from its centre) and whose
//! sizes and areas agree within [`MERGE_SIZE_RATIO`]
//! are one leaf drawn as crossed or double-sided quads; the largest of them
//! defines it. The copies of a crossed billboard are exact copies, so the
//! thresholds are tight: generated willows hang distinct leaves from one
//! node whose centres are 1 % of a leaf apart and whose sizes differ by 1 %.
//!
//! The blade frame comes from the texture coordinates: a least-squares
//! affine map `p = o + A·u + B·v` is fitted to the component's vertices; `A`
//! is the blade's `x` axis and `−B` its base-to-tip `y` axis (leaf images
//! are upright and glTF's `v = 1` is the image's bottom row, the blade's
//! base). Width and height are `|A|` and `|B|` times the UV rectangle the
//! component uses, and the anchor is the middle of that rectangle's bottom
//! edge. A component that uses only part of its texture (an atlas) gets a
//! material whose texture is cropped to that rectangle. Without usable
//! texture coordinates the frame comes from the principal axes (the longest
//! is the blade) and the base is decided later: the end nearer the skeleton.
//!
//! Components with (nearly) zero area are skipped and counted in
//! [`ImportReport::skipped_leaves`](crate::ImportReport::skipped_leaves).

use std::sync::Arc;

use glam::{Mat3, Quat, Vec2, Vec3};
use treemorph_tree::geom::NONE;
use treemorph_tree::{LeafMaterial, RgbaImage, Texture};

use crate::mesh::{FxMap, UnionFind, triangle_area};
use crate::options::ImportOptions;
use crate::read::{Document, ImageCache, Primitive};

/// Centres closer than this fraction of the smaller component's size make
/// one leaf.
pub const MERGE_DISTANCE: f32 = 0.005;
/// Largest ratio of the sizes (bounding-box diagonals) and of the areas of
/// components that make one leaf: the quads of one crossed or double-sided
/// leaf are copies of each other.
pub const MERGE_SIZE_RATIO: f32 = 1.002;
/// Components with less area than this fraction of the squared size of the
/// primitive's median component are zero-area leaves.
const MIN_RELATIVE_AREA: f32 = 1e-6;
/// UV rectangles this close to the unit square use the whole texture.
const FULL_RECT_TOLERANCE: f32 = 0.02;

/// A leaf before attachment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct LeafGeometry {
    /// Blade base (anchor), world space.
    pub anchor: Vec3,
    pub width: f32,
    pub height: f32,
    pub orientation: Quat,
    /// Index into the materials returned alongside.
    pub material: u32,
    /// The frame came from principal axes: the blade may point either way
    /// along its `y` axis; the attachment picks the end nearer the skeleton.
    pub base_unknown: bool,
}

impl LeafGeometry {
    /// The same blade seen from its other end.
    pub(crate) fn flipped(&self) -> LeafGeometry {
        let tip = self.anchor + self.orientation * Vec3::Y * self.height;
        LeafGeometry {
            anchor: tip,
            orientation: (self.orientation * Quat::from_rotation_z(std::f32::consts::PI))
                .normalize(),
            ..*self
        }
    }
}

/// The leaves of all leaf primitives and their materials.
pub(crate) struct Leaves {
    pub leaves: Vec<LeafGeometry>,
    pub materials: Vec<LeafMaterial>,
    pub skipped: usize,
}

struct Component {
    /// Original vertex ids.
    vertices: Vec<u32>,
    area: f32,
    centre: Vec3,
    size: f32,
}

/// Extracts the leaves of the primitives `prims` of `doc`.
pub(crate) fn extract(
    doc: &Document,
    prims: &[&Primitive],
    options: &ImportOptions,
    images: &mut ImageCache,
    warnings: &mut Vec<String>,
) -> Leaves {
    let max_materials = options.limits().max_leaf_materials;
    let mut out = Leaves {
        leaves: Vec::new(),
        materials: Vec::new(),
        skipped: 0,
    };
    // (glTF material or none, quantised UV rectangle or none) → material.
    let mut material_ids: FxMap<(u32, [i32; 4]), u32> = FxMap::default();
    let mut no_uv_leaves = 0usize;
    for prim in prims {
        let comps = components(prim);
        if comps.is_empty() {
            continue;
        }
        let mut sizes: Vec<f32> = comps.iter().map(|c| c.size).collect();
        let mid = sizes.len() / 2;
        let median = *sizes.select_nth_unstable_by(mid, f32::total_cmp).1;
        let min_area = MIN_RELATIVE_AREA * median * median;
        let groups = merge(&comps);
        for group in groups {
            let primary = &comps[group];
            if !(primary.area > min_area && primary.area > 0.0) {
                out.skipped += 1;
                continue;
            }
            let fitted = prim
                .uvs
                .as_ref()
                .and_then(|uvs| fit_uv(prim, uvs, &primary.vertices));
            let (geometry, rect) = match fitted {
                Some(f) => f,
                None => {
                    no_uv_leaves += 1;
                    match fit_pca(prim, &primary.vertices) {
                        Some(g) => (g, None),
                        None => {
                            out.skipped += 1;
                            continue;
                        }
                    }
                }
            };
            let usable = geometry.width > 0.0
                && geometry.height > 0.0
                && geometry.anchor.is_finite()
                && geometry.width.is_finite()
                && geometry.height.is_finite();
            if !usable {
                out.skipped += 1;
                continue;
            }
            let gltf_material = prim.material.map_or(NONE, |m| m as u32);
            let crop = rect.filter(|r| !is_full(r));
            let qkey = crop.map_or([0; 4], |r| r.map(|x| (x * 64.0).round() as i32));
            let next = out.materials.len() as u32;
            let material = if let Some(&id) = material_ids.get(&(gltf_material, qkey)) {
                id
            } else if out.materials.len() >= max_materials {
                // Too many atlas crops: reuse the uncropped material.
                match material_ids.get(&(gltf_material, [0; 4])) {
                    Some(&id) => id,
                    None => {
                        warnings.push(format!(
                            "more than {max_materials} leaf materials; extra atlas crops use the first"
                        ));
                        0
                    }
                }
            } else {
                let m = leaf_material(doc, prim.material, crop, options, images, warnings);
                out.materials.push(m);
                material_ids.insert((gltf_material, qkey), next);
                next
            };
            out.leaves.push(LeafGeometry {
                material,
                ..geometry
            });
        }
    }
    if no_uv_leaves > 0 {
        warnings.push(format!(
            "{no_uv_leaves} leaves have no usable texture coordinates; their frames come from their shapes"
        ));
    }
    if out.skipped > 0 {
        warnings.push(format!(
            "{} leaves with (nearly) zero area were skipped",
            out.skipped
        ));
    }
    out
}

fn is_full(rect: &[f32; 4]) -> bool {
    let [u0, v0, u1, v1] = *rect;
    u0.abs() < FULL_RECT_TOLERANCE
        && v0.abs() < FULL_RECT_TOLERANCE
        && (u1 - 1.0).abs() < FULL_RECT_TOLERANCE
        && (v1 - 1.0).abs() < FULL_RECT_TOLERANCE
}

fn components(prim: &Primitive) -> Vec<Component> {
    let n = prim.positions.len();
    let mut uf = UnionFind::new(n);
    for t in &prim.triangles {
        uf.union(t[0], t[1]);
        uf.union(t[1], t[2]);
    }
    let (label, k) = uf.labels();
    let mut comps: Vec<Component> = (0..k)
        .map(|_| Component {
            vertices: Vec::new(),
            area: 0.0,
            centre: Vec3::ZERO,
            size: 0.0,
        })
        .collect();
    let mut used = vec![false; n];
    for t in &prim.triangles {
        let c = &mut comps[label[t[0] as usize] as usize];
        let a = triangle_area(&prim.positions, *t);
        c.area += a;
        let centroid = t.iter().map(|&v| prim.positions[v as usize]).sum::<Vec3>() / 3.0;
        c.centre += centroid * a;
        for &v in t {
            if !std::mem::replace(&mut used[v as usize], true) {
                c.vertices.push(v);
            }
        }
    }
    comps.retain(|c| !c.vertices.is_empty());
    for c in &mut comps {
        c.centre = if c.area > 0.0 {
            c.centre / c.area
        } else {
            c.vertices
                .iter()
                .map(|&v| prim.positions[v as usize])
                .sum::<Vec3>()
                / c.vertices.len() as f32
        };
        // Twice the largest distance from the centre: unlike a bounding box
        // this does not change when a crossed quad's copy is turned.
        c.size = 2.0
            * c.vertices
                .iter()
                .map(|&v| prim.positions[v as usize].distance(c.centre))
                .fold(0.0f32, f32::max);
    }
    comps
}

/// Groups components that are one leaf; returns the primary (largest-area)
/// component of each group.
fn merge(comps: &[Component]) -> Vec<usize> {
    let mut sizes: Vec<f32> = comps.iter().map(|c| c.size).filter(|s| *s > 0.0).collect();
    if sizes.is_empty() {
        return (0..comps.len()).collect();
    }
    let mid = sizes.len() / 2;
    let cell = (*sizes.select_nth_unstable_by(mid, f32::total_cmp).1 * MERGE_DISTANCE).max(1e-9);
    let key = |p: Vec3| (p / cell).floor().as_ivec3().to_array();
    let mut grid: FxMap<[i32; 3], Vec<u32>> = FxMap::default();
    for (i, c) in comps.iter().enumerate() {
        grid.entry(key(c.centre)).or_default().push(i as u32);
    }
    let mut uf = UnionFind::new(comps.len());
    for (i, c) in comps.iter().enumerate() {
        let k = key(c.centre);
        // Saturating: hostile coordinates put keys at i32::MAX (found by
        // fuzzing). Components larger than the median look further (bounded: a
        // giant component could otherwise scan the whole grid).
        let reach = ((MERGE_DISTANCE * c.size / cell).ceil() as i32).clamp(1, 3);
        for dx in -reach..=reach {
            for dy in -reach..=reach {
                for dz in -reach..=reach {
                    let Some(list) = grid.get(&[
                        k[0].saturating_add(dx),
                        k[1].saturating_add(dy),
                        k[2].saturating_add(dz),
                    ]) else {
                        continue;
                    };
                    for &j in list {
                        let j = j as usize;
                        if j <= i {
                            continue;
                        }
                        let d = &comps[j];
                        let small = c.size.min(d.size);
                        let big = c.size.max(d.size);
                        let area_ratio =
                            c.area.max(d.area) / c.area.min(d.area).max(f32::MIN_POSITIVE);
                        if big <= MERGE_SIZE_RATIO * small
                            && area_ratio <= MERGE_SIZE_RATIO
                            && c.centre.distance(d.centre) <= MERGE_DISTANCE * small
                        {
                            uf.union(i as u32, j as u32);
                        }
                    }
                }
            }
        }
    }
    let (label, k) = uf.labels();
    let mut best: Vec<Option<usize>> = vec![None; k];
    for (i, c) in comps.iter().enumerate() {
        let slot = &mut best[label[i] as usize];
        if slot.is_none_or(|b| comps[b].area < c.area) {
            *slot = Some(i);
        }
    }
    best.into_iter().flatten().collect()
}

/// The blade frame from texture coordinates, and the UV rectangle
/// `[u0, v0, u1, v1]` it uses.
fn fit_uv(
    prim: &Primitive,
    uvs: &[Vec2],
    vertices: &[u32],
) -> Option<(LeafGeometry, Option<[f32; 4]>)> {
    // Normal equations of p ≈ o + A u + B v, centred for conditioning.
    let n = vertices.len() as f32;
    let mu = vertices.iter().map(|&v| uvs[v as usize]).sum::<Vec2>() / n;
    let mp = vertices
        .iter()
        .map(|&v| prim.positions[v as usize])
        .sum::<Vec3>()
        / n;
    let (mut suu, mut suv, mut svv) = (0.0f32, 0.0f32, 0.0f32);
    let (mut sup, mut svp) = (Vec3::ZERO, Vec3::ZERO);
    let (mut lo, mut hi) = (Vec2::splat(f32::MAX), Vec2::splat(f32::MIN));
    for &v in vertices {
        let uv = uvs[v as usize];
        lo = lo.min(uv);
        hi = hi.max(uv);
        let d = uv - mu;
        let p = prim.positions[v as usize] - mp;
        suu += d.x * d.x;
        suv += d.x * d.y;
        svv += d.y * d.y;
        sup += p * d.x;
        svp += p * d.y;
    }
    let det = suu * svv - suv * suv;
    let span = (hi - lo).max_element();
    let conditioned = det > 1e-12 * span.powi(4).max(f32::MIN_POSITIVE);
    if !conditioned || vertices.len() < 3 {
        return None;
    }
    let a = (sup * svv - svp * suv) / det;
    let b = (svp * suu - sup * suv) / det;
    let at = |uv: Vec2| mp + a * (uv.x - mu.x) + b * (uv.y - mu.y);
    let width = a.length() * (hi.x - lo.x);
    let height = b.length() * (hi.y - lo.y);
    let x = a.try_normalize()?;
    let up = -b;
    let y = (up - x * x.dot(up)).try_normalize()?;
    let z = x.cross(y);
    let orientation = Quat::from_mat3(&Mat3::from_cols(x, y, z)).normalize();
    let anchor = at(Vec2::new(0.5 * (lo.x + hi.x), hi.y));
    Some((
        LeafGeometry {
            anchor,
            width,
            height,
            orientation,
            material: 0,
            base_unknown: false,
        },
        Some([lo.x, lo.y, hi.x, hi.y]),
    ))
}

/// The blade frame from principal axes: longest = blade (`y`), second =
/// width (`x`).
fn fit_pca(prim: &Primitive, vertices: &[u32]) -> Option<LeafGeometry> {
    let n = vertices.len() as f32;
    let m = vertices
        .iter()
        .map(|&v| prim.positions[v as usize])
        .sum::<Vec3>()
        / n;
    let mut c = [[0.0f32; 3]; 3];
    for &v in vertices {
        let d = (prim.positions[v as usize] - m).to_array();
        for i in 0..3 {
            for j in 0..3 {
                c[i][j] += d[i] * d[j];
            }
        }
    }
    let cov = Mat3::from_cols_array_2d(&c);
    let y = power_axis(cov, Vec3::Y)?;
    let deflated = cov - Mat3::from_cols(y * y.x, y * y.y, y * y.z) * (cov * y).dot(y);
    let x0 = power_axis(deflated, y.any_orthonormal_vector())
        .unwrap_or_else(|| y.any_orthonormal_vector());
    let x = (x0 - y * y.dot(x0)).try_normalize()?;
    let z = x.cross(y);
    let (mut ylo, mut yhi, mut xlo, mut xhi) = (f32::MAX, f32::MIN, f32::MAX, f32::MIN);
    for &v in vertices {
        let d = prim.positions[v as usize] - m;
        ylo = ylo.min(d.dot(y));
        yhi = yhi.max(d.dot(y));
        xlo = xlo.min(d.dot(x));
        xhi = xhi.max(d.dot(x));
    }
    Some(LeafGeometry {
        anchor: m + y * ylo + x * 0.5 * (xlo + xhi),
        width: xhi - xlo,
        height: yhi - ylo,
        orientation: Quat::from_mat3(&Mat3::from_cols(x, y, z)).normalize(),
        material: 0,
        base_unknown: true,
    })
}

/// Dominant eigenvector of a symmetric 3×3 matrix by power iteration.
fn power_axis(m: Mat3, start: Vec3) -> Option<Vec3> {
    let mut v = (start + Vec3::new(0.1, 0.2, 0.3)).normalize();
    for _ in 0..64 {
        v = (m * v).try_normalize()?;
    }
    Some(v)
}

fn leaf_material(
    doc: &Document,
    material: Option<usize>,
    crop: Option<[f32; 4]>,
    options: &ImportOptions,
    images: &mut ImageCache,
    warnings: &mut Vec<String>,
) -> LeafMaterial {
    let info = material.map(|m| &doc.materials[m]);
    let name = info.map_or_else(
        || "leaf".to_owned(),
        |m| {
            if m.name.is_empty() {
                format!("material {}", material.unwrap_or(0))
            } else {
                m.name.clone()
            }
        },
    );
    let texture = info
        .and_then(|m| m.image)
        .and_then(|i| images.get(doc, i, options.max_texture_side, warnings))
        .map(|(texture, rgba)| match crop {
            Some(rect) => crop_texture(&rgba, rect).unwrap_or(texture),
            None => texture,
        });
    LeafMaterial {
        name,
        color: info.map_or([1.0; 4], |m| m.color),
        texture,
    }
}

/// The part of `image` inside the UV rectangle `[u0, v0, u1, v1]`.
fn crop_texture(image: &Arc<RgbaImage>, rect: [f32; 4]) -> Option<Texture> {
    let [u0, v0, u1, v1] = rect.map(|x| x.clamp(0.0, 1.0));
    let (w, h) = (image.width as f32, image.height as f32);
    let x0 = (u0 * w).floor() as u32;
    let x1 = ((u1 * w).ceil() as u32).min(image.width);
    let y0 = (v0 * h).floor() as u32;
    let y1 = ((v1 * h).ceil() as u32).min(image.height);
    if x1 <= x0 || y1 <= y0 {
        return None;
    }
    let mut pixels = Vec::with_capacity(((x1 - x0) * (y1 - y0) * 4) as usize);
    for y in y0..y1 {
        let row = (y * image.width) as usize * 4;
        pixels.extend_from_slice(&image.pixels[row + x0 as usize * 4..row + x1 as usize * 4]);
    }
    let cropped = RgbaImage::new(x1 - x0, y1 - y0, pixels).ok()?;
    Some(Texture::from_rgba(&cropped))
}

#[cfg(test)]
#[path = "leaves_tests.rs"]
mod tests;
