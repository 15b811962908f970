//! Current-sensor offset calibration (bridge off, no current flows).
//!
//! Averages `samples` readings per phase (taken with the offsets set to zero)
//! and accepts the result only when each offset is within `max_offset_a` of
//! zero (i.e. the amplifier sits near mid-scale) and the noise (standard
//! deviation) stays below `max_noise_a`.
//!
//! Unusable limits (no samples, or a limit that is not a finite positive
//! number) fail at the first step with [`OffsetError::InvalidLimits`]; a
//! non-finite reading fails with [`OffsetError::InvalidReading`]. `Done`
//! only ever carries finite offsets, each within `max_offset_a`.
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
    /// Samples to average (e.g. 1024 PWM periods); at least 1.
    pub samples: u32,
    /// Largest acceptable offset \[A\] per phase (finite, `> 0`).
    pub max_offset_a: f32,
    /// Largest acceptable standard deviation \[A\] per phase (finite, `> 0`).
    pub max_noise_a: f32,
}

impl OffsetLimits {
    /// True when the limits can be used: `samples >= 1` and both limits
    /// finite and `> 0` (NaN, infinite, zero or negative limits could let
    /// any offset through, or none).
    pub const fn is_valid(&self) -> bool {
        self.samples > 0 && positive_finite(self.max_offset_a) && positive_finite(self.max_noise_a)
    }
}

/// `0 < x < inf` (false for NaN).
const fn positive_finite(x: f32) -> bool {
    x.is_finite() && x > 0.0
}

/// Why the offset calibration failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum OffsetError {
    /// An offset is too far from mid-scale (phase index 0..3).
    OffsetTooLarge(u8),
    /// A phase is too noisy (phase index 0..3).
    TooNoisy(u8),
    /// A reading was not finite (or the readings' sum overflowed).
    InvalidReading,
    /// The limits are unusable (see [`OffsetLimits::is_valid`]).
    InvalidLimits,
}

/// Progress of the calibration.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum OffsetStep {
    /// More samples needed.
    InProgress,
    /// Offsets \[A\] to pass to `CurrentSense::set_offsets_a` (always
    /// finite, each within `max_offset_a`).
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

    /// Feed one reading \[A\] (taken with zero offsets, bridge off). Once
    /// done or failed, the same result is returned for every later call.
    pub fn step(&mut self, reading: Abc) -> OffsetStep {
        if let Some(d) = self.done {
            return d;
        }
        let error = if !self.limits.is_valid() {
            Some(OffsetError::InvalidLimits)
        } else if !reading.is_finite() {
            Some(OffsetError::InvalidReading)
        } else {
            None
        };
        if let Some(e) = error {
            let f = OffsetStep::Failed(e);
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
                if !m.is_finite() {
                    // The sum overflowed (readings near f32::MAX).
                    result = Some(OffsetError::InvalidReading);
                } else if m.abs() > self.limits.max_offset_a {
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

    /// Unusable limits fail at the first step, whatever the readings, and
    /// the failure sticks.
    #[test]
    fn unusable_limits_fail_cleanly() {
        let bad = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 0.0, -0.0, -0.5];
        let cases = bad.iter().flat_map(|&x| {
            [
                OffsetLimits {
                    samples: 0,
                    ..lim()
                },
                OffsetLimits {
                    max_offset_a: x,
                    ..lim()
                },
                OffsetLimits {
                    max_noise_a: x,
                    ..lim()
                },
                OffsetLimits {
                    samples: 0,
                    max_offset_a: x,
                    max_noise_a: x,
                },
            ]
        });
        for l in cases {
            assert!(!l.is_valid(), "{l:?}");
            for reading in [
                Abc::new(0.1, -0.05, 0.02),
                Abc::new(1e38, 1e38, 1e38),
                Abc::new(f32::NAN, 0.0, 0.0),
            ] {
                let mut cal = OffsetCalibrator::new(l);
                let failed = OffsetStep::Failed(OffsetError::InvalidLimits);
                assert_eq!(cal.step(reading), failed, "{l:?} {reading:?}");
                assert_eq!(cal.step(Abc::new(0.0, 0.0, 0.0)), failed);
            }
        }
        assert!(lim().is_valid());
    }

    /// Finite readings whose sum overflows never give infinite offsets,
    /// even with the largest finite limits.
    #[test]
    fn never_done_with_non_finite_offsets() {
        let wide = OffsetLimits {
            samples: 8,
            max_offset_a: f32::MAX,
            max_noise_a: f32::MAX,
        };
        for x in [f32::MAX, -f32::MAX, 3e38, 1e38] {
            let mut cal = OffsetCalibrator::new(wide);
            let r = run(&mut cal, |_| Abc::new(0.0, x, 0.0));
            match r {
                OffsetStep::Done(o) => assert!(o.is_finite(), "{x}: {o:?}"),
                OffsetStep::Failed(_) => {}
                OffsetStep::InProgress => panic!("{x}: not finished"),
            }
        }
        // Sums that overflow: rejected as invalid readings.
        let mut cal = OffsetCalibrator::new(wide);
        assert_eq!(
            run(&mut cal, |_| Abc::new(0.0, f32::MAX, 0.0)),
            OffsetStep::Failed(OffsetError::InvalidReading)
        );
        // One sample is enough with valid limits.
        let mut cal = OffsetCalibrator::new(OffsetLimits {
            samples: 1,
            ..lim()
        });
        assert_eq!(
            cal.step(Abc::new(0.1, 0.2, 0.3)),
            OffsetStep::Done(Abc::new(0.1, 0.2, 0.3))
        );
    }
}
