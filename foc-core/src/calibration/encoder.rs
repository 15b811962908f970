//! Encoder linearisation: the angle sensor's error over its turn, learnt
//! by the inertial method (design §33).
//!
//! Turning freely at a steady speed, the rotor's true angle is a smooth
//! function of time; whatever the reading does beyond that is the
//! sensor's. The reading `u(t)` (unwrapped, in radians of the reading's
//! own turn) is fitted, by least squares over whole turns, with
//!
//! ```text
//! u(t) = a + b tau + c tau^2 + d tau^3 + sum_{k=1..4} (s_k sin k r + c_k cos k r)
//! ```
//!
//! where `tau` is the time scaled to `-1 .. 1` over the recording (a slow
//! change of speed, friction against the held current, is the quadratic)
//! and `r` the reading's angle (the cubic: a speed decaying through viscous
//! friction; without it, a 2 %/s decay over three turns leaked 3 % into
//! the first harmonic): the harmonics are the sensor's error
//! `e(r)`, the first being the eccentricity. Only the normal equations
//! (12 x 12) are accumulated, in `f64`, every other period; no samples are
//! kept. They are solved one column per period, so no period does more
//! than a row's work.
//!
//! **Experiment**, per direction: reach the speed in velocity mode
//! (`settle_s`), then hold the q current the speed loop needed over its
//! last 0.2 s (it balances the friction; the speed loop, which sees the
//! sensor's error as speed ripple, would otherwise turn it into real
//! ripple), and record `turns` turns. Both directions' harmonics are
//! averaged (a reading delay moves `a` the opposite way in each and cancels
//! in neither harmonic). The correction's table is `e` at each point.
//!
//! Bounded: the current vector within `max_current_a`, the whole run within
//! `timeout_s`. Named failures: the rotor does not turn
//! ([`CalError::RotorStuck`]) or does not keep a speed
//! ([`CalError::SpeedNotReached`]), the fit is singular
//! ([`CalError::MechanicsIllConditioned`]), an error beyond
//! [`MAX_CORRECTION_RAD`] ([`CalError::ImplausibleResult`]).

use super::common::{check_input, latch, CalError, CalInput, CalStep};
use crate::angle::MechanicalAngle;
use crate::control::angle_correction::{AngleCorrection, CORRECTION_BINS, MAX_CORRECTION_RAD};
use core::f32::consts::TAU;

/// Harmonics of the reading fitted.
pub const HARMONICS: usize = 4;

/// Unknowns of the fit: the cubic in time, and two per harmonic.
const N: usize = 4 + 2 * HARMONICS;

/// The time over which the hold current is averaged \[s\].
const HOLD_MEAN_S: f32 = 0.2;

/// Settings of the encoder linearisation.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncoderCalConfig {
    /// Control period \[s\].
    pub ts_s: f32,
    /// Speed of the run, mechanical [rad/s] (> 0).
    pub speed_rad_s: f32,
    /// Turns recorded per direction (>= 1).
    pub turns: u8,
    /// Time to reach the speed before the hold \[s\] (>= 0.2).
    pub settle_s: f32,
    /// Current-vector bound \[A\].
    pub max_current_a: f32,
    /// Bound on the whole run \[s\].
    pub timeout_s: f32,
    /// No-load speed per volt of bus [rad/s / V] (`1 / (sqrt 3 p psi)`;
    /// 0: unknown): the run's speed is capped at
    /// [`MAX_SHARE_OF_NO_LOAD`] of the no-load speed at the bus read at
    /// the start.
    pub no_load_rad_s_per_v: f32,
    /// The rotor's acceleration per ampere of q current, `kt / J`
    /// [rad/s^2 / A] (0: unknown): with it, the held current follows the
    /// speed's drift with a [`HOLD_TIME_CONSTANT_S`] loop (too slow to
    /// reach the sensor's harmonics, fast enough that a large cogging's
    /// average pull, which the velocity mode's mean current misjudged by
    /// 10 % on the M153, does not run the speed away).
    pub accel_per_a_rad_s2: f32,
}

/// The held current's loop on the speed's drift \[s\].
pub const HOLD_TIME_CONSTANT_S: f32 = 1.0;

/// The longest recording per direction \[s\] (fewer turns at a low speed).
const MAX_RECORD_S: f32 = 2.5;

/// Largest share of the no-load speed the run turns at.
pub const MAX_SHARE_OF_NO_LOAD: f32 = 0.3;

impl EncoderCalConfig {
    /// Defaults: six turns per second (capped by
    /// [`Self::no_load_rad_s_per_v`]), twelve turns per direction after
    /// 1 s, a timeout of twice the planned time. The rotor's inertia must
    /// filter what the sensor's error does to the torque (the current is
    /// oriented by the erroneous angle; with the cogging, the speed is not
    /// steady at the turn's harmonics) while the sensor's few harmonics
    /// stay in the reading: at one turn per second the GL80's correction
    /// came out at 75 % of its error, at three within 2 %; at six the
    /// light HKC cheetah's within 7 %.
    pub fn new(pwm_frequency_hz: f32, max_current_a: f32) -> Self {
        let mut c = Self {
            ts_s: 1.0 / pwm_frequency_hz,
            speed_rad_s: 6.0 * TAU,
            turns: 12,
            settle_s: 1.0,
            max_current_a,
            timeout_s: 0.0,
            no_load_rad_s_per_v: 0.0,
            accel_per_a_rad_s2: 0.0,
        };
        c.timeout_s = 2.0 * c.planned_s();
        c
    }

    /// The run's duration when every direction settles at once \[s\].
    pub fn planned_s(&self) -> f32 {
        2.0 * (self.settle_s + self.record_s())
    }

    /// One direction's recording \[s\].
    fn record_s(&self) -> f32 {
        self.turns as f32 * TAU / self.speed_rad_s
    }

    fn check(&self) -> Result<(), CalError> {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        let ok = pos(self.ts_s)
            && pos(self.speed_rad_s)
            && self.turns > 0
            && self.settle_s.is_finite()
            && self.settle_s >= HOLD_MEAN_S
            && pos(self.max_current_a)
            && pos(self.timeout_s);
        if ok {
            Ok(())
        } else {
            Err(CalError::InvalidConfig)
        }
    }
}

/// Where the run is.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    /// Reaching the speed in `dir` since period `since`.
    Settle { dir: i8, since: u32 },
    /// Holding `iq_a` and recording in `dir` since period `since`.
    Record { dir: i8, since: u32, iq_a: f32 },
    /// Eliminating column `col` of `dir`'s fit.
    Solve { dir: i8, col: usize },
}

/// The normal equations of the fit.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Fit {
    ata: [[f64; N]; N],
    aty: [f64; N],
}

impl Fit {
    const ZERO: Self = Self {
        ata: [[0.0; N]; N],
        aty: [0.0; N],
    };

    /// Add one sample: `u` at scaled time `tau` and reading angle `r`.
    fn add(&mut self, tau: f32, r: MechanicalAngle, u: f64) {
        let row = basis(tau, r);
        for (i, (line, y)) in self.ata.iter_mut().zip(self.aty.iter_mut()).enumerate() {
            let ri = row.get(i).copied().unwrap_or(0.0);
            for (a, rj) in line.iter_mut().zip(row.iter()).skip(i) {
                *a += ri * rj;
            }
            *y += ri * u;
        }
    }

    /// Eliminate column `col` below the diagonal (the lower triangle is
    /// read from the upper, which is what is accumulated).
    fn eliminate(&mut self, col: usize) -> Result<(), CalError> {
        let singular = CalError::MechanicsIllConditioned;
        let pivot_row = *self.ata.get(col).ok_or(singular)?;
        let pivot = pivot_row.get(col).copied().unwrap_or(0.0);
        if !(pivot.is_finite() && pivot.abs() > 1e-12) {
            return Err(singular);
        }
        let y_col = self.aty.get(col).copied().unwrap_or(0.0);
        let rows = self.ata.iter_mut().zip(self.aty.iter_mut());
        for (i, (line, y)) in rows.enumerate().skip(col + 1) {
            // The symmetric lower entry.
            let f = pivot_row.get(i).copied().unwrap_or(0.0) / pivot;
            for (a, p) in line.iter_mut().zip(pivot_row.iter()).skip(i) {
                *a -= f * p;
            }
            *y -= f * y_col;
        }
        Ok(())
    }

    /// Back substitution after every column is eliminated.
    fn solve(&self) -> [f64; N] {
        let mut x = [0.0; N];
        for i in (0..N).rev() {
            let (Some(line), Some(y)) = (self.ata.get(i), self.aty.get(i)) else {
                continue;
            };
            let mut s = *y;
            for (a, xj) in line.iter().zip(x.iter()).skip(i + 1) {
                s -= a * xj;
            }
            let d = line.get(i).copied().unwrap_or(0.0);
            if let Some(xi) = x.get_mut(i) {
                *xi = if d != 0.0 { s / d } else { 0.0 };
            }
        }
        x
    }
}

/// The fit's regressors at `tau` and reading `r`.
fn basis(tau: f32, r: MechanicalAngle) -> [f64; N] {
    let (s1, c1) = crate::trig::sin_cos_bits(r.to_bits());
    let mut row = [0.0f64; N];
    let (t, t2) = (tau as f64, (tau * tau) as f64);
    let (head, harmonics) = row.split_at_mut(4);
    head.copy_from_slice(&[1.0, t, t2, t2 * t]);
    let (mut s, mut c) = (s1, c1);
    for pair in harmonics.chunks_exact_mut(2) {
        pair.copy_from_slice(&[s as f64, c as f64]);
        // sin/cos of (k + 1) r from k r.
        let (sn, cn) = (s * c1 + c * s1, c * c1 - s * s1);
        s = sn;
        c = cn;
    }
    row
}

/// The encoder linearisation routine.
#[derive(Clone, Copy, Debug)]
pub struct EncoderCalibration {
    config: EncoderCalConfig,
    phase: Phase,
    period: u32,
    /// Reading at the recording's start, and the unwrapped travel since
    /// \[rad\].
    start: MechanicalAngle,
    last: MechanicalAngle,
    travel_rad: f64,
    /// The hold current's sum and count over the settle's last part.
    iq_sum_a: f32,
    iq_n: u32,
    fit: Fit,
    /// The forward direction's harmonics.
    forward: [f32; 2 * HARMONICS],
    correction: AngleCorrection,
    finished: Option<CalStep<()>>,
}

impl EncoderCalibration {
    /// A new run (the config is checked at the first step).
    pub fn new(config: EncoderCalConfig) -> Self {
        Self {
            config,
            phase: Phase::Settle { dir: 1, since: 0 },
            period: 0,
            start: MechanicalAngle::ZERO,
            last: MechanicalAngle::ZERO,
            travel_rad: 0.0,
            iq_sum_a: 0.0,
            iq_n: 0,
            fit: Fit::ZERO,
            forward: [0.0; 2 * HARMONICS],
            correction: AngleCorrection::NONE,
            finished: None,
        }
    }

    /// Its settings.
    pub fn config(&self) -> &EncoderCalConfig {
        &self.config
    }

    /// The correction learnt ([`AngleCorrection::NONE`] until done).
    pub fn correction(&self) -> &AngleCorrection {
        &self.correction
    }

    /// Periods stepped so far.
    pub fn elapsed_periods(&self) -> u32 {
        self.period
    }

    /// One period; `inp.angle` is the raw reading, `inp.closed_loop` the
    /// velocity or torque mode's feedback from the second period on.
    pub fn step(&mut self, inp: &CalInput) -> CalStep<()> {
        if let Some(f) = self.finished {
            return f;
        }
        let r = self.step_inner(inp);
        latch(&mut self.finished, r)
    }

    fn step_inner(&mut self, inp: &CalInput) -> Result<CalStep<()>, CalError> {
        self.config.check()?;
        check_input(inp, self.config.max_current_a)?;
        self.period = self.period.saturating_add(1);
        if self.period as f32 * self.config.ts_s > self.config.timeout_s {
            return Err(CalError::Timeout);
        }
        let Some(fb) = inp.closed_loop else {
            // The first period: the speed within the no-load speed's share.
            let cap = MAX_SHARE_OF_NO_LOAD * self.config.no_load_rad_s_per_v * inp.v_bus_v;
            if cap > 0.0 && cap < self.config.speed_rad_s {
                self.config.speed_rad_s = cap;
                let fit = MAX_RECORD_S * cap / TAU;
                if fit < self.config.turns as f32 {
                    self.config.turns = (fit as u8).max(3);
                }
                // The bound follows the slower run (at least three turns:
                // below 3.8 rad/s the default's 12 s was too short).
                let longer = 2.0 * self.config.planned_s();
                if longer > self.config.timeout_s {
                    self.config.timeout_s = longer;
                }
            }
            return Ok(self.velocity(1));
        };
        match self.phase {
            Phase::Settle { dir, since } => {
                self.settle(dir, since, fb.i_dq_a.q, fb.velocity_rad_s, inp.angle)
            }
            Phase::Record { dir, since, iq_a } => {
                self.record(dir, since, iq_a, fb.velocity_rad_s, inp.angle)
            }
            Phase::Solve { dir, col } => self.solve(dir, col),
        }
    }

    fn velocity(&self, dir: i8) -> CalStep<()> {
        CalStep::Velocity {
            rad_s: dir as f32 * self.config.speed_rad_s,
        }
    }

    fn settle(
        &mut self,
        dir: i8,
        since: u32,
        iq_a: f32,
        w_rad_s: f32,
        reading: MechanicalAngle,
    ) -> Result<CalStep<()>, CalError> {
        let c = self.config;
        let t = self.period.saturating_sub(since) as f32 * c.ts_s;
        if t >= c.settle_s - HOLD_MEAN_S {
            self.iq_sum_a += iq_a;
            self.iq_n += 1;
        }
        if t < c.settle_s {
            return Ok(self.velocity(dir));
        }
        let target = dir as f32 * c.speed_rad_s;
        if (w_rad_s - target).abs() > 0.2 * c.speed_rad_s {
            return Err(slow_rotor(w_rad_s, target));
        }
        let hold = self.iq_sum_a / self.iq_n.max(1) as f32;
        self.iq_sum_a = 0.0;
        self.iq_n = 0;
        self.fit = Fit::ZERO;
        self.start = reading;
        self.last = reading;
        self.travel_rad = 0.0;
        self.phase = Phase::Record {
            dir,
            since: self.period,
            iq_a: hold,
        };
        Ok(CalStep::Torque { iq_a: hold })
    }

    fn record(
        &mut self,
        dir: i8,
        since: u32,
        iq_a: f32,
        w_rad_s: f32,
        reading: MechanicalAngle,
    ) -> Result<CalStep<()>, CalError> {
        let c = self.config;
        // Coasting on the held current: a rotor far off the speed is not
        // turning steadily (a load, a stall).
        let target = dir as f32 * c.speed_rad_s;
        if (w_rad_s - target).abs() > 0.5 * c.speed_rad_s {
            return Err(slow_rotor(w_rad_s, target));
        }
        // The held current follows the speed's slow drift.
        let a = c.accel_per_a_rad_s2;
        let iq_a = if a > 0.0 && a.is_finite() {
            iq_a - (w_rad_s - target) / (a * HOLD_TIME_CONSTANT_S) * c.ts_s
        } else {
            iq_a
        };
        self.phase = Phase::Record { dir, since, iq_a };
        self.travel_rad += reading.diff_radians(self.last) as f64;
        self.last = reading;
        let n = self.period.saturating_sub(since);
        if n.is_multiple_of(2) {
            let tau = 2.0 * n as f32 * c.ts_s / c.record_s() - 1.0;
            self.fit.add(tau, reading, self.travel_rad);
        }
        if self.travel_rad.abs() < c.turns as f64 * core::f64::consts::TAU {
            return Ok(CalStep::Torque { iq_a });
        }
        self.phase = Phase::Solve { dir, col: 0 };
        Ok(CalStep::Torque { iq_a })
    }

    /// One column a period; then this direction's harmonics, and the next
    /// direction or the correction.
    fn solve(&mut self, dir: i8, col: usize) -> Result<CalStep<()>, CalError> {
        self.fit.eliminate(col)?;
        if col + 1 < N {
            self.phase = Phase::Solve { dir, col: col + 1 };
            return Ok(self.velocity(dir));
        }
        let x = self.fit.solve();
        let mut h = [0.0f32; 2 * HARMONICS];
        for (k, v) in h.iter_mut().enumerate() {
            *v = x.get(4 + k).copied().unwrap_or(0.0) as f32;
        }
        if dir > 0 {
            self.forward = h;
            self.phase = Phase::Settle {
                dir: -1,
                since: self.period,
            };
            return Ok(self.velocity(-1));
        }
        for (v, f) in h.iter_mut().zip(self.forward.iter()) {
            *v = 0.5 * (*v + f);
        }
        self.correction = table_of(&h)?;
        Ok(CalStep::Done(()))
    }
}

/// The correction table from the harmonics `[s1, c1, s2, c2, ...]`.
fn table_of(h: &[f32; 2 * HARMONICS]) -> Result<AngleCorrection, CalError> {
    let mut rad = [0.0f32; CORRECTION_BINS];
    for (k, v) in rad.iter_mut().enumerate() {
        let centre = ((2 * k + 1) as u64 * (1u64 << 31) / CORRECTION_BINS as u64) as u32;
        let (s1, c1) = crate::trig::sin_cos_bits(centre);
        let (mut s, mut c) = (s1, c1);
        let mut e = 0.0;
        for pair in h.chunks_exact(2) {
            if let [sk, ck] = pair {
                e += sk * s + ck * c;
            }
            let (sn, cn) = (s * c1 + c * s1, c * c1 - s * s1);
            s = sn;
            c = cn;
        }
        *v = e;
    }
    match AngleCorrection::from_rad(&rad) {
        Ok(c) if c.peak_rad() <= MAX_CORRECTION_RAD => Ok(c),
        _ => Err(CalError::ImplausibleResult),
    }
}

/// A rotor off the speed: stuck (below a tenth of it) or slow.
fn slow_rotor(w_rad_s: f32, target_rad_s: f32) -> CalError {
    if w_rad_s.abs() < 0.1 * target_rad_s.abs() {
        CalError::RotorStuck
    } else {
        CalError::SpeedNotReached
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibration::ClosedLoopFeedback;
    use crate::frames::{Abc, Dq};

    const HZ: f32 = 10_000.0;

    /// A rotor at the requested speed (slowing by 2 % a second while the
    /// current is held), read through a sensor with `e(theta) = 0.005 sin
    /// theta + 0.0017 sin(2 theta + 0.4)` and a reading delay.
    fn run(cal: &mut EncoderCalibration, stuck: bool) -> CalStep<()> {
        let (mut theta, mut w) = (0.3f64, 0.0f64);
        let mut held;
        for n in 0..10_000_000u32 {
            let e = 0.005 * theta.sin() + 0.0017 * (2.0 * theta + 0.4).sin();
            let reading = MechanicalAngle::from_radians((theta + e) as f32);
            let mut inp = CalInput::open_loop(Abc::default(), reading, 24.0);
            if n > 0 {
                inp.closed_loop = Some(ClosedLoopFeedback {
                    v_dq_v: Dq::ZERO,
                    i_dq_a: Dq::new(0.0, 0.2 * w.signum() as f32),
                    velocity_rad_s: if stuck { 0.0 } else { w as f32 },
                    theta_e: Default::default(),
                });
            }
            match cal.step(&inp) {
                CalStep::Velocity { rad_s } => {
                    w = rad_s as f64;
                    held = false;
                }
                CalStep::Torque { .. } => held = true,
                other => return other,
            }
            if held {
                w *= 1.0 - 0.02 / HZ as f64;
            }
            if !stuck {
                theta += w / HZ as f64;
            }
        }
        panic!("did not finish");
    }

    #[test]
    fn learns_the_sensors_error() {
        let mut cal = EncoderCalibration::new(EncoderCalConfig::new(HZ, 5.0));
        assert_eq!(run(&mut cal, false), CalStep::Done(()));
        let c = cal.correction();
        for k in (0..CORRECTION_BINS).step_by(5) {
            let th = TAU as f64 * (k as f64 + 0.5) / CORRECTION_BINS as f64;
            let want = 0.005 * th.sin() + 0.0017 * (2.0 * th + 0.4).sin();
            let got = c.rad_at(k) as f64;
            assert!((got - want).abs() < 1e-4, "{k}: {got} vs {want}");
        }
    }

    #[test]
    fn named_failures() {
        let c = EncoderCalConfig::new(HZ, 5.0);
        assert_eq!(
            run(&mut EncoderCalibration::new(c), true),
            CalStep::Failed(CalError::RotorStuck)
        );
        let short = EncoderCalConfig {
            timeout_s: 1.5,
            ..c
        };
        assert_eq!(
            run(&mut EncoderCalibration::new(short), false),
            CalStep::Failed(CalError::Timeout)
        );
        let bad = EncoderCalConfig { turns: 0, ..c };
        assert_eq!(
            run(&mut EncoderCalibration::new(bad), false),
            CalStep::Failed(CalError::InvalidConfig)
        );
    }
}
