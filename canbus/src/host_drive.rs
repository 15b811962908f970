//! [`HostDrive`]: the real drive on the host, as the protocol and the
//! CANopen node see it ([`DeviceContext`]).
//!
//! It is foc-bench's [`Sim`]: the real foc-core [`foc_core::drive::cascade::Cascade`]
//! against the emulated board's motor and inverter
//! ([`foc_bench::scope_step::emulated_setup`]), calibrated from the
//! bench's knowledge as in the bench's closed-loop tests, its current
//! offsets taken as the firmware's start-up calibration takes them. It
//! only moves when told to: [`HostDrive::step_periods`] runs `n` PWM
//! periods of drive and plant.
//!
//! Its [`DeviceContext`] mirrors the firmware's (`firmware/src/comms.rs`,
//! `impl DeviceContext for Link`): commands are posted to the drive's
//! mailbox (the drive re-checks them), a keep-alive posts nothing (it
//! only feeds the link watchdog the protocol owns), a fault clear is a
//! request the drive takes at its next period, limits / current gains /
//! dividers / a fault to latch / a calibration go to the drive as a
//! [`ConfigChange`] (applied or refused whole at the next period), the
//! speed and position loops take their new configurations at once (the
//! firmware's loop tasks at their next run). The same board rules: a
//! current limit above [`MAX_CURRENT_A`] and non-positive current gains
//! are `Unsupported`, identification and alignment are `Unsupported` (the
//! drive starts calibrated), store operations only while the mailbox
//! holds `Disable`.
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
use foc_core::control::joint::JointSetup;
use foc_core::control::{Command, CommandError, Fault, FaultSet, Feedback, Limits, Mode};
use foc_core::drive::cascade::CascadeConfig;
use foc_core::drive::{ConfigChange, JointChange, Status};
use foc_protocol::config::{ConfigSource, StoreOp, MAX_RECORD};
use foc_protocol::device::{DeviceContext, Refusal, WatchdogConfig};
use foc_protocol::message::{
    Calibration, CurrentGains, ErrorCode, ParamId, PositionGains, SpeedGains, Telemetry,
};
use foc_store::fake::FakeFlash;
use foc_store::record::WatchdogRecord;
use foc_store::settings::{reaction_record, timeout_reaction};
use foc_store::{DriveRecord, Invalid, Label, Settings, Store, StoreError};

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

/// The real drive on the host (see the module docs).
pub struct HostDrive {
    setup: Setup,
    /// The build-time configuration (the emulated board's).
    base_config: CascadeConfig,
    /// The build-time settings (calibrated from the bench's knowledge).
    base: Settings,
    /// Drive and plant.
    pub sim: Sim,
    /// The configuration in force.
    settings: Settings,
    label: Label,
    /// `None` only transiently (re-opened at a power cycle) or if the
    /// region is unusable.
    store: Option<Store<DriveFlash>>,
    /// The link-watchdog setting of the record loaded at boot.
    boot_link: Option<WatchdogConfig>,
    /// PWM periods run since power-on.
    periods: u64,
    /// The CAN node's communication settings stored in the flash, as
    /// loaded at power-on (and updated by a save).
    comm: Option<foc_canopen::node::CommSettings>,
}

impl Default for HostDrive {
    fn default() -> Self {
        Self::new()
    }
}

/// A store failure as a Nack.
fn store_error(e: StoreError) -> ErrorCode {
    match e {
        StoreError::Record(_) | StoreError::Invalid(_) => ErrorCode::BadRecord,
        _ => ErrorCode::StoreFailed,
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
        let base_config = setup.cascade_config();
        let mut base = Settings::from_cascade(&base_config);
        base.angle = setup.true_angle_calibration();
        base.calibrated = true;
        let sim = Sim::new(&setup, base_config, false);
        let mut d = Self {
            setup,
            base_config,
            base,
            sim,
            settings: base,
            label: Label::new(),
            store: Store::new(flash, STORE_RANGE).ok(),
            boot_link: None,
            periods: 0,
            comm: None,
        };
        d.power_on();
        d
    }

    /// Boot: the stored record (if any, and admitted) or the build-time
    /// settings; a fresh simulation with them.
    fn power_on(&mut self) {
        self.settings = self.base;
        self.label = Label::new();
        self.boot_link = None;
        self.comm = match self.store.as_mut().map(|s| s.load_can()) {
            Some(Ok(Some(r))) => foc_canopen::node::CommSettings::from_record(&r).ok(),
            _ => None,
        };
        if let Some(Ok(Some(rec))) = self.store.as_mut().map(|s| s.load()) {
            if let Ok(s) = self.admit(&rec) {
                self.settings = s;
                self.label = rec.label.clone();
                self.boot_link = Some(link_setting(&rec));
            }
        }
        let config = self.settings.apply_to(&self.base_config);
        let mut sim = Sim::new(&self.setup, config, false);
        if let Some(p) = self.settings.permit() {
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
        self.setup.bench.pwm_frequency_hz as u32
    }

    /// The plant's true mechanical velocity [rad/s].
    pub fn plant_velocity_rad_s(&self) -> f32 {
        self.sim.plant.omega_m_rad_s() as f32
    }

    /// The configuration in force.
    pub fn settings(&self) -> &Settings {
        &self.settings
    }

    /// The drive's label (saved with the configuration).
    pub fn label(&self) -> &Label {
        &self.label
    }

    /// Replace the label (saved with the next save).
    pub fn set_label(&mut self, label: Label) {
        self.label = label;
    }

    /// The link-watchdog setting of the record loaded at the last boot.
    pub fn boot_link_setting(&self) -> Option<WatchdogConfig> {
        self.boot_link
    }

    /// The CAN node's saved communication settings, if any.
    pub fn saved_comm(&self) -> Option<foc_canopen::node::CommSettings> {
        self.comm
    }

    /// Keep the CAN node's communication settings for the next boot: in
    /// the flash, as the firmware does (`foc_store::CanRecord`).
    pub fn store_comm(&mut self, s: foc_canopen::node::CommSettings) -> Result<(), ErrorCode> {
        let store = self.store.as_mut().ok_or(ErrorCode::Unsupported)?;
        store.save_can(&s.to_record()).map_err(store_error)?;
        self.comm = Some(s);
        Ok(())
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

    fn request(&mut self, change: ConfigChange) {
        self.sim.cascade.request(change);
    }

    fn joint_change(joint: &JointSetup, limits: &Limits) -> JointChange {
        joint.rotor_change((limits.min_position_rad, limits.max_position_rad))
    }

    /// `rec` applied onto the build-time settings: whole, or refused (the
    /// firmware's `persist::admit` rules for this board).
    fn admit(&self, rec: &DriveRecord) -> Result<Settings, Invalid> {
        let invalid = |field| Err(Invalid { field });
        if rec.motor.pole_pairs != self.base.current.motor.pole_pairs {
            return invalid("motor.pole_pairs");
        }
        if rec
            .calibration
            .as_ref()
            .is_some_and(|c| c.sensor_counts_per_rev != self.base.angle.sensor_counts_per_rev)
        {
            return invalid("calibration.sensor_counts_per_rev");
        }
        let s = rec.apply(&self.base, self.pwm_hz())?;
        if s.limits.max_current_a > MAX_CURRENT_A {
            return invalid("limits.max_current_a");
        }
        Ok(s)
    }

    /// Make `s` the configuration in force (every loop gets its part).
    fn adopt(&mut self, s: Settings, label: Label) {
        self.settings = s;
        self.label = label;
        self.request(ConfigChange {
            limits: Some(s.limits),
            current: Some(s.current),
            dividers: Some(s.dividers),
            power: Some(s.power),
            permit: s.permit(),
            mechanics: s.mechanics,
            joint: Some(Self::joint_change(&s.joint, &s.limits)),
            ..ConfigChange::default()
        });
        self.sim.cascade.speed.speed_loop().set_config(s.speed);
        self.sim.cascade.position.set_config(s.position);
    }

    /// The record of the live settings with the link watchdog `link`.
    pub fn live_record(&self, link: WatchdogConfig) -> DriveRecord {
        let mut s = self.settings;
        s.watchdog = WatchdogRecord {
            timeout_periods: link.timeout_periods,
            reaction: reaction_record(link.reaction),
        };
        DriveRecord::from_settings(&self.label, self.pwm_hz(), &s)
    }

    /// The stored record, if any.
    pub fn stored_record(&mut self) -> Result<Option<DriveRecord>, ErrorCode> {
        let store = self.store.as_mut().ok_or(ErrorCode::Unsupported)?;
        store.load().map_err(store_error)
    }

    /// Flash operations only with the bridge off and staying off.
    fn quiet(&self) -> Result<(), ErrorCode> {
        if self.sim.cascade.mailbox().command != Command::Disable {
            return Err(ErrorCode::NotDisabled);
        }
        if self.sim.cascade.feedback().power.brake_on {
            return Err(ErrorCode::Busy);
        }
        Ok(())
    }

    fn load_stored(&mut self) -> Result<DriveRecord, ErrorCode> {
        self.quiet()?;
        self.stored_record()?.ok_or(ErrorCode::NothingStored)
    }

    fn save(&mut self, rec: &DriveRecord) -> Result<(), ErrorCode> {
        self.quiet()?;
        let store = self.store.as_mut().ok_or(ErrorCode::Unsupported)?;
        store.save(rec).map_err(store_error)
    }

    fn apply_record(&mut self, rec: &DriveRecord) -> Result<WatchdogConfig, ErrorCode> {
        let s = self.admit(rec).map_err(|_| ErrorCode::BadRecord)?;
        self.adopt(s, rec.label.clone());
        Ok(link_setting(rec))
    }
}

/// The link-watchdog setting a record carries.
pub fn link_setting(rec: &DriveRecord) -> WatchdogConfig {
    WatchdogConfig {
        timeout_periods: rec.watchdog.timeout_periods,
        reaction: timeout_reaction(rec.watchdog.reaction),
    }
}

impl DeviceContext for HostDrive {
    fn post(&mut self, cmd: Command) -> Result<(), CommandError> {
        self.sim.cascade.command(cmd)
    }
    fn keep_alive(&mut self) {
        // Nothing to post (as the firmware): the protocol's link watchdog
        // is the command timeout.
    }
    fn mode(&self) -> Mode {
        self.drive_status().mode
    }
    fn faults(&self) -> (FaultSet, Option<Fault>) {
        let fb = self.sim.cascade.feedback();
        (fb.faults, fb.first_fault)
    }
    fn clear_faults(&mut self) {
        self.sim.cascade.clear_faults();
    }
    fn report_fault(&mut self, fault: Fault) {
        self.request(ConfigChange {
            fault: Some(fault),
            ..ConfigChange::default()
        });
    }
    fn limits(&self) -> Limits {
        self.settings.limits
    }
    fn set_limits(&mut self, limits: Limits) -> Result<(), Refusal> {
        if limits.max_current_a > MAX_CURRENT_A {
            return Err(Refusal::Unsupported);
        }
        self.settings.limits = limits;
        self.settings.speed.current_limit_a = limits.max_current_a;
        let joint = Self::joint_change(&self.settings.joint, &limits);
        self.request(ConfigChange {
            limits: Some(limits),
            joint: Some(joint),
            ..ConfigChange::default()
        });
        let speed = self.settings.speed;
        self.sim.cascade.speed.speed_loop().set_config(speed);
        Ok(())
    }
    fn joint(&self) -> JointSetup {
        self.settings.joint
    }
    fn set_joint(&mut self, setup: JointSetup) -> Result<(), Refusal> {
        let change = Self::joint_change(&setup, &self.settings.limits);
        if let Command::Position { rad } = self.sim.cascade.mailbox().command {
            if !(change.min_position_rad..=change.max_position_rad).contains(&rad) {
                return Err(Refusal::NotDisabled);
            }
        }
        self.settings.joint = setup;
        self.request(ConfigChange {
            joint: Some(change),
            ..ConfigChange::default()
        });
        Ok(())
    }
    fn torque_constant_nm_per_a(&self) -> f32 {
        self.settings.current.motor.torque_constant_nm_per_a()
    }
    fn feedback(&self) -> Feedback {
        *self.sim.cascade.feedback()
    }
    fn set_current_gains(&mut self, gains: CurrentGains) -> Result<(), Refusal> {
        let mut cur = self.settings.current;
        gains.apply(&mut cur);
        if foc_core::calibration::Calibrated::supplied(self.settings.angle, cur).is_err() {
            return Err(Refusal::Unsupported);
        }
        self.settings.current = cur;
        self.request(ConfigChange {
            current: Some(cur),
            ..ConfigChange::default()
        });
        Ok(())
    }
    fn set_speed_gains(&mut self, gains: SpeedGains) -> Result<(), Refusal> {
        gains.apply(&mut self.settings.speed);
        let speed = self.settings.speed;
        self.sim.cascade.speed.speed_loop().set_config(speed);
        Ok(())
    }
    fn set_position_gains(&mut self, gains: PositionGains) -> Result<(), Refusal> {
        if gains.max_velocity_rad_s > self.limits().max_velocity_rad_s {
            return Err(Refusal::Unsupported);
        }
        gains.apply(&mut self.settings.position);
        let position = self.settings.position;
        self.sim.cascade.position.set_config(position);
        Ok(())
    }
    fn set_dividers(&mut self, speed: u16, position: u16) -> Result<(), Refusal> {
        let pwm = self.pwm_hz() as f32;
        self.settings.dividers = (speed, position);
        self.settings.speed.ts_s = f32::from(speed) / pwm;
        self.settings.position.ts_s = f32::from(position) / pwm;
        self.request(ConfigChange {
            dividers: Some((speed, position)),
            ..ConfigChange::default()
        });
        let (s, p) = (self.settings.speed, self.settings.position);
        self.sim.cascade.speed.speed_loop().set_config(s);
        self.sim.cascade.position.set_config(p);
        Ok(())
    }
    fn start_calibration(&mut self, routine: Calibration) -> Result<(), Refusal> {
        match routine {
            Calibration::Offsets => {
                self.request(ConfigChange {
                    calibrate_offsets: true,
                    ..ConfigChange::default()
                });
                Ok(())
            }
            // The host drive starts calibrated from the bench's knowledge.
            Calibration::Identification | Calibration::Alignment => Err(Refusal::Unsupported),
        }
    }
    fn is_calibrated(&self) -> bool {
        self.drive_status().calibrated
    }
    fn status(&self) -> Status {
        self.drive_status()
    }
    fn param(&self, id: ParamId) -> Option<f32> {
        let m = self.settings.current.motor;
        Some(match id {
            ParamId::PolePairs => f32::from(m.pole_pairs),
            ParamId::ResistanceOhm => m.r_ohm,
            ParamId::LdH => m.ld_h,
            ParamId::LqH => m.lq_h,
            ParamId::FluxLinkageWb => m.flux_linkage_wb,
            ParamId::PwmFrequencyHz => self.pwm_hz() as f32,
            ParamId::SpeedDivider => f32::from(self.settings.dividers.0),
            ParamId::PositionDivider => f32::from(self.settings.dividers.1),
            ParamId::FirmwareVersion => {
                let [a, b, c] = FIRMWARE_VERSION;
                f32::from(a) * 10_000.0 + f32::from(b) * 100.0 + f32::from(c)
            }
            ParamId::BusVoltageV => self.sim.cascade.feedback().v_bus_v,
            ParamId::Calibrated => {
                if self.is_calibrated() {
                    1.0
                } else {
                    0.0
                }
            }
            ParamId::MaxLoopCycles => 0.0,
            ParamId::CurrentKp => self.settings.current.q_gains.kp_v_per_a,
            ParamId::CurrentKi => self.settings.current.q_gains.ki_v_per_a_s,
            ParamId::SpeedKp => self.settings.speed.kp_a_per_rad_s,
            ParamId::SpeedKi => self.settings.speed.ki_a_per_rad,
            ParamId::PositionKp => self.settings.position.kp_per_s,
            // No scope on the host drive.
            ParamId::ScopeCapacity => 0.0,
            ParamId::ProtocolVersion | ParamId::TelemetryDivider | ParamId::WatchdogTimeout => {
                return None
            }
        })
    }
    fn telemetry(&self) -> Telemetry {
        Telemetry::from_feedback(self.sim.cascade.feedback(), 0)
    }
    fn firmware_version(&self) -> [u8; 3] {
        FIRMWARE_VERSION
    }
    fn config_record(
        &mut self,
        source: ConfigSource,
        link: WatchdogConfig,
        out: &mut [u8; MAX_RECORD],
    ) -> Result<usize, ErrorCode> {
        let rec = match source {
            ConfigSource::Live => self.live_record(link),
            ConfigSource::Stored => self.load_stored()?,
        };
        rec.encode(out).map_err(|_| ErrorCode::BadRecord)
    }
    fn store(
        &mut self,
        op: StoreOp,
        staged: &[u8],
        link: WatchdogConfig,
    ) -> Result<Option<WatchdogConfig>, ErrorCode> {
        self.quiet()?;
        match op {
            StoreOp::Save => {
                let rec = self.live_record(link);
                self.save(&rec).map(|()| None)
            }
            StoreOp::Erase => {
                let store = self.store.as_mut().ok_or(ErrorCode::Unsupported)?;
                store.erase().map_err(store_error)?;
                Ok(None)
            }
            StoreOp::Load => {
                let rec = self.load_stored()?;
                self.apply_record(&rec).map(Some)
            }
            StoreOp::Apply | StoreOp::ApplyAndSave => {
                let rec = DriveRecord::decode(staged).map_err(|_| ErrorCode::BadRecord)?;
                self.admit(&rec).map_err(|_| ErrorCode::BadRecord)?;
                if op == StoreOp::ApplyAndSave {
                    self.save(&rec)?;
                }
                self.apply_record(&rec).map(Some)
            }
        }
    }
}
