//! A sequence's vertex motion as a few principal displacements.
//!
//! The displacements of every sampled frame from the base pose are the
//! columns of a matrix `D` (three rows per vertex, one column per frame).
//! Its left singular vectors are an orthonormal basis of the motion,
//! ordered by how much of it they carry; the first `K` of them with the
//! frames' coordinates in them reproduce every frame as closely as any `K`
//! shapes can in the least-squares sense. They come from the eigenvectors
//! of the frames' Gram matrix `G = DᵀD` (frames × frames, tiny): with
//! `G = V Λ Vᵀ`, target `k` is `D v_k / σ_k` and frame `j`'s weight on it
//! is `σ_k v_jk` (`σ_k = √λ_k`). Normals ride along: normal target `k` is
//! the same combination `ND v_k / σ_k` of the frames' normal changes, so a
//! frame's normals are the projection of its true normal change onto the
//! motion's span.
//!
//! The least-squares optimum is not what a viewer must hold: the budget is
//! a *largest* vertex error. So [`max_errors`] measures, for every `K` up
//! to the maximum, the largest distance of any vertex of any frame from its
//! reconstruction with the targets as they will be stored (quantised ones
//! dequantised), and the caller takes the smallest `K` within budget.
//!
//! faer multiplies the matrices (`f32`, as the meshes are); the Gram matrix
//! is summed over row blocks in parallel, as faer is built here without
//! its own threads, and decomposed in `f64`.

use faer::{Mat, MatRef, Side};
use rayon::prelude::*;

/// Vertices per block of the parallel passes: a block's 60 frames are
/// about 700 KB, within a core's L2 cache.
const BLOCK_VERTICES: usize = 1024;

/// Columns of per-vertex VEC3 values, one per frame, stored column-major
/// (`rows = 3 · vertices`), each column **planar**: every vertex's `x`,
/// then every `y`, then every `z`. The basis does not depend on the row
/// order, and planar rows let [`max_errors`] compute vertex distances
/// with vector instructions.
#[derive(Clone, Debug, Default)]
pub(crate) struct Columns {
    pub(crate) rows: usize,
    pub(crate) data: Vec<f32>,
}

impl Columns {
    pub(crate) fn new(rows: usize, capacity: usize) -> Columns {
        Columns {
            rows,
            data: Vec::with_capacity(rows * capacity),
        }
    }

    pub(crate) fn count(&self) -> usize {
        self.data.len().checked_div(self.rows).unwrap_or(0)
    }

    fn matrix(&self) -> MatRef<'_, f32> {
        MatRef::from_column_major_slice(&self.data, self.rows, self.count())
    }

    pub(crate) fn column(&self, j: usize) -> &[f32] {
        &self.data[j * self.rows..(j + 1) * self.rows]
    }

    /// Vertex `v` of column `j`.
    pub(crate) fn vertex(&self, j: usize, v: usize) -> glam::Vec3 {
        let c = self.column(j);
        let n = self.rows / 3;
        glam::Vec3::new(c[v], c[n + v], c[2 * n + v])
    }
}

/// The principal displacements of a sequence.
#[derive(Clone, Debug)]
pub(crate) struct Principal {
    /// Position targets: `rows × count`, column-major.
    pub(crate) positions: Columns,
    /// Normal targets, the same shape.
    pub(crate) normals: Columns,
    /// Frame `j`'s weight on target `k` at `weights[j · count + k]`.
    pub(crate) weights: Vec<f32>,
    pub(crate) count: usize,
    /// `leading[K − 1]`: the weights (`[j · K + k]`) that fit the samples
    /// best with the first `K` targets alone, where they are not the first
    /// `K` of `weights`. Empty for principal displacements, which are
    /// orthogonal: dropping the last ones leaves the others' weights
    /// best. A weighted fit's targets are not orthogonal in each sample's
    /// weighting, so there the first `K` of all the weights can miss a
    /// sample by far more than the `K` targets need to
    /// ([`super::weighted`]).
    pub(crate) leading: Vec<Vec<f32>>,
}

impl Principal {
    /// Each frame's weights on the first `k` targets, as they fit best
    /// with those alone (`[j · k + t]`).
    pub(crate) fn leading_weights(&self, k: usize) -> std::borrow::Cow<'_, [f32]> {
        if k == self.count {
            return std::borrow::Cow::Borrowed(&self.weights);
        }
        if k > 0
            && let Some(w) = self.leading.get(k - 1)
        {
            return std::borrow::Cow::Borrowed(w);
        }
        let frames = self.weights.len().checked_div(self.count).unwrap_or(0);
        std::borrow::Cow::Owned(
            (0..frames)
                .flat_map(|j| {
                    self.weights[j * self.count..j * self.count + k]
                        .iter()
                        .copied()
                })
                .collect(),
        )
    }

    /// Keeps the first `k` targets, with the weights that fit best with
    /// them alone.
    pub(crate) fn truncate(&mut self, k: usize) {
        let k = k.min(self.count);
        self.weights = self.leading_weights(k).into_owned();
        self.positions.data.truncate(k * self.positions.rows);
        self.normals.data.truncate(k * self.normals.rows);
        self.count = k;
        self.leading.clear();
    }
}

/// At most `max` principal displacements of `d` (and the matching normal
/// combinations of `nd`), largest first. Directions whose share of the
/// motion is below `f32` precision are left out, so a still sequence has
/// none.
#[cfg(test)]
pub(crate) fn principal(d: &Columns, nd: &Columns, max: usize) -> Principal {
    principal_of(d, nd, Spectrum::of(d, max))
}

/// The directions of a sequence's motion, before any target is formed:
/// the square roots of the largest eigenvalues of its Gram matrix and
/// their eigenvectors (see [`principal`]).
pub(crate) struct Spectrum {
    sigmas: Vec<f64>,
    v: Mat<f64>,
}

impl Spectrum {
    /// At most `max` directions of `d`'s motion.
    pub(crate) fn of(d: &Columns, max: usize) -> Spectrum {
        let (sigmas, v) = largest_eigen(&gram(d), max);
        Spectrum { sigmas, v }
    }

    /// How many directions there are: the principal displacements'
    /// count.
    pub(crate) fn count(&self) -> usize {
        self.sigmas.len()
    }
}

/// The principal displacements of `d` (normals `nd`) along `spectrum`.
pub(crate) fn principal_of(d: &Columns, nd: &Columns, spectrum: Spectrum) -> Principal {
    let frames = d.count();
    let Spectrum { sigmas, v } = spectrum;
    let count = sigmas.len();
    let mut project = Mat::<f32>::zeros(frames, count);
    let mut weights = vec![0f32; frames * count];
    for (k, &s) in sigmas.iter().enumerate() {
        for j in 0..frames {
            project[(j, k)] = (v[(j, k)] / s) as f32;
            weights[j * count + k] = (v[(j, k)] * s) as f32;
        }
    }
    Principal {
        positions: multiply(d, project.as_ref()),
        normals: multiply(nd, project.as_ref()),
        weights,
        count,
        leading: Vec::new(),
    }
}

/// The row blocks (first row, row count) the matrix products are cut
/// into for the parallel passes: 16 error blocks' worth of rows each.
fn row_blocks(rows: usize) -> Vec<(usize, usize)> {
    let block = 3 * BLOCK_VERTICES * 16;
    (0..rows)
        .step_by(block)
        .map(|start| (start, block.min(rows - start)))
        .collect()
}

/// `DᵀD` in `f64`: row blocks multiplied in parallel, summed in order.
fn gram(d: &Columns) -> Mat<f64> {
    let frames = d.count();
    let m = d.matrix();
    let parts: Vec<Mat<f64>> = row_blocks(d.rows)
        .into_par_iter()
        .map(|(start, len)| {
            let part = m.subrows(start, len);
            let g = part.transpose() * part;
            Mat::<f64>::from_fn(frames, frames, |i, j| f64::from(g[(i, j)]))
        })
        .collect();
    // Summed in block order: rayon's own reduction associates as threads
    // happen to steal work, and the same sequence must give the same
    // bytes every time.
    parts
        .into_iter()
        .fold(Mat::<f64>::zeros(frames, frames), |a, b| a + b)
}

/// The square roots of the `max` largest eigenvalues of `gram` that are
/// meaningfully above zero, and their eigenvectors (columns).
pub(crate) fn largest_eigen(gram: &Mat<f64>, max: usize) -> (Vec<f64>, Mat<f64>) {
    let n = gram.nrows();
    let Ok(eigen) = gram.self_adjoint_eigen(Side::Lower) else {
        return (Vec::new(), Mat::zeros(n, 0));
    };
    let values = eigen.S().column_vector();
    let largest = (0..n).map(|i| values[i]).fold(0f64, f64::max);
    // f32 sums carry about 7 digits: below that share of the largest
    // eigenvalue a direction is rounding noise.
    let floor = largest * 1e-10;
    let picked: Vec<usize> = (0..n)
        .rev()
        .filter(|&i| values[i] > floor && values[i] > 0.0)
        .take(max)
        .collect();
    let u = eigen.U();
    let v = Mat::<f64>::from_fn(n, picked.len(), |j, k| u[(j, picked[k])]);
    (picked.iter().map(|&i| values[i].sqrt()).collect(), v)
}

/// `a · p` as columns, row blocks multiplied in parallel.
fn multiply(a: &Columns, p: MatRef<'_, f32>) -> Columns {
    let m = a.matrix();
    let parts: Vec<Mat<f32>> = row_blocks(a.rows)
        .into_par_iter()
        .map(|(start, len)| m.subrows(start, len) * p)
        .collect();
    let mut c = Columns::new(a.rows, p.ncols());
    for k in 0..p.ncols() {
        for part in &parts {
            c.data.extend(part.col(k).iter().copied());
        }
    }
    c
}

/// Which error passes to run: the first `upto` targets of `count` (the
/// weights' stride), over every `every`-th block of vertices.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Pass {
    pub(crate) count: usize,
    pub(crate) upto: usize,
    pub(crate) every: usize,
}

/// For `K = 0 … upto`, the largest distance between a vertex of a frame
/// of `d` and its reconstruction from the first `K` columns of `targets`
/// with `weights` (`weights[j · count + k]`). Over a sample of the
/// blocks (`every > 1`) the figures are lower bounds.
pub(crate) fn max_errors(d: &Columns, targets: &Columns, weights: &[f32], pass: Pass) -> Vec<f32> {
    worst_errors(d, targets, weights, pass, true)
}

/// The largest distance between a vertex of a frame of `d` and its
/// reconstruction from all `count` columns of `targets`: the last figure
/// of [`max_errors`], without measuring the counts below it (about half
/// the work of the pass).
pub(crate) fn max_error(d: &Columns, targets: &Columns, weights: &[f32], count: usize) -> f32 {
    let all = Pass {
        count,
        upto: count,
        every: 1,
    };
    worst_errors(d, targets, weights, all, false)[count]
}

/// [`max_errors`], for every target count when `each`, else for
/// `pass.upto` alone (the others stay 0).
fn worst_errors(
    d: &Columns,
    targets: &Columns,
    weights: &[f32],
    pass: Pass,
    each: bool,
) -> Vec<f32> {
    let vertices = d.rows / 3;
    let frames = d.count();
    let blocks: Vec<usize> = (0..vertices.div_ceil(BLOCK_VERTICES))
        .step_by(pass.every.max(1))
        .collect();
    let worst = blocks
        .par_iter()
        .map(|&b| {
            let start = b * BLOCK_VERTICES;
            let range = start..(start + BLOCK_VERTICES).min(vertices);
            block_errors(&Block {
                d,
                targets,
                weights,
                pass,
                each,
                range,
                frames,
            })
        })
        .reduce(
            || vec![0f32; pass.upto + 1],
            |a, b| a.iter().zip(&b).map(|(x, y)| x.max(*y)).collect(),
        );
    worst.into_iter().map(f32::sqrt).collect()
}

/// The fewest of the `count` targets whose largest error is within
/// `budget` (all of them when none is), and that error: first a pass over
/// an eighth of the vertices, whose lower bounds say where to start, then
/// full passes that stop two targets past that guess unless it was short.
pub(crate) fn fewest_within(
    d: &Columns,
    targets: &Columns,
    weights: &[f32],
    count: usize,
    budget: f32,
) -> (usize, f32) {
    let sample = Pass {
        count,
        upto: count,
        every: 8,
    };
    let bounds = max_errors(d, targets, weights, sample);
    let guess = bounds.iter().position(|&e| e <= budget).unwrap_or(count);
    // The sample's errors are lower bounds: when only all of the targets
    // may be within budget, all of them are used, and only their error
    // is left to measure.
    if guess == count {
        return (count, max_error(d, targets, weights, count));
    }
    let mut upto = (guess + 2).min(count);
    loop {
        let errors = max_errors(
            d,
            targets,
            weights,
            Pass {
                count,
                upto,
                every: 1,
            },
        );
        if let Some(k) = errors.iter().position(|&e| e <= budget) {
            return (k, errors[k]);
        }
        if upto == count {
            return (count, errors[count]);
        }
        upto = count;
    }
}

/// Vertices a [`block_errors`] step holds in registers.
const LANES: usize = 16;

/// [`worst_errors`] (squared) over the vertices `range`. Each step takes
/// [`LANES`] vertices, keeps their residual in registers and subtracts one
/// target after another for every frame, so each displacement is read
/// once and every `K`'s distance comes out of the same pass (only the
/// last `K`'s without `each`).
///
/// Compiled again for AVX-512 and AVX2 and chosen at run time: the
/// baseline x86-64 build has 16 four-lane registers, too few to keep a
/// step's residual in them, and this pass was a sixth of an animation
/// render. The results are bit-identical on every path: lane-wise
/// multiplies and subtractions round alike at any width, and Rust never
/// fuses them into FMAs.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512cd+avx512dq+avx512vl",
    "x86_64+avx2"
))]
fn block_errors<'a>(block: &Block<'a>) -> Vec<f32> {
    portable_block_errors(block)
}

/// One block of vertices of an error pass, as [`block_errors`] reads it.
struct Block<'a> {
    d: &'a Columns,
    targets: &'a Columns,
    weights: &'a [f32],
    pass: Pass,
    each: bool,
    range: std::ops::Range<usize>,
    frames: usize,
}

/// [`block_errors`]' body, compiled for the baseline where it is called
/// directly (the tests compare the two) and inlined into each clone.
#[inline(always)]
fn portable_block_errors(block: &Block<'_>) -> Vec<f32> {
    let &Block {
        d,
        targets,
        weights,
        pass,
        each,
        ref range,
        frames,
    } = block;
    let (count, upto) = (pass.count, pass.upto);
    type Lanes = [f32; LANES];
    let len = range.len().next_multiple_of(LANES);
    // The block's displacements and targets, copied into runs of `len`
    // per axis (zero-padded): a few long sequential reads of the big
    // columns instead of scattered ones.
    let local_d = gather(d, frames, range, len);
    let local_t = gather(targets, upto, range, len);
    let lanes_of = |local: &[f32], column: usize, axis: usize, at: usize| -> Lanes {
        let start = (column * 3 + axis) * len + at;
        local[start..start + LANES]
            .try_into()
            .expect("LANES floats")
    };
    let mut worst: Vec<Lanes> = vec![[0.0; LANES]; upto + 1];
    let mut t: Vec<[Lanes; 3]> = vec![[[0.0; LANES]; 3]; upto];
    for at in (0..len).step_by(LANES) {
        for (k, tk) in t.iter_mut().enumerate() {
            *tk = [0, 1, 2].map(|a| lanes_of(&local_t, k, a, at));
        }
        for j in 0..frames {
            let mut r = [0, 1, 2].map(|a| lanes_of(&local_d, j, a, at));
            let frame_weights = &weights[j * count..j * count + upto];
            if each {
                keep_largest(&mut worst[0], &r);
                for ((tk, &w), worst) in t.iter().zip(frame_weights).zip(&mut worst[1..]) {
                    subtract(&mut r, tk, w);
                    keep_largest(worst, &r);
                }
            } else {
                for (tk, &w) in t.iter().zip(frame_weights) {
                    subtract(&mut r, tk, w);
                }
                keep_largest(&mut worst[upto], &r);
            }
        }
    }
    worst
        .iter()
        .map(|lanes| lanes.iter().copied().fold(0.0, f32::max))
        .collect()
}

/// The first `columns` columns of `c` restricted to the vertices `range`:
/// per column, its `x`, `y` and `z` runs, each padded with zeros to `len`.
fn gather(c: &Columns, columns: usize, range: &std::ops::Range<usize>, len: usize) -> Vec<f32> {
    let n = c.rows / 3;
    let mut out = vec![0f32; columns * 3 * len];
    for j in 0..columns {
        let column = c.column(j);
        for a in 0..3 {
            let to = (j * 3 + a) * len;
            out[to..to + range.len()]
                .copy_from_slice(&column[a * n + range.start..a * n + range.end]);
        }
    }
    out
}

/// `r -= t · w`, lane by lane.
#[inline(always)]
fn subtract(r: &mut [[f32; LANES]; 3], t: &[[f32; LANES]; 3], w: f32) {
    for (ra, ta) in r.iter_mut().zip(t) {
        for (x, y) in ra.iter_mut().zip(ta) {
            *x -= y * w;
        }
    }
}

/// Raises each lane of `worst` to the squared length of the lane's VEC3.
#[inline(always)]
fn keep_largest(worst: &mut [f32; LANES], r: &[[f32; LANES]; 3]) {
    for l in 0..LANES {
        let s = r[0][l] * r[0][l] + r[1][l] * r[1][l] + r[2][l] * r[2][l];
        worst[l] = if s > worst[l] { s } else { worst[l] };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `vertices` × `frames` displacements with more directions than
    /// `count` targets span (row `i` of frame `j` is `f(i·a + j·b, j)`),
    /// their `count` principal displacements, and the pass over all of
    /// them.
    fn wavy(
        (vertices, frames, count): (usize, usize, usize),
        (a, b): (usize, usize),
        f: impl Fn(f32, usize) -> f32,
    ) -> (Columns, Principal, Pass) {
        let mut d = Columns::new(3 * vertices, frames);
        for j in 0..frames {
            for i in 0..3 * vertices {
                d.data.push(f((i * a + j * b) as f32, j));
            }
        }
        let p = principal(&d, &d.clone(), count);
        assert_eq!(p.count, count);
        let all = Pass {
            count,
            upto: count,
            every: 1,
        };
        (d, p, all)
    }

    /// The bit patterns of `e`, to compare errors exactly.
    fn bits(e: &[f32]) -> Vec<u32> {
        e.iter().map(|x| x.to_bits()).collect()
    }

    /// Two vertices moving along two independent directions over five
    /// frames: two targets reproduce every frame, one does not.
    #[test]
    fn two_motions_need_two_targets() {
        let mut d = Columns::new(6, 5);
        for j in 0..5 {
            let a = j as f32;
            let b = (j as f32 * 1.3).sin();
            // Planar: x of both vertices, then y, then z.
            d.data.extend([a, 0.0, 0.0, b, 0.0, 2.0 * b]);
        }
        let nd = d.clone();
        let p = principal(&d, &nd, 16);
        // Beyond the two true directions only f32 rounding noise is left.
        assert!(p.count >= 2);
        let all = Pass {
            count: p.count,
            upto: p.count,
            every: 1,
        };
        let errors = max_errors(&d, &p.positions, &p.weights, all);
        assert!(errors[0] >= 4.0 - 1e-4, "{errors:?}");
        assert!(errors[1] > 0.1, "{errors:?}");
        assert!(errors[2] < 1e-5, "{errors:?}");
        // Orthonormal targets.
        let t0 = p.positions.column(0);
        let t1 = p.positions.column(1);
        let dot: f32 = t0.iter().zip(t1).map(|(a, b)| a * b).sum();
        let n0: f32 = t0.iter().map(|a| a * a).sum();
        assert!(dot.abs() < 1e-5 && (n0 - 1.0).abs() < 1e-4);
    }

    /// The error with every target alone is the last of the errors of
    /// every count, on a motion that needs more targets than it keeps.
    #[test]
    fn the_error_with_every_target_is_the_last_of_every_count() {
        let (d, p, all) = wavy((37, 9, 4), (31, 17), |x, j| {
            (x * 0.37).sin() * (1.0 + (j as f32 * 0.5).cos())
        });
        let each = max_errors(&d, &p.positions, &p.weights, all);
        let last = max_error(&d, &p.positions, &p.weights, p.count);
        assert!(each[4] > 0.0);
        assert_eq!(last, each[4]);
    }

    /// The error pass, on whichever instruction set this machine
    /// dispatches it to, equals a plain loop of the same operations bit
    /// for bit: renders hash to the same ETag on every worker. 70
    /// vertices leave a partial step of lanes.
    #[test]
    fn the_error_pass_equals_a_plain_loop_bit_for_bit() {
        let (vertices, frames, count) = (70, 11, 5);
        let (d, p, all) = wavy((vertices, frames, count), (13, 7), |x, j| {
            (x * 0.91).sin() * (1.0 + j as f32 * 0.1)
        });
        let mut plain = vec![0f32; count + 1];
        for j in 0..frames {
            for v in 0..vertices {
                let mut r = d.vertex(j, v).to_array();
                for (k, worst) in plain.iter_mut().enumerate() {
                    if k > 0 {
                        let t = p.positions.vertex(k - 1, v).to_array();
                        let w = p.weights[j * count + k - 1];
                        for a in 0..3 {
                            r[a] -= t[a] * w;
                        }
                    }
                    let s = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
                    *worst = if s > *worst { s } else { *worst };
                }
            }
        }
        let plain: Vec<f32> = plain.into_iter().map(f32::sqrt).collect();
        let each = max_errors(&d, &p.positions, &p.weights, all);
        assert_eq!(bits(&each), bits(&plain));
        let last = max_error(&d, &p.positions, &p.weights, count);
        assert_eq!(last.to_bits(), plain[count].to_bits());
    }

    /// The clone this machine dispatches to and the baseline build of the
    /// same pass agree bit for bit, on every target count.
    #[test]
    fn the_dispatched_error_pass_equals_the_baseline_build() {
        let (vertices, frames, count) = (1500, 13, 6);
        let (d, p, pass) = wavy((vertices, frames, count), (29, 11), |x, j| {
            (x * 0.53).cos() * (0.5 + j as f32 * 0.07)
        });
        for each in [true, false] {
            let block = Block {
                d: &d,
                targets: &p.positions,
                weights: &p.weights,
                pass,
                each,
                range: 0..vertices,
                frames,
            };
            let (dispatched, baseline) = (block_errors(&block), portable_block_errors(&block));
            assert!(dispatched.iter().any(|&e| e > 0.0));
            assert_eq!(bits(&dispatched), bits(&baseline), "each: {each}");
        }
    }

    #[test]
    fn a_still_sequence_has_no_targets() {
        let mut d = Columns::new(3, 3);
        d.data.extend([0.0; 9]);
        let p = principal(&d, &d.clone(), 16);
        assert_eq!(p.count, 0);
        let none = Pass {
            count: 0,
            upto: 0,
            every: 1,
        };
        assert_eq!(max_errors(&d, &p.positions, &p.weights, none), vec![0.0]);
    }
}
