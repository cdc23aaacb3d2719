//! The skinned residual's targets, fitted where a player shows them.
//!
//! A skinned vertex's residual is its offset from its bind position in its
//! joint's frame; the player adds the targets' offsets there and the joint
//! then scales them by its scale at that instant. So a target error `e`
//! at sample `f` shows as `s_j(f) · e` on screen. The plain principal
//! displacements ([`super::motion::principal`]) weigh every sample alike:
//! a wilting joint's residual at scale 0.05, twenty times its world size,
//! outweighs everything else, and the targets spent on it then add its
//! offsets back where the joint is full size (the default morph's skinned
//! file was 1.1 m off at frame 0 on such a joint).
//!
//! Here the targets and weights minimise the error as shown,
//! `Σ_f Σ_v s_j(v)(f)² |r(f, v) − Σ_k w_fk T_k(v)|²`, by alternating least
//! squares from the principal directions of the motion as shown (as many
//! as the plain motion has; the plain principal displacements themselves
//! are formed only when this fit does not apply): with the weights
//! fixed, each vertex's targets solve a `K × K` system of its joint;
//! with the targets fixed, each sample's weights solve one of its own
//! (Srebro and Jaakkola 2003, "Weighted low-rank approximations").
//! Normals ride along: each vertex's normal targets solve the system of
//! the final weights with every sample alike (a joint turns a normal but
//! does not scale it). The targets come out ordered by how
//! much of the shown motion they carry, as the caller keeps the first
//! few, each count with the weights that fit every sample best with
//! those targets alone: a sample's weights on all the targets, cut to
//! the first few, can miss it by far more, as the targets are not
//! orthogonal in its weighting. The `K × K` systems are faer's; the
//! passes over vertices and samples are written here, as no crate does
//! this weighting.

use faer::linalg::solvers::Solve;
use faer::{Mat, Side};
use rayon::prelude::*;

use super::motion::{Columns, Principal};

/// Alternations (each a targets pass and a weights pass).
const ITERATIONS: usize = 4;

/// Vertices per block of the parallel passes.
const BLOCK: usize = 4096;

/// The vertex ranges of the parallel passes, [`BLOCK`] vertices each.
fn vertex_blocks(n: usize) -> impl IndexedParallelIterator<Item = std::ops::Range<usize>> {
    (0..n.div_ceil(BLOCK))
        .into_par_iter()
        .map(move |b| b * BLOCK..((b + 1) * BLOCK).min(n))
}

/// Which joint moves each vertex and each joint's scale at each sample.
pub(crate) struct Shown<'a> {
    pub(crate) vertex_joint: &'a [u32],
    /// `[joint][sample]`.
    pub(crate) scales: &'a [Vec<f32>],
}

impl Shown<'_> {
    fn weight(&self, j: usize, f: usize) -> f64 {
        let s = f64::from(self.scales[j][f]);
        s * s
    }

    /// The weights `s²` of the vertices `range` at sample `f`, into `out`.
    fn block_weights(&self, f: usize, range: std::ops::Range<usize>, out: &mut [f32]) {
        for (o, v) in out.iter_mut().zip(range) {
            let s = self.scales[self.vertex_joint[v] as usize][f];
            *o = s * s;
        }
    }
}

/// `k` targets and their weights fitted to the error as `shown`, for the
/// residual `d` (positions) and `nd` (normals); `None` when the shown
/// motion has fewer than `k` directions (or there is none to fit), where
/// the caller keeps the plain principal displacements.
pub(crate) fn refit(d: &Columns, nd: &Columns, shown: &Shown, k: usize) -> Option<Principal> {
    if k == 0 || d.count() == 0 {
        return None;
    }
    let mut weights = shown_start(d, shown, k)?;
    let (mut targets, mut fitted) = (Columns::default(), Fitted::default());
    for _ in 0..ITERATIONS {
        let systems = joint_systems(shown, &weights, k);
        targets = solve_targets(d, shown, &weights, &systems, k);
        (weights, fitted) = solve_weights(d, shown, &targets, k);
    }
    // A normal turns with its joint but does not scale: its targets are
    // fitted with every sample alike.
    let alike = vec![vec![1f32; d.count()]; shown.scales.len()];
    let unscaled = Shown {
        vertex_joint: shown.vertex_joint,
        scales: &alike,
    };
    let systems = joint_systems(&unscaled, &weights, k);
    let normals = solve_targets(nd, &unscaled, &weights, &systems, k);
    Some(ordered(targets, normals, (&weights, &fitted), k))
}

/// The starting weights: each sample's coordinates in the `k` principal
/// directions of the motion as shown (every residual times its joint's
/// scale), from the Gram matrix of those, summed over vertex blocks. The
/// plain principal displacements are a poor start: alternating from them
/// stays near the targets they spent on residuals that never show.
/// `None` when the shown motion has fewer than `k` directions.
fn shown_start(d: &Columns, shown: &Shown, k: usize) -> Option<Vec<f64>> {
    let n = d.rows / 3;
    let frames = d.count();
    let parts: Vec<Mat<f64>> = vertex_blocks(n)
        .map(|range| {
            let len = range.len();
            let mut sw = vec![0f32; len];
            let mut m = Mat::<f32>::zeros(3 * len, frames);
            for f in 0..frames {
                shown.block_weights(f, range.clone(), &mut sw);
                let col = d.column(f);
                for a in 0..3 {
                    for (i, v) in range.clone().enumerate() {
                        m[(a * len + i, f)] = sw[i].sqrt() * col[a * n + v];
                    }
                }
            }
            let g = m.transpose() * &m;
            Mat::<f64>::from_fn(frames, frames, |i, j| f64::from(g[(i, j)]))
        })
        .collect();
    let gram = parts
        .into_iter()
        .fold(Mat::<f64>::zeros(frames, frames), |a, b| a + b);
    let (sigmas, v) = super::motion::largest_eigen(&gram, k);
    if sigmas.len() < k {
        return None;
    }
    Some(
        (0..frames)
            .flat_map(|f| (0..k).map(move |t| (f, t)))
            .map(|(f, t)| v[(f, t)] * sigmas[t])
            .collect(),
    )
}

/// Per joint, the inverse of `Σ_f s_j(f)² w_f w_fᵀ` (a small ridge keeps a
/// joint that never shows solvable: its targets come out zero).
fn joint_systems(shown: &Shown, weights: &[f64], k: usize) -> Vec<Mat<f64>> {
    let frames = weights.len() / k;
    shown
        .scales
        .par_iter()
        .enumerate()
        .map(|(j, _)| {
            let mut m = Mat::<f64>::zeros(k, k);
            for f in 0..frames {
                let s = shown.weight(j, f);
                let w = &weights[f * k..(f + 1) * k];
                for a in 0..k {
                    for b in 0..k {
                        m[(a, b)] += s * w[a] * w[b];
                    }
                }
            }
            inverse(m)
        })
        .collect()
}

/// The inverse of the symmetric `m`, with a ridge of 1e-9 of its trace
/// (and an absolute floor) added to its diagonal.
fn inverse(mut m: Mat<f64>) -> Mat<f64> {
    let k = m.nrows();
    let trace: f64 = (0..k).map(|i| m[(i, i)]).sum();
    let ridge = (trace * 1e-9).max(1e-12);
    for i in 0..k {
        m[(i, i)] += ridge;
    }
    match m.llt(Side::Lower) {
        Ok(llt) => llt.solve(Mat::<f64>::identity(k, k)),
        Err(_) => Mat::zeros(k, k),
    }
}

/// Each vertex's targets with the weights fixed: its joint's inverse
/// times `Σ_f s² w_f r(f, v)`, per axis. Summed per vertex block, planar
/// (`[target][axis][vertex]`), so the inner loops run over contiguous
/// vertices.
fn solve_targets(
    d: &Columns,
    shown: &Shown,
    weights: &[f64],
    systems: &[Mat<f64>],
    k: usize,
) -> Columns {
    let n = d.rows / 3;
    let frames = d.count();
    let blocks: Vec<Vec<f32>> = vertex_blocks(n)
        .map(|range| {
            let len = range.len();
            let mut c = vec![0f32; k * 3 * len];
            let mut sw = vec![0f32; len];
            for f in 0..frames {
                shown.block_weights(f, range.clone(), &mut sw);
                let col = d.column(f);
                for a in 0..3 {
                    let r = &col[a * n + range.start..a * n + range.end];
                    for t in 0..k {
                        let w = weights[f * k + t] as f32;
                        let c = &mut c[(t * 3 + a) * len..(t * 3 + a + 1) * len];
                        for ((c, r), s) in c.iter_mut().zip(r).zip(&sw) {
                            *c += w * s * r;
                        }
                    }
                }
            }
            let mut out = vec![0f32; k * 3 * len];
            for (i, v) in range.clone().enumerate() {
                let inv = &systems[shown.vertex_joint[v] as usize];
                for a in 0..3 {
                    for t in 0..k {
                        let x: f64 = (0..k)
                            .map(|u| inv[(t, u)] * f64::from(c[(u * 3 + a) * len + i]))
                            .sum();
                        out[(t * 3 + a) * len + i] = x as f32;
                    }
                }
            }
            out
        })
        .collect();
    assemble(&blocks, n, k)
}

/// Planar target columns from the blocks' `[k][axis][vertex]` runs.
fn assemble(blocks: &[Vec<f32>], n: usize, k: usize) -> Columns {
    let mut out = Columns::new(3 * n, k);
    for t in 0..k {
        for a in 0..3 {
            for (b, block) in blocks.iter().enumerate() {
                let len = BLOCK.min(n - b * BLOCK);
                out.data
                    .extend_from_slice(&block[(t * 3 + a) * len..(t * 3 + a + 1) * len]);
            }
        }
    }
    out
}

/// What [`ordered`] needs again of the last weights pass: each sample's
/// system `A_f = Σ_j s_j(f)² G_j` (`G_j` the Gram matrix of joint `j`'s
/// targets) and right-hand side `b_f`. Restricted to the leading targets,
/// they are the systems of those targets alone.
#[derive(Default)]
struct Fitted {
    systems: Vec<Mat<f64>>,
    /// `b_f` at `[f · k ..]`.
    rhs: Vec<f64>,
}

impl Fitted {
    /// Sample `f`'s weights on the targets `among` (of `k`) that fit it
    /// best with those alone.
    fn weights(&self, f: usize, among: &[usize], k: usize) -> Vec<f64> {
        let a = &self.systems[f];
        let sub = Mat::<f64>::from_fn(among.len(), among.len(), |x, y| a[(among[x], among[y])]);
        let b: Vec<f64> = among.iter().map(|&t| self.rhs[f * k + t]).collect();
        solve(sub, &b)
    }
}

/// `inverse(a) · b`.
fn solve(a: Mat<f64>, b: &[f64]) -> Vec<f64> {
    let inv = inverse(a);
    (0..b.len())
        .map(|t| {
            b.iter()
                .enumerate()
                .map(|(u, bu)| inv[(t, u)] * bu)
                .sum::<f64>()
        })
        .collect()
}

/// Each sample's weights with the targets fixed: `A_f w_f = b_f`, with
/// `A_f = Σ_j s_j(f)² G_j` (`G_j` the Gram matrix of joint `j`'s targets)
/// and `b_f = Σ_v s² T(v) · r(f, v)`. The right-hand sides are summed
/// over vertex blocks, every sample of a block at once, so the targets
/// are read once per pass (a pass per sample read them sixty times and
/// took most of the refit). Returns the weights and the systems, which
/// [`ordered`] needs again for the last targets.
fn solve_weights(d: &Columns, shown: &Shown, targets: &Columns, k: usize) -> (Vec<f64>, Fitted) {
    let n = d.rows / 3;
    let frames = d.count();
    let grams = joint_grams(shown, targets, k);
    let parts: Vec<Vec<f64>> = vertex_blocks(n)
        .map(|range| {
            let mut rhs = vec![0f64; frames * k];
            let mut sw = vec![0f32; range.len()];
            for f in 0..frames {
                shown.block_weights(f, range.clone(), &mut sw);
                let col = d.column(f);
                for t in 0..k {
                    let target = targets.column(t);
                    let sum: f32 = (0..3)
                        .map(|a| {
                            let span = a * n + range.start..a * n + range.end;
                            weighted_dot(&sw, &target[span.clone()], &col[span])
                        })
                        .sum();
                    rhs[f * k + t] = f64::from(sum);
                }
            }
            rhs
        })
        .collect();
    // Summed in block order, so the same sequence gives the same bytes.
    let mut rhs = vec![0f64; frames * k];
    for part in &parts {
        for (r, p) in rhs.iter_mut().zip(part) {
            *r += p;
        }
    }
    let systems: Vec<Mat<f64>> = (0..frames)
        .into_par_iter()
        .map(|f| {
            let mut a = Mat::<f64>::zeros(k, k);
            for (j, g) in grams.iter().enumerate() {
                let s = shown.weight(j, f);
                for x in 0..k {
                    for y in 0..k {
                        a[(x, y)] += s * g[x * k + y];
                    }
                }
            }
            a
        })
        .collect();
    let fitted = Fitted { systems, rhs };
    let all: Vec<usize> = (0..k).collect();
    let weights = (0..frames)
        .into_par_iter()
        .flat_map_iter(|f| fitted.weights(f, &all, k))
        .collect();
    (weights, fitted)
}

/// `Σ_i s_i t_i r_i`, in [`LANES`] running sums so that it vectorises (a
/// single running sum is a chain of dependent additions).
fn weighted_dot(s: &[f32], t: &[f32], r: &[f32]) -> f32 {
    let mut lanes = [0f32; LANES];
    let chunks = s.len() / LANES * LANES;
    for ((s, t), r) in s[..chunks]
        .chunks_exact(LANES)
        .zip(t[..chunks].chunks_exact(LANES))
        .zip(r[..chunks].chunks_exact(LANES))
    {
        for i in 0..LANES {
            lanes[i] += s[i] * t[i] * r[i];
        }
    }
    let tail: f32 = (chunks..s.len()).map(|i| s[i] * t[i] * r[i]).sum();
    lanes.iter().sum::<f32>() + tail
}

/// Running sums of [`weighted_dot`].
const LANES: usize = 16;

/// Per joint, `Σ_{v ∈ j} Σ_axis T(v) T(v)ᵀ` (row-major `k × k`).
fn joint_grams(shown: &Shown, targets: &Columns, k: usize) -> Vec<Vec<f64>> {
    let n = targets.rows / 3;
    let columns: Vec<&[f32]> = (0..k).map(|t| targets.column(t)).collect();
    let mut grams = vec![vec![0f64; k * k]; shown.scales.len()];
    let mut row = vec![0f64; k];
    for v in 0..n {
        let g = &mut grams[shown.vertex_joint[v] as usize];
        for a in 0..3 {
            for (x, c) in row.iter_mut().zip(&columns) {
                *x = f64::from(c[a * n + v]);
            }
            for x in 0..k {
                for y in 0..k {
                    g[x * k + y] += row[x] * row[y];
                }
            }
        }
    }
    grams
}

/// The targets and weights as a [`Principal`], ordered by the shown
/// motion each carries (`Σ_f w_fk² A_f[k][k]`), largest first, with the
/// weights each leading count fits best with (`fitted`: the last weights
/// pass's systems, for the last targets).
fn ordered(
    targets: Columns,
    normals: Columns,
    (weights, fitted): (&[f64], &Fitted),
    k: usize,
) -> Principal {
    let frames = weights.len() / k;
    let energy: Vec<f64> = (0..k)
        .map(|t| {
            (0..frames)
                .map(|f| {
                    let w = weights[f * k + t];
                    let g = fitted.systems[f][(t, t)];
                    w * w * g
                })
                .sum()
        })
        .collect();
    let mut order: Vec<usize> = (0..k).collect();
    order.sort_by(|&a, &b| energy[b].total_cmp(&energy[a]).then(a.cmp(&b)));
    let pick = |c: &Columns| {
        let mut out = Columns::new(c.rows, k);
        for &t in &order {
            out.data.extend_from_slice(c.column(t));
        }
        out
    };
    Principal {
        positions: pick(&targets),
        normals: pick(&normals),
        weights: (0..frames)
            .flat_map(|f| order.iter().map(move |&t| weights[f * k + t] as f32))
            .collect(),
        count: k,
        leading: leading_weights(fitted, &order, frames),
    }
}

/// For each count `K` below all of `order`, each sample's weights on the
/// first `K` targets of `order` that fit it best with those alone
/// (`[f · K + t]`).
fn leading_weights(fitted: &Fitted, order: &[usize], frames: usize) -> Vec<Vec<f32>> {
    let k = order.len();
    (1..k)
        .into_par_iter()
        .map(|count| {
            (0..frames)
                .flat_map(|f| {
                    let w = fitted.weights(f, &order[..count], k);
                    w.into_iter().map(|w| w as f32)
                })
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// A vertex's offset at sample `f` from the first `upto` targets.
    fn offset(p: &Principal, f: usize, v: usize, upto: usize) -> Vec3 {
        (0..upto)
            .map(|t| p.positions.vertex(t, v) * p.weights[f * p.count + t])
            .sum()
    }

    /// Two joints of two vertices each over three samples: joint 0 at
    /// full scale moves along x, joint 1 is tiny in samples 1 and 2, where
    /// its residual (divided by that scale) is huge along y.
    fn case() -> (Columns, Vec<u32>, Vec<Vec<f32>>) {
        let n = 4;
        let mut d = Columns::new(3 * n, 3);
        let moves: [[Vec3; 4]; 3] = [
            [2.0 * Vec3::X, 2.0 * Vec3::X, Vec3::ZERO, Vec3::ZERO],
            [
                4.0 * Vec3::X,
                4.0 * Vec3::X,
                50.0 * Vec3::Y,
                -50.0 * Vec3::Y,
            ],
            [
                -2.0 * Vec3::X,
                -2.0 * Vec3::X,
                -40.0 * Vec3::Y,
                40.0 * Vec3::Y,
            ],
        ];
        for m in &moves {
            for a in 0..3 {
                d.data.extend(m.iter().map(|p| p[a]));
            }
        }
        (
            d,
            vec![0, 0, 1, 1],
            vec![vec![1.0; 3], vec![1.0, 0.01, 0.01]],
        )
    }

    /// The shown squared error of sample `f` with the first `k` targets of
    /// `p` and `weights` (`[f · k + t]`).
    fn shown_squared(
        d: &Columns,
        p: &Principal,
        (joints, scales): (&[u32], &[Vec<f32>]),
        f: usize,
        (k, weights): (usize, &[f32]),
    ) -> f64 {
        (0..joints.len())
            .map(|v| {
                let approx: Vec3 = (0..k)
                    .map(|t| p.positions.vertex(t, v) * weights[f * k + t])
                    .sum();
                let s = scales[joints[v] as usize][f];
                f64::from(s * s * (d.vertex(f, v) - approx).length_squared())
            })
            .sum()
    }

    /// Regression: the skinned residual's target count was chosen with
    /// each sample's weights on all the targets cut to the leading ones.
    /// A weighted fit's targets are not orthogonal in a sample's
    /// weighting, so those cut weights missed samples by far more than
    /// the leading targets need (default morph, 256 joints: 0.97 m with
    /// 2 of 16 targets, 4.99 m with 4). Each leading count's own weights
    /// fit every sample at least as well, and all the targets keep the
    /// fit's weights.
    #[test]
    fn leading_targets_carry_the_weights_that_fit_them_alone() {
        let (n, frames, joints_count) = (60, 9, 4);
        let noise = |i: usize| ((i as f32 * 12.9898).sin() * 43_758.547).fract();
        let mut d = Columns::new(3 * n, frames);
        for f in 0..frames {
            d.data
                .extend((0..3 * n).map(|r| noise(f * 1_000 + r) * (1.0 + f as f32)));
        }
        let joints: Vec<u32> = (0..n).map(|v| (v % joints_count) as u32).collect();
        let scales: Vec<Vec<f32>> = (0..joints_count)
            .map(|j| {
                (0..frames)
                    .map(|f| if (j + f) % 3 == 0 { 0.02 } else { 1.0 })
                    .collect()
            })
            .collect();
        let shown = Shown {
            vertex_joint: &joints,
            scales: &scales,
        };
        let p = refit(&d, &d, &shown, 5).expect("five shown directions");
        assert_eq!(p.leading_weights(5).as_ref(), p.weights.as_slice());
        let mut gain = 1f64;
        for k in 1..5 {
            let own = p.leading_weights(k);
            let cut: Vec<f32> = (0..frames)
                .flat_map(|f| p.weights[f * 5..f * 5 + k].to_vec())
                .collect();
            for f in 0..frames {
                let with_own = shown_squared(&d, &p, (&joints, &scales), f, (k, &own));
                let with_cut = shown_squared(&d, &p, (&joints, &scales), f, (k, &cut));
                assert!(
                    with_own <= with_cut * (1.0 + 1e-4) + 1e-9,
                    "{k} targets, sample {f}: {with_own} > {with_cut}"
                );
                gain = gain.max(with_cut / with_own.max(1e-12));
            }
        }
        assert!(
            gain > 1.1,
            "the cut weights were nearly the best everywhere: {gain}"
        );
        let mut kept = p.clone();
        kept.truncate(2);
        assert_eq!(
            (kept.count, kept.weights.as_slice()),
            (2, p.leading_weights(2).as_ref())
        );
        assert_eq!(kept.positions.data, p.positions.data[..2 * 3 * n]);
    }

    #[test]
    fn one_target_goes_where_it_shows() {
        let (d, joints, scales) = case();
        let shown = Shown {
            vertex_joint: &joints,
            scales: &scales,
        };
        let plain = super::super::motion::principal(&d, &d, 1);
        // The plain target follows the tiny joint's big residual and
        // leaves joint 0's motion, which shows at full size, unexplained.
        let shown_error = |p: &Principal| {
            let mut worst = 0f32;
            for (v, &j) in joints.iter().enumerate() {
                for (f, &s) in scales[j as usize].iter().enumerate() {
                    let e = (d.vertex(f, v) - offset(p, f, v, 1)).length() * s;
                    worst = worst.max(e);
                }
            }
            worst
        };
        let refitted = refit(&d, &d, &shown, plain.count).expect("one shown direction");
        assert!(shown_error(&plain) > 1.5, "{}", shown_error(&plain));
        assert!(shown_error(&refitted) < 0.6, "{}", shown_error(&refitted));
    }

    /// Nothing to fit, or fewer shown directions than asked: the caller
    /// keeps the plain principal displacements.
    #[test]
    fn no_fit_without_enough_shown_motion() {
        let (d, joints, _) = case();
        let hidden = vec![vec![0.0; 3], vec![0.0; 3]];
        let shown = Shown {
            vertex_joint: &joints,
            scales: &hidden,
        };
        assert!(refit(&d, &d, &shown, 1).is_none());
        assert!(refit(&d, &d, &shown, 0).is_none());
        assert!(refit(&Columns::default(), &Columns::default(), &shown, 1).is_none());
    }

    #[test]
    fn an_exact_low_rank_residual_stays_exact() {
        let (d, joints, _) = case();
        let scales = vec![vec![1.0, 0.5, 0.25], vec![0.3, 1.0, 0.7]];
        let shown = Shown {
            vertex_joint: &joints,
            scales: &scales,
        };
        let refitted = refit(&d, &d, &shown, 2).expect("two shown directions");
        for f in 0..3 {
            for v in 0..4 {
                let e = (d.vertex(f, v) - offset(&refitted, f, v, 2)).length();
                assert!(e < 1e-3, "sample {f} vertex {v}: {e}");
            }
        }
    }
}
