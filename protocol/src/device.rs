//! The device side: requests in, replies out, through a [`DeviceContext`].
//!
//! [`DeviceState`] is what the firmware's communication task owns. For every
//! decoded request it validates *everything* first (finite numbers, ranges,
//! limits, mode, faults, calibration) and only then calls the context, so a
//! Nack always means nothing changed. It also owns the link
//! [`CommandWatchdog`] and the telemetry schedule, both counted in
//! current-loop periods (the [`foc_core::control::Feedback::period`] counter
//! handed to [`DeviceState::poll`]).
//!
//! It also owns the joint's side of the link (design §21, [`crate::joint`]):
//! values of commands and telemetry are converted between the host's
//! output frame and the drive's rotor frame with the context's
//! [`DeviceContext::joint`], commands are checked against the limits in
//! force ([`crate::joint::limits_in_force`]: the motor's, with the joint's
//! travel range), and homing ([`Request::StartHoming`]) is sequenced here:
//! the [`foc_core::control::homing::Homing`] sequencer is stepped at every
//! [`DeviceState::poll`] on [`DeviceContext::feedback`], its commands
//! posted through [`DeviceContext::post`], the frame it finds set with
//! [`DeviceContext::set_joint`].
//!
//! Retransmissions: a host that got no reply sends the very same frame
//! again (same `seq`, same CRC). For requests that change something the
//! state remembers the last one and answers a repeat with the cached reply
//! instead of running it twice (a calibration is not started twice, a fault
//! latched in between is not cleared by a stale clear).
//!
//! ```
//! use foc_protocol::device::{DeviceState, tests_support::RecordingContext};
//! use foc_protocol::message::{Request, Response, ErrorCode};
//! use foc_core::control::Command;
//!
//! let mut ctx = RecordingContext::default();
//! let mut dev = DeviceState::new();
//! // 1e6 A is beyond the limits: Nack, field 1 (the value after the mode), nothing posted.
//! let r = dev.handle(&mut ctx, 1, 0, &Request::SetCommand(Command::Torque { iq_a: 1e6 }));
//! assert_eq!(r, Response::Nack(ErrorCode::OutOfRange { field: 1 }));
//! assert_eq!(ctx.calls, 0);
//! let r = dev.handle(&mut ctx, 2, 0, &Request::SetCommand(Command::Torque { iq_a: 1.0 }));
//! assert_eq!(r, Response::Ack);
//! assert_eq!(ctx.posted, Some(Command::Torque { iq_a: 1.0 }));
//! ```

use crate::config::{Chunk, ConfigSource, Staging, StoreOp, MAX_RECORD};
use crate::frame::{
    encode, FrameDecoder, FrameError, FrameErrorKind, Packet, MAX_FRAME, MAX_PAYLOAD,
};
pub use crate::message::WatchdogConfig;
use crate::message::{
    Calibration, CurrentGains, ErrorCode, FaultReport, Hello, ParamId, PositionGains, Request,
    Response, SpeedGains, Telemetry, TelemetryRate,
};
use foc_core::control::joint::{Impedance, JointSetup};
use foc_core::control::stage::TimeoutReaction;
use foc_core::control::{
    Command, CommandError, Fault, FaultSet, Feedback, Limits, LimitsError, Mode,
};

mod joint;
use joint::HomingRun;

/// Why an operation was refused: the drive's own type
/// ([`foc_core::drive::Refusal`]); a refusing context must not have
/// changed anything.
pub use foc_core::drive::Refusal;
use foc_core::drive::Status;

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
    /// Start a calibration routine (only called while disabled and not
    /// faulted); return [`Refusal::Busy`] if one is running.
    fn start_calibration(&mut self, routine: Calibration) -> Result<(), Refusal>;
    /// True once the drive may run closed loop (offsets and alignment done).
    fn is_calibrated(&self) -> bool;
    /// The drive's status, which the drive's own rules
    /// ([`foc_core::drive::Status`]) are applied to before anything is
    /// handed on. Default: started, with [`Self::mode`], [`Self::faults`]
    /// and [`Self::is_calibrated`]; a device with a start-up phase
    /// overrides it.
    fn status(&self) -> Status {
        Status {
            running: true,
            mode: self.mode(),
            faulted: !self.faults().0.is_empty(),
            calibrated: self.is_calibrated(),
        }
    }
    /// A parameter value, `None` if this device does not have it.
    fn param(&self, id: ParamId) -> Option<f32>;
    /// The latest telemetry sample, rotor frame (e.g.
    /// [`Telemetry::from_feedback`]; the protocol converts it).
    fn telemetry(&self) -> Telemetry;
    /// Firmware version `[major, minor, patch]`.
    fn firmware_version(&self) -> [u8; 3];

    /// The highest telemetry stream rate the link carries [Hz] (`None`: no
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

/// Link watchdog: counts current-loop periods since the last valid command
/// or keep-alive and, when the count passes the timeout while the drive is
/// enabled, reacts as configured (the reactions of
/// [`foc_core::control::stage::TimeoutReaction`]):
///
/// - `Disable`: latch [`Fault::CommandTimeout`] (bridge off until cleared);
/// - `Stop`: post velocity 0;
/// - `Hold`: post a position command at the measured position.
///
/// A `Stop` or `Hold` leaves the bridge on: when the link stays silent for
/// a second timeout after it, the watchdog escalates to `Disable`.
///
/// In impedance mode the reaction is always the one design §21 asks for,
/// whatever is configured: damping only ([`LinkReaction::Damp`]: `kp = 0`,
/// no feed-forward, the command's damping), then `Disable` after a second
/// timeout ([`Self::react`]).
///
/// This watches the *link* from the communication task; the current stage's
/// `command_timeout_periods` stays as the backstop for a dead communication
/// task. Keep-alives refresh both (see [`DeviceContext::keep_alive`]).
///
/// ```
/// use foc_protocol::device::{CommandWatchdog, WatchdogConfig};
/// use foc_core::control::stage::TimeoutReaction;
/// let mut wd = CommandWatchdog::new(WatchdogConfig { timeout_periods: 100, reaction: TimeoutReaction::Stop });
/// assert_eq!(wd.tick(60, true), None);
/// wd.feed();
/// assert_eq!(wd.tick(60, true), None);
/// assert_eq!(wd.tick(60, true), Some(TimeoutReaction::Stop)); // 120 > 100
/// assert_eq!(wd.tick(60, true), None); // 180: reacted once
/// assert_eq!(wd.tick(60, true), Some(TimeoutReaction::Disable)); // 240 > 200
/// assert_eq!(wd.tick(60, true), None); // then nothing until fed again
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CommandWatchdog {
    config: WatchdogConfig,
    age_periods: u32,
    /// Reactions given since the last feed (0, 1, or 2 after escalating).
    reactions: u8,
    /// The first reaction left the bridge on: a second timeout disables.
    escalates: bool,
}

/// What the link watchdog asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkReaction {
    /// Latch [`Fault::CommandTimeout`] (bridge off).
    Disable,
    /// Velocity 0.
    Stop,
    /// Hold the measured position.
    Hold,
    /// Impedance mode: damping only (`kp = 0`, `v_ref = 0`, no
    /// feed-forward, the active damping), bridge on.
    Damp,
}

impl From<TimeoutReaction> for LinkReaction {
    fn from(r: TimeoutReaction) -> Self {
        match r {
            TimeoutReaction::Disable => Self::Disable,
            TimeoutReaction::Stop => Self::Stop,
            TimeoutReaction::Hold => Self::Hold,
        }
    }
}

impl CommandWatchdog {
    /// New watchdog, fed.
    pub const fn new(config: WatchdogConfig) -> Self {
        Self {
            config,
            age_periods: 0,
            reactions: 0,
            escalates: false,
        }
    }
    /// The configuration.
    pub const fn config(&self) -> WatchdogConfig {
        self.config
    }
    /// Replace the configuration (and feed).
    pub fn configure(&mut self, config: WatchdogConfig) {
        self.config = config;
        self.feed();
    }
    /// A valid command or keep-alive arrived.
    pub fn feed(&mut self) {
        self.age_periods = 0;
        self.reactions = 0;
    }
    /// Periods since the last feed (saturating).
    pub const fn age_periods(&self) -> u32 {
        self.age_periods
    }
    /// True after it fired, until fed.
    pub const fn expired(&self) -> bool {
        self.reactions > 0
    }
    /// Advance by `periods`; `enabled` is false while the drive is disabled
    /// (then the age is held at 0). Returns the reaction once when the
    /// timeout passes, and `Disable` once when a `Stop` or `Hold` was
    /// followed by a second timeout of silence.
    pub fn tick(&mut self, periods: u32, enabled: bool) -> Option<TimeoutReaction> {
        self.react(periods, enabled, false).map(|r| match r {
            LinkReaction::Stop => TimeoutReaction::Stop,
            LinkReaction::Hold => TimeoutReaction::Hold,
            LinkReaction::Disable | LinkReaction::Damp => TimeoutReaction::Disable,
        })
    }

    /// As [`Self::tick`], for a drive in impedance mode or not: in
    /// impedance mode the first reaction is [`LinkReaction::Damp`] (then
    /// `Disable` after a second timeout), whatever is configured.
    ///
    /// ```
    /// use foc_protocol::device::{CommandWatchdog, LinkReaction, WatchdogConfig};
    /// use foc_core::control::stage::TimeoutReaction;
    /// let mut wd = CommandWatchdog::new(WatchdogConfig { timeout_periods: 100, reaction: TimeoutReaction::Disable });
    /// assert_eq!(wd.react(120, true, true), Some(LinkReaction::Damp));
    /// assert_eq!(wd.react(70, true, true), None); // 190
    /// assert_eq!(wd.react(20, true, true), Some(LinkReaction::Disable)); // 210 > 200
    /// ```
    pub fn react(&mut self, periods: u32, enabled: bool, impedance: bool) -> Option<LinkReaction> {
        let t = self.config.timeout_periods;
        if t == 0 || !enabled {
            self.age_periods = 0;
            return None;
        }
        self.age_periods = self.age_periods.saturating_add(periods);
        match self.reactions {
            0 if self.age_periods > t => {
                self.reactions = 1;
                let r = if impedance {
                    LinkReaction::Damp
                } else {
                    LinkReaction::from(self.config.reaction)
                };
                self.escalates = r != LinkReaction::Disable;
                Some(r)
            }
            1 if self.escalates && self.age_periods > t.saturating_mul(2) => {
                self.reactions = 2;
                Some(LinkReaction::Disable)
            }
            _ => None,
        }
    }
}

/// The protocol's device-side state: replies, watchdog, telemetry schedule.
#[derive(Clone, Copy, Debug)]
pub struct DeviceState {
    watchdog: CommandWatchdog,
    telemetry_every: u32,
    last_telemetry: u32,
    telemetry_seq: u16,
    last_poll: Option<u32>,
    /// The latest period counter seen by a poll or a stream poll.
    last_seen: Option<u32>,
    /// The next streamed sample is the first of a `StartTelemetry`.
    stream_first: bool,
    last_command: Option<(u16, u32, Response)>,
    /// Armed on the first closed-loop command when the host has not
    /// configured the watchdog itself (`OFF`: never).
    auto_watchdog: WatchdogConfig,
    /// The host sent `SetWatchdog` (its choice stands, `OFF` included).
    host_configured: bool,
    /// A configuration record being written by the host.
    staging: Staging,
    /// The homing running (design §21).
    homing: Option<HomingRun>,
    /// Where homing stands.
    homing_state: crate::joint::HomingState,
    /// The last impedance command posted (rotor frame): the link
    /// watchdog's damping-only reaction keeps its damping.
    last_impedance: Option<Impedance>,
}

impl Default for DeviceState {
    fn default() -> Self {
        Self::new()
    }
}

/// Largest `|value|` accepted for a gain (a sanity bound, not physics).
pub const MAX_GAIN: f32 = 1.0e9;

fn out_of_range(field: u8) -> Response {
    Response::Nack(ErrorCode::OutOfRange { field })
}

/// Check that `x` is finite and within `[lo, hi]`; field number on error.
fn check(x: f32, lo: f32, hi: f32, field: u8) -> Result<(), Response> {
    if x.is_finite() && x >= lo && x <= hi {
        Ok(())
    } else {
        Err(out_of_range(field))
    }
}

/// Map a [`Command::validate`] error on `cmd` to the offending field.
fn command_field(cmd: &Command, e: CommandError) -> ErrorCode {
    match (cmd, e) {
        (_, CommandError::Faulted) => ErrorCode::Faulted,
        (_, CommandError::Busy) => ErrorCode::Busy,
        (_, CommandError::NotCalibrated) => ErrorCode::NotCalibrated,
        (Command::Impedance(i), e) => ErrorCode::OutOfRange {
            field: crate::joint::impedance_field(i, e),
        },
        (
            Command::OpenLoop {
                v_d_v,
                v_q_v,
                omega_e_rad_s,
                ..
            },
            CommandError::NonFinite,
        ) => {
            let field = if !v_d_v.is_finite() {
                1
            } else if !v_q_v.is_finite() {
                2
            } else if !omega_e_rad_s.is_finite() {
                4
            } else {
                1
            };
            ErrorCode::OutOfRange { field }
        }
        (Command::OpenLoop { .. }, CommandError::VelocityOutOfRange) => {
            ErrorCode::OutOfRange { field: 4 }
        }
        // Voltage magnitude (v_d, v_q together): the first of the pair.
        _ => ErrorCode::OutOfRange { field: 1 },
    }
}

/// [`Limits::validate`] (the drive's one check) as a field-exact Nack.
fn validate_limits(l: &Limits) -> Result<(), Response> {
    l.validate().map_err(|e| {
        out_of_range(match e {
            LimitsError::MaxCurrent => 0,
            LimitsError::MaxVelocity => 1,
            LimitsError::MinPosition => 2,
            LimitsError::MaxPosition => 3,
            LimitsError::OpenLoopVoltage => 4,
            LimitsError::OpenLoopOmega => 5,
            LimitsError::MaxStiffness => 6,
            LimitsError::MaxDamping => 7,
        })
    })
}

impl DeviceState {
    /// Watchdog off, telemetry off.
    pub const fn new() -> Self {
        Self {
            watchdog: CommandWatchdog::new(WatchdogConfig::OFF),
            telemetry_every: 0,
            last_telemetry: 0,
            telemetry_seq: 0,
            last_poll: None,
            last_seen: None,
            stream_first: false,
            last_command: None,
            auto_watchdog: WatchdogConfig::OFF,
            host_configured: false,
            staging: Staging::new(),
            homing: None,
            homing_state: crate::joint::HomingState::Idle,
            last_impedance: None,
        }
    }

    /// Watchdog off until the first command that runs the motor (anything
    /// but `Disable`, open loop included) is accepted, which arms `auto`
    /// unless the host has sent
    /// `SetWatchdog` (its choice stands, off included): a host that goes
    /// silent mid-move does not leave the motor running (the firmware's
    /// default).
    pub const fn with_auto_watchdog(auto: WatchdogConfig) -> Self {
        let mut s = Self::new();
        s.auto_watchdog = auto;
        s
    }

    /// With a watchdog configuration (the firmware's default).
    pub const fn with_watchdog(config: WatchdogConfig) -> Self {
        let mut s = Self::new();
        s.watchdog = CommandWatchdog::new(config);
        s
    }

    /// The link watchdog.
    pub const fn watchdog(&self) -> &CommandWatchdog {
        &self.watchdog
    }

    /// A command reached the drive through another front end with its own
    /// link supervision (the CANopen node: its heartbeat consumer): feed
    /// this link's watchdog, so it does not stop or fault a drive that
    /// front end is commanding. The front end that posted last owns the
    /// drive; run one master at a time.
    pub fn feed_watchdog(&mut self) {
        self.watchdog.feed();
    }

    /// The link-watchdog setting a saved configuration carries: the host's
    /// (`SetWatchdog`), or the automatic one.
    pub const fn link_setting(&self) -> WatchdogConfig {
        if self.host_configured {
            self.watchdog.config()
        } else {
            self.auto_watchdog
        }
    }

    /// Take the link-watchdog setting of a configuration loaded at boot
    /// (as [`Request::Store`] does for one loaded later).
    pub fn restore_link_setting(&mut self, c: WatchdogConfig) {
        self.adopt_link_setting(c);
    }

    /// Take the link-watchdog setting of an applied configuration: the
    /// automatic one stays automatic, anything else is as if the host had
    /// sent it.
    fn adopt_link_setting(&mut self, c: WatchdogConfig) {
        if !self.host_configured && c == self.auto_watchdog {
            return;
        }
        self.host_configured = true;
        self.watchdog.configure(c);
    }

    /// Telemetry divider in force (periods; 0 = off).
    pub const fn telemetry_every(&self) -> u32 {
        self.telemetry_every
    }

    /// Handle one decoded request with sequence number `seq` and frame CRC
    /// `crc` (from [`Packet::crc`]; used to recognise a retransmission).
    /// Returns the reply to send with the same `seq`.
    pub fn handle<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        seq: u16,
        crc: u32,
        req: &Request,
    ) -> Response {
        if !req.is_query() {
            if let Some((s, c, reply)) = self.last_command {
                if s == seq && c == crc {
                    return reply;
                }
            }
        }
        let reply = match self.execute(ctx, req) {
            Ok(r) => r,
            Err(nack) => nack,
        };
        if !req.is_query() {
            self.last_command = Some((seq, crc, reply));
        }
        reply
    }

    /// Handle a decoder result: the `(seq, reply)` to send. Frame errors
    /// become Nacks (with `seq = 0` when the CRC was bad, so the sequence
    /// number could not be trusted).
    pub fn handle_frame<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        frame: Result<Packet<Request>, FrameError>,
    ) -> (u16, Response) {
        match frame {
            Ok(p) => (p.seq, self.handle(ctx, p.seq, p.crc, &p.msg)),
            Err(e) => {
                let code = match e.kind {
                    FrameErrorKind::BadCrc => ErrorCode::BadCrc,
                    FrameErrorKind::UnknownTag(_) => ErrorCode::UnknownMessage,
                    FrameErrorKind::BadField(field) => ErrorCode::OutOfRange { field },
                    FrameErrorKind::TooLong
                    | FrameErrorKind::Cobs
                    | FrameErrorKind::Truncated
                    | FrameErrorKind::ShortBody
                    | FrameErrorKind::LongBody => ErrorCode::Malformed,
                };
                (e.seq.unwrap_or(0), Response::Nack(code))
            }
        }
    }

    /// Feed one received byte; when it completes a frame, the encoded reply
    /// is written to `tx` and its length returned.
    pub fn on_byte<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        decoder: &mut FrameDecoder,
        byte: u8,
        tx: &mut [u8; MAX_FRAME],
    ) -> Option<usize> {
        let frame = decoder.feed::<Request>(byte)?;
        let (seq, reply) = self.handle_frame(ctx, frame);
        encode(seq, &reply, tx).ok()
    }

    /// Call regularly (any rate) with the current-loop period counter
    /// (wrapping): steps a homing, runs the watchdog and returns a
    /// telemetry sample (output frame, with its stream counter for `seq`)
    /// when one is due.
    pub fn poll<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        now_period: u32,
    ) -> Option<(u16, Response)> {
        let elapsed = match self.last_poll {
            Some(p) => now_period.wrapping_sub(p),
            None => 0,
        };
        self.last_poll = Some(now_period);
        self.last_seen = Some(now_period);
        self.step_homing(ctx);
        self.run_watchdog(ctx, elapsed);
        self.stream(ctx, now_period)
    }

    /// The link watchdog over `elapsed` periods, and its reaction.
    fn run_watchdog<C: DeviceContext>(&mut self, ctx: &mut C, elapsed: u32) {
        // Held while the drive does not take commands (start-up, a
        // calibration): nothing the link could send would be taken.
        let st = ctx.status();
        let enabled = st.running && st.mode != Mode::Disabled;
        let impedance = st.mode == Mode::Impedance;
        let Some(reaction) = self.watchdog.react(elapsed, enabled, impedance) else {
            return;
        };
        // Rotor frame: the context's own position, posted as is.
        let position_rad = ctx.telemetry().position_rad;
        let cmd = match reaction {
            LinkReaction::Disable => None,
            LinkReaction::Stop => Some(Command::Velocity { rad_s: 0.0 }),
            LinkReaction::Hold => Some(Command::Position { rad: position_rad }),
            LinkReaction::Damp => Some(self.damping_only(ctx, position_rad)),
        };
        let limits = self.limits_in_force(ctx);
        let ok = match cmd {
            Some(c) if ctx.status().check_command(&c, &limits).is_ok() => ctx.post(c).is_ok(),
            _ => false,
        };
        if !ok {
            ctx.report_fault(Fault::CommandTimeout);
        }
    }

    /// The damping-only command of an impedance timeout: the active
    /// impedance command's damping (the drive's, else the last one posted
    /// here), at least the joint's timeout damping.
    fn damping_only<C: DeviceContext>(&self, ctx: &C, position_rad: f32) -> Command {
        let active = match ctx.feedback().active {
            Command::Impedance(i) => Some(i),
            _ => self.last_impedance,
        };
        let limits = self.limits_in_force(ctx);
        let p = foc_core::clamp(
            position_rad,
            limits.min_position_rad,
            limits.max_position_rad,
        );
        let min_kd = ctx.joint().joint.timeout_kd_nm_s_per_rad;
        crate::joint::damping_only(active, min_kd, p)
    }

    /// The limits commands are checked against (rotor frame).
    fn limits_in_force<C: DeviceContext>(&self, ctx: &C) -> Limits {
        crate::joint::limits_in_force(&ctx.limits(), &ctx.joint())
    }

    /// Only the telemetry stream of [`Self::poll`] (no homing step, no
    /// watchdog): for a task that runs more often than the poll, so that
    /// the stream's rate is not bounded by the poll's.
    pub fn poll_stream<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        now_period: u32,
    ) -> Option<(u16, Response)> {
        self.last_seen = Some(now_period);
        self.stream(ctx, now_period)
    }

    /// A telemetry sample (output frame) when one is due.
    fn stream<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        now_period: u32,
    ) -> Option<(u16, Response)> {
        if self.telemetry_every == 0 {
            return None;
        }
        let since = now_period.wrapping_sub(self.last_telemetry);
        if since >= self.telemetry_every {
            // Keep the average rate when polled late; resynchronise when far
            // behind, and on the stream's first sample (its slots start now).
            let first = core::mem::take(&mut self.stream_first);
            self.last_telemetry = if first || since >= self.telemetry_every.saturating_mul(2) {
                now_period
            } else {
                self.last_telemetry.wrapping_add(self.telemetry_every)
            };
            let seq = self.telemetry_seq;
            self.telemetry_seq = self.telemetry_seq.wrapping_add(1);
            return Some((seq, Response::Stream(output_telemetry(ctx))));
        }
        None
    }

    fn execute<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        req: &Request,
    ) -> Result<Response, Response> {
        let nack = |e: ErrorCode| Response::Nack(e);
        let refused = |r: Refusal| Response::Nack(r.into());
        match *req {
            Request::Ping => Ok(Response::Hello(Hello {
                protocol_version: crate::PROTOCOL_VERSION,
                firmware_version: ctx.firmware_version(),
                max_payload: MAX_PAYLOAD as u8,
            })),
            Request::KeepAlive => {
                ctx.keep_alive();
                self.watchdog.feed();
                Ok(Response::Ack)
            }
            Request::SetCommand(cmd) => self.set_command(ctx, cmd),
            Request::SetLimits(l) => {
                validate_limits(&l)?;
                ctx.status().check_config().map_err(refused)?;
                ctx.set_limits(l).map_err(refused)?;
                Ok(Response::Ack)
            }
            Request::SetCurrentGains(g) => {
                for (i, x) in [g.kp_d, g.ki_d, g.kp_q, g.ki_q].into_iter().enumerate() {
                    check(x, 0.0, MAX_GAIN, i as u8)?;
                }
                ctx.status().check_config().map_err(refused)?;
                ctx.set_current_gains(g).map_err(refused)?;
                Ok(Response::Ack)
            }
            Request::SetSpeedGains(g) => {
                check(g.kp_a_per_rad_s, 0.0, MAX_GAIN, 0)?;
                check(g.ki_a_per_rad, 0.0, MAX_GAIN, 1)?;
                ctx.status().check_config().map_err(refused)?;
                ctx.set_speed_gains(g).map_err(refused)?;
                Ok(Response::Ack)
            }
            Request::SetPositionGains(g) => {
                check(g.kp_per_s, 0.0, MAX_GAIN, 0)?;
                check(g.max_velocity_rad_s, f32::MIN_POSITIVE, f32::MAX, 1)?;
                check(g.max_acceleration_rad_s2, f32::MIN_POSITIVE, f32::MAX, 2)?;
                ctx.status().check_config().map_err(refused)?;
                ctx.set_position_gains(g).map_err(refused)?;
                Ok(Response::Ack)
            }
            Request::SetDividers { speed, position } => {
                if speed == 0 {
                    return Err(out_of_range(0));
                }
                if position == 0 {
                    return Err(out_of_range(1));
                }
                ctx.status().check_config().map_err(refused)?;
                ctx.set_dividers(speed, position).map_err(refused)?;
                Ok(Response::Ack)
            }
            Request::SetWatchdog(c) => {
                self.host_configured = true;
                self.watchdog.configure(c);
                Ok(Response::Ack)
            }
            Request::RunCalibration(routine) => {
                ctx.status().check_calibration().map_err(refused)?;
                ctx.start_calibration(routine).map_err(refused)?;
                Ok(Response::Ack)
            }
            Request::ReadFaults => {
                let (set, first) = ctx.faults();
                Ok(Response::Faults(FaultReport::new(set, first)))
            }
            Request::ClearFaults => {
                ctx.clear_faults();
                Ok(Response::Ack)
            }
            Request::ReadParam(id) => {
                let value = match id {
                    ParamId::ProtocolVersion => Some(f32::from(crate::PROTOCOL_VERSION)),
                    ParamId::TelemetryDivider => Some(self.telemetry_every as f32),
                    ParamId::WatchdogTimeout => Some(self.watchdog.config().timeout_periods as f32),
                    _ => ctx.param(id),
                };
                value
                    .map(|value| Response::Param { id, value })
                    .ok_or(nack(ErrorCode::Unsupported))
            }
            Request::ReadTelemetry => Ok(Response::Telemetry(output_telemetry(ctx))),
            Request::SetJoint(j) => self.set_joint(ctx, &j),
            Request::ReadJoint => Ok(Response::Joint(crate::joint::JointSettings::from_setup(
                &ctx.joint(),
            ))),
            Request::StartHoming(h) => self.start_homing(ctx, &h),
            Request::ReadHoming => Ok(Response::Homing(self.homing_state)),
            Request::StartTelemetry(rate) => {
                let mut every = match rate {
                    TelemetryRate::EveryPeriods(0) => return Err(out_of_range(1)),
                    TelemetryRate::EveryPeriods(k) => k,
                    TelemetryRate::Hz(hz) => {
                        let pwm = ctx
                            .param(ParamId::PwmFrequencyHz)
                            .filter(|f| f.is_finite() && *f > 0.0)
                            .ok_or(nack(ErrorCode::Unsupported))?;
                        check(hz, f32::MIN_POSITIVE, pwm, 1)?;
                        let k = pwm / hz + 0.5;
                        // hz <= pwm, so k >= 1.5 > 1; bounded above by u32.
                        if k >= u32::MAX as f32 {
                            return Err(out_of_range(1));
                        }
                        (k as u32).max(1)
                    }
                };
                if let Some(max_hz) = ctx.max_stream_hz() {
                    let pwm = ctx.param(ParamId::PwmFrequencyHz).unwrap_or(f32::NAN);
                    // The rate asked for (a rate, or the divider's), also
                    // refused when the PWM frequency is unknown (NaN).
                    let asked = match rate {
                        TelemetryRate::Hz(hz) => hz,
                        TelemetryRate::EveryPeriods(_) => pwm / every as f32,
                    };
                    if asked.is_nan() || asked > max_hz {
                        return Err(out_of_range(1));
                    }
                    // A rate rounded to whole periods stays within the cap.
                    let floor = pwm / max_hz;
                    if floor.is_finite() && (every as f32) < floor {
                        every = (floor as u32).saturating_add(1);
                    }
                }
                self.telemetry_every = every;
                // First sample at the next poll.
                self.last_telemetry = self.last_seen.unwrap_or(0).wrapping_sub(every);
                self.stream_first = true;
                Ok(Response::Ack)
            }
            Request::StopTelemetry => {
                self.telemetry_every = 0;
                Ok(Response::Ack)
            }
            Request::ReadConfig { source, offset } => self.read_config(ctx, source, offset),
            Request::WriteConfig(chunk) => {
                self.staging.write(&chunk).map_err(nack)?;
                Ok(Response::Ack)
            }
            Request::Store(op) => self.store(ctx, op),
            Request::SetScope(_)
            | Request::ArmScope
            | Request::TriggerScope
            | Request::ReadScope
            | Request::ReadScopeData { .. } => scope_request(ctx, req),
        }
    }

    /// `SetCommand`: values checked field by field (output frame), the
    /// command converted to the rotor frame and checked against the limits
    /// in force and the drive's status, then posted; it aborts a homing.
    fn set_command<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        cmd: Command,
    ) -> Result<Response, Response> {
        precheck_command(&cmd)?;
        let joint = self.host_joint(ctx);
        let rotor = crate::joint::command_to_rotor(&cmd, &joint.frame);
        let limits = crate::joint::limits_in_force(&ctx.limits(), &joint);
        let nack = |e| Response::Nack(command_field(&rotor, e));
        ctx.status().check_command(&rotor, &limits).map_err(nack)?;
        ctx.post(rotor).map_err(nack)?;
        self.abort_homing(ctx);
        self.posted(rotor);
        Ok(Response::Ack)
    }

    /// A command of the host or of homing was posted: the watchdog is
    /// armed (automatic setting) and fed, an impedance command kept for
    /// its damping.
    fn posted(&mut self, rotor: Command) {
        if rotor != Command::Disable
            && !self.host_configured
            && self.watchdog.config().timeout_periods == 0
        {
            self.watchdog.configure(self.auto_watchdog);
        }
        self.watchdog.feed();
        if let Command::Impedance(i) = rotor {
            self.last_impedance = Some(i);
        }
    }

    fn read_config<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        source: ConfigSource,
        offset: u16,
    ) -> Result<Response, Response> {
        // Reading the store may repair it (a write): not while running.
        if source == ConfigSource::Stored {
            ctx.status()
                .check_config()
                .map_err(|r| Response::Nack(r.into()))?;
        }
        let mut buf = [0u8; MAX_RECORD];
        let n = ctx
            .config_record(source, self.link_setting(), &mut buf)
            .map_err(Response::Nack)?;
        let record = buf.get(..n).ok_or(Response::Nack(ErrorCode::BadRecord))?;
        if usize::from(offset) > n {
            return Err(out_of_range(1));
        }
        Chunk::of(record, offset)
            .map(Response::ConfigChunk)
            .ok_or(Response::Nack(ErrorCode::BadRecord))
    }

    fn store<C: DeviceContext>(&mut self, ctx: &mut C, op: StoreOp) -> Result<Response, Response> {
        ctx.status()
            .check_config()
            .map_err(|r| Response::Nack(r.into()))?;
        let mut staged = [0u8; MAX_RECORD];
        let mut n = 0;
        if op.uses_staged() {
            let rec = self
                .staging
                .complete()
                .ok_or(Response::Nack(ErrorCode::BadRecord))?;
            n = rec.len();
            staged
                .get_mut(..n)
                .ok_or(Response::Nack(ErrorCode::BadRecord))?
                .copy_from_slice(rec);
            // Applied or refused, a staged record is used once.
            self.staging.clear();
        }
        let link = ctx
            .store(op, staged.get(..n).unwrap_or(&[]), self.link_setting())
            .map_err(Response::Nack)?;
        if let Some(c) = link {
            self.adopt_link_setting(c);
        }
        Ok(Response::Ack)
    }
}

/// Field-exact reporting of what a conversion or the drive's check would
/// not name: non-finite open-loop values, an impedance command's
/// non-finite values and negative torque limit.
fn precheck_command(cmd: &Command) -> Result<(), Response> {
    match *cmd {
        Command::OpenLoop {
            v_d_v,
            v_q_v,
            omega_e_rad_s,
            ..
        } => {
            for (x, f) in [(v_d_v, 1), (v_q_v, 2), (omega_e_rad_s, 4)] {
                if !x.is_finite() {
                    return Err(out_of_range(f));
                }
            }
            Ok(())
        }
        Command::Impedance(i) => crate::joint::impedance_precheck(&i).map_err(out_of_range),
        _ => Ok(()),
    }
}

/// Bytes of one streamed telemetry frame on the wire (COBS and the
/// delimiter included; the same for every sample: its payload is shorter
/// than COBS's 254-byte block).
pub fn stream_frame_bytes() -> usize {
    let mut buf = [0u8; MAX_FRAME];
    encode(1, &Response::Stream(Telemetry::ZERO), &mut buf).unwrap_or(MAX_FRAME)
}

/// The highest sustained stream rate [Hz] a UART at `baud` (8N1: 10 bits
/// a byte) carries, leaving a tenth of the link for replies.
pub fn max_stream_hz(baud: u32) -> f32 {
    0.9 * baud as f32 / (10.0 * stream_frame_bytes() as f32)
}

/// The scope's requests.
fn scope_request<C: DeviceContext>(ctx: &mut C, req: &Request) -> Result<Response, Response> {
    use crate::scope::{scope_nack, ScopeData, ScopeReport, DATA_PER_FRAME};
    let pwm_hz = ctx.param(ParamId::PwmFrequencyHz).unwrap_or(f32::NAN);
    let now = ctx.feedback();
    let unsupported = Response::Nack(ErrorCode::Unsupported);
    let scope = ctx.scope().ok_or(unsupported)?;
    let refused = |e| Response::Nack(scope_nack(e));
    match *req {
        Request::SetScope(c) => scope.configure(&c).map_err(refused)?,
        Request::ArmScope => scope.arm(&now),
        Request::TriggerScope => scope.force().map_err(refused)?,
        Request::ReadScope => {
            let status = scope.status();
            return Ok(Response::Scope(ScopeReport {
                status,
                sample_period_s: f32::from(status.config.divider) / pwm_hz,
            }));
        }
        Request::ReadScopeData { offset } => {
            let st = scope.status();
            if st.state != foc_core::scope::State::Done {
                return Err(Response::Nack(ErrorCode::ScopeState));
            }
            let total = usize::from(st.captured).saturating_mul(usize::from(st.config.channels));
            if usize::from(offset) > total {
                return Err(out_of_range(0));
            }
            let mut values = [0.0; DATA_PER_FRAME];
            let n = scope.read(usize::from(offset), &mut values);
            return Ok(Response::ScopeData(ScopeData {
                offset,
                count: n.min(DATA_PER_FRAME) as u8,
                values,
            }));
        }
        _ => return Err(Response::Nack(ErrorCode::UnknownMessage)),
    }
    Ok(Response::Ack)
}

/// The context's telemetry in the output frame.
fn output_telemetry<C: DeviceContext>(ctx: &C) -> Telemetry {
    crate::joint::telemetry_to_output(&ctx.telemetry(), &ctx.joint().frame)
}

/// A recording [`DeviceContext`] for tests and examples: stores everything
/// it is given and counts mutating calls, so a test can check that a
/// Nack'd request touched nothing.
pub mod tests_support {
    use super::*;

    /// Records every call; sensible defaults (calibrated, disabled).
    #[derive(Clone, Copy, Debug, PartialEq)]
    pub struct RecordingContext {
        /// Number of mutating calls (post, keep_alive, clear, report,
        /// set_* (joint included), start_*).
        pub calls: u32,
        /// Last posted command.
        pub posted: Option<Command>,
        /// Keep-alives received.
        pub keep_alives: u32,
        /// Mode reported by [`DeviceContext::mode`].
        pub mode: Mode,
        /// Latched faults.
        pub faults: FaultSet,
        /// First fault.
        pub first_fault: Option<Fault>,
        /// Fault clears requested.
        pub clears: u32,
        /// Limits in force.
        pub limits: Limits,
        /// Last current gains.
        pub current_gains: Option<CurrentGains>,
        /// Last speed gains.
        pub speed_gains: Option<SpeedGains>,
        /// Last position gains.
        pub position_gains: Option<PositionGains>,
        /// Last dividers.
        pub dividers: (u16, u16),
        /// Last calibration started.
        pub calibration: Option<Calibration>,
        /// Answer to `is_calibrated`.
        pub calibrated: bool,
        /// Answer to `start_calibration` etc. when set.
        pub refuse: Option<Refusal>,
        /// PWM frequency [Hz].
        pub pwm_hz: f32,
        /// Telemetry sample returned.
        pub sample: Telemetry,
        /// Length of the configuration record it reports (bytes `i * 7 + 3`;
        /// 0: no store, `Unsupported`).
        pub record_len: usize,
        /// The last store operation run.
        pub last_store: Option<StoreOp>,
        /// The staged record it was given (first `staged_len` bytes).
        pub staged: [u8; MAX_RECORD],
        /// Length of `staged`.
        pub staged_len: usize,
        /// The link-watchdog setting it was given last.
        pub link: Option<WatchdogConfig>,
        /// The link-watchdog setting an applied record carries.
        pub applied_link: Option<WatchdogConfig>,
        /// The joint in force (identity frame by default).
        pub joint: JointSetup,
        /// Torque constant [N m/A].
        pub kt_nm_per_a: f32,
        /// The link's stream-rate limit it reports [Hz].
        pub max_stream_hz: Option<f32>,
        /// The scope (64 values; `None`: the device has none).
        pub scope: Option<foc_core::scope::Scope<[f32; 64]>>,
    }

    /// Byte `i` of [`RecordingContext`]'s configuration record.
    pub const fn record_byte(i: usize) -> u8 {
        (i.wrapping_mul(7).wrapping_add(3)) as u8
    }

    impl Default for RecordingContext {
        fn default() -> Self {
            Self {
                calls: 0,
                posted: None,
                keep_alives: 0,
                mode: Mode::Disabled,
                faults: FaultSet::EMPTY,
                first_fault: None,
                clears: 0,
                limits: Limits {
                    max_current_a: 10.0,
                    max_velocity_rad_s: 500.0,
                    min_position_rad: -100.0,
                    max_position_rad: 100.0,
                    max_open_loop_voltage_v: 12.0,
                    max_open_loop_omega_e_rad_s: 1000.0,
                    max_kp_nm_per_rad: 50.0,
                    max_kd_nm_s_per_rad: 2.0,
                },
                current_gains: None,
                speed_gains: None,
                position_gains: None,
                dividers: (10, 20),
                calibration: None,
                calibrated: true,
                refuse: None,
                pwm_hz: 20_000.0,
                sample: Telemetry::ZERO,
                record_len: 0,
                last_store: None,
                staged: [0; MAX_RECORD],
                staged_len: 0,
                max_stream_hz: None,
                scope: Some(foc_core::scope::Scope::new([0.0; 64])),
                link: None,
                applied_link: None,
                joint: crate::joint::NO_JOINT,
                kt_nm_per_a: 0.1,
            }
        }
    }

    impl RecordingContext {
        fn mutate(&mut self) -> Result<(), Refusal> {
            self.calls = self.calls.saturating_add(1);
            match self.refuse {
                Some(r) => Err(r),
                None => Ok(()),
            }
        }
    }

    impl DeviceContext for RecordingContext {
        fn post(&mut self, cmd: Command) -> Result<(), CommandError> {
            self.calls = self.calls.saturating_add(1);
            self.posted = Some(cmd);
            self.mode = cmd.mode();
            Ok(())
        }
        fn keep_alive(&mut self) {
            self.calls = self.calls.saturating_add(1);
            self.keep_alives = self.keep_alives.saturating_add(1);
        }
        fn mode(&self) -> Mode {
            self.mode
        }
        fn faults(&self) -> (FaultSet, Option<Fault>) {
            (self.faults, self.first_fault)
        }
        fn clear_faults(&mut self) {
            self.calls = self.calls.saturating_add(1);
            self.clears = self.clears.saturating_add(1);
            self.faults = FaultSet::EMPTY;
            self.first_fault = None;
        }
        fn report_fault(&mut self, fault: Fault) {
            self.calls = self.calls.saturating_add(1);
            self.faults.insert(fault);
            self.first_fault = self.first_fault.or(Some(fault));
            self.mode = Mode::Disabled;
        }
        fn limits(&self) -> Limits {
            self.limits
        }
        fn set_limits(&mut self, limits: Limits) -> Result<(), Refusal> {
            self.mutate()?;
            self.limits = limits;
            Ok(())
        }
        fn joint(&self) -> JointSetup {
            self.joint
        }
        fn set_joint(&mut self, setup: JointSetup) -> Result<(), Refusal> {
            self.mutate()?;
            self.joint = setup;
            Ok(())
        }
        fn max_stream_hz(&self) -> Option<f32> {
            self.max_stream_hz
        }
        fn scope(&mut self) -> Option<&mut dyn crate::scope::ScopePort> {
            self.scope
                .as_mut()
                .map(|s| s as &mut dyn crate::scope::ScopePort)
        }
        fn torque_constant_nm_per_a(&self) -> f32 {
            self.kt_nm_per_a
        }
        fn set_current_gains(&mut self, gains: CurrentGains) -> Result<(), Refusal> {
            self.mutate()?;
            self.current_gains = Some(gains);
            Ok(())
        }
        fn set_speed_gains(&mut self, gains: SpeedGains) -> Result<(), Refusal> {
            self.mutate()?;
            self.speed_gains = Some(gains);
            Ok(())
        }
        fn set_position_gains(&mut self, gains: PositionGains) -> Result<(), Refusal> {
            self.mutate()?;
            self.position_gains = Some(gains);
            Ok(())
        }
        fn set_dividers(&mut self, speed: u16, position: u16) -> Result<(), Refusal> {
            self.mutate()?;
            self.dividers = (speed, position);
            Ok(())
        }
        fn start_calibration(&mut self, routine: Calibration) -> Result<(), Refusal> {
            self.mutate()?;
            self.calibration = Some(routine);
            Ok(())
        }
        fn is_calibrated(&self) -> bool {
            self.calibrated
        }
        fn param(&self, id: ParamId) -> Option<f32> {
            match id {
                ParamId::PolePairs => Some(7.0),
                ParamId::PwmFrequencyHz => Some(self.pwm_hz),
                ParamId::SpeedDivider => Some(f32::from(self.dividers.0)),
                ParamId::PositionDivider => Some(f32::from(self.dividers.1)),
                ParamId::Calibrated => Some(if self.calibrated { 1.0 } else { 0.0 }),
                _ => None,
            }
        }
        fn telemetry(&self) -> Telemetry {
            self.sample
        }
        fn firmware_version(&self) -> [u8; 3] {
            [0, 1, 0]
        }
        fn config_record(
            &mut self,
            _source: ConfigSource,
            link: WatchdogConfig,
            out: &mut [u8; MAX_RECORD],
        ) -> Result<usize, ErrorCode> {
            if self.record_len == 0 {
                return Err(ErrorCode::Unsupported);
            }
            self.link = Some(link);
            for (i, b) in out.iter_mut().enumerate().take(self.record_len) {
                *b = record_byte(i);
            }
            Ok(self.record_len.min(MAX_RECORD))
        }
        fn store(
            &mut self,
            op: StoreOp,
            staged: &[u8],
            link: WatchdogConfig,
        ) -> Result<Option<WatchdogConfig>, ErrorCode> {
            self.mutate().map_err(ErrorCode::from)?;
            self.last_store = Some(op);
            self.link = Some(link);
            self.staged_len = staged.len();
            if let Some(dst) = self.staged.get_mut(..staged.len()) {
                dst.copy_from_slice(staged);
            }
            Ok(if matches!(op, StoreOp::Save | StoreOp::Erase) {
                None
            } else {
                self.applied_link
            })
        }
    }
}

#[cfg(test)]
mod command_field_tests {
    use super::*;

    #[test]
    fn refusals_of_the_stage_keep_their_own_codes() {
        let cmd = Command::Torque { iq_a: 1.0 };
        assert_eq!(
            command_field(&cmd, CommandError::NotCalibrated),
            ErrorCode::NotCalibrated
        );
        assert_eq!(
            command_field(&cmd, CommandError::Faulted),
            ErrorCode::Faulted
        );
    }
}
