//! The discrete Fréchet distance (Eiter & Mannila 1994): the shortest leash
//! that lets two walkers traverse two point sequences monotonically, each
//! step advancing one or both walkers.
//!
//! `c(i, j) = max(d(a_i, b_j), min(c(i−1, j), c(i, j−1), c(i−1, j−1)))`
//! filled row by row: O(nm) time, O(m) memory (one rolling row).

use glam::Vec2;

/// Discrete Fréchet distance between two point sequences; 0 when both are
/// empty, infinite when exactly one is.
pub fn discrete_frechet(a: &[Vec2], b: &[Vec2]) -> f32 {
    let mut row = Vec::new();
    discrete_frechet_with(a, b, &mut row)
}

/// [`discrete_frechet`] reusing `row` as the DP buffer.
pub(crate) fn discrete_frechet_with(a: &[Vec2], b: &[Vec2], row: &mut Vec<f32>) -> f32 {
    match (a.is_empty(), b.is_empty()) {
        (true, true) => return 0.0,
        (true, false) | (false, true) => return f32::INFINITY,
        _ => {}
    }
    let m = b.len();
    row.clear();
    row.resize(m, 0.0);
    // First row: the first walker stays on a_0.
    let mut acc = 0.0f32;
    for j in 0..m {
        acc = acc.max(a[0].distance(b[j]));
        row[j] = acc;
    }
    for ai in &a[1..] {
        // `diag` holds c(i−1, j−1) as we overwrite the row in place.
        let mut diag = row[0];
        row[0] = row[0].max(ai.distance(b[0]));
        for j in 1..m {
            let up = row[j];
            let best = diag.min(up).min(row[j - 1]);
            diag = up;
            row[j] = best.max(ai.distance(b[j]));
        }
    }
    row[m - 1]
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Exponential brute force over every monotone coupling.
    fn brute(a: &[Vec2], b: &[Vec2], i: usize, j: usize) -> f32 {
        let d = a[i].distance(b[j]);
        if i == a.len() - 1 && j == b.len() - 1 {
            return d;
        }
        let mut best = f32::INFINITY;
        if i + 1 < a.len() {
            best = best.min(brute(a, b, i + 1, j));
        }
        if j + 1 < b.len() {
            best = best.min(brute(a, b, i, j + 1));
        }
        if i + 1 < a.len() && j + 1 < b.len() {
            best = best.min(brute(a, b, i + 1, j + 1));
        }
        d.max(best)
    }

    fn points() -> impl Strategy<Value = Vec<Vec2>> {
        prop::collection::vec((-5.0f32..5.0, -5.0f32..5.0), 1..6)
            .prop_map(|v| v.into_iter().map(|(x, y)| Vec2::new(x, y)).collect())
    }

    proptest! {
        #[test]
        fn matches_brute_force(a in points(), b in points()) {
            let fast = discrete_frechet(&a, &b);
            let slow = brute(&a, &b, 0, 0);
            prop_assert_eq!(fast, slow);
            prop_assert_eq!(discrete_frechet(&b, &a), slow);
        }
    }

    #[test]
    fn known_values() {
        let a = [
            Vec2::new(0.0, 0.0),
            Vec2::new(1.0, 0.0),
            Vec2::new(2.0, 0.0),
        ];
        let b = [
            Vec2::new(0.0, 1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(2.0, 1.0),
        ];
        assert_eq!(discrete_frechet(&a, &b), 1.0);
        assert_eq!(discrete_frechet(&a, &a), 0.0);
        // Reversed direction: the walkers must cross.
        let r: Vec<Vec2> = a.iter().rev().copied().collect();
        assert_eq!(discrete_frechet(&a, &r), 2.0);
        assert_eq!(discrete_frechet(&[], &[]), 0.0);
        assert_eq!(discrete_frechet(&a, &[]), f32::INFINITY);
    }
}
