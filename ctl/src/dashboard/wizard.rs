//! The setup wizard's steps that need more than one request: the sensor
//! check (a slow open-loop turn, the sensor watched) and the tuning report
//! (a current step).

use foc_core::angle::ElectricalAngle;
use foc_core::control::{Command, Mode};
use foc_ctl::tune::{self, Loop};
use foc_ctl::{Client, ClientError};
use foc_protocol::message::ParamId;
use serde_json::{json, Value};
use std::f32::consts::TAU;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Electrical speed of the sensor check's field [rad/s] (one electrical
/// turn a second).
const CHECK_OMEGA_E: f32 = TAU;
/// The rotor settles onto the field for this long before it is watched.
const SETTLE: Duration = Duration::from_millis(600);
/// It is watched for this long.
const WATCH: Duration = Duration::from_secs(2);

/// The sensor check: a field turned slowly in open loop at a third of the
/// current limit (at most the open-loop voltage limit); the rotor follows
/// it, and the sensor must see the travel the field made, the right way.
pub(super) fn sensor_check(c: &mut Client, abort: &AtomicBool) -> Value {
    match check(c, abort) {
        Ok(v) => v,
        Err(e) => {
            let _ = c.set_command(Command::Disable);
            json!({"ok": false, "pass": false, "text": e.to_string()})
        }
    }
}

fn check(c: &mut Client, abort: &AtomicBool) -> Result<Value, ClientError> {
    if c.param(ParamId::AngleSource)? == 1.0 {
        return Ok(json!({"ok": true, "pass": true, "skipped": true,
            "text": "the drive runs without an angle sensor: nothing to check"}));
    }
    let f = c.faults()?;
    if !f.set.is_empty() {
        return Ok(json!({"ok": false, "pass": false,
            "text": "a fault is latched: see the status, clear it first"}));
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
    let (pass, text) = if (0.85..=1.15).contains(&ratio) {
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
    Ok(
        json!({"ok": true, "pass": pass, "text": text, "voltage_v": v,
        "expected_rad": expected, "measured_rad": measured, "ratio": ratio}),
    )
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

/// The tuning report: a q-current step of a fifth of the current limit,
/// captured by the scope, its figures and the suggestions.
pub(super) fn tune_report(c: &mut Client) -> Value {
    let step = c
        .param(ParamId::MaxCurrentA)
        .map_or(1.0, |m| (0.2 * m).max(0.1));
    match tune::run(c, Loop::Current, step, Duration::from_secs(5)) {
        Ok(r) => json!({
            "ok": true,
            "report": r.to_string(),
            "overshoot_pct": r.figures.overshoot_pct,
            "rise_s": r.figures.rise_s,
            "bandwidth_hz": r.figures.bandwidth_hz,
        }),
        Err(e) => json!({"ok": false, "report": format!("the current step failed: {e}")}),
    }
}
