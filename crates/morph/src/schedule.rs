//! [`Schedule`]: when each union chain and leaf moves within [0, 1].
//!
//! The paper runs every operation on one clock, `t` itself. A staged
//! schedule ([`ScheduleKind::Staged`]) gives each operation its own
//! **window** of `t` and eases inside it:
//!
//! - **Phases.** Wilting chains and leaves shed in `[0, 0.45]`, the
//!   matched chains reshape in `[0.1, 0.9]` and growth happens in
//!   `[0.55, 1]`: first shed, then reshape, then grow, overlapping so the
//!   motion never stops. A phase with nothing to do lends its time to the
//!   reshape: without wilting it starts at 0, without growth it ends at 1.
//! - **Off the host's reshape.** A wilting subtree (a wilting union chain
//!   whose parent does not wilt, with every wilting chain on it) has
//!   retracted by the time the chain it hangs on starts to reshape, and a
//!   growing subtree starts once that chain has reshaped: the shed window
//!   ends at the host's start (no earlier than 0.2, no later than 0.45),
//!   the growth window starts at the host's end (no earlier than 0.55, no
//!   later than 0.8). A twig that is still there while its limb swings
//!   sweeps through the neighbouring limbs: on the 50 morphs between the
//!   third-party trees CI makes, the most crossing pairs in a frame summed
//!   to 7,318 with one shed and one growth window for all, and 1,905 this
//!   way (with the finer pacing it needs, *Pacing*); on the five preset
//!   pairs 225 → 187 (benches/motion.sh, staged, one-to-many).
//! - **Parents lead.** A reshaping chain's window starts
//!   `stagger × d` of the phase after the phase starts, with
//!   `d = (level + p) / levels` (`p` its mean growth location along the
//!   parent, `levels` the union chain tree's depth plus one), and lasts
//!   `1 − stagger` of the phase. A child's
//!   `d` is never below its parent's, so trunks settle first and twigs
//!   follow, the twigs near a parent's base before those near its tip.
//!   Wilting leaves on reshaping chains fold in the shed phase twigs first
//!   (`1 − d`), growing leaves unfold in the growth phase twigs last; a
//!   leaf folds before its twig starts to reshape and unfolds after it has
//!   finished (at least 0.1 of `t` for it), so it opens and closes on the
//!   bark it belongs to, never inside a branch that is still thinning.
//! - **Slow-down.** Split and merge copies keep the paper's slow-down
//!   coefficient inside their window: the window's clock is their `t`.
//! - **Easing.** Inside a window the clock accelerates uniformly over the
//!   first `easing` of it, runs at constant speed, and decelerates over
//!   the last `easing` ([`Ease`]): C¹ at both ends, exact 0 and 1 there,
//!   so t = 0 is the source and t = 1 the target.
//! - **Tip-first growth.** A growing subtree (a growing union chain whose
//!   parent does not grow, with every growing chain on it) has one clock
//!   over the growth phase and one **front** travelling out from its
//!   junction at constant speed along the branches: a chain whose base is
//!   `b` metres from the subtree's junction (along its ancestors' target
//!   shapes) has grown `front − b` metres of its target shape, base fixed
//!   and tip advancing, so its children start exactly when the tip passes
//!   their growth location. The front travels `1.25 ×` the subtree's
//!   longest base-to-tip path: a leaf `a` metres out unfolds (scales from
//!   zero, its offset from the axis with it) while the front goes from `a`
//!   to `a + 0.25 ×` that path (eased like a window, so a big leaf's
//!   corners do not start at full speed), so it opens only after its twig
//!   reached it and the last ones finish at t = 1. Radii follow the pipe model
//!   from the tip: a point `x` metres behind the growing tip has the radius
//!   the grown chain has `x` metres behind its tip, so twig tips stay thin
//!   and bases thicken as the chain lengthens; never more than the grown
//!   chain's own radius there, so a twig thinner at its base than further
//!   out (as imported ones often are) does not swell at the base.
//! - **Wilting** is growth backwards on its own clock over the shed
//!   phase: leaves fold first, then each chain retracts into its
//!   junction, outermost first.
//!
//! [`ScheduleKind::Linear`] keeps the paper's clock: every weight is `t`
//! and growth scales about the junction.
//!
//! - **Pacing.** Windows of different lengths and depths leave some
//!   stretches of `t` busy and others nearly still (a eucalyptus's big
//!   limbs reshape early, its twigs' growth late moves little). A staged
//!   plan therefore samples its own motion at 64 instants (the farthest
//!   any node or leaf corner moves between neighbours; 256 when one of
//!   the 64 intervals moves over twice the mean, a burst the 64 do not
//!   resolve, as in some third-party morphs) and plays it so
//!   that the motion covered by `t` follows the easing over the whole
//!   morph: every frame moves about as far as the next, with a gentle
//!   start and end. A little time (5 % of the mean) is kept for every
//!   stretch, so nothing is skipped.
//!
//! Bark textures and the root follow the reshape phase's clock.

use treemorph_tree::timing::{Ease, Pace, Window};

/// The growth phase: growing chains and leaves.
pub(crate) const GROW: [f32; 2] = [0.55, 1.0];
/// How far the front travels while a leaf unfolds, as a fraction of its
/// subtree's longest base-to-tip path.
pub(crate) const UNFOLD: f32 = 0.25;

/// An instant of a morph as its schedule's windows read it
/// ([`Schedule::paced`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Paced(f32);

impl Paced {
    /// Whether it lies strictly between the ends (which are the inputs).
    pub(crate) fn inner(self) -> bool {
        self.0 > 0.0 && self.0 < 1.0
    }
}

/// A tip-first growing or wilting union chain's front.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Front {
    /// Metres from its subtree's junction to the chain's base.
    pub base: f32,
    /// Metres the front travels over the window.
    pub total: f32,
    /// Growing (the front goes out) or wilting (it comes back).
    pub grows: bool,
}

/// When one union chain moves.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct ChainTiming {
    pub window: Window,
    /// `Some` for tip-first growth and wilt.
    pub front: Option<Front>,
}

/// How a union chain stands at some `t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum ChainState {
    /// Interpolated with this weight.
    Blend(f32),
    /// Grown (or not yet retracted) this many metres from its junction.
    Reach(f32),
}

/// When one leaf moves: its window's clock, then (unfolding with a front)
/// its share of the clock.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct LeafTiming {
    pub window: Window,
    /// Where on the clock the front reaches the leaf (0 without a front).
    pub at: f32,
    /// 1 / the clock's share over which it unfolds (1 without a front).
    pub inv_unfold: f32,
    /// It folds (wilts) rather than unfolds.
    pub folds: bool,
}

/// The timing of every union chain and leaf of a plan.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct Schedule {
    pub ease: Ease,
    /// The reshape phase: the root, the bark blend.
    pub overall: Window,
    pub chains: Vec<ChainTiming>,
    pub leaves: Vec<LeafTiming>,
    /// How `t` is paced (`None`: `t` itself).
    pub pace: Option<Pace>,
}

impl Schedule {
    /// Every weight `t`: the paper's clock, for `chains` union chains and
    /// `leaves` leaves.
    pub(crate) fn linear(chains: usize, leaves: usize) -> Schedule {
        let chain = ChainTiming {
            window: Window::FULL,
            front: None,
        };
        let leaf = LeafTiming {
            window: Window::FULL,
            at: 0.0,
            inv_unfold: 1.0,
            folds: false,
        };
        Schedule {
            ease: Ease::NONE,
            overall: Window::FULL,
            chains: vec![chain; chains],
            leaves: vec![leaf; leaves],
            pace: None,
        }
    }

    /// `t` as the windows read it: after the pace, once per frame (the
    /// pace is a search among its knots, and a frame asks for every union
    /// chain's and leaf's clock).
    pub(crate) fn paced(&self, t: f32) -> Paced {
        Paced(self.pace.as_ref().map_or(t, |p| p.at(t)))
    }

    /// The eased clock of `window` at `t`.
    fn clock(&self, window: Window, Paced(t): Paced) -> f32 {
        self.ease.at(window.local(t))
    }

    /// The clock of the reshape phase (root, bark).
    pub(crate) fn overall(&self, t: Paced) -> f32 {
        self.clock(self.overall, t)
    }

    /// Union chain `i` at `t`.
    pub(crate) fn chain(&self, i: usize, t: Paced) -> ChainState {
        let c = self.chains[i];
        let clock = self.clock(c.window, t);
        match c.front {
            None => ChainState::Blend(clock),
            Some(f) => {
                let travelled = if f.grows { clock } else { 1.0 - clock };
                ChainState::Reach(travelled * f.total - f.base)
            }
        }
    }

    /// Whether union chain `i` grows or wilts from its tip.
    pub(crate) fn tip_first(&self, i: usize) -> bool {
        self.chains[i].front.is_some()
    }

    /// The interpolation weight of union chain `i` at `t`: its blend
    /// weight, or for tip-first chains how much of the front has passed.
    pub(crate) fn chain_weight(&self, i: usize, t: Paced) -> f32 {
        let c = self.chains[i];
        let clock = self.clock(c.window, t);
        match c.front {
            None => clock,
            Some(f) => {
                let path = (f.total / (1.0 + UNFOLD) - f.base).max(f32::MIN_POSITIVE);
                let travelled = if f.grows { clock } else { 1.0 - clock };
                let grown = ((travelled * f.total - f.base) / path).clamp(0.0, 1.0);
                if f.grows { grown } else { 1.0 - grown }
            }
        }
    }

    /// The interpolation weight of leaf `i` at `t`.
    pub(crate) fn leaf(&self, i: usize, t: Paced) -> f32 {
        let l = self.leaves[i];
        let clock = self.clock(l.window, t);
        if l.at == 0.0 && l.inv_unfold == 1.0 {
            return clock;
        }
        // Behind a front the unfold is eased too: a linear ramp would
        // start a big leaf's corners at full speed.
        if l.folds {
            1.0 - self
                .ease
                .at(((1.0 - clock - l.at) * l.inv_unfold).clamp(0.0, 1.0))
        } else {
            self.ease
                .at(((clock - l.at) * l.inv_unfold).clamp(0.0, 1.0))
        }
    }
}
