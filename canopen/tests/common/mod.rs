//! Fakes for the node tests: a profile that records what the node asks of
//! it (the real CiA 402 bodies are another module's), and a device that
//! records posts, stores and saves, with faults a test can set.
#![allow(dead_code)]
// Test support outside `#[test]` functions: unwrapping and indexing a
// fixture is the test failing, which is what it should do.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use foc_canopen::cia402::{Actuals, Params, State, Targets};
use foc_canopen::node::{CanDevice, CommSettings, Identity, Node};
use foc_canopen::od::{Default as Dflt, OBJECTS};
use foc_canopen::profile::Profile;
use foc_canopen::{Abort, CanFrame};
use foc_core::control::{Command, CommandError, Fault, FaultSet, Limits, Mode};
use foc_protocol::config::StoreOp;
use foc_protocol::device::tests_support::RecordingContext;
use foc_protocol::device::{DeviceContext, Refusal, WatchdogConfig};
use foc_protocol::message::{
    Calibration, CurrentGains, ErrorCode, ParamId, PositionGains, SpeedGains, Telemetry,
};

/// The table's default of an integer object.
pub fn table_default(index: u16, sub: u8) -> i64 {
    let d = foc_canopen::od::find(index, sub).expect("object");
    match d.default {
        Dflt::Int(v) => v,
        _ => 0,
    }
}

/// A profile recording the node's calls.
#[derive(Clone, Debug, PartialEq)]
pub struct FakeProfile {
    pub targets: Targets,
    pub params: Params,
    pub actuals: Actuals,
    pub state: State,
    pub cw: u16,
    pub mode: i8,
    pub cw_writes: u32,
    pub updates: u32,
    pub lost: u32,
    pub fault: Option<u16>,
}

impl FakeProfile {
    pub fn new() -> Self {
        let p = |i| table_default(i, 0);
        Self {
            targets: Targets {
                position_inc: 0,
                velocity_inc_s: 0,
                torque_permille: 0,
                velocity_offset_inc_s: 0,
                torque_offset_permille: 0,
            },
            params: Params {
                following_error_window_inc: p(0x6065) as u32,
                following_error_timeout_ms: p(0x6066) as u16,
                position_window_inc: p(0x6067) as u32,
                position_window_time_ms: p(0x6068) as u16,
                velocity_window_inc_s: p(0x606D) as u16,
                velocity_window_time_ms: p(0x606E) as u16,
                max_torque_permille: p(0x6072) as u16,
                max_profile_velocity_inc_s: p(0x607F) as u32,
                profile_velocity_inc_s: p(0x6081) as u32,
                profile_acceleration_inc_s2: p(0x6083) as u32,
                profile_deceleration_inc_s2: p(0x6084) as u32,
                quick_stop_deceleration_inc_s2: p(0x6085) as u32,
                quick_stop_option: p(0x605A) as i16,
                abort_connection_option: p(0x6007) as i16,
                torque_slope_permille_s: p(0x6087) as u32,
            },
            actuals: Actuals {
                statusword: 0x0250,
                mode_display: 0,
                position_inc: 0,
                position_demand_inc: 0,
                velocity_inc_s: 0,
                velocity_demand_inc_s: 0,
                torque_permille: 0,
                current_permille: 0,
                following_error_inc: 0,
                error_code: 0,
                dc_link_mv: 24_000,
            },
            state: State::SwitchOnDisabled,
            cw: 0,
            mode: 0,
            cw_writes: 0,
            updates: 0,
            lost: 0,
            fault: None,
        }
    }
}

impl Profile for FakeProfile {
    fn targets(&self) -> &Targets {
        &self.targets
    }
    fn targets_mut(&mut self) -> &mut Targets {
        &mut self.targets
    }
    fn params(&self) -> &Params {
        &self.params
    }
    fn set_params(&mut self, p: Params) {
        self.params = p;
    }
    fn actuals(&self) -> &Actuals {
        &self.actuals
    }
    fn state(&self) -> State {
        self.state
    }
    fn controlword(&self) -> u16 {
        self.cw
    }
    fn requested_mode(&self) -> i8 {
        self.mode
    }
    fn write_controlword<C: DeviceContext>(&mut self, cw: u16, _: u64, _: &mut C) {
        self.cw = cw;
        self.cw_writes += 1;
    }
    fn write_mode<C: DeviceContext>(&mut self, mode: i8, _: u64, _: &mut C) -> Result<(), Abort> {
        self.mode = mode;
        self.actuals.mode_display = mode;
        Ok(())
    }
    fn check_params(&self, p: &Params) -> Result<(), Abort> {
        if p.profile_velocity_inc_s > p.max_profile_velocity_inc_s {
            return Err(Abort::ParamIncompatible);
        }
        Ok(())
    }
    fn update<C: DeviceContext>(&mut self, _: u64, _: &mut C) {
        self.updates += 1;
    }
    fn connection_lost<C: DeviceContext>(&mut self, _: u64, _: &mut C) {
        self.lost += 1;
    }
    fn profile_fault(&self) -> Option<u16> {
        self.fault
    }
}

/// A device: the protocol's recording context plus what CANopen adds.
#[derive(Clone, Debug)]
pub struct FakeDevice {
    pub ctx: RecordingContext,
    pub saved: Option<CommSettings>,
    pub save_comm_fails: bool,
    pub store_fails: bool,
    pub stores: Vec<StoreOp>,
    /// The drive runs without its angle sensor (`ParamId::AngleSource`).
    pub sensorless: bool,
    /// The d-current reference in force (parameters 33-36), judged with
    /// the drive's rule on `angle` when one setting is written.
    pub field: foc_core::control::field::FieldConfig,
    /// The angle calibration the rule looks at (halls: coarse).
    pub angle: foc_core::control::stage::AngleCalibration,
    /// The anticogging map: `None` none measured, else its switch
    /// (parameter 37; peak 0.25 A).
    pub cogging: Option<bool>,
    /// The angle correction: `None` none learnt, else its switch
    /// (parameter 38; peak 0.004 rad).
    pub correction: Option<bool>,
    /// The calibration's progress the status reports.
    pub progress: foc_core::drive::Progress,
}

impl FakeDevice {
    pub fn new() -> Self {
        Self {
            ctx: RecordingContext::default(),
            saved: None,
            save_comm_fails: false,
            store_fails: false,
            stores: Vec::new(),
            sensorless: false,
            field: foc_core::control::field::FieldConfig {
                max_id_a: 10.0,
                bandwidth_rad_s: 600.0,
                ..foc_core::control::field::FieldConfig::OFF
            },
            angle: foc_core::control::stage::AngleCalibration {
                sensor_counts_per_rev: 4096,
                sensorless_only: false,
                ..foc_core::control::stage::AngleCalibration::sensorless(7, 4096)
            },
            cogging: None,
            correction: None,
            progress: foc_core::drive::Progress::Idle,
        }
    }
    pub fn set_faults(&mut self, faults: &[Fault]) {
        self.ctx.faults = FaultSet::EMPTY;
        self.ctx.first_fault = faults.first().copied();
        for &f in faults {
            self.ctx.faults.insert(f);
        }
    }
}

impl DeviceContext for FakeDevice {
    fn post(&mut self, cmd: Command) -> Result<(), CommandError> {
        self.ctx.post(cmd)
    }
    fn keep_alive(&mut self) {
        self.ctx.keep_alive()
    }
    fn mode(&self) -> Mode {
        self.ctx.mode()
    }
    fn faults(&self) -> (FaultSet, Option<Fault>) {
        self.ctx.faults()
    }
    fn clear_faults(&mut self) {
        self.ctx.clear_faults()
    }
    fn report_fault(&mut self, fault: Fault) {
        self.ctx.report_fault(fault)
    }
    fn limits(&self) -> Limits {
        self.ctx.limits()
    }
    fn set_limits(&mut self, limits: Limits) -> Result<(), Refusal> {
        self.ctx.set_limits(limits)
    }
    fn torque_constant_nm_per_a(&self) -> f32 {
        self.ctx.torque_constant_nm_per_a()
    }
    fn set_current_gains(&mut self, g: CurrentGains) -> Result<(), Refusal> {
        self.ctx.set_current_gains(g)
    }
    fn set_speed_gains(&mut self, g: SpeedGains) -> Result<(), Refusal> {
        self.ctx.set_speed_gains(g)
    }
    fn set_position_gains(&mut self, g: PositionGains) -> Result<(), Refusal> {
        self.ctx.set_position_gains(g)
    }
    fn set_dividers(&mut self, s: u16, p: u16) -> Result<(), Refusal> {
        self.ctx.set_dividers(s, p)
    }
    fn set_param(&mut self, id: ParamId, value: f32) -> Result<(), Refusal> {
        // A table's switch: not on without the table.
        let table = match id {
            ParamId::Anticogging => Some(&mut self.cogging),
            ParamId::EncoderLinearisation => Some(&mut self.correction),
            _ => None,
        };
        if let Some(t) = table {
            if value == 1.0 && t.is_none() {
                return Err(Refusal::NotCalibrated);
            }
            *t = Some(value == 1.0);
            return self.ctx.set_param(id, value);
        }
        let mut f = self.field;
        match id {
            ParamId::FieldWeakening => f.field_weakening = value == 1.0,
            ParamId::Mtpa => f.mtpa = value == 1.0,
            ParamId::MaxIdA => f.max_id_a = value,
            ParamId::ShortCircuit => f.short_circuit = value == 1.0,
            _ => return Err(Refusal::Unsupported),
        }
        foc_core::drive::check_field(&f, &self.angle).map_err(|_| Refusal::Unsupported)?;
        self.ctx.set_param(id, value)?;
        self.field = f;
        Ok(())
    }
    fn start_calibration(&mut self, r: Calibration) -> Result<(), Refusal> {
        // A sweep: the drive's rule; measured at once (switched on).
        if let Some(sweep) = r.sweep() {
            self.status().check_sweep(sweep, &self.angle)?;
        }
        self.ctx.start_calibration(r)?;
        match r {
            Calibration::Anticogging => self.cogging = Some(true),
            Calibration::EncoderLinearisation => self.correction = Some(true),
            _ => {}
        }
        Ok(())
    }
    fn status(&self) -> foc_core::drive::Status {
        foc_core::drive::Status {
            running: true,
            mode: self.ctx.mode,
            faulted: !self.ctx.faults.is_empty(),
            calibrated: self.ctx.calibrated,
            sensorless: self.sensorless,
            injection: false,
            calibration: self.progress,
        }
    }
    fn is_calibrated(&self) -> bool {
        self.ctx.is_calibrated()
    }
    fn param(&self, id: ParamId) -> Option<f32> {
        match id {
            ParamId::SpeedKp => Some(
                self.ctx
                    .speed_gains
                    .map(|g| g.kp_a_per_rad_s)
                    .unwrap_or(0.5),
            ),
            ParamId::SpeedKi => Some(self.ctx.speed_gains.map(|g| g.ki_a_per_rad).unwrap_or(2.0)),
            ParamId::ResistanceOhm => Some(0.12),
            ParamId::AngleSource => Some(f32::from(u8::from(self.sensorless))),
            ParamId::FieldWeakening => Some(f32::from(u8::from(self.field.field_weakening))),
            ParamId::Mtpa => Some(f32::from(u8::from(self.field.mtpa))),
            ParamId::MaxIdA => Some(self.field.max_id_a),
            ParamId::ShortCircuit => Some(f32::from(u8::from(self.field.short_circuit))),
            ParamId::Anticogging => Some(f32::from(u8::from(self.cogging == Some(true)))),
            ParamId::EncoderLinearisation => {
                Some(f32::from(u8::from(self.correction == Some(true))))
            }
            ParamId::AnticoggingPeakA => Some(if self.cogging.is_some() { 0.25 } else { 0.0 }),
            ParamId::EncoderCorrectionPeakRad => Some(if self.correction.is_some() {
                0.004
            } else {
                0.0
            }),
            _ => self.ctx.param(id),
        }
    }
    fn telemetry(&self) -> Telemetry {
        self.ctx.telemetry()
    }
    fn firmware_version(&self) -> [u8; 3] {
        [1, 2, 3]
    }
    fn store(
        &mut self,
        op: StoreOp,
        staged: &[u8],
        link: WatchdogConfig,
    ) -> Result<Option<WatchdogConfig>, ErrorCode> {
        if self.store_fails {
            return Err(ErrorCode::StoreFailed);
        }
        self.stores.push(op);
        self.ctx.store(op, staged, link)
    }
}

impl CanDevice for FakeDevice {
    fn identity(&self) -> Identity {
        Identity {
            vendor_id: 0x1234,
            product_code: 0x402,
            revision: 0x0001_0002,
            serial: 77,
            device_name: "FOC drive test bench",
            hardware_version: "rev B",
        }
    }
    fn link_setting(&self) -> WatchdogConfig {
        WatchdogConfig::OFF
    }
    fn save_comm(&mut self, s: &CommSettings) -> Result<(), ErrorCode> {
        if self.save_comm_fails {
            return Err(ErrorCode::StoreFailed);
        }
        self.saved = Some(*s);
        Ok(())
    }
}

pub const ID: u8 = 5;

/// Every object's value or abort.
pub type Snapshot = Vec<(u16, u8, Result<Vec<u8>, Abort>)>;

/// A bench: node, device, the frames sent, the time.
pub struct Bench {
    pub node: Node<FakeProfile>,
    pub dev: FakeDevice,
    pub sent: Vec<CanFrame>,
    pub now_us: u64,
}

impl Bench {
    /// Booted (pre-operational), node 5, heartbeat 100 ms, master 1 at 300 ms.
    pub fn new() -> Self {
        Self::with(CommSettings::new(ID, 1000, 100, Some((1, 300))).unwrap())
    }
    pub fn with(s: CommSettings) -> Self {
        let mut b = Self {
            node: Node::with_profile(s, FakeProfile::new()),
            dev: FakeDevice::new(),
            sent: Vec::new(),
            now_us: 0,
        };
        let sent = &mut b.sent;
        b.node.boot(0, &mut b.dev, &mut |f| sent.push(f));
        b
    }
    pub fn frame(&mut self, id: u16, data: &[u8]) {
        let f = CanFrame::new(id, data).unwrap();
        let sent = &mut self.sent;
        self.node
            .on_frame(&f, self.now_us, &mut self.dev, &mut |f| sent.push(f));
    }
    pub fn tick_to(&mut self, t_us: u64) {
        let sent = &mut self.sent;
        self.now_us = t_us;
        self.node.tick(t_us, &mut self.dev, &mut |f| sent.push(f));
    }
    /// Tick every `step` µs until `t_us`.
    pub fn run_to(&mut self, t_us: u64, step: u64) {
        while self.now_us + step <= t_us {
            let t = self.now_us + step;
            self.tick_to(t);
        }
    }
    pub fn take(&mut self) -> Vec<CanFrame> {
        std::mem::take(&mut self.sent)
    }
    pub fn nmt(&mut self, cs: u8, node: u8) {
        self.frame(0, &[cs, node]);
    }
    pub fn start(&mut self) {
        self.nmt(0x01, ID);
    }
    /// One SDO request: the response's 8 bytes.
    pub fn sdo(&mut self, req: [u8; 8]) -> [u8; 8] {
        self.sent.clear();
        self.frame(0x600 + u16::from(ID), &req);
        let r: Vec<_> = self
            .take()
            .into_iter()
            .filter(|f| f.id == 0x580 + u16::from(ID))
            .collect();
        assert_eq!(r.len(), 1, "one SDO response");
        assert_eq!(r[0].len, 8);
        r[0].data
    }
    /// Expedited upload: the value or the abort code.
    pub fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, u32> {
        let [i0, i1] = index.to_le_bytes();
        let r = self.sdo([0x40, i0, i1, sub, 0, 0, 0, 0]);
        match r[0] {
            0x80 => Err(u32::from_le_bytes([r[4], r[5], r[6], r[7]])),
            0x41 => {
                let n = u32::from_le_bytes([r[4], r[5], r[6], r[7]]) as usize;
                let mut out = Vec::new();
                let mut t = 0u8;
                loop {
                    let s = self.sdo([0x60 | t, 0, 0, 0, 0, 0, 0, 0]);
                    if s[0] == 0x80 {
                        return Err(u32::from_le_bytes([s[4], s[5], s[6], s[7]]));
                    }
                    assert_eq!(s[0] & 0x10, t, "toggle");
                    let len = 7 - usize::from((s[0] >> 1) & 7);
                    out.extend_from_slice(&s[1..1 + len]);
                    t ^= 0x10;
                    if s[0] & 1 != 0 {
                        break;
                    }
                }
                assert_eq!(out.len(), n);
                Ok(out)
            }
            b if b & 0xF3 == 0x43 => {
                let n = 4 - usize::from((b >> 2) & 3);
                Ok(r[4..4 + n].to_vec())
            }
            b => panic!("unexpected upload response {b:#x}"),
        }
    }
    pub fn read_u32(&mut self, index: u16, sub: u8) -> u32 {
        let v = self.read(index, sub).expect("readable");
        let mut b = [0u8; 4];
        b[..v.len()].copy_from_slice(&v);
        u32::from_le_bytes(b)
    }
    /// Expedited download with size: Ok or the abort code.
    pub fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), u32> {
        let [i0, i1] = index.to_le_bytes();
        let n = data.len();
        assert!((1..=4).contains(&n));
        let mut req = [0x23 | (((4 - n) as u8) << 2), i0, i1, sub, 0, 0, 0, 0];
        req[4..4 + n].copy_from_slice(data);
        let r = self.sdo(req);
        match r[0] {
            0x60 => Ok(()),
            0x80 => Err(u32::from_le_bytes([r[4], r[5], r[6], r[7]])),
            b => panic!("unexpected download response {b:#x}"),
        }
    }
    pub fn write_u32(&mut self, index: u16, sub: u8, v: u32) -> Result<(), u32> {
        self.write(index, sub, &v.to_le_bytes())
    }
    /// Every readable object's value (or abort), through the node's own
    /// read (no SDO traffic, no side effect).
    pub fn snapshot(&self) -> Snapshot {
        OBJECTS
            .iter()
            .map(|d| {
                (
                    d.index,
                    d.sub,
                    self.node
                        .read_object(d.index, d.sub, &self.dev)
                        .map(|v| v.bytes().to_vec()),
                )
            })
            .collect()
    }
    /// Everything that must not change after a refused request.
    pub fn state(&self) -> (Snapshot, FakeProfile, u32, usize) {
        (
            self.snapshot(),
            self.node.cia402().clone(),
            self.dev.ctx.calls,
            self.dev.stores.len(),
        )
    }
}

pub fn emcys(frames: &[CanFrame]) -> Vec<(u16, u8, u8)> {
    frames
        .iter()
        .filter(|f| f.id == 0x80 + u16::from(ID))
        .map(|f| {
            (
                u16::from_le_bytes([f.data[0], f.data[1]]),
                f.data[2],
                f.data[3],
            )
        })
        .collect()
}
