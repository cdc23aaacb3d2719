//! Which morph targets carry normals.
//!
//! A target's normals cost as many bytes as its positions (float: 12 bytes
//! per vertex each). The positions of every target are needed to hold
//! every vertex within the position budget; the normals of the later
//! targets change little of what a viewer sees. So normals ride on the
//! **leading** targets only: the fewest whose normals keep every sample's
//! *mean* normal error within [`NORMAL_BUDGET_DEGREES`], or, when all the
//! position targets' normals do not reach it, the fewest within
//! [`NORMAL_SLACK_DEGREES`] of what all of them give. The other targets'
//! NORMAL accessors have no buffer view: glTF reads them as zeros, at no
//! cost in the file.
//!
//! - **Why the mean.** A normal's error is the angle between the normal a
//!   player computes (base plus the weighted targets, normalised) and the
//!   sample's exact normal. Its tail is set by the basis itself, not by
//!   how many targets carry normals: on the default maple → conifer morph
//!   (5,000 branches, 16 targets) the worst sample's 99th percentile is
//!   35° with the normals of all 16 targets and 46° with 6 of them, from
//!   vertices on twigs that turn over and leaves that fold. The mean says
//!   how the crown shades as a whole: 1.7° with all 16 targets, 3.0° with
//!   6, 45.7° with none.
//! - **Why 5°.** A Lambertian surface's brightness changes by less than
//!   `1 − cos 5° < 0.4 %` of its light for a normal 5° off along the
//!   light, and by at most `sin 5° ≈ 9 %` of it across; on moving foliage
//!   of many small leaves that is below what a viewer tells apart.
//! - **Measured on a sample.** The mean is taken over every `stride`-th
//!   vertex (at most [`SAMPLED_VERTICES`] of them), for every sample, from
//!   no target upwards until the budget is met: a mean does not need
//!   every vertex (its standard error over 4,096 vertices is a few tenths
//!   of a degree), and the measure then costs about 25 ms whatever the
//!   tree's size, where every vertex and target count of a 5,000-branch
//!   morph took half a second.
//!
//! On the default morph 3 of 16 targets carry normals (4.6°): 42.7 MB as
//! float, against 64.9 MB with normals on every target. On a 20,000-chain
//! morph 5 of 16 do (4.0°): 147 MB against 207 MB.

use glam::Vec3;
use rayon::prelude::*;

use super::motion::{Columns, Principal};

/// The largest mean normal error (degrees) of any sample that the normals
/// of the leading targets may leave.
pub(crate) const NORMAL_BUDGET_DEGREES: f32 = 5.0;

/// When all the targets' normals leave more than the budget: how far
/// above their error the fewest leading targets may stay.
const NORMAL_SLACK_DEGREES: f32 = 0.25;

/// Most vertices the mean error is measured on.
const SAMPLED_VERTICES: usize = 4_096;

/// How many of the first `count` targets of `principal` carry normals, and
/// the largest mean normal error (degrees) of any sample that leaves:
/// `base_normals` plus the sample's `normal_changes` are its exact
/// normals. Target counts are measured from none upwards and the first
/// within budget ends the search (most sequences need a few of 16).
pub(crate) fn leading_normals(
    base_normals: &[Vec3],
    normal_changes: &Columns,
    principal: &Principal,
    count: usize,
) -> (usize, f32) {
    let mut sampled = Sampled::new(base_normals, normal_changes, principal, count);
    let mut errors = Vec::with_capacity(count + 1);
    for k in 0..=count {
        let error = sampled.worst_mean_with(k);
        if error <= NORMAL_BUDGET_DEGREES {
            return (k, error);
        }
        errors.push(error);
    }
    let all = errors[count];
    let k = errors
        .iter()
        .position(|&e| e <= all + NORMAL_SLACK_DEGREES)
        .unwrap_or(count);
    (k, errors[k])
}

/// The sampled vertices of every sample: exact normals, and the normals
/// of the leading targets so far. Gathered once: read in place, each
/// vertex touched a cache line per target and axis, and the measure took
/// half a second on a 5,000-branch morph instead of a few tens of
/// milliseconds.
struct Sampled<'a> {
    principal: &'a Principal,
    /// Per target: the sampled vertices' normal changes.
    targets: Vec<Vec<Vec3>>,
    /// Per sample: the sampled vertices' exact unit normals.
    exact: Vec<Vec<Vec3>>,
    /// Per sample: base plus the weighted targets added so far.
    approx: Vec<Vec<Vec3>>,
    /// How many targets `approx` holds.
    added: usize,
}

impl<'a> Sampled<'a> {
    fn new(
        base_normals: &[Vec3],
        normal_changes: &Columns,
        principal: &'a Principal,
        count: usize,
    ) -> Sampled<'a> {
        let n = base_normals.len();
        let stride = n.div_ceil(SAMPLED_VERTICES).max(1);
        let sampled: Vec<usize> = (0..n).step_by(stride).collect();
        let base: Vec<Vec3> = sampled.iter().map(|&v| base_normals[v]).collect();
        let targets = (0..count)
            .map(|k| {
                sampled
                    .iter()
                    .map(|&v| principal.normals.vertex(k, v))
                    .collect()
            })
            .collect();
        let exact = (0..normal_changes.count())
            .into_par_iter()
            .map(|f| {
                sampled
                    .iter()
                    .zip(&base)
                    .map(|(&v, b)| (*b + normal_changes.vertex(f, v)).normalize_or_zero())
                    .collect()
            })
            .collect();
        Sampled {
            principal,
            targets,
            approx: vec![base; normal_changes.count()],
            exact,
            added: 0,
        }
    }

    /// The largest over the samples of the mean angle (degrees) between
    /// the normals of the first `k` targets and the exact ones; `k` never
    /// below the last call's.
    fn worst_mean_with(&mut self, k: usize) -> f32 {
        let (principal, targets, added) = (self.principal, &self.targets, self.added);
        let worst = self
            .approx
            .par_iter_mut()
            .zip(&self.exact)
            .enumerate()
            .map(|(f, (approx, exact))| {
                let weights = &principal.weights[f * principal.count..];
                for (t, target) in targets.iter().enumerate().take(k).skip(added) {
                    for (a, d) in approx.iter_mut().zip(target) {
                        *a += *d * weights[t];
                    }
                }
                let sum: f64 = approx
                    .iter()
                    .zip(exact)
                    .map(|(a, e)| f64::from(angle_degrees(*a, *e)))
                    .sum();
                (sum / approx.len().max(1) as f64) as f32
            })
            .reduce(|| 0.0, f32::max);
        self.added = k;
        worst
    }
}

/// The angle between `a` (any length) and the unit `exact`; 0 between two
/// zero normals (a collapsed vertex has none to be wrong).
fn angle_degrees(a: Vec3, exact: Vec3) -> f32 {
    let a = a.normalize_or_zero();
    if a == Vec3::ZERO && exact == Vec3::ZERO {
        return 0.0;
    }
    a.dot(exact).clamp(-1.0, 1.0).acos().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Principal targets of one vertex whose normal turns by the given
    /// per-target changes, one sample with every weight 1.
    fn principal(changes: &[Vec3]) -> Principal {
        let mut normals = Columns::new(3, changes.len());
        let mut positions = Columns::new(3, changes.len());
        for c in changes {
            normals.data.extend(c.to_array());
            positions.data.extend([0.0; 3]);
        }
        Principal {
            positions,
            normals,
            weights: vec![1.0; changes.len()],
            count: changes.len(),
            leading: Vec::new(),
        }
    }

    fn sample(change: Vec3) -> Columns {
        let mut c = Columns::new(3, 1);
        c.data.extend(change.to_array());
        c
    }

    #[test]
    fn still_normals_need_no_target() {
        let p = principal(&[Vec3::ZERO, Vec3::ZERO]);
        let (k, error) = leading_normals(&[Vec3::Y], &sample(Vec3::ZERO), &p, 2);
        assert_eq!((k, error), (0, 0.0));
    }

    #[test]
    fn a_turn_beyond_the_budget_takes_the_targets_that_make_it() {
        // The normal turns from +Y to +X: 90° without targets, 45° with
        // the first, none with both.
        let p = principal(&[Vec3::X, -Vec3::Y]);
        let exact = Vec3::X - Vec3::Y;
        let mut sampled = Sampled::new(&[Vec3::Y], &sample(exact), &p, 2);
        let errors: Vec<f32> = (0..=2).map(|k| sampled.worst_mean_with(k)).collect();
        assert!((errors[0] - 90.0).abs() < 1e-3, "{errors:?}");
        assert!((errors[1] - 45.0).abs() < 1e-3, "{errors:?}");
        assert!(errors[2] < 1e-3, "{errors:?}");
        assert_eq!(leading_normals(&[Vec3::Y], &sample(exact), &p, 2).0, 2);
    }

    #[test]
    fn a_small_last_turn_is_left_out() {
        // The second target turns the normal by about 2°: within budget
        // without it.
        let small = Vec3::new(0.0, 0.0, 0.035);
        let p = principal(&[Vec3::X - Vec3::Y, small]);
        let change = Vec3::X - Vec3::Y + small;
        let (k, error) = leading_normals(&[Vec3::Y], &sample(change), &p, 2);
        assert_eq!(k, 1);
        assert!(error > 1.0 && error < NORMAL_BUDGET_DEGREES, "{error}");
    }

    #[test]
    fn short_of_the_budget_the_fewest_near_the_best_are_kept() {
        // A target that only lengthens the normal does not turn it: the
        // normal turned the other way stays 180° off, so none is kept.
        let p = principal(&[Vec3::Y]);
        let (k, _) = leading_normals(&[Vec3::Y], &sample(-2.0 * Vec3::Y), &p, 1);
        assert_eq!(k, 0);
    }
}
