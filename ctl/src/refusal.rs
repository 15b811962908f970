//! A refusal in words: the field a Nack points at, the value that was sent
//! and the range the device allows, read from the device itself (its
//! limits in force, its hardware current limit) where the rule depends on
//! them.
//!
//! ```no_run
//! use foc_ctl::{refusal, Client};
//! use foc_core::control::Command;
//! use foc_protocol::message::Request;
//! let mut c = Client::connect_tcp("127.0.0.1:4444")?;
//! let cmd = Command::Torque { iq_a: 500.0 };
//! if let Err(e) = c.set_command(cmd) {
//!     // "refused by the device: `iq_a` = 500 A is out of range (allowed: -10 .. 10 A,
//!     // the current limit); nothing changed"
//!     println!("{}", refusal::explain(&mut c, &Request::SetCommand(cmd), &e));
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use crate::joint::nack_text;
use crate::{Client, ClientError};
use foc_core::control::field::MIN_VOLTAGE_MARGIN;
use foc_core::control::stage::COARSE_FIELD_WEAKENING;
use foc_core::control::{Command, Limits};
use foc_protocol::device::MAX_GAIN;
use foc_protocol::message::{Calibration, ErrorCode, ParamId, Request, TelemetryRate};

/// The value of field `field` of `req` as sent, with its unit (`None`
/// past the numeric fields).
pub fn field_value(req: &Request, field: u8) -> Option<(f32, &'static str)> {
    let vals: &[(f32, &str)] = &match req {
        Request::SetCommand(c) => command_values(c),
        Request::SetLimits(l) => vec![
            (l.max_current_a, "A"),
            (l.max_velocity_rad_s, "rad/s"),
            (l.min_position_rad, "rad"),
            (l.max_position_rad, "rad"),
            (l.max_open_loop_voltage_v, "V"),
            (l.max_open_loop_omega_e_rad_s, "rad/s"),
            (l.max_kp_nm_per_rad, "N m/rad"),
            (l.max_kd_nm_s_per_rad, "N m s/rad"),
        ],
        Request::SetCurrentGains(g) => vec![
            (g.kp_d, "V/A"),
            (g.ki_d, "V/(A s)"),
            (g.kp_q, "V/A"),
            (g.ki_q, "V/(A s)"),
        ],
        Request::SetSpeedGains(g) => {
            vec![(g.kp_a_per_rad_s, "A/(rad/s)"), (g.ki_a_per_rad, "A/rad")]
        }
        Request::SetPositionGains(g) => vec![
            (g.kp_per_s, "1/s"),
            (g.max_velocity_rad_s, "rad/s"),
            (g.max_acceleration_rad_s2, "rad/s^2"),
        ],
        Request::SetDividers { speed, position } => {
            vec![
                (f32::from(*speed), "periods"),
                (f32::from(*position), "periods"),
            ]
        }
        Request::SetWatchdog(w) => vec![(w.timeout_periods as f32, "periods")],
        Request::SetParam { id, value } => vec![(f32::from(*id as u8), ""), (*value, id.unit())],
        Request::StartTelemetry(TelemetryRate::Hz(hz)) => vec![(0.0, ""), (*hz, "Hz")],
        Request::StartTelemetry(TelemetryRate::EveryPeriods(k)) => {
            vec![(1.0, ""), (*k as f32, "periods")]
        }
        _ => Vec::new(),
    };
    vals.get(usize::from(field)).copied()
}

/// A command's values in body order (the mode first, as a code).
fn command_values(c: &Command) -> Vec<(f32, &'static str)> {
    let mode = (f32::from(c.mode() as u8), "");
    match *c {
        Command::Disable => vec![mode],
        Command::Torque { iq_a } => vec![mode, (iq_a, "A")],
        Command::Velocity { rad_s } => vec![mode, (rad_s, "rad/s")],
        Command::Position { rad } => vec![mode, (rad, "rad")],
        Command::OpenLoop {
            v_d_v,
            v_q_v,
            theta_e,
            omega_e_rad_s,
        } => vec![
            mode,
            (v_d_v, "V"),
            (v_q_v, "V"),
            (theta_e.to_radians(), "rad"),
            (omega_e_rad_s, "rad/s"),
        ],
        Command::Impedance(i) => vec![
            mode,
            (i.position_rad, "rad"),
            (i.velocity_rad_s, "rad/s"),
            (i.kp_nm_per_rad, "N m/rad"),
            (i.kd_nm_s_per_rad, "N m s/rad"),
            (i.torque_ff_nm, "N m"),
            (i.torque_limit_nm, "N m"),
        ],
    }
}

/// The range the device allows for field `field` of `req`, in words, from
/// the limits `l` in force (`None` where it is not a plain range).
pub fn allowed_range(
    req: &Request,
    field: u8,
    l: &Limits,
    board_max_a: Option<f32>,
) -> Option<String> {
    let sym = |m: f32, u: &str, what: &str| Some(format!("-{m} .. {m} {u}, {what}"));
    match (req, field) {
        (Request::SetCommand(Command::Torque { .. }), 1) => sym(l.max_current_a, "A", "the current limit"),
        (Request::SetCommand(Command::Velocity { .. }), 1) => {
            sym(l.max_velocity_rad_s, "rad/s", "the velocity limit")
        }
        (Request::SetCommand(Command::Position { .. }), 1) => Some(format!(
            "{} .. {} rad, the position range (the joint's travel range where set)",
            l.min_position_rad, l.max_position_rad
        )),
        (Request::SetCommand(Command::OpenLoop { .. }), 1 | 2) => Some(format!(
            "|v| <= {} V, the open-loop voltage limit",
            l.max_open_loop_voltage_v
        )),
        (Request::SetCommand(Command::OpenLoop { .. }), 4) => {
            sym(l.max_open_loop_omega_e_rad_s, "rad/s", "the open-loop speed limit, electrical")
        }
        (Request::SetCommand(Command::Impedance(_)), 1) => Some(format!(
            "{} .. {} rad, the position range",
            l.min_position_rad, l.max_position_rad
        )),
        (Request::SetCommand(Command::Impedance(_)), 2) => {
            sym(l.max_velocity_rad_s, "rad/s", "the velocity limit")
        }
        (Request::SetCommand(Command::Impedance(_)), 3) => Some(format!(
            "0 .. {} N m/rad, the stiffness limit",
            l.max_kp_nm_per_rad
        )),
        (Request::SetCommand(Command::Impedance(_)), 4) => Some(format!(
            "0 .. {} N m s/rad, the damping limit",
            l.max_kd_nm_s_per_rad
        )),
        (Request::SetLimits(_), 0) => Some(match board_max_a {
            Some(m) => format!("above 0, at most {m} A, this board's hardware limit"),
            None => "above 0 and finite".into(),
        }),
        (Request::SetLimits(_), 1) => Some("above 0 and finite".into()),
        (Request::SetLimits(_), 2 | 3) => Some("finite, the lowest below the highest".into()),
        (Request::SetLimits(_), _) => Some("finite and not negative".into()),
        (
            Request::SetCurrentGains(_) | Request::SetSpeedGains(_) | Request::SetPositionGains(_),
            _,
        ) => Some(format!("0 .. {MAX_GAIN:e}, finite")),
        (Request::SetDividers { .. }, _) => Some("at least 1".into()),
        (Request::SetParam { .. }, 0) => Some(format!(
            "one of the parameters that can be written: {}",
            writable_names()
        )),
        (Request::SetParam { id, .. }, 1) if id.is_switch() => Some("0 (off) or 1 (on)".into()),
        (Request::SetParam { id: ParamId::MaxIdA, .. }, 1) => Some(
            "0 .. 1e6 A, finite (field weakening uses at most the current limit)".into(),
        ),
        (Request::StartTelemetry(_), 1) => Some(
            "above 0, at most the PWM rate and what the link carries (a board's 115200-baud UART: 192 Hz)".into(),
        ),
        _ => None,
    }
}

/// The limits `l` (rotor frame) in the frame a command's values are sent
/// in (the joint's output frame: positions through its offset and gear,
/// velocities through the gear, stiffness and damping times its square),
/// with the frame's name for the text.
fn in_command_frame(c: &mut Client, req: &Request, l: Limits) -> (Limits, &'static str) {
    let Request::SetCommand(
        Command::Velocity { .. } | Command::Position { .. } | Command::Impedance(_),
    ) = req
    else {
        return (l, "");
    };
    let Ok(j) = c.joint() else {
        return (l, " (rotor frame)");
    };
    let (g, z) = (j.gear_ratio, j.rotor_at_zero_rad);
    if g == 1.0 && z == 0.0 {
        return (l, "");
    }
    if g == 0.0 || !g.is_finite() {
        return (l, " (rotor frame)");
    }
    let a = (l.min_position_rad - z) / g;
    let b = (l.max_position_rad - z) / g;
    let out = Limits {
        max_velocity_rad_s: l.max_velocity_rad_s / g.abs(),
        min_position_rad: a.min(b),
        max_position_rad: a.max(b),
        max_kp_nm_per_rad: l.max_kp_nm_per_rad * g * g,
        max_kd_nm_s_per_rad: l.max_kd_nm_s_per_rad * g * g,
        ..l
    };
    (out, " (output frame, through the joint)")
}

/// The writable parameters' names, comma-separated.
fn writable_names() -> String {
    let names: Vec<&str> = ParamId::ALL
        .iter()
        .filter(|p| p.is_writable())
        .map(|p| p.name())
        .collect();
    names.join(", ")
}

/// `text` as a value of writable parameter `id`: a number (`nan` and `inf`
/// included: the device says what it takes), or for a switch also
/// `on`/`off`, `true`/`false`.
pub fn param_value(id: ParamId, text: &str) -> Result<f32, String> {
    let t = text.trim();
    if id.is_switch() {
        match t {
            "on" | "true" => return Ok(1.0),
            "off" | "false" => return Ok(0.0),
            _ => {}
        }
    }
    t.parse::<f32>().map_err(|_| {
        if id.is_switch() {
            format!("`{t}` is not on, off, 1 or 0")
        } else {
            format!("`{t}` is not a number")
        }
    })
}

/// Why the drive refused a d-current reference parameter its values pass
/// (`Unsupported`: the drive's rule, `foc_core::drive::check_field`), in
/// words, from what it reports.
fn field_param_refusal(c: &mut Client, id: ParamId, value: f32) -> String {
    let fw_on = c.param(ParamId::FieldWeakening).ok() == Some(1.0);
    let max_id = c.param(ParamId::MaxIdA).ok();
    match id {
        ParamId::FieldWeakening if value == 1.0 && max_id == Some(0.0) => {
            "`field-weakening` = 1 is refused: field weakening needs `max-id` above 0 \
             (set it first); nothing changed"
                .into()
        }
        ParamId::FieldWeakening if value == 1.0 => format!(
            "`field-weakening` = 1 is refused: {COARSE_FIELD_WEAKENING} (or the configuration's \
             `field.bandwidth_rad_s` is 0 or its `field.voltage_margin` below {MIN_VOLTAGE_MARGIN}); \
             nothing changed"
        ),
        ParamId::MaxIdA if value == 0.0 && fw_on => {
            "`max-id` = 0 A is refused while field weakening is on (it needs a current): \
             switch `field-weakening` off first; nothing changed"
                .into()
        }
        _ => format!(
            "`{}` = {value} is refused by the drive ({}); nothing changed",
            id.name(),
            crate::describe_error(ErrorCode::Unsupported)
        ),
    }
}

/// Why the drive refused a table's switch or a sweep calibration (design
/// §32, §33) with `code`, in words (`None`: not one of them, or a code
/// the generic words cover).
fn table_refusal(req: &Request, code: ErrorCode) -> Option<String> {
    use Calibration::{Anticogging, EncoderLinearisation};
    Some(match (req, code) {
        (
            Request::SetParam {
                id: ParamId::Anticogging,
                ..
            },
            ErrorCode::NotCalibrated,
        ) => "`anticogging` = 1 is refused: the drive holds no anticogging map; measure one \
             with `foc-ctl calibrate cogging` (or load a configuration that has one); \
             nothing changed"
            .into(),
        (
            Request::SetParam {
                id: ParamId::EncoderLinearisation,
                ..
            },
            ErrorCode::NotCalibrated,
        ) => "`encoder-linearisation` = 1 is refused: the drive holds no angle correction; \
              learn one with `foc-ctl calibrate encoder` (or load a configuration that has \
              one); nothing changed"
            .into(),
        (Request::SetParam { id, .. }, ErrorCode::NotDisabled)
            if matches!(id, ParamId::Anticogging | ParamId::EncoderLinearisation) =>
        {
            format!(
                "`{}` is written only while the drive is disabled (a command is in force \
                 or waiting): `foc-ctl mode disable` first; nothing changed",
                id.name()
            )
        }
        (
            Request::RunCalibration(r @ (Anticogging | EncoderLinearisation)),
            ErrorCode::NotCalibrated,
        ) => {
            format!(
                "{} runs on the closed loop and the drive is not calibrated: run `foc-ctl \
                 identify` first (or load a calibrated configuration); nothing changed",
                sweep_name(*r)
            )
        }
        (Request::RunCalibration(Anticogging), ErrorCode::Unsupported) => {
            "the anticogging calibration needs the rotor's angle at low speed: refused on \
             halls (their half-count uncertainty, 30 deg electrical, is as wide as a cogging \
             cycle) and sensorless without injection; nothing changed"
                .into()
        }
        (Request::RunCalibration(EncoderLinearisation), ErrorCode::Unsupported) => {
            "encoder linearisation learns the angle sensor's own error, so it needs a fine \
             sensor that is read: refused on halls (interpolated between their edges) and \
             while the drive runs sensorless; nothing changed"
                .into()
        }
        _ => return None,
    })
}

/// A sweep calibration's name, for people.
fn sweep_name(r: Calibration) -> &'static str {
    match r {
        Calibration::Anticogging => "the anticogging calibration",
        Calibration::EncoderLinearisation => "encoder linearisation",
        Calibration::Offsets | Calibration::Identification | Calibration::Alignment => {
            "the calibration"
        }
    }
}

/// Why a record that passed the host's checks may still be refused
/// (`BadRecord`) by a drive: field weakening on a coarse angle sensor, the
/// drive's rule (`None` when the record does not turn it on).
pub fn record_refusal_hint(r: &foc_store::DriveRecord) -> Option<String> {
    r.field.filter(|f| f.field_weakening).map(|_| {
        format!(
            "the record turns field weakening on (`field.field_weakening`), which the drive \
             refuses on a coarse angle sensor: {COARSE_FIELD_WEAKENING}"
        )
    })
}

/// The limits in force, as the device reports them (`None` from a device
/// that does not).
pub fn limits_in_force(c: &mut Client) -> Option<Limits> {
    let mut p = |id| c.param(id).ok();
    Some(Limits {
        max_current_a: p(ParamId::MaxCurrentA)?,
        max_velocity_rad_s: p(ParamId::MaxVelocityRadS)?,
        min_position_rad: p(ParamId::MinPositionRad)?,
        max_position_rad: p(ParamId::MaxPositionRad)?,
        max_open_loop_voltage_v: p(ParamId::MaxOpenLoopVoltageV)?,
        max_open_loop_omega_e_rad_s: p(ParamId::MaxOpenLoopOmegaERadS)?,
        max_kp_nm_per_rad: p(ParamId::MaxImpedanceKp)?,
        max_kd_nm_s_per_rad: p(ParamId::MaxImpedanceKd)?,
    })
}

/// `e`, an error of `req`, in words: for a Nack the field, the value sent
/// and the range allowed (asked of the device: its limits in force and
/// hardware limit), and that nothing changed.
pub fn explain(c: &mut Client, req: &Request, e: &ClientError) -> String {
    match e {
        ClientError::Nack(code) => {
            format!("refused by the device: {}", nack_explained(c, req, *code))
        }
        other => other.to_string(),
    }
}

/// The Nack `code` of `req` in words (see [`explain`]).
pub fn nack_explained(c: &mut Client, req: &Request, code: ErrorCode) -> String {
    let board_max_a = c.param(ParamId::BoardMaxCurrentA).ok();
    if let Some(text) = table_refusal(req, code) {
        return text;
    }
    match (req, code) {
        (Request::SetLimits(l), ErrorCode::Unsupported) => match board_max_a {
            Some(m) if l.max_current_a > m => format!(
                "`max_current_a` = {} A is above this board's hardware limit of {m} A; nothing changed",
                l.max_current_a
            ),
            _ => match c.param(ParamId::AnticoggingPeakA).ok() {
                Some(p) if l.max_current_a < p => format!(
                    "`max_current_a` = {} A is below the anticogging map's peak of {p} A (the \
                     configuration, which keeps the map, could not be saved): keep a higher \
                     limit, or drop the map first (`foc-ctl config export`, remove its \
                     `[cogging]` table, `config import`); nothing changed",
                    l.max_current_a
                ),
                _ => format!("{}; nothing changed", crate::describe_error(code)),
            },
        },
        (Request::SetParam { id, value }, ErrorCode::Unsupported) if id.is_writable() => {
            field_param_refusal(c, *id, *value)
        }
        (_, ErrorCode::OutOfRange { field }) => {
            let Some(name) = req.field_name(field) else {
                return nack_text(req, code);
            };
            // A parameter's value is named by the parameter.
            let name = match req {
                Request::SetParam { id, .. } if field == 1 => id.name(),
                _ => name,
            };
            let value = field_value(req, field)
                .map(|(v, u)| format!(" = {v}{}{u}", if u.is_empty() { "" } else { " " }))
                .unwrap_or_default();
            let range = limits_in_force(c)
                .map(|l| in_command_frame(c, req, l))
                .and_then(|(l, frame)| {
                    allowed_range(req, field, &l, board_max_a).map(|r| format!("{r}{frame}"))
                })
                .map(|r| format!(" is out of range (allowed: {r})"))
                .unwrap_or_else(|| " is invalid or out of range".into());
            format!("`{name}`{value}{range}; nothing changed")
        }
        _ => nack_text(req, code),
    }
}
