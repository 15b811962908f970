//! The angle the stage uses: the sensor's reading through its calibration,
//! interpolated between a coarse sensor's edges, and the checks that the
//! rotor moves as the angle says (stuck, frozen).

use super::*;

/// Coarse-sensor threshold [counts per electrical turn]: below it the
/// current stage interpolates the angle between the sensor's edges (the
/// tracker's angle, kept within the reading's count window); at or above it
/// (encoders) it uses the reading itself.
pub const INTERPOLATE_BELOW_COUNTS_PER_E_TURN: u32 = 64;

/// How the angle sensor relates to the motor's electrical angle.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AngleCalibration {
    /// Pole pairs.
    pub pole_pairs: u8,
    /// Electrical angle the sensor reads (after direction and pole-pair
    /// scaling) when the rotor d axis is on phase A.
    pub zero_offset: ElectricalAngle,
    /// True when the sensor counts backwards relative to A -> B -> C.
    pub reversed: bool,
    /// Counts per mechanical turn of a counting sensor, 0 if unknown or not
    /// counting. A count `n` means the sensor is somewhere in `[n, n + 1)`:
    /// with the resolution known, half a count is added to every reading, so
    /// the angle used is unbiased (this matters for coarse sensors: 30 deg(e)
    /// for 48 counts on 8 pole pairs) and the zero offset is the physical one.
    /// Below [`INTERPOLATE_BELOW_COUNTS_PER_E_TURN`] counts per electrical
    /// turn the current stage also interpolates between the edges
    /// ([`Self::interpolation_half_count`]).
    pub sensor_counts_per_rev: u32,
    /// Made without an angle sensor (an identification on a drive that
    /// runs sensorless, design §29): the zero, direction and resolution
    /// mean nothing, and the calibration unlocks the closed-loop modes only
    /// while the drive runs without its sensor
    /// ([`CurrentStage::is_calibrated`](super::CurrentStage::is_calibrated)).
    pub sensorless_only: bool,
}

impl AngleCalibration {
    /// The calibration made without reading the angle sensor (design
    /// §29): `pole_pairs`, the board's sensor resolution kept (the store
    /// checks it against the board's; the supervisor's angle checks use it
    /// on the sensor), and [`Self::sensorless_only`].
    pub const fn sensorless(pole_pairs: u8, sensor_counts_per_rev: u32) -> Self {
        Self {
            pole_pairs,
            zero_offset: ElectricalAngle::ZERO,
            reversed: false,
            sensor_counts_per_rev,
            sensorless_only: true,
        }
    }

    /// Mechanical angle in the motor's positive direction (half a count
    /// added first when the sensor's resolution is known).
    #[inline]
    pub fn mechanical(&self, raw: MechanicalAngle) -> MechanicalAngle {
        let raw = match self.sensor_counts_per_rev {
            0 => raw,
            n => raw.wrapping_add(MechanicalAngle::from_bits(0x8000_0000 / n)),
        };
        if self.reversed {
            MechanicalAngle::from_bits(raw.to_bits().wrapping_neg())
        } else {
            raw
        }
    }
    /// Half a count [mechanical angle bits] when the current stage
    /// interpolates the angle between the sensor's edges: a counting sensor
    /// of known resolution coarser than [`INTERPOLATE_BELOW_COUNTS_PER_E_TURN`]
    /// counts per electrical turn (halls, the hub motor's 48 counts on 8
    /// pole pairs). `None`: the reading (plus half a count) is used as is.
    #[inline]
    pub fn interpolation_half_count(&self) -> Option<u32> {
        let n = self.sensor_counts_per_rev;
        let pp = u32::from(self.pole_pairs.max(1));
        (n > 0 && n < INTERPOLATE_BELOW_COUNTS_PER_E_TURN * pp).then(|| 0x8000_0000 / n)
    }
    /// `estimate` kept within the count window of the reading `mech` (a
    /// [`Self::mechanical`] angle, so the centre of the window): the true
    /// angle is within half a count of it either way.
    #[inline]
    pub fn within_count(
        mech: MechanicalAngle,
        estimate: MechanicalAngle,
        half_count: u32,
    ) -> MechanicalAngle {
        let h = half_count.min(i32::MAX as u32) as i32;
        let e = estimate.to_bits().wrapping_sub(mech.to_bits()) as i32;
        mech.wrapping_add(MechanicalAngle::from_bits(e.clamp(-h, h) as u32))
    }
    /// Electrical angle of the d axis from a direction-corrected mechanical angle.
    #[inline]
    pub fn electrical(&self, mech: MechanicalAngle) -> ElectricalAngle {
        mech.to_electrical(self.pole_pairs)
            .wrapping_sub(self.zero_offset)
    }
}

impl CurrentStage {
    /// The mechanical angle the Park transform uses: the reading, or for a
    /// coarse sensor the interpolated one.
    ///
    /// A coarse sensor's reading is stale between its edges: use the
    /// tracker's angle (advancing with the tracked speed), kept within the
    /// reading's count window, and between edges never moved against the
    /// tracked speed (the tracker's correction towards the window's centre
    /// can pull back). At standstill the tracker settles on the reading
    /// (+ half a count); on a reversal the angle waits at the window's edge.
    #[inline(always)]
    pub(super) fn angle_used(&mut self, mech: MechanicalAngle, changed: bool) -> MechanicalAngle {
        match self.state.interpolation {
            None => mech,
            Some(h) => {
                let est = self.tracker.angle_at_reading();
                let mut th = AngleCalibration::within_count(mech, est, h);
                if !changed
                    && th.diff_radians(self.state.last_interp) * self.tracker.velocity_rad_s() < 0.0
                {
                    th = AngleCalibration::within_count(mech, self.state.last_interp, h);
                }
                self.state.last_interp = th;
                th
            }
        }
    }

    /// Stuck sensor / stall (a still reading while the drive pushes hard to
    /// move) and runaway (pushing at the limit without the speed error
    /// shrinking).
    #[inline(always)]
    pub(super) fn check_stuck(&mut self, changed: bool, iq_ref_from_speed_a: f32) {
        let sc = &self.config.supervisor;
        let moving = match self.state.active {
            Command::Velocity { rad_s } => rad_s.abs() >= sc.stuck_min_speed_rad_s,
            Command::Position { rad } => {
                let d = rad - self.tracker.position().to_radians();
                d.abs() >= sc.stuck_min_distance_rad
            }
            _ => false,
        };
        let demand = if iq_ref_from_speed_a.is_finite() {
            iq_ref_from_speed_a
        } else {
            0.0
        };
        // What the travel limits' soft stop let through last period: a
        // rotor held at the end of its travel is not a stuck sensor.
        let demand = match self.state.travel_window_a {
            Some((lo, hi)) => clamp(demand, lo, hi),
            None => demand,
        };
        self.supervisor.check_stuck(changed, demand, moving);
        // Runaway: velocity mode pushing at the current limit without the
        // speed error shrinking.
        let speed_error = match self.state.active {
            Command::Velocity { rad_s } => Some(rad_s - self.tracker.velocity_rad_s()),
            _ => None,
        };
        let saturated = demand.abs() >= 0.95 * self.config.limits.max_current_a;
        self.supervisor.check_runaway(speed_error, saturated);
    }

    /// The angle reading has stood still for longer than the speed it had
    /// when it last moved needs to move it two counts: a model-check trip
    /// is then the angle's (a frozen angle makes the model's back-EMF and
    /// the currents disagree), not the current sensors'.
    #[inline(always)]
    pub(super) fn angle_frozen(&self) -> bool {
        let cpr = self.config.angle.sensor_counts_per_rev;
        let count_rad = if cpr > 0 {
            core::f32::consts::TAU / cpr as f32
        } else {
            0.01
        };
        let ts = self.config.current.ts_s;
        let speed = self.state.speed_at_change_rad_s.abs();
        let moved_rad = speed * ts * self.state.unchanged_periods as f32;
        // A speed that moves two counts within 20 periods (slower, a
        // still reading is a rotor at rest); two counts' worth and more,
        // for at most 50 ms (longer, the rotor has likely stopped: then it
        // is the currents).
        let still_s = ts * self.state.unchanged_periods as f32;
        if self.state.interpolation.is_some() {
            // A coarse sensor (halls): a speed that moves a count within
            // 10 ms, four counts' worth and more (a rotor that reverses
            // inside one count stands that long too: `still_while_emf_moves`
            // asks the back-EMF to have turned two counts' worth as well).
            return speed * 0.01 > count_rad && moved_rad > 4.0 * count_rad && still_s < 0.05;
        }
        speed * ts * 20.0 > 2.0 * count_rad && moved_rad > 2.0 * count_rad && still_s < 0.05
    }

    /// The reading has stood still for two counts' worth and more at its
    /// last speed ([`Self::angle_frozen`]) while the measured back-EMF
    /// says the rotor turns.
    #[inline(always)]
    pub(super) fn still_while_emf_moves(&self) -> bool {
        self.angle_frozen() && self.emf_shows_motion() && self.emf_turned_on()
    }

    /// For a coarse sensor: the back-EMF has turned, in the direction of
    /// the last speed, by more than two counts (electrical) since the
    /// reading last changed. Its direction in the frame of the angle used
    /// is the rotor's against that frame, so a rotor that reverses inside
    /// one count turns it back; a rotor that turns on under a frozen
    /// reading turns it on. (A fine sensor: always.)
    #[inline(always)]
    fn emf_turned_on(&self) -> bool {
        if self.state.interpolation.is_none() {
            return true;
        }
        let cpr = self.config.angle.sensor_counts_per_rev.max(1);
        let count_e_rad = core::f32::consts::TAU * self.config.angle.pole_pairs as f32 / cpr as f32;
        let turned = if self.state.speed_at_change_rad_s < 0.0 {
            -self.state.emf_turned_rad
        } else {
            self.state.emf_turned_rad
        };
        turned > 2.0 * count_e_rad
    }

    /// Accumulates how far the measured back-EMF turned this period (a
    /// coarse sensor only; where it is above the check's uncertainty).
    #[inline(always)]
    pub(super) fn follow_emf(&mut self) {
        if self.state.interpolation.is_none() {
            return;
        }
        let r = self.model.last();
        let e = r.emf_dq_v;
        let e_sq = e.d * e.d + e.q * e.q;
        let strong = e_sq > r.min_emf_v * r.min_emf_v;
        if let (Some(p), true) = (self.state.last_emf_v, strong) {
            let cross = p.d * e.q - p.q * e.d;
            let dot = p.d * e.d + p.q * e.q;
            if dot > 0.0 {
                // The angle between the two, as its tangent (a period turns
                // it by far less than a radian).
                self.state.emf_turned_rad += cross / dot;
            }
        }
        self.state.last_emf_v = if strong { Some(e) } else { None };
    }

    /// The back-EMF the model check measured (independent of the angle)
    /// is at least half what the speed at the reading's last change
    /// gives, and above the check's own uncertainty: the rotor still
    /// turns (a rotor stopped against an end stop has no back-EMF).
    #[inline(always)]
    pub(super) fn emf_shows_motion(&self) -> bool {
        let r = self.model.last();
        let e = r.emf_dq_v;
        let e_sq = e.d * e.d + e.q * e.q;
        let m = &self.config.current.motor;
        let expected_v = 0.5
            * (self.state.speed_at_change_rad_s * m.pole_pairs as f32 * m.flux_linkage_wb).abs();
        e_sq > expected_v * expected_v && e_sq > r.min_emf_v * r.min_emf_v
    }
}
