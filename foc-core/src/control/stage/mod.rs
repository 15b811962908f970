//! The three stages of the cascade: loops plus mode logic (see [`super`]).
//!
//! The current stage's jobs, one file each: `angle` (the angle used and
//! its checks), `commands` (mailbox, admission, timeout), `impedance`
//! (joint mode), `window` (power window, brake), `checks` (sensor
//! plausibility), `period` (one PWM period: sense, control, publish);
//! the speed and position stages in `outer`.

mod angle;
mod checks;
mod cogging;
mod commands;
mod fallback;
mod impedance;
mod outer;
mod period;
mod safe;
mod sensorless;
mod window;

pub use angle::{AngleCalibration, INTERPOLATE_BELOW_COUNTS_PER_E_TURN};
use checks::model_check;
pub use commands::TimeoutReaction;
pub use fallback::{BesideConfig, HYBRID_BLEND_S, HYBRID_HYSTERESIS};
pub use outer::{PositionStage, SpeedStage, VelocityRef};
use period::Sensed;

use super::current::{CurrentLoop, CurrentLoopConfig, CurrentLoopInput, CurrentLoopOutput};
use super::estimator::{AngleTracker, AngleTrackerConfig, SpeedObserver, SpeedObserverConfig};
use super::field::{Field, FieldConfig};
use super::joint::JointChange;
use super::joint::{Impedance, ImpedanceLaw, JointConfig};
use super::model::{ModelCheck, Period, Verdict};
use super::permit::Calibrated;
use super::position::{PositionLoop, PositionLoopConfig};
use super::power::{PowerInputs, PowerLimiter, PowerLimitsConfig, PowerReport};
use super::sensorless::{Sensorless, SensorlessConfig};
use super::speed::{SpeedLoop, SpeedLoopConfig};
use super::supervisor::{Checks, Fault, Supervisor, SupervisorConfig};
use super::Refusal;
use super::{AngleInUse, BridgeCommand, Command, CommandSlot, Feedback, Limits, Mechanics, Mode};
use crate::angle::{ElectricalAngle, MechanicalAngle};
use crate::clamp;
use crate::frames::Dq;
use crate::hal::PhaseCurrents;
use crate::transforms;

/// Configuration of the current stage.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentStageConfig {
    /// Current loop.
    pub current: CurrentLoopConfig,
    /// Speed/position tracker (runs every period): the angle
    /// interpolation, the decoupling's speed, the plausibility checks and
    /// the position.
    pub tracker: AngleTrackerConfig,
    /// The torque-fed speed observer (runs every period): the published
    /// speed, which the speed loop uses (design §19).
    pub observer: SpeedObserverConfig,
    /// Fault limits.
    pub supervisor: SupervisorConfig,
    /// Command limits.
    pub limits: Limits,
    /// Sensor to electrical angle.
    pub angle: AngleCalibration,
    /// Periods without a new command before the timeout reaction (0: off).
    pub command_timeout_periods: u32,
    /// The timeout reaction.
    pub timeout_reaction: TimeoutReaction,
    /// Power limits (regen, bus current, power, thermal derating, brake
    /// chopper; design §18); `None`: only the current limit.
    pub power: Option<PowerLimitsConfig>,
    /// Robot-joint settings: travel limits, impedance entry and timeout
    /// (design §21).
    pub joint: JointConfig,
    /// Run without the angle sensor (design §27): the flux observer and
    /// the start's field give the angle; `None`: the angle sensor does.
    pub sensorless: Option<SensorlessConfig>,
    /// With the angle sensor: the flux observer runs beside it (design
    /// §27): a plausibility check, limp-home (under a velocity command it
    /// takes over when the sensor fails above the hand-over speed instead
    /// of stopping the drive) and halls + sensorless, as configured;
    /// `None`: off (no observer beside the sensor).
    pub fallback: Option<BesideConfig>,
    /// The d-current reference (MTPA, field weakening) and the safe state
    /// by speed (design §30).
    pub field: FieldConfig,
}

/// One period's measurements; `None` where the read failed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Phase currents \[A\].
    pub currents: Option<PhaseCurrents>,
    /// Raw mechanical angle from the sensor.
    pub angle: Option<MechanicalAngle>,
    /// Bus voltage \[V\].
    pub v_bus_v: Option<f32>,
    /// Temperature [deg C] if measured.
    pub temperature_c: Option<f32>,
}

/// The current stage's run-time state (everything but the loops, the
/// tracker and the supervisor, which keep their own), in one piece that can
/// be inspected and reset.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurrentStageState {
    /// The active command (after validation, timeout reaction and faults).
    pub active: Command,
    /// Command number of the mailbox last taken.
    pub last_seq: u32,
    /// Fault-clear number of the mailbox last performed.
    pub last_clear_seq: u32,
    /// Periods since the last new command (command timeout).
    pub age_periods: u32,
    /// Open-loop angle of the next period.
    pub ol_theta: ElectricalAngle,
    /// dq voltage of the last period \[V\] (bumpless open -> closed loop).
    pub last_out_v_dq: Dq,
    /// dq current of the last period \[A\].
    pub last_i_dq: Dq,
    /// Sensorless (design §27): the q current of the last period in the
    /// observer's frame \[A\] (on a start's field the loop's frame is the
    /// field's): the torque the speed observer takes. (With a sensor the
    /// observer takes `last_i_dq.q`.)
    pub torque_iq_a: f32,
    /// Periods stepped (wraps).
    pub period: u32,
    /// Commands refused so far.
    pub rejected: u32,
    /// A calibration permit is installed (closed-loop modes unlocked).
    pub calibrated: bool,
    /// Injection (design §28): periods in a row on the voltage limit (a
    /// slewing current is excused that long, an open winding not).
    pub limited_periods: u32,
    /// The drive runs on the observer because its angle sensor failed
    /// (design §27, limp-home).
    pub limp_home: bool,
    /// The last raw angle reading (stuck-sensor check, interpolation).
    pub last_raw: Option<MechanicalAngle>,
    /// `config.angle.interpolation_half_count()`, cached.
    pub interpolation: Option<u32>,
    /// The last interpolated (mechanical) angle.
    pub last_interp: MechanicalAngle,
    /// The angle tracker's last signed innovation [rad, mechanical].
    pub last_innovation_rad: f32,
    /// Periods since the raw angle reading last changed.
    pub unchanged_periods: u32,
    /// The tracked speed [rad/s, mechanical] when the reading last changed
    /// (names a model-check trip with a frozen reading, design §24).
    pub speed_at_change_rad_s: f32,
    /// How far the measured back-EMF has turned in the dq frame since the
    /// reading last changed [rad, electrical] (a coarse sensor's frozen
    /// reading under a turning rotor, design §24), and its last value.
    pub emf_turned_rad: f32,
    /// See `emf_turned_rad`.
    pub last_emf_v: Option<Dq>,
    /// The speed stage's q-current reference as the current loop uses it,
    /// interpolated over the speed-loop period \[A\] (design §19).
    pub iq_interp_a: f32,
    /// Its change per period towards `iq_target_a` \[A\].
    pub iq_step_a: f32,
    /// The speed stage's last output \[A\].
    pub iq_target_a: f32,
    /// `1 / N`, N the periods per speed-loop step
    /// ([`CurrentStage::set_speed_periods`]).
    pub speed_inv_periods: f32,
    /// N itself.
    pub speed_periods: u32,
    /// The impedance law of the active impedance command (design §21).
    pub impedance: ImpedanceLaw,
    /// Bumpless entry into impedance mode: the current the blend starts
    /// from \[A\] ...
    pub blend_from_a: f32,
    /// ... its weight now (1 -> 0) ...
    pub blend_weight: f32,
    /// ... and the weight's decrease per period.
    pub blend_step: f32,
    /// A command timeout in impedance mode switched to damping only; the
    /// next one disables.
    pub timeout_damping: bool,
    /// The travel limits' q-current window of this period \[A\], when they
    /// are configured and a closed-loop mode is active.
    pub travel_window_a: Option<(f32, f32)>,
}

impl CurrentStageState {
    /// Disabled, uncalibrated, nothing taken from the mailbox yet.
    pub const fn new(interpolation: Option<u32>) -> Self {
        Self {
            active: Command::Disable,
            last_seq: 0,
            last_clear_seq: 0,
            age_periods: 0,
            ol_theta: ElectricalAngle::ZERO,
            last_out_v_dq: Dq::ZERO,
            last_i_dq: Dq::ZERO,
            torque_iq_a: 0.0,
            period: 0,
            rejected: 0,
            calibrated: false,
            limited_periods: 0,
            limp_home: false,
            last_raw: None,
            interpolation,
            last_interp: MechanicalAngle::ZERO,
            last_innovation_rad: 0.0,
            unchanged_periods: 0,
            speed_at_change_rad_s: 0.0,
            emf_turned_rad: 0.0,
            last_emf_v: None,
            iq_interp_a: 0.0,
            iq_step_a: 0.0,
            iq_target_a: 0.0,
            speed_inv_periods: 1.0,
            speed_periods: 1,
            impedance: ImpedanceLaw {
                p_ref_rad: 0.0,
                p_step_rad: 0.0,
                v_ref_rad_s: 0.0,
                kp_a_per_rad: 0.0,
                kd_a_s_per_rad: 0.0,
                iq_ff_a: 0.0,
                iq_max_a: 0.0,
                p_min_rad: 0.0,
                p_max_rad: 0.0,
                p_carry_rad: 0.0,
            },
            blend_from_a: 0.0,
            blend_weight: 0.0,
            blend_step: 0.0,
            timeout_damping: false,
            travel_window_a: None,
        }
    }

    /// Back to `Disable` with the per-run values cleared. Keeps what must
    /// survive a reset: the mailbox numbers (so an old command is never
    /// taken again), the calibration flag, the period and refusal counters
    /// and the cached interpolation setting.
    pub fn reset(&mut self) {
        *self = Self {
            last_seq: self.last_seq,
            last_clear_seq: self.last_clear_seq,
            period: self.period,
            rejected: self.rejected,
            calibrated: self.calibrated,
            limp_home: self.limp_home,
            speed_inv_periods: self.speed_inv_periods,
            speed_periods: self.speed_periods,
            ..Self::new(self.interpolation)
        };
    }
}

/// The current stage: runs every PWM period at the highest priority.
///
/// `repr(C)`: its fields stay in the order written, the hot ones first
/// and the sensorless observers last. Left to the compiler, adding the
/// fall-back observer (256 bytes) moved hot fields past the Cortex-M4's
/// short load/store offsets and cost every period 60 to 100 instructions
/// (`cargo xtask bench`).
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub struct CurrentStage {
    config: CurrentStageConfig,
    current: CurrentLoop,
    tracker: AngleTracker,
    observer: SpeedObserver,
    /// The mechanics behind the observer's model (re-derived when the
    /// current loop's motor changes).
    mechanics: Option<Mechanics>,
    supervisor: Supervisor,
    /// The model-based current-sense and angle check (design §24).
    model: ModelCheck,
    state: CurrentStageState,
    /// Power limits, when configured.
    power: Option<PowerLimiter>,
    /// Their report of this period.
    power_report: PowerReport,
    /// The d-current reference (design §30).
    field: Field,
    /// The sensorless angle source, when configured (design §27).
    sensorless: Option<Sensorless>,
    /// The observer beside the sensor, when a fallback is configured.
    fallback: Option<fallback::Fallback>,
    /// The safe state by speed (design §30), last: a field added before
    /// the hot ones moved them past the short load offsets (+75
    /// instructions a period, `cargo xtask bench`).
    safe: safe::SafeMemory,
    /// The reading taken as 0 (design §33: the encoder's index).
    reading_zero: MechanicalAngle,
    /// The angle sensor's correction (design §33), after the rest (its
    /// switch read every period, its 512-byte table after it).
    angle_correction: super::angle_correction::AngleCorrection,
    /// The anticogging map (design §32): 1 KB, last.
    cogging: cogging::Anticogging,
}

impl CurrentStage {
    /// New stage, disabled, no fault (a non-finite current limit becomes 0,
    /// see [`Self::set_limits`]).
    pub fn new(mut config: CurrentStageConfig) -> Self {
        config.limits = sanitize_limits(config.limits);
        let motor = config.current.motor;
        config.power = config.power.map(|c| PowerLimitsConfig { motor, ..c });
        Self {
            current: CurrentLoop::new(config.current),
            tracker: AngleTracker::new(config.tracker),
            observer: SpeedObserver::new(config.observer),
            mechanics: None,
            supervisor: {
                let mut sup = Supervisor::new(config.supervisor);
                sup.set_angle_resolution(
                    config.angle.pole_pairs,
                    config.angle.sensor_counts_per_rev,
                );
                sup
            },
            model: model_check(&config),
            config,
            state: CurrentStageState::new(config.angle.interpolation_half_count()),
            power: config.power.map(PowerLimiter::new),
            power_report: PowerReport::unlimited(config.limits.max_current_a),
            field: field_of(&config),
            sensorless: config.sensorless.map(Sensorless::new),
            fallback: config
                .fallback
                .filter(|_| config.sensorless.is_none())
                .map(fallback::Fallback::new),
            safe: safe::SafeMemory::INIT,
            reading_zero: MechanicalAngle::ZERO,
            angle_correction: super::angle_correction::AngleCorrection::NONE,
            cogging: cogging::Anticogging::INIT,
        }
    }

    /// The run-time state.
    pub fn state(&self) -> &CurrentStageState {
        &self.state
    }

    /// Back to `Disable` with the current loop, the angle tracker and the
    /// run-time state reset ([`CurrentStageState::reset`]). Keeps the
    /// configuration, the calibration permit and latched faults.
    pub fn reset(&mut self) {
        self.current.reset();
        self.tracker.reset();
        self.observer.reset();
        self.state.reset();
        self.state.last_innovation_rad = 0.0;
        self.model.reset();
        if let Some(f) = self.fallback.as_mut() {
            f.pause();
        }
    }

    /// The configuration.
    pub fn config(&self) -> &CurrentStageConfig {
        &self.config
    }

    /// Install a calibration permit: its angle calibration (the angle
    /// tracker restarts) and its current-loop configuration. Unlocks the
    /// closed-loop modes. This is the only way to unlock them.
    pub fn set_calibration(&mut self, c: &Calibrated) {
        let before = (
            self.config.current,
            self.config.angle.interpolation_half_count().is_some(),
        );
        self.config.angle = c.angle();
        self.state.interpolation = self.config.angle.interpolation_half_count();
        self.state.last_innovation_rad = 0.0;
        self.supervisor.set_angle_resolution(
            self.config.angle.pole_pairs,
            self.config.angle.sensor_counts_per_rev,
        );
        self.tracker.reset();
        self.observer.reset();
        let mut cur = c.current_config();
        // The dead time is the board's (design §31): a permit without one
        // (an identification's, whose gains are the motor's) keeps the
        // stage's, so an identification does not switch the compensation off.
        if cur.dead_time.dead_time_s == 0.0 {
            cur.dead_time = before.0.dead_time;
        }
        self.config.current = cur;
        self.current.set_config(cur);
        self.sensorless_motor(cur.motor);
        if let Some(p) = self.power.as_mut() {
            p.set_motor(cur.motor);
        }
        self.state.calibrated = true;
        self.rederive_mechanics();
        self.rebuild_model();
        // The d-current reference follows the motor, the loop's period and
        // modulation, and the sensor's class (halls refuse weakening).
        if before != (cur, self.config.angle.interpolation_half_count().is_some()) {
            self.field = field_of(&self.config);
        }
    }

    /// The sensorless observer restarts with a new motor.
    fn sensorless_motor(&mut self, motor: super::MotorParams) {
        if let Some(sl) = self.sensorless.as_mut() {
            if sl.config().observer.motor != motor {
                sl.set_motor(motor);
            }
        }
        if let Some(c) = self.config.sensorless.as_mut() {
            c.observer.motor = motor;
        }
        // A motor without saliency has no injection: a command it allowed
        // is dropped.
        if self.sensorless_refuses(self.state.active.mode()) {
            self.state.active = Command::Disable;
        }
        // The observer beside the sensor restarts only with another motor
        // (it keeps its agreement and its tracked flux linkage otherwise).
        let Some(c) = self.config.fallback.as_mut() else {
            return;
        };
        if c.sensorless.observer.motor == motor {
            return;
        }
        c.sensorless.observer.motor = motor;
        let c = *c;
        if let Some(f) = self.fallback.as_mut() {
            *f = fallback::Fallback::new(c);
        }
    }

    /// The observer's `kt / J` after the motor changed.
    fn rederive_mechanics(&mut self) {
        if let Some(m) = self.mechanics {
            self.set_mechanics(&m);
        }
    }

    /// True once a [`Calibrated`] permit is installed (and not revoked by
    /// [`Self::set_current_config`] or [`Self::set_angle_calibration`]),
    /// and, for a permit made without an angle sensor
    /// ([`AngleCalibration::sensorless_only`]), while the drive runs
    /// without its sensor: back on the sensor the closed-loop modes are
    /// locked until an identification with the sensor (or a stored
    /// calibration of it) is installed.
    #[inline]
    pub fn is_calibrated(&self) -> bool {
        self.holds_permit() && (!self.config.angle.sensorless_only || self.sensorless.is_some())
    }

    /// A permit is installed, whether or not it unlocks the closed loop on
    /// the angle source in force ([`Self::is_calibrated`]): a change of
    /// gains keeps it.
    #[inline]
    pub fn holds_permit(&self) -> bool {
        self.state.calibrated
    }

    /// Replace the current-loop configuration with values no permit vouches
    /// for. Revokes the calibration (see [`Self::revoke_calibration`]);
    /// use [`Self::set_calibration`] to install checked values.
    pub fn set_current_config(&mut self, c: CurrentLoopConfig) {
        self.config.current = c;
        self.current.set_config(c);
        self.sensorless_motor(c.motor);
        if let Some(p) = self.power.as_mut() {
            p.set_motor(c.motor);
        }
        self.revoke_calibration();
        self.rederive_mechanics();
        self.rebuild_model();
        self.field = field_of(&self.config);
    }

    /// Replace the angle calibration with values no permit vouches for.
    /// Revokes the calibration (see [`Self::revoke_calibration`]); use
    /// [`Self::set_calibration`] to install checked values.
    pub fn set_angle_calibration(&mut self, a: AngleCalibration) {
        self.config.angle = a;
        self.state.interpolation = a.interpolation_half_count();
        self.state.last_innovation_rad = 0.0;
        self.supervisor
            .set_angle_resolution(a.pole_pairs, a.sensor_counts_per_rev);
        self.tracker.reset();
        self.observer.reset();
        self.revoke_calibration();
        self.rebuild_model();
        // The sensor's class decides whether weakening is allowed.
        self.field = field_of(&self.config);
    }

    /// Lock the closed-loop modes again; a closed-loop command that is
    /// active is replaced by `Disable` (bridge off from the next step).
    pub fn revoke_calibration(&mut self) {
        self.state.calibrated = false;
        if self.state.active.mode().is_closed_loop() {
            self.state.active = Command::Disable;
        }
    }

    /// Replace the command limits.
    /// A current limit that is not a finite, non-negative number becomes 0
    /// (closed-loop current refused and clamped to nothing).
    pub fn set_limits(&mut self, l: Limits) {
        let old_a = self.config.limits.max_current_a;
        self.config.limits = sanitize_limits(l);
        // The d-current reference depends on the current limit only.
        if self.config.limits.max_current_a != old_a {
            let keep = self.field;
            self.field = field_of(&self.config);
            self.field.keep_integrator(&keep);
        }
    }

    /// Replace the d-current reference's configuration (design §30);
    /// an unusable one is refused and nothing changes. The field-weakening
    /// integrator carries over (switching it off at speed takes effect
    /// once its d current is back at 0).
    pub fn set_field(&mut self, f: FieldConfig) -> Result<(), &'static str> {
        f.check()?;
        if f.field_weakening && self.config.angle.interpolation_half_count().is_some() {
            return Err(COARSE_FIELD_WEAKENING);
        }
        if f == self.config.field {
            // Nothing to derive (a stored record re-applied: the period
            // that applies it stays short, `cargo xtask bench`).
            return Ok(());
        }
        self.config.field = f;
        let keep = self.field;
        self.field = field_of(&self.config);
        self.field.keep_integrator(&keep);
        Ok(())
    }

    /// The d-current reference in force (design §30).
    pub fn field(&self) -> &Field {
        &self.field
    }

    /// The fault supervisor.
    pub fn supervisor(&self) -> &Supervisor {
        &self.supervisor
    }

    /// The rotor's mechanics for the speed observer: its torque input
    /// `kt / J` from the current loop's motor, and the friction (design
    /// §19). Unusable
    /// values ([`Mechanics::is_usable`]) change nothing and return false.
    pub fn set_mechanics(&mut self, m: &Mechanics) -> bool {
        let kt = self.config.current.motor.torque_constant_nm_per_a();
        let k = SpeedObserverConfig::accel_per_amp(kt, m.inertia_kg_m2);
        if !(m.is_usable() && k > 0.0) {
            return false;
        }
        self.config.observer = SpeedObserverConfig::for_mechanics(m, kt, self.config.observer.ts_s);
        self.observer.set_config(self.config.observer);
        self.mechanics = Some(*m);
        true
    }
}

/// Why field weakening is refused on a coarse angle sensor.
pub const COARSE_FIELD_WEAKENING: &str =
    "field weakening needs a fine angle sensor: a coarse one's (halls') half-count \
     uncertainty turns the weakening d current into q current";

/// The d-current reference of a stage configuration. Field weakening is
/// off on a coarse angle sensor (halls, interpolated): its half-count
/// window (30 deg electrical for halls) turns a large d current into an
/// unknown q current of half its size.
fn field_of(c: &CurrentStageConfig) -> Field {
    let cur = &c.current;
    let mut f = c.field;
    if c.angle.interpolation_half_count().is_some() {
        f.field_weakening = false;
    }
    Field::new(
        f,
        &cur.motor,
        c.limits.max_current_a,
        1.0 / cur.ts_s,
        cur.max_modulation,
    )
}

/// `max_current_a` not finite and non-negative -> 0.
fn sanitize_limits(mut l: Limits) -> Limits {
    if !(l.max_current_a >= 0.0 && l.max_current_a < f32::INFINITY) {
        l.max_current_a = 0.0;
    }
    l
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::control::MotorParams;
    use crate::drive::cascade::CascadeConfig;
    use std::vec::Vec;

    fn config() -> CurrentStageConfig {
        let motor = MotorParams {
            pole_pairs: 7,
            r_ohm: 0.2,
            ld_h: 100e-6,
            lq_h: 100e-6,
            flux_linkage_wb: 0.005,
        };
        CascadeConfig::for_motor(motor, 20_000.0, 10.0).current
    }

    fn sample() -> Sample {
        Sample {
            currents: Some(PhaseCurrents::TwoPhase { a_a: 0.0, b_a: 0.0 }),
            angle: Some(MechanicalAngle::ZERO),
            v_bus_v: Some(24.0),
            temperature_c: None,
        }
    }

    /// The board's dead-time compensation survives a permit without one
    /// (an identification's), and a permit with its own brings it.
    #[test]
    fn a_permit_without_a_dead_time_keeps_the_boards() {
        use crate::control::dead_time::DeadTimeCompensation;
        let mut c = config();
        let board = DeadTimeCompensation::for_current_limit(200e-9, 10.0);
        c.current.dead_time = board;
        let mut stage = CurrentStage::new(c);
        let identified = CurrentLoopConfig {
            dead_time: DeadTimeCompensation::OFF,
            ..c.current
        };
        let p = Calibrated::supplied(c.angle, identified).unwrap();
        stage.set_calibration(&p);
        assert_eq!(stage.config().current.dead_time, board);
        let other = DeadTimeCompensation::for_current_limit(500e-9, 10.0);
        let stored = CurrentLoopConfig {
            dead_time: other,
            ..c.current
        };
        stage.set_calibration(&Calibrated::supplied(c.angle, stored).unwrap());
        assert_eq!(stage.config().current.dead_time, other);
    }

    /// A calibrated stage in torque mode (0 A) on a sensor of `counts`
    /// per turn (8 pole pairs, zero offset 0).
    fn torque_stage(counts: u32) -> (CurrentStage, CommandSlot) {
        let mut c = config();
        c.current.motor.pole_pairs = 8;
        c.angle = AngleCalibration {
            pole_pairs: 8,
            zero_offset: ElectricalAngle::ZERO,
            reversed: false,
            sensor_counts_per_rev: counts,
            sensorless_only: false,
        };
        let mut st = CurrentStage::new(c);
        let permit = Calibrated::supplied(c.angle, c.current).unwrap();
        st.set_calibration(&permit);
        let mut slot = CommandSlot::INIT;
        slot.post(Command::Torque { iq_a: 0.0 });
        (st, slot)
    }

    /// The floor reading of a `counts` sensor at `turns` (mechanical).
    fn reading(turns: f64, counts: u32) -> MechanicalAngle {
        let q = (turns * counts as f64).floor() / counts as f64;
        MechanicalAngle::from_turns(q.rem_euclid(1.0) as f32)
    }

    /// Runs a true angle profile (`speed(k)` rad/s mechanical, 20 kHz)
    /// through a 48-count sensor; checks every Park angle lies within the
    /// reading's count window and returns (true, used) electrical angles.
    fn run_coarse(periods: usize, speed: impl Fn(usize) -> f64) -> Vec<(f64, f32)> {
        let (mut st, slot) = torque_stage(48);
        let mut turns = 0.3f64;
        let mut out = Vec::new();
        for k in 0..periods {
            turns += speed(k) / 20_000.0 / core::f64::consts::TAU;
            let mut s = sample();
            let raw = reading(turns, 48);
            s.angle = Some(raw);
            let th = st.step(&slot, 0.0, &s).1.theta_e;
            // Window [raw, raw + 1 count) in electrical degrees: 60 wide.
            let lo = raw.to_electrical(8);
            let off = th.wrapping_sub(lo).to_radians().to_degrees();
            assert!(off <= 60.0 + 1e-3, "period {k}: {off} deg into the window");
            let truth = (turns * 8.0 * 360.0).rem_euclid(360.0);
            out.push((truth, th.to_radians().to_degrees()));
        }
        out
    }

    fn err_deg(truth: f64, used: f32) -> f64 {
        (used as f64 - truth + 540.0).rem_euclid(360.0) - 180.0
    }

    /// At a steady speed the angle advances between the edges (never
    /// backwards) and follows the true angle far better than the reading.
    #[test]
    fn coarse_sensor_angle_advances_monotonically_within_the_window() {
        let v = run_coarse(8000, |_| 100.0);
        let mut worst: f64 = 0.0;
        for w in v[4000..].windows(2) {
            let step = err_deg(w[0].1 as f64, w[1].1); // used(k+1) - used(k)
            assert!(step >= -1e-3, "moved back by {step} deg");
            worst = worst.max(err_deg(w[1].0, w[1].1).abs());
        }
        // The reading (+ half a count) is up to 30 deg(e) off.
        assert!(worst < 12.0, "worst error {worst} deg(e)");
    }

    /// Standstill: the angle settles on the reading plus half a count.
    #[test]
    fn coarse_sensor_at_standstill_uses_the_reading_plus_half_a_count() {
        let v = run_coarse(6000, |k| if k < 2000 { 100.0 } else { 0.0 });
        let (truth, used) = v[5999];
        let centre = ((truth / 60.0).floor() * 60.0 + 30.0) % 360.0;
        assert!(err_deg(centre, used).abs() < 0.5, "{used} vs {centre}");
    }

    /// A reversal: the angle stays in the window (checked every period),
    /// and follows the new direction afterwards.
    #[test]
    fn coarse_sensor_reversal_stays_in_the_window() {
        let v = run_coarse(12_000, |k| if k < 4000 { 60.0 } else { -60.0 });
        let worst = v[9000..]
            .iter()
            .fold(0.0f64, |m, &(t, u)| m.max(err_deg(t, u).abs()));
        assert!(
            worst < 20.0,
            "worst error after the reversal {worst} deg(e)"
        );
    }

    /// The angle is clamped at the window's edge when the tracked speed
    /// runs ahead of the rotor (sudden stop: no edge comes).
    #[test]
    fn coarse_sensor_angle_is_clamped_at_the_window_edge() {
        let (mut st, slot) = torque_stage(48);
        let mut s = sample();
        let mut turns = 0.0f64;
        for _ in 0..4000 {
            turns += 150.0 / 20_000.0 / core::f64::consts::TAU;
            s.angle = Some(reading(turns, 48));
            st.step(&slot, 0.0, &s);
        }
        // Stopped just after an edge: the tracker still runs at 150 rad/s.
        let raw = reading(turns, 48);
        s.angle = Some(raw);
        let mut max_off: f32 = 0.0;
        for _ in 0..40 {
            let th = st.step(&slot, 0.0, &s).1.theta_e;
            let off = th
                .wrapping_sub(raw.to_electrical(8))
                .to_radians()
                .to_degrees();
            max_off = max_off.max(off);
        }
        assert!((max_off - 60.0).abs() < 0.1, "reached {max_off} deg");
    }

    /// A fine encoder (64 counts per electrical turn and more) is not
    /// interpolated: the reading plus half a count, bit for bit.
    #[test]
    fn fine_encoder_uses_the_reading_bit_for_bit() {
        for counts in [0u32, 512, 4096] {
            let (mut st, slot) = torque_stage(counts);
            assert_eq!(st.config().angle.interpolation_half_count(), None);
            let mut turns = 0.1f64;
            for _ in 0..2000 {
                turns += 200.0 / 20_000.0 / core::f64::consts::TAU;
                let mut s = sample();
                let raw = if counts == 0 {
                    MechanicalAngle::from_turns(turns.rem_euclid(1.0) as f32)
                } else {
                    reading(turns, counts)
                };
                s.angle = Some(raw);
                let th = st.step(&slot, 0.0, &s).1.theta_e;
                let a = st.config().angle;
                assert_eq!(th, a.electrical(a.mechanical(raw)));
            }
        }
        assert!(torque_stage(48)
            .0
            .config()
            .angle
            .interpolation_half_count()
            .is_some());
        assert!(torque_stage(511)
            .0
            .config()
            .angle
            .interpolation_half_count()
            .is_some());
    }

    fn open_loop(v_d_v: f32, theta_deg: f32, omega_e_rad_s: f32) -> Command {
        Command::OpenLoop {
            v_d_v,
            v_q_v: 0.0,
            theta_e: ElectricalAngle::from_degrees(theta_deg),
            omega_e_rad_s,
        }
    }

    fn deg(a: ElectricalAngle) -> f32 {
        a.to_signed_radians().to_degrees()
    }

    /// A second open-loop command with a new angle moves the field there at
    /// once (it used to keep running from the old angle).
    #[test]
    fn open_loop_takes_a_new_angle_while_in_open_loop() {
        let mut st = CurrentStage::new(config());
        let mut slot = CommandSlot::INIT;
        slot.post(open_loop(1.0, 90.0, 0.0));
        let (_, fb) = st.step(&slot, 0.0, &sample());
        assert!((deg(fb.theta_e) - 90.0).abs() < 1e-3);
        slot.post(open_loop(1.0, 0.0, 0.0));
        let (_, fb) = st.step(&slot, 0.0, &sample());
        assert!(deg(fb.theta_e).abs() < 1e-3, "at {} deg", deg(fb.theta_e));
        // Same angle again, other voltage: nothing to re-position.
        slot.post(open_loop(2.0, 0.0, 0.0));
        let (_, fb) = st.step(&slot, 0.0, &sample());
        assert!(deg(fb.theta_e).abs() < 1e-3);
    }

    /// A command that changes only the voltage or the speed of a spinning
    /// field keeps the running angle (continuous rotation).
    #[test]
    fn open_loop_voltage_change_keeps_the_running_angle() {
        let mut st = CurrentStage::new(config());
        let mut slot = CommandSlot::INIT;
        let w = 1000.0; // rad/s electrical: 0.05 rad per period
        slot.post(open_loop(1.0, 0.0, w));
        let mut last = ElectricalAngle::ZERO;
        for _ in 0..10 {
            last = st.step(&slot, 0.0, &sample()).1.theta_e;
        }
        for cmd in [open_loop(1.5, 0.0, w), open_loop(1.5, 0.0, 1.2 * w)] {
            slot.post(cmd);
            let th = st.step(&slot, 0.0, &sample()).1.theta_e;
            let step = th.diff_radians(last);
            assert!(
                (step - w / 20_000.0).abs() < 1e-3 * w / 20_000.0 + 1e-6,
                "jumped by {step} rad"
            );
            last = th;
        }
    }
}
