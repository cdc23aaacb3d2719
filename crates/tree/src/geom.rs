//! Small geometry shared by every stage: the point-to-segment projection
//! and the "no index" sentinel.
//!
//! The projection is written once so that the analysis, the importer, the
//! morph and the sketch metrics agree to the last bit on which point of a
//! polyline is nearest: they compare those distances against each other's
//! output.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::ops::{Add, Mul, Sub};

use glam::{DVec2, IVec3, Vec2, Vec3};

/// "No index" in `u32` index arrays (no parent, no vertex, not yet
/// visited, no owner). Index arrays stay plain `u32` rather than
/// `Option<u32>` because they are large and scanned in hot loops; every
/// valid index is below the array's length, which never reaches
/// `u32::MAX`.
pub const NONE: u32 = u32::MAX;

/// Points a segment can be projected in: glam's `Vec2`, `Vec3` and `DVec2`.
pub trait SegmentPoint:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Self::Scalar, Output = Self>
{
    /// The coordinate type (`f32` or `f64`).
    type Scalar: Copy;

    /// See [`segment_param`].
    fn segment_param(self, a: Self, b: Self) -> Self::Scalar;

    /// Euclidean distance to `other`.
    fn distance(self, other: Self) -> Self::Scalar;
}

macro_rules! segment_point {
    ($point:ty, $scalar:ty) => {
        impl SegmentPoint for $point {
            type Scalar = $scalar;

            #[inline]
            fn segment_param(self, a: Self, b: Self) -> $scalar {
                let ab = b - a;
                let len2 = ab.length_squared();
                if len2 > 0.0 {
                    ((self - a).dot(ab) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                }
            }

            #[inline]
            fn distance(self, other: Self) -> $scalar {
                <$point>::distance(self, other)
            }
        }
    };
}

segment_point!(Vec2, f32);
segment_point!(Vec3, f32);
segment_point!(DVec2, f64);

/// Squared distance between segments `p1q1` and `p2q2` (Ericson 5.1.9).
pub fn segment_segment_sq(p1: Vec3, q1: Vec3, p2: Vec3, q2: Vec3) -> f32 {
    let (d1, d2, r) = (q1 - p1, q2 - p2, p1 - p2);
    let (a, e, f) = (d1.length_squared(), d2.length_squared(), d2.dot(r));
    const EPS: f32 = 1e-20;
    let (s, t);
    if a <= EPS && e <= EPS {
        return p1.distance_squared(p2);
    }
    if a <= EPS {
        s = 0.0;
        t = (f / e).clamp(0.0, 1.0);
    } else {
        let c = d1.dot(r);
        if e <= EPS {
            t = 0.0;
            s = (-c / a).clamp(0.0, 1.0);
        } else {
            let b = d1.dot(d2);
            let denom = a * e - b * b;
            let s0 = if denom > 0.0 {
                ((b * f - c * e) / denom).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let t0 = (b * s0 + f) / e;
            if t0 < 0.0 {
                t = 0.0;
                s = (-c / a).clamp(0.0, 1.0);
            } else if t0 > 1.0 {
                t = 1.0;
                s = ((b - c) / a).clamp(0.0, 1.0);
            } else {
                t = t0;
                s = s0;
            }
        }
    }
    (p1 + d1 * s).distance_squared(p2 + d2 * t)
}

/// Fraction along segment `a`–`b` of the point closest to `p`, in [0, 1];
/// 0 when the segment has zero length (then every point of it is `a`).
#[inline]
pub fn segment_param<P: SegmentPoint>(p: P, a: P, b: P) -> P::Scalar {
    p.segment_param(a, b)
}

/// Closest point to `p` on segment `a`–`b`, and its fraction along the
/// segment ([`segment_param`]).
#[inline]
pub fn closest_on_segment<P: SegmentPoint>(p: P, a: P, b: P) -> (P, P::Scalar) {
    let f = p.segment_param(a, b);
    (a + (b - a) * f, f)
}

/// Distance from `p` to segment `a`–`b`.
#[inline]
pub fn distance_to_segment<P: SegmentPoint>(p: P, a: P, b: P) -> P::Scalar {
    p.distance(closest_on_segment(p, a, b).0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projects_inside_clamps_outside_and_survives_zero_length() {
        let (a, b) = (Vec3::ZERO, Vec3::new(2.0, 0.0, 0.0));
        assert_eq!(
            closest_on_segment(Vec3::new(0.5, 1.0, 0.0), a, b),
            (Vec3::new(0.5, 0.0, 0.0), 0.25)
        );
        assert_eq!(segment_param(Vec3::new(-1.0, 0.0, 0.0), a, b), 0.0);
        assert_eq!(segment_param(Vec3::new(3.0, 0.0, 0.0), a, b), 1.0);
        assert_eq!(
            closest_on_segment(Vec2::ONE, Vec2::ZERO, Vec2::ZERO),
            (Vec2::ZERO, 0.0)
        );
        assert_eq!(
            segment_param(DVec2::new(1.0, 5.0), DVec2::ZERO, DVec2::X * 4.0),
            0.25
        );
        assert_eq!(distance_to_segment(Vec3::new(5.0, 4.0, 0.0), a, b), 5.0);
    }
}

/// A map keyed by grid cell, hashed multiplicatively: SipHash, the
/// default, cost more than the work done per cell in the spatial grids
/// that use it (lobe clustering, branch crossings).
pub type CellMap<V> = HashMap<IVec3, V, BuildHasherDefault<CellHasher>>;

/// The hasher of [`CellMap`].
#[derive(Clone, Copy, Debug, Default)]
pub struct CellHasher(u64);

// `#[inline]`: the maps that use it are instantiated in other crates.
impl Hasher for CellHasher {
    #[inline]
    fn finish(&self) -> u64 {
        self.0
    }

    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }

    #[inline]
    fn write_i32(&mut self, v: i32) {
        self.write_u64(u64::from(v as u32));
    }

    #[inline]
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(21) ^ v).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
}
