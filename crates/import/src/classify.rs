//! Telling foliage from wood, one primitive at a time.
//!
//! Rules, first match wins:
//! 1. the material, mesh or node name matches a
//!    [`wood_materials`](crate::ImportOptions::wood_materials) pattern → wood;
//! 2. it matches a [`leaf_materials`](crate::ImportOptions::leaf_materials)
//!    pattern → leaves;
//! 3. the material's `alphaMode` is `MASK` or `BLEND` → leaves;
//! 4. the base colour texture is a cut-out: between [`MIN_CUTOUT`] and
//!    [`MAX_CUTOUT`] of its pixels have alpha below one half → leaves (bark
//!    textures are opaque);
//! 5. the geometry is many small, flat, disconnected pieces: at least
//!    [`MIN_PIECES`] connected components with a median of at most
//!    [`MAX_PIECE_TRIANGLES`] triangles each (a quad is 2), four in five of
//!    them planar → leaves. (Flatness matters: coarse tube soups have
//!    pieces of 6 triangles too.)
//! 6. otherwise → wood.

use crate::mesh::UnionFind;
use crate::options::{ImportOptions, name_matches};
use crate::read::{AlphaMode, Document, ImageCache, Primitive};

/// Smallest fraction of transparent pixels of a cut-out texture.
pub const MIN_CUTOUT: f32 = 0.05;
/// Largest fraction of transparent pixels of a cut-out texture.
pub const MAX_CUTOUT: f32 = 0.97;
/// Fewest connected pieces for rule 5.
pub const MIN_PIECES: usize = 8;
/// Largest median triangle count per piece for rule 5.
pub const MAX_PIECE_TRIANGLES: usize = 8;

/// What a primitive is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {
    Wood,
    Leaves,
}

/// Classifies every primitive of `doc`.
pub(crate) fn classify(
    doc: &Document,
    options: &ImportOptions,
    images: &mut ImageCache,
    warnings: &mut Vec<String>,
) -> Vec<Kind> {
    let mut cutout: Vec<Option<bool>> = vec![None; doc.images.len()];
    doc.primitives
        .iter()
        .map(|p| {
            let material = p.material.map(|m| &doc.materials[m]);
            let names = [
                material.map_or("", |m| m.name.as_str()),
                p.mesh_name.as_str(),
                p.node_name.as_str(),
            ];
            let matches = |patterns: &[String]| {
                patterns
                    .iter()
                    .any(|pat| names.iter().any(|n| name_matches(pat, n)))
            };
            if matches(&options.wood_materials) {
                return Kind::Wood;
            }
            if matches(&options.leaf_materials) {
                return Kind::Leaves;
            }
            if let Some(m) = material {
                if m.alpha != AlphaMode::Opaque {
                    return Kind::Leaves;
                }
                if let Some(i) = m.image {
                    let is_cutout = *cutout[i].get_or_insert_with(|| {
                        images
                            .get(doc, i, options.max_texture_side, warnings)
                            .is_some_and(|(_, rgba)| {
                                let n = (rgba.width * rgba.height) as usize;
                                let clear =
                                    rgba.pixels.chunks_exact(4).filter(|c| c[3] < 128).count();
                                let f = clear as f32 / n.max(1) as f32;
                                (MIN_CUTOUT..=MAX_CUTOUT).contains(&f)
                            })
                    });
                    if is_cutout {
                        return Kind::Leaves;
                    }
                }
            }
            if many_small_pieces(p) {
                Kind::Leaves
            } else {
                Kind::Wood
            }
        })
        .collect()
}

fn many_small_pieces(p: &Primitive) -> bool {
    if p.triangles.len() < MIN_PIECES {
        return false;
    }
    let mut uf = UnionFind::new(p.positions.len());
    for t in &p.triangles {
        uf.union(t[0], t[1]);
        uf.union(t[1], t[2]);
    }
    let (label, k) = uf.labels();
    let mut counts = vec![0usize; k];
    for t in &p.triangles {
        counts[label[t[0] as usize] as usize] += 1;
    }
    counts.retain(|&c| c > 0);
    if counts.len() < MIN_PIECES {
        return false;
    }
    let mut sorted = counts.clone();
    let mid = sorted.len() / 2;
    if *sorted.select_nth_unstable(mid).1 > MAX_PIECE_TRIANGLES {
        return false;
    }
    // Blades are flat; tubes, however coarse, are not. Check a sample of
    // pieces against the plane of their first triangle.
    let mut first_triangle: Vec<Option<[u32; 3]>> = vec![None; k];
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); k];
    for t in &p.triangles {
        let l = label[t[0] as usize] as usize;
        first_triangle[l].get_or_insert(*t);
    }
    let step = (k / 64).max(1);
    for (v, &l) in label.iter().enumerate() {
        if (l as usize).is_multiple_of(step) {
            members[l as usize].push(v as u32);
        }
    }
    let (mut flat, mut checked) = (0usize, 0usize);
    for l in (0..k).step_by(step) {
        let Some(t) = first_triangle[l] else { continue };
        let [a, b, c] = t.map(|v| p.positions[v as usize]);
        let Some(n) = (b - a).cross(c - a).try_normalize() else {
            continue;
        };
        let size = members[l]
            .iter()
            .map(|&v| p.positions[v as usize].distance(a))
            .fold(0.0f32, f32::max);
        let off = members[l]
            .iter()
            .map(|&v| (p.positions[v as usize] - a).dot(n).abs())
            .fold(0.0f32, f32::max);
        checked += 1;
        if off <= 1e-3 * size {
            flat += 1;
        }
    }
    checked > 0 && flat * 5 >= checked * 4
}
