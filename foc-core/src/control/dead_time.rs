//! Dead-time compensation of the applied voltage (design §31, issue 38).
//!
//! During the dead time `t_d` of each switching edge neither switch of a
//! leg conducts and the phase follows its current through a body diode:
//! low when the current flows into the motor, at the bus when it flows
//! out. Over a PWM period `T` the leg's average voltage is off by
//!
//! ```text
//! dv_k = -sgn(i_k) V_bus t_d / T            (per phase k = a, b, c)
//! ```
//!
//! a six-step square wave against the current: at low speed, where it is
//! a large part of the small voltage the winding needs, the phase current
//! carries 5th and 7th harmonics and the torque ripples at 6 times the
//! electrical frequency. The current loop cancels it by adding, on top of
//! the PI's limited voltage,
//!
//! ```text
//! duty_k += s(i_k) t_d / T,   i.e.  v_ab += clarke(s(i_a), s(i_b), s(i_c)) V_bus t_d / T
//! s(i) = clamp(i / band, -1, 1)                               (the smooth sign)
//! ```
//!
//! # Which current gives the sign: the reference, at the applied angle
//!
//! The sign is that of the phase current *while the duties act*: the dq
//! reference turned to the angle at which the voltage will apply,
//! `theta_e + k w_e Ts` (the same angle the loop's delay compensation,
//! [`CurrentLoopConfig::delay_compensation_periods`](super::current::CurrentLoopConfig::delay_compensation_periods),
//! applies the voltage at), then the inverse Clarke. The reference,
//! not the measurement: the measured phase current near its zero carries
//! the sensor's noise and quantisation, the PWM ripple and the very
//! harmonics the compensation is to remove, and a sign taken from it
//! chatters across zero and feeds that back into the voltage; it is also
//! a period late. The reference is smooth, known for the period ahead and,
//! with the loop tracking, is the current within a small error. Where the
//! loop does not track (the voltage limit at speed, a step's first
//! periods), the dead time is a small share of the voltage and a sign
//! that is briefly wrong costs at most the error without compensation.
//!
//! # The smooth sign's band ([`DEFAULT_BAND_SHARE`])
//!
//! A hard sign would step the voltage by `2 V_bus t_d / T` wherever the
//! reference crosses zero, also where the true current (the reference plus
//! the loop's tracking error and the PWM ripple) has not yet. The real
//! inverter is not a hard sign either: with a ripple about the mean the
//! switching edges see currents of both signs near a zero and the error
//! falls off there (the plant models this: its sign is taken at every
//! sub-step). So within `+-band` of zero the compensation is proportional
//! to the current, the usual remedy of the dead-time compensation
//! literature (a saturation or sigmoid function in place of `sgn`).
//!
//! The band is [`DEFAULT_BAND_SHARE`] (2 %) of the drive's current limit
//! ([`DeadTimeCompensation::for_current_limit`]), from the bench
//! (`tests/tests/dead_time.rs`, `band_sweep`; design §31): at 2 % of the
//! no-load speed and the rated current, the dead time's 5th + 7th
//! harmonics left with a band of 1, 2, 5, 10, 20 % of the limit were
//! 0.12, 0.14, 0.21, 0.72, 1.58 % of the fundamental on the DJI M2006
//! (1.41 % without compensation) and 0.002, 0.004, 0.023, 0.08, 0.19 % on
//! the 540 V interior-PM motor (0.18 % without): a wide band gives back
//! what the compensation won, below 2 % nothing more is won. At 2 % a
//! reference that wanders about zero (a hold, the speed loop's output at
//! rest) still gets a proportional compensation rather than full steps,
//! and a rated current's phase spends little of the turn inside the band
//! (`asin(band / I)`: 1.1 deg electrical either side of a zero at the
//! current limit, 3.8 deg at the M2006's rated 3 A of 10).
//!
//! # Where the compensation sits, and what sees it
//!
//! - **Not the PI's output.** The PIs, the voltage circle and the
//!   anti-windup see the dq voltage without the compensation (the voltage
//!   the motor's terminals get once the bridge's error is cancelled):
//!   [`CurrentLoopOutput::v_dq_v`](super::current::CurrentLoopOutput::v_dq_v)
//!   is that voltage, as is the stage's `last_out_v_dq` that field
//!   weakening, the bumpless preload and the sensorless hand-over read.
//!   The compensation uses the room between the circle
//!   (`max_modulation` of `V_bus / sqrt(3)`) and the modulator's hexagon:
//!   its largest vector, `4/3 V_bus t_d / T` (all three signs saturated),
//!   fits while `max_modulation <= 1 - 2.31 t_d / T` (0.95 with 200 ns at
//!   20 kHz: 0.4 % of the period; with 1 us at 20 kHz, 0.954); beyond,
//!   on the voltage limit only, the modulator scales the sum onto the
//!   hexagon ([`SvpwmOutput::saturated`](crate::svpwm::SvpwmOutput::saturated))
//!   and the duties stay in `[0, 1]`. Field weakening judges `|v_dq|`
//!   against the circle: the voltage the winding gets, which is now the
//!   commanded one (without the compensation the winding got less than
//!   `v_dq` by the dead time's error, which the weakening did not see).
//! - **In the voltage handed to the modulator.**
//!   [`CurrentLoopOutput::v_ab_v`](super::current::CurrentLoopOutput::v_ab_v)
//!   and the duties include it, so the injection (design §28), which adds
//!   its voltage to `v_ab_v` and modulates again, keeps it.
//! - **Estimates that rebuild the applied voltage from the duties**: the
//!   model-based sensor supervision ([`super::model`]) and the flux
//!   observer ([`super::flux_observer`]) take the duties handed to the
//!   bridge (compensation included) and subtract the dead time's
//!   `sgn(i) V_bus t_d / T` by the *measured* current's sign outside their
//!   current floor: that is the bridge's real voltage with or without the
//!   compensation, so both stay right unchanged. Their tolerances for the
//!   dead time (the model's `2 dead_v` near a zero, the sensorless start's
//!   hand-over speed from `V_bus t_d / T`) are about their own sign near a
//!   zero, which the compensation does not change: kept.
//! - **Open-loop voltage** ([`CurrentLoop::step_voltage`](super::current::CurrentLoop::step_voltage)):
//!   not compensated. There is no current reference to take a sign from,
//!   and the identification's routines measure the resistance and the
//!   dead-time drop from open-loop voltages (the drop is the intercept of
//!   `v = R i + v_0`): they measure the bridge as it is.
//! - **Injection (HFI)**: the compensation follows the reference at the
//!   fundamental; the injection's ripple at the PWM rate is not
//!   compensated (its ratio does not depend on how much of the injected
//!   voltage the dead time eats, [`super::hfi`]).
//!
//! Off ([`DeadTimeCompensation::OFF`], the constructors' default, or a dead
//! time of 0) the loop's outputs are bit for bit those without it.
//!
//! ```
//! use foc_core::control::dead_time::{smooth_sign, DeadTimeCompensation};
//! use foc_core::frames::Dq;
//! // 1 us at 20 kHz, band 2 % of a 10 A limit.
//! let dt = DeadTimeCompensation::for_current_limit(1e-6, 10.0);
//! assert!((dt.band_a - 0.2).abs() < 1e-6);
//! let g = dt.gains(50e-6);
//! assert!(g.is_on());
//! assert_eq!(smooth_sign(0.5), 0.5);
//! assert_eq!(smooth_sign(-3.0), -1.0);
//! // 4 A on phase a (at angle 0): a gets +t_d/T, b and c -t_d/T (their
//! // -2 A is beyond the band): the vector 4/3 of 2 % of the 24 V bus on alpha.
//! let v = g.voltage_ab(Dq::new(4.0, 0.0), 0.0, 1.0, 24.0);
//! assert!((v.alpha - 4.0 / 3.0 * 0.02 * 24.0).abs() < 1e-5 && v.beta.abs() < 1e-6);
//! ```

use crate::frames::{Abc, AlphaBeta, Dq};
use crate::transforms;

/// The smooth sign's band as a share of the drive's current limit (module
/// docs, "The smooth sign's band").
pub const DEFAULT_BAND_SHARE: f32 = 0.02;

/// The largest dead time taken, as a share of the PWM period: a longer one
/// (a unit slip, nanoseconds given as microseconds) leaves the
/// compensation off.
pub const MAX_DEAD_TIME_SHARE: f32 = 0.1;

/// The dead-time compensation's configuration (a field of
/// [`CurrentLoopConfig`](super::current::CurrentLoopConfig)).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DeadTimeCompensation {
    /// The bridge's dead time per switching edge \[s\] (the board's, as the
    /// timer inserts it): 0 turns the compensation off.
    pub dead_time_s: f32,
    /// The smooth sign's band \[A\]: a phase current reference within
    /// `+-band_a` gets that share of the full compensation.
    pub band_a: f32,
}

impl DeadTimeCompensation {
    /// No compensation (the constructors' default).
    pub const OFF: Self = Self {
        dead_time_s: 0.0,
        band_a: 0.0,
    };

    /// The board's dead time \[s\] with the band [`DEFAULT_BAND_SHARE`] of
    /// the drive's current limit \[A\].
    pub fn for_current_limit(dead_time_s: f32, max_current_a: f32) -> Self {
        Self {
            dead_time_s,
            band_a: DEFAULT_BAND_SHARE * max_current_a,
        }
    }

    /// The per-step values at the loop period `ts_s` \[s\]: off
    /// ([`DeadTimeGains::OFF`]) unless the dead time is positive and at
    /// most [`MAX_DEAD_TIME_SHARE`] of the period and the band is finite
    /// and positive (NaN anywhere: off).
    pub fn gains(&self, ts_s: f32) -> DeadTimeGains {
        let share = self.dead_time_s / ts_s;
        let inv_band = 1.0 / self.band_a;
        let usable = share > 0.0
            && share <= MAX_DEAD_TIME_SHARE
            && self.band_a > 0.0
            && inv_band.is_finite()
            && inv_band > 0.0;
        if usable {
            DeadTimeGains {
                share,
                inv_band_per_a: inv_band,
            }
        } else {
            DeadTimeGains::OFF
        }
    }
}

impl Default for DeadTimeCompensation {
    fn default() -> Self {
        Self::OFF
    }
}

/// The values the loop's step uses, derived once per configuration
/// ([`DeadTimeCompensation::gains`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DeadTimeGains {
    /// `t_d / T`: the duty added per phase at a saturated sign (0: off).
    pub share: f32,
    /// `1 / band` \[1/A\].
    pub inv_band_per_a: f32,
}

impl DeadTimeGains {
    /// Off.
    pub const OFF: Self = Self {
        share: 0.0,
        inv_band_per_a: 0.0,
    };

    /// True when the compensation acts.
    #[inline(always)]
    pub fn is_on(&self) -> bool {
        self.share > 0.0
    }

    /// The smooth signs of the three phase currents `i_abc_a` \[A\]: the
    /// duty each phase gets is `share` times its sign.
    #[inline(always)]
    pub fn signs(&self, i_abc_a: Abc) -> Abc {
        let k = self.inv_band_per_a;
        Abc::new(
            smooth_sign(i_abc_a.a * k),
            smooth_sign(i_abc_a.b * k),
            smooth_sign(i_abc_a.c * k),
        )
    }

    /// The compensation's alpha/beta voltage \[V\] for the dq current
    /// reference `i_ref_dq_a` \[A\] turned by `(sin, cos)` of the angle the
    /// voltage applies at, on the bus `v_bus_v` \[V\]:
    /// `clarke(s(i_a), s(i_b), s(i_c)) V_bus t_d / T` (only its
    /// line-to-line part matters: the star point floats). Zero when off; a
    /// NaN current gives a zero sign.
    #[inline(always)]
    pub fn voltage_ab(&self, i_ref_dq_a: Dq, sin: f32, cos: f32, v_bus_v: f32) -> AlphaBeta {
        let i = transforms::inverse_clarke(transforms::inverse_park(i_ref_dq_a, sin, cos));
        let s = transforms::clarke(self.signs(i));
        let g = v_bus_v * self.share;
        AlphaBeta::new(s.alpha * g, s.beta * g)
    }
}

/// The smooth sign: `x` clamped to `[-1, 1]` (`x = i / band`); NaN gives 0.
#[inline(always)]
pub fn smooth_sign(x: f32) -> f32 {
    if x >= 1.0 {
        1.0
    } else if x <= -1.0 {
        -1.0
    } else if x.is_nan() {
        0.0
    } else {
        x
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trig;
    extern crate std;

    #[test]
    fn smooth_sign_is_a_clamped_line_and_nan_safe() {
        assert_eq!(smooth_sign(0.0), 0.0);
        assert_eq!(smooth_sign(0.3), 0.3);
        assert_eq!(smooth_sign(-0.3), -0.3);
        assert_eq!(smooth_sign(1.0), 1.0);
        assert_eq!(smooth_sign(-1.0), -1.0);
        assert_eq!(smooth_sign(7.0), 1.0);
        assert_eq!(smooth_sign(-7.0), -1.0);
        assert_eq!(smooth_sign(f32::INFINITY), 1.0);
        assert_eq!(smooth_sign(f32::NEG_INFINITY), -1.0);
        assert_eq!(smooth_sign(f32::NAN), 0.0);
        // Odd, monotonic, and continuous with slope at most 1 (no step
        // anywhere: the voltage it makes never jumps).
        let mut prev = smooth_sign(-3.0);
        for k in -3000..=3000 {
            let x = k as f32 * 1e-3;
            let s = smooth_sign(x);
            assert_eq!(s, -smooth_sign(-x));
            assert!(s >= prev && s - prev <= 1e-3 + 1e-6, "{x}: {prev} -> {s}");
            assert!((-1.0..=1.0).contains(&s));
            prev = s;
        }
    }

    #[test]
    fn gains_and_band() {
        let c = DeadTimeCompensation::for_current_limit(500e-9, 50.0);
        assert_eq!(c.band_a, DEFAULT_BAND_SHARE * 50.0);
        let g = c.gains(1.0 / 20e3);
        assert!((g.share - 0.01).abs() < 1e-7);
        assert!((g.inv_band_per_a - 1.0).abs() < 1e-6);
        // Within the band the share follows the current, beyond it is full.
        let s = g.signs(Abc::new(0.25, -0.5, 3.0));
        assert!((s.a - 0.25).abs() < 1e-6 && (s.b + 0.5).abs() < 1e-6 && s.c == 1.0);
        assert_eq!(DeadTimeCompensation::default(), DeadTimeCompensation::OFF);
    }

    #[test]
    fn unusable_values_leave_it_off() {
        let ts = 1.0 / 20e3;
        for (t, b) in [
            (0.0, 1.0),
            (-1e-6, 1.0),
            (f32::NAN, 1.0),
            (f32::INFINITY, 1.0),
            (1e-6, 0.0),
            (1e-6, -1.0),
            (1e-6, f32::NAN),
            (1e-6, f32::INFINITY),
            (1e-6, 1e-45),
            // 10 us at 20 kHz: 20 % of the period (a unit slip).
            (10e-6, 1.0),
        ] {
            let g = DeadTimeCompensation {
                dead_time_s: t,
                band_a: b,
            }
            .gains(ts);
            assert_eq!(g, DeadTimeGains::OFF, "{t} {b}");
            assert!(!g.is_on());
        }
        for ts in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            let g = DeadTimeCompensation::for_current_limit(1e-6, 10.0).gains(ts);
            assert!(!g.is_on(), "{ts}");
        }
        assert_eq!(
            DeadTimeGains::OFF.voltage_ab(Dq::new(3.0, 4.0), 0.3, 0.95, 24.0),
            AlphaBeta::new(0.0, 0.0)
        );
    }

    /// Far outside the band the compensation is the six-step square wave
    /// `V_bus t_d / T (sgn a, sgn b, sgn c)` of the phase currents (its
    /// line-to-line values); it turns with the reference and its angle; a
    /// NaN reference gives nothing.
    #[test]
    fn compensation_is_the_phase_signs_line_to_line() {
        let g = DeadTimeCompensation::for_current_limit(1e-6, 1.0).gains(1.0 / 20e3);
        let (share, vbus) = (0.02f32, 48.0f32);
        for deg in (0..360).step_by(7) {
            let th = crate::angle::ElectricalAngle::from_degrees(deg as f32 + 0.5);
            let (s, c) = trig::sin_cos(th);
            let i_ref = Dq::new(-3.0, 40.0);
            let v = g.voltage_ab(i_ref, s, c, vbus);
            let i = transforms::inverse_clarke(transforms::inverse_park(i_ref, s, c));
            let sg = |x: f32| if x > 0.0 { 1.0 } else { -1.0 };
            let want = Abc::new(sg(i.a), sg(i.b), sg(i.c));
            let got = transforms::inverse_clarke(v);
            let ll = |x: Abc| [x.a - x.b, x.b - x.c, x.c - x.a];
            for (g, w) in ll(got).iter().zip(ll(want)) {
                assert!(
                    (g - w * share * vbus).abs() < 1e-4,
                    "{deg}: {got:?} {want:?}"
                );
            }
        }
        let v = g.voltage_ab(Dq::new(f32::NAN, 1.0), 0.0, 1.0, 24.0);
        assert_eq!(v, AlphaBeta::new(0.0, 0.0));
    }
}
