//! The sensor check of the setup wizard: a field turned slowly in open
//! loop (one electrical turn a second) at a third of the current limit
//! (between 5 % and half of the open-loop voltage limit); the rotor follows
//! it, and the angle sensor must see the travel the field made, the right
//! way, within 15 %. It needs no calibration (open loop), and it tells a
//! reversed sensor, a sensor that sees nothing and a wrong pole-pair count
//! apart.

use crate::{Client, ClientError};
use foc_core::angle::ElectricalAngle;
use foc_core::control::{Command, Mode};
use foc_protocol::message::ParamId;
use std::f32::consts::TAU;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Electrical speed of the check's field [rad/s] (one electrical turn a
/// second).
pub const CHECK_OMEGA_E: f32 = TAU;
/// The rotor settles onto the field for this long before it is watched.
const SETTLE: Duration = Duration::from_millis(600);
/// It is watched for this long.
const WATCH: Duration = Duration::from_secs(2);

/// What the check found.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorCheck {
    /// The sensor saw the field's travel, the right way.
    pub pass: bool,
    /// The drive runs without an angle sensor: nothing was checked.
    pub skipped: bool,
    /// For people: what was seen, and what to do when it failed.
    pub text: String,
    /// The field's voltage \[V\].
    pub voltage_v: f32,
    /// The field's travel over the watch [rad, output].
    pub expected_rad: f32,
    /// The sensor's [rad, output].
    pub measured_rad: f32,
}

/// Run the check (the bridge off at its end, also on an error or when
/// `abort` is set).
pub fn run(c: &mut Client, abort: &AtomicBool) -> Result<SensorCheck, ClientError> {
    let r = check(c, abort);
    if r.is_err() {
        let _ = c.set_command(Command::Disable);
    }
    r
}

fn check(c: &mut Client, abort: &AtomicBool) -> Result<SensorCheck, ClientError> {
    let mut out = SensorCheck {
        pass: true,
        skipped: true,
        text: "the drive runs without an angle sensor: nothing to check".into(),
        voltage_v: 0.0,
        expected_rad: 0.0,
        measured_rad: 0.0,
    };
    if c.param(ParamId::AngleSource)? == 1.0 {
        return Ok(out);
    }
    out.skipped = false;
    if !c.faults()?.set.is_empty() {
        out.pass = false;
        out.text = "a fault is latched: see the status, clear it first".into();
        return Ok(out);
    }
    let pp = c.param(ParamId::PolePairs)?.max(1.0);
    let r = c.param(ParamId::ResistanceOhm)?;
    let i_max = c.param(ParamId::MaxCurrentA)?;
    let v_max = c.param(ParamId::MaxOpenLoopVoltageV)?;
    let gear = c.joint()?.gear_ratio;
    let v = (r * i_max / 3.0).clamp(0.05 * v_max, 0.5 * v_max);
    let cmd = Command::OpenLoop {
        v_d_v: v,
        v_q_v: 0.0,
        theta_e: ElectricalAngle::from_radians(0.0),
        omega_e_rad_s: CHECK_OMEGA_E,
    };
    let pwm_hz = c.param(ParamId::PwmFrequencyHz)?;
    c.set_command(cmd)?;
    let (p1, k1) = hold(c, SETTLE, abort)?;
    let (p2, k2) = hold(c, WATCH, abort)?;
    c.set_command(Command::Disable)?;
    // The field's travel over the drive's own time (its period counter: a
    // simulated drive may run faster than real time); telemetry's position
    // is the output's, the rotor's over the gear ratio.
    let dt_s = k2.wrapping_sub(k1) as f32 / pwm_hz;
    let expected = CHECK_OMEGA_E / pp * dt_s / gear;
    let measured = p2 - p1;
    let ratio = measured / expected;
    out.voltage_v = v;
    out.expected_rad = expected;
    out.measured_rad = measured;
    (out.pass, out.text) = if (0.85..=1.15).contains(&ratio) {
        (true, format!(
            "the sensor follows the field: {measured:.3} rad for {expected:.3} rad expected ({:.0} %), the right way",
            ratio * 100.0
        ))
    } else if (-1.15..=-0.85).contains(&ratio) {
        (
            false,
            "the sensor counts the other way: swap two motor phases or set the sensor's direction"
                .to_string(),
        )
    } else if ratio.abs() < 0.1 {
        (false, format!(
            "the sensor saw no motion ({measured:.4} rad): its wiring, supply or magnet, or the rotor is blocked"
        ))
    } else {
        (false, format!(
            "the sensor saw {measured:.3} rad for {expected:.3} rad expected ({:.0} %): check the pole pairs ({pp}) and the sensor's counts per turn",
            ratio * 100.0
        ))
    };
    Ok(out)
}

/// Keep the command alive for `d` (the link watchdog is armed): the
/// position and the period counter at the end.
fn hold(c: &mut Client, d: Duration, abort: &AtomicBool) -> Result<(f32, u32), ClientError> {
    let end = Instant::now() + d;
    while Instant::now() < end {
        if abort.load(Ordering::Relaxed) {
            return Err(ClientError::NotReady(
                "stopped by the page's Disable".into(),
            ));
        }
        c.keep_alive()?;
        std::thread::sleep(Duration::from_millis(50));
    }
    let t = c.read_telemetry()?;
    if t.mode != Mode::OpenLoop {
        return Err(ClientError::NotReady(format!(
            "the drive left open loop during the check (now {:?}, fault code {})",
            t.mode, t.fault_code
        )));
    }
    Ok((t.position_rad, t.period))
}
