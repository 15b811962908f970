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

mod context;
mod joint;
mod requests;
#[cfg(any(test, feature = "test-support"))]
pub mod tests_support;
mod watchdog;
pub use context::DeviceContext;
use joint::HomingRun;
use requests::out_of_range;
pub use requests::MAX_GAIN;
pub use watchdog::{CommandWatchdog, LinkReaction};

/// Why an operation was refused: the drive's own type
/// ([`foc_core::drive::Refusal`]); a refusing context must not have
/// changed anything.
pub use foc_core::drive::Refusal;
use foc_core::drive::Status;

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
            // Without the angle sensor there is no position to hold: stop.
            LinkReaction::Hold if st.angle_only_in_motion() => {
                Some(Command::Velocity { rad_s: 0.0 })
            }
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
}

/// Bytes of one streamed telemetry frame on the wire (COBS and the
/// delimiter included; the same for every sample: its payload is shorter
/// than COBS's 254-byte block).
pub fn stream_frame_bytes() -> usize {
    let mut buf = [0u8; MAX_FRAME];
    encode(1, &Response::Stream(Telemetry::ZERO), &mut buf).unwrap_or(MAX_FRAME)
}

/// The highest sustained stream rate \[Hz\] a UART at `baud` (8N1: 10 bits
/// a byte) carries, leaving a tenth of the link for replies.
pub fn max_stream_hz(baud: u32) -> f32 {
    0.9 * baud as f32 / (10.0 * stream_frame_bytes() as f32)
}

/// The context's telemetry in the output frame.
fn output_telemetry<C: DeviceContext>(ctx: &C) -> Telemetry {
    crate::joint::telemetry_to_output(&ctx.telemetry(), &ctx.joint().frame)
}

#[cfg(test)]
mod command_field_tests {
    use super::requests::command_field;
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
