//! Encoder linearisation: the angle sensor's own error over its turn,
//! taken off every reading before anything else uses it (design §33).
//!
//! A magnetic sensor over an off-centre magnet reads `theta + e(theta)`:
//! an error that repeats every mechanical turn, mostly its first harmonic
//! (the eccentricity) and second (the magnet's and the sensor's
//! non-uniformity), a few tenths of a degree on a well-mounted AS5047P,
//! several degrees on a poorly centred one; times the pole pairs in
//! electrical angle (6 deg(e) for 0.3 deg on a 21-pole-pair motor). The
//! speed estimate differentiates it into a speed ripple, the angle error
//! turns part of the q current into d current.
//!
//! The correction is a table of [`CORRECTION_BINS`] points over one turn
//! of the sensor's reading (not of the rotor: the error belongs to the
//! sensor's disc), linearly interpolated, subtracted from the reading:
//! `theta = reading - e(reading)`. Measured by
//! [`crate::calibration::encoder`].
//!
//! The table is referred to the reading, so it stays valid across power
//! cycles only where the reading's zero does: an absolute sensor, or an
//! incremental encoder referred to its index (design §33). Storage: `i16`
//! counts of `scale_rad` (512 bytes).

use crate::angle::MechanicalAngle;

/// Points of the table per turn of the reading.
pub const CORRECTION_BINS: usize = 256;

/// `log2(CORRECTION_BINS)`.
const BIN_BITS: u32 = 8;

/// Largest count of the table.
const FULL_COUNT: f32 = 32767.0;

/// Radians per full turn of a [`MechanicalAngle`]'s bits.
const RAD_PER_BIT: f32 = core::f32::consts::TAU / 4_294_967_296.0;

/// The sensor's error over its turn, to be taken off its reading.
/// `repr(C)`: the switch and the scale, read every period, before the
/// table.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct AngleCorrection {
    /// Apply the correction.
    pub enabled: bool,
    /// Radians per count of [`Self::table`] (finite, `>= 0`).
    pub scale_rad: f32,
    /// The error at reading `(k + 1/2) / CORRECTION_BINS` turns (its
    /// bin's centre), in counts of `scale_rad`.
    pub table: [i16; CORRECTION_BINS],
}

/// Why a correction was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AngleCorrectionError {
    /// The scale is negative or not finite.
    BadScale,
    /// A value given to [`AngleCorrection::from_rad`] is not finite.
    NotFinite,
    /// The error's peak is above [`MAX_CORRECTION_RAD`]: a sensor that
    /// far off is broken or loose, not to be corrected.
    TooLarge,
}

/// Largest error a table may correct \[rad\] (5 deg mechanical).
pub const MAX_CORRECTION_RAD: f32 = 0.087;

impl AngleCorrection {
    /// No correction: zero everywhere, off.
    pub const NONE: Self = Self {
        enabled: false,
        scale_rad: 0.0,
        table: [0; CORRECTION_BINS],
    };

    /// A table from radians per point (quantised to the peak over 32767),
    /// enabled.
    pub fn from_rad(rad: &[f32; CORRECTION_BINS]) -> Result<Self, AngleCorrectionError> {
        let mut peak = 0.0f32;
        for r in rad {
            if !r.is_finite() {
                return Err(AngleCorrectionError::NotFinite);
            }
            peak = peak.max(r.abs());
        }
        let scale_rad = peak / FULL_COUNT;
        let mut c = Self {
            enabled: true,
            scale_rad,
            table: [0; CORRECTION_BINS],
        };
        if scale_rad > 0.0 {
            for (t, r) in c.table.iter_mut().zip(rad) {
                let x = libm::roundf(r / scale_rad).clamp(-FULL_COUNT, FULL_COUNT);
                *t = x as i16;
            }
        }
        c.check()?;
        Ok(c)
    }

    /// An enabled table of zeros with the scale [`Self::from_rad`] picks
    /// for errors up to `peak_rad`: the start of a table filled a few
    /// points at a time with [`Self::set_rad`] where [`Self::from_rad`]'s
    /// whole table at once would take too long (in a control period).
    /// Refused as [`Self::from_rad`] would refuse a table with that peak.
    pub fn with_peak(peak_rad: f32) -> Result<Self, AngleCorrectionError> {
        if !peak_rad.is_finite() {
            return Err(AngleCorrectionError::NotFinite);
        }
        let scale_rad = peak_rad.abs() / FULL_COUNT;
        // What `peak_rad` of the table filled up to its peak will say.
        if FULL_COUNT * scale_rad > MAX_CORRECTION_RAD {
            return Err(AngleCorrectionError::TooLarge);
        }
        Ok(Self {
            enabled: true,
            scale_rad,
            table: [0; CORRECTION_BINS],
        })
    }

    /// Point `k`'s error \[rad\], quantised as [`Self::from_rad`] does
    /// (clamped to the scale's peak; `k` beyond the table: nothing).
    pub fn set_rad(&mut self, k: usize, rad: f32) -> Result<(), AngleCorrectionError> {
        if !rad.is_finite() {
            return Err(AngleCorrectionError::NotFinite);
        }
        if let Some(t) = self.table.get_mut(k) {
            *t = if self.scale_rad > 0.0 {
                libm::roundf(rad / self.scale_rad).clamp(-FULL_COUNT, FULL_COUNT) as i16
            } else {
                0
            };
        }
        Ok(())
    }

    /// The error at point `k` \[rad\] (`k` modulo the bins).
    pub fn rad_at(&self, k: usize) -> f32 {
        self.table.get(k % CORRECTION_BINS).copied().unwrap_or(0) as f32 * self.scale_rad
    }

    /// The table's largest magnitude \[rad\].
    pub fn peak_rad(&self) -> f32 {
        let c = self
            .table
            .iter()
            .map(|t| (*t as i32).unsigned_abs())
            .max()
            .unwrap_or(0);
        c as f32 * self.scale_rad
    }

    /// The largest error the table can hold at its scale \[rad\] (any
    /// count, `-32768` included): a bound on [`Self::peak_rad`] without
    /// its scan.
    pub fn bound_rad(&self) -> f32 {
        -(i16::MIN as f32) * self.scale_rad
    }

    /// The error of a full count \[rad\]: the peak of a table scaled to
    /// its peak ([`Self::from_rad`], [`Self::with_peak`]), without the
    /// scan of [`Self::peak_rad`].
    pub fn full_scale_rad(&self) -> f32 {
        FULL_COUNT * self.scale_rad
    }

    /// Check before installing: a usable scale, a peak within
    /// [`MAX_CORRECTION_RAD`].
    pub fn check(&self) -> Result<(), AngleCorrectionError> {
        if !(self.scale_rad.is_finite() && self.scale_rad >= 0.0) {
            return Err(AngleCorrectionError::BadScale);
        }
        // No count can exceed the scale's bound: within the limit, no scan
        // (the check runs in the interrupt when a linearisation ends).
        if self.bound_rad() <= MAX_CORRECTION_RAD {
            return Ok(());
        }
        if self.peak_rad() > MAX_CORRECTION_RAD {
            return Err(AngleCorrectionError::TooLarge);
        }
        Ok(())
    }

    /// The sensor's error at `reading` \[rad\], linear between the two
    /// nearest points' centres.
    #[inline(always)]
    pub fn error_rad(&self, reading: MechanicalAngle) -> f32 {
        let bits = reading.to_bits().wrapping_sub(1 << (31 - BIN_BITS));
        let k = (bits >> (32 - BIN_BITS)) as usize;
        let frac = ((bits >> (16 - BIN_BITS)) & 0xFFFF) as f32 * (1.0 / 65536.0);
        let a = self.table.get(k).copied().unwrap_or(0) as f32;
        let b = self
            .table
            .get((k + 1) % CORRECTION_BINS)
            .copied()
            .unwrap_or(0) as f32;
        (a + (b - a) * frac) * self.scale_rad
    }

    /// The reading with its error taken off (the reading itself when off).
    #[inline(always)]
    pub fn correct(&self, reading: MechanicalAngle) -> MechanicalAngle {
        if !self.enabled {
            return reading;
        }
        // The error in bits of a turn (at most 5 deg: no overflow).
        let e = self.error_rad(reading) * (1.0 / RAD_PER_BIT);
        MechanicalAngle::from_bits(reading.to_bits().wrapping_sub(e as i32 as u32))
    }
}

/// The point of the table a reading falls in.
#[inline]
pub fn bin_of(reading: MechanicalAngle) -> usize {
    (reading.to_bits() >> (32 - BIN_BITS)) as usize
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f32::consts::TAU;

    fn eccentric(first: f32, second: f32) -> [f32; CORRECTION_BINS] {
        let mut a = [0.0; CORRECTION_BINS];
        for (k, v) in a.iter_mut().enumerate() {
            let th = TAU * (k as f32 + 0.5) / CORRECTION_BINS as f32;
            *v = first * libm::sinf(th) + second * libm::sinf(2.0 * th + 0.3);
        }
        a
    }

    #[test]
    fn takes_the_error_off_the_reading() {
        let c = AngleCorrection::from_rad(&eccentric(0.005, 0.0017)).unwrap();
        for i in 0..2000u32 {
            let truth = i as f32 / 2000.0 * TAU;
            let err = 0.005 * libm::sinf(truth) + 0.0017 * libm::sinf(2.0 * truth + 0.3);
            let reading = MechanicalAngle::from_radians(truth + err);
            let got = c.correct(reading).to_radians();
            let d = libm::remainderf(got - truth, TAU);
            // 256 points: the interpolation and the error's slope at the
            // reading instead of the truth (e e' = 2.5e-5), within 4e-5 rad.
            assert!(d.abs() < 4e-5, "{i}: {d}");
        }
    }

    #[test]
    fn filled_a_point_at_a_time_as_from_rad() {
        let rad = eccentric(0.005, 0.0017);
        let peak = rad.iter().fold(0.0f32, |p, r| p.max(r.abs()));
        let mut c = AngleCorrection::with_peak(peak).unwrap();
        for (k, r) in rad.iter().enumerate() {
            c.set_rad(k, *r).unwrap();
        }
        c.set_rad(CORRECTION_BINS, 1.0).unwrap();
        assert_eq!(Ok(c), AngleCorrection::from_rad(&rad));
        assert_eq!(c.set_rad(3, f32::NAN), Err(AngleCorrectionError::NotFinite));
        assert_eq!(
            AngleCorrection::with_peak(0.1),
            Err(AngleCorrectionError::TooLarge)
        );
        assert_eq!(
            AngleCorrection::with_peak(f32::INFINITY),
            Err(AngleCorrectionError::NotFinite)
        );
        let zero = AngleCorrection::with_peak(0.0).unwrap();
        assert_eq!(Ok(zero), AngleCorrection::from_rad(&[0.0; CORRECTION_BINS]));
    }

    #[test]
    fn off_too_large_and_not_finite() {
        let mut c = AngleCorrection::from_rad(&eccentric(0.005, 0.0)).unwrap();
        c.enabled = false;
        let r = MechanicalAngle::from_bits(123_456_789);
        assert_eq!(c.correct(r), r);
        assert_eq!(
            AngleCorrection::from_rad(&eccentric(0.1, 0.0)),
            Err(AngleCorrectionError::TooLarge)
        );
        let mut nan = eccentric(0.005, 0.0);
        nan[9] = f32::INFINITY;
        assert_eq!(
            AngleCorrection::from_rad(&nan),
            Err(AngleCorrectionError::NotFinite)
        );
        assert_eq!(AngleCorrection::NONE.correct(r), r);
    }
}
