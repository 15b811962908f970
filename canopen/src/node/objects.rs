//! The node's object values: where each object of [`crate::od::OBJECTS`]
//! lives, how it is read, and how a write is validated whole
//! ([`Dict::prepare`]: no side effect) before it is applied
//! ([`Dict::apply`]).

use foc_core::calibration::identification::Step;
use foc_core::drive::Progress;
use foc_protocol::device::Refusal;
use foc_protocol::message::{Calibration, ParamId, SpeedGains};

use crate::cia402::{OpMode, Params, Targets};
use crate::emcy::Emcy;
use crate::nmt::HeartbeatConsumer;
use crate::od::{self, Access, Data, Default, ObjectDef, Value};
use crate::pdo::{PdoConfig, COUNT};
use crate::profile::Profile;
use crate::Abort;
use foc_protocol::config::StoreOp;

use super::{CanDevice, CommSettings};

/// "save" (0x1010 sub 1).
pub const SAVE: u32 = 0x6576_6173;
/// "load" (0x1011 sub 1).
pub const LOAD: u32 = 0x6461_6F6C;

/// The object values the node holds, and the profile.
#[derive(Clone, Debug)]
pub(crate) struct Dict<P> {
    pub node_id: u8,
    /// 0x1005.
    pub sync_cob_id: u32,
    /// 0x1006 \[µs\].
    pub cycle_us: u32,
    /// 0x1016 sub 1.
    pub consumer_entry: u32,
    /// 0x1017 \[ms\].
    pub heartbeat_ms: u16,
    /// 0x1400.. / 0x1600..
    pub rpdo: [PdoConfig; COUNT],
    /// 0x1800.. / 0x1A00..
    pub tpdo: [PdoConfig; COUNT],
    /// 0x1001, 0x1003.
    pub emcy: Emcy,
    /// 0x2100 / 0x2101: the settings for the next boot.
    pub next: CommSettings,
    /// The settings last saved by 0x1010 (taken by NMT reset node).
    pub saved: Option<CommSettings>,
    /// What the store's CAN record holds as far as this node knows: the
    /// settings it was created with (the firmware creates it from the
    /// stored record, or the defaults where there is none), the last
    /// saved ones, the defaults after a restore. A save whose second
    /// write fails writes them back (see [`Action::Save`]).
    pub stored: CommSettings,
    /// The profile (0x6xxx).
    pub profile: P,
}

/// A validated write, to apply.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Action {
    ClearHistory,
    SyncCobId(u32),
    Cycle(u32),
    Consumer(u32),
    Heartbeat(u16),
    Rpdo(usize, PdoConfig),
    Tpdo(usize, PdoConfig),
    Save,
    Restore,
    SpeedGains(SpeedGains),
    /// A writable parameter (0x2008: the d-current reference's; 0x2009,
    /// 0x200A sub 1: the tables' switches).
    Param(ParamId, f32),
    /// Start a calibration (0x2009, 0x200A sub 2).
    Calibrate(Calibration),
    NodeId(u8),
    BitRate(u16),
    Controlword(u16),
    Mode(i8),
    Targets(Targets),
    Params(Params),
}

/// A value read: a number of the object's type, or a string.
enum Out {
    V(Value),
    S(Data),
}

fn refusal(r: Refusal) -> Abort {
    match r {
        Refusal::Unsupported => Abort::InvalidValue,
        Refusal::Busy | Refusal::NotCalibrated | Refusal::NotDisabled | Refusal::Faulted => {
            Abort::DeviceState
        }
    }
}

fn int(i: impl Into<i64>) -> Result<Out, Abort> {
    Ok(Out::V(Value::Int(i.into())))
}

fn real(x: Option<f32>) -> Result<Out, Abort> {
    x.map(|x| Out::V(Value::Real(x))).ok_or(Abort::NoData)
}

/// An on/off parameter as a BOOLEAN (1 on).
fn switch(x: Option<f32>) -> Result<Out, Abort> {
    int(u8::from(x.ok_or(Abort::NoData)? == 1.0))
}

/// The parameter behind sub-index `sub` of 0x2008 (the d-current
/// reference).
fn field_param(sub: u8) -> Result<ParamId, Abort> {
    match sub {
        1 => Ok(ParamId::FieldWeakening),
        2 => Ok(ParamId::Mtpa),
        3 => Ok(ParamId::MaxIdA),
        4 => Ok(ParamId::ShortCircuit),
        _ => Err(Abort::NoSubIndex),
    }
}

/// The table object `index` (0x2009 the anticogging map, 0x200A the
/// angle correction): its switch, its calibration and the step that
/// calibration runs as, its peak.
fn table_object(index: u16) -> Result<(ParamId, Calibration, Step, ParamId), Abort> {
    match index {
        0x2009 => Ok((
            ParamId::Anticogging,
            Calibration::Anticogging,
            Step::Cogging,
            ParamId::AnticoggingPeakA,
        )),
        0x200A => Ok((
            ParamId::EncoderLinearisation,
            Calibration::EncoderLinearisation,
            Step::Encoder,
            ParamId::EncoderCorrectionPeakRad,
        )),
        _ => Err(Abort::NoObject),
    }
}

/// f32 to a u32 with saturation (NaN: 0).
fn sat_u32(x: f32) -> u32 {
    if x.is_finite() && x > 0.0 {
        if x >= u32::MAX as f32 {
            u32::MAX
        } else {
            x as u32
        }
    } else {
        0
    }
}

/// 0x60C2 for a cycle period: `(value, index)` with `value * 10^index` s.
pub(crate) fn interpolation_period(cycle_us: u32) -> (u8, i8) {
    let mut v = cycle_us;
    let mut idx: i8 = -6;
    while idx < 0 && v != 0 && (v.is_multiple_of(10) || v > 255) {
        v /= 10;
        idx += 1;
    }
    (v.min(255) as u8, idx)
}

impl<P: Profile> Dict<P> {
    pub fn new(settings: &CommSettings, profile: P) -> Self {
        let mut d = Self {
            node_id: settings.node_id(),
            sync_cob_id: 0x80,
            cycle_us: 1000,
            consumer_entry: 0,
            heartbeat_ms: 0,
            rpdo: [PdoConfig::rpdo_default(0, 1); COUNT],
            tpdo: [PdoConfig::tpdo_default(0, 1); COUNT],
            emcy: Emcy::new(),
            next: *settings,
            saved: None,
            stored: *settings,
            profile,
        };
        d.reset_comm(settings);
        d
    }

    /// Communication objects to their defaults for `settings`.
    pub fn reset_comm(&mut self, s: &CommSettings) {
        self.node_id = s.node_id();
        self.sync_cob_id = 0x80;
        self.cycle_us = 1000;
        self.heartbeat_ms = s.heartbeat_ms();
        self.consumer_entry = s
            .consumer()
            .map(|(n, ms)| (u32::from(n) << 16) | u32::from(ms))
            .unwrap_or(0);
        for (n, p) in self.rpdo.iter_mut().enumerate() {
            *p = PdoConfig::rpdo_default(n, s.node_id());
        }
        for (n, p) in self.tpdo.iter_mut().enumerate() {
            *p = PdoConfig::tpdo_default(n, s.node_id());
        }
        self.emcy = Emcy::new();
        self.next = *s;
    }

    /// EMCY COB-ID.
    pub fn emcy_id(&self) -> u16 {
        0x80 + u16::from(self.node_id)
    }

    /// The bytes of a readable object.
    pub fn read<C: CanDevice>(&self, index: u16, sub: u8, ctx: &C) -> Result<Data, Abort> {
        let def = od::lookup(index, sub)?;
        if !def.access.readable() {
            return Err(Abort::WriteOnly);
        }
        Ok(match self.get(def, ctx)? {
            Out::V(v) => od::encode(def.data_type, v),
            Out::S(s) => s,
        })
    }

    /// The value of a readable numeric object (PDO packing).
    pub fn value<C: CanDevice>(&self, def: &ObjectDef, ctx: &C) -> Result<Value, Abort> {
        match self.get(def, ctx)? {
            Out::V(v) => Ok(v),
            Out::S(_) => Err(Abort::NotMappable),
        }
    }

    fn get<C: CanDevice>(&self, def: &ObjectDef, ctx: &C) -> Result<Out, Abort> {
        let (index, sub) = (def.index, def.sub);
        // Constants (and the sub 0 of fixed compounds) come from the table.
        if def.access == Access::Const {
            if let Default::Int(v) = def.default {
                return int(v);
            }
        }
        match index {
            0x1000..=0x1FFF => self.get_communication(index, sub, ctx),
            0x2000..=0x5FFF => self.get_manufacturer(index, sub, ctx),
            _ => self.get_profile(index, sub, ctx),
        }
    }

    /// The communication objects (0x1000-0x1FFF).
    fn get_communication<C: CanDevice>(&self, index: u16, sub: u8, ctx: &C) -> Result<Out, Abort> {
        match (index, sub) {
            (0x1001, 0) => int(self.emcy.register()),
            (0x1003, 0) => int(self.emcy.count()),
            (0x1003, n) => int(self.emcy.history(n).unwrap_or(0)),
            (0x1005, 0) => int(self.sync_cob_id),
            (0x1006, 0) => int(self.cycle_us),
            (0x1008, 0) => Ok(Out::S(Data::from_bytes(
                ctx.identity().device_name.as_bytes(),
            ))),
            (0x1009, 0) => Ok(Out::S(Data::from_bytes(
                ctx.identity().hardware_version.as_bytes(),
            ))),
            (0x100A, 0) => {
                let [a, b, c] = ctx.firmware_version();
                let mut d = Data::empty();
                // Fits: at most 11 bytes.
                let _ = core::fmt::write(&mut d, format_args!("{a}.{b}.{c}"));
                Ok(Out::S(d))
            }
            (0x1010, 1) | (0x1011, 1) => int(1u32),
            (0x1014, 0) => int(self.emcy_id()),
            (0x1016, 1) => int(self.consumer_entry),
            (0x1017, 0) => int(self.heartbeat_ms),
            (0x1018, n) => {
                let id = ctx.identity();
                match n {
                    1 => int(id.vendor_id),
                    2 => int(id.product_code),
                    3 => int(id.revision),
                    _ => int(id.serial),
                }
            }
            (0x1400..=0x1403, s) => {
                let c = self
                    .rpdo
                    .get(usize::from(index - 0x1400))
                    .ok_or(Abort::NoObject)?;
                comm_value(c, s)
            }
            (0x1800..=0x1803, s) => {
                let c = self
                    .tpdo
                    .get(usize::from(index - 0x1800))
                    .ok_or(Abort::NoObject)?;
                comm_value(c, s)
            }
            (0x1600..=0x1603, s) => {
                let c = self
                    .rpdo
                    .get(usize::from(index - 0x1600))
                    .ok_or(Abort::NoObject)?;
                map_value(c, s)
            }
            (0x1A00..=0x1A03, s) => {
                let c = self
                    .tpdo
                    .get(usize::from(index - 0x1A00))
                    .ok_or(Abort::NoObject)?;
                map_value(c, s)
            }
            _ => Err(Abort::NoData),
        }
    }

    /// The manufacturer objects (0x2000-0x5FFF): the motor model, the
    /// gains, the node's next communication settings.
    fn get_manufacturer<C: CanDevice>(&self, index: u16, sub: u8, ctx: &C) -> Result<Out, Abort> {
        match (index, sub) {
            (0x2000, 0) => {
                let pp = ctx.param(ParamId::PolePairs).ok_or(Abort::NoData)?;
                int(sat_u32(pp + 0.5).min(255))
            }
            (0x2001, 0) => real(ctx.param(ParamId::ResistanceOhm)),
            (0x2002, 0) => real(ctx.param(ParamId::LdH)),
            (0x2003, 0) => real(ctx.param(ParamId::LqH)),
            (0x2004, 0) => real(ctx.param(ParamId::FluxLinkageWb)),
            (0x2005, 0) => int(u8::from(ctx.is_calibrated())),
            (0x2006, 0) => {
                let [a, b, c] = ctx.firmware_version();
                int(u32::from(a) * 10_000 + u32::from(b) * 100 + u32::from(c))
            }
            (0x2007, 0) => {
                let s = ctx.param(ParamId::AngleSource).ok_or(Abort::NoData)?;
                // 0 to 3 (a value beyond is not one).
                int(if (0.0..=3.0).contains(&s) { s as u8 } else { 0 })
            }
            (0x2008, 3) => real(ctx.param(ParamId::MaxIdA)),
            (0x2008, s) => switch(ctx.param(field_param(s)?)),
            (0x2009 | 0x200A, s) => {
                let (on, _, step, peak) = table_object(index)?;
                match s {
                    1 => switch(ctx.param(on)),
                    // 1 while this calibration runs.
                    2 => int(u8::from(
                        ctx.status().calibration == Progress::Running(step),
                    )),
                    3 => real(ctx.param(peak)),
                    _ => Err(Abort::NoSubIndex),
                }
            }
            (0x2010, 0) => real(ctx.param(ParamId::CurrentKp)),
            (0x2011, 0) => real(ctx.param(ParamId::CurrentKi)),
            (0x2012, 0) => real(ctx.param(ParamId::SpeedKp)),
            (0x2013, 0) => real(ctx.param(ParamId::SpeedKi)),
            (0x2014, 0) => real(ctx.param(ParamId::PositionKp)),
            (0x2100, 0) => int(self.next.node_id()),
            (0x2101, 0) => int(self.next.bitrate_kbit()),
            _ => Err(Abort::NoData),
        }
    }

    /// The device profile's objects (CiA 402, 0x6000 on).
    fn get_profile<C: CanDevice>(&self, index: u16, sub: u8, ctx: &C) -> Result<Out, Abort> {
        let t = self.profile.targets();
        let p = self.profile.params();
        let a = self.profile.actuals();
        match (index, sub) {
            (0x603F, 0) => int(a.error_code),
            (0x6040, 0) => int(self.profile.controlword()),
            (0x6041, 0) => int(a.statusword),
            (0x605A, 0) => int(p.quick_stop_option),
            (0x6007, 0) => int(p.abort_connection_option),
            (0x6060, 0) => int(self.profile.requested_mode()),
            (0x6061, 0) => int(a.mode_display),
            (0x6062, 0) => int(a.position_demand_inc),
            (0x6064, 0) => int(a.position_inc),
            (0x6065, 0) => int(p.following_error_window_inc),
            (0x6066, 0) => int(p.following_error_timeout_ms),
            (0x6067, 0) => int(p.position_window_inc),
            (0x6068, 0) => int(p.position_window_time_ms),
            (0x606B, 0) => int(a.velocity_demand_inc_s),
            (0x606C, 0) => int(a.velocity_inc_s),
            (0x606D, 0) => int(p.velocity_window_inc_s),
            (0x606E, 0) => int(p.velocity_window_time_ms),
            (0x6071, 0) => int(t.torque_permille),
            (0x6072, 0) => int(p.max_torque_permille),
            (0x6075, 0) => int(sat_u32(ctx.limits().max_current_a * 1000.0)),
            (0x6076, 0) => int(sat_u32(
                ctx.limits().max_current_a * ctx.torque_constant_nm_per_a() * 1000.0,
            )),
            (0x6077, 0) => int(a.torque_permille),
            (0x6078, 0) => int(a.current_permille),
            (0x6079, 0) => int(a.dc_link_mv),
            (0x607A, 0) => int(t.position_inc),
            (0x607F, 0) => int(p.max_profile_velocity_inc_s),
            (0x6081, 0) => int(p.profile_velocity_inc_s),
            (0x6083, 0) => int(p.profile_acceleration_inc_s2),
            (0x6084, 0) => int(p.profile_deceleration_inc_s2),
            (0x6085, 0) => int(p.quick_stop_deceleration_inc_s2),
            (0x6087, 0) => int(p.torque_slope_permille_s),
            (0x60B1, 0) => int(t.velocity_offset_inc_s),
            (0x60B2, 0) => int(t.torque_offset_permille),
            (0x60C2, 1) => int(interpolation_period(self.cycle_us).0),
            (0x60C2, 2) => int(interpolation_period(self.cycle_us).1),
            (0x60F4, 0) => int(a.following_error_inc),
            (0x60FF, 0) => int(t.velocity_inc_s),
            _ => Err(Abort::NoData),
        }
    }

    /// Validate a write of `bytes` to `index`/`sub` completely: the
    /// action to apply, nothing changed yet.
    pub fn prepare<C: CanDevice>(
        &self,
        index: u16,
        sub: u8,
        bytes: &[u8],
        ctx: &C,
    ) -> Result<Action, Abort> {
        let def = od::lookup(index, sub)?;
        if !def.access.writable() {
            return Err(Abort::ReadOnly);
        }
        let v = od::parse(def, bytes)?;
        self.prepare_value(def, v, ctx)
    }

    /// As [`Self::prepare`] for a decoded value (PDO).
    pub fn prepare_value<C: CanDevice>(
        &self,
        def: &ObjectDef,
        v: Value,
        ctx: &C,
    ) -> Result<Action, Abort> {
        let (t, p) = (*self.profile.targets(), *self.profile.params());
        self.prepare_staged(def, v, ctx, t, p)
    }

    /// As [`Self::prepare_value`], on top of targets `t` and parameters
    /// `p` already staged by the earlier objects of the same PDO (so two
    /// targets mapped in one RPDO both count).
    pub fn prepare_staged<C: CanDevice>(
        &self,
        def: &ObjectDef,
        v: Value,
        ctx: &C,
        t: Targets,
        p: Params,
    ) -> Result<Action, Abort> {
        od::check_range(def, v)?;
        match def.index {
            0x1000..=0x1FFF => self.prepare_communication(def, v, ctx),
            0x2000..=0x5FFF => self.prepare_manufacturer(def, v, ctx),
            _ => self.prepare_profile(def, v, t, p),
        }
    }

    /// A write to a communication object (0x1000-0x1FFF).
    fn prepare_communication<C: CanDevice>(
        &self,
        def: &ObjectDef,
        v: Value,
        ctx: &C,
    ) -> Result<Action, Abort> {
        let i = v.int();
        let u = i as u32;
        let a = match (def.index, def.sub) {
            (0x1003, 0) if i == 0 => Action::ClearHistory,
            (0x1003, _) => return Err(Abort::InvalidValue),
            (0x1005, 0) => {
                // Consumer only: bit 30 (produce) and 29-bit ids refused.
                if u & 0xFFFF_F800 != 0 || crate::pdo::restricted(u) && u != 0x80 {
                    return Err(Abort::InvalidValue);
                }
                Action::SyncCobId(u)
            }
            (0x1006, 0) => Action::Cycle(u),
            (0x1010, 1) => {
                if u != SAVE {
                    return Err(Abort::CannotStore);
                }
                ctx.status()
                    .check_config()
                    .map_err(|_| Abort::DeviceState)?;
                Action::Save
            }
            (0x1011, 1) => {
                if u != LOAD {
                    return Err(Abort::CannotStore);
                }
                ctx.status()
                    .check_config()
                    .map_err(|_| Abort::DeviceState)?;
                Action::Restore
            }
            (0x1016, 1) => {
                let node = (u >> 16) & 0xFF;
                if u >> 24 != 0
                    || (u & 0xFFFF != 0
                        && (node == 0 || node > 127 || node == u32::from(self.node_id)))
                {
                    return Err(Abort::InvalidValue);
                }
                Action::Consumer(u)
            }
            (0x1017, 0) => Action::Heartbeat(u as u16),
            (0x1400..=0x1403, s) => {
                let n = usize::from(def.index - 0x1400);
                let c = self.rpdo.get(n).ok_or(Abort::NoObject)?;
                Action::Rpdo(n, c.with_comm(true, s, u)?)
            }
            (0x1600..=0x1603, s) => {
                let n = usize::from(def.index - 0x1600);
                let c = self.rpdo.get(n).ok_or(Abort::NoObject)?;
                Action::Rpdo(n, c.with_mapping(true, s, u)?)
            }
            (0x1800..=0x1803, s) => {
                let n = usize::from(def.index - 0x1800);
                let c = self.tpdo.get(n).ok_or(Abort::NoObject)?;
                Action::Tpdo(n, c.with_comm(false, s, u)?)
            }
            (0x1A00..=0x1A03, s) => {
                let n = usize::from(def.index - 0x1A00);
                let c = self.tpdo.get(n).ok_or(Abort::NoObject)?;
                Action::Tpdo(n, c.with_mapping(false, s, u)?)
            }
            _ => return Err(Abort::UnsupportedAccess),
        };
        Ok(a)
    }

    /// A write to a manufacturer object (0x2000-0x5FFF).
    fn prepare_manufacturer<C: CanDevice>(
        &self,
        def: &ObjectDef,
        v: Value,
        ctx: &C,
    ) -> Result<Action, Abort> {
        let i = v.int();
        let u = i as u32;
        let a = match (def.index, def.sub) {
            (0x2012 | 0x2013, 0) => {
                let Value::Real(x) = v else {
                    return Err(Abort::InvalidValue);
                };
                if x < 0.0 {
                    return Err(Abort::ValueTooLow);
                }
                let kp = ctx
                    .param(ParamId::SpeedKp)
                    .ok_or(Abort::DeviceIncompatible)?;
                let ki = ctx
                    .param(ParamId::SpeedKi)
                    .ok_or(Abort::DeviceIncompatible)?;
                ctx.status().check_config().map_err(refusal)?;
                Action::SpeedGains(if def.index == 0x2012 {
                    SpeedGains {
                        kp_a_per_rad_s: x,
                        ki_a_per_rad: ki,
                    }
                } else {
                    SpeedGains {
                        kp_a_per_rad_s: kp,
                        ki_a_per_rad: x,
                    }
                })
            }
            (0x2008, s) => {
                let id = field_param(s)?;
                let x = match v {
                    Value::Int(i) => i as f32,
                    Value::Real(x) => x,
                };
                // The protocol's check of the value (the table's range
                // took a BOOLEAN's already), then the drive's state; the
                // drive's own rule (field weakening on halls) when applied.
                if !id.accepts(x) {
                    return Err(if x < 0.0 {
                        Abort::ValueTooLow
                    } else if x.is_finite() {
                        Abort::ValueTooHigh
                    } else {
                        Abort::InvalidValue
                    });
                }
                ctx.status().check_config().map_err(refusal)?;
                Action::Param(id, x)
            }
            // A table's switch (the BOOLEAN's range checked already); on
            // without a table is the drive's refusal (0x08000022).
            (0x2009 | 0x200A, 1) => {
                let (on, ..) = table_object(def.index)?;
                ctx.status().check_config().map_err(refusal)?;
                Action::Param(on, if u == 1 { 1.0 } else { 0.0 })
            }
            // Its calibration: 1 starts it (as `RunCalibration`: started,
            // disabled, not faulted; then the drive's rule when applied:
            // uncalibrated 0x08000022, halls or sensorless 0x06090030).
            (0x2009 | 0x200A, 2) => {
                let (_, routine, ..) = table_object(def.index)?;
                if u != 1 {
                    return Err(Abort::InvalidValue);
                }
                ctx.status().check_calibration().map_err(refusal)?;
                Action::Calibrate(routine)
            }
            (0x2100, 0) => Action::NodeId(u as u8),
            (0x2101, 0) => {
                if !CommSettings::BIT_RATES.contains(&(u as u16)) {
                    return Err(Abort::InvalidValue);
                }
                Action::BitRate(u as u16)
            }
            _ => return Err(Abort::UnsupportedAccess),
        };
        Ok(a)
    }

    /// A write to a device-profile object (CiA 402, 0x6000 on): targets,
    /// the controlword and mode, or parameters (checked together).
    fn prepare_profile(
        &self,
        def: &ObjectDef,
        v: Value,
        mut t: Targets,
        mut p: Params,
    ) -> Result<Action, Abort> {
        let i = v.int();
        let u = i as u32;
        let a = match (def.index, def.sub) {
            (0x6040, 0) => Action::Controlword(u as u16),
            (0x6060, 0) => {
                if OpMode::from_i8(i as i8).is_none() {
                    return Err(Abort::InvalidValue);
                }
                Action::Mode(i as i8)
            }
            (0x607A, 0) => {
                t.position_inc = i as i32;
                Action::Targets(t)
            }
            (0x60FF, 0) => {
                t.velocity_inc_s = i as i32;
                Action::Targets(t)
            }
            (0x6071, 0) => {
                t.torque_permille = i as i16;
                Action::Targets(t)
            }
            (0x60B1, 0) => {
                t.velocity_offset_inc_s = i as i32;
                Action::Targets(t)
            }
            (0x60B2, 0) => {
                t.torque_offset_permille = i as i16;
                Action::Targets(t)
            }
            (index, 0) => {
                match index {
                    0x605A => p.quick_stop_option = i as i16,
                    0x6007 => p.abort_connection_option = i as i16,
                    0x6065 => p.following_error_window_inc = u,
                    0x6066 => p.following_error_timeout_ms = u as u16,
                    0x6067 => p.position_window_inc = u,
                    0x6068 => p.position_window_time_ms = u as u16,
                    0x606D => p.velocity_window_inc_s = u as u16,
                    0x606E => p.velocity_window_time_ms = u as u16,
                    0x6072 => p.max_torque_permille = u as u16,
                    0x607F => p.max_profile_velocity_inc_s = u,
                    0x6081 => p.profile_velocity_inc_s = u,
                    0x6083 => p.profile_acceleration_inc_s2 = u,
                    0x6084 => p.profile_deceleration_inc_s2 = u,
                    0x6085 => p.quick_stop_deceleration_inc_s2 = u,
                    0x6087 => p.torque_slope_permille_s = u,
                    _ => return Err(Abort::UnsupportedAccess),
                }
                self.profile.check_params(&p)?;
                Action::Params(p)
            }
            _ => return Err(Abort::UnsupportedAccess),
        };
        Ok(a)
    }

    /// Apply a validated write. Only the store operations, the gains, the
    /// writable parameters and the calibrations (the device's own
    /// refusals: field weakening on halls, a sweep on halls are
    /// `InvalidValue`; a table's switch without its table, a sweep on an
    /// uncalibrated drive `DeviceState`) can still fail, having changed
    /// nothing here.
    pub fn apply<C: CanDevice>(
        &mut self,
        a: Action,
        now_us: u64,
        ctx: &mut C,
    ) -> Result<(), Abort> {
        match a {
            Action::ClearHistory => self.emcy.clear_history(),
            Action::SyncCobId(v) => self.sync_cob_id = v,
            Action::Cycle(v) => self.cycle_us = v,
            Action::Consumer(v) => self.consumer_entry = v,
            Action::Heartbeat(v) => self.heartbeat_ms = v,
            Action::Rpdo(n, c) => {
                if let Some(p) = self.rpdo.get_mut(n) {
                    *p = c;
                }
            }
            Action::Tpdo(n, c) => {
                if let Some(p) = self.tpdo.get_mut(n) {
                    *p = c;
                }
            }
            Action::Save => {
                // All or nothing (an aborted SDO changes nothing): the CAN
                // record first; if the drive's record then fails, the CAN
                // record goes back to what it held. (Two items of one
                // power-fail-safe log: each write is whole or absent, the
                // pair is made so by this order.)
                let s = self.settings_to_save();
                ctx.save_comm(&s).map_err(|_| Abort::Hardware)?;
                let link = ctx.link_setting();
                if ctx.store(StoreOp::Save, &[], link).is_err() {
                    // If this fails as well the flash itself is failing:
                    // the new CAN settings may stay (reported as the same
                    // hardware abort).
                    let _ = ctx.save_comm(&self.stored);
                    return Err(Abort::Hardware);
                }
                self.saved = Some(s);
                self.stored = s;
            }
            Action::Restore => {
                let link = ctx.link_setting();
                ctx.store(StoreOp::Erase, &[], link)
                    .map_err(|_| Abort::Hardware)?;
                // Nothing stored any more: a reset keeps the settings in
                // force; the next power-on starts from the defaults.
                self.saved = None;
                self.stored = CommSettings::DEFAULT;
            }
            Action::SpeedGains(g) => ctx.set_speed_gains(g).map_err(refusal)?,
            Action::Param(id, x) => ctx.set_param(id, x).map_err(refusal)?,
            Action::Calibrate(r) => ctx.start_calibration(r).map_err(refusal)?,
            Action::NodeId(n) => {
                self.next = CommSettings::new(
                    n,
                    self.next.bitrate_kbit(),
                    self.next.heartbeat_ms(),
                    self.next.consumer(),
                )
                .map_err(|_| Abort::InvalidValue)?;
            }
            Action::BitRate(b) => {
                self.next = CommSettings::new(
                    self.next.node_id(),
                    b,
                    self.next.heartbeat_ms(),
                    self.next.consumer(),
                )
                .map_err(|_| Abort::InvalidValue)?;
            }
            Action::Controlword(cw) => self.profile.write_controlword(cw, now_us, ctx),
            Action::Mode(m) => self.profile.write_mode(m, now_us, ctx)?,
            Action::Targets(t) => *self.profile.targets_mut() = t,
            Action::Params(p) => self.profile.set_params(p),
        }
        Ok(())
    }

    /// What 0x1010 saves: the node id and bit rate of 0x2100 / 0x2101,
    /// the heartbeat times in force.
    pub fn settings_to_save(&self) -> CommSettings {
        let consumer = HeartbeatConsumer::decode(self.consumer_entry);
        CommSettings::new(
            self.next.node_id(),
            self.next.bitrate_kbit(),
            self.heartbeat_ms,
            consumer,
        )
        .unwrap_or(self.next)
    }

    /// Write a whole value (SDO): validate, then apply.
    pub fn write<C: CanDevice>(
        &mut self,
        index: u16,
        sub: u8,
        bytes: &[u8],
        now_us: u64,
        ctx: &mut C,
    ) -> Result<(), Abort> {
        let a = self.prepare(index, sub, bytes, ctx)?;
        self.apply(a, now_us, ctx)
    }
}

fn comm_value(c: &PdoConfig, sub: u8) -> Result<Out, Abort> {
    match sub {
        1 => int(c.cob_id),
        2 => int(c.transmission),
        3 => int(c.inhibit_100us),
        5 => int(c.event_ms),
        _ => Err(Abort::NoSubIndex),
    }
}

fn map_value(c: &PdoConfig, sub: u8) -> Result<Out, Abort> {
    if sub == 0 {
        return int(c.map.count());
    }
    int(c.map.slot(sub).ok_or(Abort::NoSubIndex)?)
}
