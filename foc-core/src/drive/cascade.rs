//! The whole cascade stepped in one place, in the firmware's order.
//!
//! The firmware runs the three stages as separate prioritised tasks; this
//! struct runs the very same stages in the same order for the simulator,
//! the SIL runner and tests: every period the current stage, then (every N)
//! the speed stage, then (every M) the position stage, each slower stage's
//! output being used from the next period on, exactly as when the current
//! task pends the lower-priority tasks and returns.

use super::{ConfigChange, Inputs, Lifecycle, LifecycleConfig, Output};
use crate::angle::ElectricalAngle;
use crate::control::current::CurrentLoopConfig;
use crate::control::estimator::{AngleTrackerConfig, SpeedObserverConfig};
use crate::control::field::FieldConfig;
use crate::control::homing::{Homing, HomingError, HomingMethod, HomingStep};
use crate::control::joint::{JointConfig, JointError, JointSetup, OutputFrame, TravelConfig};
use crate::control::model::ModelTolerances;
use crate::control::permit::Calibrated;
use crate::control::position::PositionLoopConfig;
use crate::control::speed::SpeedLoopConfig;
use crate::control::stage::{
    AngleCalibration, CurrentStage, CurrentStageConfig, PositionStage, Sample, SpeedStage,
    TimeoutReaction, VelocityRef,
};
use crate::control::supervisor::{Fault, SupervisorConfig};
use crate::control::{
    BridgeCommand, Command, CommandError, CommandSlot, Feedback, Limits, Mechanics, MotorParams,
    Rates,
};
use crate::frames::Abc;

/// The angle tracker's bandwidth [rad/s] (80 Hz).
pub const TRACKER_BANDWIDTH_RAD_S: f32 = 2.0 * core::f32::consts::PI * 80.0;

pub use crate::control::estimator::{OBSERVER_DISTURBANCE_POLE_RAD_S, OBSERVER_POLE_RAD_S};

/// Configuration of the whole cascade.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CascadeConfig {
    /// Loop rates.
    pub rates: Rates,
    /// Current stage (current loop, tracker, supervisor, limits, angle).
    pub current: CurrentStageConfig,
    /// Speed loop.
    pub speed: SpeedLoopConfig,
    /// Position loop.
    pub position: PositionLoopConfig,
    /// The rotor's mechanics the speed and position loops and the speed
    /// observer were derived from ([`Self::set_mechanics`]); `None`: not
    /// known (no torque input to the observer).
    pub mechanics: Option<Mechanics>,
}

impl CascadeConfig {
    /// The joint's travel defaults for this cascade
    /// ([`TravelConfig::defaults`] with its torque constant, current limit,
    /// mechanics, position-loop acceleration and speed-loop gain).
    pub fn default_travel(&self) -> TravelConfig {
        TravelConfig::defaults(
            self.current.current.motor.torque_constant_nm_per_a(),
            self.current.limits.max_current_a,
            self.mechanics,
            self.position.max_acceleration_rad_s2,
            self.speed.kp_a_per_rad_s,
        )
    }

    /// Reasonable defaults for a motor: source tuning of the current loop
    /// (technical optimum), speed loop at about 1/20 of the current-loop
    /// bandwidth for an assumed small inertia, position loop a fifth of that,
    /// supervisor at 1.5x the current limit (stuck-sensor / stall check:
    /// reading still for 20 ms with half the current limit demanded). `angle` is a placeholder (zero
    /// offset, not reversed): a cascade refuses closed-loop commands until
    /// a [`Calibrated`] permit is installed ([`Cascade::set_calibration`]).
    /// With the inertia unknown ([`Self::clear_mechanics`]) the speed
    /// estimate has no model and the speed loop no feed-forward (a guessed
    /// inertia would make both wrong by orders of magnitude).
    pub fn for_motor(motor: MotorParams, pwm_frequency_hz: f32, max_current_a: f32) -> Self {
        let mut c = Self::for_motor_with_inertia(motor, pwm_frequency_hz, max_current_a, 1e-5);
        c.clear_mechanics();
        c
    }

    /// As [`Self::for_motor`] with the rotor (plus load) inertia [kg m^2]:
    /// the speed gains, the speed loop's reference model and the
    /// position's acceleration feed-forward from it, and the speed
    /// estimate's torque input `kt / J` (design §19).
    pub fn for_motor_with_inertia(
        motor: MotorParams,
        pwm_frequency_hz: f32,
        max_current_a: f32,
        inertia_kg_m2: f32,
    ) -> Self {
        let rates = Rates::for_pwm(pwm_frequency_hz);
        let kt = motor.torque_constant_nm_per_a();
        let speed_bw = SPEED_BANDWIDTH_RAD_S;
        let max_velocity = 1.0e4;
        let mut c = Self {
            rates,
            current: CurrentStageConfig {
                current: CurrentLoopConfig::technical_optimum(motor, pwm_frequency_hz),
                tracker: AngleTrackerConfig::with_bandwidth(
                    TRACKER_BANDWIDTH_RAD_S,
                    rates.current_ts_s(),
                ),
                observer: SpeedObserverConfig::new(
                    OBSERVER_POLE_RAD_S,
                    OBSERVER_DISTURBANCE_POLE_RAD_S,
                    rates.current_ts_s(),
                    SpeedObserverConfig::accel_per_amp(kt, inertia_kg_m2),
                ),
                supervisor: SupervisorConfig {
                    max_phase_current_a: 1.5 * max_current_a,
                    max_vector_current_a: 1.5 * max_current_a,
                    // Stuck sensor / stall: reading still for 20 ms with at
                    // least half the current limit demanded to move.
                    stuck_periods: (0.02 * pwm_frequency_hz) as u32,
                    stuck_current_a: 0.5 * max_current_a,
                    // Over-speed a fifth above the velocity limit; runaway
                    // over 100 ms windows.
                    max_speed_rad_s: 1.2 * max_velocity,
                    runaway_periods: (0.1 * pwm_frequency_hz) as u32,
                    // Current sense and angle from the motor model
                    // (design §24): floor 2 % of the current limit.
                    model: ModelTolerances::for_current_limit(max_current_a),
                    // Its back-up: tracking error above 15 % of the
                    // current limit for 2 ms off the voltage limit.
                    tracking_band_a: 0.15 * max_current_a,
                    tracking_periods: (0.002 * pwm_frequency_hz) as u32,
                    ..SupervisorConfig::default()
                },
                limits: Limits {
                    max_current_a,
                    max_velocity_rad_s: max_velocity,
                    min_position_rad: -1.0e5,
                    max_position_rad: 1.0e5,
                    max_open_loop_voltage_v: 60.0,
                    max_open_loop_omega_e_rad_s: 1.0e4,
                    // Full current for 0.01 rad or 1 rad/s of error.
                    max_kp_nm_per_rad: kt * max_current_a / 0.01,
                    max_kd_nm_s_per_rad: kt * max_current_a,
                },
                angle: AngleCalibration {
                    pole_pairs: motor.pole_pairs,
                    zero_offset: ElectricalAngle::ZERO,
                    reversed: false,
                    sensor_counts_per_rev: 0,
                    sensorless_only: false,
                },
                command_timeout_periods: 0,
                timeout_reaction: TimeoutReaction::Disable,
                power: None,
                joint: JointConfig::for_pwm(pwm_frequency_hz),
                sensorless: None,
                fallback: None,
                field: FieldConfig::for_motor(&motor, max_current_a, pwm_frequency_hz),
            },
            speed: SpeedLoopConfig::from_bandwidth(
                inertia_kg_m2,
                kt,
                speed_bw,
                rates.speed_ts_s(),
                max_current_a,
            ),
            position: PositionLoopConfig {
                ts_s: rates.position_ts_s(),
                kp_per_s: speed_bw * POSITION_GAIN_RATIO,
                max_velocity_rad_s: 100.0,
                max_acceleration_rad_s2: 1000.0,
                accel_ff_a_per_rad_s2: if kt > 0.0 { inertia_kg_m2 / kt } else { 0.0 },
            },
            mechanics: None,
        };
        c.set_mechanics(&Mechanics::inertia(inertia_kg_m2));
        c
    }

    /// Forget the rotor's mechanics: the speed observer without a model
    /// (the 80 Hz tracker's loop), and no acceleration or disturbance
    /// feed-forward in the speed loop (the gains stay).
    pub fn clear_mechanics(&mut self) {
        let ts = self.current.observer.ts_s;
        self.current.observer = SpeedObserverConfig::tracker_like(TRACKER_BANDWIDTH_RAD_S, ts);
        self.speed.accel_ff_a_per_rad_s2 = 0.0;
        self.mechanics = None;
    }

    /// Install the rotor's mechanics (design §19): the speed loop's gains
    /// for its bandwidth ([`SPEED_BANDWIDTH_RAD_S`]) on this inertia, its
    /// reference model's feed-forward, the position loop's acceleration
    /// feed-forward, and the speed observer's model: torque input
    /// `kt / J` and friction (with stiction at rest). The friction is in
    /// the observer's model only: what the model does not explain is the
    /// disturbance the speed loop cancels, and a rotor at rest is not
    /// pushed by a friction that stiction holds. Unusable values
    /// ([`Mechanics::is_usable`]) change nothing and return false.
    pub fn set_mechanics(&mut self, m: &Mechanics) -> bool {
        let kt = self.current.current.motor.torque_constant_nm_per_a();
        if !(m.is_usable() && kt > 0.0 && kt.is_finite()) {
            return false;
        }
        let ts = self.current.observer.ts_s;
        let j = m.inertia_kg_m2;
        self.speed = SpeedLoopConfig::from_bandwidth(
            j,
            kt,
            SPEED_BANDWIDTH_RAD_S,
            self.speed.ts_s,
            self.speed.current_limit_a,
        );
        self.position.accel_ff_a_per_rad_s2 = j / kt;
        self.current.observer = SpeedObserverConfig::for_mechanics(m, kt, ts);
        self.mechanics = Some(*m);
        true
    }
}

/// The position loop's gain over the speed loop's bandwidth (design §19).
pub const POSITION_GAIN_RATIO: f32 = 0.25;

/// The speed loop's bandwidth [rad/s] (design §19): 20 Hz, at most a
/// fortieth of the current loop's on every motor file of the bench, well
/// inside the speed observer's poles and the speed loop's rate.
pub const SPEED_BANDWIDTH_RAD_S: f32 = 2.0 * core::f32::consts::PI * 20.0;

/// All three stages and the drive's [`Lifecycle`] (which keeps the rate
/// dividers). [`Cascade::new`] starts disabled, uncalibrated and already
/// started (offsets taken as calibrated): closed-loop commands are refused
/// with [`CommandError::NotCalibrated`] until [`Cascade::set_calibration`].
/// [`Cascade::from_reset`] starts where the firmware does, with the offset
/// calibration.
#[derive(Clone, Copy, Debug)]
pub struct Cascade {
    config: CascadeConfig,
    /// Current stage.
    pub current: CurrentStage,
    /// Speed stage.
    pub speed: SpeedStage,
    /// Position stage.
    pub position: PositionStage,
    life: Lifecycle,
    slot: CommandSlot,
    change: Option<ConfigChange>,
    /// The encoder's index reading for the next step (design §33).
    index: Option<crate::angle::MechanicalAngle>,
    iq_ref_a: f32,
    w_ref: VelocityRef,
    output: Option<Output>,
    /// The feedback published (written in place by the lifecycle).
    feedback: Feedback,
    /// The joint's output frame and travel range (design §21).
    joint: JointSetup,
    /// The position range without travel limits (the build's).
    unbounded_rad: (f32, f32),
    /// A homing running, with the output position of its home point.
    homing: Option<(Homing, f32)>,
    /// How the last homing ended.
    homing_result: Option<Result<(), HomingError>>,
}

impl Cascade {
    /// New cascade, disabled, started (no offset calibration, no
    /// identification available).
    pub fn new(config: CascadeConfig) -> Self {
        let life = LifecycleConfig {
            offsets: None,
            sensor_check_reads: 0,
            identification: None,
            identify_at_start_up: false,
            speed_divider: config.rates.speed_divider,
            position_divider: config.rates.position_divider,
            angle_kind: crate::drive::AngleKind::Incremental,
            stored: None,
        };
        Self::with_lifecycle(config, Lifecycle::started(life))
    }

    /// New cascade from reset, as the firmware starts: offset calibration
    /// (the caller installs [`Self::take_offsets`] in its current sensing),
    /// sensor check, then the identification if `life` asks for it. The
    /// dividers are `life`'s.
    pub fn from_reset(config: CascadeConfig, life: LifecycleConfig) -> Self {
        Self::with_lifecycle(config, Lifecycle::new(life))
    }

    fn with_lifecycle(config: CascadeConfig, life: Lifecycle) -> Self {
        Self {
            config,
            current: CurrentStage::new(config.current),
            speed: SpeedStage::new(config.speed),
            position: PositionStage::new(config.position),
            life,
            slot: CommandSlot::INIT,
            change: None,
            index: None,
            iq_ref_a: 0.0,
            w_ref: VelocityRef::default(),
            output: None,
            feedback: Feedback::INIT,
            joint: JointSetup {
                frame: OutputFrame::IDENTITY,
                travel_out_rad: None,
                travel: config.default_travel(),
                joint: config.current.joint,
            },
            unbounded_rad: (
                config.current.limits.min_position_rad,
                config.current.limits.max_position_rad,
            ),
            homing: None,
            homing_result: None,
        }
    }

    /// The joint's setup (output frame, travel range).
    pub fn joint(&self) -> &JointSetup {
        &self.joint
    }

    /// Set the joint up (output frame, travel range at the output): the
    /// rotor-frame range and travel limits are requested from the stage
    /// (taken at the next step in any mode, see
    /// [`crate::drive::JointChange`]).
    pub fn set_joint(&mut self, setup: JointSetup) -> Result<(), JointError> {
        setup.validate()?;
        self.joint = setup;
        self.request(ConfigChange {
            joint: Some(setup.rotor_change(self.unbounded_rad)),
            ..ConfigChange::default()
        });
        Ok(())
    }

    /// Start homing (design §21); `home_output_rad` is the output position
    /// of the home point. Runs at the position loop's rate; see
    /// [`Self::homing_result`]. The travel limits are off while it runs
    /// (they are in a frame homing is about to move) and back when it ends.
    pub fn start_homing(
        &mut self,
        method: HomingMethod,
        home_output_rad: f32,
    ) -> Result<(), HomingError> {
        if !home_output_rad.is_finite() {
            return Err(HomingError::Invalid(CommandError::NonFinite));
        }
        let l = self.current.config().limits;
        let kt = self
            .current
            .config()
            .current
            .motor
            .torque_constant_nm_per_a();
        let h = Homing::new(method, &l, kt, self.config.rates.current_ts_s())?;
        self.homing = Some((h, home_output_rad));
        self.homing_result = None;
        let free = JointSetup {
            travel_out_rad: None,
            ..self.joint
        };
        self.request(ConfigChange {
            joint: Some(free.rotor_change(self.unbounded_rad)),
            ..ConfigChange::default()
        });
        Ok(())
    }

    /// How the last homing ended (`None` while one runs or before any).
    pub fn homing_result(&self) -> Option<Result<(), HomingError>> {
        self.homing_result
    }

    /// True while homing runs.
    pub fn is_homing(&self) -> bool {
        self.homing.is_some()
    }

    fn step_homing(&mut self) {
        let Some((mut h, home_out)) = self.homing else {
            return;
        };
        let l = self.current.config().limits;
        let end = match h.step(&self.feedback, &l) {
            HomingStep::Post(cmd) => self
                .command(cmd)
                .err()
                .map(|e| Err(HomingError::Invalid(e))),
            HomingStep::Running => None,
            HomingStep::Done { home_rotor_rad } => {
                Some(match self.joint.frame.homed_at(home_rotor_rad, home_out) {
                    Some(frame) => {
                        let setup = JointSetup {
                            frame,
                            ..self.joint
                        };
                        self.set_joint(setup)
                            .map_err(|_| HomingError::Invalid(CommandError::NonFinite))
                    }
                    None => Err(HomingError::Invalid(CommandError::NonFinite)),
                })
            }
            HomingStep::Failed(e) => Some(Err(e)),
        };
        if let Some(r) = end {
            if r.is_err() {
                self.slot.post(Command::Disable);
                // The travel limits back, in the frame they were set in.
                let _ = self.set_joint(self.joint);
            }
            self.homing = None;
            self.homing_result = Some(r);
        } else {
            self.homing = Some((h, home_out));
        }
    }

    /// The drive's lifecycle.
    pub fn lifecycle(&self) -> &Lifecycle {
        &self.life
    }

    /// The lifecycle, to configure it (e.g. its index search, design §33).
    pub fn lifecycle_mut(&mut self) -> &mut Lifecycle {
        &mut self.life
    }

    /// The reading the encoder latched at its index pulse, for the next
    /// step (what `AngleSensor::take_index` gives the firmware's drive).
    pub fn set_index(&mut self, index: Option<crate::angle::MechanicalAngle>) {
        self.index = index;
    }

    /// Ask for a configuration change (applied, or refused whole, at the
    /// start of the next step: see [`Self::last_output`]'s `change`).
    pub fn request(&mut self, change: ConfigChange) {
        let mut c = self.change.unwrap_or_default();
        c.merge(change);
        self.change = Some(c);
    }

    /// A calibration (offsets, identification, anticogging) is requested
    /// and not yet taken by a step.
    pub fn calibration_pending(&self) -> bool {
        self.change.is_some_and(|c| {
            c.identify || c.calibrate_offsets || c.calibrate_cogging || c.calibrate_encoder
        })
    }

    /// The lifecycle's output of the last step.
    pub fn last_output(&self) -> Option<&Output> {
        self.output.as_ref()
    }

    /// Offsets \[A\] the last step asked to install in the current sensing.
    pub fn take_offsets(&mut self) -> Option<Abc> {
        self.output.as_mut().and_then(|o| o.offsets_a.take())
    }

    /// The operator's command mailbox.
    pub fn mailbox(&self) -> &CommandSlot {
        &self.slot
    }

    /// The configuration: as built, with the current stage's calibration,
    /// limits and the dividers as the lifecycle last changed them.
    pub fn config(&self) -> &CascadeConfig {
        &self.config
    }

    /// Post a command (validated now; the current stage re-checks it).
    ///
    /// While a fault is latched only `Disable` is accepted, unless a clear
    /// is pending ([`Self::clear_faults`] not yet taken effect): the current
    /// stage performs the clear first and then takes the command, in the
    /// same step (if the fault condition persists it trips again at once).
    pub fn command(&mut self, cmd: Command) -> Result<(), CommandError> {
        let mut status = self.life.status(&self.current);
        status.faulted &= !self.current.clear_pending(&self.slot);
        status.check_command(&cmd, &self.current.config().limits)?;
        self.slot.post(cmd);
        Ok(())
    }

    /// Install a calibration permit in the current stage (angle
    /// calibration and current-loop configuration; the configuration
    /// returned by [`Self::config`] follows). Unlocks the closed-loop modes.
    pub fn set_calibration(&mut self, c: &Calibrated) {
        self.current.set_calibration(c);
        self.config.current.angle = c.angle();
        self.config.current.current = c.current_config();
    }

    /// True once a calibration permit is installed.
    pub fn is_calibrated(&self) -> bool {
        self.current.is_calibrated()
    }

    /// Request a fault clear (takes effect at the next step).
    pub fn clear_faults(&mut self) {
        self.slot.request_clear();
    }

    /// Latch a fault found outside the loops (e.g. overrun).
    pub fn report_fault(&mut self, f: Fault) {
        self.current.report_fault(f);
    }

    /// The feedback of the last step.
    pub fn feedback(&self) -> &Feedback {
        &self.feedback
    }

    /// The drive's status as its rules judge commands and changes.
    pub fn status(&self) -> super::Status {
        self.life.status(&self.current)
    }

    /// The q-current reference from the speed stage \[A\].
    pub fn iq_ref_a(&self) -> f32 {
        self.iq_ref_a
    }

    /// The velocity reference from the position stage.
    pub fn velocity_ref(&self) -> VelocityRef {
        self.w_ref
    }

    /// One PWM period: the lifecycle (and through it the current stage),
    /// then the slower stages it schedules, in the firmware's order.
    pub fn step(&mut self, sample: &Sample) -> BridgeCommand {
        let change = self.change.take();
        let mut inputs = Inputs::new(self.slot, self.iq_ref_a);
        inputs.change = change.as_ref();
        inputs.index = self.index.take();
        let out = self
            .life
            .step(&mut self.current, &inputs, sample, &mut self.feedback);
        let fb = self.feedback;
        if out.run_speed {
            self.iq_ref_a = self.speed.step(&fb, self.w_ref);
        }
        if out.run_position {
            self.w_ref = self.position.step(&fb);
            self.step_homing();
        }
        if let Some(crate::drive::Event::Identified(r)) = out.event {
            // The measured mechanics (design §19): the speed and position
            // loops re-derived from them (the stage's observer already is).
            if let Some(m) = r.mechanics {
                let mut c = self.config;
                c.current = *self.current.config();
                if c.set_mechanics(&Mechanics::from(m)) {
                    self.speed.speed_loop().set_config(c.speed);
                    self.position.set_config(c.position);
                    self.config.speed = c.speed;
                    self.config.position = c.position;
                    self.config.mechanics = c.mechanics;
                }
            }
        }
        if out.event.is_some() || matches!(out.change, Some(Ok(()))) {
            // An identification or a change moved the stage's calibration,
            // limits or dividers: keep `config()` in step with it.
            self.config.current = *self.current.config();
            let (n, m) = self.life.dividers();
            self.config.rates.speed_divider = n as u16;
            self.config.rates.position_divider = m as u16;
        }
        self.output = Some(out);
        out.bridge
    }
}

/// A thin wrapper: a [`Cascade`] built with a [`Calibrated`] permit
/// already installed (`Cascade::new` + `Cascade::set_calibration`).
#[derive(Clone, Copy, Debug)]
pub struct CalibratedCascade {
    inner: Cascade,
}

impl CalibratedCascade {
    /// The cascade of `config` with the permit's angle calibration and
    /// current-loop configuration installed (closed-loop modes unlocked).
    pub fn new(config: CascadeConfig, permit: &Calibrated) -> Self {
        let mut inner = Cascade::new(config);
        inner.set_calibration(permit);
        Self { inner }
    }

    /// Post a command (see `Cascade::command`).
    pub fn command(&mut self, cmd: Command) -> Result<(), CommandError> {
        self.inner.command(cmd)
    }

    /// One PWM period (see `Cascade::step`).
    pub fn step(&mut self, sample: &Sample) -> BridgeCommand {
        self.inner.step(sample)
    }

    /// The feedback of the last step.
    pub fn feedback(&self) -> &Feedback {
        self.inner.feedback()
    }

    /// Request a fault clear.
    pub fn clear_faults(&mut self) {
        self.inner.clear_faults();
    }

    /// Latch a fault found outside the loops.
    pub fn report_fault(&mut self, f: Fault) {
        self.inner.report_fault(f);
    }

    /// Read access to the cascade.
    pub fn cascade(&self) -> &Cascade {
        &self.inner
    }

    /// The cascade itself.
    pub fn into_inner(self) -> Cascade {
        self.inner
    }
}
