//! [`HostDrive`]: the real drive on the host, as the protocol and the
//! CANopen node see it ([`DeviceContext`](foc_protocol::DeviceContext)).
//!
//! It is foc-bench's [`Sim`]: the real foc-core [`foc_core::drive::cascade::Cascade`]
//! against the emulated board's motor and inverter
//! ([`foc_bench::scope_step::emulated_setup`]), calibrated from the
//! bench's knowledge as in the bench's closed-loop tests, its current
//! offsets taken as the firmware's start-up calibration takes them. It
//! only moves when told to: [`HostDrive::step_periods`] runs `n` PWM
//! periods of drive and plant.
//!
//! Its [`DeviceContext`](foc_protocol::DeviceContext) is the firmware's: the link's rules are
//! [`foc_service`]'s, with this drive's board facts ([`host_board`]): a
//! current limit above [`MAX_CURRENT_A`] is `Unsupported`, identification
//! too (the drive starts calibrated from the bench's knowledge), store
//! operations only while quiet. Each call takes a snapshot of the drive,
//! hands it to a [`Link`] and commits the link's outbox at once: commands
//! and fault clears into the drive's mailbox (the drive re-checks them),
//! configuration changes to the drive (applied or refused whole at the
//! next period), the speed and position loops' configurations at once
//! (the firmware's loop tasks take them at their next run).
//!
//! The configuration lives in a [`foc_store::Store`] over a RAM NOR flash
//! ([`DriveFlash`]): a save encodes and writes a record; the flash
//! survives [`HostDrive::power_cycle`] (a new simulation, the store
//! re-opened from the raw flash, the record loaded and adopted at boot as
//! the firmware does).
//!
//! ```
//! use foc_canbus::host_drive::HostDrive;
//! use foc_protocol::device::DeviceContext;
//! use foc_core::control::Command;
//! let mut d = HostDrive::new();
//! d.post(Command::Velocity { rad_s: 50.0 }).unwrap();
//! d.step_periods(2000); // 100 ms
//! assert!(d.plant_velocity_rad_s() > 25.0);
//! ```

use foc_bench::mission::{Setup, Sim};
use foc_bench::plant::{EncoderFault, Faults, Phase, PhaseShort};
use foc_bench::scope_step::emulated_setup;
use foc_canopen::node::CommSettings;
use foc_core::drive::Status;
use foc_protocol::device::WatchdogConfig;
use foc_protocol::message::ErrorCode;
use foc_service::{Board, Link, Outbox, Pending, RecordStore, Service, Snapshot};
use foc_store::fake::FakeFlash;
use foc_store::{DriveRecord, Label, Settings, Store};

/// The drive's configuration flash: 4 pages of 1 KiB, 4-byte words.
pub type DriveFlash = FakeFlash<4, 1024, 4>;
/// The store's region of [`DriveFlash`] (all of it).
const STORE_RANGE: core::ops::Range<u32> = 0..4096;

/// Current limit of the emulated board \[A\] (limits above it are refused).
pub const MAX_CURRENT_A: f32 = foc_bench::scope_step::MAX_CURRENT_A;

/// Version reported by the host drive.
pub const FIRMWARE_VERSION: [u8; 3] = [0, 1, 0];

/// A fault to inject into the plant or its sensors.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    /// `encoder`: the encoder reading freezes (a broken encoder): at 100
    /// rad/s the drive latches `AngleSensorStuck` within about 450 periods.
    EncoderStuck,
    /// `short` (or `overcurrent`): a phase-to-phase short A-B at the motor
    /// terminals through 10 mohm: `OverCurrentPhase` within 2 periods.
    PhaseShort,
    /// `open-phase`: phase C's lead disconnected (the drive has no
    /// open-phase detection: unloaded, nothing latches).
    OpenPhase,
    /// `nan-current`: the phase A current channel reads NaN: `NonFinite`
    /// at once.
    NanCurrent,
    /// `clear`: every injected fault removed (the drive's latched faults
    /// stay until cleared).
    Clear,
}

impl FaultKind {
    /// From its control-channel name.
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "encoder" | "encoder-stuck" => Self::EncoderStuck,
            "short" | "overcurrent" | "over-current" => Self::PhaseShort,
            "open-phase" => Self::OpenPhase,
            "nan-current" => Self::NanCurrent,
            "clear" => Self::Clear,
            _ => return None,
        })
    }
}

/// The host drive's board facts: the emulated board's configuration,
/// calibrated from the bench's knowledge (the sensor's zero is the
/// plant's, so it survives a power cycle), no identification on command,
/// no scope, the CANopen identity of the host test bus.
pub fn host_board(setup: &Setup) -> Board {
    let pwm_hz = setup.bench.pwm_frequency_hz as u32;
    let mut b = Board::new(setup.cascade_config(), pwm_hz, MAX_CURRENT_A);
    b.base.angle = setup.true_angle_calibration();
    b.base.calibrated = true;
    b.zero_survives_reset = true;
    b.identifies = false;
    b.firmware_version = FIRMWARE_VERSION;
    b.can_identity = crate::canopen_node::IDENTITY;
    b
}

/// The real drive on the host (see the module docs).
pub struct HostDrive {
    setup: Setup,
    /// The link's rules and the configuration in force.
    service: Service,
    /// Drive and plant.
    pub sim: Sim,
    /// `None` only transiently (re-opened at a power cycle) or if the
    /// region is unusable.
    store: Option<Store<DriveFlash>>,
    /// PWM periods run since power-on.
    periods: u64,
    /// The CAN node's communication settings stored in the flash, as
    /// loaded at power-on (and updated by a save).
    comm: Option<CommSettings>,
}

impl Default for HostDrive {
    fn default() -> Self {
        Self::new()
    }
}

impl HostDrive {
    /// A drive on a blank flash, powered on.
    pub fn new() -> Self {
        Self::with_flash(DriveFlash::new())
    }

    /// A drive on `flash` (e.g. one written by another drive), powered on.
    pub fn with_flash(flash: DriveFlash) -> Self {
        let setup = emulated_setup();
        let service = Service::new(host_board(&setup));
        let sim = Sim::new(&setup, service.cascade(), false);
        let mut d = Self {
            setup,
            service,
            sim,
            store: Store::new(flash, STORE_RANGE).ok(),
            periods: 0,
            comm: None,
        };
        d.power_on();
        d
    }

    /// Boot: the stored record (if any, and admitted) or the build-time
    /// settings; a fresh simulation with them.
    fn power_on(&mut self) {
        self.comm = match self.store.as_mut().map(|s| s.load_can()) {
            Some(Ok(Some(r))) => CommSettings::from_record(&r).ok(),
            _ => None,
        };
        let board = *self.service.board();
        (self.service, _) = Service::boot(board, self.store.as_mut());
        let mut sim = Sim::new(&self.setup, self.service.cascade(), false);
        if let Some(p) = self.service.settings().permit() {
            sim.cascade.set_calibration(&p);
        }
        // The firmware calibrates its current offsets at start-up.
        let o = self.setup.bench.sensors.current_offset_a;
        sim.set_current_offsets(foc_core::frames::Abc::new(
            o[0] as f32,
            o[1] as f32,
            o[2] as f32,
        ));
        self.sim = sim;
        self.periods = 0;
    }

    /// Power-cycle: a new simulation (rotor at rest, no injected faults),
    /// the store re-opened from the same flash and its record adopted.
    pub fn power_cycle(&mut self) {
        let flash = self.store.take().map(Store::into_flash).unwrap_or_default();
        self.store = Store::new(flash, STORE_RANGE).ok();
        self.power_on();
    }

    /// A copy of the raw flash (e.g. to build another drive on it with
    /// [`Self::with_flash`]); `None` if the store is unusable.
    pub fn flash_copy(&mut self) -> Option<DriveFlash> {
        let s = self.store.take()?;
        let f = s.into_flash();
        self.store = Store::new(f.clone(), STORE_RANGE).ok();
        Some(f)
    }

    /// Run the drive and its plant for `n` PWM periods.
    pub fn step_periods(&mut self, n: u32) {
        for _ in 0..n {
            self.sim.step();
        }
        self.periods = self.periods.saturating_add(u64::from(n));
    }

    /// PWM periods run since power-on.
    pub fn periods(&self) -> u64 {
        self.periods
    }

    /// PWM frequency \[Hz\].
    pub fn pwm_hz(&self) -> u32 {
        self.service.board().pwm_hz
    }

    /// The plant's true mechanical velocity [rad/s].
    pub fn plant_velocity_rad_s(&self) -> f32 {
        self.sim.plant.omega_m_rad_s() as f32
    }

    /// The configuration in force.
    pub fn settings(&self) -> &Settings {
        self.service.settings()
    }

    /// The drive's label (saved with the configuration).
    pub fn label(&self) -> &Label {
        self.service.label()
    }

    /// Replace the label (saved with the next save).
    pub fn set_label(&mut self, label: Label) {
        self.service.set_label(label);
    }

    /// The link-watchdog setting of the record loaded at the last boot.
    pub fn boot_link_setting(&self) -> Option<WatchdogConfig> {
        self.service.boot_link_setting()
    }

    /// The CAN node's saved communication settings, if any.
    pub fn saved_comm(&self) -> Option<CommSettings> {
        self.comm
    }

    /// Note that the CAN node's communication settings were saved.
    pub(crate) fn comm_saved(&mut self, s: CommSettings) {
        self.comm = Some(s);
    }

    /// Inject a fault into the plant or its sensors.
    pub fn inject(&mut self, kind: FaultKind) {
        let f = self.sim.plant.faults_mut();
        match kind {
            FaultKind::EncoderStuck => f.encoder = EncoderFault::Stuck,
            FaultKind::PhaseShort => {
                f.phase_short = Some(PhaseShort {
                    a: Phase::A,
                    b: Phase::B,
                    r_ohm: 0.01,
                })
            }
            FaultKind::OpenPhase => f.disconnected_phase = Some(Phase::C),
            FaultKind::NanCurrent => f.nan_current = Some(Phase::A),
            FaultKind::Clear => *f = Faults::default(),
        }
    }

    /// The drive's status (started, mode, faulted, calibrated).
    fn drive_status(&self) -> Status {
        self.sim
            .cascade
            .lifecycle()
            .status(&self.sim.cascade.current)
    }

    /// The drive now, as the link sees it.
    fn snapshot(&self) -> Snapshot {
        let c = &self.sim.cascade;
        Snapshot {
            feedback: *c.feedback(),
            max_loop_cycles: 0,
            status: self.drive_status(),
            identified: None,
            pending: Pending {
                command: c.mailbox().command,
                calibration: c.calibration_pending(),
            },
        }
    }

    /// The snapshot and the service (the link's read-only calls).
    pub fn view_parts(&self) -> (Snapshot, &Service) {
        (self.snapshot(), &self.service)
    }

    /// Run `f` on a link to the drive now and commit its outbox.
    pub fn with_link<R>(&mut self, f: impl FnOnce(&mut Link<'_, Store<DriveFlash>>) -> R) -> R {
        let snap = self.snapshot();
        let setting = self
            .service
            .boot_link_setting()
            .unwrap_or(WatchdogConfig::OFF);
        let mut link = self.service.link(snap, self.store.as_mut(), None, setting);
        let r = f(&mut link);
        let out = link.out;
        self.commit(&out);
        r
    }

    /// A link's outbox into the drive: the fault clear, then the command
    /// (the drive re-checks it, as the firmware's current loop does the
    /// mailbox's), the current loop's change (taken at the next period),
    /// the slower loops' configurations.
    fn commit(&mut self, out: &Outbox) {
        let c = &mut self.sim.cascade;
        if out.clear {
            c.clear_faults();
        }
        if let Some(cmd) = out.post {
            // Refused by the drive as the firmware's current loop refuses
            // a mailbox command: the status tells.
            let _ = c.command(cmd);
        }
        if let Some(change) = out.config.current {
            c.request(change);
        }
        if let Some(s) = out.config.speed {
            c.speed.speed_loop().set_config(s);
        }
        if let Some(p) = out.config.position {
            c.position.set_config(p);
        }
    }

    /// The record of the live settings with the link watchdog `link`.
    pub fn live_record(&self, link: WatchdogConfig) -> DriveRecord {
        self.service.live_record(link)
    }

    /// The stored record, if any.
    pub fn stored_record(&mut self) -> Result<Option<DriveRecord>, ErrorCode> {
        let store = self.store.as_mut().ok_or(ErrorCode::Unsupported)?;
        RecordStore::load(store).map_err(foc_service::records::store_error)
    }
}

foc_service::forward_device_context!(HostDrive);
