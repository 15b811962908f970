//! Phase resistance from DC steps on the d axis at 0, 120 and 240 electrical
//! degrees, with open-phase, imbalance and current-sense checks.
//!
//! At each angle (phases A, B, C in turn) the routine
//! 1. *aligns*: from rest, raises the d voltage with a rate-limited
//!    integrator until the current (vector magnitude) reaches the *high*
//!    level (`current_a`) and waits until it has stayed `settle_s` inside a
//!    3 % band (low-passed over 16 periods) with the rotor still (see
//!    below), so that the rotor has turned into the test angle;
//! 2. rests at zero voltage until the current has decayed;
//! 3. raises the voltage until the current reaches the *low* level
//!    (`low_fraction * current_a`), settles as in 1., then averages `v_d`
//!    and the dq current over `average_s`;
//! 4. does the same at the high level;
//! 5. takes `R = (v_high - v_low) / (i_high - i_low)`.
//!
//! **The rotor must not move while a level is sampled.** The test current
//! turns the rotor towards the test angle, and a rotor with a large flux
//! linkage on a small resistance is damped so strongly by its own
//! short-circuit current (`1.5 p^2 psi^2 / R`) that it *creeps* into place
//! for up to a second, far too slowly for the swing detector. The creep's
//! back-EMF `psi * w_e` drives a current across the test axis (about 3 A
//! on M153's 0.05 ohm at 1 rad/s electrical) and biases `v / |i|` (M153:
//! R 2.6 to 5.4 % low, depending on where the rotor started). Hence the
//! alignment at the high current first: the rotor creeps into place there
//! and stops (against its friction, or at the aligned position), and the
//! measurement levels, with no more torque than that, cannot move it
//! again. And every settling and averaging requires the sensor reading to
//! stay within [`STILL_TURNS`] of the reading at the start of the settling
//! (a larger change restarts the settling), so that a level is never
//! sampled on a creeping rotor.
//!
//! The slope cancels every voltage error that does not depend on the current
//! level, above all the inverter's dead-time error (a constant voltage as long
//! as no phase current changes sign, which holds for a DC vector). The
//! intercept `v_low - R i_low` is reported as [`ResistanceResult::v_offset_v`]
//! (the dead-time drop at the test angles) so that later open-loop steps can
//! size their voltage.
//!
//! The current is regulated on its magnitude, so that a wrongly wired
//! sense still settles at the test current and is then caught by the angle
//! check (regulating the d projection would drive a turned vector into the
//! over-current limit). While the sensor shows the rotor moving (swinging
//! into the new field position) the voltage is held, not raised, and the
//! settling waits. The integrator gain adapts to the winding:
//! `dv/dt = wc * (v / |i|) * (i_target - |i|)`, i.e. a first-order approach at `loop_bandwidth_rad_s`
//! whatever the resistance, limited to `ramp_v_per_s` (also the ramp used
//! before any current flows).
//!
//! Checks:
//! - no current (below 25 % of the target) with the voltage held at the limit
//!   for `settle_s` -> [`CalError::OpenPhase`] for the phase of that angle
//!   (with one phase open, no current can flow along that phase's axis);
//! - averaged (settled) current angle off the commanded angle by more than
//!   `max_angle_error_rad` (40 degrees by default: an open neighbouring phase
//!   turns the vector by 30 degrees, swapped sense phases by 120, a negated
//!   sense by 180) -> [`CalError::CurrentSenseMismatch`];
//! - the three resistances differ by more than `imbalance_tolerance` of their
//!   mean -> [`CalError::PhaseImbalance`];
//! - over-current, NaN inputs, timeouts.
//!
//! ```
//! use foc_core::calibration::resistance::{PhaseResistance, ResistanceConfig};
//! use foc_core::calibration::{CalInput, CalStep};
//! use foc_core::{angle::MechanicalAngle, frames::Abc};
//! let mut r = PhaseResistance::new(ResistanceConfig::new(20_000.0, 2.0, 6.0));
//! // First period: nothing flows yet, the routine rests at zero voltage.
//! let s = r.step(&CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0));
//! assert!(matches!(s, CalStep::Apply { .. }));
//! ```

use super::common::{
    approach_v, check_input, current_dq, latch, periods, voltage_limit_v, CalError, CalInput,
    CalStep, Mean, Motion, Phase,
};
use crate::angle::{ElectricalAngle, MechanicalAngle};
use crate::frames::Dq;

/// Configuration of the resistance measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ResistanceConfig {
    /// PWM (step) period \[s\].
    pub ts_s: f32,
    /// High test current \[A\] (the d current at the second level).
    pub current_a: f32,
    /// Low level as a fraction of `current_a` (e.g. 0.5).
    pub low_fraction: f32,
    /// Largest open-loop voltage \[V\] (also limited by the bus).
    pub max_voltage_v: f32,
    /// Current vector that aborts the routine \[A\].
    pub max_current_a: f32,
    /// Approach rate of the current to its target [rad/s].
    pub loop_bandwidth_rad_s: f32,
    /// Fastest voltage change [V/s] (and the ramp before current flows).
    pub ramp_v_per_s: f32,
    /// Time inside the 3 % band before averaging \[s\].
    pub settle_s: f32,
    /// Averaging time per level \[s\].
    pub average_s: f32,
    /// Time limit per level (and per rest) \[s\].
    pub level_timeout_s: f32,
    /// Largest spread of the three resistances, as a fraction of their mean.
    pub imbalance_tolerance: f32,
    /// Largest angle between measured current and commanded angle \[rad\].
    pub max_angle_error_rad: f32,
}

impl ResistanceConfig {
    /// Defaults for a PWM frequency, a test current \[A\] and a voltage
    /// limit \[V\]: low level at half the current, 30 rad/s approach, 10 V/s
    /// ramp, 50 ms settle, 50 ms averaging, 2 s per level, 10 % imbalance,
    /// 40 degree angle tolerance, abort at 1.5 times the test current.
    pub fn new(pwm_frequency_hz: f32, current_a: f32, max_voltage_v: f32) -> Self {
        Self {
            ts_s: 1.0 / pwm_frequency_hz,
            current_a,
            low_fraction: 0.5,
            max_voltage_v,
            max_current_a: 1.5 * current_a,
            loop_bandwidth_rad_s: 30.0,
            ramp_v_per_s: 10.0,
            settle_s: 0.05,
            average_s: 0.05,
            level_timeout_s: 2.0,
            imbalance_tolerance: 0.1,
            max_angle_error_rad: 40.0 * (core::f32::consts::PI / 180.0),
        }
    }

    fn is_valid(&self) -> bool {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        pos(self.ts_s)
            && pos(self.current_a)
            && pos(self.low_fraction)
            && self.low_fraction < 0.95
            && pos(self.max_voltage_v)
            && pos(self.max_current_a)
            && self.max_current_a > self.current_a
            && pos(self.loop_bandwidth_rad_s)
            && pos(self.ramp_v_per_s)
            && pos(self.settle_s)
            && pos(self.average_s)
            && pos(self.level_timeout_s)
            && pos(self.imbalance_tolerance)
            && pos(self.max_angle_error_rad)
    }
}

/// Result of the resistance measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ResistanceResult {
    /// Phase resistance \[ohm\] (mean of the three angles).
    pub r_ohm: f32,
    /// Resistance at 0, 120 and 240 electrical degrees \[ohm\].
    pub r_per_angle_ohm: [f32; 3],
    /// Mean intercept `v - R i` at the test currents \[V\] (dead-time drop).
    pub v_offset_v: f32,
}

/// Weight of a new sample in the decision filter (16-period time constant).
const FILTER: f32 = 1.0 / 16.0;

/// Largest change of the sensor reading \[turns\] over a level's settling and
/// averaging (1/2048 turn: two counts of a 4096-count encoder, eight of a
/// 16384-count one, so a count of jitter or noise does not restart it).
pub const STILL_TURNS: f32 = 1.0 / 2048.0;

/// [`STILL_TURNS`] in the sensor's bits (full turn = 2^32).
const STILL_BITS: u32 = 1 << 21;

/// The current level of the present step at one angle.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Level {
    /// The high current until the rotor is still (not sampled).
    Align,
    /// The low current, sampled.
    Low,
    /// The high current, sampled.
    High,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum State {
    Rest,
    Ramp,
    Settle(u32),
    Average,
}

/// The resistance measurement state machine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhaseResistance {
    cfg: ResistanceConfig,
    state: State,
    angle_idx: u8,
    level: Level,
    v_d: f32,
    level_periods: u32,
    limit_periods: u32,
    i_filt: Dq,
    motion: Motion,
    /// Sensor reading at the start of the level's settling.
    anchor: MechanicalAngle,
    avg_v: Mean,
    avg_i: Mean,
    avg_iq: Mean,
    /// Mean voltage and current of the low level.
    low: (f32, f32),
    r: [f32; 3],
    offset: [f32; 3],
    finished: Option<CalStep<ResistanceResult>>,
}

impl PhaseResistance {
    /// New measurement (starts at phase A, resting).
    pub fn new(config: ResistanceConfig) -> Self {
        Self {
            cfg: config,
            state: State::Rest,
            angle_idx: 0,
            level: Level::Align,
            v_d: 0.0,
            level_periods: 0,
            limit_periods: 0,
            i_filt: Dq::ZERO,
            motion: Motion::NEW,
            anchor: MechanicalAngle::ZERO,
            avg_v: Mean::ZERO,
            avg_i: Mean::ZERO,
            avg_iq: Mean::ZERO,
            low: (0.0, 0.0),
            r: [0.0; 3],
            offset: [0.0; 3],
            finished: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &ResistanceConfig {
        &self.cfg
    }

    fn theta(&self) -> ElectricalAngle {
        let deg = match self.angle_idx {
            0 => 0.0,
            1 => 120.0,
            _ => 240.0,
        };
        ElectricalAngle::from_degrees(deg)
    }

    fn phase(&self) -> Phase {
        match self.angle_idx {
            0 => Phase::A,
            1 => Phase::B,
            _ => Phase::C,
        }
    }

    fn target_a(&self) -> f32 {
        if self.level != Level::Low {
            self.cfg.current_a
        } else {
            self.cfg.current_a * self.cfg.low_fraction
        }
    }

    /// One PWM period. See the module docs.
    pub fn step(&mut self, inp: &CalInput) -> CalStep<ResistanceResult> {
        if let Some(f) = self.finished {
            return f;
        }
        let r = self.run(inp);
        latch(&mut self.finished, r)
    }

    fn angle_error_rad(i: Dq) -> f32 {
        libm::atan2f(i.q, i.d).abs()
    }

    /// The sensor reading is within [`STILL_BITS`] of the anchor.
    fn still(&self, a: MechanicalAngle) -> bool {
        (a.wrapping_sub(self.anchor).to_bits() as i32).unsigned_abs() <= STILL_BITS
    }

    fn run(&mut self, inp: &CalInput) -> Result<CalStep<ResistanceResult>, CalError> {
        if !self.cfg.is_valid() {
            return Err(CalError::InvalidConfig);
        }
        check_input(inp, self.cfg.max_current_a)?;
        let theta = self.theta();
        let i = current_dq(inp.i_abc_a, theta);
        // Low-pass (time constant 16 periods) for the decisions, so that
        // sensor noise does not reset the settling or trip a check.
        self.i_filt = Dq::new(
            self.i_filt.d + (i.d - self.i_filt.d) * FILTER,
            self.i_filt.q + (i.q - self.i_filt.q) * FILTER,
        );
        let f = self.i_filt;
        let moving = self.motion.update(inp.angle);
        let target = self.target_a();
        let v_lim = voltage_limit_v(self.cfg.max_voltage_v, inp.v_bus_v);
        self.level_periods = self.level_periods.saturating_add(1);
        if self.level_periods > periods(self.cfg.level_timeout_s, self.cfg.ts_s) {
            return Err(CalError::Timeout);
        }

        if self.state == State::Rest {
            self.v_d = 0.0;
            if f.magnitude() < 0.05 * target {
                self.state = State::Ramp;
                self.level_periods = 0;
                self.limit_periods = 0;
            }
            return Ok(self.apply(theta));
        }
        self.drive_voltage(i, moving, target, v_lim)?;
        let in_band = !moving && (target - f.magnitude()).abs() < 0.03 * target;
        self.advance(inp.angle, i, in_band, theta)
    }

    /// The integrator towards the target current, and the checks when it
    /// reaches the voltage limit without reaching the target.
    fn drive_voltage(
        &mut self,
        i: Dq,
        moving: bool,
        target: f32,
        v_lim: f32,
    ) -> Result<(), CalError> {
        let f = self.i_filt;
        let v_new = approach_v(
            self.v_d,
            i.magnitude(),
            target,
            self.cfg.loop_bandwidth_rad_s,
            self.cfg.ramp_v_per_s,
            self.cfg.ts_s,
            v_lim,
        );
        // Hold (never raise) the voltage while the rotor swings.
        if !(moving && v_new > self.v_d) {
            self.v_d = v_new;
        }

        // At the voltage limit without reaching the target.
        if self.v_d >= v_lim && target - f.magnitude() > 0.03 * target {
            self.limit_periods = self.limit_periods.saturating_add(1);
            if self.limit_periods > periods(self.cfg.settle_s, self.cfg.ts_s) {
                return Err(if f.magnitude() < 0.25 * target {
                    CalError::OpenPhase(self.phase())
                } else if Self::angle_error_rad(f) > self.cfg.max_angle_error_rad {
                    CalError::CurrentSenseMismatch
                } else {
                    CalError::VoltageLimitReached
                });
            }
        } else {
            self.limit_periods = 0;
        }
        Ok(())
    }

    /// Ramp, settle on the target with the rotor still, then average.
    fn advance(
        &mut self,
        angle: MechanicalAngle,
        i: Dq,
        in_band: bool,
        theta: ElectricalAngle,
    ) -> Result<CalStep<ResistanceResult>, CalError> {
        match self.state {
            State::Rest | State::Ramp => {
                if in_band {
                    self.state = State::Settle(0);
                    self.anchor = angle;
                }
            }
            State::Settle(n) => self.on_settle(n, angle, in_band),
            State::Average => {
                if !self.still(angle) {
                    // The rotor moved after all: discard, settle again.
                    self.state = State::Settle(0);
                    self.anchor = angle;
                    return Ok(self.apply(theta));
                }
                self.avg_v.add(self.v_d);
                self.avg_i.add(i.d);
                self.avg_iq.add(i.q);
                if self.avg_v.count() >= periods(self.cfg.average_s, self.cfg.ts_s) {
                    return self.level_done(theta);
                }
            }
        }
        Ok(self.apply(theta))
    }

    /// Settling: again from here when out of the band or creeping; once
    /// settled, rest after the alignment level, else average.
    fn on_settle(&mut self, n: u32, angle: MechanicalAngle, in_band: bool) {
        if !in_band || !self.still(angle) {
            // Out of the band, or the rotor still creeping: settle
            // again from here.
            self.state = State::Settle(0);
            self.anchor = angle;
        } else if n + 1 >= periods(self.cfg.settle_s, self.cfg.ts_s) {
            if self.level == Level::Align {
                // The rotor is in place: rest, then measure.
                self.level = Level::Low;
                self.state = State::Rest;
                self.v_d = 0.0;
                self.level_periods = 0;
                self.limit_periods = 0;
                return;
            }
            self.state = State::Average;
            self.avg_v = Mean::ZERO;
            self.avg_i = Mean::ZERO;
            self.avg_iq = Mean::ZERO;
        } else {
            self.state = State::Settle(n + 1);
        }
    }

    fn apply(&self, theta: ElectricalAngle) -> CalStep<ResistanceResult> {
        CalStep::Apply {
            v_dq: Dq::new(self.v_d, 0.0),
            theta_e: theta,
        }
    }

    fn level_done(
        &mut self,
        theta: ElectricalAngle,
    ) -> Result<CalStep<ResistanceResult>, CalError> {
        let i_dq = Dq::new(self.avg_i.mean(), self.avg_iq.mean());
        if Self::angle_error_rad(i_dq) > self.cfg.max_angle_error_rad {
            return Err(CalError::CurrentSenseMismatch);
        }
        let (v, i) = (self.avg_v.mean(), i_dq.magnitude());
        self.level_periods = 0;
        self.limit_periods = 0;
        if self.level == Level::Low {
            self.low = (v, i);
            self.level = Level::High;
            self.state = State::Ramp;
            return Ok(self.apply(theta));
        }
        let (v_lo, i_lo) = self.low;
        let di = i - i_lo;
        let r = if di > 0.0 { (v - v_lo) / di } else { f32::NAN };
        if !(r.is_finite() && r > 0.0) {
            return Err(CalError::ImplausibleResult);
        }
        let k = usize::from(self.angle_idx);
        if let (Some(rk), Some(ok)) = (self.r.get_mut(k), self.offset.get_mut(k)) {
            *rk = r;
            *ok = v_lo - r * i_lo;
        }
        if self.angle_idx < 2 {
            self.angle_idx += 1;
            self.level = Level::Align;
            self.state = State::Rest;
            self.v_d = 0.0;
            return Ok(self.apply(self.theta()));
        }
        let [a, b, c] = self.r;
        let mean = (a + b + c) / 3.0;
        let spread = a.max(b).max(c) - a.min(b).min(c);
        if spread > self.cfg.imbalance_tolerance * mean {
            return Err(CalError::PhaseImbalance);
        }
        let [oa, ob, oc] = self.offset;
        Ok(CalStep::Done(ResistanceResult {
            r_ohm: mean,
            r_per_angle_ohm: self.r,
            v_offset_v: (oa + ob + oc) / 3.0,
        }))
    }
}
