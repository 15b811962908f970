//! The setup wizard's steps that need more than one request: the sensor
//! check ([`foc_ctl::sensor_check`]) and the tuning report (a current
//! step).

use foc_ctl::sensor_check;
use foc_ctl::tune::{self, Loop};
use foc_ctl::Client;
use foc_protocol::message::ParamId;
use serde_json::{json, Value};
use std::sync::atomic::AtomicBool;
use std::time::Duration;

/// The sensor check as the page shows it.
pub(super) fn sensor_check(c: &mut Client, abort: &AtomicBool) -> Value {
    match sensor_check::run(c, abort) {
        Ok(r) => json!({"ok": true, "pass": r.pass, "skipped": r.skipped, "text": r.text,
            "voltage_v": r.voltage_v, "expected_rad": r.expected_rad, "measured_rad": r.measured_rad}),
        Err(e) => json!({"ok": false, "pass": false, "text": e.to_string()}),
    }
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
