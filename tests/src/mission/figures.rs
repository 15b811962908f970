//! Figures from a segment of the trace (settling times, overshoot,
//! errors) and the small helpers they share.

use super::*;

pub(super) fn secs(setup: &Setup, s: f64) -> usize {
    (s * setup.bench.pwm_frequency_hz as f64).round().max(1.0) as usize
}

pub(super) fn col<'a>(t: &'a Trace, name: &str) -> &'a [f64] {
    t.column(name).unwrap_or(&[])
}

pub(super) fn mean(x: &[f64]) -> f64 {
    if x.is_empty() {
        f64::NAN
    } else {
        x.iter().sum::<f64>() / x.len() as f64
    }
}

/// Largest |speed estimate - true speed| [rad/s] in step `seg` to `step`
/// [rad/s] from rest, while the true speed is below 90 % of the step (the
/// acceleration).
pub(super) fn estimate_error_accelerating(trace: &Trace, seg: &Segment, step: f64) -> f64 {
    let w = &col(trace, "speed_rad_s")[seg.start..seg.end];
    let est = &col(trace, "speed_est_rad_s")[seg.start..seg.end];
    let end = w
        .iter()
        .position(|v| v.abs() >= 0.9 * step.abs())
        .unwrap_or(w.len());
    w[..end]
        .iter()
        .zip(&est[..end])
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()))
}

/// `n` PWM periods of `ts` seconds \[ms\].
pub(super) fn ms(n: usize, ts: f64) -> f64 {
    n as f64 * ts * 1e3
}

/// Current step `cs` of `i_step` \[A\]: (figures of the magnitude?, overshoot
/// [%], 2 % settling \[periods\], d-current peak \[A\]).
pub(super) fn current_step_figures(
    setup: &Setup,
    trace: &Trace,
    cs: &Segment,
    i_step: f64,
) -> (bool, f64, Option<usize>, f64) {
    // The true current (a current probe on the bench), at the sample instants.
    // With a hall-class sensor the controller's angle is only known to
    // +-half a count (+-30 deg(e) on the hub motor) at the locked position,
    // so the true current's q share says more about the sensor than about
    // the loop: there the true current's magnitude is measured.
    let current_step_magnitude = identify::hall_class(setup);
    let iq_mag: Vec<f64>;
    let iq = if current_step_magnitude {
        let (q, d) = (col(trace, "iq_true_a"), col(trace, "id_true_a"));
        iq_mag = (cs.start..cs.end).map(|k| q[k].hypot(d[k])).collect();
        &iq_mag[..]
    } else {
        &col(trace, "iq_true_a")[cs.start..cs.end]
    };
    let id = &col(trace, "id_a")[cs.start..cs.end];
    (
        current_step_magnitude,
        metrics::overshoot_percent(iq, 0.0, i_step),
        metrics::settling_index(iq, 0.0, i_step, 0.02),
        id.iter().fold(0.0f64, |m, v| m.max(v.abs())),
    )
}

/// Speed step `ss` to `w1` [rad/s]: (overshoot [%], 2 % settling \[ms\]).
pub(super) fn speed_step_figures(
    trace: &Trace,
    ss: &Segment,
    w1: f64,
    ts: f64,
) -> (f64, Option<f64>) {
    let w = &col(trace, "speed_rad_s")[ss.start..ss.end];
    (
        metrics::overshoot_percent(w, 0.0, w1),
        metrics::settling_index(w, 0.0, w1, 0.02).map(|n| ms(n, ts)),
    )
}

/// Load step `ls` at `w2d` [rad/s]: (largest dip [rad/s], steady error
/// [rad/s], recovery into +-2 % \[ms\]).
pub(super) fn load_step_figures(
    setup: &Setup,
    trace: &Trace,
    ls: &Segment,
    w2d: f64,
    ts: f64,
) -> (f64, f64, Option<f64>) {
    let w = &col(trace, "speed_rad_s")[ls.start..ls.end];
    let load_dip_rad_s = w.iter().fold(0.0f64, |m, v| m.max(w2d - v));
    let tail = secs(setup, 0.1).min(w.len());
    let load_steady_error_rad_s = w2d - mean(&w[w.len() - tail..]);
    let load_recovery_ms = {
        let tol = 0.02 * w2d.abs();
        let last_out = w.iter().rposition(|v| (v - w2d).abs() > tol);
        match last_out {
            None => Some(0.0),
            Some(i) if i + 1 < w.len() => Some(ms(i + 1, ts)),
            Some(_) => None,
        }
    };
    (load_dip_rad_s, load_steady_error_rad_s, load_recovery_ms)
}

/// Position move `ps` of `move_d` \[rad\] from the true position `p0_true`:
/// (2 % settling \[ms\], final error \[rad\]).
pub(super) fn position_figures(
    setup: &Setup,
    trace: &Trace,
    ps: &Segment,
    p0_true: f64,
    move_d: f64,
    ts: f64,
) -> (Option<f64>, f64) {
    let pos = &col(trace, "position_rad")[ps.start..ps.end];
    let disp: Vec<f64> = pos.iter().map(|p| p - p0_true).collect();
    let position_settling_ms = metrics::settling_index(&disp, 0.0, move_d, 0.02).map(|n| ms(n, ts));
    let tail = secs(setup, 0.05).min(disp.len());
    let position_final_error_rad = move_d - mean(&disp[disp.len() - tail..]);
    (position_settling_ms, position_final_error_rad)
}

/// The faults latched during the mission (names, first occurrence order),
/// plus a note when position mode was never active.
pub(super) fn mission_faults(trace: &Trace) -> Vec<String> {
    let mut faults: Vec<String> = Vec::new();
    for &c in col(trace, "fault") {
        if c > 0.0 {
            if let Some(f) = foc_core::control::Fault::from_code(c as u8) {
                let n = f.name().to_string();
                if !faults.contains(&n) {
                    faults.push(n);
                }
            }
        }
    }
    let modes_ok = col(trace, "mode").contains(&(Mode::Position as u8 as f64));
    if !modes_ok {
        faults.push("position mode never active".into());
    }
    faults
}
