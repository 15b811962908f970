//! The frozen-channel check (design §24): a current channel whose reading
//! repeats to the bit while the rotor turns the current it measures.
//!
//! The model check's observer absorbs a steady reading error: a channel
//! that stops where it stood reads right at first and drifts from the
//! truth only as fast as the rotor turns the phase's current, so the
//! residual sees a frozen channel late, and with hall sensors (whose
//! angle uncertainty widens every bound) after the current has run away.
//! A healthy channel cannot stand still that long: a conversion of a
//! current that moved by more than one step of the ADC reads a new value,
//! and a real ADC's noise moves its last bit besides.
//!
//! So each channel keeps the stretch of periods over which it has read
//! the same value, bit for bit, and the dq current of the stretch's first
//! period: turned by each later period's angle and projected on the
//! phase, it is what the phase's current would be now had the dq current
//! stayed. A healthy reading stands within one ADC step of the phase's
//! current, which is within `|i_dq(now) - i_dq(start)|` of that
//! projection. So when the projection has left the reading by more than
//! [`SPAN_FLOORS`] times the model's current floor plus how far the
//! current loop's reference moved since the stretch began, for more than
//! [`MIN_REPEATS`] periods in a row, the channel is frozen. A rotor at
//! rest turns nothing: a current held at standstill never trips it; nor
//! does a current that falls while the rotor turns it into a phase (a
//! speed loop letting go of a step), which can hold that phase's current
//! still for a dozen periods: the reference falls with it. While the
//! loop's voltage is limited the current is not where the reference
//! says, and the check pauses; after an angle correction (a hall edge)
//! the loop has the repeats to move the current. (The bound takes the
//! reference's move for the current's: a loop still settling from a
//! reference step made before the stretch began is covered only by the
//! span; the healthy tests' longest run stays at 2 of the 7 that trip.)
//!
//! A channel dead at a constant value (a broken amplifier read without
//! noise) is frozen too; a dead channel that reads noise is the residual's
//! to find.
//!
//! ```
//! use foc_core::control::frozen::{FrozenChannels, Readings};
//! use foc_core::frames::Dq;
//! let mut f = FrozenChannels::new(0.2);
//! let i_dq = Dq::new(0.0, 10.0);
//! let mut frozen = false;
//! // Phase A's reading stands at 3 A while the rotor turns 10 A through it.
//! for k in 0..40 {
//!     let th = 0.01 * k as f32;
//!     frozen |= f.check(&Readings {
//!         channels_a: [Some(3.0), Some(-1.5 + 0.01 * k as f32), None],
//!         i_dq_a: i_dq,
//!         i_ref_a: i_dq,
//!         sin_cos: (libm::sinf(th), libm::cosf(th)),
//!         voltage_limited: false,
//!     });
//! }
//! assert!(frozen);
//! ```

use crate::frames::Dq;

/// The projection must stay off its start for more than this many
/// periods in a row (the trip is on the next): more than a current loop
/// needs to move a current by one ADC step after an angle correction.
pub const MIN_REPEATS: u16 = 6;

/// How far, in model floors (`ModelTolerances::floor_a`), the projection
/// must be off the reading (beyond the reference's move).
pub const SPAN_FLOORS: f32 = 2.0;

/// The bits no reading is taken to have (a NaN's): no stretch yet.
const NO_READING: u32 = u32::MAX;

/// One channel's stretch of equal readings.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Channel {
    /// The reading's bits.
    bits: u32,
    /// The stretch's first dq current projected on the phase at an angle
    /// `theta`: `cos_a cos(theta) + sin_a sin(theta)` \[A\].
    cos_a: f32,
    sin_a: f32,
    /// The projection when the stretch began (the reading, less any
    /// zero-sequence part three channels read) \[A\].
    start_a: f32,
    /// The current reference when the stretch began \[A\].
    start_ref_a: Dq,
    /// Consecutive periods off the reading by more than the span.
    over: u16,
}

impl Default for Channel {
    fn default() -> Self {
        Self {
            bits: NO_READING,
            cos_a: 0.0,
            sin_a: 0.0,
            start_a: 0.0,
            start_ref_a: Dq::ZERO,
            over: 0,
        }
    }
}

impl Channel {
    /// One period of this channel (`read`: its reading, `None` without
    /// one; `(pa, pb)`: its phase's unit vector); the periods it has been
    /// off by more than `span` (module docs).
    #[inline(always)]
    fn step(&mut self, read: Option<f32>, (pa, pb): (f32, f32), p: &Readings, span: f32) -> u16 {
        let Some(read) = read else {
            return 0;
        };
        let (sin, cos) = p.sin_cos;
        let bits = read.to_bits();
        if self.bits != bits {
            // The phase's current at angle theta from this dq current:
            // pa alpha + pb beta, alpha = d cos - q sin, beta = d sin + q cos.
            let Dq { d, q } = p.i_dq_a;
            let (cos_a, sin_a) = (pa * d + pb * q, pb * d - pa * q);
            *self = Channel {
                bits,
                cos_a,
                sin_a,
                start_a: cos_a * cos + sin_a * sin,
                start_ref_a: p.i_ref_a,
                over: 0,
            };
            return 0;
        }
        let turned = self.cos_a * cos + self.sin_a * sin;
        let r = p.i_ref_a;
        let moved = (r.d - self.start_ref_a.d).abs() + (r.q - self.start_ref_a.q).abs();
        self.over = if (turned - self.start_a).abs() > span + moved {
            self.over.saturating_add(1)
        } else {
            0
        };
        self.over
    }
}

/// The phases' unit vectors in alpha-beta (a, b, c).
const PHASES: [(f32, f32); 3] = [
    (1.0, 0.0),
    (-0.5, crate::SQRT_3_2),
    (-0.5, -crate::SQRT_3_2),
];

/// One period's inputs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Readings {
    /// The channels as read, per phase (`None` for a phase without a
    /// channel) \[A\].
    pub channels_a: [Option<f32>; 3],
    /// The dq current computed from them \[A\].
    pub i_dq_a: Dq,
    /// The current loop's reference this period \[A\].
    pub i_ref_a: Dq,
    /// `(sin, cos)` of the angle `i_dq_a` was computed with.
    pub sin_cos: (f32, f32),
    /// The current loop's voltage was limited (the check pauses).
    pub voltage_limited: bool,
}

/// The check for up to three channels (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrozenChannels {
    span_a: f32,
    channels: [Channel; 3],
    /// The longest run of periods off the reading (the margin).
    peak_over: u16,
}

impl FrozenChannels {
    /// The check with the model's current floor \[A\] (a floor that is
    /// not finite and positive gives a span of 0: any stretch off the
    /// reading trips, as the model check's tolerances tighten).
    pub fn new(floor_a: f32) -> Self {
        let span = SPAN_FLOORS * floor_a;
        Self {
            span_a: if span.is_finite() && span > 0.0 {
                span
            } else {
                0.0
            },
            ..Self::default()
        }
    }

    /// Forget every stretch (the bridge off, a new configuration).
    pub fn reset(&mut self) {
        self.channels = [Channel::default(); 3];
    }

    /// The longest run of periods a projection stayed off its reading,
    /// over the run that trips (`MIN_REPEATS + 1`): a healthy drive stays
    /// below 1. Kept across [`Self::reset`].
    pub fn peak_ratio(&self) -> f32 {
        f32::from(self.peak_over) / (f32::from(MIN_REPEATS) + 1.0)
    }

    /// Forget the longest run seen.
    pub fn reset_peak(&mut self) {
        self.peak_over = 0;
    }

    /// Carry the longest run over from a check this one replaces (as
    /// [`Self::peak_ratio`] gave it).
    pub fn keep_peak(&mut self, ratio: f32) {
        let over = ratio * (f32::from(MIN_REPEATS) + 1.0) + 0.5;
        // (`as` saturates; NaN becomes 0.)
        self.peak_over = over as u16;
    }

    /// Judge this period (module docs); true when a channel is frozen.
    #[inline(always)]
    pub fn check(&mut self, p: &Readings) -> bool {
        if p.voltage_limited {
            // The current is not where the loop asks: its reference says
            // nothing of how far it moved. Every stretch starts again.
            self.reset();
            return false;
        }
        let [a, b, c] = &mut self.channels;
        let [ra, rb, rc] = p.channels_a;
        let [pa, pb, pc] = PHASES;
        let span = self.span_a;
        let longest = a.step(ra, pa, p, span);
        let longest = longest.max(b.step(rb, pb, p, span));
        let longest = longest.max(c.step(rc, pc, p, span));
        if longest > self.peak_over {
            self.peak_over = longest;
        }
        longest > MIN_REPEATS
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sc(th: f32) -> (f32, f32) {
        (libm::sinf(th), libm::cosf(th))
    }

    /// The phase `k`'s current of `dq` at the angle of `(sin, cos)`.
    fn phase_of(dq: Dq, (sin, cos): (f32, f32), k: usize) -> f32 {
        let (pa, pb) = PHASES[k];
        pa * (dq.d * cos - dq.q * sin) + pb * (dq.d * sin + dq.q * cos)
    }

    /// Readings with the current at its (constant) reference.
    fn rd(channels_a: [Option<f32>; 3], i_dq_a: Dq, sin_cos: (f32, f32)) -> Readings {
        Readings {
            channels_a,
            i_dq_a,
            i_ref_a: i_dq_a,
            sin_cos,
            voltage_limited: false,
        }
    }

    /// A current that falls while the rotor turns it into the phase holds
    /// the phase's reading: no trip.
    #[test]
    fn a_falling_current_turned_into_the_phase_is_not_frozen() {
        let mut f = FrozenChannels::new(0.2);
        // Phase a = I cos(th): I falls as th falls, keeping it at 6 A.
        for k in 0..200 {
            let th = -0.5 + 0.002 * k as f32;
            let i = 6.0 / libm::cosf(th);
            assert!(
                !f.check(&rd([Some(6.0), None, None], Dq::new(i, 0.0), sc(th))),
                "{k}"
            );
        }
    }

    /// A current held at standstill repeats every reading: no trip.
    #[test]
    fn a_current_held_at_standstill_is_not_frozen() {
        let mut f = FrozenChannels::new(0.2);
        for _ in 0..10_000 {
            assert!(!f.check(&rd(
                [Some(5.0), Some(-2.5), None],
                Dq::new(0.0, 5.0),
                sc(0.3)
            )));
        }
    }

    /// Readings that follow the turning current never trip; the same
    /// readings stopped do, once the current would have moved by the span.
    #[test]
    fn a_reading_that_stops_while_the_rotor_turns_is_frozen() {
        let mut f = FrozenChannels::new(0.2);
        let i = Dq::new(-1.0, 8.0);
        let mut th = 0.0f32;
        for _ in 0..2_000 {
            th += 0.003;
            let (a, b) = (phase_of(i, sc(th), 0), phase_of(i, sc(th), 1));
            assert!(!f.check(&rd([Some(a), Some(b), None], i, sc(th))));
        }
        let held = phase_of(i, sc(th), 1);
        let mut periods = None;
        for k in 0..2_000 {
            th += 0.003;
            let a = phase_of(i, sc(th), 0);
            if f.check(&rd([Some(a), Some(held), None], i, sc(th))) {
                periods = Some(k);
                break;
            }
        }
        // 0.4 A of a sinusoid of 8.06 A at 0.003 rad a period: at most
        // the angle its flattest stretch needs (0.32 rad, about 105
        // periods), at least the repeats.
        let k = periods.expect("frozen channel not found");
        assert!((MIN_REPEATS as usize..=110).contains(&k), "{k}");
    }

    /// A reading that changes even by its last bit starts a new stretch.
    #[test]
    fn any_change_restarts_the_stretch() {
        let mut f = FrozenChannels::new(0.0);
        let i = Dq::new(0.0, 10.0);
        for k in 0..100 {
            let read = if k % 2 == 0 {
                1.0
            } else {
                f32::from_bits(1.0f32.to_bits() + 1)
            };
            assert!(!f.check(&rd([Some(read), None, None], i, sc(0.01 * k as f32))));
        }
    }

    /// A phase without a channel is never judged; a reset forgets.
    #[test]
    fn missing_channels_and_reset() {
        let mut f = FrozenChannels::new(0.01);
        let i = Dq::new(0.0, 10.0);
        for k in 0..100 {
            assert!(!f.check(&rd([None, None, None], i, sc(0.05 * k as f32))));
        }
        // A reading stuck while the rotor turns: one period short of the
        // trip, a reset forgets the stretch; without it the next trips.
        let run = |f: &mut FrozenChannels| {
            for k in 0..=(MIN_REPEATS as u32) {
                assert!(!f.check(&rd([Some(2.0), None, None], i, sc(0.05 * k as f32))));
            }
        };
        let mut g = f;
        run(&mut f);
        f.reset();
        assert!(!f.check(&rd([Some(2.0), None, None], i, sc(0.4))));
        run(&mut g);
        assert!(g.check(&rd([Some(2.0), None, None], i, sc(0.4))));
    }
}
