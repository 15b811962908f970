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
//! (12 x 12) are accumulated; no samples are kept.
//!
//! **Experiment**, per direction: reach the speed in velocity mode
//! (`settle_s`), then hold the q current the speed loop needed over its
//! last 0.2 s (it balances the friction; the speed loop, which sees the
//! sensor's error as speed ripple, would otherwise turn it into real
//! ripple), and record `turns` turns. Both directions' harmonics are
//! averaged (a reading delay moves `a` the opposite way in each and cancels
//! in neither harmonic). The correction's table is `e` at each point.
//!
//! **A period's work.** The routine runs in the current loop's interrupt
//! on a Cortex-M4F, whose `f64` is software (about a hundred instructions
//! an operation), so no period does more than a handful of `f64`
//! operations, and none on a sample:
//!
//! - recording, every period: the travel, unwrapped in integer bits of a
//!   turn (exact);
//! - every other period, a sample: its regressors, and its products into
//!   an `f32` block of the normal equations' upper triangle and
//!   right-hand side (90 multiply-adds). What is fitted is the travel less
//!   the nominal run `dir * speed * t`: a straight line in `tau`, which
//!   only moves `a` and `b`, and leaves a few radians instead of tens for
//!   the `f32` products (in the unit test's run the table came within
//!   2e-7 rad of an all-`f64` fit's, against 9e-7 fitting the travel
//!   itself);
//! - the periods between, a fold: 6 of the block's entries added to the
//!   `f64` sums and zeroed, round the block, so each entry sums in `f32`
//!   over 15 samples at most;
//! - after the last sample, the solve, the velocity loop holding the speed
//!   (161 periods): the block folded once more (15), the elimination (a
//!   pivot's reciprocal, or up to 4 `f64` multiply-subtracts of one row,
//!   a period: 124) and the back substitution by columns (the same: 22);
//! - after both directions, the table in 8 points a period (65 periods):
//!   the error's peak, which sets the quantisation, then the points
//!   quantised into the correction ([`AngleCorrection::with_peak`],
//!   [`AngleCorrection::set_rad`]).
//!
//! Bounded: the current vector within `max_current_a`, the whole run within
//! `timeout_s`. Named failures: the rotor does not turn
//! ([`CalError::RotorStuck`]) or does not keep a speed
//! ([`CalError::SpeedNotReached`]), the fit is singular
//! ([`CalError::MechanicsIllConditioned`]), an error beyond
//! [`MAX_CORRECTION_RAD`](crate::control::angle_correction::MAX_CORRECTION_RAD)
//! ([`CalError::ImplausibleResult`]).

use super::common::{check_input, latch, CalError, CalInput, CalStep};
use crate::angle::MechanicalAngle;
use crate::control::angle_correction::{AngleCorrection, CORRECTION_BINS};
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
    /// Solving `dir`'s fit, a step a period.
    Solve { dir: i8 },
    /// The correction's peak over its points from `at` (still turning in
    /// `dir`); its scale at `CORRECTION_BINS`.
    Peak { dir: i8, at: usize },
    /// The correction's points from `at`, quantised.
    Fill { dir: i8, at: usize },
}

/// Entries of the normal equations as kept: row `i` holds columns
/// `i .. N` of the (symmetric) matrix, then its right-hand side.
const TRI: usize = N * (N + 1) / 2 + N;

/// Block entries folded into the sums a period.
const FOLD: usize = 6;

/// `f64` multiply-subtracts a period in the solve.
const MADDS: usize = 4;

/// Correction points computed a period.
const BINS_A_PERIOD: usize = 8;

/// Where row `i` starts in the kept entries.
const fn row_start(i: usize) -> usize {
    i * (N + 1) - i * i.saturating_sub(1) / 2
}

/// Where entry `(i, j)` is kept (`i <= j <= N`; `j = N` is the
/// right-hand side).
const fn at(i: usize, j: usize) -> usize {
    row_start(i) + j.saturating_sub(i)
}

/// The solve's place.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Stage {
    /// Folding the block from entry `at`, once more after the last sample.
    Fold { at: usize },
    /// Column `col`'s pivot checked and replaced by its reciprocal.
    Pivot { col: usize },
    /// Column `col` taken out of row `row`, from its entry `from` on.
    Eliminate { col: usize, row: usize, from: usize },
    /// Unknown `col` solved (from 0) and taken out of rows `from ..` above.
    Substitute { col: usize, from: usize },
}

/// The fit's normal equations: the recent samples' sums in `f32`, the
/// rest in `f64`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Fit {
    /// The samples since each entry was last folded.
    block: [f32; TRI],
    /// The folded sums; solved in place (the pivots become their
    /// reciprocals, the right-hand sides the unknowns).
    sums: [f64; TRI],
    /// The entry the next fold starts at.
    fold_at: usize,
    stage: Stage,
}

impl Fit {
    const ZERO: Self = Self {
        block: [0.0; TRI],
        sums: [0.0; TRI],
        fold_at: 0,
        stage: Stage::Fold { at: 0 },
    };

    /// Add one sample: `y` at scaled time `tau` and reading angle `r`.
    fn add(&mut self, tau: f32, r: MechanicalAngle, y: f32) {
        let b = basis(tau, r);
        for (i, bi) in b.iter().enumerate() {
            let line = self.block.get_mut(row_start(i)..row_start(i + 1));
            let Some((rhs, upper)) = line.and_then(|l| l.split_last_mut()) else {
                continue;
            };
            for (a, bj) in upper.iter_mut().zip(b.iter().skip(i)) {
                *a += bi * bj;
            }
            *rhs += bi * y;
        }
    }

    /// Move [`FOLD`] entries of the block from `at` into the sums.
    fn fold(&mut self, at: usize) {
        let end = (at + FOLD).min(TRI);
        let (Some(sums), Some(block)) = (self.sums.get_mut(at..end), self.block.get_mut(at..end))
        else {
            return;
        };
        for (s, b) in sums.iter_mut().zip(block.iter_mut()) {
            *s += f64::from(*b);
            *b = 0.0;
        }
    }

    /// The recording's fold: the next entries, round the block.
    fn fold_next(&mut self) {
        self.fold(self.fold_at);
        self.fold_at = if self.fold_at + FOLD < TRI {
            self.fold_at + FOLD
        } else {
            0
        };
    }

    fn sum(&self, i: usize) -> f64 {
        self.sums.get(i).copied().unwrap_or(0.0)
    }

    fn set(&mut self, i: usize, v: f64) {
        if let Some(s) = self.sums.get_mut(i) {
            *s = v;
        }
    }

    /// One step of the solve; the harmonics after the last.
    fn solve_step(&mut self) -> Result<Option<[f32; 2 * HARMONICS]>, CalError> {
        let next = match self.stage {
            Stage::Fold { at } => {
                self.fold(at);
                if at + FOLD < TRI {
                    Stage::Fold { at: at + FOLD }
                } else {
                    Stage::Pivot { col: 0 }
                }
            }
            Stage::Pivot { col } => {
                self.pivot(col)?;
                if col + 1 < N {
                    Stage::Eliminate {
                        col,
                        row: col + 1,
                        from: 0,
                    }
                } else {
                    Stage::Substitute { col, from: 0 }
                }
            }
            Stage::Eliminate { col, row, from } => self.eliminate(col, row, from),
            Stage::Substitute { col, from } => match self.substitute(col, from) {
                Some(next) => next,
                None => return Ok(Some(self.harmonics())),
            },
        };
        self.stage = next;
        Ok(None)
    }

    /// Check column `col`'s pivot (every column above it eliminated) and
    /// keep its reciprocal in its place.
    fn pivot(&mut self, col: usize) -> Result<(), CalError> {
        let p = self.sum(at(col, col));
        if !(p.is_finite() && p.abs() > 1e-12) {
            return Err(CalError::MechanicsIllConditioned);
        }
        self.set(at(col, col), 1.0 / p);
        Ok(())
    }

    /// Take column `col` out of row `row`'s entries `from ..` (up to
    /// [`MADDS`] of them): the lower entry is read from the upper, the
    /// pivot row is row `col`.
    fn eliminate(&mut self, col: usize, row: usize, from: usize) -> Stage {
        let f = self.sum(at(col, row)) * self.sum(at(col, col));
        let len = N + 1 - row;
        for k in from..(from + MADDS).min(len) {
            let p = self.sum(at(col, row + k));
            if let Some(a) = self.sums.get_mut(at(row, row + k)) {
                *a -= f * p;
            }
        }
        if from + MADDS < len {
            Stage::Eliminate {
                col,
                row,
                from: from + MADDS,
            }
        } else if row + 1 < N {
            Stage::Eliminate {
                col,
                row: row + 1,
                from: 0,
            }
        } else {
            Stage::Pivot { col: col + 1 }
        }
    }

    /// Back substitution by columns: unknown `col` (its right-hand side
    /// over the pivot, at `from` 0), taken out of the right-hand sides of
    /// rows `from ..` above it (up to [`MADDS`]). `None` after the last.
    fn substitute(&mut self, col: usize, from: usize) -> Option<Stage> {
        let x = if from == 0 {
            let x = self.sum(at(col, N)) * self.sum(at(col, col));
            self.set(at(col, N), x);
            x
        } else {
            self.sum(at(col, N))
        };
        for k in from..(from + MADDS).min(col) {
            let a = self.sum(at(k, col));
            if let Some(y) = self.sums.get_mut(at(k, N)) {
                *y -= a * x;
            }
        }
        if from + MADDS < col {
            Some(Stage::Substitute {
                col,
                from: from + MADDS,
            })
        } else if col > 0 {
            Some(Stage::Substitute {
                col: col - 1,
                from: 0,
            })
        } else {
            None
        }
    }

    /// The solved harmonics `[s1, c1, s2, c2, ...]`.
    fn harmonics(&self) -> [f32; 2 * HARMONICS] {
        let mut h = [0.0f32; 2 * HARMONICS];
        for (k, v) in h.iter_mut().enumerate() {
            *v = self.sum(at(4 + k, N)) as f32;
        }
        h
    }
}

/// The fit's regressors at `tau` and reading `r`.
fn basis(tau: f32, r: MechanicalAngle) -> [f32; N] {
    let (s1, c1) = crate::trig::sin_cos_bits(r.to_bits());
    let mut row = [0.0f32; N];
    let t2 = tau * tau;
    let (head, harmonics) = row.split_at_mut(4);
    head.copy_from_slice(&[1.0, tau, t2, t2 * tau]);
    let (mut s, mut c) = (s1, c1);
    for pair in harmonics.chunks_exact_mut(2) {
        pair.copy_from_slice(&[s, c]);
        // sin/cos of (k + 1) r from k r.
        let (sn, cn) = (s * c1 + c * s1, c * c1 - s * s1);
        s = sn;
        c = cn;
    }
    row
}

/// Radians per bit of a [`MechanicalAngle`].
const RAD_PER_BIT: f32 = TAU / 4_294_967_296.0;

/// The encoder linearisation routine.
#[derive(Clone, Copy, Debug)]
pub struct EncoderCalibration {
    config: EncoderCalConfig,
    phase: Phase,
    period: u32,
    /// The last reading, and the unwrapped travel since the recording's
    /// start [bits of a turn].
    last: MechanicalAngle,
    travel: i64,
    /// The hold current's sum and count over the settle's last part.
    iq_sum_a: f32,
    iq_n: u32,
    fit: Fit,
    /// The forward direction's harmonics, then both directions' mean.
    harmonics: [f32; 2 * HARMONICS],
    /// The correction's peak over the points computed so far \[rad\].
    peak_rad: f32,
    /// The correction, built in the last periods.
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
            last: MechanicalAngle::ZERO,
            travel: 0,
            iq_sum_a: 0.0,
            iq_n: 0,
            fit: Fit::ZERO,
            harmonics: [0.0; 2 * HARMONICS],
            peak_rad: 0.0,
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
        if matches!(self.finished, Some(CalStep::Done(()))) {
            &self.correction
        } else {
            &AngleCorrection::NONE
        }
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
            self.cap_speed(inp.v_bus_v);
            return Ok(self.velocity(1));
        };
        match self.phase {
            Phase::Settle { dir, since } => {
                self.settle(dir, since, fb.i_dq_a.q, fb.velocity_rad_s, inp.angle)
            }
            Phase::Record { dir, since, iq_a } => {
                self.record(dir, since, iq_a, fb.velocity_rad_s, inp.angle)
            }
            Phase::Solve { dir } => self.solve(dir),
            Phase::Peak { dir, at } => self.peak(dir, at),
            Phase::Fill { dir, at } => Ok(self.fill(dir, at)),
        }
    }

    /// The first period: the speed within the no-load speed's share.
    fn cap_speed(&mut self, v_bus_v: f32) {
        let cap = MAX_SHARE_OF_NO_LOAD * self.config.no_load_rad_s_per_v * v_bus_v;
        if !(cap > 0.0 && cap < self.config.speed_rad_s) {
            return;
        }
        self.config.speed_rad_s = cap;
        let fit = MAX_RECORD_S * cap / TAU;
        if fit < self.config.turns as f32 {
            self.config.turns = (fit as u8).max(3);
        }
        // The bound follows the slower run (at least three turns: below
        // 3.8 rad/s the default's 12 s was too short).
        let longer = 2.0 * self.config.planned_s();
        if longer > self.config.timeout_s {
            self.config.timeout_s = longer;
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
        self.last = reading;
        self.travel = 0;
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
        let step = reading.to_bits().wrapping_sub(self.last.to_bits()) as i32;
        self.travel = self.travel.wrapping_add(i64::from(step));
        self.last = reading;
        let n = self.period.saturating_sub(since);
        if n.is_multiple_of(2) {
            let tau = 2.0 * n as f32 * c.ts_s / c.record_s() - 1.0;
            self.fit.add(tau, reading, self.residual_rad(dir, n));
        } else {
            self.fit.fold_next();
        }
        if self.travel.unsigned_abs() < u64::from(c.turns) << 32 {
            return Ok(CalStep::Torque { iq_a });
        }
        self.fit.stage = Stage::Fold { at: 0 };
        self.phase = Phase::Solve { dir };
        Ok(CalStep::Torque { iq_a })
    }

    /// The travel less the nominal run's, `dir * speed * t`, at the
    /// recording's `n`-th period \[rad\]: what is fitted (the nominal
    /// line only moves the fit's `a` and `b`).
    fn residual_rad(&self, dir: i8, n: u32) -> f32 {
        let c = self.config;
        let per_period = (dir as f32 * c.speed_rad_s * c.ts_s / RAD_PER_BIT) as i32;
        let nominal = i64::from(n) * i64::from(per_period);
        self.travel.wrapping_sub(nominal) as f32 * RAD_PER_BIT
    }

    /// A step of the solve a period; then this direction's harmonics, and
    /// the next direction or the correction.
    fn solve(&mut self, dir: i8) -> Result<CalStep<()>, CalError> {
        let Some(h) = self.fit.solve_step()? else {
            return Ok(self.velocity(dir));
        };
        if dir > 0 {
            self.harmonics = h;
            self.phase = Phase::Settle {
                dir: -1,
                since: self.period,
            };
            return Ok(self.velocity(-1));
        }
        for (v, f) in self.harmonics.iter_mut().zip(h.iter()) {
            *v = 0.5 * (*v + f);
        }
        self.peak_rad = 0.0;
        self.phase = Phase::Peak { dir, at: 0 };
        Ok(self.velocity(dir))
    }

    /// The correction's peak over [`BINS_A_PERIOD`] points; the period
    /// after the last, the correction's scale (a table of zeros written:
    /// a period of its own).
    fn peak(&mut self, dir: i8, at: usize) -> Result<CalStep<()>, CalError> {
        if at >= CORRECTION_BINS {
            self.correction = AngleCorrection::with_peak(self.peak_rad)
                .map_err(|_| CalError::ImplausibleResult)?;
            self.phase = Phase::Fill { dir, at: 0 };
            return Ok(self.velocity(dir));
        }
        for k in at..(at + BINS_A_PERIOD).min(CORRECTION_BINS) {
            let e = error_at(&self.harmonics, k);
            if !e.is_finite() {
                return Err(CalError::ImplausibleResult);
            }
            self.peak_rad = self.peak_rad.max(e.abs());
        }
        self.phase = Phase::Peak {
            dir,
            at: at + BINS_A_PERIOD,
        };
        Ok(self.velocity(dir))
    }

    /// [`BINS_A_PERIOD`] of the correction's points (finite: the peak's
    /// pass saw them); done after the last.
    fn fill(&mut self, dir: i8, at: usize) -> CalStep<()> {
        for k in at..(at + BINS_A_PERIOD).min(CORRECTION_BINS) {
            let _ = self.correction.set_rad(k, error_at(&self.harmonics, k));
        }
        if at + BINS_A_PERIOD < CORRECTION_BINS {
            self.phase = Phase::Fill {
                dir,
                at: at + BINS_A_PERIOD,
            };
            return self.velocity(dir);
        }
        CalStep::Done(())
    }
}

/// The error with harmonics `h` (`[s1, c1, s2, c2, ...]`) at the centre of
/// the correction's point `k` \[rad\].
fn error_at(h: &[f32; 2 * HARMONICS], k: usize) -> f32 {
    // (2k + 1) / (2 CORRECTION_BINS) turns.
    let centre = (2 * k as u32 + 1).wrapping_mul((1 << 31) / CORRECTION_BINS as u32);
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
    e
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

    /// The folded, chunked solve against a plain elimination of the same
    /// sums in `f64`.
    #[test]
    fn solves_as_a_plain_elimination() {
        let mut fit = Fit::ZERO;
        let (mut a, mut b) = ([[0.0f64; N]; N], [0.0f64; N]);
        let mut seed = 12345u32;
        for n in 0..4000u32 {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let tau = n as f32 / 2000.0 - 1.0;
            let r = MechanicalAngle::from_bits(n.wrapping_mul(7_516_193) ^ (seed >> 20));
            let th = r.to_radians();
            let noise = (seed >> 8) as f32 / 16_777_216.0 - 0.5;
            let y = 0.3
                + 0.8 * tau
                + 0.002 * libm::sinf(th)
                + 0.001 * libm::cosf(2.0 * th)
                + 1e-4 * noise;
            fit.add(tau, r, y);
            if n % 2 == 1 {
                fit.fold_next();
            }
            let x = basis(tau, r);
            for i in 0..N {
                for j in 0..N {
                    a[i][j] += x[i] as f64 * x[j] as f64;
                }
                b[i] += x[i] as f64 * y as f64;
            }
        }
        fit.stage = Stage::Fold { at: 0 };
        let mut steps = 0;
        let h = loop {
            steps += 1;
            if let Some(h) = fit.solve_step().unwrap() {
                break h;
            }
        };
        assert_eq!(steps, 161);
        for c in 0..N {
            let pivot = a[c];
            for r in c + 1..N {
                let f = a[r][c] / pivot[c];
                for (v, p) in a[r].iter_mut().zip(pivot).skip(c) {
                    *v -= f * p;
                }
                b[r] -= f * b[c];
            }
        }
        let mut x = [0.0f64; N];
        for i in (0..N).rev() {
            let s: f64 = (i + 1..N).map(|j| a[i][j] * x[j]).sum();
            x[i] = (b[i] - s) / a[i][i];
        }
        for (k, v) in h.iter().enumerate() {
            assert!(
                (*v as f64 - x[4 + k]).abs() < 1e-7,
                "{k}: {v} vs {}",
                x[4 + k]
            );
        }
        assert!(
            (h[0] - 0.002).abs() < 2e-5 && (h[3] - 0.001).abs() < 2e-5,
            "{h:?}"
        );
    }
}
