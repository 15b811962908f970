//! Step-response and tracking metrics, pure functions on sampled traces.
//!
//! Times are in samples (one sample per control period); multiply by the
//! period for seconds. A step goes from `initial` to `target` (either sign).
//!
//! ```
//! use foc_bench::metrics;
//! let y = [0.0, 0.5, 0.9, 1.05, 1.01, 1.0, 1.0];
//! assert!((metrics::overshoot_percent(&y, 0.0, 1.0) - 5.0).abs() < 1e-9);
//! assert_eq!(metrics::settling_index(&y, 0.0, 1.0, 0.02), Some(4));
//! ```

pub use foc_core::response::{overshoot_percent, rise_time, settling_index};

/// Steady-state error `target - mean(last n samples)` (error = setpoint -
/// measurement). NaN for an empty trace.
pub fn steady_state_error(y: &[f64], target: f64, last_n: usize) -> f64 {
    let n = last_n.min(y.len());
    if n == 0 {
        return f64::NAN;
    }
    let tail = &y[y.len() - n..];
    target - tail.iter().sum::<f64>() / n as f64
}

/// RMS of `reference - y` over the common length. NaN when empty.
pub fn rms_error(reference: &[f64], y: &[f64]) -> f64 {
    let n = reference.len().min(y.len());
    if n == 0 {
        return f64::NAN;
    }
    let s: f64 = reference
        .iter()
        .zip(y)
        .map(|(r, v)| (r - v) * (r - v))
        .sum();
    (s / n as f64).sqrt()
}

/// Least squares `y = a + b x1 + c x2` -> `(b, c)`.
pub fn fit_two(x1: &[f64], x2: &[f64], y: &[f64]) -> (f64, f64) {
    let n = y.len() as f64;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / n;
    let (m1, m2, my) = (mean(x1), mean(x2), mean(y));
    let (mut s11, mut s22, mut s12, mut s1y, mut s2y) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for ((a, b), c) in x1.iter().zip(x2).zip(y) {
        let (a, b, c) = (a - m1, b - m2, c - my);
        s11 += a * a;
        s22 += b * b;
        s12 += a * b;
        s1y += a * c;
        s2y += b * c;
    }
    let det = s11 * s22 - s12 * s12;
    ((s1y * s22 - s2y * s12) / det, (s2y * s11 - s1y * s12) / det)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Second-order step response with damping `z`, natural frequency `wn` [rad/sample].
    fn second_order(z: f64, wn: f64, n: usize) -> Vec<f64> {
        let wd = wn * (1.0 - z * z).sqrt();
        let phi = (z / (1.0 - z * z).sqrt()).atan();
        (0..n)
            .map(|k| {
                let t = k as f64;
                1.0 - (-z * wn * t).exp() * (wd * t).cos()
                    - (-z * wn * t).exp() * phi.tan() * (wd * t).sin()
            })
            .collect()
    }

    #[test]
    fn second_order_matches_textbook() {
        // z = 1/sqrt2 (technical optimum): overshoot exp(-pi z / sqrt(1 - z^2)) = 4.32 %.
        let z = std::f64::consts::FRAC_1_SQRT_2;
        let wn = 0.05;
        let y = second_order(z, wn, 4000);
        let os = overshoot_percent(&y, 0.0, 1.0);
        let expected = 100.0 * (-std::f64::consts::PI * z / (1.0 - z * z).sqrt()).exp();
        assert!((os - expected).abs() < 0.01, "{os} vs {expected}");
        // 2 % settling of the envelope: about 4 / (z wn) samples (within 25 %).
        let ts = settling_index(&y, 0.0, 1.0, 0.02).unwrap() as f64;
        let approx = 4.0 / (z * wn);
        assert!((ts - approx).abs() < 0.25 * approx, "{ts} vs {approx}");
        // Same for a negative step.
        let yn: Vec<f64> = y.iter().map(|v| 2.0 - 2.0 * v).collect();
        assert!((overshoot_percent(&yn, 2.0, 0.0) - expected).abs() < 0.01);
    }

    #[test]
    fn first_order_rise_time() {
        // 10-90 % rise time of 1 - exp(-t/tau) is tau ln 9.
        let tau = 50.0;
        let y: Vec<f64> = (0..1000).map(|k| 1.0 - (-(k as f64) / tau).exp()).collect();
        let tr = rise_time(&y, 0.0, 1.0, 0.1, 0.9).unwrap();
        assert!((tr - tau * 9f64.ln()).abs() < 0.5, "{tr}");
        assert_eq!(overshoot_percent(&y, 0.0, 1.0), 0.0);
        assert!(rise_time(&y[..10], 0.0, 1.0, 0.1, 0.9).is_none());
    }

    #[test]
    fn settling_needs_to_stay_inside() {
        let y = [0.0, 1.0, 1.0, 1.5, 1.0, 1.0];
        assert_eq!(settling_index(&y, 0.0, 1.0, 0.02), Some(4));
        assert_eq!(settling_index(&[0.0, 0.5], 0.0, 1.0, 0.02), None);
    }

    #[test]
    fn errors() {
        let y = [0.0, 0.9, 0.9, 0.9];
        assert!((steady_state_error(&y, 1.0, 3) - 0.1).abs() < 1e-12);
        assert!((rms_error(&[1.0, 1.0], &[0.0, 2.0]) - 1.0).abs() < 1e-12);
        assert!(rms_error(&[], &[]).is_nan());
    }

    #[test]
    fn fit_two_recovers_a_plane() {
        let x1: Vec<f64> = (0..50).map(|k| (k as f64 * 0.3).sin()).collect();
        let x2: Vec<f64> = (0..50).map(|k| (k as f64 * 0.3).cos()).collect();
        let y: Vec<f64> = x1
            .iter()
            .zip(&x2)
            .map(|(a, b)| 2.0 - 3.0 * a + 0.5 * b)
            .collect();
        let (b, c) = fit_two(&x1, &x2, &y);
        assert!((b + 3.0).abs() < 1e-9 && (c - 0.5).abs() < 1e-9, "{b} {c}");
    }
}
