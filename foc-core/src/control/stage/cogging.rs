//! The anticogging feed-forward in the stage (design §32): the map, and
//! the q current it added this period; and the angle sensor's correction
//! (design §33), which the same calibrations install.

use super::*;
use crate::control::angle_correction::{AngleCorrection, AngleCorrectionError};
use crate::control::cogging::{CoggingMap, CoggingMapError};

/// The map and what it added (kept last in the stage: see its docs).
/// `repr(C)`, what every period reads first (the map's table after).
#[derive(Clone, Copy, Debug)]
#[repr(C)]
pub(super) struct Anticogging {
    /// The feed-forward of the last closed-loop period \[A\] (0 otherwise).
    pub(super) last_a: f32,
    pub(super) map: CoggingMap,
}

impl Anticogging {
    pub(super) const INIT: Self = Self {
        last_a: 0.0,
        map: CoggingMap::EMPTY,
    };
}

impl CurrentStage {
    /// Install a cogging map (design §32); refused whole if its scale is
    /// unusable or its peak is above the current limit.
    pub fn set_cogging(&mut self, map: &CoggingMap) -> Result<(), CoggingMapError> {
        map.check(self.config.limits.max_current_a)?;
        self.cogging.map = *map;
        self.cogging.last_a = 0.0;
        Ok(())
    }

    /// Switch the installed map's feed-forward on or off.
    pub fn set_cogging_enabled(&mut self, on: bool) {
        self.cogging.map.enabled = on;
        self.cogging.last_a = 0.0;
    }

    /// Install the angle sensor's correction (design §33), refused whole
    /// if its scale is unusable or its peak too large.
    pub fn set_angle_correction(
        &mut self,
        c: &AngleCorrection,
    ) -> Result<(), AngleCorrectionError> {
        c.check()?;
        self.angle_correction = *c;
        Ok(())
    }

    /// Switch the installed angle correction on or off.
    pub fn set_angle_correction_enabled(&mut self, on: bool) {
        self.angle_correction.enabled = on;
    }

    /// The installed angle correction ([`AngleCorrection::NONE`] when none).
    pub fn angle_correction(&self) -> &AngleCorrection {
        &self.angle_correction
    }

    /// The reading taken as 0 (design §33: the encoder's index, once
    /// found): subtracted from every reading first.
    pub fn set_reading_zero(&mut self, zero: MechanicalAngle) {
        self.reading_zero = zero;
    }

    /// A raw reading referred to the reading's zero ([`Self::set_reading_zero`]),
    /// as the stage uses it and the calibration routines must see it.
    #[inline(always)]
    pub fn reading(&self, raw: MechanicalAngle) -> MechanicalAngle {
        raw.wrapping_sub(self.reading_zero)
    }

    /// The installed cogging map ([`CoggingMap::EMPTY`] when none).
    pub fn cogging(&self) -> &CoggingMap {
        &self.cogging.map
    }

    /// The feed-forward added to the q current last period \[A\].
    pub fn cogging_feed_forward_a(&self) -> f32 {
        self.cogging.last_a
    }

    /// `iq_a` plus the map's feed-forward at the angle where the current
    /// will act (`theta_e` advanced by the current loop's delay
    /// compensation at `w_e`: at 5 % of its speed the DJI M2006's cogging
    /// is at 2 kHz, where a period's lag turned the feed-forward against
    /// the cogging), within the current limit; kept for the speed
    /// observer.
    #[inline(always)]
    pub(super) fn with_cogging(
        &mut self,
        iq_a: Option<f32>,
        theta_e: ElectricalAngle,
        w_e: f32,
    ) -> Option<f32> {
        if !self.cogging.map.enabled {
            return iq_a;
        }
        let Some(iq) = iq_a else {
            self.cogging.last_a = 0.0;
            return None;
        };
        let c = &self.config.current;
        let ahead = theta_e.add_radians(w_e * c.delay_compensation_periods * c.ts_s);
        let ff = self.cogging.map.iq_a(ahead);
        self.cogging.last_a = ff;
        let lim = self.config.limits.max_current_a;
        Some(clamp(iq + ff, -lim, lim))
    }

    /// The q current that drove the rotor, as the torque-fed speed
    /// observer takes it: the feed-forward cancelled the cogging, so it
    /// moved nothing and is taken off.
    #[inline(always)]
    pub(super) fn net_torque_iq_a(&self, i_dq: Dq) -> f32 {
        self.field.torque_iq_a(i_dq) - self.cogging.last_a
    }
}
