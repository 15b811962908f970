//! Host side of the drive's command channel ([`foc_protocol`]).
//!
//! - [`Client`]: typed requests with timeouts, retransmission and
//!   sequence-number checking over any [`Transport`] (TCP, e.g. QEMU's
//!   `-serial tcp:127.0.0.1:PORT,server,nowait`; or a serial port).
//! - [`config`]: configuration records over the link (read, write, store
//!   operations with a longer timeout for flash stalls).
//! - [`joint`]: robot joints: the joint's settings, homing, and texts that
//!   say which frame (output or rotor) a value is in.
//! - [`sim`]: the simulated drive (the real drive of [`foc_simdrive`]:
//!   foc-core's control on the bench plant, behind the device service's
//!   rules, one protocol session per client) served on a TCP socket in
//!   real time, for tests and for trying `foc-ctl` without hardware.
//!
//! ```no_run
//! use foc_ctl::Client;
//! use foc_core::control::Command;
//! use foc_protocol::message::{ParamId, TelemetryRate};
//! use std::time::Duration;
//!
//! let mut c = Client::connect_tcp("127.0.0.1:4444")?;
//! let hello = c.ping()?;
//! println!("protocol v{}", hello.protocol_version);
//! c.set_command(Command::Velocity { rad_s: 50.0 })?;
//! let pp = c.param(ParamId::PolePairs)?;
//! let samples = c.telemetry(TelemetryRate::Hz(100.0), Duration::from_secs(1))?;
//! println!("{pp} pole pairs, {} samples", samples.len());
//! # Ok::<(), foc_ctl::ClientError>(())
//! ```
//!
//! # Where to start reading
//!
//! [`Client`] (typed requests over a [`Transport`]), then [`sim`] (the
//! simulated drive `foc-ctl simulate` serves) and the `foc-ctl` binary's
//! commands in `src/main.rs`.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod calibration;
pub mod config;
pub mod joint;
pub mod refusal;
pub mod scope;
pub mod sensor_check;
pub mod sim;
pub mod transport;
pub mod tune;

use foc_core::control::{Command, Limits};
use foc_protocol::frame::{encode, FrameDecoder, MAX_FRAME};
use foc_protocol::message::{
    Calibration, CurrentGains, ErrorCode, FaultReport, Hello, ParamId, PositionGains, Request,
    Response, SpeedGains, Telemetry, TelemetryRate, WatchdogConfig,
};
use std::collections::VecDeque;
use std::fmt;
use std::io;
use std::net::ToSocketAddrs;
use std::time::{Duration, Instant};
pub use transport::{TcpTransport, Transport};

/// Why a request failed.
#[derive(Debug)]
pub enum ClientError {
    /// The transport failed (connection closed, port gone...).
    Io(io::Error),
    /// No matching reply after all attempts.
    Timeout {
        /// Frames sent (first try + retries).
        attempts: u32,
    },
    /// The device refused (nothing changed on the device).
    Nack(ErrorCode),
    /// A reply of the wrong kind for the request.
    Unexpected(Response),
    /// A configuration transfer that does not add up.
    Transfer(config::TransferError),
    /// The device answers, but what was waited for did not happen (a
    /// scope not triggered, a step response missing...): what and why.
    NotReady(String),
}

impl fmt::Display for ClientError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ClientError::Io(e) => write!(f, "transport error: {e}"),
            ClientError::Timeout { attempts } => {
                write!(f, "no reply from the device after {attempts} attempt(s)")
            }
            ClientError::Nack(e) => write!(f, "refused by the device: {}", describe_error(*e)),
            ClientError::Unexpected(r) => write!(f, "unexpected reply: {r:?}"),
            ClientError::Transfer(e) => write!(f, "configuration transfer failed: {e}"),
            ClientError::NotReady(why) => write!(f, "{why}"),
        }
    }
}

impl std::error::Error for ClientError {}

impl From<io::Error> for ClientError {
    fn from(e: io::Error) -> Self {
        ClientError::Io(e)
    }
}

/// A human-readable Nack reason.
pub fn describe_error(e: ErrorCode) -> String {
    match e {
        ErrorCode::Malformed => "malformed frame".into(),
        ErrorCode::BadCrc => "bad CRC".into(),
        ErrorCode::UnknownMessage => "unknown message".into(),
        ErrorCode::OutOfRange { field } => format!("field {field} out of range"),
        ErrorCode::Faulted => "a fault is latched (clear it first)".into(),
        ErrorCode::Busy => "busy".into(),
        ErrorCode::NotCalibrated => "not calibrated".into(),
        ErrorCode::NotDisabled => "only allowed while disabled".into(),
        ErrorCode::Unsupported => "not supported by this device".into(),
        ErrorCode::StoreFailed => "the flash store failed (see the device log)".into(),
        ErrorCode::BadRecord => {
            "configuration record refused (incomplete, corrupt, other version or out of range; nothing applied)".into()
        }
        ErrorCode::NothingStored => "nothing is stored".into(),
        ErrorCode::ScopeState => {
            "the scope is not in the state this needs (trigger: armed; data: capture done)".into()
        }
        ErrorCode::NeedsAngleSensor => {
            "the drive runs sensorless: torque, position and impedance need the angle sensor (velocity and open loop are taken)".into()
        }
        ErrorCode::Other(c) => format!("error code {c}"),
    }
}

/// Link counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Requests sent (not counting retransmissions).
    pub requests: u64,
    /// Retransmissions.
    pub retransmissions: u64,
    /// Frames that failed to decode on the host.
    pub bad_frames: u64,
    /// Replies that matched no outstanding request (late replies).
    pub stale_replies: u64,
    /// Streamed telemetry samples received.
    pub stream_samples: u64,
    /// Streamed samples lost (gaps in the stream counter).
    pub stream_lost: u64,
}

/// A streamed telemetry sample as received.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StreamSample {
    /// Host time since the client was created.
    pub host_time: Duration,
    /// Stream counter.
    pub seq: u16,
    /// The sample.
    pub sample: Telemetry,
}

/// Most streamed samples kept while waiting for replies.
const MAX_QUEUED: usize = 100_000;

/// A command-channel client.
pub struct Client {
    transport: Box<dyn Transport>,
    decoder: FrameDecoder,
    seq: u16,
    timeout: Duration,
    /// Reply timeout of flash operations (see [`config`]).
    store_timeout: Duration,
    retries: u32,
    queue: VecDeque<StreamSample>,
    last_stream_seq: Option<u16>,
    stats: LinkStats,
    epoch: Instant,
}

/// A random first sequence number. The device answers a repeated frame
/// (same `seq`, same CRC) from its cache without running it again: a new
/// connection that started at 1 as the last one did would have its first
/// command taken for a retransmission of that connection's (two one-shot
/// `foc-ctl mode velocity 50` in a row on one serial port, the second
/// after the watchdog stopped the first: nothing would move).
fn random_seq() -> u16 {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    h.finish() as u16
}

impl Client {
    /// Client over any transport. Sends one 0x00 first so the device drops
    /// whatever it had half-received.
    pub fn new(transport: Box<dyn Transport>) -> Result<Self, ClientError> {
        let mut c = Self {
            transport,
            decoder: FrameDecoder::new(),
            seq: random_seq(),
            timeout: Duration::from_millis(250),
            store_timeout: config::DEFAULT_STORE_TIMEOUT,
            retries: 3,
            queue: VecDeque::new(),
            last_stream_seq: None,
            stats: LinkStats::default(),
            epoch: Instant::now(),
        };
        c.transport.write_all(&[0])?;
        Ok(c)
    }

    /// Connect over TCP (e.g. QEMU's emulated USART).
    pub fn connect_tcp(addr: impl ToSocketAddrs) -> Result<Self, ClientError> {
        Self::new(Box::new(TcpTransport::connect(addr)?))
    }

    /// Open a serial port.
    #[cfg(feature = "serial")]
    pub fn open_serial(path: &str, baud: u32) -> Result<Self, ClientError> {
        Self::new(Box::new(transport::SerialTransport::open(path, baud)?))
    }

    /// Reply timeout per attempt (default 250 ms).
    pub fn set_timeout(&mut self, timeout: Duration) {
        self.timeout = timeout;
    }

    /// Retransmissions after the first attempt (default 3).
    pub fn set_retries(&mut self, retries: u32) {
        self.retries = retries;
    }

    /// Link counters.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    fn next_seq(&mut self) -> u16 {
        self.seq = self.seq.wrapping_add(1);
        if self.seq == 0 {
            self.seq = 1;
        }
        self.seq
    }

    fn queue_stream(&mut self, seq: u16, sample: Telemetry) {
        if let Some(last) = self.last_stream_seq {
            let gap = seq.wrapping_sub(last).wrapping_sub(1);
            // A huge gap is a restart of the stream, not a loss.
            if gap < 0x8000 {
                self.stats.stream_lost += u64::from(gap);
            }
        }
        self.last_stream_seq = Some(seq);
        self.stats.stream_samples += 1;
        if self.queue.len() >= MAX_QUEUED {
            self.queue.pop_front();
        }
        self.queue.push_back(StreamSample {
            host_time: self.epoch.elapsed(),
            seq,
            sample,
        });
    }

    /// One read from the transport (waiting at most until `deadline`):
    /// streamed samples are queued, the first other frame is returned
    /// (any further non-stream frame in the same chunk is counted stale).
    fn pump(&mut self, deadline: Instant) -> Result<Option<(u16, Response)>, ClientError> {
        let mut buf = [0u8; 256];
        let wait = deadline.saturating_duration_since(Instant::now());
        let n = self.transport.read(&mut buf, wait)?;
        let mut found = None;
        for &b in &buf[..n] {
            match self.decoder.feed::<Response>(b) {
                None => {}
                Some(Err(_)) => self.stats.bad_frames += 1,
                Some(Ok(p)) => match p.msg {
                    Response::Stream(t) => self.queue_stream(p.seq, t),
                    other if found.is_none() => found = Some((p.seq, other)),
                    _ => self.stats.stale_replies += 1,
                },
            }
        }
        Ok(found)
    }

    /// Send a request and wait for its reply (same `seq`), retransmitting
    /// the same frame on timeout or on a frame-level Nack. A Nack for the
    /// request itself is returned as [`ClientError::Nack`].
    pub fn request(&mut self, req: &Request) -> Result<Response, ClientError> {
        self.request_timed(req, self.timeout)
    }

    /// [`Self::request`] waiting `timeout` per attempt.
    fn request_timed(&mut self, req: &Request, timeout: Duration) -> Result<Response, ClientError> {
        let seq = self.next_seq();
        let mut frame = [0u8; MAX_FRAME];
        let n = encode(seq, req, &mut frame)
            .map_err(|_| ClientError::Io(io::Error::other("request does not fit a frame")))?;
        self.stats.requests += 1;
        let attempts = self.retries.saturating_add(1);
        for attempt in 0..attempts {
            if attempt > 0 {
                self.stats.retransmissions += 1;
            }
            self.transport.write_all(&frame[..n])?;
            let deadline = Instant::now() + timeout;
            while Instant::now() < deadline {
                match self.pump(deadline)? {
                    None => {}
                    Some((s, reply)) if s == seq => {
                        return match reply {
                            Response::Nack(e) => Err(ClientError::Nack(e)),
                            r => Ok(r),
                        };
                    }
                    // The device could not read our frame: send it again now.
                    Some((0, Response::Nack(ErrorCode::BadCrc | ErrorCode::Malformed))) => break,
                    Some(_) => self.stats.stale_replies += 1,
                }
            }
        }
        Err(ClientError::Timeout { attempts })
    }

    /// Send a request that answers `Ack` (any setting or command).
    pub fn send(&mut self, req: &Request) -> Result<(), ClientError> {
        self.expect_ack(req)
    }

    pub(crate) fn expect_ack(&mut self, req: &Request) -> Result<(), ClientError> {
        match self.request(req)? {
            Response::Ack => Ok(()),
            r => Err(ClientError::Unexpected(r)),
        }
    }

    /// Protocol and firmware versions.
    pub fn ping(&mut self) -> Result<Hello, ClientError> {
        match self.request(&Request::Ping)? {
            Response::Hello(h) => Ok(h),
            r => Err(ClientError::Unexpected(r)),
        }
    }
    /// Keep the active command alive (feeds the device's watchdog).
    pub fn keep_alive(&mut self) -> Result<(), ClientError> {
        self.expect_ack(&Request::KeepAlive)
    }
    /// Set mode and target.
    pub fn set_command(&mut self, cmd: Command) -> Result<(), ClientError> {
        self.expect_ack(&Request::SetCommand(cmd))
    }
    /// Replace the command limits.
    pub fn set_limits(&mut self, limits: Limits) -> Result<(), ClientError> {
        self.expect_ack(&Request::SetLimits(limits))
    }
    /// Current-loop gains.
    pub fn set_current_gains(&mut self, g: CurrentGains) -> Result<(), ClientError> {
        self.expect_ack(&Request::SetCurrentGains(g))
    }
    /// Speed-loop gains.
    pub fn set_speed_gains(&mut self, g: SpeedGains) -> Result<(), ClientError> {
        self.expect_ack(&Request::SetSpeedGains(g))
    }
    /// Position gain and trajectory limits.
    pub fn set_position_gains(&mut self, g: PositionGains) -> Result<(), ClientError> {
        self.expect_ack(&Request::SetPositionGains(g))
    }
    /// Loop dividers (device must be disabled).
    pub fn set_dividers(&mut self, speed: u16, position: u16) -> Result<(), ClientError> {
        self.expect_ack(&Request::SetDividers { speed, position })
    }
    /// Link watchdog.
    pub fn set_watchdog(&mut self, c: WatchdogConfig) -> Result<(), ClientError> {
        self.expect_ack(&Request::SetWatchdog(c))
    }
    /// Start a calibration routine.
    pub fn calibrate(&mut self, routine: Calibration) -> Result<(), ClientError> {
        self.expect_ack(&Request::RunCalibration(routine))
    }
    /// Latched faults.
    pub fn faults(&mut self) -> Result<FaultReport, ClientError> {
        match self.request(&Request::ReadFaults)? {
            Response::Faults(f) => Ok(f),
            r => Err(ClientError::Unexpected(r)),
        }
    }
    /// Clear latched faults.
    pub fn clear_faults(&mut self) -> Result<(), ClientError> {
        self.expect_ack(&Request::ClearFaults)
    }
    /// Read a parameter.
    pub fn param(&mut self, id: ParamId) -> Result<f32, ClientError> {
        match self.request(&Request::ReadParam(id))? {
            Response::Param { id: got, value } if got == id => Ok(value),
            r => Err(ClientError::Unexpected(r)),
        }
    }
    /// Write a parameter ([`ParamId::is_writable`]; a switch 0 or 1).
    pub fn set_param(&mut self, id: ParamId, value: f32) -> Result<(), ClientError> {
        self.expect_ack(&Request::SetParam { id, value })
    }
    /// One telemetry sample now.
    pub fn read_telemetry(&mut self) -> Result<Telemetry, ClientError> {
        match self.request(&Request::ReadTelemetry)? {
            Response::Telemetry(t) => Ok(t),
            r => Err(ClientError::Unexpected(r)),
        }
    }
    /// Start streaming.
    pub fn start_telemetry(&mut self, rate: TelemetryRate) -> Result<(), ClientError> {
        self.last_stream_seq = None;
        self.expect_ack(&Request::StartTelemetry(rate))
    }
    /// Stop streaming.
    pub fn stop_telemetry(&mut self) -> Result<(), ClientError> {
        self.expect_ack(&Request::StopTelemetry)
    }
    /// The next streamed sample, waiting at most `timeout`.
    pub fn next_stream(&mut self, timeout: Duration) -> Result<Option<StreamSample>, ClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(s) = self.queue.pop_front() {
                return Ok(Some(s));
            }
            if Instant::now() >= deadline {
                return Ok(None);
            }
            if self.pump(deadline)?.is_some() {
                self.stats.stale_replies += 1;
            }
        }
    }
    /// Drop queued streamed samples.
    pub fn clear_stream_queue(&mut self) {
        self.queue.clear();
    }
    /// Stream for `duration`, calling `on_sample` for each sample as it
    /// arrives; stops the stream at the end (also on error).
    pub fn telemetry_with(
        &mut self,
        rate: TelemetryRate,
        duration: Duration,
        mut on_sample: impl FnMut(&StreamSample),
    ) -> Result<(), ClientError> {
        self.clear_stream_queue();
        self.start_telemetry(rate)?;
        let end = Instant::now() + duration;
        let result = (|| loop {
            let now = Instant::now();
            if now >= end {
                return Ok(());
            }
            if let Some(s) = self.next_stream(end - now)? {
                on_sample(&s);
            }
        })();
        let stop = self.stop_telemetry();
        result.and(stop)
    }
    /// Stream for `duration` and return the samples.
    pub fn telemetry(
        &mut self,
        rate: TelemetryRate,
        duration: Duration,
    ) -> Result<Vec<StreamSample>, ClientError> {
        let mut v = Vec::new();
        self.telemetry_with(rate, duration, |s| v.push(*s))?;
        Ok(v)
    }
}
