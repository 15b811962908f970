//! Angle-sensor alignment: direction, electrical zero and pole-pair check.
//!
//! With a d-axis voltage `voltage_v` (sized from the measured resistance so
//! that about the test current flows) the routine
//! 1. ramps the voltage up at `theta_e = 0` and holds it (`hold_s`),
//! 2. turns the open-loop angle forward at `speed_e_rad_s` for
//!    `lead_in_turns_e + turns_e` electrical turns,
//! 3. holds again, then turns backward by the same amount.
//!
//! Over the last `turns_e` turns of each sweep (whole turns, so cyclic
//! errors of the sensor and cogging average out) it records the sensor's
//! multi-turn travel and, every period, the difference between the sensor's
//! electrical angle and the commanded angle. Then:
//!
//! - pole pairs = commanded electrical travel / measured mechanical travel
//!   (both sweeps); differing from the configured count by more than
//!   `max_pole_pair_error` -> [`CalError::PolePairMismatch`] (reported, never
//!   absorbed: the configuration is wrong);
//! - direction = sign of the sensor travel during the forward sweep; if the
//!   configuration states an expected direction and it differs ->
//!   [`CalError::SensorReversed`], else `reversed` is set from it;
//! - zero offset = circular mean of `p * theta_m - theta_cmd` over both
//!   sweeps: friction and the loop delay make the rotor lag the field on the
//!   forward sweep and lead it on the backward one, and the mean of both
//!   cancels that lag ([`AlignmentResult::lag_e_rad`] reports it);
//! - total sensor travel below 1/16 of the expected ->
//!   [`CalError::SensorNoMotion`]; motion that stops part way (an electrical
//!   turn with less than a quarter of the average travel, travel against the
//!   field, or forward and backward travel differing by more than 25 %) ->
//!   [`CalError::RotorStuck`].
//!
//! ```
//! use foc_core::calibration::alignment::{Alignment, AlignmentConfig};
//! use foc_core::calibration::{CalInput, CalStep};
//! use foc_core::{angle::MechanicalAngle, frames::Abc};
//! let mut a = Alignment::new(AlignmentConfig::new(7, 20_000.0, 1.0, 5.0));
//! let s = a.step(&CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0));
//! let (v, _theta) = s.voltage().unwrap(); // ramping up at theta_e = 0
//! assert!(v.d > 0.0 && v.d < 1.0);
//! ```

use super::common::{
    check_input, latch, periods, voltage_limit_v, CalError, CalInput, CalStep, CircularMean,
};
use crate::angle::{ElectricalAngle, MechanicalAngle, MultiTurn};
use crate::control::stage::AngleCalibration;
use crate::frames::Dq;
use core::f32::consts::TAU;

/// Configuration of the alignment.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AlignmentConfig {
    /// PWM (step) period \[s\].
    pub ts_s: f32,
    /// Configured pole pairs (checked, never changed).
    pub pole_pairs: u8,
    /// Expected sensor direction: `Some(true)` if the sensor must count
    /// backwards relative to A -> B -> C, `Some(false)` forwards, `None` to
    /// detect it.
    pub expected_reversed: Option<bool>,
    /// d-axis voltage during the sweeps \[V\].
    pub voltage_v: f32,
    /// Largest open-loop voltage \[V\] (also limited by the bus).
    pub max_voltage_v: f32,
    /// Current vector that aborts the routine \[A\].
    pub max_current_a: f32,
    /// Sweep speed [rad/s, electrical].
    pub speed_e_rad_s: f32,
    /// Electrical turns evaluated per sweep.
    pub turns_e: u16,
    /// Electrical turns at the start of each sweep that are not evaluated.
    pub lead_in_turns_e: u16,
    /// Ramp-and-hold time before each sweep \[s\].
    pub hold_s: f32,
    /// Largest accepted `|measured - configured|` pole pairs.
    pub max_pole_pair_error: f32,
    /// Counts per mechanical turn of the angle sensor, 0 if unknown. A
    /// counting sensor reads `floor` of its position, on average half a
    /// count behind it; when the resolution is known the sweeps read through
    /// `AngleCalibration::mechanical`, which adds that half count, and the
    /// result carries the resolution so the current stage does the same (the
    /// zero found is then the physical one: without it the bias is
    /// `p / (2 counts)` of a turn, 30 deg(e) for 48 counts on 8 pole pairs).
    pub sensor_counts_per_rev: u32,
}

impl AlignmentConfig {
    /// Defaults: `voltage_v` on d, abort at `max_current_a`, voltage limit
    /// twice `voltage_v`, 2 electrical turns/s, 1 lead-in plus 2 evaluated
    /// turns each way, 0.5 s holds, pole-pair tolerance 0.2, direction
    /// detected.
    pub fn new(pole_pairs: u8, pwm_frequency_hz: f32, voltage_v: f32, max_current_a: f32) -> Self {
        Self {
            ts_s: 1.0 / pwm_frequency_hz,
            pole_pairs,
            expected_reversed: None,
            voltage_v,
            max_voltage_v: 2.0 * voltage_v,
            max_current_a,
            speed_e_rad_s: 2.0 * TAU,
            turns_e: 2,
            lead_in_turns_e: 1,
            hold_s: 0.5,
            max_pole_pair_error: 0.2,
            sensor_counts_per_rev: 0,
        }
    }

    fn is_valid(&self) -> bool {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        self.pole_pairs > 0
            && pos(self.ts_s)
            && pos(self.voltage_v)
            && pos(self.max_voltage_v)
            && pos(self.max_current_a)
            && pos(self.speed_e_rad_s)
            && self.speed_e_rad_s * self.ts_s < 0.5
            && self.turns_e > 0
            && pos(self.hold_s)
            && pos(self.max_pole_pair_error)
    }
}

/// Result of the alignment.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AlignmentResult {
    /// Sensor to electrical angle (configured pole pairs, measured zero and
    /// direction).
    pub calibration: AngleCalibration,
    /// Measured pole pairs times 100.
    pub measured_pole_pairs_x100: u16,
    /// Half the difference of the forward and backward offsets [rad,
    /// electrical]: how far the rotor trailed the field (friction, delay).
    pub lag_e_rad: f32,
    /// Mean resultant length of the offset samples (1 = no scatter).
    pub consistency: f32,
}

#[derive(Clone, Copy, Debug, PartialEq, Default)]
struct Sweep {
    start_rad: f32,
    travel_rad: f32,
    chunk_start_rad: f32,
    min_chunk_rad: f32,
    max_chunk_rad: f32,
    cmd_rad: f32,
    normal: CircularMean,
    reversed: CircularMean,
}

impl Sweep {
    /// The sensor's electrical angle against the commanded `theta`, in
    /// both sign conventions.
    fn record(&mut self, c: &AlignmentConfig, angle: MechanicalAngle, theta: ElectricalAngle) {
        let normal = AngleCalibration {
            pole_pairs: c.pole_pairs,
            zero_offset: ElectricalAngle::ZERO,
            reversed: false,
            sensor_counts_per_rev: c.sensor_counts_per_rev,
            sensorless_only: false,
        };
        let rev = AngleCalibration {
            reversed: true,
            ..normal
        };
        self.normal.add(
            normal
                .electrical(normal.mechanical(angle))
                .wrapping_sub(theta),
        );
        self.reversed
            .add(rev.electrical(rev.mechanical(angle)).wrapping_sub(theta));
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    Hold { n: u32, forward: bool },
    Sweep { n: u32, forward: bool },
}

/// The alignment state machine.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Alignment {
    cfg: AlignmentConfig,
    state: State,
    theta: ElectricalAngle,
    step_bits: u32,
    per_turn: u32,
    position: Option<MultiTurn>,
    fwd: Sweep,
    back: Sweep,
    finished: Option<CalStep<AlignmentResult>>,
}

impl Alignment {
    /// New alignment (starts with the ramp at `theta_e = 0`).
    pub fn new(config: AlignmentConfig) -> Self {
        let per_turn = periods(TAU / config.speed_e_rad_s, config.ts_s).max(4);
        Self {
            cfg: config,
            state: State::Hold {
                n: 0,
                forward: true,
            },
            theta: ElectricalAngle::ZERO,
            step_bits: (4_294_967_296u64 / u64::from(per_turn)) as u32,
            per_turn,
            position: None,
            fwd: Sweep::default(),
            back: Sweep::default(),
            finished: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &AlignmentConfig {
        &self.cfg
    }

    /// One PWM period. See the module docs.
    pub fn step(&mut self, inp: &CalInput) -> CalStep<AlignmentResult> {
        if let Some(f) = self.finished {
            return f;
        }
        let r = self.run(inp);
        latch(&mut self.finished, r)
    }

    fn run(&mut self, inp: &CalInput) -> Result<CalStep<AlignmentResult>, CalError> {
        if !self.cfg.is_valid() {
            return Err(CalError::InvalidConfig);
        }
        check_input(inp, self.cfg.max_current_a)?;
        let c = self.cfg;
        let pos_rad = self.position_rad(inp.angle);
        let v_lim = voltage_limit_v(c.max_voltage_v, inp.v_bus_v);
        let v_full = if c.voltage_v < v_lim {
            c.voltage_v
        } else {
            v_lim
        };
        let hold = periods(c.hold_s, c.ts_s);
        let theta = self.theta;
        let mut v_d = v_full;

        match self.state {
            State::Hold { n, forward } => {
                if forward && n < hold / 2 {
                    v_d = v_full * (n as f32 + 1.0) / (hold / 2) as f32;
                }
                self.state = if n + 1 >= hold {
                    State::Sweep { n: 0, forward }
                } else {
                    State::Hold { n: n + 1, forward }
                };
            }
            State::Sweep { n, forward } => {
                if self.on_sweep(n, forward, pos_rad, inp.angle) {
                    return self.finish().map(CalStep::Done);
                }
                let step = ElectricalAngle::from_bits(self.step_bits);
                self.theta = if forward {
                    theta.wrapping_add(step)
                } else {
                    theta.wrapping_sub(step)
                };
            }
        }
        Ok(CalStep::Apply {
            v_dq: Dq::new(v_d, 0.0),
            theta_e: theta,
        })
    }

    /// The rotor's position since the first period [rad, mechanical].
    fn position_rad(&mut self, angle: MechanicalAngle) -> f32 {
        match self.position.as_mut() {
            Some(p) => {
                p.update(angle);
                p.to_radians()
            }
            None => {
                let p = MultiTurn::new(angle);
                self.position = Some(p);
                p.to_radians()
            }
        }
    }

    /// One period of a sweep: after the lead-in, the sensor's angle against
    /// the commanded one in both sign conventions, and each electrical
    /// turn's travel. True when the backward sweep's window has closed.
    fn on_sweep(&mut self, n: u32, forward: bool, pos_rad: f32, angle: MechanicalAngle) -> bool {
        let c = self.cfg;
        let lead = self.per_turn.saturating_mul(u32::from(c.lead_in_turns_e));
        let window = self.per_turn.saturating_mul(u32::from(c.turns_e));
        let (theta, per_turn, step_bits) = (self.theta, self.per_turn, self.step_bits);
        let sweep = if forward {
            &mut self.fwd
        } else {
            &mut self.back
        };
        if n == lead {
            sweep.start_rad = pos_rad;
            sweep.chunk_start_rad = pos_rad;
            sweep.min_chunk_rad = f32::INFINITY;
            sweep.max_chunk_rad = f32::NEG_INFINITY;
        }
        if n >= lead && n < lead + window {
            sweep.record(&c, angle, theta);
        }
        if n >= lead && (n + 1 - lead).is_multiple_of(per_turn) {
            // One electrical turn evaluated: its travel, signed in
            // the commanded direction.
            let chunk = pos_rad - sweep.chunk_start_rad;
            sweep.chunk_start_rad = pos_rad;
            let signed = if forward { chunk } else { -chunk };
            sweep.min_chunk_rad = sweep.min_chunk_rad.min(signed);
            sweep.max_chunk_rad = sweep.max_chunk_rad.max(signed);
        }
        if n + 1 >= lead + window {
            // Window closes with the sample of this period.
            sweep.travel_rad = pos_rad - sweep.start_rad;
            sweep.cmd_rad = window as f32 * step_bits as f32 * (TAU / 4_294_967_296.0);
            if !forward {
                return true;
            }
            self.state = State::Hold {
                n: 0,
                forward: false,
            };
        } else {
            self.state = State::Sweep { n: n + 1, forward };
        }
        false
    }

    fn finish(&self) -> Result<AlignmentResult, CalError> {
        let c = self.cfg;
        let p_conf = f32::from(c.pole_pairs);
        let (f, b) = (&self.fwd, &self.back);
        let cmd = f.cmd_rad + b.cmd_rad;
        let moved = f.travel_rad.abs() + b.travel_rad.abs();
        if !(moved.is_finite() && moved >= cmd / p_conf / 16.0) {
            return Err(CalError::SensorNoMotion);
        }
        // The sensor's sign convention is not known yet: judge the chunks
        // in the direction the sensor moved on the forward sweep.
        let s = if f.travel_rad < 0.0 { -1.0 } else { 1.0 };
        let per_turn_rad = moved / (2.0 * f32::from(c.turns_e));
        let chunk_ok = |sw: &Sweep| {
            let (lo, hi) = if s > 0.0 {
                (sw.min_chunk_rad, sw.max_chunk_rad)
            } else {
                (-sw.max_chunk_rad, -sw.min_chunk_rad)
            };
            lo.is_finite() && hi.is_finite() && lo > 0.25 * per_turn_rad
        };
        let opposite = f.travel_rad * b.travel_rad < 0.0;
        let (fa, ba) = (f.travel_rad.abs(), b.travel_rad.abs());
        let balanced = (fa - ba).abs() <= 0.25 * fa.max(ba);
        if !opposite || !balanced || !chunk_ok(f) || !chunk_ok(b) {
            return Err(CalError::RotorStuck);
        }
        let p = cmd / moved;
        let x100 = libm::roundf(100.0 * p);
        let measured_x100 = if x100 >= 65_535.0 {
            u16::MAX
        } else {
            x100 as u16
        };
        let close = (p - p_conf).abs() <= c.max_pole_pair_error;
        if !close {
            return Err(CalError::PolePairMismatch {
                configured: c.pole_pairs,
                measured_x100,
            });
        }
        let reversed = f.travel_rad < 0.0;
        if let Some(expected) = c.expected_reversed {
            if expected != reversed {
                return Err(CalError::SensorReversed);
            }
        }
        let (mf, mb) = if reversed {
            (f.reversed, b.reversed)
        } else {
            (f.normal, b.normal)
        };
        let mut all = mf;
        all.merge(&mb);
        let (Some((zero, consistency)), Some((zf, _)), Some((zb, _))) =
            (all.mean(), mf.mean(), mb.mean())
        else {
            return Err(CalError::ImplausibleResult);
        };
        if consistency < 0.7 {
            return Err(CalError::ImplausibleResult);
        }
        Ok(AlignmentResult {
            calibration: AngleCalibration {
                pole_pairs: c.pole_pairs,
                zero_offset: zero,
                reversed,
                sensor_counts_per_rev: c.sensor_counts_per_rev,
                sensorless_only: false,
            },
            measured_pole_pairs_x100: measured_x100,
            lag_e_rad: 0.5 * zb.diff_radians(zf),
            consistency,
        })
    }
}
