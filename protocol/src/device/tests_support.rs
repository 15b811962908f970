//! A recording [`DeviceContext`] for tests and examples: stores everything
//! it is given and counts mutating calls, so a test can check that a
//! Nack'd request touched nothing.

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
    /// PWM frequency \[Hz\].
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
    /// The link's stream-rate limit it reports \[Hz\].
    pub max_stream_hz: Option<f32>,
    /// The scope (64 values; `None`: the device has none).
    pub scope: Option<foc_core::scope::Scope<[f32; 64]>>,
    /// It runs without its angle sensor (`ParamId::AngleSource` 1).
    pub sensorless: bool,
    /// ... and holds torque at standstill (injection, design §28).
    pub injection: bool,
    /// The last parameter written (`SetParam`).
    pub written: Option<(ParamId, f32)>,
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
            sensorless: false,
            injection: false,
            written: None,
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
    fn set_param(&mut self, id: ParamId, value: f32) -> Result<(), Refusal> {
        self.mutate()?;
        self.written = Some((id, value));
        Ok(())
    }
    fn start_calibration(&mut self, routine: Calibration) -> Result<(), Refusal> {
        self.mutate()?;
        self.calibration = Some(routine);
        Ok(())
    }
    fn status(&self) -> foc_core::drive::Status {
        foc_core::drive::Status {
            running: true,
            mode: self.mode,
            faulted: !self.faults.is_empty(),
            calibrated: self.calibrated,
            sensorless: self.sensorless,
            injection: self.injection,
            calibration: foc_core::drive::Progress::Idle,
        }
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
            ParamId::AngleSource => Some(f32::from(u8::from(self.sensorless))),
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
