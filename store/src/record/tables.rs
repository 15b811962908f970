//! The tables kept with the configuration (schema 9): the anticogging map
//! (design §32) and the angle sensor's correction (design §33), each with
//! its switch and scale, as foc-core holds them.
//!
//! A table is `N` `i16` counts of its scale, stored as `2 N` bytes,
//! little-endian ([`Counts`]: postcard writes a length varint and the
//! bytes, so the map costs 1032 bytes with its tag, switch and scale, the
//! correction 520; a varint per count would take up to 3 bytes each). A
//! length other than `2 N` does not decode (`RecordError::Malformed`); a
//! scale or a peak foc-core's check refuses (`CoggingMap::check` against
//! the record's current limit, `AngleCorrection::check`) is `Invalid`,
//! named by its field.
//!
//! ```
//! use foc_store::record::{CoggingRecord, Counts};
//! use foc_core::control::cogging::{CoggingMap, COGGING_BINS};
//! let mut amps = [0.0; COGGING_BINS];
//! amps[3] = 0.25;
//! let map = CoggingMap::from_amps(&amps).unwrap();
//! let r = CoggingRecord::from_map(&map);
//! assert_eq!(r.validate(5.0), Ok(()));
//! assert_eq!(r.to_map(), map);
//! // A peak above the current limit is a measurement gone wrong.
//! assert_eq!(r.validate(0.2).unwrap_err().field, "cogging.table");
//! ```

use core::fmt;
use core::marker::PhantomData;

use foc_core::control::angle_correction::{AngleCorrection, AngleCorrectionError, CORRECTION_BINS};
use foc_core::control::cogging::{CoggingMap, CoggingMapError, COGGING_BINS};
use serde::de::{Error as _, SeqAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::Invalid;

/// The longest table \[counts\] (the cogging map's).
const MAX_COUNTS: usize = COGGING_BINS;

/// `N` counts, stored as `2 N` bytes little-endian (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Counts<const N: usize>(pub [i16; N]);

impl<const N: usize> Counts<N> {
    /// Zero everywhere.
    pub const ZERO: Self = Self([0; N]);

    /// The counts as a slice.
    pub fn as_slice(&self) -> &[i16] {
        &self.0
    }

    /// From a slice of exactly `N` counts.
    pub fn from_slice(s: &[i16]) -> Option<Self> {
        s.try_into().ok().map(Self)
    }
}

impl<const N: usize> Serialize for Counts<N> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        const { assert!(N <= MAX_COUNTS) };
        let mut buf = [0u8; 2 * MAX_COUNTS];
        for (b, c) in buf.chunks_exact_mut(2).zip(self.0.iter()) {
            b.copy_from_slice(&c.to_le_bytes());
        }
        s.serialize_bytes(buf.get(..2 * N).unwrap_or(&[]))
    }
}

/// Reads the bytes (postcard) or a sequence of bytes (a self-describing
/// format); anything but `2 N` bytes is an error.
struct CountsVisitor<const N: usize>(PhantomData<[i16; N]>);

impl<'de, const N: usize> Visitor<'de> for CountsVisitor<N> {
    type Value = Counts<N>;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} bytes ({N} little-endian i16 counts)", 2 * N)
    }

    fn visit_bytes<E: serde::de::Error>(self, v: &[u8]) -> Result<Self::Value, E> {
        if v.len() != 2 * N {
            return Err(E::invalid_length(v.len(), &self));
        }
        let mut out = [0i16; N];
        for (c, b) in out.iter_mut().zip(v.chunks_exact(2)) {
            *c = i16::from_le_bytes([
                b.first().copied().unwrap_or(0),
                b.get(1).copied().unwrap_or(0),
            ]);
        }
        Ok(Counts(out))
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
        let mut out = [0i16; N];
        let mut n = 0usize;
        while let Some(b) = seq.next_element::<u8>()? {
            let (k, hi) = (n / 2, n % 2 == 1);
            let c = out
                .get_mut(k)
                .ok_or_else(|| A::Error::invalid_length(n + 1, &self))?;
            let [lo_b, hi_b] = c.to_le_bytes();
            *c = if hi {
                i16::from_le_bytes([lo_b, b])
            } else {
                i16::from_le_bytes([b, hi_b])
            };
            n += 1;
        }
        if n != 2 * N {
            return Err(A::Error::invalid_length(n, &self));
        }
        Ok(Counts(out))
    }
}

impl<'de, const N: usize> Deserialize<'de> for Counts<N> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_bytes(CountsVisitor::<N>(PhantomData))
    }
}

/// The anticogging map (design §32; foc-core's `CoggingMap`): the q
/// current that cancels the cogging over one electrical turn.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CoggingRecord {
    /// The feed-forward is applied (a map can be kept switched off).
    pub enabled: bool,
    /// Amperes per count (finite, `>= 0`).
    pub scale_a: f32,
    /// The map's points over the electrical turn, in counts of `scale_a`.
    pub table: Counts<COGGING_BINS>,
}

impl CoggingRecord {
    /// The record of a map.
    pub fn from_map(m: &CoggingMap) -> Self {
        Self {
            enabled: m.enabled,
            scale_a: m.scale_a,
            table: Counts(m.table),
        }
    }

    /// As foc-core's map.
    pub fn to_map(&self) -> CoggingMap {
        CoggingMap {
            enabled: self.enabled,
            scale_a: self.scale_a,
            table: self.table.0,
        }
    }

    /// foc-core's check (`CoggingMap::check`) against the current limit
    /// `max_current_a`: a bad scale is `cogging.scale_a`, a peak above
    /// the limit `cogging.table`.
    pub fn validate(&self, max_current_a: f32) -> Result<(), Invalid> {
        self.to_map().check(max_current_a).map_err(|e| Invalid {
            field: match e {
                CoggingMapError::BadScale => "cogging.scale_a",
                CoggingMapError::NotFinite | CoggingMapError::TooLarge => "cogging.table",
            },
        })
    }

    /// Its largest feed-forward \[A\].
    pub fn peak_a(&self) -> f32 {
        self.to_map().peak_a()
    }
}

/// The angle sensor's correction (design §33; foc-core's
/// `AngleCorrection`): its error over a turn of its reading.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CorrectionRecord {
    /// The correction is applied.
    pub enabled: bool,
    /// Radians (mechanical) per count (finite, `>= 0`).
    pub scale_rad: f32,
    /// The error's points over the reading's turn, in counts of
    /// `scale_rad`.
    pub table: Counts<CORRECTION_BINS>,
}

impl CorrectionRecord {
    /// The record of a correction.
    pub fn from_correction(c: &AngleCorrection) -> Self {
        Self {
            enabled: c.enabled,
            scale_rad: c.scale_rad,
            table: Counts(c.table),
        }
    }

    /// As foc-core's correction.
    pub fn to_correction(&self) -> AngleCorrection {
        AngleCorrection {
            enabled: self.enabled,
            scale_rad: self.scale_rad,
            table: self.table.0,
        }
    }

    /// foc-core's check (`AngleCorrection::check`): a bad scale is
    /// `angle_correction.scale_rad`, a peak above foc-core's
    /// `MAX_CORRECTION_RAD` `angle_correction.table`.
    pub fn validate(&self) -> Result<(), Invalid> {
        self.to_correction().check().map_err(|e| Invalid {
            field: match e {
                AngleCorrectionError::BadScale => "angle_correction.scale_rad",
                AngleCorrectionError::NotFinite | AngleCorrectionError::TooLarge => {
                    "angle_correction.table"
                }
            },
        })
    }

    /// Its largest correction \[rad\].
    pub fn peak_rad(&self) -> f32 {
        self.to_correction().peak_rad()
    }
}
