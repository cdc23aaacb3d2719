//! Animation time, shared by the plan, the sketcher and the metrics.

/// Clamps an animation time into [0, 1]; NaN is 0.
pub(crate) fn clamp_t(t: f32) -> f32 {
    if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) }
}
