//! The flux observer beside the angle sensor (design §27, limp-home): it
//! follows the rotor with the sensor; its angle is compared with the
//! sensor's above the hand-over speed (the plausibility check), and under
//! a velocity command it takes over when the sensor fails there.

use super::*;
use crate::frames::AlphaBeta;

/// The largest angle between the sensor and the observer that counts as
/// agreement \[rad, electrical\].
pub const AGREEMENT_RAD: f32 = 0.5;

/// Periods of disagreement after which the observer takes over under a
/// velocity command when the sensor's reading also stands still for three
/// counts' worth of the observer's motion (a frozen sensor).
pub const TAKE_OVER_PERIODS: u32 = 10;

/// The observer beside the sensor and what it has seen.
#[derive(Clone, Copy, Debug)]
pub(super) struct Fallback {
    sl: Sensorless,
    /// Consecutive periods of agreement above the hand-over speed.
    agree: u32,
    /// Consecutive periods of disagreement above it, after agreement.
    disagree: u32,
    /// Consecutive periods with the bridge on (the observer is paused,
    /// its angle and speed frozen, while it is off).
    driven: u32,
}

impl Fallback {
    pub(super) fn new(cfg: SensorlessConfig) -> Self {
        Self {
            sl: Sensorless::new(cfg),
            agree: 0,
            disagree: 0,
            driven: 0,
        }
    }

    /// The configuration.
    pub(super) fn config(&self) -> &SensorlessConfig {
        self.sl.config()
    }

    /// Above the hand-over speed, agreeing for the lock time.
    fn locked(&self) -> bool {
        self.agree >= self.sl.config().lock_periods.max(1)
    }
}

impl CurrentStage {
    /// True once the drive runs on the observer because its sensor failed
    /// (limp-home). A configuration change to the sensor ends it.
    pub fn is_limp_home(&self) -> bool {
        self.state.limp_home
    }

    /// The observer beside the sensor takes this period's current and is
    /// compared with the sensor's angle `theta_sensor`. Disagreeing for
    /// the lock time-out after it had agreed latches
    /// [`Fault::AngleSensorImplausible`] (the plausibility check); under a
    /// velocity command the observer takes over instead (returns true).
    #[inline(never)]
    pub(super) fn sense_beside(&mut self, i_ab: AlphaBeta, theta_sensor: ElectricalAngle) -> bool {
        let pp = self.config.angle.pole_pairs;
        let frozen = self.reading_frozen_against_observer();
        let Some(f) = self.fallback.as_mut() else {
            return false;
        };
        f.sl.sense(i_ab, pp);
        let obs = f.sl.observer();
        let c = f.sl.config();
        // A paused observer (bridge off) or one just resumed says nothing.
        let observable = f.driven >= 2 && obs.speed_rad_s().abs() >= c.handover_rad_s;
        let apart = theta_sensor.diff_radians(obs.angle()).abs() > AGREEMENT_RAD;
        match (observable, apart) {
            (false, _) => {
                f.agree = 0;
                f.disagree = 0;
            }
            (true, false) => {
                f.agree = f.agree.saturating_add(1);
                f.disagree = 0;
            }
            (true, true) => {
                if f.locked() {
                    f.disagree = f.disagree.saturating_add(1);
                } else {
                    f.agree = 0;
                }
            }
        }
        // Under a velocity command the observer takes over: at once for a
        // frozen reading (it drives the current off the rotor), after four
        // lock times for a sensor that moves but disagrees (a transient of
        // the observer's own settles sooner); otherwise the disagreement
        // is a fault after the lock time-out.
        let velocity = matches!(self.state.active, Command::Velocity { .. });
        let wait = if frozen {
            TAKE_OVER_PERIODS
        } else {
            c.lock_periods.saturating_mul(4)
        };
        if velocity && f.disagree > wait {
            return true;
        }
        if !velocity && f.disagree > c.lock_timeout_periods {
            self.supervisor.trip(Fault::AngleSensorImplausible);
        }
        false
    }

    /// The sensor's reading has stood still while the observer beside it
    /// saw the rotor turn three counts or more.
    fn reading_frozen_against_observer(&self) -> bool {
        let Some(f) = self.fallback.as_ref() else {
            return false;
        };
        let cpr = self.config.angle.sensor_counts_per_rev;
        if cpr == 0 {
            return false;
        }
        let pp = f32::from(self.config.angle.pole_pairs.max(1));
        let count_rad = core::f32::consts::TAU / cpr as f32;
        let moved_rad = f.sl.observer().speed_rad_s().abs() / pp
            * self.config.current.ts_s
            * self.state.unchanged_periods as f32;
        moved_rad > 3.0 * count_rad
    }

    /// The observer beside the sensor may take over now: a velocity
    /// command and an observer that agreed with the sensor for the lock
    /// time above the hand-over speed.
    #[inline(never)]
    pub(super) fn fallback_ready(&self) -> bool {
        matches!(self.state.active, Command::Velocity { .. })
            && self.fallback.as_ref().is_some_and(Fallback::locked)
    }

    /// [`Self::sense`] on the angle sensor with the observer beside it:
    /// the observer takes this period's current; under a velocity command
    /// it takes over when the sensor gives no reading, fails its checks
    /// (an implausible jump, a stuck reading: the fault is withdrawn when
    /// it is this period's only new one) or disagrees with it
    /// (limp-home). Kept apart from the sensor's path so that a drive
    /// without a fall-back does not pay for it.
    #[inline(never)]
    pub(super) fn sense_with_fallback(&mut self, s: &Sample, iq_ref_from_speed_a: f32) -> Sensed {
        if s.currents.is_some() && s.angle.is_none() && self.fallback_ready() {
            self.take_over();
            return self.sense_sensorless(s);
        }
        let before = self.supervisor.faults();
        let (tracker, observer) = (self.tracker, self.observer);
        let mut sensed = self.sense_sensor(s, iq_ref_from_speed_a);
        if s.currents.is_none() || s.angle.is_none() || s.v_bus_v.is_none() {
            return sensed;
        }
        let new = crate::control::FaultSet(self.supervisor.faults().0 & !before.0);
        let found = [Fault::AngleSensorImplausible, Fault::AngleSensorStuck]
            .into_iter()
            .find(|f| new.contains(*f));
        let disagrees = self.sense_beside(sensed.i_ab, sensed.theta_e);
        // A sensor fault: only when it is this period's only new fault
        // (withdrawn); a disagreement: only in a period without a new one.
        let take = match found {
            Some(f) => self.fallback_ready() && self.supervisor.withdraw(f, before),
            None => disagrees && new.is_empty(),
        };
        if take && found.is_some() {
            // The rejected reading moved neither the tracker nor the speed
            // observer.
            self.tracker = tracker;
            self.observer = observer;
        }
        if take {
            self.take_over();
            if let Some(sl) = self.sensorless.as_ref() {
                sensed.theta_e = sl.observer().angle();
            }
        }
        sensed
    }

    /// The observer beside the sensor takes over (limp-home): the drive
    /// runs sensorless from now on. The angle tracker, the speed observer
    /// and the current loop go on as they were: the observer agreed with
    /// the sensor's angle they ran on, and its mechanical angle continues
    /// from the tracker's.
    #[inline(never)]
    pub(super) fn take_over(&mut self) {
        let Some(f) = self.fallback.take() else {
            return;
        };
        let mut sl = f.sl;
        sl.take_over(self.tracker.angle());
        self.config.sensorless = Some(*sl.config());
        self.sensorless = Some(sl);
        // The sensor's own state goes with it.
        self.state.last_innovation_rad = 0.0;
        self.state.unchanged_periods = 0;
        self.state.speed_at_change_rad_s = 0.0;
        self.state.emf_turned_rad = 0.0;
        // The speed observer's torque input from now on (what
        // `publish_sensorless` keeps up to date).
        self.state.torque_iq_a = self.state.last_i_dq.q;
        self.model.reset();
        self.state.limp_home = true;
    }

    /// Sensor path, end of period: the observer beside the sensor records
    /// the duties (or pauses with the bridge off).
    #[inline(never)]
    pub(super) fn publish_beside(&mut self, duties: Option<[f32; 3]>, v_bus_v: f32) {
        if let Some(f) = self.fallback.as_mut() {
            f.sl.record(duties, v_bus_v);
            if duties.is_some() {
                f.driven = f.driven.saturating_add(1);
            } else {
                // Paused: its agreement starts again once it runs.
                f.driven = 0;
                f.agree = 0;
                f.disagree = 0;
            }
        }
    }
}
