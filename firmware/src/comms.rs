//! The command and telemetry channel: `foc_protocol` over the board's
//! command UART (`board::CommandSerial`, USART2 on every board).
//!
//! Two priority-1 tasks use it (see `main.rs`): the `serial` task (bound to
//! `board::SERIAL_IRQ`) feeds received bytes to
//! [`DeviceState::on_byte`] and queues the replies; `housekeeping` calls
//! [`DeviceState::poll`] for the link watchdog and streamed telemetry.
//! Both hold [`Comms`] (a shared resource of theirs, so never contended).
//!
//! The link's rules are `foc_service`'s (host-tested there, the same code
//! the CAN host bus and `foc-ctl simulate` run): every frame is handled on
//! a [`Snapshot`] of the shared state taken under one lock, and what it
//! asks for comes back as an [`Outbox`], committed into the RTIC shared
//! resources right after (`main.rs`):
//!
//! - commands, keep-alives and fault clears go to the `command`
//!   `CommandSlot` (read by the current loop);
//! - configuration changes go to the `config_request` [`ConfigMailbox`],
//!   one part per owning task: the current loop takes limits, current gains,
//!   dividers, the offset calibration and a fault to latch; the speed loop
//!   its configuration; the position loop its own. Each applies its part at
//!   its next run (at most one position-loop period later). Changes merge:
//!   a newer value replaces a pending one, so back-to-back requests are
//!   never lost.
//!
//! This board's facts for those rules ([`persist::board_facts`]): its
//! current limit (`config::MOTOR`), PWM rate, sensor kind, scope size and
//! the UART's telemetry rate. Its store is wrapped so that every flash
//! operation runs with the watchdog stretched ([`persist::GuardedStore`]).
//!
//! The joint (design §21): the protocol converts between the host's output
//! frame and the drive's rotor frame with the joint in force, and runs
//! homing in `poll` (housekeeping, 50 Hz; its commands go to the `command`
//! mailbox like the host's).
//!
//! The tables kept with the configuration (the anticogging map and the
//! angle sensor's correction, design §32, §33: 1.5 KB) never cross the
//! configuration mailbox (its change is copied into the current loop
//! every period it waits). They move between the service and the drive's
//! current stage from priority 1 under the `drive` lock, with the bridge
//! off: [`install_tables`] when a link's outbox asks
//! (`Outbox::tables`: a record applied, a switch written), through
//! `Drive::stage_while_disabled`; [`take_measured_tables`] before each
//! link once the current loop has counted a measured table, so the next
//! save stores it. The stored ones are installed in `init`, before the
//! interrupt runs.

use crate::app::BoardDrive;
use crate::persist::{self, GuardedStore};
use board_support::board;
use core::sync::atomic::{AtomicBool, Ordering};
use foc_core::control::Feedback;
use foc_core::scope::{Scope, ScopeConfig, ScopeError, ScopeStatus};
use foc_protocol::frame::{encode, FrameDecoder, MAX_FRAME};
use foc_protocol::scope::ScopePort;
use foc_protocol::{DeviceState, WatchdogConfig};
use foc_service::Service;
pub use foc_service::{ConfigMailbox, Identified, Outbox, Pending, Snapshot};

/// The link of one CAN message or node tick on this board.
#[cfg(feature = "can")]
pub type Link<'a> = foc_service::Link<'a, GuardedStore>;

/// Link watchdog armed by the first closed-loop command over the link
/// (unless the host configured it with `SetWatchdog`, `foc-ctl watchdog`):
/// 1 s without a command or keep-alive stops the motor (velocity 0), one
/// more second disables it (`CommandTimeout`). Commands that do not come
/// over the link (`config::START_COMMAND`) do not arm it.
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

/// Firmware version reported in `Hello`.
pub const FIRMWARE_VERSION: [u8; 3] = foc_service::board::parse_version(env!("CARGO_PKG_VERSION"));

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

/// Link counters (for the log).
#[derive(Clone, Copy, Debug, Default, defmt::Format)]
pub struct LinkCounters {
    /// Frames handled.
    pub frames: u32,
    /// Replies or samples dropped because the TX ring was full.
    pub tx_dropped: u32,
}

/// The channel's state: UART, decoder, protocol state, the service.
pub struct Comms {
    /// The command UART.
    pub serial: board::CommandSerial,
    /// Frame decoder of the receive direction.
    pub decoder: FrameDecoder,
    /// Protocol state (watchdog, telemetry schedule, retransmission cache).
    pub device: DeviceState,
    /// The link's rules and the configuration in force.
    pub service: Service,
    /// The configuration store (`None`: this board's region is unusable).
    pub store: Option<GuardedStore>,
    /// Counters.
    pub counters: LinkCounters,
    tx: [u8; MAX_FRAME],
}

impl Comms {
    /// Channel over `serial`, watchdog [`AUTO_WATCHDOG`] (armed by the first
    /// closed-loop command), telemetry off.
    /// The service and store come from `boot` (see `persist`).
    pub fn new(serial: board::CommandSerial, boot: persist::Boot) -> Self {
        let mut device = DeviceState::with_auto_watchdog(AUTO_WATCHDOG);
        // A stored link-watchdog setting other than the automatic one is
        // taken as the host's (see `DeviceState::link_setting`).
        if let Some(link) = boot.service.boot_link_setting() {
            device.restore_link_setting(link);
        }
        Self {
            serial,
            decoder: FrameDecoder::new(),
            device,
            service: boot.service,
            store: boot.store.map(GuardedStore),
            counters: LinkCounters::default(),
            tx: [0; MAX_FRAME],
        }
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
        while let Some(b) = self.serial.read_byte() {
            let setting = self.device.link_setting();
            let mut link = self
                .service
                .link(snap, self.store.as_mut(), Some(&mut *scope), setting);
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
        let setting = self.device.link_setting();
        let mut link = self.service.link(snap, self.store.as_mut(), None, setting);
        if let Some((seq, msg)) = self.device.poll_stream(&mut link, now_period) {
            if let Ok(n) = encode(seq, &msg, &mut self.tx) {
                self.send(n);
            }
        }
    }

    /// The link of one CAN frame or node tick (the CANopen node's
    /// `CanDevice`): `snap` is the shared state now; commit the link's
    /// outbox after the call, as for a protocol frame.
    ///
    /// A command the node posts also feeds the command channel's link
    /// watchdog ([`Comms::can_posted`]): the node's own supervision is the
    /// heartbeat consumer.
    #[cfg(feature = "can")]
    pub fn can_link(&mut self, snap: Snapshot) -> Link<'_> {
        let setting = self.device.link_setting();
        self.service.link(snap, self.store.as_mut(), None, setting)
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
    /// periods). Returns the outbox to commit (a watchdog reaction, and
    /// the loops' configurations an identification re-derived).
    pub fn poll(&mut self, snap: Snapshot, now_period: u32) -> Outbox {
        let setting = self.device.link_setting();
        let mut link = self.service.link(snap, self.store.as_mut(), None, setting);
        let sample = self.device.poll(&mut link, now_period);
        let mut out = link.out;
        out.config.merge(&self.service.take_pending());
        if let Some((seq, msg)) = sample {
            if let Ok(n) = encode(seq, &msg, &mut self.tx) {
                self.send(n);
            }
        }
        out
    }
}

/// The tables are being moved under the drive's lock ([`with_drive`]).
static TABLES_BUSY: AtomicBool = AtomicBool::new(false);

/// True while the tables are moved under the drive's lock: the current
/// loop held off for it (with the bridge off) does not count its late run
/// as an overrun.
pub fn tables_busy() -> bool {
    TABLES_BUSY.load(Ordering::Relaxed)
}

/// `f` on the drive under its lock from priority 1: a move of the tables
/// and their checks (about 3.5k cycles, the current loop held off while
/// the bridge is off), flagged for the current loop's overrun check.
fn with_drive<R>(
    drive: impl rtic::Mutex<T = BoardDrive>,
    f: impl FnOnce(&mut BoardDrive) -> R,
) -> R {
    TABLES_BUSY.store(true, Ordering::Relaxed);
    let mut drive = drive;
    let r = drive.lock(f);
    TABLES_BUSY.store(false, Ordering::Relaxed);
    r
}

/// After a calibration measured a table (the current loop counts
/// `CoggingMeasured` and `EncoderLinearised` in `measured`): the stage's
/// tables become the service's, so a save stores them. Call it before
/// each link; the drive is locked only when the count moved.
pub fn take_measured_tables(
    measured: impl rtic::Mutex<T = u32>,
    drive: impl rtic::Mutex<T = BoardDrive>,
    comms: impl rtic::Mutex<T = Comms>,
) {
    let (mut measured, mut comms) = (measured, comms);
    let count = measured.lock(|n| *n);
    comms.lock(|c| {
        if c.service.tables_seen() != count {
            with_drive(drive, |d| c.service.take_measured_tables(count, d.stage()));
        }
    });
}

/// A link's outbox asked for the tables in force to be installed
/// (`Outbox::tables`): into the current stage the drive lends while
/// disabled, whole; otherwise the stage's stay and become the service's
/// again (logged by the service).
pub fn install_tables(
    out: &Outbox,
    drive: impl rtic::Mutex<T = BoardDrive>,
    comms: impl rtic::Mutex<T = Comms>,
) {
    if !out.tables {
        return;
    }
    let mut comms = comms;
    comms.lock(|c| {
        with_drive(drive, |d| {
            if let Some(stage) = d.stage_while_disabled() {
                let _logged = c.service.install_tables(stage);
            } else {
                c.service.tables_not_installed(d.stage());
            }
        })
    });
}

/// The shared state now, for the link: feedback, timing, status, the last
/// identification and what is pending in the mailboxes, all under one
/// lock (one critical section at the current loop's priority, a copy of
/// about 300 bytes), so every part is of the same period.
pub fn snapshot(
    feedback: impl rtic::Mutex<T = Feedback>,
    timing: impl rtic::Mutex<T = crate::timing::LoopTiming>,
    status: impl rtic::Mutex<T = foc_core::drive::Status>,
    identified: impl rtic::Mutex<T = Option<Identified>>,
    command: impl rtic::Mutex<T = foc_core::control::CommandSlot>,
    request: impl rtic::Mutex<T = ConfigMailbox>,
) -> Snapshot {
    use rtic::mutex::prelude::*;
    (feedback, timing, status, identified, command, request).lock(|fb, tm, st, id, c, r| Snapshot {
        feedback: *fb,
        max_loop_cycles: tm.max_cycles,
        status: *st,
        identified: *id,
        pending: Pending {
            command: c.command,
            calibration: r.calibration_pending(),
        },
    })
}

/// Commit a link's outbox into the loops' mailboxes, under one lock:
/// configuration changes merged into `request`, then the command part into
/// `command` (a fault clear before the command).
pub fn commit(
    out: &Outbox,
    command: impl rtic::Mutex<T = foc_core::control::CommandSlot>,
    request: impl rtic::Mutex<T = ConfigMailbox>,
) {
    use rtic::mutex::prelude::*;
    if !out.touches_config() && !out.touches_command() {
        return;
    }
    (command, request).lock(|c, r| {
        r.merge(&out.config);
        out.apply_command(c);
    });
}
