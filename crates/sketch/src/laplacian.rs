//! Sparse linear least squares for the Laplacian deformations (Eq. 1):
//! `min ‖A x − b‖²` through the normal equations `AᵀA x = Aᵀb`, factorised
//! once with faer's sparse Cholesky (AMD ordering) and solved for as many
//! right-hand sides as there are frames. Only `b` changes from frame to
//! frame: the constraint targets.
//!
//! Everything is solved in **displacement form**: with Laplacian
//! coordinates `σ = L x₀` of the rest shape, `L x − σ = L (x − x₀)`, so the
//! unknowns are displacements from rest and a zero right-hand side gives an
//! exactly zero solution (the t = 0 frame reproduces the input bit for bit).
//! Two columns are solved at once: the x and y of the view plane.

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, Mat, Par, Side};

use crate::error::SketchError;

/// Number of right-hand-side columns (the view plane's x and y).
pub(crate) const COLS: usize = 2;

/// A factorised least-squares problem `min ‖A x − b‖²`.
#[derive(Debug)]
pub(crate) struct LeastSquares {
    unknowns: usize,
    rows: usize,
    /// A in compressed sparse columns: column j's entries are
    /// `row_idx[col_ptr[j]..col_ptr[j + 1]]` / `vals[…]`, for `Aᵀ b`.
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    vals: Vec<f64>,
    symbolic: Option<SymbolicCholesky<usize>>,
    factor: Vec<f64>,
}

impl LeastSquares {
    /// Factorises `AᵀA` for `A` given as `(row, column, value)` entries
    /// (duplicates are summed). Every unknown must be determined (AᵀA
    /// positive definite); otherwise this is an internal error.
    pub(crate) fn new(
        unknowns: usize,
        rows: usize,
        entries: &[(usize, usize, f64)],
    ) -> Result<LeastSquares, SketchError> {
        // Columns of A.
        let mut counts = vec![0usize; unknowns + 1];
        for &(_, c, _) in entries {
            counts[c + 1] += 1;
        }
        for j in 0..unknowns {
            counts[j + 1] += counts[j];
        }
        let col_ptr = counts.clone();
        let mut fill = counts;
        let mut row_idx = vec![0usize; entries.len()];
        let mut vals = vec![0.0f64; entries.len()];
        for &(r, c, v) in entries {
            let k = fill[c];
            row_idx[k] = r;
            vals[k] = v;
            fill[c] += 1;
        }
        if unknowns == 0 {
            return Ok(LeastSquares {
                unknowns,
                rows,
                col_ptr,
                row_idx,
                vals,
                symbolic: None,
                factor: Vec::new(),
            });
        }
        let by_row = rows_of(rows, entries.iter().copied());
        let ata = normal_matrix(unknowns, &by_row)?;
        let symbolic = symbolic_cholesky(&ata)?;
        let mut factor = vec![0.0f64; symbolic.len_val()];
        let mut mem = MemBuffer::new(
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
        );
        symbolic
            .factorize_numeric_llt::<f64>(
                &mut factor,
                ata.as_ref(),
                Side::Upper,
                LltRegularization::default(),
                Par::Seq,
                MemStack::new(&mut mem),
                Default::default(),
            )
            .map_err(|e| SketchError::Internal(format!("Laplacian system is singular: {e:?}")))?;
        Ok(LeastSquares {
            unknowns,
            rows,
            col_ptr,
            row_idx,
            vals,
            symbolic: Some(symbolic),
            factor,
        })
    }

    /// A system stored by [`Serialize`]: the symbolic factorisation is
    /// computed again from A's pattern (it depends on nothing else), the
    /// numeric factor is taken as stored, so solves give the same bits as
    /// the system that was stored.
    fn restored(stored: Stored) -> Result<LeastSquares, SketchError> {
        let Stored {
            unknowns,
            rows,
            col_ptr,
            row_idx,
            vals,
            factor,
        } = stored;
        let consistent = col_ptr.len() == unknowns + 1
            && col_ptr.windows(2).all(|w| w[0] <= w[1])
            && col_ptr.last() == Some(&row_idx.len())
            && row_idx.len() == vals.len()
            && row_idx.iter().all(|&r| r < rows);
        if !consistent {
            return Err(SketchError::Internal(
                "stored system is inconsistent".into(),
            ));
        }
        let symbolic = if unknowns == 0 {
            None
        } else {
            let (col_ptr, row_idx, vals) = (&col_ptr, &row_idx, &vals);
            let entries = (0..unknowns)
                .flat_map(|c| (col_ptr[c]..col_ptr[c + 1]).map(move |k| (row_idx[k], c, vals[k])));
            let ata = normal_matrix(unknowns, &rows_of(rows, entries))?;
            let symbolic = symbolic_cholesky(&ata)?;
            if symbolic.len_val() != factor.len() {
                return Err(SketchError::Internal("stored factor does not fit".into()));
            }
            Some(symbolic)
        };
        Ok(LeastSquares {
            unknowns,
            rows,
            col_ptr,
            row_idx,
            vals,
            symbolic,
            factor,
        })
    }

    /// Number of rows of A.
    pub(crate) fn rows(&self) -> usize {
        self.rows
    }

    /// Scratch a solve needs.
    pub(crate) fn scratch(&self) -> StackReq {
        match &self.symbolic {
            Some(s) => s.solve_in_place_scratch::<f64>(COLS, Par::Seq),
            None => StackReq::EMPTY,
        }
    }

    /// Solves for `b` (`rows × 2`, row-major pairs); writes the solution
    /// into `x` (`unknowns × 2`), which is resized as needed.
    pub(crate) fn solve(&self, b: &[[f64; COLS]], x: &mut Mat<f64>, mem: &mut MemBuffer) {
        debug_assert_eq!(b.len(), self.rows);
        if x.nrows() != self.unknowns || x.ncols() != COLS {
            *x = Mat::zeros(self.unknowns, COLS);
        }
        for j in 0..self.unknowns {
            let mut acc = [0.0f64; COLS];
            for k in self.col_ptr[j]..self.col_ptr[j + 1] {
                let v = self.vals[k];
                let r = &b[self.row_idx[k]];
                acc[0] += v * r[0];
                acc[1] += v * r[1];
            }
            x[(j, 0)] = acc[0];
            x[(j, 1)] = acc[1];
        }
        if let Some(symbolic) = &self.symbolic {
            LltRef::new(symbolic, &self.factor).solve_in_place_with_conj(
                Conj::No,
                x.as_mut(),
                Par::Seq,
                MemStack::new(mem),
            );
        }
    }
}

/// A's entries `(column, value)` by row.
fn rows_of(
    rows: usize,
    entries: impl Iterator<Item = (usize, usize, f64)>,
) -> Vec<Vec<(usize, f64)>> {
    let mut by_row: Vec<Vec<(usize, f64)>> = vec![Vec::new(); rows];
    for (r, c, v) in entries {
        by_row[r].push((c, v));
    }
    by_row
}

/// AᵀA, upper triangle, from the rows of A.
fn normal_matrix(
    unknowns: usize,
    by_row: &[Vec<(usize, f64)>],
) -> Result<SparseColMat<usize, f64>, SketchError> {
    let mut triplets: Vec<Triplet<usize, usize, f64>> = Vec::new();
    for row in by_row {
        for &(ci, vi) in row {
            for &(cj, vj) in row {
                if ci <= cj {
                    triplets.push(Triplet::new(ci, cj, vi * vj));
                }
            }
        }
    }
    SparseColMat::<usize, f64>::try_new_from_triplets(unknowns, unknowns, &triplets)
        .map_err(|e| SketchError::Internal(format!("normal equations: {e:?}")))
}

fn symbolic_cholesky(
    ata: &SparseColMat<usize, f64>,
) -> Result<SymbolicCholesky<usize>, SketchError> {
    factorize_symbolic_cholesky(
        ata.symbolic(),
        Side::Upper,
        SymmetricOrdering::Amd,
        CholeskySymbolicParams::default(),
    )
    .map_err(|e| SketchError::Internal(format!("symbolic Cholesky: {e:?}")))
}

/// What of a [`LeastSquares`] is stored (borrowed to write, owned to read:
/// the same fields in the same order).
#[derive(serde::Serialize)]
struct StoredRef<'a> {
    unknowns: usize,
    rows: usize,
    col_ptr: &'a [usize],
    row_idx: &'a [usize],
    vals: &'a [f64],
    factor: &'a [f64],
}

#[derive(serde::Deserialize)]
struct Stored {
    unknowns: usize,
    rows: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    vals: Vec<f64>,
    factor: Vec<f64>,
}

impl serde::Serialize for LeastSquares {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        StoredRef {
            unknowns: self.unknowns,
            rows: self.rows,
            col_ptr: &self.col_ptr,
            row_idx: &self.row_idx,
            vals: &self.vals,
            factor: &self.factor,
        }
        .serialize(serializer)
    }
}

impl<'de> serde::Deserialize<'de> for LeastSquares {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let stored = Stored::deserialize(deserializer)?;
        LeastSquares::restored(stored).map_err(serde::de::Error::custom)
    }
}

/// A scratch buffer big enough for every system in `systems`.
pub(crate) fn scratch_for<'a>(systems: impl IntoIterator<Item = &'a LeastSquares>) -> MemBuffer {
    let req = systems
        .into_iter()
        .fold(StackReq::EMPTY, |acc, s| acc.or(s.scratch()));
    MemBuffer::new(req)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed polygon Laplacian (uniform weights) plus a constraint row
    /// on every vertex.
    #[test]
    fn all_vertices_constrained_gives_the_constraints() {
        let n = 7;
        let w = 10.0;
        let mut entries = Vec::new();
        for i in 0..n {
            entries.push((i, i, 2.0));
            entries.push((i, (i + 1) % n, -1.0));
            entries.push((i, (i + n - 1) % n, -1.0));
        }
        for i in 0..n {
            entries.push((n + i, i, w));
        }
        let ls = LeastSquares::new(n, 2 * n, &entries).unwrap();
        // Displacement form: Laplacian rows want 0, constraint rows
        // w·target. A common translation satisfies every row exactly.
        let mut b = vec![[0.0; 2]; 2 * n];
        for i in 0..n {
            b[n + i] = [w * 0.3, w * -1.2];
        }
        let mut x = Mat::zeros(0, 0);
        let mut mem = scratch_for([&ls]);
        ls.solve(&b, &mut x, &mut mem);
        for i in 0..n {
            assert!((x[(i, 0)] - 0.3).abs() < 1e-12);
            assert!((x[(i, 1)] + 1.2).abs() < 1e-12);
        }
        // Pure constraint rows (no Laplacian rows) reproduce arbitrary
        // targets exactly.
        let entries: Vec<_> = (0..n).map(|i| (i, i, w)).collect();
        let ls = LeastSquares::new(n, n, &entries).unwrap();
        let b: Vec<[f64; 2]> = (0..n).map(|i| [w * i as f64, w * (i * i) as f64]).collect();
        let mut mem = scratch_for([&ls]);
        ls.solve(&b, &mut x, &mut mem);
        for i in 0..n {
            assert!((x[(i, 0)] - i as f64).abs() < 1e-10);
            assert!((x[(i, 1)] - (i * i) as f64).abs() < 1e-10);
        }
    }

    #[test]
    fn zero_right_hand_side_gives_exact_zero() {
        let entries = vec![(0, 0, 2.0), (0, 1, -1.0), (1, 1, 1.0), (2, 0, 3.0)];
        let ls = LeastSquares::new(2, 3, &entries).unwrap();
        let mut x = Mat::zeros(0, 0);
        let mut mem = scratch_for([&ls]);
        ls.solve(&[[0.0; 2]; 3], &mut x, &mut mem);
        assert_eq!((x[(0, 0)], x[(1, 1)]), (0.0, 0.0));
    }

    #[test]
    fn underdetermined_systems_are_internal_errors() {
        let entries = vec![(0, 0, 1.0), (0, 1, -1.0)];
        assert!(matches!(
            LeastSquares::new(2, 1, &entries),
            Err(SketchError::Internal(_))
        ));
    }
}
