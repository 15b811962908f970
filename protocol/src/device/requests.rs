//! One request: every value checked first, then the drive's status, then
//! the context called (a Nack always means nothing changed).

use super::*;

/// Largest `|value|` accepted for a gain (a sanity bound, not physics).
pub const MAX_GAIN: f32 = 1.0e9;

pub(super) fn out_of_range(field: u8) -> Response {
    Response::Nack(ErrorCode::OutOfRange { field })
}

/// Check that `x` is finite and within `[lo, hi]`; field number on error.
pub(super) fn check(x: f32, lo: f32, hi: f32, field: u8) -> Result<(), Response> {
    if x.is_finite() && x >= lo && x <= hi {
        Ok(())
    } else {
        Err(out_of_range(field))
    }
}

/// Map a [`Command::validate`] error on `cmd` to the offending field.
pub(super) fn command_field(cmd: &Command, e: CommandError) -> ErrorCode {
    match (cmd, e) {
        (_, CommandError::Faulted) => ErrorCode::Faulted,
        (_, CommandError::Busy) => ErrorCode::Busy,
        (_, CommandError::NotCalibrated) => ErrorCode::NotCalibrated,
        (_, CommandError::NeedsAngleSensor) => ErrorCode::NeedsAngleSensor,
        (Command::Impedance(i), e) => ErrorCode::OutOfRange {
            field: crate::joint::impedance_field(i, e),
        },
        (
            Command::OpenLoop {
                v_d_v,
                v_q_v,
                omega_e_rad_s,
                ..
            },
            CommandError::NonFinite,
        ) => {
            let field = if !v_d_v.is_finite() {
                1
            } else if !v_q_v.is_finite() {
                2
            } else if !omega_e_rad_s.is_finite() {
                4
            } else {
                1
            };
            ErrorCode::OutOfRange { field }
        }
        (Command::OpenLoop { .. }, CommandError::VelocityOutOfRange) => {
            ErrorCode::OutOfRange { field: 4 }
        }
        // Voltage magnitude (v_d, v_q together): the first of the pair.
        _ => ErrorCode::OutOfRange { field: 1 },
    }
}

/// [`Limits::validate`] (the drive's one check) as a field-exact Nack.
pub(super) fn validate_limits(l: &Limits) -> Result<(), Response> {
    l.validate().map_err(|e| {
        out_of_range(match e {
            LimitsError::MaxCurrent => 0,
            LimitsError::MaxVelocity => 1,
            LimitsError::MinPosition => 2,
            LimitsError::MaxPosition => 3,
            LimitsError::OpenLoopVoltage => 4,
            LimitsError::OpenLoopOmega => 5,
            LimitsError::MaxStiffness => 6,
            LimitsError::MaxDamping => 7,
        })
    })
}

impl DeviceState {
    pub(super) fn execute<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        req: &Request,
    ) -> Result<Response, Response> {
        let nack = |e: ErrorCode| Response::Nack(e);
        let refused = |r: Refusal| Response::Nack(r.into());
        match *req {
            Request::Ping => Ok(Response::Hello(Hello {
                protocol_version: crate::PROTOCOL_VERSION,
                firmware_version: ctx.firmware_version(),
                max_payload: MAX_PAYLOAD as u8,
            })),
            Request::KeepAlive => {
                ctx.keep_alive();
                self.watchdog.feed();
                Ok(Response::Ack)
            }
            Request::SetCommand(cmd) => self.set_command(ctx, cmd),
            Request::SetLimits(_)
            | Request::SetCurrentGains(_)
            | Request::SetSpeedGains(_)
            | Request::SetPositionGains(_)
            | Request::SetDividers { .. }
            | Request::SetParam { .. } => configure(ctx, req),
            Request::SetWatchdog(c) => {
                self.host_configured = true;
                self.watchdog.configure(c);
                Ok(Response::Ack)
            }
            Request::RunCalibration(routine) => {
                ctx.status().check_calibration().map_err(refused)?;
                ctx.start_calibration(routine).map_err(refused)?;
                Ok(Response::Ack)
            }
            Request::ReadFaults => {
                let (set, first) = ctx.faults();
                Ok(Response::Faults(FaultReport::new(set, first)))
            }
            Request::ClearFaults => {
                ctx.clear_faults();
                Ok(Response::Ack)
            }
            Request::ReadParam(id) => self.read_param(ctx, id),
            Request::ReadTelemetry => Ok(Response::Telemetry(output_telemetry(ctx))),
            Request::SetJoint(j) => self.set_joint(ctx, &j),
            Request::ReadJoint => Ok(Response::Joint(crate::joint::JointSettings::from_setup(
                &ctx.joint(),
            ))),
            Request::StartHoming(h) => self.start_homing(ctx, &h),
            Request::ReadHoming => Ok(Response::Homing(self.homing_state)),
            Request::StartTelemetry(rate) => self.start_telemetry(ctx, rate),
            Request::StopTelemetry => {
                self.telemetry_every = 0;
                Ok(Response::Ack)
            }
            Request::ReadConfig { source, offset } => self.read_config(ctx, source, offset),
            Request::WriteConfig(chunk) => {
                self.staging.write(&chunk).map_err(nack)?;
                Ok(Response::Ack)
            }
            Request::Store(op) => self.store(ctx, op),
            Request::SetScope(_)
            | Request::ArmScope
            | Request::TriggerScope
            | Request::ReadScope
            | Request::ReadScopeData { .. } => scope_request(ctx, req),
        }
    }

    /// `ReadParam`: the protocol's own parameters, else the context's.
    pub(super) fn read_param<C: DeviceContext>(
        &self,
        ctx: &C,
        id: ParamId,
    ) -> Result<Response, Response> {
        let value = match id {
            ParamId::ProtocolVersion => Some(f32::from(crate::PROTOCOL_VERSION)),
            ParamId::TelemetryDivider => Some(self.telemetry_every as f32),
            ParamId::WatchdogTimeout => Some(self.watchdog.config().timeout_periods as f32),
            _ => ctx.param(id),
        };
        value
            .map(|value| Response::Param { id, value })
            .ok_or(Response::Nack(ErrorCode::Unsupported))
    }

    /// `StartTelemetry`: the rate as a period divider, within what the
    /// link carries (a divider rounded up to stay within the cap); the
    /// first sample at the next poll.
    pub(super) fn start_telemetry<C: DeviceContext>(
        &mut self,
        ctx: &C,
        rate: TelemetryRate,
    ) -> Result<Response, Response> {
        let mut every = match rate {
            TelemetryRate::EveryPeriods(0) => return Err(out_of_range(1)),
            TelemetryRate::EveryPeriods(k) => k,
            TelemetryRate::Hz(hz) => {
                let pwm = ctx
                    .param(ParamId::PwmFrequencyHz)
                    .filter(|f| f.is_finite() && *f > 0.0)
                    .ok_or(Response::Nack(ErrorCode::Unsupported))?;
                check(hz, f32::MIN_POSITIVE, pwm, 1)?;
                let k = pwm / hz + 0.5;
                // hz <= pwm, so k >= 1.5 > 1; bounded above by u32.
                if k >= u32::MAX as f32 {
                    return Err(out_of_range(1));
                }
                (k as u32).max(1)
            }
        };
        if let Some(max_hz) = ctx.max_stream_hz() {
            let pwm = ctx.param(ParamId::PwmFrequencyHz).unwrap_or(f32::NAN);
            // The rate asked for (a rate, or the divider's), also
            // refused when the PWM frequency is unknown (NaN).
            let asked = match rate {
                TelemetryRate::Hz(hz) => hz,
                TelemetryRate::EveryPeriods(_) => pwm / every as f32,
            };
            if asked.is_nan() || asked > max_hz {
                return Err(out_of_range(1));
            }
            // A rate rounded to whole periods stays within the cap.
            let floor = pwm / max_hz;
            if floor.is_finite() && (every as f32) < floor {
                every = (floor as u32).saturating_add(1);
            }
        }
        self.telemetry_every = every;
        // First sample at the next poll.
        self.last_telemetry = self.last_seen.unwrap_or(0).wrapping_sub(every);
        self.stream_first = true;
        Ok(Response::Ack)
    }

    /// `SetCommand`: values checked field by field (output frame), the
    /// command converted to the rotor frame and checked against the limits
    /// in force and the drive's status, then posted; it aborts a homing.
    pub(super) fn set_command<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        cmd: Command,
    ) -> Result<Response, Response> {
        precheck_command(&cmd)?;
        let joint = self.host_joint(ctx);
        let rotor = crate::joint::command_to_rotor(&cmd, &joint.frame);
        let limits = crate::joint::limits_in_force(&ctx.limits(), &joint);
        let nack = |e| Response::Nack(command_field(&rotor, e));
        ctx.status().check_command(&rotor, &limits).map_err(nack)?;
        ctx.post(rotor).map_err(nack)?;
        self.abort_homing(ctx);
        self.posted(rotor);
        Ok(Response::Ack)
    }

    /// A command of the host or of homing was posted: the watchdog is
    /// armed (automatic setting) and fed, an impedance command kept for
    /// its damping.
    pub(super) fn posted(&mut self, rotor: Command) {
        if rotor != Command::Disable
            && !self.host_configured
            && self.watchdog.config().timeout_periods == 0
        {
            self.watchdog.configure(self.auto_watchdog);
        }
        self.watchdog.feed();
        if let Command::Impedance(i) = rotor {
            self.last_impedance = Some(i);
        }
    }

    pub(super) fn read_config<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        source: ConfigSource,
        offset: u16,
    ) -> Result<Response, Response> {
        // Reading the store may repair it (a write): not while running.
        if source == ConfigSource::Stored {
            ctx.status()
                .check_config()
                .map_err(|r| Response::Nack(r.into()))?;
        }
        let mut buf = [0u8; MAX_RECORD];
        let n = ctx
            .config_record(source, self.link_setting(), &mut buf)
            .map_err(Response::Nack)?;
        let record = buf.get(..n).ok_or(Response::Nack(ErrorCode::BadRecord))?;
        if usize::from(offset) > n {
            return Err(out_of_range(1));
        }
        Chunk::of(record, offset)
            .map(Response::ConfigChunk)
            .ok_or(Response::Nack(ErrorCode::BadRecord))
    }

    pub(super) fn store<C: DeviceContext>(
        &mut self,
        ctx: &mut C,
        op: StoreOp,
    ) -> Result<Response, Response> {
        ctx.status()
            .check_config()
            .map_err(|r| Response::Nack(r.into()))?;
        let mut staged = [0u8; MAX_RECORD];
        let mut n = 0;
        if op.uses_staged() {
            let rec = self
                .staging
                .complete()
                .ok_or(Response::Nack(ErrorCode::BadRecord))?;
            n = rec.len();
            staged
                .get_mut(..n)
                .ok_or(Response::Nack(ErrorCode::BadRecord))?
                .copy_from_slice(rec);
            // Applied or refused, a staged record is used once.
            self.staging.clear();
        }
        let link = ctx
            .store(op, staged.get(..n).unwrap_or(&[]), self.link_setting())
            .map_err(Response::Nack)?;
        if let Some(c) = link {
            self.adopt_link_setting(c);
        }
        Ok(Response::Ack)
    }
}

/// The configuration setters (limits, gains, dividers): values checked
/// field by field, then the drive's status (only while started and
/// disabled), then the context's own rules.
pub(super) fn configure<C: DeviceContext>(
    ctx: &mut C,
    req: &Request,
) -> Result<Response, Response> {
    let refused = |r: Refusal| Response::Nack(r.into());
    match *req {
        Request::SetLimits(l) => {
            validate_limits(&l)?;
            ctx.status().check_config().map_err(refused)?;
            ctx.set_limits(l).map_err(refused)?;
            Ok(Response::Ack)
        }
        Request::SetCurrentGains(g) => {
            for (i, x) in [g.kp_d, g.ki_d, g.kp_q, g.ki_q].into_iter().enumerate() {
                check(x, 0.0, MAX_GAIN, i as u8)?;
            }
            ctx.status().check_config().map_err(refused)?;
            ctx.set_current_gains(g).map_err(refused)?;
            Ok(Response::Ack)
        }
        Request::SetSpeedGains(g) => {
            check(g.kp_a_per_rad_s, 0.0, MAX_GAIN, 0)?;
            check(g.ki_a_per_rad, 0.0, MAX_GAIN, 1)?;
            ctx.status().check_config().map_err(refused)?;
            ctx.set_speed_gains(g).map_err(refused)?;
            Ok(Response::Ack)
        }
        Request::SetPositionGains(g) => {
            check(g.kp_per_s, 0.0, MAX_GAIN, 0)?;
            check(g.max_velocity_rad_s, f32::MIN_POSITIVE, f32::MAX, 1)?;
            check(g.max_acceleration_rad_s2, f32::MIN_POSITIVE, f32::MAX, 2)?;
            ctx.status().check_config().map_err(refused)?;
            ctx.set_position_gains(g).map_err(refused)?;
            Ok(Response::Ack)
        }
        Request::SetDividers { speed, position } => {
            if speed == 0 {
                return Err(out_of_range(0));
            }
            if position == 0 {
                return Err(out_of_range(1));
            }
            ctx.status().check_config().map_err(refused)?;
            ctx.set_dividers(speed, position).map_err(refused)?;
            Ok(Response::Ack)
        }
        Request::SetParam { id, value } => {
            if !id.is_writable() {
                return Err(out_of_range(0));
            }
            if !id.accepts(value) {
                return Err(out_of_range(1));
            }
            ctx.status().check_config().map_err(refused)?;
            ctx.set_param(id, value).map_err(refused)?;
            Ok(Response::Ack)
        }
        _ => Err(Response::Nack(ErrorCode::Unsupported)),
    }
}

/// Field-exact reporting of what a conversion or the drive's check would
/// not name: non-finite open-loop values, an impedance command's
/// non-finite values and negative torque limit.
pub(super) fn precheck_command(cmd: &Command) -> Result<(), Response> {
    match *cmd {
        Command::OpenLoop {
            v_d_v,
            v_q_v,
            omega_e_rad_s,
            ..
        } => {
            for (x, f) in [(v_d_v, 1), (v_q_v, 2), (omega_e_rad_s, 4)] {
                if !x.is_finite() {
                    return Err(out_of_range(f));
                }
            }
            Ok(())
        }
        Command::Impedance(i) => crate::joint::impedance_precheck(&i).map_err(out_of_range),
        _ => Ok(()),
    }
}

/// The scope's requests.
pub(super) fn scope_request<C: DeviceContext>(
    ctx: &mut C,
    req: &Request,
) -> Result<Response, Response> {
    use crate::scope::{scope_nack, ScopeData, ScopeReport, DATA_PER_FRAME};
    let pwm_hz = ctx.param(ParamId::PwmFrequencyHz).unwrap_or(f32::NAN);
    let now = ctx.feedback();
    let unsupported = Response::Nack(ErrorCode::Unsupported);
    let scope = ctx.scope().ok_or(unsupported)?;
    let refused = |e| Response::Nack(scope_nack(e));
    match *req {
        Request::SetScope(c) => scope.configure(&c).map_err(refused)?,
        Request::ArmScope => scope.arm(&now),
        Request::TriggerScope => scope.force().map_err(refused)?,
        Request::ReadScope => {
            let status = scope.status();
            return Ok(Response::Scope(ScopeReport {
                status,
                sample_period_s: f32::from(status.config.divider) / pwm_hz,
            }));
        }
        Request::ReadScopeData { offset } => {
            let st = scope.status();
            if st.state != foc_core::scope::State::Done {
                return Err(Response::Nack(ErrorCode::ScopeState));
            }
            let total = usize::from(st.captured).saturating_mul(usize::from(st.config.channels));
            if usize::from(offset) > total {
                return Err(out_of_range(0));
            }
            let mut values = [0.0; DATA_PER_FRAME];
            let n = scope.read(usize::from(offset), &mut values);
            return Ok(Response::ScopeData(ScopeData {
                offset,
                count: n.min(DATA_PER_FRAME) as u8,
                values,
            }));
        }
        _ => return Err(Response::Nack(ErrorCode::UnknownMessage)),
    }
    Ok(Response::Ack)
}
