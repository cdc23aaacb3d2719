//! Self-adaptive cages (§5.4.1): child cages stretch to cover the parts of
//! their parent cage no child covers.
//!
//! Computed once per plan on the final (t = 1) cages, top-down through the
//! MCT. For an internal cage P (at its final, already adapted position) and
//! its children (at their baseline positions, carried by mean value
//! coordinates):
//!
//! 1. P's boundary is sampled every τ (the coverage threshold, the paper's
//!    10 pixels: [`crate::SketchOptions::coverage_threshold`] × the crown's
//!    screen diagonal). A sample is **covered** (O) when some child cage's
//!    boundary is within τ of it or the sample is inside a child, otherwise
//!    **uncovered** (F).
//! 2. Every F sample within [`crate::SketchOptions::adapt_reach`] of a
//!    child is **owned** by its nearest child; consecutive samples with one
//!    owner form a run. The paper stretches the children matched to the
//!    covered segments on either side of an F segment; on real crowns a
//!    long F segment borders many children (a conifer's whorls all stop
//!    short of the crown's convex outline), and stretching only the two at
//!    its ends tears them across the whole segment. Nearest-child ownership
//!    is the same rule applied to each piece of the segment.
//! 3. A child's **facing section** — the span of its boundary nearest to the
//!    run, widened to at least 3 of its vertices (at most half) so a run
//!    that wraps around one of its corners (a star's spike) pulls a section
//!    and not a single spike — is mapped onto the run by arc-length
//!    parameterisation (the paper's "mappings induced by the screen-space
//!    arc-length parameterisation of the child cage and the F segment"):
//!    both are counter-clockwise and the child is inside, so they run the
//!    same way. Those vertices are constraints at their run positions; the
//!    child's vertices matched to P's boundary (within τ of it) are
//!    constraints where they are — the paper's constraint selection.
//! 4. Each stretched child is deformed by a Laplacian deformation of its
//!    polygon (Eq. 1 with 1/|edge| weights, the polygon analogue of
//!    cotangent weights, hard constraints, rows normalised), its free
//!    vertices softly anchored where they were (weight 0.2 against the
//!    normalised Laplacian rows) so that a child touching P nowhere stretches
//!    rather than slides away and leaves a hole. Its correction from the
//!    baseline is stored; at time t a cage gets `t ×` its correction on top
//!    of its baseline, so t = 0 stays the rest pose.
//!
//! Stretching a cage carries its content along (the children's vertices
//! follow by mean value coordinates), and the next level down covers what
//! the stretch uncovered, so the coverage cascades to the leaf cages and
//! the chains they drive.

use std::collections::BTreeMap;

use glam::Vec2;
use rayon::prelude::*;

use crate::error::SketchError;
use crate::laplacian::{LeastSquares, scratch_for};
use crate::mct::Mct;
use crate::mvc;
use crate::polygon;

/// Laplacian deformation of a closed polygon with hard constraints
/// (`(vertex, target)`); every other vertex is free, softly anchored at
/// rest with weight `anchor` (relative to the normalised Laplacian rows; 0:
/// no anchors). 1/|edge| weights from `rest`. With every vertex constrained
/// the result is the constraints.
pub(crate) fn deform_closed(
    rest: &[Vec2],
    constraints: &BTreeMap<usize, Vec2>,
    anchor: f32,
) -> Result<Vec<Vec2>, SketchError> {
    let n = rest.len();
    let mut out: Vec<Vec2> = rest.to_vec();
    for (&v, &p) in constraints {
        out[v] = p;
    }
    let free: Vec<usize> = (0..n).filter(|v| !constraints.contains_key(v)).collect();
    if free.is_empty() || constraints.is_empty() {
        return Ok(out);
    }
    let mut unknown = vec![usize::MAX; n];
    for (k, &v) in free.iter().enumerate() {
        unknown[v] = k;
    }
    // 1/|edge| weights, edges floored at 1 % of the mean edge so that
    // (near-)coincident vertices do not make the system ill-conditioned.
    let floor = 0.01 * f64::from(polygon::perimeter(rest)) / n as f64;
    let weight =
        |a: usize, b: usize| 1.0 / f64::from(rest[a].distance(rest[b])).max(floor).max(1e-12);
    // Row i: Σ_j w_ij (d_i − d_j) / Σ_j w_ij = 0 in displacement form;
    // known displacements go to the right-hand side.
    let mut entries = Vec::new();
    let mut b = vec![[0.0f64; 2]; n];
    for i in 0..n {
        let nbrs = [(i + n - 1) % n, (i + 1) % n];
        let wsum: f64 = nbrs.iter().map(|&j| weight(i, j)).sum();
        let mut add = |v: usize, coef: f64, b: &mut [f64; 2]| {
            if unknown[v] != usize::MAX {
                entries.push((i, unknown[v], coef));
            } else {
                let d = out[v] - rest[v];
                b[0] -= coef * f64::from(d.x);
                b[1] -= coef * f64::from(d.y);
            }
        };
        add(i, 1.0, &mut b[i]);
        for &j in &nbrs {
            add(j, -weight(i, j) / wsum, &mut b[i]);
        }
    }
    // Soft anchors: every free vertex mildly wants to stay.
    let mut rows = n;
    if anchor > 0.0 {
        for k in 0..free.len() {
            entries.push((rows, k, f64::from(anchor)));
            b.push([0.0; 2]);
            rows += 1;
        }
    }
    let ls = LeastSquares::new(free.len(), rows, &entries)?;
    let mut x = faer::Mat::zeros(0, 0);
    let mut mem = scratch_for([&ls]);
    ls.solve(&b, &mut x, &mut mem);
    for (k, &v) in free.iter().enumerate() {
        out[v] = rest[v] + Vec2::new(x[(k, 0)] as f32, x[(k, 1)] as f32);
    }
    Ok(out)
}

/// Samples a closed polygon every `spacing` (at most `max` samples).
fn sample_boundary(poly: &[Vec2], spacing: f32, max: usize) -> Vec<Vec2> {
    let per = polygon::perimeter(poly);
    let spacing = spacing.max(per / max as f32).max(1e-9);
    let n = poly.len();
    let mut out = Vec::new();
    for i in 0..n {
        let (a, b) = (poly[i], poly[(i + 1) % n]);
        let k = ((a.distance(b) / spacing).ceil() as usize).max(1);
        for s in 0..k {
            out.push(a.lerp(b, s as f32 / k as f32));
        }
    }
    out
}

/// Weight of the soft anchors that keep a stretched child's free vertices
/// near their place, relative to the (normalised) Laplacian rows.
const ANCHOR: f32 = 0.2;

/// Fewest vertices a stretched child moves onto a run (when it has them).
const MIN_PULLED: usize = 3;

/// Stretches `child` so that its side facing the run `run` (a piece of the
/// parent's boundary, counter-clockwise) lies on it; adds the constraints
/// to `out` (first come, first kept).
///
/// The facing side is the span of the run's nearest points on the child,
/// widened to at least [`MIN_PULLED`] vertices (at most half of them) so a
/// run wrapping around one corner of the child still pulls a section of it,
/// not a single spike. Its vertices map onto the run by arc length (the
/// paper's arc-length parameterisation of the child cage and the F
/// segment): the child and the parent are both counter-clockwise and the
/// child is inside, so its facing side runs the same way as the run.
fn pull(child: &[Vec2], parent: &[Vec2], tau: f32, run: &[Vec2], out: &mut BTreeMap<usize, Vec2>) {
    let n = child.len();
    if n < 3 || run.is_empty() {
        return;
    }
    let cum = polygon::cumulative(child, true);
    let per = *cum.last().unwrap_or(&0.0);
    if per <= 0.0 {
        return;
    }
    let wrap = |x: f32| {
        let w = x.rem_euclid(per);
        if w > 0.5 * per { w - per } else { w }
    };
    let centre = polygon::nearest_arc(child, &cum, true, run[run.len() / 2]).0;
    let (mut lo, mut hi) = (0.0f32, 0.0f32);
    for &p in run {
        let o = wrap(polygon::nearest_arc(child, &cum, true, p).0 - centre);
        lo = lo.min(o);
        hi = hi.max(o);
    }
    // Vertex offsets from the centre, and widening to enough vertices.
    let offsets: Vec<f32> = (0..n).map(|v| wrap(cum[v] - centre)).collect();
    let want = MIN_PULLED.min(n / 2).max(1);
    loop {
        let inside = offsets.iter().filter(|&&o| o >= lo && o <= hi).count();
        if inside >= want {
            break;
        }
        let below = offsets
            .iter()
            .copied()
            .filter(|&o| o < lo)
            .fold(f32::NEG_INFINITY, f32::max);
        let above = offsets
            .iter()
            .copied()
            .filter(|&o| o > hi)
            .fold(f32::INFINITY, f32::min);
        if !below.is_finite() && !above.is_finite() {
            break;
        }
        if lo - below <= above - hi {
            lo = below;
        } else {
            hi = above;
        }
    }
    let rcum = polygon::cumulative(run, false);
    let rlen = *rcum.last().unwrap_or(&0.0);
    let span = hi - lo;
    let mut pulled = vec![false; n];
    for v in 0..n {
        let o = offsets[v];
        if o < lo || o > hi {
            continue;
        }
        let f = if span > 0.0 { (o - lo) / span } else { 0.5 };
        pulled[v] = true;
        out.entry(v)
            .or_insert_with(|| polygon::point_at(run, &rcum, false, f * rlen));
    }
    // The paper's constraints: vertices matched to the parent's boundary
    // (within τ of it) stay put; the rest is free, so the Laplacian spreads
    // the stretch over the cage, softly anchored so that a child touching
    // the boundary nowhere stretches rather than slides away.
    let matched: Vec<bool> = (0..n)
        .map(|v| !pulled[v] && polygon::distance_to_boundary(parent, child[v]) <= tau)
        .collect();
    for v in (0..n).filter(|&v| matched[v]) {
        out.entry(v).or_insert(child[v]);
    }
}

/// No child: a sample nobody covers or stretches to.
const NOBODY: usize = usize::MAX;

/// Boundary samples of a parent assigned in one parallel task.
const SAMPLES_PER_TASK: usize = 64;

/// The child of `children` (bounding `boxes`) nearest to `s` and its
/// distance (0 inside it); `(∞, NOBODY)` when there is none.
fn nearest_child(children: &[Vec<Vec2>], boxes: &[(Vec2, Vec2)], s: Vec2) -> (f32, usize) {
    let mut best = (f32::INFINITY, NOBODY);
    for (c, child) in children.iter().enumerate() {
        let (lo, hi) = boxes[c];
        let box_d = (lo - s).max(s - hi).max(Vec2::ZERO).length();
        if box_d >= best.0 || child.len() < 3 {
            continue;
        }
        let d = if polygon::contains(child, s) {
            0.0
        } else {
            polygon::distance_to_boundary(child, s)
        };
        if d < best.0 {
            best = (d, c);
        }
    }
    best
}

/// Stretches `children` (baseline polygons) to cover `parent`'s uncovered
/// segments; returns the new polygon of every child that moved. `reach`
/// bounds how far a child stretches.
pub(crate) fn cover(
    parent: &[Vec2],
    children: &[Vec<Vec2>],
    tau: f32,
    reach: f32,
) -> Result<Vec<Option<Vec<Vec2>>>, SketchError> {
    let mut result = vec![None; children.len()];
    if children.is_empty() || parent.len() < 3 || tau <= 0.0 {
        return Ok(result);
    }
    let samples = sample_boundary(parent, tau, 4096);
    let boxes: Vec<(Vec2, Vec2)> = children
        .iter()
        .map(|c| polygon::bounds(c).unwrap_or((Vec2::ZERO, Vec2::ZERO)))
        .collect();
    // Per sample: the child covering it, or the child that will stretch
    // to it (NOBODY: none). The samples are independent: in parallel.
    let owner: Vec<usize> = samples
        .par_iter()
        .with_min_len(SAMPLES_PER_TASK)
        .map(|&s| {
            let best = nearest_child(children, &boxes, s);
            if best.0 > tau && best.0 <= reach {
                best.1
            } else {
                NOBODY
            }
        })
        .collect();
    let m = samples.len();
    if owner.iter().all(|&o| o == NOBODY) {
        return Ok(result);
    }
    // Runs of consecutive samples with one owner, starting after a break.
    let start = (0..m)
        .find(|&k| owner[k] != owner[(k + m - 1) % m])
        .unwrap_or(0);
    let mut constraints: Vec<BTreeMap<usize, Vec2>> = vec![BTreeMap::new(); children.len()];
    let mut k = 0;
    while k < m {
        let i = (start + k) % m;
        let o = owner[i];
        let mut run = vec![samples[i]];
        k += 1;
        while k < m && owner[(start + k) % m] == o {
            run.push(samples[(start + k) % m]);
            k += 1;
        }
        if o != NOBODY {
            pull(&children[o], parent, tau, &run, &mut constraints[o]);
        }
    }
    for (c, cons) in constraints.iter().enumerate() {
        if cons.iter().any(|(&v, &t)| t != children[c][v]) {
            result[c] = Some(deform_closed(&children[c], cons, ANCHOR)?);
        }
    }
    Ok(result)
}

/// Computes every cage's self-adaptive correction (see the module docs).
/// `crown_delta` is the crown samples' t = 1 displacement; `tau` the
/// coverage threshold in NDC.
///
/// A cage's cover needs only its own final polygon, which its parent's
/// cover fixed: the cages of one depth of the tree are covered in
/// parallel, depth by depth, with the same result as one at a time.
pub(crate) fn adapt(
    mct: &mut Mct,
    crown_delta: &[Vec2],
    tau: f32,
    reach: f32,
) -> Result<(), SketchError> {
    let mut disp = vec![Vec2::ZERO; mct.vertex_count];
    disp[..crown_delta.len()].copy_from_slice(crown_delta);
    for depth in by_depth(mct) {
        for &i in &depth {
            final_displacement(mct, i, &mut disp);
        }
        let covered: Vec<Result<_, SketchError>> = depth
            .par_iter()
            .filter(|&&i| !mct.cages[i].children.is_empty())
            .map(|&i| corrections(mct, i, &disp, tau, reach))
            .collect();
        // In cage order, so a failure names the first cage that failed,
        // as one cage at a time did.
        for corrected in covered {
            for (child, adapt) in corrected? {
                mct.cages[child as usize].adapt = adapt;
            }
        }
    }
    Ok(())
}

/// The cages by their depth in the tree, the crown alone first; in cage
/// order within a depth.
fn by_depth(mct: &Mct) -> Vec<Vec<usize>> {
    let mut depth = vec![0usize; mct.cages.len()];
    let mut levels: Vec<Vec<usize>> = Vec::new();
    for (i, cage) in mct.cages.iter().enumerate() {
        depth[i] = cage.parent.map_or(0, |p| depth[p as usize] + 1);
        if levels.len() <= depth[i] {
            levels.resize_with(depth[i] + 1, Vec::new);
        }
        levels[depth[i]].push(i);
    }
    levels
}

/// Cage `i`'s final displacement into `disp`: its parent's, carried by
/// mean value coordinates, plus its own correction (already known).
fn final_displacement(mct: &Mct, i: usize, disp: &mut [Vec2]) {
    let Some(p) = mct.cages[i].parent else {
        return;
    };
    let (po, m) = (
        mct.cages[p as usize].offset,
        mct.cages[p as usize].rest.len(),
    );
    let cage = &mct.cages[i];
    for (v, row) in cage.weights.chunks_exact(m).enumerate() {
        let mut d = mvc::apply(row, &disp[po..po + m]);
        if !cage.adapt.is_empty() {
            d += cage.adapt[v];
        }
        disp[cage.offset + v] = d;
    }
}

/// The corrections of cage `i`'s children that stretch to cover it: per
/// child that moved, its new polygon less its baseline.
fn corrections(
    mct: &Mct,
    i: usize,
    disp: &[Vec2],
    tau: f32,
    reach: f32,
) -> Result<Vec<(u32, Vec<Vec2>)>, SketchError> {
    let cage = &mct.cages[i];
    let m = cage.rest.len();
    let parent_disp = &disp[cage.offset..cage.offset + m];
    let final_poly: Vec<Vec2> = cage
        .rest
        .iter()
        .zip(parent_disp)
        .map(|(&r, &d)| r + d)
        .collect();
    let baselines: Vec<Vec<Vec2>> = cage
        .children
        .iter()
        .map(|&c| {
            let child = &mct.cages[c as usize];
            child
                .weights
                .chunks_exact(m)
                .zip(&child.rest)
                .map(|(row, &r)| r + mvc::apply(row, parent_disp))
                .collect()
        })
        .collect();
    let covered = cover(&final_poly, &baselines, tau, reach)?;
    Ok(cage
        .children
        .iter()
        .zip(&baselines)
        .zip(covered)
        .filter_map(|((&c, base), new)| {
            Some((c, new?.iter().zip(base).map(|(&n, &b)| n - b).collect()))
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn circle(n: usize, r: f32, c: Vec2) -> Vec<Vec2> {
        (0..n)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / n as f32;
                c + Vec2::new(a.cos(), a.sin()) * r
            })
            .collect()
    }

    #[test]
    fn laplacian_with_every_vertex_constrained_is_the_constraints() {
        let rest = circle(9, 1.0, Vec2::ZERO);
        let targets: BTreeMap<usize, Vec2> = (0..9)
            .map(|i| (i, Vec2::new(i as f32 * 0.37 - 1.0, (i * i) as f32 * 0.1)))
            .collect();
        let out = deform_closed(&rest, &targets, 0.0).unwrap();
        for (i, p) in out.iter().enumerate() {
            assert_eq!(*p, targets[&i]);
        }
    }

    /// Regression: corners a hair apart (inflated single-leaf lobes) made
    /// 1/|edge| weights explode and sent a free vertex thousands of units
    /// away (maple × heart).
    #[test]
    fn near_coincident_corners_stay_bounded() {
        let child = vec![
            Vec2::new(0.10245742, -0.13126667),
            Vec2::new(0.14983615, -0.13649064),
            Vec2::new(0.14983618, -0.13649064),
            Vec2::new(0.14983615, -0.13649064),
            Vec2::new(0.14856097, -0.11597657),
            Vec2::new(0.12815706, -0.10087104),
        ];
        let target = Vec2::new(0.13189104, -0.0678477);
        let c: BTreeMap<usize, Vec2> = [(1, child[1]), (3, target), (4, target), (5, target)]
            .into_iter()
            .collect();
        for anchor in [0.0, ANCHOR] {
            let out = deform_closed(&child, &c, anchor).unwrap();
            for p in &out {
                assert!(p.distance(child[0]) < 0.2, "{p:?}");
            }
        }
    }

    #[test]
    fn laplacian_translation_is_reproduced() {
        // Constraining two vertices to a common translation moves the rest
        // rigidly with them (the Laplacian of a translation is zero).
        let rest = circle(12, 1.0, Vec2::ZERO);
        let t = Vec2::new(0.4, -0.3);
        let c: BTreeMap<usize, Vec2> = [(0, rest[0] + t), (6, rest[6] + t)].into_iter().collect();
        let out = deform_closed(&rest, &c, 0.0).unwrap();
        for (p, r) in out.iter().zip(&rest) {
            assert!((*p - *r - t).length() < 1e-5);
        }
    }

    #[test]
    fn children_stretch_over_an_uncovered_side() {
        // Parent: a big square. Children: two small squares in the left
        // corners along the bottom and top edges; the right side is bare.
        let parent = vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(4.0, 0.0),
            Vec2::new(4.0, 4.0),
            Vec2::new(0.0, 4.0),
        ];
        let sq = |x: f32, y: f32| {
            vec![
                Vec2::new(x, y),
                Vec2::new(x + 1.0, y),
                Vec2::new(x + 1.0, y + 1.0),
                Vec2::new(x, y + 1.0),
            ]
        };
        let children = vec![sq(0.0, 0.0), sq(0.0, 3.0), sq(0.0, 1.5)];
        let out = cover(&parent, &children, 0.1, 3.0).unwrap();
        // The untouched interior one stays; at least one corner child moves
        // toward the right side.
        let reach = |poly: &Vec<Vec2>| poly.iter().map(|p| p.x).fold(f32::MIN, f32::max);
        let moved: Vec<f32> = out.iter().flatten().map(reach).collect();
        assert!(!moved.is_empty());
        assert!(moved.iter().any(|&x| x > 2.0), "{moved:?}");
    }
}
