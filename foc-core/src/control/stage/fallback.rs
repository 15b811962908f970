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

/// Halls + sensorless: the current loop goes back on the sensor's angle
/// below this share of [`BesideConfig::observer_above_rad_s`] (hysteresis).
pub const HYBRID_HYSTERESIS: f32 = 0.8;

/// Halls + sensorless: the time over which the angle the current loop
/// uses moves from the sensor's to the observer's and back \[s\] (a
/// bumpless hand-over: the two agree within `AGREEMENT_RAD` (0.5 rad), and the
/// difference is taken up gradually instead of in one step).
pub const HYBRID_BLEND_S: f32 = 0.02;

/// The flux observer beside the angle sensor (design §27).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BesideConfig {
    /// The observer's configuration, as for running sensorless.
    pub sensorless: SensorlessConfig,
    /// Limp-home: under a velocity command the observer takes over when
    /// the sensor fails above the hand-over speed. `false`: the observer is
    /// a plausibility check only (a lasting disagreement latches
    /// [`Fault::AngleSensorImplausible`], a failure the sensor's fault).
    pub limp_home: bool,
    /// Halls + sensorless: above this speed [rad/s, electrical], with the
    /// observer agreeing, the current loop runs on the observer's angle
    /// (the sensor still gives the position and the speed, and is still
    /// checked); below [`HYBRID_HYSTERESIS`] times it on the sensor's. The
    /// hand-over takes [`HYBRID_BLEND_S`] either way. `None`: always on
    /// the sensor's angle.
    pub observer_above_rad_s: Option<f32>,
}

impl BesideConfig {
    /// The observer as a plausibility check that takes over when the
    /// sensor fails (limp-home), never driving the loop otherwise.
    pub const fn limp_home(sensorless: SensorlessConfig) -> Self {
        Self {
            sensorless,
            limp_home: true,
            observer_above_rad_s: None,
        }
    }

    /// Halls + sensorless with limp-home: the observer's angle drives the
    /// loop above twice the observer's hand-over speed (where it is locked
    /// with margin; back on the sensor below 1.6 times it).
    pub fn hybrid(sensorless: SensorlessConfig) -> Self {
        Self {
            observer_above_rad_s: Some(2.0 * sensorless.handover_rad_s),
            ..Self::limp_home(sensorless)
        }
    }
}

/// The observer beside the sensor and what it has seen.
#[derive(Clone, Copy, Debug)]
pub(super) struct Fallback {
    sl: Sensorless,
    limp_home: bool,
    /// Halls + sensorless: the speed above which the observer's angle is
    /// used [rad/s, electrical].
    above_rad_s: Option<f32>,
    /// The share of the observer's angle in the angle used (0 to 1), its
    /// step per period, and whether it is moving towards 1.
    weight: f32,
    weight_step: f32,
    on_observer: bool,
    /// Consecutive periods of agreement above the hand-over speed.
    agree: u32,
    /// Consecutive periods of disagreement above it, after agreement.
    disagree: u32,
    /// Consecutive periods with the bridge on (the observer is paused,
    /// its angle and speed frozen, while it is off).
    driven: u32,
}

impl Fallback {
    pub(super) fn new(cfg: BesideConfig) -> Self {
        let ts = cfg.sensorless.observer.ts_s;
        let blend_periods = (HYBRID_BLEND_S / ts).max(1.0);
        Self {
            sl: Sensorless::new(cfg.sensorless),
            limp_home: cfg.limp_home,
            above_rad_s: cfg.observer_above_rad_s,
            weight: 0.0,
            weight_step: 1.0 / blend_periods,
            on_observer: false,
            agree: 0,
            disagree: 0,
            driven: 0,
        }
    }

    /// The bridge is off: the observer is paused (its angle frozen), its
    /// agreement starts again once it runs, and the loop's angle is the
    /// sensor's at once (a frozen angle must not reach a restart).
    pub(super) fn pause(&mut self) {
        self.driven = 0;
        self.agree = 0;
        self.disagree = 0;
        self.weight = 0.0;
        self.on_observer = false;
    }

    /// Above the hand-over speed, agreeing for the lock time.
    fn locked(&self) -> bool {
        self.agree >= self.sl.config().lock_periods.max(1)
    }

    /// Halls + sensorless: the share of the observer's angle in this
    /// period's angle (hysteresis on the speed; back to the sensor while
    /// the two disagree or the observer is not locked), moved one step.
    fn blend_weight(&mut self) -> f32 {
        let Some(above) = self.above_rad_s else {
            return 0.0;
        };
        let w = self.sl.observer().speed_rad_s().abs();
        let fast = w >= above || (self.on_observer && w >= HYBRID_HYSTERESIS * above);
        self.on_observer = fast && self.locked() && self.disagree == 0;
        self.weight = if self.on_observer {
            (self.weight + self.weight_step).min(1.0)
        } else {
            (self.weight - self.weight_step).max(0.0)
        };
        self.weight
    }
}

impl CurrentStage {
    /// True once the drive runs on the observer because its sensor failed
    /// (limp-home). A configuration change to the sensor ends it.
    pub fn is_limp_home(&self) -> bool {
        self.state.limp_home
    }

    /// Halls + sensorless: the share (0 to 1) of the observer's angle in
    /// the angle the current loop uses; 0 without an observer beside the
    /// sensor.
    pub fn observer_share(&self) -> f32 {
        self.fallback.as_ref().map_or(0.0, |f| f.weight)
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
        let c = *f.sl.config();
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
        let locked = f.locked() && f.disagree == 0;
        f.sl.set_agrees_with_sensor(locked);
        // Under a velocity command the observer takes over: at once for a
        // frozen reading (it drives the current off the rotor), after four
        // lock times for a sensor that moves but disagrees (a transient of
        // the observer's own settles sooner); otherwise the disagreement
        // is a fault after the lock time-out.
        let velocity = f.limp_home && matches!(self.state.active, Command::Velocity { .. });
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
            && self
                .fallback
                .as_ref()
                .is_some_and(|f| f.limp_home && f.locked())
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
        } else {
            self.blend_observer_angle(&mut sensed);
        }
        sensed
    }

    /// Halls + sensorless: the angle the current loop uses moves towards
    /// the observer's above the configured speed (and back below it).
    #[inline(never)]
    fn blend_observer_angle(&mut self, sensed: &mut Sensed) {
        let Some(f) = self.fallback.as_mut() else {
            return;
        };
        let share = f.blend_weight();
        if share > 0.0 {
            let apart = f.sl.observer().angle().diff_radians(sensed.theta_e);
            sensed.theta_e = sensed.theta_e.add_radians(share * apart);
        }
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
        self.state.torque_iq_a = self.net_torque_iq_a(self.state.last_i_dq);
        self.model.reset();
        self.state.limp_home = true;
    }

    /// Sensor path, end of period: the observer beside the sensor records
    /// the duties (or pauses with the bridge off).
    #[inline(never)]
    pub(super) fn publish_beside(
        &mut self,
        duties: Option<[f32; 3]>,
        v_bus_v: f32,
        fb: &mut Feedback,
    ) {
        if let Some(f) = self.fallback.as_mut() {
            f.sl.record(duties, v_bus_v);
            if duties.is_some() {
                f.driven = f.driven.saturating_add(1);
                if f.weight >= 0.5 {
                    fb.angle_in_use = AngleInUse::Observer;
                }
            } else {
                f.pause();
            }
        }
    }
}
