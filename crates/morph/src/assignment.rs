//! Minimum-weight bipartite matching with one-to-none allowed: the
//! Hungarian (Kuhn–Munkres) algorithm with potentials, written here because
//! it is forty lines and the chain-group blocks it solves are small.
//!
//! [`match_or_leave`] takes an `n × m` cost matrix and, per row and per
//! column, the cost of leaving it unmatched. It minimises
//! `Σ matched cost + Σ unmatched-row cost + Σ unmatched-column cost` by
//! solving a rectangular assignment of the smaller side into the larger side
//! plus one private dummy column per row: a row assigned to its dummy is
//! unmatched, and column `j`'s unmatched cost is subtracted from every real
//! entry of column `j` (matching column `j` saves it). That is
//! `O(k² (k + l))` for `k ≤ l` the two side sizes, so a chain with 18 child
//! groups against five stems with 600 between them stays well under a
//! millisecond.

/// Cost of a forbidden pair; any entry at or above it (or NaN) is never
/// matched.
pub const FORBIDDEN: f64 = 1e12;

/// Minimum-cost assignment of every row of a `rows × cols` matrix
/// (`rows ≤ cols`, row-major) to a distinct column. Returns each row's
/// column.
fn assign(costs: &[f64], rows: usize, cols: usize) -> Vec<usize> {
    debug_assert!(rows <= cols);
    debug_assert_eq!(costs.len(), rows * cols);
    let inf = f64::INFINITY;
    // 1-based potentials and matching, as in the classic formulation.
    let mut u = vec![0.0; rows + 1];
    let mut v = vec![0.0; cols + 1];
    let mut p = vec![0usize; cols + 1]; // row matched to column j (0: none)
    let mut way = vec![0usize; cols + 1];
    let mut minv = vec![inf; cols + 1];
    let mut used = vec![false; cols + 1];
    for i in 1..=rows {
        p[0] = i;
        let mut j0 = 0;
        minv.fill(inf);
        used.fill(false);
        loop {
            used[j0] = true;
            let i0 = p[j0];
            let mut delta = inf;
            let mut j1 = 0;
            let row = &costs[(i0 - 1) * cols..i0 * cols];
            for j in 1..=cols {
                if !used[j] {
                    let cur = row[j - 1] - u[i0] - v[j];
                    if cur < minv[j] {
                        minv[j] = cur;
                        way[j] = j0;
                    }
                    if minv[j] < delta {
                        delta = minv[j];
                        j1 = j;
                    }
                }
            }
            for j in 0..=cols {
                if used[j] {
                    u[p[j]] += delta;
                    v[j] -= delta;
                } else {
                    minv[j] -= delta;
                }
            }
            j0 = j1;
            if p[j0] == 0 {
                break;
            }
        }
        loop {
            let j1 = way[j0];
            p[j0] = p[j1];
            j0 = j1;
            if j0 == 0 {
                break;
            }
        }
    }
    let mut out = vec![0; rows];
    for j in 1..=cols {
        if p[j] != 0 {
            out[p[j] - 1] = j - 1;
        }
    }
    out
}

/// Minimum-weight bipartite matching in which any row or column may stay
/// unmatched at a price. `costs` is `unmatched_rows.len() ×
/// unmatched_cols.len()`, row-major; entries ≥ [`FORBIDDEN`] or NaN are
/// never matched. Returns, for every row, its column or `None`.
pub fn match_or_leave(
    costs: &[f64],
    unmatched_rows: &[f64],
    unmatched_cols: &[f64],
) -> Vec<Option<usize>> {
    let (n, m) = (unmatched_rows.len(), unmatched_cols.len());
    debug_assert_eq!(costs.len(), n * m);
    if n == 0 || m == 0 {
        return vec![None; n];
    }
    let allowed = |c: f64| c < FORBIDDEN; // false for NaN too
    if n <= m {
        // Rows into columns + one dummy per row.
        let cols = m + n;
        let mut a = vec![FORBIDDEN; n * cols];
        for i in 0..n {
            for j in 0..m {
                let c = costs[i * m + j];
                if allowed(c) {
                    a[i * cols + j] = c - unmatched_cols[j];
                }
            }
            a[i * cols + m + i] = unmatched_rows[i];
        }
        assign(&a, n, cols)
            .into_iter()
            .enumerate()
            .map(|(i, j)| (j < m && allowed(costs[i * m + j])).then_some(j))
            .collect()
    } else {
        // Columns into rows + one dummy per column, then invert.
        let cols = n + m;
        let mut a = vec![FORBIDDEN; m * cols];
        for j in 0..m {
            for i in 0..n {
                let c = costs[i * m + j];
                if allowed(c) {
                    a[j * cols + i] = c - unmatched_rows[i];
                }
            }
            a[j * cols + n + j] = unmatched_cols[j];
        }
        let mut out = vec![None; n];
        for (j, i) in assign(&a, m, cols).into_iter().enumerate() {
            if i < n && allowed(costs[i * m + j]) {
                out[i] = Some(j);
            }
        }
        out
    }
}

/// Total cost of a matching as [`match_or_leave`] minimises it.
#[cfg(test)]
pub(crate) fn total_cost(
    costs: &[f64],
    unmatched_rows: &[f64],
    unmatched_cols: &[f64],
    matching: &[Option<usize>],
) -> f64 {
    let m = unmatched_cols.len();
    let mut used = vec![false; m];
    let mut total = 0.0;
    for (i, j) in matching.iter().enumerate() {
        match j {
            Some(j) => {
                assert!(!used[*j], "column {j} matched twice");
                used[*j] = true;
                total += costs[i * m + j];
            }
            None => total += unmatched_rows[i],
        }
    }
    for (j, u) in used.iter().zip(unmatched_cols) {
        if !j {
            total += u;
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    /// Every partial matching, exhaustively.
    fn brute_force(costs: &[f64], ur: &[f64], uc: &[f64]) -> f64 {
        fn go(
            i: usize,
            costs: &[f64],
            ur: &[f64],
            uc: &[f64],
            used: &mut Vec<bool>,
            acc: f64,
            best: &mut f64,
        ) {
            let m = uc.len();
            if i == ur.len() {
                let rest: f64 = (0..m).filter(|&j| !used[j]).map(|j| uc[j]).sum();
                *best = best.min(acc + rest);
                return;
            }
            go(i + 1, costs, ur, uc, used, acc + ur[i], best);
            for j in 0..m {
                let c = costs[i * m + j];
                if !used[j] && c < FORBIDDEN {
                    used[j] = true;
                    go(i + 1, costs, ur, uc, used, acc + c, best);
                    used[j] = false;
                }
            }
        }
        let mut best = f64::INFINITY;
        go(0, costs, ur, uc, &mut vec![false; uc.len()], 0.0, &mut best);
        best
    }

    fn instance() -> impl Strategy<Value = (Vec<f64>, Vec<f64>, Vec<f64>)> {
        (0usize..6, 0usize..6).prop_flat_map(|(n, m)| {
            (
                proptest::collection::vec(
                    prop_oneof![8 => 0.0f64..10.0, 1 => Just(FORBIDDEN)],
                    n * m,
                ),
                proptest::collection::vec(0.0f64..6.0, n),
                proptest::collection::vec(0.0f64..6.0, m),
            )
        })
    }

    proptest! {
        #[test]
        fn matches_brute_force((costs, ur, uc) in instance()) {
            let matching = match_or_leave(&costs, &ur, &uc);
            prop_assert_eq!(matching.len(), ur.len());
            let got = total_cost(&costs, &ur, &uc, &matching);
            let want = brute_force(&costs, &ur, &uc);
            prop_assert!((got - want).abs() < 1e-9, "got {got}, brute force {want}");
            for (i, j) in matching.iter().enumerate() {
                if let Some(j) = j {
                    prop_assert!(costs[i * uc.len() + j] < FORBIDDEN);
                }
            }
        }
    }

    #[test]
    fn expensive_pairs_stay_unmatched() {
        // Matching row 0 to column 0 costs 5 > 1 + 1 for leaving both.
        let m = match_or_leave(&[5.0, 0.5, 0.2, 9.0], &[1.0, 1.0], &[1.0, 1.0]);
        assert_eq!(m, vec![Some(1), Some(0)]);
        let m = match_or_leave(&[5.0], &[1.0], &[1.0]);
        assert_eq!(m, vec![None]);
        let m = match_or_leave(&[1.5], &[1.0], &[1.0]);
        assert_eq!(m, vec![Some(0)]);
    }

    #[test]
    fn wide_and_tall_matrices_agree() {
        // The same problem transposed gives the transposed matching.
        let costs = [3.0, 1.0, 4.0, 1.0, 5.0, 9.0, 2.0, 6.0];
        let (ur, uc) = ([2.0, 2.0], [1.0, 1.0, 1.0, 1.0]);
        let a = match_or_leave(&costs, &ur, &uc);
        let mut t = [0.0; 8];
        for i in 0..2 {
            for j in 0..4 {
                t[j * 2 + i] = costs[i * 4 + j];
            }
        }
        let b = match_or_leave(&t, &uc, &ur);
        for (i, j) in a.iter().enumerate() {
            if let Some(j) = j {
                assert_eq!(b[*j], Some(i));
            }
        }
        assert_eq!(a.iter().flatten().count(), b.iter().flatten().count());
    }
}
