//! The anticogging calibration: the cogging map
//! ([`crate::control::cogging::CoggingMap`]) measured by a
//! slow constant-speed sweep in both directions (design §32).
//!
//! At a constant speed the rotor does not accelerate, so the q current the
//! speed loop holds balances every torque on the rotor:
//!
//! ```text
//! kt iq(theta) = Fc sgn(w) + B w + T_load - T_cog(theta)
//! ```
//!
//! Averaged per point of the electrical turn over several turns, and then
//! over the two directions at the same speed, the friction terms cancel;
//! the mean over the turn (a constant load; the cogging's mean is zero by
//! definition) is removed. What is left is `-T_cog / kt`: the map.
//!
//! The speed loop does not hold the speed perfectly: the rest of the
//! cogging accelerates the rotor a little, `J dw/dt`, which the measured
//! current does not contain. The sweep is therefore slow (the cogging's
//! frequency well inside the speed loop's bandwidth), and runs in
//! `passes`: each later pass runs with the previous pass's map applied
//! (the stage's feed-forward), so the speed loop has only the remainder to
//! reject and the speed is steadier; the measured current is the total
//! again, so each pass replaces the map.
//!
//! **Experiment**, per pass: forward at `sweep_e_rad_s` (settle, then record
//! `turns` electrical turns), backward the same; then the map. Bounded:
//! the current vector within `max_current_a` ([`CalError::OverCurrent`]),
//! the whole calibration within `timeout_s` ([`CalError::Timeout`]).
//! Named failures: the rotor does not turn ([`CalError::RotorStuck`]), it
//! turns but not at the sweep speed ([`CalError::SpeedNotReached`]), a
//! point of the turn never seen ([`CalError::SensorNoMotion`]), a map
//! beyond `max_map_share` of the current limit
//! ([`CalError::ImplausibleResult`]: a load or a fault, not cogging).
//! The rotor must turn freely (no load that changes with the angle).
//!
//! **Work per period.** The routine is stepped in the current loop's
//! interrupt, once per PWM period (50 us at 20 kHz, of which the drive
//! takes about a third). Recording adds one sample to one point. The
//! arithmetic at the end of a direction, its *fold*, would be a loop over
//! the whole map (done in one period, the end of a pass took about 47 500
//! instructions under QEMU: several periods' worth), so it is spread over
//! periods, 32 points a period (`BINS_PER_PERIOD`: 16 periods per sweep
//! of the map, under a millisecond at 20 kHz):
//!
//! - after the forward direction, one sweep (16 periods): its mean per
//!   point, in counts, into `forward`;
//! - after the backward direction, three sweeps (48 periods): the two
//!   directions averaged (and summed, for the turn's mean); the mean taken
//!   off (and the peak found, which sets the scale); quantised to the peak
//!   into `forward`, whose table then becomes the pass's map in one 1 KB
//!   copy. [`CoggingCalibration::map`] and
//!   [`CoggingCalibration::passes_done`] change only then (the driver
//!   installs the map when the passes grow), and the map is the one the
//!   computation in one go gives.
//!
//! A point's sum and count are cleared as the fold takes them (no 3 KB
//! clear in one period). The fold runs while the sweep settles in the next
//! direction (1 s by default), and recording, which reuses the tables,
//! waits for it even with no settling time; after the last pass the sweep
//! goes on for the fold's 48 periods before the routine reports done. A
//! failure a fold finds (a point never seen, a value not finite, a map too
//! large) fails the calibration as it did in one go.

use super::common::{check_input, latch, CalError, CalInput, CalStep};
use crate::angle::ElectricalAngle;
use crate::control::cogging::{bin_of, count_of, scale_for_peak, CoggingMap, COGGING_BINS};
use core::f32::consts::TAU;
use core::ops::Range;

/// Points of the map a fold takes per period: a sixteenth of the map
/// (see the module docs).
const BINS_PER_PERIOD: usize = 32;

/// Longest time the rotor may stay off the sweep speed while recording \[s\].
const OFF_SPEED_S: f32 = 0.5;

/// The pull towards the sweep's angle \[1/s\]: the lag closes with a
/// 0.3 s time constant.
const POSITION_GAIN_PER_S: f32 = 3.0;

/// Largest lead of the sweep's angle over the rotor's \[rad\] (electrical).
const MAX_LEAD_RAD: f32 = 1.0;

/// Settings of the anticogging calibration.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CoggingCalConfig {
    /// Pole pairs (the velocity requests are mechanical).
    pub pole_pairs: u8,
    /// Control period \[s\].
    pub ts_s: f32,
    /// Sweep speed, electrical [rad/s] (> 0).
    pub sweep_e_rad_s: f32,
    /// Electrical turns recorded per direction and pass (>= 1).
    pub turns: u8,
    /// Time to settle at the sweep speed before recording \[s\].
    pub settle_s: f32,
    /// Passes (>= 1); from the second on, the previous map is applied.
    pub passes: u8,
    /// Current-vector bound \[A\].
    pub max_current_a: f32,
    /// Largest map peak, as a share of `max_current_a`.
    pub max_map_share: f32,
    /// Bound on the whole calibration \[s\].
    pub timeout_s: f32,
}

impl CoggingCalConfig {
    /// Defaults: a fifth of an electrical turn per second (the cogging's
    /// 6 to 18 cycles per electrical turn at 1.2 to 3.6 Hz, well inside
    /// the speed loop's bandwidth: at one turn per second the DJI M2006
    /// stuck and slipped from tooth to tooth), one turn recorded per
    /// direction after 1 s of settling, 2 passes (24 s in all), a map of
    /// at most half the current bound, and a timeout of twice the planned
    /// time.
    pub fn new(pole_pairs: u8, pwm_frequency_hz: f32, max_current_a: f32) -> Self {
        let mut c = Self {
            pole_pairs,
            ts_s: 1.0 / pwm_frequency_hz,
            sweep_e_rad_s: 0.2 * TAU,
            turns: 1,
            settle_s: 1.0,
            passes: 2,
            max_current_a,
            max_map_share: 0.5,
            timeout_s: 0.0,
        };
        c.timeout_s = 2.0 * c.planned_s();
        c
    }

    /// The calibration's duration when every direction settles at once \[s\].
    pub fn planned_s(&self) -> f32 {
        let per_direction = self.settle_s + self.turns as f32 * TAU / self.sweep_e_rad_s;
        2.0 * self.passes as f32 * per_direction
    }

    fn check(&self) -> Result<(), CalError> {
        let pos = |x: f32| x.is_finite() && x > 0.0;
        let ok = self.pole_pairs > 0
            && pos(self.ts_s)
            && pos(self.sweep_e_rad_s)
            && self.turns > 0
            && self.settle_s.is_finite()
            && self.settle_s >= 0.0
            && self.passes > 0
            && pos(self.max_current_a)
            && pos(self.max_map_share)
            && pos(self.timeout_s);
        if ok {
            Ok(())
        } else {
            Err(CalError::InvalidConfig)
        }
    }

    /// The sweep's mechanical speed [rad/s] in direction `dir` (+-1).
    fn mech_rad_s(&self, dir: f32) -> f32 {
        dir * self.sweep_e_rad_s / self.pole_pairs as f32
    }
}

/// Where the sweep is.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    /// Reaching the sweep speed in `dir` since period `since`.
    Settle { dir: i8, since: u32 },
    /// Recording in `dir`; `travelled_rad` electrical so far.
    Record { dir: i8, travelled_rad: f32 },
    /// The last pass recorded, its fold running on while the sweep goes
    /// on in `dir`.
    Finish { dir: i8 },
}

impl Phase {
    fn dir(self) -> i8 {
        match self {
            Self::Settle { dir, .. } | Self::Record { dir, .. } | Self::Finish { dir } => dir,
        }
    }
}

/// A fold's stage: what is done to each point (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Stage {
    /// The forward direction's means into `forward`.
    Keep,
    /// The two directions averaged into `sum_a`; `total` their sum so far.
    Average { total: f32 },
    /// The turn's `mean` taken off; `peak_a` the largest magnitude so far.
    Centre { mean: f32, peak_a: f32 },
    /// Counts of `scale_a` into `forward`; `top` the largest so far.
    Quantise { scale_a: f32, top: u32 },
}

/// A fold under way: its stage, and the next point it takes.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Fold {
    stage: Stage,
    next_k: usize,
}

impl Fold {
    const fn start(stage: Stage) -> Self {
        Self { stage, next_k: 0 }
    }
}

/// The anticogging calibration routine.
#[derive(Clone, Copy, Debug)]
pub struct CoggingCalibration {
    config: CoggingCalConfig,
    phase: Phase,
    period: u32,
    passes_done: u8,
    last_theta: Option<ElectricalAngle>,
    /// How far the sweep's angle is ahead of the rotor's \[rad\]
    /// (electrical).
    lead_rad: f32,
    /// Consecutive recording periods off the sweep speed.
    off_speed_periods: u32,
    /// The fold under way, a chunk per period.
    fold: Option<Fold>,
    /// This direction's sum of q current per point \[A\] (during a pass's
    /// fold: the two directions' average).
    sum_a: [f32; COGGING_BINS],
    /// Samples per point this direction.
    count: [u16; COGGING_BINS],
    /// The forward direction's mean per point, in counts of
    /// `forward_scale_a` (at the end of a pass's fold: the new map's
    /// table).
    forward: [i16; COGGING_BINS],
    forward_scale_a: f32,
    /// The map of the last finished pass.
    map: CoggingMap,
    finished: Option<CalStep<()>>,
}

impl CoggingCalibration {
    /// A new calibration (the config is checked at the first step).
    pub fn new(config: CoggingCalConfig) -> Self {
        Self {
            config,
            phase: Phase::Settle { dir: 1, since: 0 },
            period: 0,
            passes_done: 0,
            last_theta: None,
            off_speed_periods: 0,
            lead_rad: 0.0,
            fold: None,
            sum_a: [0.0; COGGING_BINS],
            count: [0; COGGING_BINS],
            forward: [0; COGGING_BINS],
            forward_scale_a: config.max_current_a / 32767.0,
            map: CoggingMap::EMPTY,
            finished: None,
        }
    }

    /// Its settings.
    pub fn config(&self) -> &CoggingCalConfig {
        &self.config
    }

    /// Passes finished; from the first on, [`Self::map`] is the last
    /// pass's map (the driver applies it for the next pass).
    pub fn passes_done(&self) -> u8 {
        self.passes_done
    }

    /// The map of the last finished pass ([`CoggingMap::EMPTY`] before).
    pub fn map(&self) -> &CoggingMap {
        &self.map
    }

    /// Periods stepped so far.
    pub fn elapsed_periods(&self) -> u32 {
        self.period
    }

    /// One period: `inp.closed_loop` must carry the velocity mode's
    /// feedback (with its electrical angle) from the second period on.
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
            // The first period: ask for the sweep.
            return Ok(self.sweep(1));
        };
        self.track(self.phase.dir(), fb.theta_e);
        let folded = self.fold_chunk()?;
        let step = match self.phase {
            Phase::Settle { dir, since } => self.settle(dir, since, folded, fb.velocity_rad_s)?,
            Phase::Record { dir, travelled_rad } => self.record(
                dir,
                travelled_rad,
                fb.theta_e,
                fb.i_dq_a.q,
                fb.velocity_rad_s,
            )?,
            Phase::Finish { .. } if folded => CalStep::Done(()),
            Phase::Finish { dir } => self.sweep(dir),
        };
        self.last_theta = Some(fb.theta_e);
        Ok(step)
    }

    /// The velocity request: the sweep speed plus a pull towards the
    /// sweep's angle (a rotor held in a cogging well by a velocity loop
    /// whose error cannot exceed the small sweep speed builds its torque
    /// slowly and then slips from tooth to tooth; with the angle's lag
    /// added the request grows while it is held), never backwards and at
    /// most four times the sweep speed.
    fn sweep(&self, dir: i8) -> CalStep<()> {
        let w = self.config.sweep_e_rad_s;
        let e = (w + POSITION_GAIN_PER_S * self.lead_rad).clamp(0.0, 4.0 * w);
        CalStep::Velocity {
            rad_s: dir as f32 * e / self.config.pole_pairs as f32,
        }
    }

    /// The sweep's angle runs on by a period; the rotor's advance in the
    /// sweep's direction is taken off the lead.
    fn track(&mut self, dir: i8, theta_e: ElectricalAngle) {
        let moved = self.last_theta.map_or(0.0, |l| theta_e.diff_radians(l));
        let lead =
            self.lead_rad + self.config.sweep_e_rad_s * self.config.ts_s - moved * dir as f32;
        // Bounded: a rotor held for long does not store a lunge.
        self.lead_rad = lead.clamp(-MAX_LEAD_RAD, MAX_LEAD_RAD);
    }

    /// Settling: recording starts after `settle_s` at speed, once the
    /// last direction's fold is `folded` (the recording reuses its
    /// tables); a rotor that is not at speed after four times that fails.
    fn settle(
        &mut self,
        dir: i8,
        since: u32,
        folded: bool,
        w_rad_s: f32,
    ) -> Result<CalStep<()>, CalError> {
        let target = self.config.mech_rad_s(dir as f32);
        let settled_s = self.period.saturating_sub(since) as f32 * self.config.ts_s;
        let at_speed = (w_rad_s - target).abs() < 0.5 * target.abs();
        if settled_s >= self.config.settle_s && at_speed && folded {
            // The fold left `sum_a` and `count` cleared.
            self.phase = Phase::Record {
                dir,
                travelled_rad: 0.0,
            };
        } else if settled_s > 4.0 * self.config.settle_s.max(0.25) {
            return Err(slow_rotor(w_rad_s, target));
        }
        Ok(self.sweep(dir))
    }

    fn record(
        &mut self,
        dir: i8,
        travelled_rad: f32,
        theta_e: ElectricalAngle,
        iq_a: f32,
        w_rad_s: f32,
    ) -> Result<CalStep<()>, CalError> {
        let target = self.config.mech_rad_s(dir as f32);
        // Off the speed for a moment (a tooth's pull) is what the sweep
        // measures; off it for half a second is a rotor that cannot follow.
        if (w_rad_s - target).abs() > 0.9 * target.abs() {
            self.off_speed_periods = self.off_speed_periods.saturating_add(1);
            if self.off_speed_periods as f32 * self.config.ts_s > OFF_SPEED_S {
                return Err(slow_rotor(w_rad_s, target));
            }
        } else {
            self.off_speed_periods = 0;
        }
        let k = bin_of(theta_e);
        if let (Some(s), Some(n)) = (self.sum_a.get_mut(k), self.count.get_mut(k)) {
            if *n < u16::MAX {
                *s += iq_a;
                *n += 1;
            }
        }
        let moved = self.last_theta.map_or(0.0, |l| theta_e.diff_radians(l));
        let travelled_rad = travelled_rad + moved * dir as f32;
        if travelled_rad < self.config.turns as f32 * TAU {
            self.phase = Phase::Record { dir, travelled_rad };
            return Ok(self.sweep(dir));
        }
        Ok(self.end_direction(dir))
    }

    /// A direction recorded: its fold starts (from the next period), and
    /// the sweep turns round, or (after the last pass) goes on until the
    /// fold has finished.
    fn end_direction(&mut self, dir: i8) -> CalStep<()> {
        let stage = if dir > 0 {
            Stage::Keep
        } else {
            Stage::Average { total: 0.0 }
        };
        self.fold = Some(Fold::start(stage));
        if dir < 0 && self.passes_done.saturating_add(1) >= self.config.passes {
            self.phase = Phase::Finish { dir };
            return self.sweep(dir);
        }
        self.lead_rad = 0.0;
        self.phase = Phase::Settle {
            dir: -dir,
            since: self.period,
        };
        self.sweep(-dir)
    }

    /// This period's chunk of the fold under way: at most
    /// [`BINS_PER_PERIOD`] points. True when no fold is left after it.
    fn fold_chunk(&mut self) -> Result<bool, CalError> {
        let Some(Fold { stage, next_k }) = self.fold else {
            return Ok(true);
        };
        let end = (next_k + BINS_PER_PERIOD).min(COGGING_BINS);
        let stage = self.fold_points(stage, next_k..end)?;
        self.fold = if end < COGGING_BINS {
            Some(Fold { stage, next_k: end })
        } else {
            self.next_stage(stage)?.map(Fold::start)
        };
        Ok(self.fold.is_none())
    }

    /// `stage` applied to points `ks`; the stage with its running figures.
    fn fold_points(&mut self, stage: Stage, ks: Range<usize>) -> Result<Stage, CalError> {
        Ok(match stage {
            Stage::Keep => {
                for k in ks {
                    self.keep_point(k)?;
                }
                stage
            }
            Stage::Average { mut total } => {
                for k in ks {
                    total += self.average_point(k)?;
                }
                Stage::Average { total }
            }
            Stage::Centre { mean, mut peak_a } => {
                for k in ks {
                    peak_a = peak_a.max(self.centre_point(k, mean)?);
                }
                Stage::Centre { mean, peak_a }
            }
            Stage::Quantise { scale_a, mut top } => {
                for k in ks {
                    top = top.max(self.quantise_point(k, scale_a));
                }
                Stage::Quantise { scale_a, top }
            }
        })
    }

    /// The stage after `done` (all its points taken), or `None` at the
    /// fold's end (a pass's map published).
    fn next_stage(&mut self, done: Stage) -> Result<Option<Stage>, CalError> {
        Ok(match done {
            Stage::Keep => None,
            Stage::Average { total } => Some(Stage::Centre {
                mean: total / COGGING_BINS as f32,
                peak_a: 0.0,
            }),
            Stage::Centre { peak_a, .. } => Some(Stage::Quantise {
                scale_a: scale_for_peak(peak_a),
                top: 0,
            }),
            Stage::Quantise { scale_a, top } => {
                self.publish(scale_a, top)?;
                None
            }
        })
    }

    /// This direction's mean q current at point `k` \[A\], its sum and
    /// count cleared for the next recording; a point never seen fails.
    fn take_mean(&mut self, k: usize) -> Result<f32, CalError> {
        match (self.sum_a.get_mut(k), self.count.get_mut(k)) {
            (Some(s), Some(n)) if *n > 0 => {
                let mean = *s / *n as f32;
                *s = 0.0;
                *n = 0;
                Ok(mean)
            }
            _ => Err(CalError::SensorNoMotion),
        }
    }

    /// The forward direction's mean at point `k`, kept while the backward
    /// one runs.
    fn keep_point(&mut self, k: usize) -> Result<(), CalError> {
        let c = libm::roundf(self.take_mean(k)? / self.forward_scale_a).clamp(-32767.0, 32767.0);
        if let Some(f) = self.forward.get_mut(k) {
            *f = c as i16;
        }
        Ok(())
    }

    /// The two directions' average at point `k` \[A\], in place of the
    /// backward direction's sum (no second table).
    fn average_point(&mut self, k: usize) -> Result<f32, CalError> {
        let fwd = self.forward.get(k).copied().unwrap_or(0) as f32 * self.forward_scale_a;
        let both = 0.5 * (fwd + self.take_mean(k)?);
        if let Some(s) = self.sum_a.get_mut(k) {
            *s = both;
        }
        Ok(both)
    }

    /// Point `k` less the turn's `mean`: its magnitude \[A\]; not finite
    /// fails.
    fn centre_point(&mut self, k: usize, mean: f32) -> Result<f32, CalError> {
        let Some(s) = self.sum_a.get_mut(k) else {
            return Ok(0.0);
        };
        *s -= mean;
        if s.is_finite() {
            Ok(s.abs())
        } else {
            Err(CalError::InvalidInput)
        }
    }

    /// Point `k` in counts of `scale_a` into `forward` (as
    /// [`CoggingMap::from_amps`] quantises), its sum cleared; the count's
    /// magnitude.
    fn quantise_point(&mut self, k: usize, scale_a: f32) -> u32 {
        let Some(s) = self.sum_a.get_mut(k) else {
            return 0;
        };
        let c = if scale_a > 0.0 {
            count_of(*s, scale_a)
        } else {
            0
        };
        *s = 0.0;
        if let Some(f) = self.forward.get_mut(k) {
            *f = c;
        }
        (c as i32).unsigned_abs()
    }

    /// The pass's map, quantised into `forward` with `scale_a` and
    /// largest count `top`, checked and made the calibration's map.
    fn publish(&mut self, scale_a: f32, top: u32) -> Result<(), CalError> {
        // What `CoggingMap::peak_a` gives for it.
        let peak_a = top as f32 * scale_a;
        if peak_a > self.config.max_map_share * self.config.max_current_a {
            return Err(CalError::ImplausibleResult);
        }
        self.map.enabled = true;
        self.map.scale_a = scale_a;
        self.map.table = self.forward;
        self.passes_done += 1;
        Ok(())
    }
}

/// A rotor off the sweep speed: stuck (below a tenth of it) or slow.
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
    use crate::angle::MechanicalAngle;
    use crate::calibration::ClosedLoopFeedback;
    use crate::frames::{Abc, Dq};

    const PP: u8 = 7;
    const HZ: f32 = 10_000.0;

    /// A rotor held at the requested speed by a perfect speed loop: the q
    /// current is friction with the speed's sign plus `-T_cog / kt`
    /// (`cog_a sin(6 theta_e)`), and `stuck` keeps it still.
    struct Rotor {
        theta: ElectricalAngle,
        w_mech: f32,
        cog_a: f32,
        stuck: bool,
        n: u32,
    }

    impl Rotor {
        fn new(cog_a: f32, stuck: bool) -> Self {
            Self {
                theta: ElectricalAngle::ZERO,
                w_mech: 0.0,
                cog_a,
                stuck,
                n: 0,
            }
        }

        /// One period of `cal`: its step, the rotor moved on a request.
        fn step(&mut self, cal: &mut CoggingCalibration) -> CalStep<()> {
            let x = self.theta.to_radians();
            let iq = 0.3 * self.w_mech.signum() + self.cog_a * libm::sinf(6.0 * x);
            let mut inp = CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0);
            if self.n > 0 {
                inp.closed_loop = Some(ClosedLoopFeedback {
                    v_dq_v: Dq::ZERO,
                    i_dq_a: Dq::new(0.0, iq),
                    velocity_rad_s: if self.stuck { 0.0 } else { self.w_mech },
                    theta_e: self.theta,
                });
            }
            self.n += 1;
            let step = cal.step(&inp);
            if let CalStep::Velocity { rad_s } = step {
                self.w_mech = rad_s;
                if !self.stuck {
                    self.theta = self.theta.add_radians(rad_s * PP as f32 / HZ);
                }
            }
            step
        }
    }

    fn run(cal: &mut CoggingCalibration, cog_a: f32, stuck: bool) -> (CalStep<()>, u32) {
        let mut rotor = Rotor::new(cog_a, stuck);
        for n in 0..10_000_000u32 {
            match rotor.step(cal) {
                CalStep::Velocity { .. } => {}
                other => return (other, n),
            }
        }
        panic!("did not finish");
    }

    #[test]
    fn measures_the_cogging_and_cancels_friction() {
        let mut cal = CoggingCalibration::new(CoggingCalConfig::new(PP, HZ, 5.0));
        let (end, n) = run(&mut cal, 0.2, false);
        assert_eq!(end, CalStep::Done(()));
        let planned = cal.config().planned_s() * HZ;
        assert!(
            (n as f32) < 1.05 * planned,
            "{n} periods, planned {planned}"
        );
        let map = cal.map();
        assert_eq!(cal.passes_done(), 2);
        for k in (0..COGGING_BINS).step_by(7) {
            // The point's centre.
            let x = TAU * (k as f32 + 0.5) / COGGING_BINS as f32;
            let want = 0.2 * libm::sinf(6.0 * x);
            assert!(
                (map.amps_at(k) - want).abs() < 0.01,
                "{k}: {}",
                map.amps_at(k)
            );
        }
    }

    #[test]
    fn named_failures() {
        let c = CoggingCalConfig::new(PP, HZ, 5.0);
        let (end, _) = run(&mut CoggingCalibration::new(c), 0.2, true);
        assert_eq!(end, CalStep::Failed(CalError::RotorStuck));
        // A map beyond half the current bound is not cogging.
        let (end, _) = run(&mut CoggingCalibration::new(c), 3.0, false);
        assert_eq!(end, CalStep::Failed(CalError::ImplausibleResult));
        let short = CoggingCalConfig {
            timeout_s: 1.0,
            ..c
        };
        let (end, _) = run(&mut CoggingCalibration::new(short), 0.2, false);
        assert_eq!(end, CalStep::Failed(CalError::Timeout));
        let bad = CoggingCalConfig { turns: 0, ..c };
        let (end, _) = run(&mut CoggingCalibration::new(bad), 0.2, false);
        assert_eq!(end, CalStep::Failed(CalError::InvalidConfig));
        // Over the current bound, and a NaN.
        let mut cal = CoggingCalibration::new(c);
        let hot = CalInput::open_loop(Abc::new(9.0, -4.5, -4.5), MechanicalAngle::ZERO, 24.0);
        assert_eq!(cal.step(&hot), CalStep::Failed(CalError::OverCurrent));
        let mut cal = CoggingCalibration::new(c);
        let nan = CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, f32::NAN);
        assert_eq!(cal.step(&nan), CalStep::Failed(CalError::InvalidInput));
        // Found by a fold: a point never seen (in the second chunk), a sum
        // gone infinite.
        let mut rotor = Rotor::new(0.2, false);
        rotor.n = 1;
        let mut cal = CoggingCalibration::new(c);
        cal.fold = Some(Fold::start(Stage::Keep));
        cal.count = [1; COGGING_BINS];
        cal.count[40] = 0;
        assert!(matches!(rotor.step(&mut cal), CalStep::Velocity { .. }));
        assert_eq!(
            rotor.step(&mut cal),
            CalStep::Failed(CalError::SensorNoMotion)
        );
        let mut cal = CoggingCalibration::new(c);
        cal.fold = Some(Fold::start(Stage::Average { total: 0.0 }));
        cal.count = [1; COGGING_BINS];
        cal.sum_a[3] = f32::INFINITY;
        let end = (0..3 * COGGING_BINS).find_map(|_| match rotor.step(&mut cal) {
            CalStep::Velocity { .. } => None,
            other => Some(other),
        });
        assert_eq!(end, Some(CalStep::Failed(CalError::InvalidInput)));
    }

    /// The forward means in counts, in one go (the computation before the
    /// fold was spread over periods).
    fn straight_keep(cal: &CoggingCalibration) -> [i16; COGGING_BINS] {
        let mut f = [0; COGGING_BINS];
        for (k, f) in f.iter_mut().enumerate() {
            let mean = cal.sum_a[k] / cal.count[k] as f32;
            *f = libm::roundf(mean / cal.forward_scale_a).clamp(-32767.0, 32767.0) as i16;
        }
        f
    }

    /// The pass's map, in one go.
    fn straight_map(cal: &CoggingCalibration) -> CoggingMap {
        let mut amps = [0.0; COGGING_BINS];
        let mut total = 0.0f32;
        for (k, a) in amps.iter_mut().enumerate() {
            let fwd = cal.forward[k] as f32 * cal.forward_scale_a;
            *a = 0.5 * (fwd + cal.sum_a[k] / cal.count[k] as f32);
            total += *a;
        }
        let mean = total / COGGING_BINS as f32;
        for a in amps.iter_mut() {
            *a -= mean;
        }
        CoggingMap::from_amps(&amps).unwrap()
    }

    /// Points whose tables a period changed.
    fn points_changed(a: &CoggingCalibration, b: &CoggingCalibration) -> usize {
        (0..COGGING_BINS)
            .filter(|&k| {
                a.sum_a[k].to_bits() != b.sum_a[k].to_bits()
                    || a.count[k] != b.count[k]
                    || a.forward[k] != b.forward[k]
            })
            .count()
    }

    /// The most points a period may fold (the interrupt's budget).
    const MOST_POINTS: usize = 32;

    /// What the folds of a calibration did, period by period.
    struct FoldWatch {
        /// (stage at the start, periods it took) per fold.
        folds: [(Stage, usize); 4],
        n: usize,
        want_forward: [i16; COGGING_BINS],
        want_map: CoggingMap,
    }

    impl FoldWatch {
        /// A period from `a` to `b`: at most a chunk of points changed
        /// (and the one recorded); the map shows only once whole.
        fn period(&mut self, a: &CoggingCalibration, b: &CoggingCalibration) {
            assert!(points_changed(a, b) <= MOST_POINTS.min(BINS_PER_PERIOD) + 1);
            match (a.fold, b.fold) {
                (None, Some(f)) => self.started(f.stage, b),
                (Some(_), None) => self.ended(a, b),
                (Some(_), Some(_)) => {
                    self.folds[self.n - 1].1 += 1;
                    assert_eq!(b.map(), a.map());
                    assert_eq!(b.passes_done(), a.passes_done());
                    assert!(!matches!(b.phase, Phase::Record { .. }));
                }
                (None, None) => {}
            }
        }

        /// A fold set up: what the computation in one go gives.
        fn started(&mut self, stage: Stage, cal: &CoggingCalibration) {
            self.folds[self.n] = (stage, 0);
            self.n += 1;
            self.want_forward = straight_keep(cal);
            if stage != Stage::Keep {
                self.want_map = straight_map(cal);
            }
        }

        /// A fold's last chunk: its result, the tables cleared.
        fn ended(&mut self, a: &CoggingCalibration, b: &CoggingCalibration) {
            self.folds[self.n - 1].1 += 1;
            assert!(b.sum_a.iter().all(|s| *s == 0.0));
            assert!(b.count.iter().all(|n| *n == 0));
            if self.folds[self.n - 1].0 == Stage::Keep {
                assert_eq!(b.forward, self.want_forward);
            } else {
                assert_eq!(b.passes_done(), a.passes_done() + 1);
                assert_eq!(b.map(), &self.want_map);
            }
        }
    }

    /// Each fold takes a chunk of points per period (the period's one
    /// recorded point aside), the map shows only once whole, and it is
    /// the one-go computation's; with no settling time, the recording
    /// waits for the fold.
    #[test]
    fn folds_a_chunk_per_period() {
        let c = CoggingCalConfig {
            settle_s: 0.0,
            sweep_e_rad_s: 2.0 * TAU,
            ..CoggingCalConfig::new(PP, HZ, 5.0)
        };
        let mut cal = CoggingCalibration::new(c);
        let mut rotor = Rotor::new(0.2, false);
        let mut watch = FoldWatch {
            folds: [(Stage::Keep, 0); 4],
            n: 0,
            want_forward: [0; COGGING_BINS],
            want_map: CoggingMap::EMPTY,
        };
        let end = loop {
            let before = cal;
            let step = rotor.step(&mut cal);
            watch.period(&before, &cal);
            if !matches!(step, CalStep::Velocity { .. }) {
                // Done in the period the last fold ended.
                assert!(before.fold.is_some());
                break step;
            }
        };
        assert_eq!(end, CalStep::Done(()));
        assert_eq!(watch.n, 4);
        let chunks = COGGING_BINS.div_ceil(BINS_PER_PERIOD);
        for (i, (stage, periods)) in watch.folds.iter().enumerate() {
            let sweeps = if i % 2 == 0 { 1 } else { 3 };
            assert_eq!(*periods, sweeps * chunks, "{i}: {stage:?}");
        }
        assert_eq!(cal.passes_done(), 2);
        assert!((cal.map().peak_a() - 0.2).abs() < 0.01);
    }
}
