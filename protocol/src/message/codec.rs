//! The messages on the wire: tags, little-endian fields, and the
//! [`Message`] codec of [`Request`] and [`Response`].

use super::*;

pub(super) fn get_telemetry(r: &mut Reader<'_>) -> Result<Telemetry, DecodeError> {
    // Fields in wire order (struct literals evaluate in source order, but
    // the flags byte feeds two fields).
    let period = r.u32()?;
    let i_d_a = r.f32()?;
    let i_q_a = r.f32()?;
    let v_d_v = r.f32()?;
    let v_q_v = r.f32()?;
    let velocity_rad_s = r.f32()?;
    let position_rad = r.f32()?;
    let mode = mode_from_code(r.u8()?).ok_or(DecodeError::BadField(7))?;
    let fault_code = r.u8()?;
    let max_loop_cycles = r.u32()?;
    let v_bus_v = r.f32()?;
    let power_limit = active_limit_from_code(r.u8()?).ok_or(DecodeError::BadField(11))?;
    let limit_left_pct = match r.u8()? {
        p @ 0..=100 => p,
        _ => return Err(DecodeError::BadField(12)),
    };
    let flags = match r.u8()? {
        f @ 0..=15 => f,
        _ => return Err(DecodeError::BadField(13)),
    };
    let winding_c = temperature_from_wire(r.u16()? as i16);
    let stage_c = temperature_from_wire(r.u16()? as i16);
    Ok(Telemetry {
        period,
        i_d_a,
        i_q_a,
        v_d_v,
        v_q_v,
        velocity_rad_s,
        position_rad,
        mode,
        fault_code,
        max_loop_cycles,
        v_bus_v,
        power_limit,
        limit_left_pct,
        brake_on: flags & 1 != 0,
        brake_locked: flags & 2 != 0,
        winding_c,
        stage_c,
        // Two bits: every value is a code.
        angle_in_use: AngleInUse::from_code((flags >> 2) & 3).unwrap_or_default(),
    })
}

pub(super) fn put_command(w: &mut Writer<'_>, c: &Command) {
    w.u8(c.mode() as u8);
    match *c {
        Command::Disable => {}
        Command::Torque { iq_a } => w.f32(iq_a),
        Command::Velocity { rad_s } => w.f32(rad_s),
        Command::Position { rad } => w.f32(rad),
        Command::OpenLoop {
            v_d_v,
            v_q_v,
            theta_e,
            omega_e_rad_s,
        } => {
            w.f32(v_d_v);
            w.f32(v_q_v);
            w.u32(theta_e.to_bits());
            w.f32(omega_e_rad_s);
        }
        Command::Impedance(i) => {
            w.f32(i.position_rad);
            w.f32(i.velocity_rad_s);
            w.f32(i.kp_nm_per_rad);
            w.f32(i.kd_nm_s_per_rad);
            w.f32(i.torque_ff_nm);
            w.f32(i.torque_limit_nm);
        }
    }
}

pub(super) fn get_command(r: &mut Reader<'_>) -> Result<Command, DecodeError> {
    let mode = mode_from_code(r.u8()?).ok_or(DecodeError::BadField(0))?;
    Ok(match mode {
        Mode::Disabled => Command::Disable,
        Mode::Torque => Command::Torque { iq_a: r.f32()? },
        Mode::Velocity => Command::Velocity { rad_s: r.f32()? },
        Mode::Position => Command::Position { rad: r.f32()? },
        Mode::OpenLoop => Command::OpenLoop {
            v_d_v: r.f32()?,
            v_q_v: r.f32()?,
            theta_e: ElectricalAngle::from_bits(r.u32()?),
            omega_e_rad_s: r.f32()?,
        },
        Mode::Impedance => Command::Impedance(Impedance {
            position_rad: r.f32()?,
            velocity_rad_s: r.f32()?,
            kp_nm_per_rad: r.f32()?,
            kd_nm_s_per_rad: r.f32()?,
            torque_ff_nm: r.f32()?,
            torque_limit_nm: r.f32()?,
        }),
    })
}

pub(super) fn put_joint(w: &mut Writer<'_>, j: &JointSettings) {
    w.f32(j.gear_ratio);
    w.f32(j.rotor_at_zero_rad);
    let (flag, (lo, hi)) = match j.travel_out_rad {
        Some(range) => (1, range),
        None => (0, (0.0, 0.0)),
    };
    w.u8(flag);
    w.f32(lo);
    w.f32(hi);
    w.f32(j.fault_margin_rad);
    w.f32(j.brake_accel_rad_s2);
    w.f32(j.kv_a_per_rad_s);
    w.u32(j.entry_blend_periods);
    w.f32(j.timeout_kd_nm_s_per_rad);
}

pub(super) fn get_joint(r: &mut Reader<'_>) -> Result<JointSettings, DecodeError> {
    let gear_ratio = r.f32()?;
    let rotor_at_zero_rad = r.f32()?;
    let flag = r.u8()?;
    let range = (r.f32()?, r.f32()?);
    // Without a travel range its two fields are 0 (one layout per value).
    let travel_out_rad = match flag {
        0 if range.0.to_bits() == 0 && range.1.to_bits() == 0 => None,
        0 => return Err(DecodeError::BadField(3)),
        1 => Some(range),
        _ => return Err(DecodeError::BadField(2)),
    };
    Ok(JointSettings {
        gear_ratio,
        rotor_at_zero_rad,
        travel_out_rad,
        fault_margin_rad: r.f32()?,
        brake_accel_rad_s2: r.f32()?,
        kv_a_per_rad_s: r.f32()?,
        entry_blend_periods: r.u32()?,
        timeout_kd_nm_s_per_rad: r.f32()?,
    })
}

pub(super) fn put_homing(w: &mut Writer<'_>, h: &HomingStart) {
    match h.method {
        HomingMethod::Present => {
            w.u8(0);
            w.f32(h.home_output_rad);
        }
        HomingMethod::EndStop(e) => {
            w.u8(1);
            w.f32(h.home_output_rad);
            w.f32(e.velocity_rad_s);
            w.f32(e.current_a);
            w.f32(e.detect_fraction);
            w.f32(e.confirm_s);
            w.f32(e.backoff_rad);
            w.f32(e.max_travel_rad);
        }
    }
}

pub(super) fn get_homing(r: &mut Reader<'_>) -> Result<HomingStart, DecodeError> {
    let method = r.u8()?;
    let home_output_rad = r.f32()?;
    let method = match method {
        0 => HomingMethod::Present,
        1 => HomingMethod::EndStop(EndStop {
            velocity_rad_s: r.f32()?,
            current_a: r.f32()?,
            detect_fraction: r.f32()?,
            confirm_s: r.f32()?,
            backoff_rad: r.f32()?,
            max_travel_rad: r.f32()?,
        }),
        _ => return Err(DecodeError::BadField(0)),
    };
    Ok(HomingStart {
        method,
        home_output_rad,
    })
}

pub(super) fn put_chunk(w: &mut Writer<'_>, c: &Chunk) {
    w.u16(c.offset);
    w.u16(c.total);
    w.u8(c.data().len() as u8);
    w.bytes(c.data());
}

pub(super) fn get_chunk(r: &mut Reader<'_>) -> Result<Chunk, DecodeError> {
    let offset = r.u16()?;
    let total = r.u16()?;
    let len = r.u8()?;
    Chunk::new(offset, total, r.slice(usize::from(len))?).ok_or(DecodeError::BadField(2))
}

pub(super) mod tags {
    pub const PING: u8 = 0x01;
    pub const KEEP_ALIVE: u8 = 0x02;
    pub const SET_COMMAND: u8 = 0x10;
    pub const SET_LIMITS: u8 = 0x11;
    pub const SET_CURRENT_GAINS: u8 = 0x12;
    pub const SET_SPEED_GAINS: u8 = 0x13;
    pub const SET_POSITION_GAINS: u8 = 0x14;
    pub const SET_DIVIDERS: u8 = 0x15;
    pub const SET_WATCHDOG: u8 = 0x16;
    pub const SET_JOINT: u8 = 0x17;
    pub const SET_PARAM: u8 = 0x18;
    pub const RUN_CALIBRATION: u8 = 0x20;
    pub const READ_FAULTS: u8 = 0x21;
    pub const CLEAR_FAULTS: u8 = 0x22;
    pub const READ_PARAM: u8 = 0x23;
    pub const READ_TELEMETRY: u8 = 0x24;
    pub const READ_JOINT: u8 = 0x25;
    pub const START_HOMING: u8 = 0x26;
    pub const READ_HOMING: u8 = 0x27;
    pub const START_TELEMETRY: u8 = 0x30;
    pub const STOP_TELEMETRY: u8 = 0x31;
    pub const READ_CONFIG: u8 = 0x40;
    pub const WRITE_CONFIG: u8 = 0x41;
    pub const STORE: u8 = 0x42;
    pub const SET_SCOPE: u8 = 0x50;
    pub const ARM_SCOPE: u8 = 0x51;
    pub const TRIGGER_SCOPE: u8 = 0x52;
    pub const READ_SCOPE: u8 = 0x53;
    pub const READ_SCOPE_DATA: u8 = 0x54;

    pub const ACK: u8 = 0x80;
    pub const NACK: u8 = 0x81;
    pub const HELLO: u8 = 0x82;
    pub const FAULTS: u8 = 0x83;
    pub const PARAM: u8 = 0x84;
    pub const TELEMETRY: u8 = 0x85;
    pub const STREAM: u8 = 0x86;
    pub const CONFIG_CHUNK: u8 = 0x87;
    pub const JOINT: u8 = 0x88;
    pub const HOMING: u8 = 0x89;
    pub const SCOPE: u8 = 0x8A;
    pub const SCOPE_DATA: u8 = 0x8B;
}

impl Message for Request {
    fn tag(&self) -> u8 {
        use tags::*;
        match self {
            Request::Ping => PING,
            Request::KeepAlive => KEEP_ALIVE,
            Request::SetCommand(_) => SET_COMMAND,
            Request::SetLimits(_) => SET_LIMITS,
            Request::SetCurrentGains(_) => SET_CURRENT_GAINS,
            Request::SetSpeedGains(_) => SET_SPEED_GAINS,
            Request::SetPositionGains(_) => SET_POSITION_GAINS,
            Request::SetDividers { .. } => SET_DIVIDERS,
            Request::SetWatchdog(_) => SET_WATCHDOG,
            Request::SetJoint(_) => SET_JOINT,
            Request::SetParam { .. } => SET_PARAM,
            Request::ReadJoint => READ_JOINT,
            Request::StartHoming(_) => START_HOMING,
            Request::ReadHoming => READ_HOMING,
            Request::RunCalibration(_) => RUN_CALIBRATION,
            Request::ReadFaults => READ_FAULTS,
            Request::ClearFaults => CLEAR_FAULTS,
            Request::ReadParam(_) => READ_PARAM,
            Request::ReadTelemetry => READ_TELEMETRY,
            Request::StartTelemetry(_) => START_TELEMETRY,
            Request::StopTelemetry => STOP_TELEMETRY,
            Request::ReadConfig { .. } => READ_CONFIG,
            Request::WriteConfig(_) => WRITE_CONFIG,
            Request::Store(_) => STORE,
            Request::SetScope(_) => SET_SCOPE,
            Request::ArmScope => ARM_SCOPE,
            Request::TriggerScope => TRIGGER_SCOPE,
            Request::ReadScope => READ_SCOPE,
            Request::ReadScopeData { .. } => READ_SCOPE_DATA,
        }
    }

    fn encode_body(&self, w: &mut Writer<'_>) {
        match self {
            Request::Ping
            | Request::KeepAlive
            | Request::ReadFaults
            | Request::ClearFaults
            | Request::ReadTelemetry
            | Request::StopTelemetry
            | Request::ReadJoint
            | Request::ReadHoming
            | Request::ArmScope
            | Request::TriggerScope
            | Request::ReadScope => {}
            Request::SetScope(c) => crate::scope::put_config(w, c),
            Request::ReadScopeData { offset } => w.u16(*offset),
            Request::SetCommand(c) => put_command(w, c),
            Request::SetLimits(l) => {
                w.f32(l.max_current_a);
                w.f32(l.max_velocity_rad_s);
                w.f32(l.min_position_rad);
                w.f32(l.max_position_rad);
                w.f32(l.max_open_loop_voltage_v);
                w.f32(l.max_open_loop_omega_e_rad_s);
                w.f32(l.max_kp_nm_per_rad);
                w.f32(l.max_kd_nm_s_per_rad);
            }
            Request::SetCurrentGains(g) => {
                w.f32(g.kp_d);
                w.f32(g.ki_d);
                w.f32(g.kp_q);
                w.f32(g.ki_q);
            }
            Request::SetSpeedGains(g) => {
                w.f32(g.kp_a_per_rad_s);
                w.f32(g.ki_a_per_rad);
            }
            Request::SetPositionGains(g) => {
                w.f32(g.kp_per_s);
                w.f32(g.max_velocity_rad_s);
                w.f32(g.max_acceleration_rad_s2);
            }
            Request::SetDividers { speed, position } => {
                w.u16(*speed);
                w.u16(*position);
            }
            Request::SetWatchdog(c) => {
                w.u32(c.timeout_periods);
                w.u8(reaction_code(c.reaction));
            }
            Request::SetJoint(j) => put_joint(w, j),
            Request::SetParam { id, value } => {
                w.u8(*id as u8);
                w.f32(*value);
            }
            Request::StartHoming(h) => put_homing(w, h),
            Request::RunCalibration(c) => w.u8(*c as u8),
            Request::ReadParam(p) => w.u8(*p as u8),
            Request::StartTelemetry(rate) => match *rate {
                TelemetryRate::EveryPeriods(k) => {
                    w.u8(0);
                    w.u32(k);
                }
                TelemetryRate::Hz(hz) => {
                    w.u8(1);
                    w.f32(hz);
                }
            },
            Request::ReadConfig { source, offset } => {
                w.u8(*source as u8);
                w.u16(*offset);
            }
            Request::WriteConfig(c) => put_chunk(w, c),
            Request::Store(op) => w.u8(*op as u8),
        }
    }

    fn decode_body(tag: u8, r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        use tags::*;
        Ok(match tag {
            PING => Request::Ping,
            KEEP_ALIVE => Request::KeepAlive,
            SET_COMMAND => Request::SetCommand(get_command(r)?),
            SET_LIMITS => Request::SetLimits(Limits {
                max_current_a: r.f32()?,
                max_velocity_rad_s: r.f32()?,
                min_position_rad: r.f32()?,
                max_position_rad: r.f32()?,
                max_open_loop_voltage_v: r.f32()?,
                max_open_loop_omega_e_rad_s: r.f32()?,
                max_kp_nm_per_rad: r.f32()?,
                max_kd_nm_s_per_rad: r.f32()?,
            }),
            SET_CURRENT_GAINS => Request::SetCurrentGains(CurrentGains {
                kp_d: r.f32()?,
                ki_d: r.f32()?,
                kp_q: r.f32()?,
                ki_q: r.f32()?,
            }),
            SET_SPEED_GAINS => Request::SetSpeedGains(SpeedGains {
                kp_a_per_rad_s: r.f32()?,
                ki_a_per_rad: r.f32()?,
            }),
            SET_POSITION_GAINS => Request::SetPositionGains(PositionGains {
                kp_per_s: r.f32()?,
                max_velocity_rad_s: r.f32()?,
                max_acceleration_rad_s2: r.f32()?,
            }),
            SET_DIVIDERS => Request::SetDividers {
                speed: r.u16()?,
                position: r.u16()?,
            },
            SET_WATCHDOG => {
                let timeout_periods = r.u32()?;
                let reaction = reaction_from_code(r.u8()?).ok_or(DecodeError::BadField(1))?;
                Request::SetWatchdog(WatchdogConfig {
                    timeout_periods,
                    reaction,
                })
            }
            SET_JOINT => Request::SetJoint(get_joint(r)?),
            SET_PARAM => Request::SetParam {
                id: ParamId::from_code(r.u8()?).ok_or(DecodeError::BadField(0))?,
                value: r.f32()?,
            },
            READ_JOINT => Request::ReadJoint,
            START_HOMING => Request::StartHoming(get_homing(r)?),
            READ_HOMING => Request::ReadHoming,
            SET_SCOPE => Request::SetScope(crate::scope::get_config(r)?),
            ARM_SCOPE => Request::ArmScope,
            TRIGGER_SCOPE => Request::TriggerScope,
            READ_SCOPE => Request::ReadScope,
            READ_SCOPE_DATA => Request::ReadScopeData { offset: r.u16()? },
            RUN_CALIBRATION => Request::RunCalibration(
                Calibration::from_code(r.u8()?).ok_or(DecodeError::BadField(0))?,
            ),
            READ_FAULTS => Request::ReadFaults,
            CLEAR_FAULTS => Request::ClearFaults,
            READ_PARAM => {
                Request::ReadParam(ParamId::from_code(r.u8()?).ok_or(DecodeError::BadField(0))?)
            }
            READ_TELEMETRY => Request::ReadTelemetry,
            START_TELEMETRY => Request::StartTelemetry(match r.u8()? {
                0 => TelemetryRate::EveryPeriods(r.u32()?),
                1 => TelemetryRate::Hz(r.f32()?),
                _ => return Err(DecodeError::BadField(0)),
            }),
            STOP_TELEMETRY => Request::StopTelemetry,
            READ_CONFIG => Request::ReadConfig {
                source: ConfigSource::from_code(r.u8()?).ok_or(DecodeError::BadField(0))?,
                offset: r.u16()?,
            },
            WRITE_CONFIG => Request::WriteConfig(get_chunk(r)?),
            STORE => Request::Store(StoreOp::from_code(r.u8()?).ok_or(DecodeError::BadField(0))?),
            _ => return Err(DecodeError::UnknownTag),
        })
    }
}

impl Message for Response {
    fn tag(&self) -> u8 {
        use tags::*;
        match self {
            Response::Ack => ACK,
            Response::Nack(_) => NACK,
            Response::Hello(_) => HELLO,
            Response::Faults(_) => FAULTS,
            Response::Param { .. } => PARAM,
            Response::Telemetry(_) => TELEMETRY,
            Response::Stream(_) => STREAM,
            Response::ConfigChunk(_) => CONFIG_CHUNK,
            Response::Joint(_) => JOINT,
            Response::Homing(_) => HOMING,
            Response::Scope(_) => SCOPE,
            Response::ScopeData(_) => SCOPE_DATA,
        }
    }

    fn encode_body(&self, w: &mut Writer<'_>) {
        match self {
            Response::Ack => {}
            Response::Nack(e) => {
                let (c, f) = e.to_wire();
                w.u8(c);
                w.u8(f);
            }
            Response::Hello(h) => {
                w.u8(h.protocol_version);
                w.bytes(&h.firmware_version);
                w.u8(h.max_payload);
            }
            Response::Faults(f) => {
                w.u32(f.set.0);
                w.u8(f.first_code);
            }
            Response::Param { id, value } => {
                w.u8(*id as u8);
                w.f32(*value);
            }
            Response::Telemetry(t) | Response::Stream(t) => {
                w.u32(t.period);
                w.f32(t.i_d_a);
                w.f32(t.i_q_a);
                w.f32(t.v_d_v);
                w.f32(t.v_q_v);
                w.f32(t.velocity_rad_s);
                w.f32(t.position_rad);
                w.u8(t.mode as u8);
                w.u8(t.fault_code);
                w.u32(t.max_loop_cycles);
                w.f32(t.v_bus_v);
                w.u8(t.power_limit as u8);
                w.u8(t.limit_left_pct.min(100));
                w.u8(u8::from(t.brake_on)
                    | (u8::from(t.brake_locked) << 1)
                    | (t.angle_in_use.code() << 2));
                w.u16(temperature_to_wire(t.winding_c) as u16);
                w.u16(temperature_to_wire(t.stage_c) as u16);
            }
            Response::ConfigChunk(c) => put_chunk(w, c),
            Response::Joint(j) => put_joint(w, j),
            Response::Homing(h) => {
                let (state, reason) = h.to_wire();
                w.u8(state);
                w.u8(reason);
            }
            Response::Scope(r) => crate::scope::put_report(w, r),
            Response::ScopeData(d) => crate::scope::put_data(w, d),
        }
    }

    fn decode_body(tag: u8, r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        use tags::*;
        Ok(match tag {
            ACK => Response::Ack,
            NACK => {
                let code = r.u8()?;
                let field = r.u8()?;
                Response::Nack(ErrorCode::from_wire(code, field))
            }
            HELLO => Response::Hello(Hello {
                protocol_version: r.u8()?,
                firmware_version: [r.u8()?, r.u8()?, r.u8()?],
                max_payload: r.u8()?,
            }),
            FAULTS => Response::Faults(FaultReport {
                set: FaultSet(r.u32()?),
                first_code: r.u8()?,
            }),
            PARAM => Response::Param {
                id: ParamId::from_code(r.u8()?).ok_or(DecodeError::BadField(0))?,
                value: r.f32()?,
            },
            TELEMETRY => Response::Telemetry(get_telemetry(r)?),
            STREAM => Response::Stream(get_telemetry(r)?),
            CONFIG_CHUNK => Response::ConfigChunk(get_chunk(r)?),
            JOINT => Response::Joint(get_joint(r)?),
            HOMING => {
                let state = r.u8()?;
                let reason = r.u8()?;
                Response::Homing(
                    HomingState::from_wire(state, reason).ok_or(DecodeError::BadField(0))?,
                )
            }
            SCOPE => Response::Scope(crate::scope::get_report(r)?),
            SCOPE_DATA => Response::ScopeData(crate::scope::get_data(r)?),
            _ => return Err(DecodeError::UnknownTag),
        })
    }
}
