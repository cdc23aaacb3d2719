//! Pruning (§5.4.2): cages that end up mostly outside the sketched crown
//! wilt with their branches.
//!
//! Top-down from the crown's children, each cage — at its final (t = 1)
//! position, after self-adaptation — is clipped with the sketched crown
//! polygon (geo's boolean operations; the paper uses Vatti clipping) and
//! the largest piece kept. With r = area(largest piece) / area(cage):
//! r < [`crate::SketchOptions::prune_ratio`] (0.3) marks the cage and its
//! whole subtree for pruning; r ≥ [`crate::SketchOptions::inside_ratio`]
//! (0.95, the paper's "r ≈ 1") stops the descent; otherwise its children
//! are tested. The crown itself is never pruned.
//!
//! We clip the cages where the deformation puts them rather than at rest:
//! what pruning removes is branches that would end up outside the drawn
//! crown ("unnaturally transformed branches"). A deformed cage can fold
//! over itself where the sketch is concave; its area is that of the region
//! it covers (non-zero fill rule).

use geo::algorithm::bool_ops::{BooleanOps, FillRule};
use geo::{Area, Coord, LineString, MultiPolygon, Polygon};
use glam::Vec2;

use crate::mct::Mct;
use crate::polygon;

/// A geo polygon from a closed polygon.
pub(crate) fn to_geo(poly: &[Vec2]) -> Polygon<f64> {
    let mut ring: Vec<Coord<f64>> = poly
        .iter()
        .map(|p| Coord {
            x: f64::from(p.x),
            y: f64::from(p.y),
        })
        .collect();
    if let Some(&first) = ring.first() {
        ring.push(first);
    }
    Polygon::new(LineString::new(ring), Vec::new())
}

fn covered_area(poly: &[Vec2]) -> f64 {
    if polygon::first_self_intersection(&polygon::dedup(poly, true), true).is_none() {
        return polygon::signed_area2(poly).abs() * 0.5;
    }
    let (lo, hi) = polygon::bounds(poly).unwrap_or((Vec2::ZERO, Vec2::ZERO));
    let (lo, hi) = (lo - Vec2::ONE, hi + Vec2::ONE);
    let rect = to_geo(&[lo, Vec2::new(hi.x, lo.y), hi, Vec2::new(lo.x, hi.y)]);
    to_geo(poly)
        .intersection_with_fill_rule(&rect, FillRule::NonZero)
        .unsigned_area()
}

/// r = area of the largest piece of `cage ∩ sketch` / area of `cage`.
pub(crate) fn clip_ratio(cage: &[Vec2], sketch: &Polygon<f64>) -> f64 {
    let area = covered_area(cage);
    if area <= 0.0 {
        return 1.0;
    }
    let pieces: MultiPolygon<f64> =
        to_geo(cage).intersection_with_fill_rule(sketch, FillRule::NonZero);
    let largest = pieces
        .0
        .iter()
        .map(|p| p.unsigned_area())
        .fold(0.0, f64::max);
    (largest / area).clamp(0.0, 1.0)
}

/// Marks cages for pruning. `finals` holds every cage vertex's final
/// position (flat, by cage offset); `sketched` is the sketched crown.
///
/// Top-down: a cage mostly outside the sketch is pruned with its subtree,
/// one partly outside has its children tested, one inside is kept whole.
/// A cage's test needs only its own polygon, so each depth's cages are
/// tested in parallel (boolean operations, the costly part).
pub(crate) fn prune(
    mct: &mut Mct,
    finals: &[Vec2],
    sketched: &[Vec2],
    prune_ratio: f32,
    inside_ratio: f32,
) {
    use rayon::prelude::*;
    let sketch = to_geo(sketched);
    let mut tested: Vec<u32> = mct.cages[0].children.clone();
    while !tested.is_empty() {
        let ratios: Vec<f64> = tested
            .par_iter()
            .map(|&n| {
                let cage = &mct.cages[n as usize];
                clip_ratio(&finals[cage.offset..cage.offset + cage.rest.len()], &sketch)
            })
            .collect();
        let mut next = Vec::new();
        for (&n, r) in tested.iter().zip(ratios) {
            if r < f64::from(prune_ratio) {
                prune_subtree(mct, n);
            } else if r < f64::from(inside_ratio) {
                next.extend_from_slice(&mct.cages[n as usize].children);
            }
        }
        tested = next;
    }
}

/// Marks cage `n` and everything below it pruned.
fn prune_subtree(mct: &mut Mct, n: u32) {
    let mut sub = vec![n];
    while let Some(s) = sub.pop() {
        mct.cages[s as usize].pruned = true;
        sub.extend_from_slice(&mct.cages[s as usize].children);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(x: f32, y: f32, s: f32) -> Vec<Vec2> {
        vec![
            Vec2::new(x, y),
            Vec2::new(x + s, y),
            Vec2::new(x + s, y + s),
            Vec2::new(x, y + s),
        ]
    }

    #[test]
    fn ratios() {
        let sketch = to_geo(&square(0.0, 0.0, 2.0));
        assert!((clip_ratio(&square(0.5, 0.5, 1.0), &sketch) - 1.0).abs() < 1e-9);
        assert!((clip_ratio(&square(1.5, 0.5, 1.0), &sketch) - 0.5).abs() < 1e-9);
        assert_eq!(clip_ratio(&square(5.0, 5.0, 1.0), &sketch), 0.0);
        // Two pieces: a U-shaped sketch cut by a bar; the largest counts.
        let u = vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(3.0, 0.0),
            Vec2::new(3.0, 3.0),
            Vec2::new(2.0, 3.0),
            Vec2::new(2.0, 1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(1.0, 3.0),
            Vec2::new(0.0, 3.0),
        ];
        let bar = vec![
            Vec2::new(0.0, 2.0),
            Vec2::new(2.5, 2.0),
            Vec2::new(2.5, 2.5),
            Vec2::new(0.0, 2.5),
        ];
        let r = clip_ratio(&bar, &to_geo(&u));
        assert!((r - 0.4).abs() < 1e-6, "{r}");
    }
}
