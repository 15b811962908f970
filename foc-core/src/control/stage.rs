//! The three stages of the cascade: loops plus mode logic (see [`super`]).

use super::current::{CurrentLoop, CurrentLoopConfig, CurrentLoopInput, CurrentLoopOutput};
use super::estimator::{AngleTracker, AngleTrackerConfig, SpeedObserver, SpeedObserverConfig};
use super::joint::JointChange;
use super::joint::{Impedance, ImpedanceLaw, JointConfig};
use super::model::{ModelCheck, Period, Verdict};
use super::permit::Calibrated;
use super::position::{PositionLoop, PositionLoopConfig};
use super::power::{PowerInputs, PowerLimitsConfig, PowerReport, PowerStage};
use super::speed::{SpeedLoop, SpeedLoopConfig};
use super::supervisor::{Checks, Fault, Supervisor, SupervisorConfig};
use super::Refusal;
use super::{BridgeCommand, Command, CommandSlot, Feedback, Limits, Mechanics, Mode};
use crate::angle::{ElectricalAngle, MechanicalAngle};
use crate::clamp;
use crate::frames::Dq;
use crate::hal::PhaseCurrents;
use crate::transforms;

/// Coarse-sensor threshold [counts per electrical turn]: below it the
/// current stage interpolates the angle between the sensor's edges (the
/// tracker's angle, kept within the reading's count window); at or above it
/// (encoders) it uses the reading itself.
pub const INTERPOLATE_BELOW_COUNTS_PER_E_TURN: u32 = 64;

/// How the angle sensor relates to the motor's electrical angle.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AngleCalibration {
    /// Pole pairs.
    pub pole_pairs: u8,
    /// Electrical angle the sensor reads (after direction and pole-pair
    /// scaling) when the rotor d axis is on phase A.
    pub zero_offset: ElectricalAngle,
    /// True when the sensor counts backwards relative to A -> B -> C.
    pub reversed: bool,
    /// Counts per mechanical turn of a counting sensor, 0 if unknown or not
    /// counting. A count `n` means the sensor is somewhere in `[n, n + 1)`:
    /// with the resolution known, half a count is added to every reading, so
    /// the angle used is unbiased (this matters for coarse sensors: 30 deg(e)
    /// for 48 counts on 8 pole pairs) and the zero offset is the physical one.
    /// Below [`INTERPOLATE_BELOW_COUNTS_PER_E_TURN`] counts per electrical
    /// turn the current stage also interpolates between the edges
    /// ([`Self::interpolation_half_count`]).
    pub sensor_counts_per_rev: u32,
}

impl AngleCalibration {
    /// Mechanical angle in the motor's positive direction (half a count
    /// added first when the sensor's resolution is known).
    #[inline]
    pub fn mechanical(&self, raw: MechanicalAngle) -> MechanicalAngle {
        let raw = match self.sensor_counts_per_rev {
            0 => raw,
            n => raw.wrapping_add(MechanicalAngle::from_bits(0x8000_0000 / n)),
        };
        if self.reversed {
            MechanicalAngle::from_bits(raw.to_bits().wrapping_neg())
        } else {
            raw
        }
    }
    /// Half a count [mechanical angle bits] when the current stage
    /// interpolates the angle between the sensor's edges: a counting sensor
    /// of known resolution coarser than [`INTERPOLATE_BELOW_COUNTS_PER_E_TURN`]
    /// counts per electrical turn (halls, the hub motor's 48 counts on 8
    /// pole pairs). `None`: the reading (plus half a count) is used as is.
    #[inline]
    pub fn interpolation_half_count(&self) -> Option<u32> {
        let n = self.sensor_counts_per_rev;
        let pp = u32::from(self.pole_pairs.max(1));
        (n > 0 && n < INTERPOLATE_BELOW_COUNTS_PER_E_TURN * pp).then(|| 0x8000_0000 / n)
    }
    /// `estimate` kept within the count window of the reading `mech` (a
    /// [`Self::mechanical`] angle, so the centre of the window): the true
    /// angle is within half a count of it either way.
    #[inline]
    pub fn within_count(
        mech: MechanicalAngle,
        estimate: MechanicalAngle,
        half_count: u32,
    ) -> MechanicalAngle {
        let h = half_count.min(i32::MAX as u32) as i32;
        let e = estimate.to_bits().wrapping_sub(mech.to_bits()) as i32;
        mech.wrapping_add(MechanicalAngle::from_bits(e.clamp(-h, h) as u32))
    }
    /// Electrical angle of the d axis from a direction-corrected mechanical angle.
    #[inline]
    pub fn electrical(&self, mech: MechanicalAngle) -> ElectricalAngle {
        mech.to_electrical(self.pole_pairs)
            .wrapping_sub(self.zero_offset)
    }
}

/// What to do when commands stop arriving.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TimeoutReaction {
    /// Latch [`Fault::CommandTimeout`] (bridge off).
    Disable,
    /// Switch to velocity 0.
    Stop,
    /// Hold the current position.
    Hold,
}

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
}

/// One period's measurements; `None` where the read failed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Phase currents [A].
    pub currents: Option<PhaseCurrents>,
    /// Raw mechanical angle from the sensor.
    pub angle: Option<MechanicalAngle>,
    /// Bus voltage [V].
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
    /// dq voltage of the last period [V] (bumpless open -> closed loop).
    pub last_out_v_dq: Dq,
    /// dq current of the last period [A].
    pub last_i_dq: Dq,
    /// Periods stepped (wraps).
    pub period: u32,
    /// Commands refused so far.
    pub rejected: u32,
    /// A calibration permit is installed (closed-loop modes unlocked).
    pub calibrated: bool,
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
    /// The speed stage's q-current reference as the current loop uses it,
    /// interpolated over the speed-loop period [A] (design §19).
    pub iq_interp_a: f32,
    /// Its change per period towards `iq_target_a` [A].
    pub iq_step_a: f32,
    /// The speed stage's last output [A].
    pub iq_target_a: f32,
    /// `1 / N`, N the periods per speed-loop step
    /// ([`CurrentStage::set_speed_periods`]).
    pub speed_inv_periods: f32,
    /// N itself.
    pub speed_periods: u32,
    /// The impedance law of the active impedance command (design §21).
    pub impedance: ImpedanceLaw,
    /// Bumpless entry into impedance mode: the current the blend starts
    /// from [A] ...
    pub blend_from_a: f32,
    /// ... its weight now (1 -> 0) ...
    pub blend_weight: f32,
    /// ... and the weight's decrease per period.
    pub blend_step: f32,
    /// A command timeout in impedance mode switched to damping only; the
    /// next one disables.
    pub timeout_damping: bool,
    /// The travel limits' q-current window of this period [A], when they
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
            period: 0,
            rejected: 0,
            calibrated: false,
            last_raw: None,
            interpolation,
            last_interp: MechanicalAngle::ZERO,
            last_innovation_rad: 0.0,
            unchanged_periods: 0,
            speed_at_change_rad_s: 0.0,
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
            speed_inv_periods: self.speed_inv_periods,
            speed_periods: self.speed_periods,
            ..Self::new(self.interpolation)
        };
    }
}

/// The current stage: runs every PWM period at the highest priority.
#[derive(Clone, Copy, Debug)]
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
    power: Option<PowerStage>,
    /// Their report of this period.
    power_report: PowerReport,
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
            power: config.power.map(PowerStage::new),
            power_report: PowerReport::unlimited(config.limits.max_current_a),
        }
    }

    /// Configure (or switch off, `None`) the power limits (design §18).
    /// Their motor model is the current loop's (`cfg.motor` is replaced).
    /// A stage that already had power limits keeps its winding estimate
    /// (reconfiguring does not cool the winding); the first configuration
    /// starts it at the ambient temperature.
    pub fn set_power_limits(&mut self, cfg: Option<PowerLimitsConfig>) {
        let motor = self.config.current.motor;
        let cfg = cfg.map(|c| PowerLimitsConfig { motor, ..c });
        self.config.power = cfg;
        self.power = match (cfg, self.power.as_ref()) {
            (Some(c), Some(old)) => Some(old.reconfigured(c)),
            (Some(c), None) => Some(PowerStage::new(c)),
            (None, _) => None,
        };
    }

    /// Step the brake chopper alone, for a period in which [`Self::step`]
    /// does not run (the drive's start-up calibrations, bridge off);
    /// nothing without power limits.
    pub fn step_brake(&mut self, v_bus_v: Option<f32>) {
        if let Some(p) = self.power.as_mut() {
            self.power_report.brake_on = p.step_chopper(v_bus_v, self.config.current.ts_s);
            self.power_report.brake_locked = p.brake_locked_out();
        }
    }

    /// The power limits' brake chopper conducts (false without power
    /// limits).
    #[inline]
    pub fn brake_on(&self) -> bool {
        self.power.is_some() && self.power_report.brake_on
    }

    /// The power limits' report of the last period (the current limit's
    /// window without power limits).
    pub fn power_report(&self) -> PowerReport {
        if self.power.is_some() {
            self.power_report
        } else {
            PowerReport::unlimited(self.config.limits.max_current_a)
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
    }

    /// The configuration.
    pub fn config(&self) -> &CurrentStageConfig {
        &self.config
    }

    /// Install a calibration permit: its angle calibration (the angle
    /// tracker restarts) and its current-loop configuration. Unlocks the
    /// closed-loop modes. This is the only way to unlock them.
    pub fn set_calibration(&mut self, c: &Calibrated) {
        self.config.angle = c.angle();
        self.state.interpolation = self.config.angle.interpolation_half_count();
        self.state.last_innovation_rad = 0.0;
        self.supervisor.set_angle_resolution(
            self.config.angle.pole_pairs,
            self.config.angle.sensor_counts_per_rev,
        );
        self.tracker.reset();
        self.observer.reset();
        let cur = c.current_config();
        self.config.current = cur;
        self.current.set_config(cur);
        if let Some(p) = self.power.as_mut() {
            p.set_motor(cur.motor);
        }
        self.state.calibrated = true;
        self.rederive_mechanics();
        self.rebuild_model();
    }

    /// The model check for the present motor, period and angle sensor (its
    /// healthy margin kept).
    fn rebuild_model(&mut self) {
        let peaks = self.model.peaks_sq();
        self.model = model_check(&self.config);
        self.model.keep_peaks(peaks);
    }

    /// The model-based sensor check (design §24): its last residual and
    /// the healthy margin.
    pub fn model_check(&self) -> &ModelCheck {
        &self.model
    }

    /// Forget the model check's healthy margin (start a new measurement).
    pub fn reset_model_margin(&mut self) {
        self.model.reset_peak();
    }

    /// The observer's `kt / J` after the motor changed.
    fn rederive_mechanics(&mut self) {
        if let Some(m) = self.mechanics {
            self.set_mechanics(&m);
        }
    }

    /// True once a [`Calibrated`] permit is installed (and not revoked by
    /// [`Self::set_current_config`] or [`Self::set_angle_calibration`]).
    pub fn is_calibrated(&self) -> bool {
        self.state.calibrated
    }

    /// Replace the current-loop configuration with values no permit vouches
    /// for. Revokes the calibration (see [`Self::revoke_calibration`]);
    /// use [`Self::set_calibration`] to install checked values.
    pub fn set_current_config(&mut self, c: CurrentLoopConfig) {
        self.config.current = c;
        self.current.set_config(c);
        if let Some(p) = self.power.as_mut() {
            p.set_motor(c.motor);
        }
        self.revoke_calibration();
        self.rederive_mechanics();
        self.rebuild_model();
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
    }

    /// Lock the closed-loop modes again; a closed-loop command that is
    /// active is replaced by `Disable` (bridge off from the next step).
    pub fn revoke_calibration(&mut self) {
        self.state.calibrated = false;
        if self.state.active.mode().is_closed_loop() {
            self.state.active = Command::Disable;
        }
    }

    /// Replace the travel range (the limits' position range) and the
    /// joint settings (design §21), in any mode: refused whole when a
    /// value is invalid ([`Refusal::Unsupported`]) or an active position
    /// command's target is outside the new range
    /// ([`Refusal::NotDisabled`]). An active impedance law's reference is
    /// moved into the new range.
    pub fn set_joint(&mut self, j: &JointChange) -> Result<(), Refusal> {
        let l = Limits {
            min_position_rad: j.min_position_rad,
            max_position_rad: j.max_position_rad,
            ..self.config.limits
        };
        if l.validate().is_err() || !j.joint.is_valid() {
            return Err(Refusal::Unsupported);
        }
        let target = match self.state.active {
            Command::Position { rad } => Some(rad),
            _ => None,
        };
        if target.is_some_and(|p| !(l.min_position_rad <= p && p <= l.max_position_rad)) {
            return Err(Refusal::NotDisabled);
        }
        self.config.limits = l;
        self.config.joint = j.joint;
        let law = &mut self.state.impedance;
        law.p_min_rad = l.min_position_rad;
        law.p_max_rad = l.max_position_rad;
        law.p_ref_rad = clamp(law.p_ref_rad, l.min_position_rad, l.max_position_rad);
        Ok(())
    }

    /// Replace the command limits.
    /// A current limit that is not a finite, non-negative number becomes 0
    /// (closed-loop current refused and clamped to nothing).
    pub fn set_limits(&mut self, l: Limits) {
        self.config.limits = sanitize_limits(l);
    }

    /// The fault supervisor.
    pub fn supervisor(&self) -> &Supervisor {
        &self.supervisor
    }

    /// Latch a fault found by the caller (overrun, gate driver, PWM error...).
    /// The next [`Self::step`] returns the safe state.
    pub fn report_fault(&mut self, f: Fault) {
        self.supervisor.trip(f);
        self.state.active = Command::Disable;
    }

    /// True when `slot` requests a fault clear this stage has not yet
    /// performed (it does so at the start of its next step, before it
    /// looks at the command).
    pub fn clear_pending(&self, slot: &CommandSlot) -> bool {
        slot.clear_seq != self.state.last_clear_seq
    }

    /// Take `slot`'s command and fault-clear numbers as seen without acting
    /// on them: after an identification, neither the operator's earlier
    /// command nor a clear sent during it acts later.
    pub fn sync_mailbox(&mut self, slot: &CommandSlot) {
        self.state.last_seq = slot.seq;
        self.state.last_clear_seq = slot.clear_seq;
    }

    /// Perform `slot`'s pending fault clear now (the step would do it
    /// first thing): the caller then latches faults it found this period,
    /// which the clear must not erase.
    /// Returns true when a clear was performed.
    pub fn take_clear(&mut self, slot: &CommandSlot) -> bool {
        if slot.clear_seq != self.state.last_clear_seq {
            self.state.last_clear_seq = slot.clear_seq;
            self.supervisor.clear();
            return true;
        }
        false
    }

    /// Commands refused so far (invalid, sent while faulted, or closed-loop
    /// without a calibration).
    pub fn rejected_commands(&self) -> u32 {
        self.state.rejected
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

    /// The speed stage runs every `n` periods (0 counts as 1): its q-current
    /// reference is interpolated over that many periods (design §19).
    #[inline]
    pub fn set_speed_periods(&mut self, n: u32) {
        let n = n.max(1);
        if n != self.state.speed_periods {
            self.state.speed_periods = n;
            self.state.speed_inv_periods = 1.0 / n as f32;
        }
    }

    /// The speed stage's output `target_a` [A] as the current loop uses it
    /// this period: a new value is reached in a straight line over the
    /// speed-loop period instead of in one step.
    #[inline(always)]
    fn interpolate_speed_output(&mut self, target_a: f32) -> f32 {
        let st = &mut self.state;
        if target_a != st.iq_target_a {
            st.iq_target_a = target_a;
            st.iq_step_a = (target_a - st.iq_interp_a) * st.speed_inv_periods;
        }
        let next = st.iq_interp_a + st.iq_step_a;
        let reached = if st.iq_step_a >= 0.0 {
            next >= target_a
        } else {
            next <= target_a
        };
        st.iq_interp_a = if reached { target_a } else { next };
        // Within the current limit in force now (it may have been lowered
        // while a ramp from a larger value was running).
        let lim = self.config.limits.max_current_a;
        clamp(st.iq_interp_a, -lim, lim)
    }

    /// The active command.
    pub fn active(&self) -> Command {
        self.state.active
    }

    fn accept(&mut self, cmd: Command) {
        let faulted = self.supervisor.is_faulted();
        if faulted
            || super::admit(&cmd, &self.config.limits, faulted, self.state.calibrated).is_err()
        {
            self.state.rejected = self.state.rejected.wrapping_add(1);
            return;
        }
        let (old, new) = (self.state.active.mode(), cmd.mode());
        match (old, new) {
            (_, Mode::OpenLoop) => {
                // Entering open loop starts at the command's angle. A new
                // open-loop command while in open loop takes its angle when
                // that differs from the previous command's (re-positioning,
                // e.g. the second step of an alignment); one that only
                // changes the voltage or the speed keeps the running angle,
                // so a spinning field stays continuous.
                if let Command::OpenLoop { theta_e, .. } = cmd {
                    let keep = matches!(
                        self.state.active,
                        Command::OpenLoop { theta_e: prev, .. } if prev == theta_e
                    );
                    if !keep {
                        self.state.ol_theta = theta_e;
                    }
                }
            }
            (Mode::OpenLoop, Mode::Torque | Mode::Velocity | Mode::Position | Mode::Impedance) => {
                // Bumpless: the PIs continue from the open-loop voltage.
                let w_e = self.tracker.velocity_rad_s() * self.config.angle.pole_pairs as f32;
                self.current
                    .preload(self.state.last_out_v_dq, self.state.last_i_dq, w_e);
            }
            (Mode::Disabled, _) => self.current.reset(),
            _ => {}
        }
        if let Command::Velocity { .. } = cmd {
            self.supervisor.restart_runaway();
        }
        if let Command::Impedance(i) = cmd {
            self.start_impedance(&i, old);
        }
        self.state.timeout_damping = false;
        self.state.active = cmd;
    }

    /// Take an impedance command (validated): its law, and when the mode
    /// is entered, a blend from the current in force (bumpless entry).
    fn start_impedance(&mut self, i: &Impedance, old: Mode) {
        let kt = self.config.current.motor.torque_constant_nm_per_a();
        let st = &mut self.state;
        st.impedance = ImpedanceLaw::new(i, kt, self.config.current.ts_s, &self.config.limits);
        if old != Mode::Impedance {
            let n = self.config.joint.entry_blend_periods;
            st.blend_from_a = match old {
                Mode::Torque | Mode::Velocity | Mode::Position => st.iq_interp_a,
                Mode::OpenLoop => st.last_i_dq.q,
                _ => 0.0,
            };
            st.blend_weight = if n > 0 { 1.0 } else { 0.0 };
            st.blend_step = if n > 0 { 1.0 / n as f32 } else { 1.0 };
        }
    }

    /// The impedance law's q current this period [A] (before the limits),
    /// blended from the current in force while the mode is being entered.
    #[inline(always)]
    fn impedance_iq(&mut self) -> f32 {
        let p = self.tracker.position().to_radians();
        let v = self.joint_velocity_rad_s();
        let st = &mut self.state;
        let law = st.impedance.step(p, v);
        if st.blend_weight > 0.0 {
            let iq = law + st.blend_weight * (st.blend_from_a - law);
            st.blend_weight -= st.blend_step;
            iq
        } else {
            law
        }
    }

    /// The velocity the joint features use [rad/s]: the angle tracker's
    /// (model-free). A joint's external torques are large against the
    /// rotor's inertia and mostly balanced by the law, so the speed
    /// observer, which sees them only as an unmodelled disturbance learnt
    /// with its 25 Hz pole, lags where the tracker follows the motion
    /// itself. With a fine sensor it is the rate of the tracked angle
    /// (`omega + kp e`: no phase lag well inside the tracker's 80 Hz);
    /// with a coarse one, whose innovation jumps at every edge, the
    /// tracker's integrator (design §21).
    #[inline(always)]
    fn joint_velocity_rad_s(&self) -> f32 {
        let w = self.tracker.velocity_rad_s();
        if self.state.interpolation.is_some() {
            w
        } else {
            w + self.config.tracker.kp_per_s * self.state.last_innovation_rad
        }
    }

    /// The travel limits (design §21): a position beyond the range by more
    /// than the margin trips [`Fault::TravelLimit`]; otherwise the soft
    /// stop's window clamps `iq_a`. Nothing without travel limits.
    #[inline(always)]
    fn travel(&mut self, iq_a: f32) -> f32 {
        let Some(t) = self.config.joint.travel else {
            return iq_a;
        };
        let p = self.tracker.position().to_radians();
        let (lo_p, hi_p) = (
            self.config.limits.min_position_rad,
            self.config.limits.max_position_rad,
        );
        if t.exceeded(p, lo_p, hi_p) {
            self.supervisor.trip(Fault::TravelLimit);
        }
        // The braking deceleration's current, `a J / kt`, when the
        // observer knows `kt / J`.
        let per_a = self.config.observer.accel_per_a_rad_s2;
        let brake_a = if per_a > 0.0 {
            t.brake_accel_rad_s2 / per_a
        } else {
            0.0
        };
        let v = self.joint_velocity_rad_s();
        let (lo, hi) = t.window_a(p, v, (lo_p, hi_p), brake_a);
        self.state.travel_window_a = Some((lo, hi));
        let x = if iq_a > hi { hi } else { iq_a };
        let x = if x < lo { lo } else { x };
        // Pushing back is within the current limit too.
        let lim = self.config.limits.max_current_a;
        clamp(x, -lim, lim)
    }

    /// One PWM period: commands, sensors, supervision, control. Returns what
    /// the bridge must do and the feedback for the slower stages.
    pub fn step(
        &mut self,
        slot: &CommandSlot,
        iq_ref_from_speed_a: f32,
        s: &Sample,
    ) -> (BridgeCommand, Feedback) {
        let mut fb = Feedback::INIT;
        let bridge = self.step_into(slot, iq_ref_from_speed_a, s, &mut fb);
        (bridge, fb)
    }

    /// [`Self::step`] with the feedback written in place into `fb` (every
    /// field): the firmware passes the feedback its other tasks read, so
    /// nothing is copied (design §20).
    pub fn step_into(
        &mut self,
        slot: &CommandSlot,
        iq_ref_from_speed_a: f32,
        s: &Sample,
        fb: &mut Feedback,
    ) -> BridgeCommand {
        self.state.period = self.state.period.wrapping_add(1);
        self.take_operator_actions(slot);
        let sensed = self.sense(s, iq_ref_from_speed_a);
        self.apply_command_timeout();
        let (out, i_ref, theta_e) = self.control(&sensed, iq_ref_from_speed_a);
        self.publish(out, i_ref, theta_e, sensed.v_bus_v, fb)
    }

    /// Step 1: operator actions: clear first, then a new command.
    #[inline(always)]
    fn take_operator_actions(&mut self, slot: &CommandSlot) {
        if slot.clear_seq != self.state.last_clear_seq {
            self.state.last_clear_seq = slot.clear_seq;
            self.supervisor.clear();
        }
        if slot.seq != self.state.last_seq {
            self.state.last_seq = slot.seq;
            self.state.age_periods = 0;
            self.accept(slot.command);
        }
    }

    /// Step 2: sensors and supervision: the angle used this period, the phase
    /// currents and the checks of the fault supervisor. A failed read trips
    /// its fault and leaves zeros.
    #[inline(always)]
    fn sense(&mut self, s: &Sample, iq_ref_from_speed_a: f32) -> Sensed {
        let mut sensed = Sensed {
            theta_e: ElectricalAngle::ZERO,
            i_abc: crate::frames::Abc::default(),
            i_ab: crate::frames::AlphaBeta::new(0.0, 0.0),
            v_bus_v: s.v_bus_v.unwrap_or(0.0),
            v_bus_read_v: s.v_bus_v,
            temperature_c: s.temperature_c,
        };
        match (s.currents, s.angle, s.v_bus_v) {
            (None, _, _) => self.supervisor.trip(Fault::CurrentSenseError),
            (_, None, _) => self.supervisor.trip(Fault::AngleSensorError),
            (_, _, None) => self.supervisor.trip(Fault::BusSenseError),
            (Some(cur), Some(raw), Some(v_bus_v)) => {
                let mech = self.config.angle.mechanical(raw);
                let innovation = self.tracker.update(mech);
                let innovation_step = innovation - self.state.last_innovation_rad;
                self.state.last_innovation_rad = innovation;
                let changed = self.state.last_raw != Some(raw);
                self.state.unchanged_periods = if changed {
                    self.state.speed_at_change_rad_s = self.tracker.velocity_rad_s();
                    0
                } else {
                    self.state.unchanged_periods.saturating_add(1)
                };
                let used = self.angle_used(mech, changed);
                // The torque-fed observer (design §19) takes the angle used
                // (the reading itself for a fine sensor) and the q current
                // measured at the last period's start: the torque that
                // drove the rotor since.
                self.observer.update(used, self.state.last_i_dq.q);
                sensed.theta_e = self.config.angle.electrical(used);
                sensed.i_abc = cur.to_abc();
                // |i_ab|^2 against the squared limit: no square root (see
                // `Supervisor::check_vector_sq`).
                sensed.i_ab = transforms::clarke(sensed.i_abc);
                let i_ab = sensed.i_ab;
                let vector_sq = i_ab.alpha * i_ab.alpha + i_ab.beta * i_ab.beta;
                self.supervisor.check_vector_sq(
                    &Checks {
                        i_abc_a: sensed.i_abc,
                        measured_sum_a: cur.measured_sum_a(),
                        vector_current_a: 0.0, // unused: the square is passed
                        v_bus_v,
                        angle_innovation_rad: innovation.abs(),
                        angle_step_rad: innovation_step.abs(),
                        speed_rad_s: self.tracker.velocity_rad_s(),
                        temperature_c: s.temperature_c,
                    },
                    vector_sq,
                );
                self.state.last_raw = Some(raw);
                self.check_stuck(changed, iq_ref_from_speed_a);
            }
        }
        sensed
    }

    /// The mechanical angle the Park transform uses: the reading, or for a
    /// coarse sensor the interpolated one.
    ///
    /// A coarse sensor's reading is stale between its edges: use the
    /// tracker's angle (advancing with the tracked speed), kept within the
    /// reading's count window, and between edges never moved against the
    /// tracked speed (the tracker's correction towards the window's centre
    /// can pull back). At standstill the tracker settles on the reading
    /// (+ half a count); on a reversal the angle waits at the window's edge.
    #[inline(always)]
    fn angle_used(&mut self, mech: MechanicalAngle, changed: bool) -> MechanicalAngle {
        match self.state.interpolation {
            None => mech,
            Some(h) => {
                let est = self.tracker.angle_at_reading();
                let mut th = AngleCalibration::within_count(mech, est, h);
                if !changed
                    && th.diff_radians(self.state.last_interp) * self.tracker.velocity_rad_s() < 0.0
                {
                    th = AngleCalibration::within_count(mech, self.state.last_interp, h);
                }
                self.state.last_interp = th;
                th
            }
        }
    }

    /// Stuck sensor / stall (a still reading while the drive pushes hard to
    /// move) and runaway (pushing at the limit without the speed error
    /// shrinking).
    #[inline(always)]
    fn check_stuck(&mut self, changed: bool, iq_ref_from_speed_a: f32) {
        let sc = &self.config.supervisor;
        let moving = match self.state.active {
            Command::Velocity { rad_s } => rad_s.abs() >= sc.stuck_min_speed_rad_s,
            Command::Position { rad } => {
                let d = rad - self.tracker.position().to_radians();
                d.abs() >= sc.stuck_min_distance_rad
            }
            _ => false,
        };
        let demand = if iq_ref_from_speed_a.is_finite() {
            iq_ref_from_speed_a
        } else {
            0.0
        };
        // What the travel limits' soft stop let through last period: a
        // rotor held at the end of its travel is not a stuck sensor.
        let demand = match self.state.travel_window_a {
            Some((lo, hi)) => clamp(demand, lo, hi),
            None => demand,
        };
        self.supervisor.check_stuck(changed, demand, moving);
        // Runaway: velocity mode pushing at the current limit without the
        // speed error shrinking.
        let speed_error = match self.state.active {
            Command::Velocity { rad_s } => Some(rad_s - self.tracker.velocity_rad_s()),
            _ => None,
        };
        let saturated = demand.abs() >= 0.95 * self.config.limits.max_current_a;
        self.supervisor.check_runaway(speed_error, saturated);
    }

    /// Step 3: command timeout.
    #[inline(always)]
    fn apply_command_timeout(&mut self) {
        if self.state.active.mode() == Mode::Disabled || self.config.command_timeout_periods == 0 {
            return;
        }
        self.state.age_periods = self.state.age_periods.saturating_add(1);
        if self.state.age_periods <= self.config.command_timeout_periods {
            return;
        }
        self.state.age_periods = 0;
        if let Command::Impedance(i) = self.state.active {
            // Impedance (design §21): damping only, then disable.
            if self.state.timeout_damping || !self.state.calibrated {
                self.supervisor.trip(Fault::CommandTimeout);
            } else {
                let kd_min = self.config.joint.timeout_kd_nm_s_per_rad;
                let damping = Impedance {
                    position_rad: self.tracker.position().to_radians(),
                    velocity_rad_s: 0.0,
                    kp_nm_per_rad: 0.0,
                    kd_nm_s_per_rad: if i.kd_nm_s_per_rad > kd_min {
                        i.kd_nm_s_per_rad
                    } else {
                        kd_min
                    },
                    torque_ff_nm: 0.0,
                    torque_limit_nm: i.torque_limit_nm,
                };
                self.start_impedance(&damping, Mode::Impedance);
                self.state.active = Command::Impedance(damping);
                self.state.timeout_damping = true;
            }
            return;
        }
        match self.config.timeout_reaction {
            // Stop and Hold are closed-loop: without a calibration
            // (open loop) the timeout disables.
            TimeoutReaction::Disable => self.supervisor.trip(Fault::CommandTimeout),
            _ if !self.state.calibrated => self.supervisor.trip(Fault::CommandTimeout),
            TimeoutReaction::Stop => self.accept(Command::Velocity { rad_s: 0.0 }),
            TimeoutReaction::Hold => {
                let p = self.tracker.position().to_radians();
                self.state.active = Command::Position { rad: p };
            }
        }
    }

    /// Step 4: control: the current loop in the active mode (`None`: bridge off).
    /// Returns the output, the dq current reference and the electrical
    /// angle used (the open-loop angle in open loop).
    #[inline(always)]
    fn control(
        &mut self,
        sensed: &Sensed,
        iq_ref_from_speed_a: f32,
    ) -> (Option<CurrentLoopOutput>, Dq, ElectricalAngle) {
        let mut theta_e = sensed.theta_e;
        let pp = self.config.angle.pole_pairs as f32;
        let w_e = self.tracker.velocity_rad_s() * pp;
        let mut i_ref = Dq::ZERO;
        // The q-current each closed-loop mode asks for, before the window.
        let lim = self.config.limits.max_current_a;
        let from_speed = if iq_ref_from_speed_a.is_finite() {
            clamp(iq_ref_from_speed_a, -lim, lim)
        } else {
            0.0
        };
        let requested = match self.state.active {
            Command::Disable | Command::OpenLoop { .. } => {
                self.state.iq_interp_a = 0.0;
                self.state.iq_target_a = from_speed;
                self.state.iq_step_a = 0.0;
                None
            }
            Command::Torque { iq_a } => {
                // The speed stage tracks this reference: entering velocity
                // mode interpolates from it.
                self.state.iq_interp_a = iq_a;
                self.state.iq_target_a = from_speed;
                self.state.iq_step_a = 0.0;
                Some(iq_a)
            }
            Command::Velocity { .. } | Command::Position { .. } => {
                Some(self.interpolate_speed_output(from_speed))
            }
            Command::Impedance(_) => {
                let iq = clamp(self.impedance_iq(), -lim, lim);
                // As in torque mode: the speed stage tracks it.
                self.state.iq_interp_a = iq;
                self.state.iq_target_a = from_speed;
                self.state.iq_step_a = 0.0;
                Some(iq)
            }
        };
        self.state.travel_window_a = None;
        let requested = requested.map(|iq| self.travel(iq));
        // Stepped every period (winding estimate, chopper), faulted or not.
        let windowed = self.power_window(sensed, w_e, requested.unwrap_or(0.0));
        if self.supervisor.is_faulted() {
            self.state.active = Command::Disable;
            self.model.reset();
            return (None, i_ref, theta_e);
        }
        // The closed-loop modes share one (inlined) current-loop call.
        let w = &self.power_report;
        let closed = requested.map(|iq| {
            if windowed {
                Dq::new(w.id_ref_a, w.clamp(iq))
            } else {
                Dq::new(0.0, iq)
            }
        });
        let closed_iq = closed.map(|i| i.q);
        let out = match (closed, self.state.active) {
            (Some(i), _) => {
                i_ref = i;
                // `i_ab` is `clarke(i_abc)` (both zero when a read failed).
                Some(self.current.step_inline_ab(
                    &CurrentLoopInput {
                        i_abc_a: sensed.i_abc,
                        theta_e,
                        omega_e_rad_s: w_e,
                        v_bus_v: sensed.v_bus_v,
                        i_dq_ref_a: i_ref,
                    },
                    sensed.i_ab,
                ))
            }
            (
                None,
                Command::OpenLoop {
                    v_d_v,
                    v_q_v,
                    omega_e_rad_s,
                    ..
                },
            ) => {
                let th = self.state.ol_theta;
                self.state.ol_theta = th.add_radians(omega_e_rad_s * self.config.current.ts_s);
                theta_e = th;
                Some(self.current.step_voltage(
                    sensed.i_abc,
                    th,
                    Dq::new(v_d_v, v_q_v),
                    sensed.v_bus_v,
                ))
            }
            (None, _) => None,
        };
        // The model takes its speed from the angle's change; for a coarse
        // sensor (halls) from the torque-fed observer, which knows the
        // acceleration between the edges (design §19).
        let w_observer = self.observer.velocity_rad_s() * pp;
        if closed_iq.is_some()
            && !(self.sensors_plausible(out.as_ref(), sensed, w_observer)
                && self.currents_track(out.as_ref(), i_ref, w_e))
        {
            // The bridge goes off: nothing recorded this period was applied.
            self.model.reset();
            self.state.active = Command::Disable;
            return (None, i_ref, theta_e);
        }
        if closed_iq.is_none() {
            // Open loop or off: the angle does not drive the bridge; the
            // model waits, its speed window counts the reading's increments.
            self.model.idle(sensed.theta_e);
        }
        (out, i_ref, theta_e)
    }

    /// The power limits' q-current window of this period, when they are
    /// configured (true): steps the winding estimate (from the last
    /// measured currents) and the brake chopper, the report written into
    /// `power_report`. Without them nothing is computed (false; the
    /// published report is the current limit's window).
    #[inline(always)]
    fn power_window(&mut self, sensed: &Sensed, w_e: f32, iq_request_a: f32) -> bool {
        let Some(p) = self.power.as_mut() else {
            return false;
        };
        p.step_into(
            self.state.last_i_dq,
            self.state.last_out_v_dq,
            self.config.current.ts_s,
            PowerInputs {
                v_bus_v: sensed.v_bus_read_v,
                omega_e_rad_s: w_e,
                i_d_a: 0.0,
                iq_request_a,
                current_limit_a: self.config.limits.max_current_a,
                winding_temperature_c: None,
                stage_temperature_c: sensed.temperature_c,
            },
            &mut self.power_report,
        );
        true
    }

    /// Sensor plausibility from the motor model (closed loop, design
    /// §24): judges this period, then records what it drives. False when
    /// a fault tripped.
    #[inline(always)]
    fn sensors_plausible(
        &mut self,
        out: Option<&CurrentLoopOutput>,
        sensed: &Sensed,
        w_e_rad_s: f32,
    ) -> bool {
        let Some(o) = out.filter(|o| !o.invalid) else {
            self.model.reset();
            return true;
        };
        let p = Period {
            i_ab_a: sensed.i_ab,
            i_dq_a: o.i_dq_a,
            sin_cos: o.sin_cos,
            theta_e: sensed.theta_e,
            // The observer's speed against the tracker's (coarse sensors).
            omega_spread_rad_s: w_e_rad_s
                - self.tracker.velocity_rad_s() * self.config.angle.pole_pairs as f32,
            omega_e_rad_s: w_e_rad_s,
            unchanged_periods: self.state.unchanged_periods,
        };
        let fault = match self.model.check(&p) {
            Verdict::CurrentSense if self.angle_frozen() => Some(Fault::AngleSensorStuck),
            Verdict::CurrentSense => Some(Fault::CurrentSenseError),
            // A fine sensor only: a coarse one (halls) legitimately stands
            // still through a reversal inside one of its wide counts.
            Verdict::Quiet
                if self.state.interpolation.is_none() && self.still_while_emf_moves() =>
            {
                Some(Fault::AngleSensorStuck)
            }
            Verdict::Quiet => None,
        };
        match fault {
            Some(f) => {
                self.supervisor.trip(f);
                self.model.reset();
                false
            }
            None => {
                self.model.record(&p, o.duties, sensed.v_bus_v);
                true
            }
        }
    }

    /// The angle reading has stood still for longer than the speed it had
    /// when it last moved needs to move it two counts: a model-check trip
    /// is then the angle's (a frozen angle makes the model's back-EMF and
    /// the currents disagree), not the current sensors'.
    #[inline(always)]
    fn angle_frozen(&self) -> bool {
        let cpr = self.config.angle.sensor_counts_per_rev;
        let count_rad = if cpr > 0 {
            core::f32::consts::TAU / cpr as f32
        } else {
            0.01
        };
        let ts = self.config.current.ts_s;
        let speed = self.state.speed_at_change_rad_s.abs();
        let moved_rad = speed * ts * self.state.unchanged_periods as f32;
        // A speed that moves two counts within 20 periods (slower, a
        // still reading is a rotor at rest); two counts' worth and more,
        // for at most 50 ms (longer, the rotor has likely stopped: then it
        // is the currents).
        let still_s = ts * self.state.unchanged_periods as f32;
        speed * ts * 20.0 > 2.0 * count_rad && moved_rad > 2.0 * count_rad && still_s < 0.05
    }

    /// The reading has stood still for two counts' worth and more at its
    /// last speed ([`Self::angle_frozen`]) while the measured back-EMF
    /// says the rotor turns.
    #[inline(always)]
    fn still_while_emf_moves(&self) -> bool {
        self.angle_frozen() && self.emf_shows_motion()
    }

    /// The back-EMF the model check measured (independent of the angle)
    /// is at least half what the speed at the reading's last change
    /// gives, and above the check's own uncertainty: the rotor still
    /// turns (a rotor stopped against an end stop has no back-EMF).
    #[inline(always)]
    fn emf_shows_motion(&self) -> bool {
        let r = self.model.last();
        let e = r.emf_dq_v;
        let e_sq = e.d * e.d + e.q * e.q;
        let m = &self.config.current.motor;
        let expected_v = 0.5
            * (self.state.speed_at_change_rad_s * m.pole_pairs as f32 * m.flux_linkage_wb).abs();
        e_sq > expected_v * expected_v && e_sq > r.min_emf_v * r.min_emf_v
    }

    /// The slower back-up of the model check: the loop's tracking error
    /// against the supervisor's band, excused on the voltage limit (the
    /// reference out of reach: back-EMF, or `L di/dt` while a large
    /// inductance slews) and while the angle reading looks frozen (the
    /// stuck check's to name). False when it trips.
    #[inline(always)]
    fn currents_track(
        &mut self,
        out: Option<&CurrentLoopOutput>,
        i_ref: Dq,
        w_e_rad_s: f32,
    ) -> bool {
        let Some(o) = out else {
            return true;
        };
        let (ed, eq) = (i_ref.d - o.i_dq_a.d, i_ref.q - o.i_dq_a.q);
        let cpr = self.config.angle.sensor_counts_per_rev;
        let count_rad = if cpr > 0 {
            core::f32::consts::TAU / cpr as f32
        } else {
            0.01
        };
        let commanded_rad_s = match self.state.active {
            Command::Velocity { rad_s } => rad_s.abs(),
            _ => 0.0,
        };
        let pp = self.config.angle.pole_pairs.max(1) as f32;
        let tracked_rad_s = (w_e_rad_s / pp).abs();
        let speed = if commanded_rad_s > tracked_rad_s {
            commanded_rad_s
        } else {
            tracked_rad_s
        };
        let moved_rad = speed * self.config.current.ts_s * self.state.unchanged_periods as f32;
        let excused = o.voltage_limited || moved_rad > 2.0 * count_rad;
        self.supervisor
            .check_tracking(ed * ed + eq * eq, excused)
            .is_none()
    }

    /// Step 5: the bridge command and the feedback. A control output that is
    /// itself invalid is a fault too.
    #[inline(always)]
    fn publish(
        &mut self,
        out: Option<CurrentLoopOutput>,
        i_ref: Dq,
        theta_e: ElectricalAngle,
        v_bus: f32,
        fb: &mut Feedback,
    ) -> BridgeCommand {
        let out = match out {
            Some(o) if o.invalid => {
                self.supervisor.trip(Fault::NonFinite);
                self.state.active = Command::Disable;
                None
            }
            o => o,
        };
        let (bridge, duties, v_dq, i_dq, limited) = match out {
            Some(o) => (
                BridgeCommand::Duties(o.duties),
                o.duties,
                o.v_dq_v,
                o.i_dq_a,
                o.voltage_limited,
            ),
            None => {
                self.current.reset();
                (
                    BridgeCommand::SafeState,
                    [0.5; 3],
                    Dq::ZERO,
                    Dq::ZERO,
                    false,
                )
            }
        };
        self.state.last_out_v_dq = v_dq;
        self.state.last_i_dq = i_dq;
        *fb = Feedback {
            mode: self.state.active.mode(),
            active: self.state.active,
            position_rad: self.tracker.position().to_radians(),
            velocity_rad_s: self.observer.velocity_rad_s(),
            disturbance_rad_s2: self.observer.disturbance_rad_s2(),
            theta_e,
            i_dq_a: i_dq,
            i_dq_ref_a: i_ref,
            v_dq_v: v_dq,
            v_bus_v: v_bus,
            duties,
            faults: self.supervisor.faults(),
            first_fault: self.supervisor.first_fault(),
            voltage_limited: limited,
            current_limit_a: self.config.limits.max_current_a,
            power: self.published_window(),
            period: self.state.period,
        };
        bridge
    }
}

impl CurrentStage {
    /// The power report published: the power limits' (or the current
    /// limit's) window, narrowed by the travel limits' soft stop.
    #[inline(always)]
    fn published_window(&self) -> PowerReport {
        let mut r = if self.power.is_some() {
            self.power_report
        } else {
            PowerReport::unlimited(self.config.limits.max_current_a)
        };
        if let Some((lo, hi)) = self.state.travel_window_a {
            if lo > r.iq_min_a {
                r.iq_min_a = lo;
            }
            if hi < r.iq_max_a {
                r.iq_max_a = hi;
            }
        }
        r
    }
}

/// The model check of a stage configuration: the current loop's motor and
/// period, the supervisor's tolerances with the angle sensor's resolution
/// added (a whole count for a fine sensor, half of one where the stage
/// interpolates a coarse one).
fn model_check(c: &CurrentStageConfig) -> ModelCheck {
    let a = &c.angle;
    let count_e_rad = match a.sensor_counts_per_rev {
        0 => 0.0,
        n => core::f32::consts::TAU * a.pole_pairs as f32 / n as f32,
    };
    let mut tol = c.supervisor.model;
    // An interpolated coarse sensor (halls) is within its half-count
    // window; a fine one within a count.
    tol.angle_e_rad += match a.interpolation_half_count() {
        Some(_) => 0.5 * count_e_rad,
        None => count_e_rad,
    };
    let coarse = a.interpolation_half_count().is_some();
    ModelCheck::new(c.current.motor, c.current.ts_s, tol, coarse)
}

/// `max_current_a` not finite and non-negative -> 0.
fn sanitize_limits(mut l: Limits) -> Limits {
    if !(l.max_current_a >= 0.0 && l.max_current_a < f32::INFINITY) {
        l.max_current_a = 0.0;
    }
    l
}

/// What [`CurrentStage::step`] measured this period (zeros where a read
/// failed).
#[derive(Clone, Copy, Debug)]
struct Sensed {
    /// Electrical angle of the d axis from the sensor.
    theta_e: ElectricalAngle,
    /// Phase currents [A].
    i_abc: crate::frames::Abc,
    /// `clarke(i_abc)` [A].
    i_ab: crate::frames::AlphaBeta,
    /// Bus voltage [V] (0 when the read failed).
    v_bus_v: f32,
    /// The bus voltage as read.
    v_bus_read_v: Option<f32>,
    /// Power-stage temperature as read.
    temperature_c: Option<f32>,
}

/// What the position stage hands the speed stage.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VelocityRef {
    /// Velocity reference [rad/s, mechanical].
    pub rad_s: f32,
    /// Torque feed-forward as a q current [A].
    pub iq_ff_a: f32,
}

/// The speed stage: runs every N periods.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeedStage {
    speed: SpeedLoop,
    last_mode: Mode,
    iq_ref_a: f32,
}

impl SpeedStage {
    /// New stage.
    pub fn new(config: SpeedLoopConfig) -> Self {
        Self {
            speed: SpeedLoop::new(config),
            last_mode: Mode::Disabled,
            iq_ref_a: 0.0,
        }
    }
    /// The speed loop.
    pub fn speed_loop(&mut self) -> &mut SpeedLoop {
        &mut self.speed
    }
    /// One step: returns the q-current reference [A] for the current stage.
    /// Outside velocity/position modes it tracks the active current
    /// reference so that entering those modes is bumpless.
    pub fn step(&mut self, fb: &Feedback, from_position: VelocityRef) -> f32 {
        let (w_ref, ff) = match fb.active {
            Command::Velocity { rad_s } => (Some(rad_s), 0.0),
            Command::Position { .. } => (Some(from_position.rad_s), from_position.iq_ff_a),
            _ => (None, 0.0),
        };
        let entering = !matches!(self.last_mode, Mode::Velocity | Mode::Position);
        let model_starts = fb.mode == Mode::Velocity && self.last_mode != Mode::Velocity;
        self.last_mode = fb.mode;
        self.iq_ref_a = match w_ref {
            Some(w) => {
                if entering {
                    // Bumpless: the current in force, less what the
                    // disturbance feed-forward already adds.
                    let dob = self.speed.disturbance_ff_a(fb.disturbance_rad_s2);
                    self.speed.preload(fb.i_dq_ref_a.q - dob);
                }
                if model_starts {
                    // The reference model starts where the rotor is.
                    self.speed.start_model(fb.velocity_rad_s);
                }
                // Within the current limit and the power limits' window.
                // (Plain comparisons: `f32::max` is branchy on the M4F.)
                let lim = fb.current_limit_a;
                let (p_lo, p_hi) = (fb.power.iq_min_a, fb.power.iq_max_a);
                let lo = if p_lo > -lim { p_lo } else { -lim };
                let hi = if p_hi < lim { p_hi } else { lim };
                // The travel limits' soft stop may push back (a window
                // without 0); the speed loop's stays at 0 there and the
                // current stage pushes.
                let lo = if lo > 0.0 { 0.0 } else { lo };
                let hi = if hi < 0.0 { 0.0 } else { hi };
                if fb.mode == Mode::Velocity {
                    // A step of the operator's reference: through the
                    // reference model (two degrees of freedom).
                    self.speed
                        .step_model(w, fb.velocity_rad_s, fb.disturbance_rad_s2, lim, lo, hi)
                } else {
                    // The trajectory is already smooth, with its own
                    // acceleration feed-forward.
                    self.speed.step_in(
                        w,
                        fb.velocity_rad_s,
                        ff + self.speed.disturbance_ff_a(fb.disturbance_rad_s2),
                        lo,
                        hi,
                    )
                }
            }
            None => {
                self.speed.preload(fb.i_dq_ref_a.q);
                fb.i_dq_ref_a.q
            }
        };
        self.iq_ref_a
    }
}

/// The position stage: runs every M periods.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PositionStage {
    pos: PositionLoop,
    last_mode: Mode,
    last_target: f32,
}

impl PositionStage {
    /// New stage.
    pub fn new(config: PositionLoopConfig) -> Self {
        Self {
            pos: PositionLoop::new(config),
            last_mode: Mode::Disabled,
            last_target: 0.0,
        }
    }
    /// The position loop.
    pub fn position_loop(&self) -> &PositionLoop {
        &self.pos
    }
    /// Replace the position-loop configuration.
    pub fn set_config(&mut self, c: PositionLoopConfig) {
        self.pos.set_config(c);
    }
    /// One step: returns the velocity reference (and acceleration
    /// feed-forward) for the speed stage. Outside position mode it returns
    /// the measured velocity and no feed-forward.
    pub fn step(&mut self, fb: &Feedback) -> VelocityRef {
        let w = if let Command::Position { rad } = fb.active {
            if self.last_mode != Mode::Position {
                self.pos.start_move(fb.position_rad, fb.velocity_rad_s, rad);
            } else if rad != self.last_target {
                self.pos.retarget(rad);
            }
            self.last_target = rad;
            let w = self.pos.step(fb.position_rad);
            VelocityRef {
                rad_s: w,
                iq_ff_a: self.pos.current_feed_forward_a(),
            }
        } else {
            VelocityRef {
                rad_s: fb.velocity_rad_s,
                iq_ff_a: 0.0,
            }
        };
        self.last_mode = fb.mode;
        w
    }
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
