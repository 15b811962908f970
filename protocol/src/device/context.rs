//! The drive as the protocol sees it: [`DeviceContext`].

use super::*;

impl From<Refusal> for ErrorCode {
    fn from(r: Refusal) -> Self {
        match r {
            Refusal::Busy => ErrorCode::Busy,
            Refusal::NotCalibrated => ErrorCode::NotCalibrated,
            Refusal::NotDisabled => ErrorCode::NotDisabled,
            Refusal::Faulted => ErrorCode::Faulted,
            Refusal::Unsupported => ErrorCode::Unsupported,
        }
    }
}

/// What the firmware (or a simulator) gives the protocol. Every method is
/// called only after the request was fully validated.
///
/// In the RTIC firmware the methods map onto shared resources: `post` and
/// `keep_alive` onto the [`foc_core::control::CommandSlot`] (`slot.post(cmd)`,
/// `slot.post(slot.command)`), `clear_faults` onto `slot.request_clear()`,
/// `mode`/`faults`/`telemetry` onto the latest
/// [`foc_core::control::Feedback`], the setters onto the loop configs
/// (applied by the task that owns each loop).
pub trait DeviceContext {
    /// Hand a validated command (rotor frame) to the current stage (e.g.
    /// `CommandSlot::post`). Called only with commands that passed
    /// [`Command::validate`] against the limits in force
    /// ([`crate::joint::limits_in_force`] of [`Self::limits`] and
    /// [`Self::joint`]).
    fn post(&mut self, cmd: Command) -> Result<(), CommandError>;
    /// Refresh the active command so the current stage's own command
    /// timeout restarts (e.g. `slot.post(slot.command)`, which bumps
    /// [`foc_core::control::CommandSlot::seq`]).
    fn keep_alive(&mut self);
    /// Active mode ([`foc_core::control::Feedback::mode`]).
    fn mode(&self) -> Mode;
    /// Latched faults and the first one.
    fn faults(&self) -> (FaultSet, Option<Fault>);
    /// Request a fault clear (e.g. `CommandSlot::request_clear`).
    fn clear_faults(&mut self);
    /// Latch a fault (the watchdog's `Disable` reaction reports
    /// [`Fault::CommandTimeout`]).
    fn report_fault(&mut self, fault: Fault);
    /// The motor's command limits (rotor frame; the position range is the
    /// motor's own: a joint's travel range narrows it, see
    /// [`crate::joint::limits_in_force`]).
    fn limits(&self) -> Limits;
    /// Replace the motor's limits (already checked: finite, positive,
    /// min < max). With a travel range the range in force stays the
    /// travel range.
    fn set_limits(&mut self, limits: Limits) -> Result<(), Refusal>;
    /// The joint in force: output frame, travel range, soft stop,
    /// impedance entry and timeout. Default: none ([`crate::joint::NO_JOINT`]).
    fn joint(&self) -> JointSetup {
        crate::joint::NO_JOINT
    }
    /// Replace the joint (already checked whole, the drive started): the
    /// drive takes its rotor-frame change in any mode
    /// ([`foc_core::drive::JointChange`]); refuse with
    /// [`Refusal::NotDisabled`] when the active position command's target
    /// would leave the new range. Default: [`Refusal::Unsupported`].
    fn set_joint(&mut self, setup: JointSetup) -> Result<(), Refusal> {
        let _ = setup;
        Err(Refusal::Unsupported)
    }
    /// The motor's torque constant [N m/A] (0 when unknown: homing to an
    /// end stop is then refused). Default: from the pole pairs and the
    /// flux linkage ([`Self::param`]).
    fn torque_constant_nm_per_a(&self) -> f32 {
        match (
            self.param(ParamId::PolePairs),
            self.param(ParamId::FluxLinkageWb),
        ) {
            (Some(pp), Some(psi)) => 1.5 * pp * psi,
            _ => 0.0,
        }
    }
    /// The drive's latest feedback (rotor frame), for homing and the
    /// link watchdog's impedance reaction. Default: built from
    /// [`Self::telemetry`] ([`crate::joint::feedback_of`]).
    fn feedback(&self) -> Feedback {
        crate::joint::feedback_of(&self.telemetry())
    }
    /// Replace the current-loop gains (finite, >= 0).
    fn set_current_gains(&mut self, gains: CurrentGains) -> Result<(), Refusal>;
    /// Replace the speed-loop gains (finite, >= 0).
    fn set_speed_gains(&mut self, gains: SpeedGains) -> Result<(), Refusal>;
    /// Replace the position gain and trajectory limits (finite, > 0).
    fn set_position_gains(&mut self, gains: PositionGains) -> Result<(), Refusal>;
    /// Replace the loop dividers (>= 1; only called while disabled).
    fn set_dividers(&mut self, speed: u16, position: u16) -> Result<(), Refusal>;
    /// Write a parameter (only called while started and disabled, with a
    /// writable `id` and a `value` it accepts: [`ParamId::accepts`]): the
    /// d-current reference's, applied whole with the drive's rule
    /// (`foc_core::drive::check_field`: no field weakening on a coarse
    /// angle sensor, nor with `max-id` 0: [`Refusal::Unsupported`]); the
    /// tables' switches (`anticogging`, `encoder-linearisation`: on
    /// without a table is [`Refusal::NotCalibrated`]).
    /// Default: [`Refusal::Unsupported`].
    fn set_param(&mut self, id: ParamId, value: f32) -> Result<(), Refusal> {
        let _ = (id, value);
        Err(Refusal::Unsupported)
    }
    /// Start a calibration routine (only called while disabled and not
    /// faulted); return [`Refusal::Busy`] if one is running. A sweep
    /// ([`Calibration::sweep`]: anticogging, encoder linearisation) is
    /// judged with the drive's rule, `foc_core::drive::Status::check_sweep`
    /// on the angle calibration in force ([`Refusal::NotCalibrated`],
    /// [`Refusal::Unsupported`]).
    fn start_calibration(&mut self, routine: Calibration) -> Result<(), Refusal>;
    /// True once the drive may run closed loop (offsets and alignment done).
    fn is_calibrated(&self) -> bool;
    /// The drive's status, which the drive's own rules
    /// ([`foc_core::drive::Status`]) are applied to before anything is
    /// handed on. Default: started, with [`Self::mode`], [`Self::faults`],
    /// [`Self::is_calibrated`] and [`ParamId::AngleSource`]; a device with a start-up phase
    /// overrides it.
    fn status(&self) -> Status {
        Status {
            running: true,
            mode: self.mode(),
            faulted: !self.faults().0.is_empty(),
            calibrated: self.is_calibrated(),
            sensorless: matches!(self.param(ParamId::AngleSource), Some(1.0 | 3.0)),
            // Not known from the parameters: refused as without injection.
            injection: false,
            calibration: foc_core::drive::Progress::Idle,
        }
    }
    /// A parameter value, `None` if this device does not have it.
    fn param(&self, id: ParamId) -> Option<f32>;
    /// The latest telemetry sample, rotor frame (e.g.
    /// [`Telemetry::from_feedback`]; the protocol converts it).
    fn telemetry(&self) -> Telemetry;
    /// Firmware version `[major, minor, patch]`.
    fn firmware_version(&self) -> [u8; 3];

    /// The highest telemetry stream rate the link carries \[Hz\] (`None`: no
    /// limit, e.g. a socket): `StartTelemetry` above it is refused
    /// (out of range, field 1). A UART's: [`max_stream_hz`].
    fn max_stream_hz(&self) -> Option<f32> {
        None
    }

    /// The scope (design §22), if the device has one (default: none, the
    /// scope requests are Nack'd `Unsupported`).
    fn scope(&mut self) -> Option<&mut dyn crate::scope::ScopePort> {
        None
    }
    /// The live or the stored configuration record, encoded into `out`:
    /// its length. `link` is the link-watchdog setting in force (part of
    /// the live record). Default: no store, [`ErrorCode::Unsupported`].
    fn config_record(
        &mut self,
        source: ConfigSource,
        link: WatchdogConfig,
        out: &mut [u8; MAX_RECORD],
    ) -> Result<usize, ErrorCode> {
        let _ = (source, link, out);
        Err(ErrorCode::Unsupported)
    }
    /// Run a store operation (only called while started and disabled).
    /// `staged` is the whole record the host wrote, for the `Apply`
    /// operations (empty otherwise); `link` the link-watchdog setting in
    /// force, saved with the configuration. An applied record is validated
    /// whole before anything changes; its link-watchdog setting is
    /// returned for the protocol to take. Default: no store,
    /// [`ErrorCode::Unsupported`].
    fn store(
        &mut self,
        op: StoreOp,
        staged: &[u8],
        link: WatchdogConfig,
    ) -> Result<Option<WatchdogConfig>, ErrorCode> {
        let _ = (op, staged, link);
        Err(ErrorCode::Unsupported)
    }
}
