//! When things move: the schedule options shared by the morph and the
//! sketch pipelines, and the eased windows of `t` they are built from.
//!
//! Both pipelines animate over t ∈ [0, 1]. A **linear** schedule runs
//! every chain on `t` itself; a **staged** one gives each chain its own
//! [`Window`] of `t` (wilting first, parents before their twigs) and eases
//! inside it ([`Ease`]). The phases themselves — which operations go in
//! which window — are each pipeline's own (see their crate docs).

use std::ops::RangeInclusive;

use serde::{Deserialize, Serialize};

use crate::frame::{Frame, JumpMeter};

/// The shed phase: wilting chains and leaves go first.
pub const SHED: [f32; 2] = [0.0, 0.45];

/// When the reshaping chains move while something wilts (and, in a
/// morph, something grows): they start once shedding is under way.
pub const RESHAPE: [f32; 2] = [0.1, 0.9];

/// When the operations of an animation happen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ScheduleKind {
    /// Every chain and leaf on one linear clock over all of [0, 1]: a
    /// morph's growth and wilt scale about the junction, as before
    /// schedules.
    Linear,
    /// First shed, then reshape (then, in a morph, grow); parents lead
    /// their children; each window eased (default).
    #[default]
    Staged,
}

/// How a [`ScheduleKind::Staged`] animation is timed; ignored by
/// [`ScheduleKind::Linear`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[non_exhaustive]
pub struct ScheduleOptions {
    /// Linear or staged (default).
    pub kind: ScheduleKind,
    /// How far the starts of one phase's windows spread, as a fraction of
    /// the phase: 0 moves every chain together, 0.3 (default) starts the
    /// deepest twigs 30 % of a phase after the trunk; each window lasts the
    /// phase less the stagger. In [0, 0.9].
    pub stagger: f32,
    /// Fraction of each window spent accelerating, and as much
    /// decelerating, at constant acceleration (default 0.25: C¹ at the
    /// window ends, top speed 4/3 of the mean). 0 is constant speed, 0.5
    /// accelerates for half the window. In [0, 0.5].
    pub easing: f32,
}

impl Default for ScheduleOptions {
    fn default() -> ScheduleOptions {
        ScheduleOptions {
            kind: ScheduleKind::Staged,
            stagger: 0.3,
            easing: 0.25,
        }
    }
}

impl ScheduleOptions {
    /// The linear clock of the animations before schedules.
    pub fn linear() -> ScheduleOptions {
        ScheduleOptions {
            kind: ScheduleKind::Linear,
            ..ScheduleOptions::default()
        }
    }

    /// The first field out of range, as (`schedule.<field>`, why); each
    /// pipeline wraps it in its own error.
    pub fn invalid_field(&self) -> Option<(&'static str, String)> {
        [
            ("schedule.stagger", self.stagger, 0.9),
            ("schedule.easing", self.easing, 0.5),
        ]
        .into_iter()
        .find(|&(_, v, max)| !(v.is_finite() && (0.0..=max).contains(&v)))
        .map(|(option, v, max)| (option, format!("must be a number in [0, {max}], got {v}")))
    }
}

/// A window of `t`, stored as its start and inverse length.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Window {
    start: f32,
    inv_len: f32,
}

impl Window {
    /// All of [0, 1].
    pub const FULL: Window = Window {
        start: 0.0,
        inv_len: 1.0,
    };

    /// `[start, end]`, `end > start`.
    pub fn new(start: f32, end: f32) -> Window {
        Window {
            start,
            inv_len: 1.0 / (end - start),
        }
    }

    /// A window starting `delay` (a fraction, clamped to [0, 1]) of the
    /// `stagger` into `phase` and lasting the phase's `1 − stagger`.
    pub fn staggered(phase: [f32; 2], stagger: f32, delay: f32) -> Window {
        let len = phase[1] - phase[0];
        let start = phase[0] + stagger * delay.clamp(0.0, 1.0) * len;
        Window::new(start, start + (1.0 - stagger) * len)
    }

    /// When the window opens.
    pub fn start(self) -> f32 {
        self.start
    }

    /// When the window closes.
    pub fn end(self) -> f32 {
        self.start + 1.0 / self.inv_len
    }

    /// Where `t` is in the window, clamped to [0, 1].
    pub fn local(self, t: f32) -> f32 {
        ((t - self.start) * self.inv_len).clamp(0.0, 1.0)
    }
}

/// Constant acceleration over the first `a` of a window, constant speed,
/// constant deceleration over the last `a`: C¹ for `a > 0`, exactly 0 at 0
/// and 1 at 1.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Ease {
    a: f32,
    /// Top speed, `1 / (1 − a)`.
    v: f32,
}

impl Ease {
    /// Easing over `a` ∈ [0, 0.5] at each end.
    pub fn new(a: f32) -> Ease {
        Ease {
            a,
            v: 1.0 / (1.0 - a),
        }
    }

    /// No easing: the identity.
    pub const NONE: Ease = Ease { a: 0.0, v: 1.0 };

    /// The eased position at `x ∈ [0, 1]`.
    pub fn at(self, x: f32) -> f32 {
        let (a, v) = (self.a, self.v);
        if a == 0.0 {
            x
        } else if x < a {
            0.5 * v * x * x / a
        } else if x > 1.0 - a {
            let y = 1.0 - x;
            1.0 - 0.5 * v * y * y / a
        } else {
            v * (x - 0.5 * a)
        }
    }
}

/// Share of the mean motion per sample every stretch keeps, however still.
const PACE_FLOOR: f32 = 0.05;

/// Even pacing of a staged animation. Windows of different lengths and
/// depths leave some stretches of `t` busy and others nearly still; a
/// pace plays the motion so that the share of it covered by `t` follows
/// the easing over the whole animation: every frame moves about as far as
/// the next, with a gentle start and end. The motion is sampled at even
/// instants (the farthest any node or leaf corner moves between
/// neighbours; a morph takes 64, and 4 times as many where those find a
/// burst, [`Pace::concentrated`]); a little time (5 % of the mean) is kept
/// for every stretch, so nothing is skipped.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Pace {
    /// Share of the motion covered at `τ = i / (len − 1)`, increasing from
    /// exactly 0 to exactly 1.
    covered: Vec<f32>,
    ease: Ease,
}

impl Pace {
    /// Paces the motion `frame_at` makes (it writes the unpaced frame at
    /// `τ` into the frame given), sampled `samples` times after τ = 0;
    /// `None` when nothing moves.
    pub fn measure(
        samples: usize,
        easing: f32,
        frame_at: impl FnMut(f32, &mut Frame),
    ) -> Option<Pace> {
        Pace::of_moves(&Pace::moves(samples, 1..=samples, frame_at), easing)
    }

    /// How far the motion `frame_at` makes moves from even sample `i − 1`
    /// to sample `i` (of `samples` after τ = 0), for each `i` of `span`
    /// (within `1..=samples`). Runs of samples ([`Pace::runs`]) can be
    /// measured apart, in parallel, and their moves joined for
    /// [`Pace::of_moves`]: the same moves as [`Pace::measure`]'s.
    pub fn moves(
        samples: usize,
        span: RangeInclusive<usize>,
        mut frame_at: impl FnMut(f32, &mut Frame),
    ) -> Vec<f32> {
        let at = |i: usize| i as f32 / samples as f32;
        let mut frame = Frame::default();
        let mut jumps = JumpMeter::default();
        frame_at(at(span.start().saturating_sub(1)), &mut frame);
        jumps.jump(&frame);
        span.map(|i| {
            frame_at(at(i), &mut frame);
            jumps.jump(&frame)
        })
        .collect()
    }

    /// Whether a motion sampled into `moved` ([`Pace::moves`]) is
    /// concentrated beyond what its samples resolve: one interval moves more
    /// than [`Pace::CONCENTRATED`] times the mean. A pace is linear in `τ`
    /// inside each interval, so a burst within one bunches into the frames
    /// that fall there; measured [`Pace::REFINE`] times as finely, it is
    /// spread like the rest.
    pub fn concentrated(moved: &[f32]) -> bool {
        let mean = moved.iter().sum::<f32>() / moved.len().max(1) as f32;
        mean > 0.0 && moved.iter().any(|&d| d > Pace::CONCENTRATED * mean)
    }

    /// See [`Pace::concentrated`]. On the ten third-party trees CI makes
    /// (the 50 morphs between their two families, 60 frames), the morphs
    /// whose largest move in a frame was over twice the median one first
    /// had a 64-sample interval moving 4.0–7.8 times the mean. Once
    /// tip-first subtrees kept off their hosts' reshape, the limbs'
    /// reshape stands more alone, and a limb whose junction slides
    /// through a sharp bend of its parent (an imported pine's hooked trunk
    /// top) swings in a burst that 64 samples left at 2.21 times the median
    /// move with the mean under 4 times: at 2, every one of the 50 is
    /// within 1.5. Refined plans take about 0.13–0.15 s longer to plan.
    pub const CONCENTRATED: f32 = 2.0;

    /// How many times as finely a concentrated motion is sampled again.
    /// On those morphs, 64 × 4 samples brought the largest move in a frame
    /// from 2.10–2.67 to 1.20–1.47 times the median (× 2 left one at
    /// 1.79).
    pub const REFINE: usize = 4;

    /// `1..=samples` cut into `count` (at least 1) consecutive runs of
    /// about equal length, for [`Pace::moves`].
    pub fn runs(samples: usize, count: usize) -> Vec<RangeInclusive<usize>> {
        let per_run = samples.div_ceil(count.max(1)).max(1);
        (1..=samples)
            .step_by(per_run)
            .map(|start| start..=(start + per_run - 1).min(samples))
            .collect()
    }

    /// The pace of a motion that moves `moved[i]` between its even
    /// samples `i` and `i + 1`; `None` when nothing moves.
    pub fn of_moves(moved: &[f32], easing: f32) -> Option<Pace> {
        let mean = moved.iter().sum::<f32>() / moved.len().max(1) as f32;
        if !(mean > 0.0 && mean.is_finite()) {
            return None;
        }
        let mut covered = Vec::with_capacity(moved.len() + 1);
        covered.push(0.0f64);
        for d in moved {
            let last = *covered.last().expect("one");
            covered.push(last + f64::from(d + PACE_FLOOR * mean));
        }
        let total = *covered.last().expect("samples");
        let mut covered: Vec<f32> = covered.iter().map(|c| (c / total) as f32).collect();
        *covered.last_mut().expect("samples") = 1.0;
        Some(Pace {
            covered,
            ease: Ease::new(easing),
        })
    }

    /// The unpaced time `τ` at `t`: exactly 0 at 0 and 1 at 1.
    pub fn at(&self, t: f32) -> f32 {
        let m = self.ease.at(t.clamp(0.0, 1.0));
        let c = &self.covered;
        if m <= 0.0 {
            return 0.0;
        }
        if m >= 1.0 {
            return 1.0;
        }
        let i = (c.partition_point(|&x| x <= m) - 1).min(c.len() - 2);
        let f = ((m - c[i]) / (c[i + 1] - c[i])).clamp(0.0, 1.0);
        (i as f32 + f) / (c.len() - 1) as f32
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;

    use super::*;

    /// Two nodes moving unevenly: the second accelerates.
    fn frame_at(t: f32, frame: &mut Frame) {
        frame.t = t;
        frame.positions = vec![Vec3::new(t, 0.0, 0.0), Vec3::new(0.0, t * t * t, 1.0)];
    }

    /// Runs cover `1..=samples` in order, once each, however many.
    #[test]
    fn runs_cover_every_sample_once() {
        for (samples, count) in [(64, 2), (64, 3), (24, 5), (3, 8), (1, 1), (10, 0)] {
            let joined: Vec<usize> = Pace::runs(samples, count).into_iter().flatten().collect();
            assert_eq!(
                joined,
                (1..=samples).collect::<Vec<_>>(),
                "{samples} in {count}"
            );
        }
    }

    /// A node still but for a burst narrower than one of 64 intervals:
    /// paced from 64 samples, the frames that fall in the burst's interval
    /// share it evenly in `τ`, so the burst's own frames leap; measured
    /// again 4 times as finely, as a concentrated motion is, the 60 paced
    /// frames move about alike.
    #[test]
    fn a_burst_within_one_interval_is_paced_from_finer_samples() {
        let burst = |t: f32, frame: &mut Frame| {
            let x = (t - 0.508) / 0.002;
            frame.t = t;
            frame.positions = vec![Vec3::new(0.01 * t + 1.0 / (1.0 + (-x).exp()), 0.0, 0.0)];
        };
        let ratio = |samples: usize| {
            let moved = Pace::moves(samples, 1..=samples, burst);
            let pace = Pace::of_moves(&moved, 0.0).expect("it moves");
            let (mut meter, mut frame) = (JumpMeter::default(), Frame::default());
            let jumps: Vec<f32> = (0..60)
                .map(|i| {
                    burst(pace.at(i as f32 / 59.0), &mut frame);
                    meter.jump(&frame)
                })
                .collect();
            crate::frame::jump_ratio(&jumps)
        };
        let coarse = Pace::moves(64, 1..=64, burst);
        assert!(Pace::concentrated(&coarse));
        assert!(ratio(64) > 2.0, "64 samples: {}", ratio(64));
        assert!(ratio(64 * Pace::REFINE) <= 2.0, "refined: {}", ratio(256));
        // Speeding up steadily (the last interval moves 4/3 of the mean)
        // is not concentrated.
        let steady = |t: f32, frame: &mut Frame| {
            frame.t = t;
            frame.positions = vec![Vec3::new(t + 0.5 * t * t, 0.0, 0.0)];
        };
        assert!(!Pace::concentrated(&Pace::moves(64, 1..=64, steady)));
    }

    /// The moves of runs measured apart, joined, are the moves of one run,
    /// so the pace is the same bit for bit.
    #[test]
    fn joined_runs_pace_as_one_measure() {
        let whole = Pace::measure(24, 0.25, frame_at);
        assert!(whole.is_some());
        for count in [1, 2, 3, 7] {
            let moved: Vec<f32> = Pace::runs(24, count)
                .into_iter()
                .flat_map(|span| Pace::moves(24, span, frame_at))
                .collect();
            assert_eq!(Pace::of_moves(&moved, 0.25), whole, "{count} runs");
        }
    }
}
