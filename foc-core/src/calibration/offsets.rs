//! Current-sensor offset calibration (bridge off, no current flows).
//!
//! Averages `samples` readings per phase (taken with the offsets set to zero)
//! and accepts the result only when each offset is within `max_offset_a` of
//! zero (i.e. the amplifier sits near mid-scale) and the noise (standard
//! deviation) stays below `max_noise_a`.
//!
//! ```
//! use foc_core::calibration::offsets::{OffsetCalibrator, OffsetLimits, OffsetStep};
//! use foc_core::frames::Abc;
//! let mut cal = OffsetCalibrator::new(OffsetLimits { samples: 4, max_offset_a: 0.5, max_noise_a: 0.05 });
//! let mut last = OffsetStep::InProgress;
//! for _ in 0..4 { last = cal.step(Abc::new(0.1, -0.05, 0.02)); }
//! match last {
//!     OffsetStep::Done(o) => assert!((o.a - 0.1).abs() < 1e-6),
//!     _ => panic!("not done"),
//! }
//! ```

use crate::frames::Abc;
use crate::sqrtf;

/// Limits of the offset calibration.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct OffsetLimits {
    /// Samples to average (e.g. 1024 PWM periods).
    pub samples: u32,
    /// Largest acceptable offset [A] per phase.
    pub max_offset_a: f32,
    /// Largest acceptable standard deviation [A] per phase.
    pub max_noise_a: f32,
}

/// Why the offset calibration failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum OffsetError {
    /// An offset is too far from mid-scale (phase index 0..3).
    OffsetTooLarge(u8),
    /// A phase is too noisy (phase index 0..3).
    TooNoisy(u8),
    /// A reading was not finite, or the limits are unusable.
    InvalidReading,
}

/// Progress of the calibration.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum OffsetStep {
    /// More samples needed.
    InProgress,
    /// Offsets [A] to pass to `CurrentSense::set_offsets_a`.
    Done(Abc),
    /// Rejected.
    Failed(OffsetError),
}

/// The offset calibrator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OffsetCalibrator {
    limits: OffsetLimits,
    n: u32,
    sum: [f32; 3],
    sum_sq: [f32; 3],
    done: Option<OffsetStep>,
}

impl OffsetCalibrator {
    /// New calibrator.
    pub const fn new(limits: OffsetLimits) -> Self {
        Self {
            limits,
            n: 0,
            sum: [0.0; 3],
            sum_sq: [0.0; 3],
            done: None,
        }
    }

    /// Feed one reading [A] (taken with zero offsets, bridge off).
    pub fn step(&mut self, reading: Abc) -> OffsetStep {
        if let Some(d) = self.done {
            return d;
        }
        if !reading.is_finite() || self.limits.samples == 0 {
            let f = OffsetStep::Failed(OffsetError::InvalidReading);
            self.done = Some(f);
            return f;
        }
        for ((s, q), x) in self
            .sum
            .iter_mut()
            .zip(self.sum_sq.iter_mut())
            .zip(reading.to_array())
        {
            *s += x;
            *q += x * x;
        }
        self.n += 1;
        if self.n < self.limits.samples {
            return OffsetStep::InProgress;
        }
        let n = self.n as f32;
        let mut mean = [0.0f32; 3];
        let mut result = None;
        for (k, ((s, q), m)) in self
            .sum
            .iter()
            .zip(self.sum_sq.iter())
            .zip(mean.iter_mut())
            .enumerate()
        {
            *m = s / n;
            let var = q / n - *m * *m;
            let sd = if var > 0.0 { sqrtf(var) } else { 0.0 };
            if result.is_none() {
                if m.abs() > self.limits.max_offset_a {
                    result = Some(OffsetError::OffsetTooLarge(k as u8));
                } else if sd > self.limits.max_noise_a {
                    result = Some(OffsetError::TooNoisy(k as u8));
                }
            }
        }
        let out = match result {
            Some(e) => OffsetStep::Failed(e),
            None => {
                let [a, b, c] = mean;
                OffsetStep::Done(Abc::new(a, b, c))
            }
        };
        self.done = Some(out);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lim() -> OffsetLimits {
        OffsetLimits {
            samples: 1000,
            max_offset_a: 0.5,
            max_noise_a: 0.05,
        }
    }

    fn run(cal: &mut OffsetCalibrator, f: impl Fn(u32) -> Abc) -> OffsetStep {
        let mut last = OffsetStep::InProgress;
        for k in 0..2000 {
            last = cal.step(f(k));
            if last != OffsetStep::InProgress {
                break;
            }
        }
        last
    }

    #[test]
    fn averages_noisy_offsets() {
        let mut cal = OffsetCalibrator::new(lim());
        // +-0.02 A square-ish noise around (0.1, -0.2, 0.3).
        let r = run(&mut cal, |k| {
            let n = if k % 2 == 0 { 0.02 } else { -0.02 };
            Abc::new(0.1 + n, -0.2 - n, 0.3 + n)
        });
        let OffsetStep::Done(o) = r else {
            panic!("{r:?}")
        };
        assert!((o.a - 0.1).abs() < 1e-4 && (o.b + 0.2).abs() < 1e-4 && (o.c - 0.3).abs() < 1e-4);
    }

    #[test]
    fn rejects_far_from_mid_scale_and_noisy() {
        let mut cal = OffsetCalibrator::new(lim());
        assert_eq!(
            run(&mut cal, |_| Abc::new(0.0, 0.6, 0.0)),
            OffsetStep::Failed(OffsetError::OffsetTooLarge(1))
        );
        let mut cal = OffsetCalibrator::new(lim());
        let r = run(&mut cal, |k| {
            let n = if k % 2 == 0 { 0.2 } else { -0.2 };
            Abc::new(0.0, 0.0, n)
        });
        assert_eq!(r, OffsetStep::Failed(OffsetError::TooNoisy(2)));
        let mut cal = OffsetCalibrator::new(lim());
        assert_eq!(
            run(&mut cal, |_| Abc::new(f32::NAN, 0.0, 0.0)),
            OffsetStep::Failed(OffsetError::InvalidReading)
        );
    }
}
