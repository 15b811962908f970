//! The command and telemetry channel: `foc_protocol` over the board's
//! command UART (`board::CommandSerial`, USART2 on every board).
//!
//! Two priority-1 tasks use it (see `main.rs`): the `serial` task (bound to
//! `board::SERIAL_IRQ`) feeds received bytes to
//! [`DeviceState::on_byte`] and queues the replies; `housekeeping` calls
//! [`DeviceState::poll`] for the link watchdog and streamed telemetry.
//! Both hold [`Comms`] (a shared resource of theirs, so never contended).
//!
//! The protocol validates every request before it touches the
//! [`DeviceContext`]. [`Link`] is that context: a *snapshot* of the shared
//! state (feedback, timing, phase) taken before a frame is handled, the
//! scope (one lock per call), plus
//! an outbox of what the frame asked for, committed into the RTIC shared
//! resources right after (`Link::commit` in `main.rs`):
//!
//! - commands, keep-alives and fault clears go to the `command`
//!   [`CommandSlot`] (read by the current loop);
//! - configuration changes go to the `config_request` [`ConfigMailbox`],
//!   one part per owning task: the current loop takes limits, current gains,
//!   dividers, the offset calibration and a fault to latch; the speed loop
//!   its [`SpeedLoopConfig`]; the position loop its [`PositionLoopConfig`].
//!   Each applies its part at its next run (at most one position-loop
//!   period later). Changes merge: a newer value replaces a pending one,
//!   so back-to-back requests are never lost.
//!
//! The drive's own rules (only while started and disabled, identification
//! not while faulted, commands against the limits and the permit) are
//! `foc_core::drive::Status`'s, applied by the protocol to the snapshot's
//! status for the immediate Nack and by the drive again when it takes the
//! change. This board adds (nothing changes, the host gets a Nack):
//!
//! | request | refused when | reply |
//! |---|---|---|
//! | limits | `max_current_a` above the build-time limit (`config::MOTOR`) | `Unsupported` |
//! | current gains | not positive (a calibration permit cannot vouch for them) | `Unsupported` |
//! | calibration `alignment` alone | always: it is part of `identification` | `Unsupported` |
//! | joint | the pending position command's target outside the new travel range | `NotDisabled` |
//!
//! The joint (design §21): `Settings::joint` is the joint in force; the
//! protocol converts between the host's output frame and the drive's rotor
//! frame with it, and runs homing in `poll` (housekeeping, 50 Hz; its
//! commands go to the `command` mailbox like the host's). A `SetJoint`
//! (or a homing's result) goes to the current loop as
//! `ConfigChange::joint`, the travel range in the rotor frame, taken while
//! running too; a change of the limits or an adopted record sends it again
//! (the limits' position range would replace the travel range).

use crate::config;
use crate::persist::{self, BoardStore};
use board_support::board;
use foc_core::calibration::identification::IdentificationResult;
use foc_core::calibration::Calibrated;
use foc_core::control::joint::JointSetup;
use foc_core::control::position::PositionLoopConfig;
use foc_core::control::speed::SpeedLoopConfig;
use foc_core::control::{
    Command, CommandError, CommandSlot, Fault, FaultSet, Feedback, Limits, Mode,
};
use foc_core::drive::{ConfigChange, JointChange, Status};
use foc_core::scope::{Scope, ScopeConfig, ScopeError, ScopeStatus};
use foc_protocol::config::{ConfigSource, StoreOp, MAX_RECORD};
use foc_protocol::frame::{encode, FrameDecoder, MAX_FRAME};
use foc_protocol::message::ErrorCode;
use foc_protocol::message::{
    Calibration, CurrentGains, ParamId, PositionGains, SpeedGains, Telemetry,
};
use foc_protocol::scope::ScopePort;
use foc_protocol::{DeviceContext, DeviceState, Refusal, WatchdogConfig};
use foc_store::{DriveRecord, Label, StoreError};

/// Link watchdog armed by the first closed-loop command over the link
/// (unless the host configured it with `SetWatchdog`, `foc-ctl watchdog`):
/// 1 s without a command or keep-alive stops the motor (velocity 0), one
/// more second disables it (`CommandTimeout`). Commands that do not come
/// over the link (`config::START_COMMAND`, the QEMU mission) do not arm it.
pub const AUTO_WATCHDOG: WatchdogConfig = WatchdogConfig {
    timeout_periods: board::PWM_FREQUENCY_HZ,
    reaction: foc_core::control::stage::TimeoutReaction::Stop,
};

/// The scope (design §22) over its static buffer (`config::SCOPE_VALUES`
/// values); recorded by `current_loop`, reached by the channel through
/// [`ScopeLock`].
pub type BoardScope = Scope<&'static mut [f32]>;

/// The shared scope resource as the protocol's [`ScopePort`]: each call
/// one critical section at the current loop's priority (a status, a
/// configuration, or a copy of at most 12 values).
pub struct ScopeLock<M>(pub M);

impl<M: rtic::Mutex<T = BoardScope>> ScopePort for ScopeLock<M> {
    fn configure(&mut self, c: &ScopeConfig) -> Result<(), ScopeError> {
        self.0.lock(|s| s.configure(*c))
    }
    fn arm(&mut self, now: &Feedback) {
        self.0.lock(|s| s.arm(now));
    }
    fn force(&mut self) -> Result<(), ScopeError> {
        self.0.lock(|s| s.force())
    }
    fn status(&mut self) -> ScopeStatus {
        self.0.lock(|s| s.status())
    }
    fn read(&mut self, offset: usize, out: &mut [f32]) -> usize {
        self.0.lock(|s| s.read(offset, out))
    }
}

/// Pending configuration changes, one part per owning task.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ConfigMailbox {
    /// Taken by `current_loop` (4): the drive applies or refuses it whole.
    pub current: Option<ConfigChange>,
    /// Taken by `speed_loop` (3).
    pub speed: Option<SpeedLoopConfig>,
    /// Taken by `position_loop` (2).
    pub position: Option<PositionLoopConfig>,
}

impl ConfigMailbox {
    /// Nothing pending.
    pub const EMPTY: Self = Self {
        current: None,
        speed: None,
        position: None,
    };

    /// Merge `o` into the pending changes (newer values win).
    pub fn merge(&mut self, o: &ConfigMailbox) {
        if let Some(c) = o.current {
            let mut cur = self.current.unwrap_or_default();
            cur.merge(c);
            self.current = Some(cur);
        }
        self.speed = o.speed.or(self.speed);
        self.position = o.position.or(self.position);
    }

    /// A calibration request is waiting for the current loop.
    pub fn calibration_pending(&self) -> bool {
        self.current
            .is_some_and(|c| c.identify || c.calibrate_offsets)
    }

    fn is_empty(&self) -> bool {
        self.current.is_none() && self.speed.is_none() && self.position.is_none()
    }
}

/// The configuration in force, as last requested over the link or loaded
/// from the store (the owning tasks apply it within one position-loop
/// period). Its `watchdog` is the *link* watchdog's setting (the current
/// stage's own command timeout is off in this firmware).
pub use foc_store::Settings;

/// A successful identification, as the current loop publishes it.
#[derive(Clone, Copy, Debug)]
pub struct Identified {
    /// What was measured.
    pub result: IdentificationResult,
    /// The permit the stage holds since: angle calibration, motor model
    /// and current-loop gains.
    pub permit: Calibrated,
    /// Identifications so far (tells the channel a new one happened).
    pub count: u32,
}

/// What the shared state looked like when a frame arrived.
#[derive(Clone, Copy, Debug)]
pub struct Snapshot {
    /// Latest feedback of the current loop.
    pub feedback: Feedback,
    /// Longest current-loop run [cycles].
    pub max_loop_cycles: u32,
    /// The drive's status (started, mode, faulted, calibrated).
    pub status: Status,
    /// The last successful identification.
    pub identified: Option<Identified>,
    /// What the drive has been asked but has not taken yet.
    pub pending: Pending,
}

/// Requests committed to the drive's mailboxes that the current loop may
/// not have taken yet (the status in a [`Snapshot`] is the last period's).
#[derive(Clone, Copy, Debug)]
pub struct Pending {
    /// The operator's command in the mailbox (taken or not).
    pub command: Command,
    /// A calibration (offsets, identification) requested and not taken.
    pub calibration: bool,
}

/// Mutations a frame asked for, committed after it was handled.
#[derive(Clone, Copy, Debug, Default)]
pub struct Outbox {
    /// Command to post.
    pub post: Option<Command>,
    /// Request a fault clear.
    pub clear: bool,
    /// Configuration changes.
    pub config: ConfigMailbox,
}

impl Outbox {
    /// Apply the command part to the mailbox (clear first, as the current
    /// stage does: a command sent with a clear is taken after it).
    pub fn apply_command(&self, slot: &mut CommandSlot) {
        if self.clear {
            slot.request_clear();
        }
        // A keep-alive only feeds the link watchdog (`DeviceState` does
        // that): it never re-posts the last command, which after a fault
        // clear or a timeout reaction would restart the motor on an old
        // setpoint. (The stage's own command timeout is off in this
        // firmware; the link watchdog is the command timeout.)
        if let Some(c) = self.post {
            slot.post(c);
        }
    }
    /// True when something must be written to the command mailbox.
    pub fn touches_command(&self) -> bool {
        self.clear || self.post.is_some()
    }
    /// True when configuration changes are pending.
    pub fn touches_config(&self) -> bool {
        !self.config.is_empty()
    }
}

/// The [`DeviceContext`] of one frame (or one poll).
pub struct Link<'a> {
    /// State when the frame arrived.
    pub snap: Snapshot,
    /// The configuration in force.
    pub settings: &'a mut Settings,
    /// The drive's label (saved with the configuration).
    pub label: &'a mut Label,
    /// The configuration store (`None`: this board's region is unusable).
    pub store: &'a mut Option<BoardStore>,
    /// What to commit.
    pub out: Outbox,
    /// The scope (frames only; `None` in a poll).
    pub scope: Option<&'a mut dyn ScopePort>,
    /// The link-watchdog setting in force (the protocol's
    /// `DeviceState::link_setting`), for the CANopen node's 0x1010 save.
    #[cfg(feature = "can")]
    pub link_setting: WatchdogConfig,
}

impl Link<'_> {
    /// The motor model in use (the identified one after an identification,
    /// see [`Comms::fold_identification`]).
    fn motor(&self) -> foc_core::control::MotorParams {
        self.settings.current.motor
    }

    /// The drive's change for `joint` on the motor's limits `limits`: the
    /// travel range in the rotor frame (or the limits' own range).
    fn joint_change(joint: &JointSetup, limits: &Limits) -> JointChange {
        joint.rotor_change((limits.min_position_rad, limits.max_position_rad))
    }

    /// Make `s` (a whole, validated record's settings) the configuration in
    /// force: every owning task gets its part. The record's calibration
    /// becomes the drive's permit only where the sensor's angle survives a
    /// reset (`AngleKind::zero_survives_reset`); elsewhere its motor model
    /// and gains apply to the calibration the drive has.
    fn adopt(&mut self, s: Settings, label: Label) {
        *self.settings = s;
        *self.label = label;
        let permit = s
            .permit()
            .filter(|_| board::angle_kind().zero_survives_reset());
        let c = self.out.config.current.get_or_insert_with(Default::default);
        c.merge(ConfigChange {
            limits: Some(s.limits),
            current: Some(s.current),
            dividers: Some(s.dividers),
            power: Some(s.power),
            permit,
            mechanics: s.mechanics,
            joint: Some(Self::joint_change(&s.joint, &s.limits)),
            ..ConfigChange::default()
        });
        self.out.config.speed = Some(s.speed);
        self.out.config.position = Some(s.position);
    }

    /// Decode, check and adopt a record: whole, or nothing changes.
    fn apply_record(&mut self, rec: &DriveRecord) -> Result<WatchdogConfig, ErrorCode> {
        let s = persist::admit(rec).map_err(|e| {
            defmt::warn!("store: record refused: {}", e);
            ErrorCode::BadRecord
        })?;
        self.adopt(s, rec.label.clone());
        Ok(persist::link_setting(rec))
    }

    /// A flash operation stalls the processor for seconds: only when the
    /// bridge is off and stays off while it runs. The protocol checked the
    /// last period's status (started, disabled); a command or calibration
    /// committed since (an earlier frame of the same burst) and not yet
    /// taken by the current loop would turn the bridge on during the
    /// stall. Nothing else posts commands while this runs: every other
    /// writer of the mailboxes is a priority-1 task like this one.
    fn quiet(&self) -> Result<(), ErrorCode> {
        if self.snap.pending.command != Command::Disable {
            return Err(ErrorCode::NotDisabled);
        }
        if self.snap.pending.calibration {
            return Err(ErrorCode::Busy);
        }
        // A flash erase stalls the processor (and the current loop) for
        // seconds: never with the brake resistor conducting, which would
        // stay on for the whole stall.
        if self.snap.feedback.power.brake_on {
            return Err(ErrorCode::Busy);
        }
        Ok(())
    }

    fn load_stored(&mut self) -> Result<DriveRecord, ErrorCode> {
        self.quiet()?;
        let store = self.store.as_mut().ok_or(ErrorCode::Unsupported)?;
        match persist::guarded(|| store.load()) {
            Ok(Some(r)) => Ok(r),
            Ok(None) => Err(ErrorCode::NothingStored),
            Err(e) => Err(store_error(e)),
        }
    }

    fn save(&mut self, rec: &DriveRecord) -> Result<(), ErrorCode> {
        self.quiet()?;
        let store = self.store.as_mut().ok_or(ErrorCode::Unsupported)?;
        persist::guarded(|| store.save(rec)).map_err(store_error)?;
        defmt::info!("store: saved \"{=str}\"", rec.label.as_str());
        Ok(())
    }
}

/// A store failure as a Nack, logged.
fn store_error(e: StoreError) -> ErrorCode {
    defmt::warn!("store: {}", e);
    match e {
        StoreError::Record(_) | StoreError::Invalid(_) => ErrorCode::BadRecord,
        _ => ErrorCode::StoreFailed,
    }
}

/// `"1.2.3"` -> `[1, 2, 3]` at compile time (evaluated for a constant: an
/// index out of range fails the build).
#[allow(clippy::indexing_slicing)]
const fn version() -> [u8; 3] {
    let s = env!("CARGO_PKG_VERSION").as_bytes();
    let mut out = [0u8; 3];
    let (mut i, mut part) = (0, 0);
    while i < s.len() && part < 3 {
        let c = s[i];
        if c == b'.' {
            part += 1;
        } else if c.is_ascii_digit() {
            out[part] = out[part].wrapping_mul(10).wrapping_add(c - b'0');
        } else {
            break;
        }
        i += 1;
    }
    out
}

/// Firmware version reported in `Hello`.
pub const FIRMWARE_VERSION: [u8; 3] = version();

impl DeviceContext for Link<'_> {
    fn post(&mut self, cmd: Command) -> Result<(), CommandError> {
        self.out.post = Some(cmd);
        Ok(())
    }
    fn keep_alive(&mut self) {
        // Nothing to post: see `Outbox::apply_command`.
    }
    fn mode(&self) -> Mode {
        self.snap.status.mode
    }
    fn faults(&self) -> (FaultSet, Option<Fault>) {
        (self.snap.feedback.faults, self.snap.feedback.first_fault)
    }
    fn clear_faults(&mut self) {
        self.out.clear = true;
    }
    fn report_fault(&mut self, fault: Fault) {
        let c = self.out.config.current.get_or_insert_with(Default::default);
        c.fault = Some(fault);
    }
    fn limits(&self) -> Limits {
        self.settings.limits
    }
    fn set_limits(&mut self, limits: Limits) -> Result<(), Refusal> {
        if limits.max_current_a > config::MOTOR.1 {
            return Err(Refusal::Unsupported);
        }
        let mut speed = self.settings.speed;
        speed.current_limit_a = limits.max_current_a;
        self.settings.limits = limits;
        self.settings.speed = speed;
        let c = self.out.config.current.get_or_insert_with(Default::default);
        c.limits = Some(limits);
        // Applied after the limits: the travel range stays in force.
        c.joint = Some(Self::joint_change(&self.settings.joint, &limits));
        self.out.config.speed = Some(speed);
        Ok(())
    }
    fn joint(&self) -> JointSetup {
        self.settings.joint
    }
    fn set_joint(&mut self, setup: JointSetup) -> Result<(), Refusal> {
        let change = Self::joint_change(&setup, &self.settings.limits);
        // The drive refuses a range that leaves the active position
        // target outside; the pending command is the one it will have.
        if let Command::Position { rad } = self.snap.pending.command {
            if !(change.min_position_rad..=change.max_position_rad).contains(&rad) {
                return Err(Refusal::NotDisabled);
            }
        }
        self.settings.joint = setup;
        let c = self.out.config.current.get_or_insert_with(Default::default);
        c.joint = Some(change);
        Ok(())
    }
    fn torque_constant_nm_per_a(&self) -> f32 {
        self.motor().torque_constant_nm_per_a()
    }
    fn feedback(&self) -> Feedback {
        self.snap.feedback
    }
    fn set_current_gains(&mut self, gains: CurrentGains) -> Result<(), Refusal> {
        // After an identification `settings.current` holds the measured
        // motor model (decoupling, back-EMF feed-forward): only the gains
        // change.
        let mut cur = self.settings.current;
        gains.apply(&mut cur);
        // The stage keeps its calibration only with values a permit vouches
        // for; the current loop re-checks when it installs them.
        if Calibrated::supplied(self.settings.angle, cur).is_err() {
            return Err(Refusal::Unsupported);
        }
        self.settings.current = cur;
        let c = self.out.config.current.get_or_insert_with(Default::default);
        c.current = Some(cur);
        Ok(())
    }
    fn set_speed_gains(&mut self, gains: SpeedGains) -> Result<(), Refusal> {
        gains.apply(&mut self.settings.speed);
        self.out.config.speed = Some(self.settings.speed);
        Ok(())
    }
    fn set_position_gains(&mut self, gains: PositionGains) -> Result<(), Refusal> {
        // A move may not be faster than a velocity command is allowed to be.
        if gains.max_velocity_rad_s > self.limits().max_velocity_rad_s {
            return Err(Refusal::Unsupported);
        }
        gains.apply(&mut self.settings.position);
        self.out.config.position = Some(self.settings.position);
        Ok(())
    }
    fn set_dividers(&mut self, speed: u16, position: u16) -> Result<(), Refusal> {
        let pwm = board::PWM_FREQUENCY_HZ as f32;
        self.settings.dividers = (speed, position);
        // The slower loops' discrete-time gains follow their new periods.
        self.settings.speed.ts_s = f32::from(speed) / pwm;
        self.settings.position.ts_s = f32::from(position) / pwm;
        let c = self.out.config.current.get_or_insert_with(Default::default);
        c.dividers = Some((speed, position));
        self.out.config.speed = Some(self.settings.speed);
        self.out.config.position = Some(self.settings.position);
        Ok(())
    }
    fn start_calibration(&mut self, routine: Calibration) -> Result<(), Refusal> {
        let change = match routine {
            Calibration::Offsets => ConfigChange {
                calibrate_offsets: true,
                ..ConfigChange::default()
            },
            Calibration::Identification => ConfigChange {
                identify: true,
                ..ConfigChange::default()
            },
            // Alignment alone is part of the identification sequence.
            Calibration::Alignment => return Err(Refusal::Unsupported),
        };
        self.out
            .config
            .current
            .get_or_insert_with(Default::default)
            .merge(change);
        Ok(())
    }
    fn is_calibrated(&self) -> bool {
        self.snap.status.calibrated
    }
    fn status(&self) -> Status {
        self.snap.status
    }
    fn param(&self, id: ParamId) -> Option<f32> {
        Some(match id {
            ParamId::PolePairs => f32::from(self.motor().pole_pairs),
            ParamId::ResistanceOhm => self.motor().r_ohm,
            ParamId::LdH => self.motor().ld_h,
            ParamId::LqH => self.motor().lq_h,
            ParamId::FluxLinkageWb => self.motor().flux_linkage_wb,
            ParamId::PwmFrequencyHz => board::PWM_FREQUENCY_HZ as f32,
            ParamId::SpeedDivider => f32::from(self.settings.dividers.0),
            ParamId::PositionDivider => f32::from(self.settings.dividers.1),
            ParamId::FirmwareVersion => {
                let [a, b, c] = FIRMWARE_VERSION;
                f32::from(a) * 10_000.0 + f32::from(b) * 100.0 + f32::from(c)
            }
            ParamId::BusVoltageV => self.snap.feedback.v_bus_v,
            ParamId::Calibrated => {
                if self.snap.status.calibrated {
                    1.0
                } else {
                    0.0
                }
            }
            ParamId::MaxLoopCycles => self.snap.max_loop_cycles as f32,
            ParamId::CurrentKp => self.settings.current.q_gains.kp_v_per_a,
            ParamId::CurrentKi => self.settings.current.q_gains.ki_v_per_a_s,
            ParamId::SpeedKp => self.settings.speed.kp_a_per_rad_s,
            ParamId::SpeedKi => self.settings.speed.ki_a_per_rad,
            ParamId::PositionKp => self.settings.position.kp_per_s,
            ParamId::ScopeCapacity => config::SCOPE_VALUES as f32,
            // Answered by the protocol layer itself.
            ParamId::ProtocolVersion | ParamId::TelemetryDivider | ParamId::WatchdogTimeout => {
                return None
            }
        })
    }
    fn telemetry(&self) -> Telemetry {
        Telemetry::from_feedback(&self.snap.feedback, self.snap.max_loop_cycles)
    }
    fn firmware_version(&self) -> [u8; 3] {
        FIRMWARE_VERSION
    }
    fn max_stream_hz(&self) -> Option<f32> {
        Some(foc_protocol::device::max_stream_hz(board::SERIAL_BAUD))
    }
    fn scope(&mut self) -> Option<&mut dyn ScopePort> {
        match self.scope.as_mut() {
            Some(s) => Some(&mut **s),
            None => None,
        }
    }
    fn config_record(
        &mut self,
        source: ConfigSource,
        link: WatchdogConfig,
        out: &mut [u8; MAX_RECORD],
    ) -> Result<usize, ErrorCode> {
        let rec = match source {
            ConfigSource::Live => persist::live_record(self.label, self.settings, link),
            ConfigSource::Stored => self.load_stored()?,
        };
        rec.encode(out).map_err(|e| {
            defmt::warn!("store: record does not encode: {}", e);
            ErrorCode::BadRecord
        })
    }
    fn store(
        &mut self,
        op: StoreOp,
        staged: &[u8],
        link: WatchdogConfig,
    ) -> Result<Option<WatchdogConfig>, ErrorCode> {
        // Applying is refused too while something is pending: the drive
        // would refuse the current loop's part and the slower loops would
        // still take theirs.
        self.quiet()?;
        match op {
            StoreOp::Save => {
                let rec = persist::live_record(self.label, self.settings, link);
                self.save(&rec).map(|()| None)
            }
            StoreOp::Erase => {
                let store = self.store.as_mut().ok_or(ErrorCode::Unsupported)?;
                persist::guarded(|| store.erase()).map_err(store_error)?;
                defmt::info!("store: erased (the next boot starts from the build-time defaults)");
                Ok(None)
            }
            StoreOp::Load => {
                let rec = self.load_stored()?;
                self.apply_record(&rec).map(Some)
            }
            StoreOp::Apply | StoreOp::ApplyAndSave => {
                let rec = DriveRecord::decode(staged).map_err(|e| {
                    defmt::warn!("store: staged record refused: {}", e);
                    ErrorCode::BadRecord
                })?;
                // Checked whole before anything is written or applied.
                persist::admit(&rec).map_err(|e| {
                    defmt::warn!("store: staged record refused: {}", e);
                    ErrorCode::BadRecord
                })?;
                if op == StoreOp::ApplyAndSave {
                    self.save(&rec)?;
                }
                self.apply_record(&rec).map(Some)
            }
        }
    }
}

/// The CANopen node's identity (0x1018, 0x1008, 0x1009): no CiA vendor
/// ID is assigned to the project (0); product code and revision are the
/// EDS's (`docs/canopen/foc-drive.eds`), as on the host test bus.
#[cfg(feature = "can")]
pub const CAN_IDENTITY: foc_canopen::node::Identity = foc_canopen::node::Identity {
    vendor_id: 0,
    product_code: foc_canopen::eds::EdsInfo::FOC_DRIVE.product_number,
    revision: foc_canopen::eds::EdsInfo::FOC_DRIVE.revision_number,
    serial: 0,
    device_name: "rust-foc drive",
    hardware_version: board::NAME,
};

#[cfg(feature = "can")]
impl foc_canopen::node::CanDevice for Link<'_> {
    fn identity(&self) -> foc_canopen::node::Identity {
        CAN_IDENTITY
    }
    fn link_setting(&self) -> WatchdogConfig {
        self.link_setting
    }
    /// Only while the drive is quiet (as a configuration save: the flash
    /// write stalls the processor), then into the store's CAN record.
    fn save_comm(&mut self, s: &foc_canopen::node::CommSettings) -> Result<(), ErrorCode> {
        self.quiet()?;
        let store = self.store.as_mut().ok_or(ErrorCode::Unsupported)?;
        persist::guarded(|| store.save_can(&s.to_record())).map_err(store_error)?;
        defmt::info!("store: CAN settings saved: {}", s);
        Ok(())
    }
}

/// Link counters (for the log).
#[derive(Clone, Copy, Debug, Default, defmt::Format)]
pub struct LinkCounters {
    /// Frames handled.
    pub frames: u32,
    /// Replies or samples dropped because the TX ring was full.
    pub tx_dropped: u32,
}

/// The channel's state: UART, decoder, protocol state, settings.
pub struct Comms {
    /// The command UART.
    pub serial: board::CommandSerial,
    /// Frame decoder of the receive direction.
    pub decoder: FrameDecoder,
    /// Protocol state (watchdog, telemetry schedule, retransmission cache).
    pub device: DeviceState,
    /// The configuration in force.
    pub settings: Settings,
    /// The drive's label.
    pub label: Label,
    /// The configuration store.
    pub store: Option<BoardStore>,
    /// The identification last folded into `settings`.
    seen_identification: u32,
    /// Speed and position configurations re-derived from an
    /// identification's mechanics, for the next outbox.
    pending: ConfigMailbox,
    /// Counters.
    pub counters: LinkCounters,
    tx: [u8; MAX_FRAME],
}

impl Comms {
    /// Channel over `serial`, watchdog [`AUTO_WATCHDOG`] (armed by the first
    /// closed-loop command), telemetry off.
    /// The settings, label and store come from `boot` (see `persist`).
    pub fn new(serial: board::CommandSerial, boot: persist::Boot) -> Self {
        let mut device = DeviceState::with_auto_watchdog(AUTO_WATCHDOG);
        // A stored link-watchdog setting other than the automatic one is
        // taken as the host's (see `DeviceState::link_setting`).
        if let Some(link) = boot.link {
            device.restore_link_setting(link);
        }
        Self {
            serial,
            decoder: FrameDecoder::new(),
            device,
            settings: boot.settings,
            label: boot.label,
            store: boot.store,
            seen_identification: 0,
            pending: ConfigMailbox::EMPTY,
            counters: LinkCounters::default(),
            tx: [0; MAX_FRAME],
        }
    }

    /// Save the configuration in force and read it back: true when saved
    /// and equal (the emulated board's store mission).
    #[cfg(feature = "qemu")]
    pub fn save_and_verify(&mut self) -> bool {
        let rec = persist::live_record(&self.label, &self.settings, self.device.link_setting());
        let Some(store) = self.store.as_mut() else {
            defmt::error!("store: none on this run");
            return false;
        };
        match store.save(&rec).and_then(|()| store.load()) {
            Ok(Some(back)) => {
                defmt::info!("store: saved \"{=str}\"", rec.label.as_str());
                back == rec
            }
            Ok(None) => false,
            Err(e) => {
                defmt::error!("store: {}", e);
                false
            }
        }
    }

    /// Take a new identification into the settings: from now on they
    /// carry its angle calibration, motor model and gains (and so a save
    /// stores them).
    fn fold_identification(&mut self, id: Option<Identified>) {
        let Some(id) = id else {
            return;
        };
        if id.count == self.seen_identification {
            return;
        }
        self.seen_identification = id.count;
        self.settings.angle = id.permit.angle();
        self.settings.current = id.permit.current_config();
        self.settings.calibrated = true;
        // The measured mechanics (design §19): the speed and position
        // loops re-derived from them, sent to their tasks with the next
        // outbox (the current stage's observer took them already).
        if let Some(m) = id.result.mechanics {
            let mut c = persist::cascade(&self.settings);
            let m = foc_core::control::Mechanics::from(m);
            if c.set_mechanics(&m) {
                self.settings.mechanics = Some(m);
                self.settings.speed = c.speed;
                self.settings.position = c.position;
                self.pending.speed = Some(c.speed);
                self.pending.position = Some(c.position);
            }
        }
    }

    /// The configurations an identification left for the tasks, once.
    fn take_pending(&mut self, out: &mut Outbox) {
        out.config
            .merge(&core::mem::replace(&mut self.pending, ConfigMailbox::EMPTY));
    }

    /// Queue a whole frame, or nothing when it does not fit (a cut frame
    /// would cost the host the next one too).
    fn send(&mut self, n: usize) {
        let frame = self.tx.get(..n).unwrap_or(&[]);
        if self.serial.tx_free() >= frame.len() {
            self.serial.write(frame);
        } else {
            self.counters.tx_dropped = self.counters.tx_dropped.wrapping_add(1);
        }
    }

    /// Feed received bytes to the protocol until a frame completes or the
    /// UART is drained. `snap` is the shared state now; returns the outbox
    /// of the completed frame (commit it, then call again), or `None` when
    /// no more bytes are waiting.
    pub fn receive(&mut self, snap: Snapshot, scope: &mut dyn ScopePort) -> Option<Outbox> {
        self.fold_identification(snap.identified);
        while let Some(b) = self.serial.read_byte() {
            let mut link = Link {
                snap,
                settings: &mut self.settings,
                label: &mut self.label,
                store: &mut self.store,
                out: Outbox::default(),
                scope: Some(&mut *scope),
                #[cfg(feature = "can")]
                link_setting: self.device.link_setting(),
            };
            if let Some(n) = self
                .device
                .on_byte(&mut link, &mut self.decoder, b, &mut self.tx)
            {
                let out = link.out;
                self.counters.frames = self.counters.frames.wrapping_add(1);
                self.send(n);
                return Some(out);
            }
        }
        None
    }

    /// The telemetry stream alone, at `now_period` (the `stream` task,
    /// more often than [`Comms::poll`]).
    pub fn stream(&mut self, snap: Snapshot, now_period: u32) {
        let mut link = Link {
            snap,
            settings: &mut self.settings,
            label: &mut self.label,
            store: &mut self.store,
            out: Outbox::default(),
            scope: None,
            #[cfg(feature = "can")]
            link_setting: self.device.link_setting(),
        };
        if let Some((seq, msg)) = self.device.poll_stream(&mut link, now_period) {
            if let Ok(n) = encode(seq, &msg, &mut self.tx) {
                self.send(n);
            }
        }
    }

    /// The [`DeviceContext`] of one CAN frame or node tick (the CANopen
    /// node's [`foc_canopen::node::CanDevice`]): `snap` is the shared state
    /// now; commit the link's outbox after the call, as for a protocol
    /// frame.
    ///
    /// A command the node posts also feeds the command channel's link
    /// watchdog ([`Comms::can_posted`]): the node's own supervision is the
    /// heartbeat consumer.
    #[cfg(feature = "can")]
    pub fn can_link(&mut self, snap: Snapshot) -> Link<'_> {
        self.fold_identification(snap.identified);
        Link {
            snap,
            settings: &mut self.settings,
            label: &mut self.label,
            store: &mut self.store,
            out: Outbox::default(),
            scope: None,
            link_setting: self.device.link_setting(),
        }
    }

    /// The CANopen node posted a command (`out`): feed the command
    /// channel's link watchdog, so it does not act against the CAN
    /// master's commands (whichever front end posted last owns the drive).
    #[cfg(feature = "can")]
    pub fn can_posted(&mut self, out: &Outbox) {
        if out.post.is_some() {
            self.device.feed_watchdog();
        }
    }

    /// Link watchdog and telemetry stream, at `now_period` (current-loop
    /// periods). Returns the outbox to commit (a watchdog reaction).
    pub fn poll(&mut self, snap: Snapshot, now_period: u32) -> Outbox {
        self.fold_identification(snap.identified);
        let mut link = Link {
            snap,
            settings: &mut self.settings,
            label: &mut self.label,
            store: &mut self.store,
            out: Outbox::default(),
            scope: None,
            #[cfg(feature = "can")]
            link_setting: self.device.link_setting(),
        };
        let sample = self.device.poll(&mut link, now_period);
        let mut out = link.out;
        self.take_pending(&mut out);
        if let Some((seq, msg)) = sample {
            if let Ok(n) = encode(seq, &msg, &mut self.tx) {
                self.send(n);
            }
        }
        out
    }
}
