//! The simulated device of `foc-ctl simulate`: the real drive
//! ([`foc_simdrive::HostDrive`]: foc-core's cascade, identification
//! included, on the bench plant, behind the device service's rules) with
//! one protocol session per client ([`SimDevice`]), served on TCP in real
//! time or faster ([`SimServer`]).
//!
//! Several clients at once: each connection is a session with the
//! firmware's protocol state ([`DeviceState`]: retransmissions, its own
//! telemetry stream, its link watchdog, armed by its first command that
//! runs the motor, as on a board: [`AUTO_WATCHDOG_S`]). The drive is
//! shared. The session that posted the last command owns the drive: the
//! other sessions' watchdogs are fed (one front end commands at a time,
//! as with [`DeviceState::feed_watchdog`]); the owner's keeps counting
//! after its client disconnects, so a one-shot `foc-ctl mode velocity 50`
//! stops about a second later, as on hardware.
//!
//! ```no_run
//! use std::net::TcpListener;
//! let server = foc_ctl::sim::SimServer::spawn(TcpListener::bind("127.0.0.1:0")?)?;
//! let mut client = foc_ctl::Client::connect_tcp(server.addr())?;
//! client.ping()?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod server;

pub use foc_simdrive::{HostDrive, Options, Start};
pub use server::SimServer;

use foc_core::control::stage::TimeoutReaction;
use foc_protocol::device::{DeviceState, WatchdogConfig};
use foc_protocol::frame::{encode, FrameDecoder, MAX_FRAME};
use foc_protocol::joint::HomingState;
use foc_store::Label;
use std::path::Path;

/// The link watchdog a session arms at its first command that runs the
/// motor, unless its host configured one \[s\] (the firmware's
/// `AUTO_WATCHDOG`: stop after a second without a request).
pub const AUTO_WATCHDOG_S: f32 = 1.0;

/// Label of a drive without a stored one.
pub const DEFAULT_LABEL: &str = "simulated drive";

/// Bytes a session may hold for a client that does not read before
/// streamed samples are dropped (and counted lost by the client, from the
/// stream's counter).
pub const MAX_BACKLOG: usize = 64 * 1024;

/// A client's session (see the module docs).
#[derive(Debug)]
struct Session {
    id: u64,
    state: DeviceState,
    decoder: FrameDecoder,
    /// Encoded frames waiting for the client.
    out: Vec<u8>,
    /// The client is still connected.
    open: bool,
    /// Streamed samples dropped because the client did not read.
    dropped: u64,
}

/// The simulated device: the drive and its clients' sessions.
pub struct SimDevice {
    /// The drive.
    pub drive: HostDrive,
    sessions: Vec<Session>,
    next_id: u64,
    /// The session that posted the last command.
    owner: Option<u64>,
    posts_seen: u64,
    /// The drive's homing state (the last any session reported).
    homing: HomingState,
    /// The link-watchdog setting in force (the automatic one until a host
    /// configures one).
    link_setting: WatchdogConfig,
    /// Streamed samples dropped for sessions that have ended.
    dropped_closed: u64,
}

impl core::fmt::Debug for SimDevice {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("SimDevice")
            .field("periods", &self.drive.periods())
            .field("settings", self.drive.settings())
            .field("sessions", &self.sessions)
            .field("owner", &self.owner)
            .finish()
    }
}

impl Default for SimDevice {
    /// The emulated board's motor (the QEMU plant's).
    fn default() -> Self {
        Self::new(Options::simulator(foc_bench::scope_step::emulated_setup()))
    }
}

impl SimDevice {
    /// A device with a fresh drive of `opts` on a blank flash.
    pub fn new(opts: Options) -> Self {
        Self::with_drive(HostDrive::with_options(opts, Default::default()))
    }

    /// A device on `drive` (labelled [`DEFAULT_LABEL`] unless its stored
    /// record gave it a label), its start-up run (50 ms simulated: a host
    /// connects to a drive that has booted).
    pub fn with_drive(mut drive: HostDrive) -> Self {
        drive.start_up();
        if drive.label().as_str().is_empty() {
            drive.set_label(Label::try_from(DEFAULT_LABEL).unwrap_or_default());
        }
        Self {
            drive,
            sessions: Vec::new(),
            next_id: 0,
            owner: None,
            posts_seen: 0,
            homing: HomingState::Idle,
            link_setting: WatchdogConfig::OFF,
            dropped_closed: 0,
        }
        .with_link_setting()
    }

    /// The link setting at power-on: the one loaded at boot, else the
    /// automatic one.
    fn with_link_setting(mut self) -> Self {
        self.link_setting = self
            .drive
            .boot_link_setting()
            .unwrap_or_else(|| self.auto_watchdog());
        self
    }

    /// The watchdog a session arms at its first motion command.
    fn auto_watchdog(&self) -> WatchdogConfig {
        WatchdogConfig {
            timeout_periods: (AUTO_WATCHDOG_S * self.drive.pwm_hz() as f32) as u32,
            reaction: TimeoutReaction::Stop,
        }
    }

    /// `foc-ctl simulate --motor FILE`: the drive on a motor file's motor
    /// and inverter.
    pub fn from_motor_file(path: &Path) -> Result<Self, String> {
        let setup = foc_bench::mission::Setup::load(path).map_err(|e| e.to_string())?;
        Ok(Self::new(Options::simulator(setup)))
    }

    /// Open a session for a new client: its id.
    pub fn open(&mut self) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        let auto = self.auto_watchdog();
        let mut state = DeviceState::with_auto_watchdog(auto);
        if self.link_setting != auto {
            state.restore_link_setting(self.link_setting);
        }
        state.share_homing_state(self.homing);
        self.sessions.push(Session {
            id,
            state,
            decoder: FrameDecoder::new(),
            out: Vec::new(),
            open: true,
            dropped: 0,
        });
        id
    }

    /// The client of session `id` left: its session ends, unless it owns
    /// the drive (its watchdog keeps counting).
    pub fn close(&mut self, id: u64) {
        if let Some(s) = self.sessions.iter_mut().find(|s| s.id == id) {
            s.open = false;
        }
        self.drop_closed();
    }

    fn drop_closed(&mut self) {
        let owner = self.owner;
        let gone: u64 = self
            .sessions
            .iter()
            .filter(|s| !s.open && Some(s.id) != owner)
            .map(|s| s.dropped)
            .sum();
        self.dropped_closed += gone;
        self.sessions.retain(|s| s.open || Some(s.id) == owner);
    }

    /// Sessions held (connected clients, and a disconnected owner).
    pub fn sessions(&self) -> usize {
        self.sessions.len()
    }

    /// Bytes received from session `id`'s client: requests handled, the
    /// replies queued for it.
    pub fn receive(&mut self, id: u64, bytes: &[u8]) {
        let Some(k) = self.sessions.iter().position(|s| s.id == id) else {
            return;
        };
        let mut tx = [0u8; MAX_FRAME];
        for &b in bytes {
            let Some(s) = self.sessions.get_mut(k) else {
                return;
            };
            self.drive.set_link_setting(s.state.link_setting());
            if let Some(n) = s.state.on_byte(&mut self.drive, &mut s.decoder, b, &mut tx) {
                s.out.extend_from_slice(tx.get(..n).unwrap_or_default());
            }
            self.note_owner(id);
        }
        self.share_homing(id);
        self.share_link_setting(id);
        self.drop_closed();
    }

    /// Session `id`'s link-watchdog setting, when its host configured one
    /// (`SetWatchdog`, a loaded record), is the drive's: every session
    /// takes it, as the one link of a board would.
    fn share_link_setting(&mut self, id: u64) {
        let Some(c) = self
            .sessions
            .iter()
            .find(|s| s.id == id)
            .map(|s| s.state.link_setting())
        else {
            return;
        };
        if c == self.link_setting {
            return;
        }
        self.link_setting = c;
        for s in self.sessions.iter_mut().filter(|s| s.id != id) {
            s.state.restore_link_setting(c);
        }
    }

    /// Streamed samples dropped so far because a client did not read.
    pub fn dropped(&self) -> u64 {
        self.sessions.iter().map(|s| s.dropped).sum::<u64>() + self.dropped_closed
    }

    /// Put back what could not be sent to session `id`'s client (it goes
    /// first next time).
    pub fn unsend(&mut self, id: u64, rest: &[u8]) {
        if let Some(s) = self.sessions.iter_mut().find(|s| s.id == id) {
            let mut v = rest.to_vec();
            v.append(&mut s.out);
            s.out = v;
        }
    }

    /// Session `id`'s homing state is the drive's: every session reports
    /// it (a homing a session runs stays its own).
    fn share_homing(&mut self, id: u64) {
        let Some(state) = self
            .sessions
            .iter()
            .find(|s| s.id == id)
            .map(|s| s.state.homing_state())
        else {
            return;
        };
        if state == self.homing {
            return;
        }
        self.homing = state;
        for s in self.sessions.iter_mut().filter(|s| s.id != id) {
            s.state.share_homing_state(state);
        }
    }

    /// A session's request or homing posted a command: it owns the drive.
    fn note_owner(&mut self, id: u64) {
        if self.drive.posts() != self.posts_seen {
            self.posts_seen = self.drive.posts();
            self.owner = Some(id);
        }
    }

    /// Run the drive `periods` PWM periods; after each, every session's
    /// watchdog, homing and telemetry (the others' watchdogs fed).
    pub fn advance(&mut self, periods: u32) {
        let mut tx = [0u8; MAX_FRAME];
        for _ in 0..periods {
            self.drive.step_periods(1);
            let now = self.drive.periods() as u32;
            for k in 0..self.sessions.len() {
                let Some(s) = self.sessions.get_mut(k) else {
                    break;
                };
                let id = s.id;
                if self.owner != Some(id) {
                    s.state.feed_watchdog();
                }
                self.drive.set_link_setting(s.state.link_setting());
                if let Some((seq, r)) = s.state.poll(&mut self.drive, now) {
                    if let Ok(n) = encode(seq, &r, &mut tx) {
                        if s.out.len() + n <= MAX_BACKLOG && s.open {
                            s.out.extend_from_slice(tx.get(..n).unwrap_or_default());
                        } else {
                            s.dropped += 1;
                        }
                    }
                }
                self.note_owner(id);
                self.share_homing(id);
            }
        }
        self.drop_closed();
    }

    /// Take what waits for session `id`'s client.
    pub fn take_output(&mut self, id: u64) -> Vec<u8> {
        self.sessions
            .iter_mut()
            .find(|s| s.id == id)
            .map(|s| std::mem::take(&mut s.out))
            .unwrap_or_default()
    }
}
