//! Three 120-degree hall sensors: sector decoding, direction, interpolation.
//!
//! The state is `H = (C << 2) | (B << 1) | A`. Turning forward (increasing
//! electrical angle) the states run `1, 3, 2, 6, 4, 5` = sectors `0..=5`;
//! sector `k` covers the electrical angles `offset + [k, k + 1) * 60 deg`.
//! `000` and `111` cannot occur with 120-degree halls (a wire is off or a
//! supply is missing): they are errors.
//!
//! Between edges the angle is interpolated from the time since the last edge
//! and the duration of the last sector, never past the next edge, and falls
//! back to the sector centre when the speed is unknown (after start, after a
//! reversal, after a skipped sector) or the rotor stalls. A hall set gives the
//! *electrical* angle; the mechanical angle is built by counting electrical
//! turns modulo the pole-pair count, so it is relative to the position at
//! start-up (but `mechanical.to_electrical(pole_pairs)` is exact).
//!
//! ```
//! use board_support::logic::hall::{HallConfig, HallDecoder};
//! let mut h = HallDecoder::new(HallConfig { pole_pairs: 7, ..HallConfig::DEFAULT });
//! let r = h.update(0b001, 0).unwrap(); // sector 0, speed unknown: centre
//! assert!((r.electrical.to_degrees() - 30.0).abs() < 0.01);
//! assert!(h.update(0b111, 10).is_err());
//! ```

use core::f32::consts::PI;
use foc_core::angle::{ElectricalAngle, MechanicalAngle};

/// Sector (0..=5) of a hall state, or an error for `000` / `111` / > 7.
pub const fn sector(state: u8) -> Result<u8, HallError> {
    match state {
        0b001 => Ok(0),
        0b011 => Ok(1),
        0b010 => Ok(2),
        0b110 => Ok(3),
        0b100 => Ok(4),
        0b101 => Ok(5),
        s => Err(HallError::InvalidState(s)),
    }
}

/// Hall decoding error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "_hal", derive(defmt::Format))]
pub enum HallError {
    /// `000`, `111` (or a value above 7): no valid sector.
    InvalidState(u8),
}

/// Rotation direction seen by the halls.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "_hal", derive(defmt::Format))]
pub enum Direction {
    /// Increasing electrical angle.
    Forward,
    /// Decreasing electrical angle.
    Reverse,
    /// Not known yet (start, skipped sector).
    Unknown,
}

/// Hall decoder configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HallConfig {
    /// Motor pole pairs (>= 1).
    pub pole_pairs: u8,
    /// Electrical angle of the start of sector 0 (state `001`).
    pub offset: ElectricalAngle,
    /// Frequency of the time stamps passed to [`HallDecoder::update`] [Hz].
    pub ticks_per_second: u32,
    /// No edge for this long: the rotor is taken as stopped [ticks].
    pub stall_timeout_ticks: u32,
}

impl HallConfig {
    /// 1 pole pair, no offset, microsecond time stamps, 100 ms stall timeout.
    pub const DEFAULT: Self = Self {
        pole_pairs: 1,
        offset: ElectricalAngle::ZERO,
        ticks_per_second: 1_000_000,
        stall_timeout_ticks: 100_000,
    };

    /// The same configuration with time stamps at `ticks_per_second`,
    /// keeping the stall timeout's duration in seconds.
    pub fn at_tick_rate(self, ticks_per_second: u32) -> Self {
        let stall = u64::from(self.stall_timeout_ticks) * u64::from(ticks_per_second)
            / u64::from(self.ticks_per_second.max(1));
        Self {
            ticks_per_second,
            stall_timeout_ticks: stall.min(u64::from(u32::MAX)) as u32,
            ..self
        }
    }
}

/// One decoded hall reading.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HallReading {
    /// Sector 0..=5.
    pub sector: u8,
    /// Interpolated electrical angle.
    pub electrical: ElectricalAngle,
    /// Mechanical angle (relative to the turn at start-up, see module docs).
    pub mechanical: MechanicalAngle,
    /// Electrical velocity [rad/s] (0 when unknown or stalled).
    pub velocity_elec_rad_s: f32,
    /// Direction of the last edge.
    pub direction: Direction,
}

/// Hall state decoder with edge timing.
#[derive(Clone, Copy, Debug)]
pub struct HallDecoder {
    cfg: HallConfig,
    last_sector: Option<u8>,
    /// Time stamp of the last edge, if an edge was seen.
    last_edge: Option<u32>,
    /// Duration of the last complete sector [ticks] (0 = unknown).
    interval: u32,
    direction: Direction,
    /// Electrical turns modulo pole pairs.
    turns: u8,
}

const SECTOR_TURNS: f32 = 1.0 / 6.0;

impl HallDecoder {
    /// A decoder that has seen nothing yet.
    pub const fn new(cfg: HallConfig) -> Self {
        Self {
            cfg,
            last_sector: None,
            last_edge: None,
            interval: 0,
            direction: Direction::Unknown,
            turns: 0,
        }
    }

    /// Configuration in use.
    pub const fn config(&self) -> &HallConfig {
        &self.cfg
    }

    /// Forget all history (e.g. after a fault).
    pub fn reset(&mut self) {
        *self = Self::new(self.cfg);
    }

    /// Feed the current hall state and a time stamp (free-running, wrapping
    /// `u32` ticks of `ticks_per_second`).
    pub fn update(&mut self, state: u8, now: u32) -> Result<HallReading, HallError> {
        let s = match sector(state) {
            Ok(s) => s,
            Err(e) => {
                // Invalid state: forget timing; the next valid state restarts.
                self.last_sector = None;
                self.last_edge = None;
                self.interval = 0;
                self.direction = Direction::Unknown;
                return Err(e);
            }
        };
        if let Some(prev) = self.last_sector {
            if prev != s {
                let step = (s + 6 - prev) % 6;
                let dir = match step {
                    1 => Direction::Forward,
                    5 => Direction::Reverse,
                    _ => Direction::Unknown, // skipped sector(s)
                };
                let pp = self.cfg.pole_pairs.max(1);
                if dir == Direction::Forward && prev == 5 {
                    self.turns = (self.turns + 1) % pp;
                } else if dir == Direction::Reverse && prev == 0 {
                    self.turns = (self.turns + pp - 1) % pp;
                }
                // Speed is known only after two edges in the same direction.
                self.interval = match (self.last_edge, dir == self.direction) {
                    (Some(t), true) if dir != Direction::Unknown => now.wrapping_sub(t).max(1),
                    _ => 0,
                };
                self.direction = dir;
                self.last_edge = Some(now);
            }
        }
        self.last_sector = Some(s);
        Ok(self.reading(s, now))
    }

    fn reading(&self, s: u8, now: u32) -> HallReading {
        let since = self
            .last_edge
            .map(|t| now.wrapping_sub(t))
            .unwrap_or(u32::MAX);
        let moving = self.interval != 0 && since < self.cfg.stall_timeout_ticks;
        // Position inside the sector, in sectors [0, 1).
        let in_sector = if moving {
            let frac = since as f32 / self.interval as f32;
            let frac = if frac < 0.999 { frac } else { 0.999 };
            match self.direction {
                Direction::Forward => frac,
                Direction::Reverse => 1.0 - frac,
                Direction::Unknown => 0.5,
            }
        } else {
            0.5
        };
        let velocity = if moving {
            // Never faster than what the time since the last edge allows.
            let dt = if since > self.interval {
                since
            } else {
                self.interval
            };
            let w = (PI / 3.0) * self.cfg.ticks_per_second as f32 / dt as f32;
            match self.direction {
                Direction::Forward => w,
                Direction::Reverse => -w,
                Direction::Unknown => 0.0,
            }
        } else {
            0.0
        };
        let rel = (s as f32 + in_sector) * SECTOR_TURNS; // [0, 1)
        let offset = self.cfg.offset.to_turns();
        let pp = self.cfg.pole_pairs.max(1) as f32;
        HallReading {
            sector: s,
            electrical: ElectricalAngle::from_turns(rel + offset),
            mechanical: MechanicalAngle::from_turns((self.turns as f32 + rel + offset) / pp),
            velocity_elec_rad_s: velocity,
            direction: self.direction,
        }
    }
}

#[cfg(test)]
mod tests {

    #[test]
    fn tick_rate_change_keeps_the_stall_time() {
        let c = HallConfig::DEFAULT.at_tick_rate(180_000_000);
        assert_eq!(c.ticks_per_second, 180_000_000);
        // 100 ms at 1 MHz is 100 ms at 180 MHz.
        assert_eq!(c.stall_timeout_ticks, 18_000_000);
        assert_eq!(c.pole_pairs, HallConfig::DEFAULT.pole_pairs);
        // Saturates instead of wrapping.
        let slow = HallConfig {
            ticks_per_second: 1,
            stall_timeout_ticks: u32::MAX,
            ..HallConfig::DEFAULT
        };
        assert_eq!(slow.at_tick_rate(1_000).stall_timeout_ticks, u32::MAX);
    }

    use super::*;
    use proptest::prelude::*;

    const FWD: [u8; 6] = [0b001, 0b011, 0b010, 0b110, 0b100, 0b101];

    #[test]
    fn table_and_invalid() {
        for (k, s) in FWD.iter().enumerate() {
            assert_eq!(sector(*s), Ok(k as u8));
        }
        assert_eq!(sector(0), Err(HallError::InvalidState(0)));
        assert_eq!(sector(7), Err(HallError::InvalidState(7)));
        assert_eq!(sector(9), Err(HallError::InvalidState(9)));
    }

    #[test]
    fn forward_interpolates_and_measures_speed() {
        let mut h = HallDecoder::new(HallConfig::DEFAULT);
        h.update(FWD[0], 0).unwrap();
        h.update(FWD[1], 1000).unwrap(); // first edge: no speed yet
        let r = h.update(FWD[2], 2000).unwrap(); // second edge: 1000 us per sector
        assert_eq!(r.direction, Direction::Forward);
        assert!((r.electrical.to_degrees() - 120.0).abs() < 0.01);
        let w = (PI / 3.0) / 1e-3;
        assert!((r.velocity_elec_rad_s - w).abs() < 1.0);
        // Half way to the next edge.
        let r = h.update(FWD[2], 2500).unwrap();
        assert!((r.electrical.to_degrees() - 150.0).abs() < 0.01);
        // Late: never past the next edge, speed decays.
        let r = h.update(FWD[2], 4000).unwrap();
        assert!(r.electrical.to_degrees() < 180.0);
        assert!(r.velocity_elec_rad_s < w);
        // Stalled: centre, zero speed.
        let r = h.update(FWD[2], 2000 + 200_000).unwrap();
        assert!((r.electrical.to_degrees() - 150.0).abs() < 0.01);
        assert_eq!(r.velocity_elec_rad_s, 0.0);
    }

    #[test]
    fn reverse_and_turn_counting() {
        let cfg = HallConfig {
            pole_pairs: 2,
            ..HallConfig::DEFAULT
        };
        let mut h = HallDecoder::new(cfg);
        h.update(FWD[0], 0).unwrap();
        h.update(FWD[5], 100).unwrap();
        let r = h.update(FWD[4], 200).unwrap();
        assert_eq!(r.direction, Direction::Reverse);
        assert!(r.velocity_elec_rad_s < 0.0);
        // Entered sector 4 from 5: at its upper edge (300 deg).
        assert!((r.electrical.to_degrees() - 300.0).abs() < 0.01);
        // Electrical turn went 0 -> -1 = 1 (mod 2): mechanical in the 2nd half.
        assert!(r.mechanical.to_turns() > 0.5);
        assert!((r.mechanical.to_electrical(2).to_degrees() - 300.0).abs() < 0.01);
    }

    #[test]
    fn skipped_sector_forgets_speed() {
        let mut h = HallDecoder::new(HallConfig::DEFAULT);
        h.update(FWD[0], 0).unwrap();
        h.update(FWD[1], 100).unwrap();
        h.update(FWD[2], 200).unwrap();
        let r = h.update(FWD[4], 300).unwrap();
        assert_eq!(r.direction, Direction::Unknown);
        assert_eq!(r.velocity_elec_rad_s, 0.0);
        assert!((r.electrical.to_degrees() - 270.0).abs() < 0.01);
    }

    #[test]
    fn invalid_state_resets_timing() {
        let mut h = HallDecoder::new(HallConfig::DEFAULT);
        h.update(FWD[0], 0).unwrap();
        h.update(FWD[1], 100).unwrap();
        h.update(FWD[2], 200).unwrap();
        assert_eq!(h.update(0, 250), Err(HallError::InvalidState(0)));
        let r = h.update(FWD[3], 300).unwrap();
        assert_eq!(r.velocity_elec_rad_s, 0.0);
    }

    proptest! {
        #[test]
        fn angle_stays_in_current_sector(start in 0usize..6, n in 1usize..40, dt in 1u32..10_000, fwd in prop::bool::ANY, probe in 0u32..20_000) {
            let mut h = HallDecoder::new(HallConfig { pole_pairs: 7, ..HallConfig::DEFAULT });
            let mut t = 0u32;
            let mut k = start;
            h.update(FWD[k], t).unwrap();
            for _ in 0..n {
                k = if fwd { (k + 1) % 6 } else { (k + 5) % 6 };
                t = t.wrapping_add(dt);
                h.update(FWD[k], t).unwrap();
            }
            let r = h.update(FWD[k], t.wrapping_add(probe)).unwrap();
            let deg = r.electrical.to_degrees();
            let lo = k as f32 * 60.0;
            prop_assert!(deg >= lo - 0.01 && deg <= lo + 60.0 + 0.01, "{} not in sector {}", deg, k);
            prop_assert!(r.velocity_elec_rad_s.is_finite());
            let e = r.mechanical.to_electrical(7).to_degrees();
            let d = (e - deg).abs();
            prop_assert!(!(0.1..=359.9).contains(&d), "mech->elec {} vs {}", e, deg);
        }
    }
}
