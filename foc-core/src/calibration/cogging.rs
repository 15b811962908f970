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

use super::common::{check_input, latch, CalError, CalInput, CalStep};
use crate::angle::ElectricalAngle;
use crate::control::cogging::{bin_of, CoggingMap, COGGING_BINS};
use core::f32::consts::TAU;

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
    /// This direction's sum of q current per point \[A\].
    sum_a: [f32; COGGING_BINS],
    /// Samples per point this direction.
    count: [u16; COGGING_BINS],
    /// The forward direction's mean per point, in counts of
    /// `forward_scale_a`.
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
        let dir = match self.phase {
            Phase::Settle { dir, .. } | Phase::Record { dir, .. } => dir,
        };
        self.track(dir, fb.theta_e);
        let step = match self.phase {
            Phase::Settle { dir, since } => self.settle(dir, since, fb.velocity_rad_s)?,
            Phase::Record { dir, travelled_rad } => self.record(
                dir,
                travelled_rad,
                fb.theta_e,
                fb.i_dq_a.q,
                fb.velocity_rad_s,
            )?,
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

    /// Settling: recording starts after `settle_s` at speed; a rotor that
    /// is not at speed after four times that fails.
    fn settle(&mut self, dir: i8, since: u32, w_rad_s: f32) -> Result<CalStep<()>, CalError> {
        let target = self.config.mech_rad_s(dir as f32);
        let settled_s = self.period.saturating_sub(since) as f32 * self.config.ts_s;
        let at_speed = (w_rad_s - target).abs() < 0.5 * target.abs();
        if settled_s >= self.config.settle_s && at_speed {
            self.sum_a = [0.0; COGGING_BINS];
            self.count = [0; COGGING_BINS];
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
        if dir > 0 {
            self.keep_forward()?;
            self.lead_rad = 0.0;
            self.phase = Phase::Settle {
                dir: -1,
                since: self.period,
            };
            return Ok(self.sweep(-1));
        }
        self.finish_pass()?;
        if self.passes_done >= self.config.passes {
            return Ok(CalStep::Done(()));
        }
        self.lead_rad = 0.0;
        self.phase = Phase::Settle {
            dir: 1,
            since: self.period,
        };
        Ok(self.sweep(1))
    }

    /// The forward direction's means, kept while the backward one runs.
    fn keep_forward(&mut self) -> Result<(), CalError> {
        let scale = self.forward_scale_a;
        for k in 0..COGGING_BINS {
            let mean = self.mean(k)?;
            if let Some(f) = self.forward.get_mut(k) {
                let c = libm::roundf(mean / scale).clamp(-32767.0, 32767.0);
                *f = c as i16;
            }
        }
        Ok(())
    }

    /// This direction's mean q current at point `k` \[A\]; a point never
    /// seen fails.
    fn mean(&self, k: usize) -> Result<f32, CalError> {
        match (self.sum_a.get(k), self.count.get(k)) {
            (Some(s), Some(n)) if *n > 0 => Ok(*s / *n as f32),
            _ => Err(CalError::SensorNoMotion),
        }
    }

    /// The two directions averaged, the mean removed: the pass's map.
    fn finish_pass(&mut self) -> Result<(), CalError> {
        // In place of this direction's sums (no second table on the stack).
        let mut total = 0.0f32;
        for k in 0..COGGING_BINS {
            let fwd = self.forward.get(k).copied().unwrap_or(0) as f32 * self.forward_scale_a;
            let both = 0.5 * (fwd + self.mean(k)?);
            if let Some(s) = self.sum_a.get_mut(k) {
                *s = both;
            }
            total += both;
        }
        let mean = total / COGGING_BINS as f32;
        for s in self.sum_a.iter_mut() {
            *s -= mean;
        }
        self.count = [0; COGGING_BINS];
        let map = CoggingMap::from_amps(&self.sum_a).map_err(|_| CalError::InvalidInput)?;
        if map.peak_a() > self.config.max_map_share * self.config.max_current_a {
            return Err(CalError::ImplausibleResult);
        }
        self.map = map;
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
    fn run(cal: &mut CoggingCalibration, cog_a: f32, stuck: bool) -> (CalStep<()>, u32) {
        let mut theta = ElectricalAngle::ZERO;
        let mut w_mech = 0.0f32;
        for n in 0..10_000_000u32 {
            let x = theta.to_radians();
            let iq = 0.3 * w_mech.signum() + cog_a * libm::sinf(6.0 * x);
            let mut inp = CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0);
            if n > 0 {
                inp.closed_loop = Some(ClosedLoopFeedback {
                    v_dq_v: Dq::ZERO,
                    i_dq_a: Dq::new(0.0, iq),
                    velocity_rad_s: if stuck { 0.0 } else { w_mech },
                    theta_e: theta,
                });
            }
            match cal.step(&inp) {
                CalStep::Velocity { rad_s } => w_mech = rad_s,
                other => return (other, n),
            }
            if !stuck {
                theta = theta.add_radians(w_mech * PP as f32 / HZ);
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
    }
}
