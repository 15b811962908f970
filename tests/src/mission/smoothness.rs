//! The mission's low-speed smoothness segment (design §32 anticogging,
//! §33 encoder linearisation; issue 38): the motor file's cogging torque,
//! angle-sensor error and dead time, measured before and after the
//! drive learns its two corrections.
//!
//! It runs last, on a **separate simulation of the same setup**: a fresh
//! [`Sim`] whose plant has the file's imperfections
//! ([`Imperfections::apply_plant`]) and whose bench has the file's dead
//! time ([`Imperfections::apply_bench`]), driven by the configuration the
//! mission ended with (its identified calibration, gains and mechanics,
//! its current-sense offsets), the dead-time compensation set from the
//! bench as [`Setup::cascade_config`] sets it (design §31). The mission's
//! own plant and trace are untouched, so every earlier figure is the same
//! with or without this segment; the segment's periods are not in the
//! mission's trace.
//!
//! In order, each figure as `tests/tests/anticogging.rs` and
//! `tests/tests/encoder.rs` measure it:
//!
//! 1. **before**, both corrections off: the sensor's angle error (the
//!    reading against the rotor's true angle, a dyno turning the rotor at
//!    one turn per second, the bridge off, peak to peak over the turn);
//!    the zero-torque ripple (torque mode at 0 A, a dyno turning the rotor
//!    at half an electrical turn per second, the shaft torque peak to peak
//!    over one electrical turn); the speed ripple in velocity mode at 1 %
//!    and 5 % of the no-load speed (the rotor free, the true speed peak to
//!    peak over the whole electrical turns of 1.5 s after 0.5 s, at least
//!    one turn);
//! 2. the **encoder linearisation** (`ConfigChange::calibrate_encoder`),
//!    then the **anticogging calibration** (`calibrate_cogging`, on the
//!    corrected angle: on the magnetic sensors the raw reading is off by
//!    several electrical degrees, a large share of a cogging cycle), then
//!    the encoder linearisation **again**, with the map on: the
//!    linearisation takes every departure from a steady speed for the
//!    sensor's, and the cogging is most of it (on the M153 the first run
//!    learnt twice the sensor's error and left the reading worse than
//!    before; on the cheetah the second run's error is a sixth of the
//!    first's). Each runs through the drive's lifecycle, timed from its
//!    event; before each the rotor is brought back to where the segment
//!    started (position mode: see `return_to_start` for why), after each
//!    to rest; a failure is reported, the fault cleared and the segment
//!    goes on (the second linearisation only after the first two
//!    finished);
//! 3. **after**, both switched on (where both finished): the same figures.
//!
//! 4. **the floor**: the zero-torque ripple once more with the plant's
//!    cogging taken out and the map off (what ripples without any
//!    cogging, which anticogging cannot remove).
//!
//! It passes when both calibrations finish, the zero-torque ripple falls
//! at least [`SMOOTHNESS_RIPPLE_GOAL`] times (or to within
//! [`FLOOR_MARGIN`] of its floor) and the angle error falls or
//! is within two counts of the sensor, with no fault. It is skipped, the
//! reason stated, where the file states neither cogging nor a sensor
//! error, and on a coarse angle sensor (halls: the drive refuses both
//! calibrations, its own rule `AngleCalibration::interpolation_half_count`).
//! Its simulated time is about 50 to 62 s (the calibrations 5 to 7 s, 24 s
//! and 5 to 7 s, design §32, §33); each calibration is given at most
//! twice its planned time plus a second.

use super::markdown::Table;
use super::sensorless::significant;
use super::*;
use crate::real::Real;
use foc_core::calibration::cogging::CoggingCalConfig;
use foc_core::calibration::encoder::EncoderCalConfig;
use foc_core::drive::{ConfigChange, Event};
use std::f64::consts::TAU;

/// The zero-torque ripple must fall at least this many times. Issue 38's
/// goal is ten where cogging dominates; the current ADC's step limits the
/// interior-PM file to about four (design §32), and the dead time's own
/// ripple near zero current (design §31) limits it further where the
/// file's dead time is large.
pub const SMOOTHNESS_RIPPLE_GOAL: f64 = 3.0;

/// A zero-torque ripple within this factor of its floor without the
/// cogging passes even below [`SMOOTHNESS_RIPPLE_GOAL`]: what is left is
/// then not the cogging's. (On the interior-PM file at 540 V the floor is
/// 0.003 N m and the ripple with the map 0.20 N m: there the dead time
/// distorts the map's own small currents, design §32, and it fails.)
pub const FLOOR_MARGIN: f64 = 1.25;

/// The speed-ripple figures' speeds, shares of the no-load speed
/// ([`Setup::max_speed_rad_s`]).
pub const SMOOTHNESS_SPEED_SHARES: [f32; 2] = [0.01, 0.05];

/// The dyno's speed for the zero-torque ripple [electrical turns/s]; the
/// ripple is taken over one electrical turn.
const ZERO_TORQUE_E_TURNS_PER_S: f64 = 0.5;

/// Torque mode at 0 A for this long before the zero-torque window \[s\].
const ZERO_TORQUE_SETTLE_S: f64 = 0.05;

/// The dyno's speed for the angle error [turns/s]; the error is taken
/// over one turn.
const ANGLE_TURNS_PER_S: f64 = 1.0;

/// Velocity mode for this long before a speed-ripple window \[s\].
const SPEED_SETTLE_S: f64 = 0.5;

/// A speed-ripple window: the whole electrical turns within this, at
/// least one \[s\].
const SPEED_WINDOW_S: f64 = 1.5;

/// 0 rad/s commanded for this long after a speed-ripple window \[s\].
const SPEED_STOP_S: f64 = 0.3;

/// The bridge off for this long before the rotor is handed back \[s\].
const RELEASE_S: f64 = 0.01;

/// 0 rad/s commanded for this long after a calibration \[s\].
const REST_S: f64 = 0.5;

/// The return to the segment's start: this long after the trajectory's
/// time \[s\] ...
const RETURN_SETTLE_S: f64 = 0.3;

/// ... and at most this long in all \[s\].
const RETURN_MAX_S: f64 = 2.0;

/// Points of each waveform in `smoothness.svg`.
const WAVE_POINTS: usize = 1000;

/// The segment: its figures, or why it did not run.
#[derive(Clone, Debug, PartialEq)]
pub enum SmoothnessSegment {
    /// It ran (boxed: the figures are ten times the size of a reason).
    Ran(Box<SmoothnessFigures>),
    /// It does not apply to this motor (a coarse angle sensor, or no
    /// imperfection stated).
    Skipped(String),
    /// It could not start (the mission's calibration refused on the
    /// separate simulation).
    Failed(String),
}

/// A calibration's run, from its event.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibrationRun {
    /// Simulated time \[s\].
    pub time_s: f64,
    /// The correction's peak: \[rad\] (mechanical) for the encoder
    /// linearisation, \[A\] (q current) for the anticogging map.
    pub peak: f64,
}

/// A calibration's run, or why it failed (refused, a named failure, not
/// finished in time).
pub type CalibrationOutcome = Result<CalibrationRun, String>;

/// One set of the segment's figures, rotor frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SmoothnessMeasures {
    /// Shaft torque at a zero-torque command, peak to peak over one
    /// electrical turn [N m].
    pub zero_torque_ripple_nm: f64,
    /// True speed peak to peak in velocity mode at
    /// [`SMOOTHNESS_SPEED_SHARES`] of the no-load speed [rad/s].
    pub speed_ripple_rad_s: [f64; 2],
    /// The (corrected) reading against the true angle, peak to peak over a
    /// turn \[rad\].
    pub angle_error_rad: f64,
}

/// The segment's figures.
#[derive(Clone, Debug, PartialEq)]
pub struct SmoothnessFigures {
    /// The imperfections in force, in words.
    pub imperfections: String,
    /// The speeds of the speed-ripple figures [rad/s].
    pub speeds_rad_s: [f64; 2],
    /// One count of the angle sensor \[rad\].
    pub count_rad: f64,
    /// Both corrections off.
    pub before: SmoothnessMeasures,
    /// Both on (None: a calibration did not finish).
    pub after: Option<SmoothnessMeasures>,
    /// The zero-torque ripple of the same drive and plant without the
    /// cogging (the plant's taken out, the map off) [N m]: what ripples
    /// without any cogging, the floor anticogging cannot go below (None:
    /// not measured, a calibration failed).
    pub zero_torque_floor_nm: Option<f64>,
    /// The encoder linearisation on the raw reading, or why it failed.
    pub encoder: CalibrationOutcome,
    /// The anticogging calibration, or why it failed.
    pub cogging: CalibrationOutcome,
    /// The encoder linearisation again, with the map on, or why it failed
    /// (None: not run, an earlier calibration failed).
    pub encoder_again: Option<CalibrationOutcome>,
    /// Faults latched during the segment (names).
    pub faults: Vec<String>,
    /// Simulated time \[s\].
    pub time_s: f64,
    /// Wall time \[s\].
    pub wall_time_s: f64,
}

impl SmoothnessSegment {
    /// What fails ([`SmoothnessFigures::failures`]); nothing when skipped.
    pub fn failures(&self) -> Vec<String> {
        match self {
            Self::Ran(s) => s.failures(),
            Self::Skipped(_) => Vec::new(),
            Self::Failed(why) => vec![format!("low-speed smoothness: {why}")],
        }
    }
}

impl SmoothnessFigures {
    /// Zero-torque ripple before over after (None: not measured after).
    pub fn ripple_ratio(&self) -> Option<f64> {
        self.after
            .map(|a| self.before.zero_torque_ripple_nm / a.zero_torque_ripple_nm)
    }

    /// What fails: a calibration that did not finish, the zero-torque
    /// ripple down less than [`SMOOTHNESS_RIPPLE_GOAL`] times and not
    /// within [`FLOOR_MARGIN`] of its floor without the cogging, the angle
    /// error neither smaller nor within two counts, a fault.
    pub fn failures(&self) -> Vec<String> {
        let mut f = Vec::new();
        for (name, run) in [
            ("encoder linearisation", Some(&self.encoder)),
            ("anticogging calibration", Some(&self.cogging)),
            (
                "encoder linearisation with the map on",
                self.encoder_again.as_ref(),
            ),
        ] {
            if let Some(Err(e)) = run {
                f.push(format!("low-speed smoothness: {name} failed: {e}"));
            }
        }
        if let (Some(a), Some(r)) = (&self.after, self.ripple_ratio()) {
            let at_floor = self
                .zero_torque_floor_nm
                .is_some_and(|fl| a.zero_torque_ripple_nm <= FLOOR_MARGIN * fl);
            if r.is_nan() || (r < SMOOTHNESS_RIPPLE_GOAL && !at_floor) {
                f.push(format!(
                    "low-speed smoothness: zero-torque ripple {:.3e} -> {:.3e} N m, {r:.1}x less (goal {SMOOTHNESS_RIPPLE_GOAL}x)",
                    self.before.zero_torque_ripple_nm, a.zero_torque_ripple_nm
                ));
            }
            let (b, e) = (self.before.angle_error_rad, a.angle_error_rad);
            if !(below(e, b) || e <= 2.0 * self.count_rad) {
                f.push(format!(
                    "low-speed smoothness: angle error {:.3} -> {:.3} mrad, neither smaller nor within two counts",
                    1e3 * b,
                    1e3 * e
                ));
            }
        }
        if !self.faults.is_empty() {
            f.push(format!(
                "low-speed smoothness: faults latched: {}",
                self.faults.join(", ")
            ));
        }
        f
    }
}

/// The imperfections in words.
fn describe(imp: &Imperfections) -> String {
    let cogging = imp.cogging.map_or("no cogging".into(), |c| {
        format!(
            "cogging {} cycles per turn, {} N m, second harmonic {:.2}",
            c.cycles_per_turn,
            significant(c.amplitude_nm as f32),
            c.second_harmonic_share
        )
    });
    let sensor = imp.sensor_error.map_or("no sensor error".into(), |e| {
        format!(
            "sensor error {:.2} / {:.2} mrad once / twice per turn",
            1e3 * e.first_rad as f64,
            1e3 * e.second_rad as f64
        )
    });
    let dead = if imp.dead_time_s > 0.0 {
        format!(
            "dead time {:.0} ns (compensated, design §31)",
            1e9 * imp.dead_time_s as f64
        )
    } else {
        "no dead time".into()
    };
    format!("{cogging}; {sensor}; {dead}")
}

/// A speed-ripple window at `w` [rad/s]: whole electrical turns within
/// [`SPEED_WINDOW_S`], at least one \[s\]; and one electrical turn \[s\].
fn speed_window_s(setup: &Setup, w: f64) -> (f64, f64) {
    let turn_s = TAU / (w * setup.motor.pole_pairs as f64);
    ((SPEED_WINDOW_S / turn_s).floor().max(1.0) * turn_s, turn_s)
}

/// The speeds of the speed-ripple figures [rad/s].
fn ripple_speeds(setup: &Setup) -> [f64; 2] {
    SMOOTHNESS_SPEED_SHARES.map(|s| (s * setup.max_speed_rad_s()) as f64)
}

/// One set of figures' simulated time \[s\].
fn measures_s(setup: &Setup) -> f64 {
    let speeds: f64 = ripple_speeds(setup)
        .iter()
        .map(|&w| SPEED_SETTLE_S + speed_window_s(setup, w).0 + SPEED_STOP_S + RELEASE_S)
        .sum();
    1.0 / ANGLE_TURNS_PER_S
        + ZERO_TORQUE_SETTLE_S
        + 1.0 / ZERO_TORQUE_E_TURNS_PER_S
        + RELEASE_S
        + speeds
}

/// The calibrations' planned times for the drive's defaults \[s\]:
/// (encoder linearisation, anticogging).
fn planned_s(setup: &Setup) -> (f64, f64) {
    let hz = setup.pwm_hz();
    let encoder = EncoderCalConfig::new(hz, setup.max_current_a).planned_s();
    let cogging =
        CoggingCalConfig::new(setup.motor.pole_pairs, hz, setup.max_current_a).planned_s();
    (encoder as f64, cogging as f64)
}

/// The segment's simulated time when it runs, for the progress bar \[s\].
pub(super) fn smoothness_expected_s(setup: &Setup) -> f64 {
    let (e, c) = planned_s(setup);
    2.0 * measures_s(setup) + 2.0 * e + c + 3.0 * (REST_S + RETURN_SETTLE_S)
}

/// `x` wrapped into `[-pi, pi)`.
fn wrap(x: f64) -> f64 {
    (x + TAU / 2.0).rem_euclid(TAU) - TAU / 2.0
}

/// Peak to peak of `v` (0 when empty).
fn p2p(v: &[f64]) -> f64 {
    let max = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let min = v.iter().copied().fold(f64::INFINITY, f64::min);
    if v.is_empty() {
        0.0
    } else {
        max - min
    }
}

/// The first `n` samples of `v`, [`WAVE_POINTS`] of them evenly spaced.
fn resample(v: &[f64], n: usize) -> Vec<f64> {
    let n = n.min(v.len());
    (0..WAVE_POINTS)
        .map(|k| v.get(k * n / WAVE_POINTS).copied().unwrap_or(f64::NAN))
        .collect()
}

/// One set of figures and the waveforms of `smoothness.svg`: the shaft
/// torque and the speed at 1 % over one electrical turn, the angle error
/// \[mrad\] over one turn.
struct Measured {
    figures: SmoothnessMeasures,
    waves: [Vec<f64>; 3],
}

/// The separate simulation the segment runs on, with the mission's
/// progress.
struct SmoothnessBench<'a, 'p> {
    setup: Setup,
    sim: Sim,
    progress: &'a mut Progress<'p>,
    /// The mission's rows plus this simulation's periods so far.
    done: usize,
    /// This simulation's periods so far.
    periods: usize,
    faults: Vec<String>,
    /// The drive's position where the segment started [rad, rotor].
    start_rad: f32,
}

impl SmoothnessBench<'_, '_> {
    fn secs(&self, s: f64) -> usize {
        secs(&self.setup, s)
    }

    fn step(&mut self) {
        self.sim.step();
        self.done += 1;
        self.periods += 1;
        self.progress.tick_at(self.done);
    }

    fn run(&mut self, n: usize) {
        for _ in 0..n {
            self.step();
        }
    }

    /// `n` periods, `f` of each.
    fn record(&mut self, n: usize, f: impl Fn(&Sim) -> f64) -> Vec<f64> {
        let mut v = Vec::with_capacity(n);
        for _ in 0..n {
            self.step();
            v.push(f(&self.sim));
        }
        v
    }

    /// Note the faults latched so far and clear them, so that the segment
    /// goes on.
    fn note_faults(&mut self) {
        let latched: Vec<String> = self
            .sim
            .cascade
            .feedback()
            .faults
            .iter()
            .map(|f| f.name().to_string())
            .collect();
        if latched.is_empty() {
            return;
        }
        for n in latched {
            if !self.faults.contains(&n) {
                self.faults.push(n);
            }
        }
        self.sim.cascade.command(Command::Disable).ok();
        self.sim.cascade.clear_faults();
        self.run(2);
    }

    /// The bridge off, then the rotor back from the dyno.
    fn release(&mut self) {
        self.sim.cascade.command(Command::Disable).ok();
        self.run(self.secs(RELEASE_S));
        self.sim.plant.set_mechanics(Mechanics::Free);
        self.note_faults();
    }

    /// The sensor's angle error over one turn, the dyno turning the rotor,
    /// the bridge off: (peak to peak \[rad\], the error from its first
    /// sample \[rad\]).
    fn angle_error(&mut self) -> (f64, Vec<f64>) {
        self.sim.cascade.command(Command::Disable).ok();
        self.sim
            .plant
            .set_mechanics(Mechanics::ConstantSpeed((TAU * ANGLE_TURNS_PER_S) as Real));
        let n = self.secs(1.0 / ANGLE_TURNS_PER_S);
        let v = self.record(n, |s| {
            let read = s
                .cascade
                .current
                .angle_correction()
                .correct(s.last_sample().angle);
            wrap(read.to_radians() as f64 - s.plant.theta_m_rad() as f64)
        });
        self.sim.plant.set_mechanics(Mechanics::Free);
        let first = v.first().copied().unwrap_or(0.0);
        let v: Vec<f64> = v.iter().map(|x| wrap(x - first)).collect();
        (p2p(&v), v)
    }

    /// Shaft torque at a zero-torque command over one electrical turn, the
    /// dyno turning the rotor: (peak to peak [N m], the torque).
    fn zero_torque_ripple(&mut self) -> (f64, Vec<f64>) {
        let w = ZERO_TORQUE_E_TURNS_PER_S * TAU / self.setup.motor.pole_pairs as f64;
        self.sim
            .plant
            .set_mechanics(Mechanics::ConstantSpeed(w as Real));
        self.sim.cascade.command(Command::Torque { iq_a: 0.0 }).ok();
        self.run(self.secs(ZERO_TORQUE_SETTLE_S));
        let n = self.secs(1.0 / ZERO_TORQUE_E_TURNS_PER_S);
        let v = self.record(n, |s| s.plant.shaft_torque_nm() as f64);
        self.release();
        (p2p(&v), v)
    }

    /// True speed in velocity mode at `w` [rad/s] over the window: (peak
    /// to peak [rad/s], the speed, periods of one electrical turn).
    fn speed_ripple(&mut self, w: f64) -> (f64, Vec<f64>, usize) {
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: w as f32 })
            .ok();
        self.run(self.secs(SPEED_SETTLE_S));
        let (window_s, turn_s) = speed_window_s(&self.setup, w);
        let v = self.record(self.secs(window_s), |s| s.plant.omega_m_rad_s() as f64);
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: 0.0 })
            .ok();
        self.run(self.secs(SPEED_STOP_S));
        self.release();
        (p2p(&v), v, self.secs(turn_s))
    }

    /// The zero-torque ripple without the cogging: the plant's taken out
    /// and the map off for the measurement, both back after.
    fn zero_torque_floor(&mut self) -> f64 {
        let cogging = self.sim.plant.cogging().copied();
        self.sim.plant.set_cogging(None);
        self.sim.cascade.current.set_cogging_enabled(false);
        let (r, _) = self.zero_torque_ripple();
        self.sim.plant.set_cogging(cogging);
        self.sim.cascade.current.set_cogging_enabled(true);
        r
    }

    /// One set of figures with both corrections `on` or off.
    fn measure(&mut self, on: bool) -> Measured {
        self.sim.cascade.current.set_angle_correction_enabled(on);
        self.sim.cascade.current.set_cogging_enabled(on);
        let (angle, angle_wave) = self.angle_error();
        let (torque, torque_wave) = self.zero_torque_ripple();
        let [w1, w5] = ripple_speeds(&self.setup);
        let (s1, speed_wave, turn) = self.speed_ripple(w1);
        let (s5, _, _) = self.speed_ripple(w5);
        let n_torque = torque_wave.len();
        let n_angle = angle_wave.len();
        Measured {
            figures: SmoothnessMeasures {
                zero_torque_ripple_nm: torque,
                speed_ripple_rad_s: [s1, s5],
                angle_error_rad: angle,
            },
            waves: [
                resample(&torque_wave, n_torque),
                resample(&speed_wave, turn),
                resample(&angle_wave, n_angle)
                    .iter()
                    .map(|x| 1e3 * x)
                    .collect(),
            ],
        }
    }

    /// The rotor back to where the segment started (position mode, the
    /// configured trajectory, at most [`RETURN_MAX_S`]), then the bridge
    /// off. The anticogging sweep's impedance reference is a
    /// single-precision position advanced by a few microradians a period:
    /// some hundred radians from zero that step is below the reference's
    /// resolution and the sweep stalls (`RotorStuck` on the M2006 and the
    /// cheetah after the speed-ripple figures), so each calibration
    /// starts near the position the segment started at.
    fn return_to_start(&mut self) {
        let c = self.sim.cascade.config().position;
        let d = (self.sim.cascade.feedback().position_rad - self.start_rad).abs() as f64;
        let (v, a) = (
            c.max_velocity_rad_s.max(1e-3) as f64,
            c.max_acceleration_rad_s2.max(1e-3) as f64,
        );
        let t = (d / v + v / a + RETURN_SETTLE_S).min(RETURN_MAX_S);
        self.sim
            .cascade
            .command(Command::Position {
                rad: self.start_rad,
            })
            .ok();
        self.run(self.secs(t));
        self.sim.cascade.command(Command::Disable).ok();
        self.run(self.secs(RELEASE_S));
        self.note_faults();
    }

    /// Request `change` (one calibration) from where the segment started
    /// and run it to its event, at most `limit_s` \[s\]; then the rotor
    /// brought to rest and the bridge off.
    fn calibrate(&mut self, change: ConfigChange, limit_s: f64) -> CalibrationOutcome {
        self.return_to_start();
        self.sim.cascade.request(change);
        let hz = self.setup.pwm_hz() as f64;
        let mut result = Err(format!("did not finish within {limit_s:.1} s simulated"));
        for _ in 0..self.secs(limit_s) {
            self.step();
            let Some(out) = self.sim.cascade.last_output().copied() else {
                continue;
            };
            if let Some(Err(r)) = out.change {
                result = Err(format!("refused by the drive: {r:?}"));
                break;
            }
            let run = |peak: f32, periods: u32| {
                Ok(CalibrationRun {
                    time_s: periods as f64 / hz,
                    peak: peak as f64,
                })
            };
            result = match out.event {
                Some(Event::EncoderLinearised { peak_rad, periods }) => run(peak_rad, periods),
                Some(Event::CoggingMeasured { peak_a, periods }) => run(peak_a, periods),
                Some(Event::IdentificationFailed(e, st)) => Err(format!("{e:?} in {st:?}")),
                Some(Event::IdentificationAborted(f, st)) => {
                    Err(format!("aborted ({f:?}) in {st:?}"))
                }
                _ => continue,
            };
            break;
        }
        // Stops a run that did not finish; a finished one left the
        // rotor turning.
        self.sim.cascade.command(Command::Disable).ok();
        self.run(2);
        self.note_faults();
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: 0.0 })
            .ok();
        self.run(self.secs(REST_S));
        self.sim.cascade.command(Command::Disable).ok();
        self.run(self.secs(RELEASE_S));
        self.note_faults();
        result
    }
}

impl Mission<'_> {
    /// The low-speed smoothness segment: see the module docs. Returns its
    /// figures and the waveforms of `smoothness.svg` (where it ran).
    pub(super) fn smoothness(&mut self, imp: &Imperfections) -> (SmoothnessSegment, Option<Trace>) {
        let wall = Instant::now();
        let (setup, sim) = match self.separate_sim(imp) {
            Ok(s) => s,
            Err(not_run) => return (not_run, None),
        };
        let done = self.sim.rows();
        let mut bench = SmoothnessBench {
            setup,
            sim,
            progress: &mut self.progress,
            done,
            periods: 0,
            faults: Vec::new(),
            start_rad: 0.0,
        };
        bench.run(2);
        bench.start_rad = bench.sim.cascade.feedback().position_rad;
        let before = bench.measure(false);
        let (encoder, cogging, encoder_again) = bench.calibrations();
        let after = (encoder.is_ok() && cogging.is_ok()).then(|| bench.measure(true));
        let zero_torque_floor_nm = after.as_ref().map(|_| bench.zero_torque_floor());
        let count_rad = TAU / f64::from(bench.setup.bench.sensors.encoder_counts_per_rev.max(1));
        let waves = after.as_ref().map(|a| waves_trace(&before, a));
        let figures = SmoothnessFigures {
            imperfections: describe(imp),
            speeds_rad_s: ripple_speeds(&bench.setup),
            count_rad,
            before: before.figures,
            after: after.map(|a| a.figures),
            zero_torque_floor_nm,
            encoder,
            cogging,
            encoder_again,
            faults: bench.faults,
            time_s: bench.periods as f64 / bench.setup.bench.pwm_frequency_hz as f64,
            wall_time_s: wall.elapsed().as_secs_f64(),
        };
        (SmoothnessSegment::Ran(Box::new(figures)), waves)
    }

    /// The separate simulation: the same setup with the file's dead time
    /// on the bench and its cogging and sensor error in the plant, the
    /// drive as the mission left it (its configuration, calibration and
    /// current-sense offsets), the dead time compensated as
    /// [`Setup::cascade_config`] does it. `Err`: why the segment does not
    /// run.
    fn separate_sim(&self, imp: &Imperfections) -> Result<(Setup, Sim), SmoothnessSegment> {
        if imp.cogging.is_none() && imp.sensor_error.is_none() {
            return Err(SmoothnessSegment::Skipped(
                "the motor file states no cogging torque and no angle-sensor error".into(),
            ));
        }
        let mut setup = self.setup.clone();
        imp.apply_bench(&mut setup.bench);
        let fresh = setup.cascade_config();
        let mut config = *self.sim.cascade.config();
        config.current = *self.sim.cascade.current.config();
        config.current.current.dead_time = fresh.current.current.dead_time;
        config.current.supervisor.model.dead_time_s = fresh.current.supervisor.model.dead_time_s;
        let angle = config.current.angle;
        if angle.interpolation_half_count().is_some() {
            let cpr = angle.sensor_counts_per_rev;
            return Err(SmoothnessSegment::Skipped(format!(
                "a coarse angle sensor ({cpr} counts per turn, {} per electrical turn: halls, interpolated between their edges): the drive refuses the encoder linearisation and the anticogging calibration (design §32, §33)",
                cpr / u32::from(angle.pole_pairs.max(1))
            )));
        }
        let permit = Calibrated::supplied(angle, config.current.current).map_err(|e| {
            SmoothnessSegment::Failed(format!(
                "the mission's calibration is refused on the separate simulation: {e:?}"
            ))
        })?;
        let mut plant = Plant::new(setup.motor, setup.bench);
        imp.apply_plant(&mut plant);
        let mut sim = Sim::with_plant(&setup, plant, config, false);
        if let Some(o) = self.sim.current_offsets() {
            sim.set_current_offsets(o);
        }
        sim.cascade.set_calibration(&permit);
        Ok((setup, sim))
    }
}

impl SmoothnessBench<'_, '_> {
    /// The encoder linearisation, the anticogging calibration, and (where
    /// both finished) the linearisation again with the map on; each given
    /// twice its planned time plus a second.
    fn calibrations(
        &mut self,
    ) -> (
        CalibrationOutcome,
        CalibrationOutcome,
        Option<CalibrationOutcome>,
    ) {
        let (e, c) = planned_s(&self.setup);
        let linearise = ConfigChange {
            calibrate_encoder: true,
            ..ConfigChange::default()
        };
        let encoder = self.calibrate(linearise, 2.0 * e + 1.0);
        self.sim
            .cascade
            .current
            .set_angle_correction_enabled(encoder.is_ok());
        let anticogging = ConfigChange {
            calibrate_cogging: true,
            ..ConfigChange::default()
        };
        let cogging = self.calibrate(anticogging, 2.0 * c + 1.0);
        let again = (encoder.is_ok() && cogging.is_ok()).then(|| {
            self.sim.cascade.current.set_cogging_enabled(true);
            self.calibrate(linearise, 2.0 * e + 1.0)
        });
        (encoder, cogging, again)
    }
}

/// The waveforms' columns, before and after, in [`Measured::waves`]'s order.
const WAVE_COLUMNS: [[&str; 2]; 3] = [
    ["shaft_torque_before_nm", "shaft_torque_after_nm"],
    ["speed_1pc_before_rad_s", "speed_1pc_after_rad_s"],
    ["angle_error_before_mrad", "angle_error_after_mrad"],
];

/// The waveforms against the share of their turn (0 to 1).
fn waves_trace(before: &Measured, after: &Measured) -> Trace {
    let names: Vec<&str> = WAVE_COLUMNS.iter().flatten().copied().collect();
    let mut t = Trace::new(&names);
    for k in 0..WAVE_POINTS {
        let row: Vec<f64> = before
            .waves
            .iter()
            .zip(&after.waves)
            .flat_map(|(b, a)| [b[k], a[k]])
            .collect();
        t.push(k as f64 / WAVE_POINTS as f64, &row);
    }
    t
}

impl MissionResult {
    /// `smoothness.svg`: the low-speed smoothness segment's waveforms,
    /// before and after (where both calibrations finished).
    pub(super) fn write_smoothness(
        &self,
        dir: &Path,
        out: &mut Vec<std::path::PathBuf>,
    ) -> std::io::Result<()> {
        let (Some(t), Some(SmoothnessSegment::Ran(s))) =
            (&self.smoothness_trace, &self.summary.smoothness)
        else {
            return Ok(());
        };
        let p = dir.join("smoothness.svg");
        crate::report::plot_svg_against(
            &p,
            &format!(
                "Low-speed smoothness: {} (before: corrections off; after: encoder linearisation and anticogging on; {:.1}x less zero-torque ripple)",
                self.summary.motor,
                s.ripple_ratio().unwrap_or(f64::NAN)
            ),
            t,
            &[
                Panel::new(
                    "shaft torque at 0 A (one electrical turn, dyno)",
                    "N m",
                    &WAVE_COLUMNS[0],
                ),
                Panel::new(
                    "speed at 1 % of no-load (one electrical turn)",
                    "rad/s",
                    &WAVE_COLUMNS[1],
                ),
                Panel::new(
                    "angle error of the reading (one turn, dyno)",
                    "mrad",
                    &WAVE_COLUMNS[2],
                ),
            ],
            "share of the turn",
        )?;
        out.push(p);
        Ok(())
    }
}

impl MissionSummary {
    /// The low-speed smoothness segment's rows (design §32, §33).
    pub(super) fn smoothness_rows(&self, t: &mut Table) {
        const NAME: &str = "low-speed smoothness (design §32, §33)";
        let s = match &self.smoothness {
            None => return,
            Some(SmoothnessSegment::Skipped(why)) => {
                t.row(NAME, format!("skipped: {why}"));
                return;
            }
            Some(SmoothnessSegment::Failed(why)) => {
                t.row(NAME, format!("FAILED: {why}"));
                return;
            }
            Some(SmoothnessSegment::Ran(s)) => s,
        };
        t.row(
            NAME,
            format!(
                "the motor file's imperfections ({}) on a separate simulation of the same setup, the mission's calibration: before (both corrections off), the encoder linearisation, the anticogging calibration and the encoder linearisation again with the map on, through the drive's lifecycle, after (both on): {:.1} s simulated ({:.2} s wall)",
                s.imperfections, s.time_s, s.wall_time_s
            ),
        );
        let run = |r: &CalibrationOutcome, peak: &dyn Fn(f64) -> String| match r {
            Ok(r) => format!("{:.1} s simulated, {}", r.time_s, peak(r.peak)),
            Err(e) => format!("FAILED: {e}"),
        };
        let mrad = |p: f64| format!("correction peak {:.3} mrad", 1e3 * p);
        t.row(
            "low-speed smoothness: encoder linearisation",
            run(&s.encoder, &mrad),
        );
        t.row(
            "low-speed smoothness: anticogging calibration",
            run(&s.cogging, &|p| {
                format!("map peak {} A", significant(p as f32))
            }),
        );
        if let Some(r) = &s.encoder_again {
            t.row(
                "low-speed smoothness: encoder linearisation again, the map on",
                run(r, &mrad),
            );
        }
        let a = s.after.as_ref();
        let b = &s.before;
        let pair = |before: f64, after: Option<f64>, unit: &str| match after {
            Some(x) => format!(
                "{} -> {} {unit} ({})",
                significant(before as f32),
                significant(x as f32),
                ratio(before, x)
            ),
            None => format!(
                "{} {unit} -> not measured (a calibration failed)",
                significant(before as f32)
            ),
        };
        t.row(
            "low-speed smoothness: zero-torque shaft-torque ripple p-p, before -> after",
            format!(
                "{}; goal {SMOOTHNESS_RIPPLE_GOAL}x",
                pair(
                    b.zero_torque_ripple_nm,
                    a.map(|a| a.zero_torque_ripple_nm),
                    "N m"
                )
            ),
        );
        if let Some(fl) = s.zero_torque_floor_nm {
            t.row(
                "low-speed smoothness: zero-torque ripple without the cogging (its floor)",
                format!(
                    "{} N m (the plant's cogging out, the map off)",
                    significant(fl as f32)
                ),
            );
        }
        for (k, pc) in ["1 %", "5 %"].iter().enumerate() {
            t.row(
                &format!("low-speed smoothness: speed ripple p-p at {pc} of the no-load speed, before -> after"),
                format!(
                    "at {} rad/s: {}",
                    significant(s.speeds_rad_s[k] as f32),
                    pair(
                        b.speed_ripple_rad_s[k],
                        a.map(|a| a.speed_ripple_rad_s[k]),
                        "rad/s"
                    )
                ),
            );
        }
        t.row(
            "low-speed smoothness: angle error p-p of the sensor's reading, before -> after",
            format!(
                "{}; {:.2}{} counts (two counts {:.3} mrad)",
                pair(
                    1e3 * b.angle_error_rad,
                    a.map(|a| 1e3 * a.angle_error_rad),
                    "mrad"
                ),
                b.angle_error_rad / s.count_rad,
                a.map_or(String::new(), |a| format!(
                    " -> {:.2}",
                    a.angle_error_rad / s.count_rad
                )),
                2e3 * s.count_rad
            ),
        );
        t.row(
            "low-speed smoothness: faults",
            if s.faults.is_empty() {
                "none".into()
            } else {
                s.faults.join(", ")
            },
        );
    }
}

/// `before / after` in words: "11.1x less" or "1.2x more".
fn ratio(before: f64, after: f64) -> String {
    let r = before / after;
    if r >= 1.0 {
        format!("{r:.1}x less")
    } else {
        format!("{:.1}x more", 1.0 / r)
    }
}

/// The sensorless mission's statement: the segment does not run there.
pub const SMOOTHNESS_SENSORLESS: &str = "Low-speed smoothness (design §32, §33): skipped: the sensorless mission has no angle sensor (nothing to linearise, and the segment's figures are the sensor's and the cogging's against it); `cargo xtask sim` runs it.";

#[cfg(test)]
mod tests {
    use super::*;

    fn figures(zero_after_nm: f64, angle_after_rad: f64) -> SmoothnessFigures {
        let m = |zero, angle| SmoothnessMeasures {
            zero_torque_ripple_nm: zero,
            speed_ripple_rad_s: [0.5, 0.2],
            angle_error_rad: angle,
        };
        SmoothnessFigures {
            imperfections: String::new(),
            speeds_rad_s: [0.3, 1.5],
            count_rad: 1e-3,
            before: m(1.0, 10e-3),
            after: Some(m(zero_after_nm, angle_after_rad)),
            zero_torque_floor_nm: Some(0.01),
            encoder: Ok(CalibrationRun {
                time_s: 6.0,
                peak: 5e-3,
            }),
            cogging: Ok(CalibrationRun {
                time_s: 24.0,
                peak: 0.9,
            }),
            encoder_again: Some(Ok(CalibrationRun {
                time_s: 6.0,
                peak: 5e-3,
            })),
            faults: Vec::new(),
            time_s: 50.0,
            wall_time_s: 10.0,
        }
    }

    #[test]
    fn passes_on_three_times_less_ripple_and_a_smaller_or_two_count_angle_error() {
        assert!(figures(1.0 / 3.0, 9e-3).failures().is_empty());
        // The angle error larger, but within two counts.
        let mut f = figures(0.1, 2e-3);
        f.before.angle_error_rad = 1.5e-3;
        assert!(f.failures().is_empty());
    }

    #[test]
    fn fails_on_too_little_ripple_reduction_a_larger_angle_error_or_nan() {
        assert_eq!(figures(0.34, 9e-3).failures().len(), 1);
        assert_eq!(figures(0.1, 11e-3).failures().len(), 1);
        assert_eq!(figures(f64::NAN, f64::NAN).failures().len(), 2);
    }

    #[test]
    fn at_its_floor_without_the_cogging_passes() {
        let mut f = figures(0.8, 9e-3);
        assert_eq!(f.failures().len(), 1);
        f.zero_torque_floor_nm = Some(0.7);
        assert!(f.failures().is_empty(), "{:?}", f.failures());
        f.zero_torque_floor_nm = Some(0.6);
        assert_eq!(f.failures().len(), 1);
    }

    #[test]
    fn a_failed_calibration_or_a_fault_fails() {
        let mut f = figures(0.1, 1e-3);
        f.cogging = Err("RotorStuck in Cogging".into());
        f.encoder_again = None;
        f.after = None;
        f.faults.push("calibration failed".into());
        let fails = SmoothnessSegment::Ran(Box::new(f)).failures();
        assert_eq!(fails.len(), 2, "{fails:?}");
        assert!(fails[0].contains("anticogging calibration failed: RotorStuck"));
        assert!(SmoothnessSegment::Skipped("halls".into())
            .failures()
            .is_empty());
        assert_eq!(SmoothnessSegment::Failed("x".into()).failures().len(), 1);
    }

    #[test]
    fn speed_windows_are_whole_electrical_turns() {
        let setup = Setup::load(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/motors/m153-source.toml"
        ))
        .unwrap();
        // 4 pole pairs: an electrical turn at 1 rad/s is pi/2 s.
        let (window, turn) = speed_window_s(&setup, 1.0);
        assert!((turn - TAU / 4.0).abs() < 1e-12);
        assert!((window - turn).abs() < 1e-12, "one turn, longer than 1.5 s");
        let (window, turn) = speed_window_s(&setup, 10.0);
        assert!((window - 9.0 * turn).abs() < 1e-9, "{window} {turn}");
    }

    #[test]
    fn helpers() {
        assert_eq!(p2p(&[]), 0.0);
        assert_eq!(p2p(&[1.0, -2.0, 0.5]), 3.0);
        assert!((wrap(TAU + 0.1) - 0.1).abs() < 1e-12);
        let v: Vec<f64> = (0..10).map(f64::from).collect();
        let r = resample(&v, 5);
        assert_eq!(r.len(), WAVE_POINTS);
        assert_eq!((r[0], r[WAVE_POINTS - 1]), (0.0, 4.0));
        assert_eq!(ratio(2.0, 1.0), "2.0x less");
        assert_eq!(ratio(1.0, 2.0), "2.0x more");
    }
}
