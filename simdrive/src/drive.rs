//! [`HostDrive`]: the real drive on the host, as the protocol and the
//! CANopen node see it ([`DeviceContext`](foc_protocol::DeviceContext)).
//!
//! It is foc-bench's [`Sim`]: the real foc-core
//! [`Cascade`](foc_core::drive::cascade::Cascade) against a motor and
//! inverter of the bench plant ([`Options::setup`]: the emulated board's
//! by default, or a motor file's). It only moves when told to:
//! [`HostDrive::step_periods`] runs `n` PWM periods of drive and plant.
//!
//! Two ways to start ([`Start`]):
//! - [`Start::Calibrated`] (the CAN test bus): calibrated from the bench's
//!   knowledge, as in the bench's closed-loop tests, the current offsets
//!   installed as the firmware's start-up calibration takes them; no
//!   identification on command.
//! - [`Start::FromReset`] (`foc-ctl simulate`): as a board powers up: the
//!   lifecycle's offset calibration and sensor check, then uncalibrated
//!   (open loop only) until an identification on command or a stored
//!   calibration admitted at boot. The identification is the drive's own
//!   (resistance, inductances, alignment, flux linkage, mechanics) on the
//!   plant, with the bench's settings for the motor
//!   ([`foc_bench::identify::config`]); its result is published to the
//!   service as the firmware's current loop publishes it.
//!
//! Its [`DeviceContext`](foc_protocol::DeviceContext) is the firmware's:
//! the link's rules are [`foc_service`]'s with this drive's board facts
//! ([`board`]): a current limit above the setup's maximum current is
//! `Unsupported` (the board's hardware limit), store operations only while
//! quiet. Each call takes a snapshot of the drive, hands it to a [`Link`]
//! and commits the link's outbox at once: commands and fault clears into
//! the drive's mailbox (the drive re-checks them), configuration changes
//! and calibrations to the drive (applied or refused whole at the next
//! period), the speed and position loops' configurations at once (the
//! firmware's loop tasks take them at their next run).
//!
//! The configuration lives in a [`foc_store::Store`] over a RAM NOR flash
//! ([`DriveFlash`]): a save encodes and writes a record; the flash
//! survives [`HostDrive::power_cycle`] (a new simulation, the store
//! re-opened from the raw flash, the record loaded and adopted at boot as
//! the firmware does).
//!
//! The tables kept with the configuration (the anticogging map, the angle
//! correction) take the firmware's path, outside the period's mailbox:
//! installed in the current stage at power-on before the first period and
//! when a link's outbox asks ([`foc_service::Outbox::tables`]: committed
//! at once, between periods, the link having checked the drive is
//! disabled), and taken back from the stage when a calibration measured
//! one ([`foc_service::Service::take_measured_tables`]).
//!
//! ```
//! use foc_simdrive::HostDrive;
//! use foc_protocol::device::DeviceContext;
//! use foc_core::control::Command;
//! let mut d = HostDrive::new();
//! d.post(Command::Velocity { rad_s: 50.0 }).unwrap();
//! d.step_periods(2000); // 100 ms
//! assert!(d.plant_velocity_rad_s() > 25.0);
//! ```

use crate::board::{board, lifecycle, Options, Start};
use foc_bench::mission::{Setup, Sim};
use foc_core::calibration::Calibrated;
use foc_core::drive::{Event, Status};
use foc_core::scope::Scope;
use foc_protocol::device::WatchdogConfig;
use foc_protocol::message::ErrorCode;
use foc_service::{Identified, Link, Outbox, Pending, RecordStore, Service, Snapshot};
use foc_store::fake::FakeFlash;
use foc_store::{DriveRecord, Label, Settings, Store};

/// The drive's configuration flash: 4 pages of 4 KiB, 4-byte words (a
/// page holds the largest record, 2 KiB with both tables).
pub type DriveFlash = FakeFlash<4, 4096, 4>;
/// The store's region of [`DriveFlash`] (all of it).
pub const STORE_RANGE: core::ops::Range<u32> = 0..16384;

/// The real drive on the host (see the module docs).
pub struct HostDrive {
    opts: Options,
    /// The link's rules and the configuration in force.
    service: Service,
    /// Drive and plant.
    pub sim: Sim,
    /// `None` only transiently (re-opened at a power cycle) or if the
    /// region is unusable.
    store: Option<Store<DriveFlash>>,
    /// PWM periods run since power-on.
    periods: u64,
    /// The last successful identification, as the current loop publishes
    /// it (the service folds it in at the next link call).
    identified: Option<Identified>,
    /// Commands the link has committed since power-on (tells a server
    /// which client commanded last).
    posts: u64,
    /// The link-watchdog setting of the link now talking to the drive (a
    /// saved record carries it).
    link_setting: WatchdogConfig,
    /// Tables measured by a calibration since power-on (the current loop's
    /// count of `CoggingMeasured` and `EncoderLinearised`).
    tables_measured: u32,
    /// The scope (design §22), recording the period's feedback.
    pub scope: Scope<Vec<f32>>,
    /// The CAN node's communication settings stored in the flash, as
    /// loaded at power-on (and updated by a save).
    #[cfg(feature = "canopen")]
    pub(crate) comm: Option<foc_canopen::node::CommSettings>,
}

impl Default for HostDrive {
    fn default() -> Self {
        Self::new()
    }
}

impl HostDrive {
    /// The CAN test bus's drive ([`Options::default`]) on a blank flash,
    /// powered on.
    pub fn new() -> Self {
        Self::with_flash(DriveFlash::new())
    }

    /// As [`Self::new`] on `flash` (e.g. one written by another drive).
    pub fn with_flash(flash: DriveFlash) -> Self {
        Self::with_options(Options::default(), flash)
    }

    /// A drive with `opts` on `flash`, powered on.
    pub fn with_options(opts: Options, flash: DriveFlash) -> Self {
        let service = Service::new(board(&opts));
        let sim = Sim::new(&opts.setup, service.cascade(), false);
        let scope = Scope::new(vec![0.0; opts.scope_values]);
        let mut d = Self {
            opts,
            service,
            sim,
            store: Store::new(flash, STORE_RANGE).ok(),
            periods: 0,
            identified: None,
            posts: 0,
            link_setting: WatchdogConfig::OFF,
            tables_measured: 0,
            scope,
            #[cfg(feature = "canopen")]
            comm: None,
        };
        d.power_on();
        d
    }

    /// Boot: the stored record (if any, and admitted) or the build-time
    /// settings; a fresh simulation with them.
    fn power_on(&mut self) {
        #[cfg(feature = "canopen")]
        self.load_comm();
        let board = *self.service.board();
        (self.service, _) = Service::boot(board, self.store.as_mut());
        let setup = &self.opts.setup;
        let config = self.service.cascade();
        let permit = self.service.settings().permit();
        let mut sim = Sim::new(setup, config, false);
        match self.opts.start {
            Start::Calibrated => {
                if let Some(p) = permit {
                    sim.cascade.set_calibration(&p);
                }
                // The firmware calibrates its current offsets at start-up.
                let o = setup.bench.sensors.current_offset_a;
                sim.set_current_offsets(foc_core::frames::Abc::new(
                    o[0] as f32,
                    o[1] as f32,
                    o[2] as f32,
                ));
            }
            Start::FromReset => {
                // Raw samples until the lifecycle hands over its offsets.
                sim.set_current_offsets(foc_core::frames::Abc::default());
                sim.cascade = foc_core::drive::cascade::Cascade::from_reset(
                    config,
                    lifecycle(setup, &config, permit),
                );
            }
        }
        // The stored tables, before the first period (as the firmware
        // installs them before its interrupt runs); admitted with the
        // record, whose current limit is the stage's, so the stage takes
        // them (else it keeps none and so does the service).
        let _taken = self.service.install_tables(&mut sim.cascade.current);
        self.sim = sim;
        self.periods = 0;
        self.identified = None;
        self.tables_measured = 0;
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
            self.step();
        }
    }

    /// One PWM period: drive and plant, the scope recording the period's
    /// feedback, an identification's result published, a measured table
    /// taken into the configuration in force, the end stops.
    fn step(&mut self) {
        self.sim.step();
        self.scope.record(self.sim.cascade.feedback());
        let event = self.sim.cascade.last_output().and_then(|o| o.event);
        if matches!(
            event,
            Some(Event::CoggingMeasured { .. } | Event::EncoderLinearised { .. })
        ) {
            self.tables_measured = self.tables_measured.wrapping_add(1);
            self.service
                .take_measured_tables(self.tables_measured, &self.sim.cascade.current);
        }
        if let Some(Event::Identified(result)) = event {
            let c = self.sim.cascade.current.config();
            if let Ok(permit) = Calibrated::supplied(c.angle, c.current) {
                let count = self.identified.map_or(0, |i| i.count).wrapping_add(1);
                self.identified = Some(Identified {
                    result,
                    permit,
                    count,
                });
            }
        }
        self.hold_at_end_stops();
        self.periods = self.periods.saturating_add(1);
    }

    /// The mechanical end stops ([`Options::end_stops_rad`], in the
    /// drive's rotor frame): the rotor stops dead at either.
    fn hold_at_end_stops(&mut self) {
        let (lo, hi) = self.opts.end_stops_rad;
        let p = self.sim.true_position_rad();
        let w = self.sim.plant.omega_m_rad_s();
        // The plant's `Real` is f32 with its `plant-f32` feature.
        #[allow(clippy::unnecessary_cast)]
        let offset = self.sim.plant.position_rad() as f64 - p;
        let (stop, outward) = if p < f64::from(lo) {
            (lo, w < 0.0)
        } else if p > f64::from(hi) {
            (hi, w > 0.0)
        } else {
            return;
        };
        self.sim.plant.set_position((f64::from(stop) + offset) as _);
        if outward {
            self.sim.plant.set_speed(0.0);
        }
    }

    /// Latch `fault` at the next period, as a supervisor would (bridge
    /// off; e.g. to test how a host sees a fault).
    pub fn trip(&mut self, fault: foc_core::control::Fault) {
        self.sim.cascade.request(foc_core::drive::ConfigChange {
            fault: Some(fault),
            ..Default::default()
        });
        self.step();
    }

    /// Run the identification now, through the service's rules as a host's
    /// request would, and step the drive until it is calibrated or
    /// `max_s` simulated seconds have passed: the calibrated flag.
    pub fn identify(&mut self, max_s: f32) -> bool {
        use foc_protocol::message::Calibration;
        let asked = self.with_link(|l| {
            foc_protocol::DeviceContext::start_calibration(l, Calibration::Identification)
        });
        if asked.is_err() {
            return false;
        }
        let n = (max_s * self.pwm_hz() as f32) as u64;
        for _ in 0..n {
            self.step();
            let st = self.status();
            if st.calibrated && self.identified.is_some() && st.running {
                // The service takes the result at the next link call.
                self.with_link(|_| ());
                return true;
            }
        }
        false
    }

    /// Run the start-up (offsets, sensor check) to its end, at most 1 s
    /// simulated: `true` when the drive runs.
    pub fn start_up(&mut self) -> bool {
        for _ in 0..self.pwm_hz() {
            if self.status().running {
                return true;
            }
            self.step();
        }
        self.status().running
    }

    /// Calibrate from the bench's knowledge, as a finished identification
    /// would with exact results: the start-up run to its end (at most 1 s
    /// simulated), the setup's exact angle calibration and motor with the
    /// configuration's gains installed and published to the service. For
    /// tests and demos that are not about the identification (`foc-ctl
    /// simulate --calibrated`); `false` if the drive did not start or
    /// refused the permit.
    pub fn calibrate_from_bench(&mut self) -> bool {
        self.start_up();
        let config = self.service.cascade();
        let permit = self.opts.setup.supplied_calibration(&config);
        self.sim.cascade.request(foc_core::drive::ConfigChange {
            permit: Some(permit),
            ..Default::default()
        });
        self.step();
        if !self.status().calibrated {
            return false;
        }
        let m = config.current.current.motor;
        let count = self.identified.map_or(0, |i| i.count).wrapping_add(1);
        self.identified = Some(Identified {
            result: foc_core::calibration::identification::IdentificationResult {
                r_ohm: m.r_ohm,
                ld_h: m.ld_h,
                lq_h: m.lq_h,
                flux_linkage_wb: m.flux_linkage_wb,
                mechanics: None,
                angle: permit.angle(),
                pole_pairs: m.pole_pairs,
            },
            permit,
            count,
        });
        self.with_link(|_| ());
        true
    }

    /// PWM periods run since power-on.
    pub fn periods(&self) -> u64 {
        self.periods
    }

    /// PWM frequency \[Hz\].
    pub fn pwm_hz(&self) -> u32 {
        self.service.board().pwm_hz
    }

    /// The bench setup (motor, inverter, sensors) the drive runs on.
    pub fn setup(&self) -> &Setup {
        &self.opts.setup
    }

    /// The plant's true mechanical velocity [rad/s].
    pub fn plant_velocity_rad_s(&self) -> f32 {
        self.sim.plant.omega_m_rad_s() as f32
    }

    /// The configuration in force.
    pub fn settings(&self) -> &Settings {
        self.service.settings()
    }

    /// The tables in force (the anticogging map, the angle correction:
    /// what a save stores).
    pub fn tables(&self) -> &foc_store::settings::Tables {
        self.service.tables()
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

    /// The link-watchdog setting of the link talking to the drive now (a
    /// save writes it into the record; default: the one loaded at boot,
    /// else off).
    pub fn set_link_setting(&mut self, s: WatchdogConfig) {
        self.link_setting = s;
    }

    /// Commands the link has committed since power-on.
    pub fn posts(&self) -> u64 {
        self.posts
    }

    /// The drive's status (started, mode, faulted, calibrated).
    pub fn status(&self) -> Status {
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
            status: self.status(),
            identified: self.identified,
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
        let setting = self.link_setting_in_force();
        let mut link = self.service.link(snap, self.store.as_mut(), None, setting);
        let r = f(&mut link);
        let out = link.out;
        self.commit(&out);
        r
    }

    /// The link setting a save records: the one set by the server, else
    /// the one loaded at boot, else off.
    pub(crate) fn link_setting_in_force(&self) -> WatchdogConfig {
        if self.link_setting != WatchdogConfig::OFF {
            return self.link_setting;
        }
        self.service
            .boot_link_setting()
            .unwrap_or(WatchdogConfig::OFF)
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
            self.posts = self.posts.wrapping_add(1);
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
        // Between periods, the link having checked the drive is disabled
        // (the firmware takes the drive's lock from its low priority).
        if out.tables {
            let _logged = self.service.install_tables(&mut c.current);
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

    /// The configuration store (`None`: unusable region).
    pub fn store_mut(&mut self) -> Option<&mut Store<DriveFlash>> {
        self.store.as_mut()
    }
}

foc_service::forward_device_context!(HostDrive, scope: scope);
