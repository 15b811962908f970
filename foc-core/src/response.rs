//! Step-response figures (design §22), pure functions on sampled traces:
//! what the bench's tests and the host tool's tuning report (`foc-ctl
//! tune`) both measure, so their figures mean the same.
//!
//! Times are in samples; multiply by the sample period for seconds. A step
//! goes from `initial` to `target` (either sign).
//!
//! ```
//! use foc_core::response;
//! let y = [0.0, 0.5, 0.9, 1.05, 1.01, 1.0, 1.0];
//! assert!((response::overshoot_percent(&y, 0.0, 1.0) - 5.0).abs() < 1e-9);
//! assert_eq!(response::settling_index(&y, 0.0, 1.0, 0.02), Some(4));
//! ```

/// `ln 9`.
const LN_9: f64 = 2.197_224_577_336_219_6;

/// Overshoot past `target` in percent of the step `target - initial`
/// (0 when the response never passes the target; NaN for a zero step).
pub fn overshoot_percent(y: &[f64], initial: f64, target: f64) -> f64 {
    let step = target - initial;
    if step == 0.0 {
        return f64::NAN;
    }
    let peak = y.iter().map(|v| (v - target) / step).fold(0.0f64, f64::max);
    100.0 * peak
}

/// First sample index from which `y` stays within `band` (fraction of the
/// step, 0.02 for the 2 % criterion) of `target` until the end; `None` if it
/// does not settle.
pub fn settling_index(y: &[f64], initial: f64, target: f64, band: f64) -> Option<usize> {
    let tol = band * (target - initial).abs();
    let last_out = y.iter().rposition(|v| (v - target).abs() > tol);
    match last_out {
        None => Some(0),
        Some(i) if i + 1 < y.len() => Some(i + 1),
        Some(_) => None,
    }
}

/// Rise time in samples from `lo` to `hi` (fractions of the step, e.g. 0.1
/// and 0.9), linearly interpolated between samples; `None` if not reached.
pub fn rise_time(y: &[f64], initial: f64, target: f64, lo: f64, hi: f64) -> Option<f64> {
    let step = target - initial;
    if step == 0.0 {
        return None;
    }
    let crossing = |frac: f64| -> Option<f64> {
        let level = frac;
        let mut prev = 0.0;
        for (i, v) in y.iter().enumerate() {
            let x = (v - initial) / step;
            if x >= level {
                if i == 0 {
                    return Some(0.0);
                }
                return Some(i as f64 - 1.0 + (level - prev) / (x - prev));
            }
            prev = x;
        }
        None
    };
    Some(crossing(hi)? - crossing(lo)?)
}

/// Bandwidth \[Hz\] a 10-90 % rise time of `rise_s` \[s\] implies for a
/// first-order response (`0.35 / t_r`: `t_r = ln 9 tau`, `f = 1 / (2 pi tau)`).
pub fn bandwidth_hz_from_rise(rise_s: f64) -> Option<f64> {
    (rise_s > 0.0 && rise_s.is_finite()).then(|| LN_9 / (2.0 * core::f64::consts::PI * rise_s))
}
