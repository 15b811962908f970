//! The sub-records' checks and conversions (to and from the drive's
//! configuration types), field by field.

use super::*;

pub(super) fn invalid(field: &'static str) -> Invalid {
    Invalid { field }
}

/// `Ok` when `ok`, else the field.
pub(super) fn check(ok: bool, field: &'static str) -> Result<(), Invalid> {
    if ok {
        Ok(())
    } else {
        Err(invalid(field))
    }
}

pub(super) fn positive(x: f32) -> bool {
    x.is_finite() && x > 0.0
}

pub(super) fn non_negative(x: f32) -> bool {
    x.is_finite() && x >= 0.0
}

/// `>= 0`, `inf` allowed (off).
pub(super) fn limit(x: f32) -> bool {
    x >= 0.0
}

/// A `(start, end)` window: no NaN, `start <= end` (`end = inf`: off).
pub(super) fn window(start: f32, end: f32) -> bool {
    !start.is_nan() && !end.is_nan() && start <= end
}

impl PowerRecord {
    /// Check every value (see the field docs).
    pub fn validate(&self) -> Result<(), Invalid> {
        check(
            window(self.regen_start_v, self.regen_end_v) && self.regen_start_v > 0.0,
            "power.regen_start_v",
        )?;
        check(limit(self.regen_id_max_a), "power.regen_id_max_a")?;
        check(
            limit(self.bus_current_motoring_max_a),
            "power.bus_current_motoring_max_a",
        )?;
        check(
            limit(self.bus_current_regen_max_a),
            "power.bus_current_regen_max_a",
        )?;
        check(
            limit(self.power_motoring_max_w),
            "power.power_motoring_max_w",
        )?;
        check(limit(self.power_regen_max_w), "power.power_regen_max_w")?;
        check(
            positive(self.thermal_resistance_k_per_w),
            "power.thermal_resistance_k_per_w",
        )?;
        check(
            non_negative(self.thermal_time_constant_s),
            "power.thermal_time_constant_s",
        )?;
        check(self.ambient_c.is_finite(), "power.ambient_c")?;
        check(
            window(self.winding_derate_start_c, self.winding_derate_end_c),
            "power.winding_derate_start_c",
        )?;
        check(
            window(self.stage_derate_start_c, self.stage_derate_end_c),
            "power.stage_derate_start_c",
        )?;
        check(
            window(self.brake_off_v, self.brake_on_v) && self.brake_off_v > 0.0,
            "power.brake_off_v",
        )?;
        check(limit(self.brake_max_on_s), "power.brake_max_on_s")?;
        Ok(())
    }

    /// From foc-core's configuration (its motor model is not stored).
    pub fn from_config(c: &PowerLimitsConfig) -> Self {
        Self {
            regen_start_v: c.regen_start_v,
            regen_end_v: c.regen_end_v,
            regen_id_max_a: c.regen_id_max_a,
            bus_current_motoring_max_a: c.bus_current_motoring_max_a,
            bus_current_regen_max_a: c.bus_current_regen_max_a,
            power_motoring_max_w: c.power_motoring_max_w,
            power_regen_max_w: c.power_regen_max_w,
            thermal_resistance_k_per_w: c.thermal_resistance_k_per_w,
            thermal_time_constant_s: c.thermal_time_constant_s,
            ambient_c: c.ambient_c,
            winding_derate_start_c: c.winding_derate_start_c,
            winding_derate_end_c: c.winding_derate_end_c,
            stage_derate_start_c: c.stage_derate_start_c,
            stage_derate_end_c: c.stage_derate_end_c,
            brake_on_v: c.brake_on_v,
            brake_off_v: c.brake_off_v,
            brake_max_on_s: c.brake_max_on_s,
        }
    }

    /// foc-core's configuration for `motor`.
    pub fn to_config(&self, motor: MotorParams) -> PowerLimitsConfig {
        PowerLimitsConfig {
            motor,
            regen_start_v: self.regen_start_v,
            regen_end_v: self.regen_end_v,
            regen_id_max_a: self.regen_id_max_a,
            bus_current_motoring_max_a: self.bus_current_motoring_max_a,
            bus_current_regen_max_a: self.bus_current_regen_max_a,
            power_motoring_max_w: self.power_motoring_max_w,
            power_regen_max_w: self.power_regen_max_w,
            thermal_resistance_k_per_w: self.thermal_resistance_k_per_w,
            thermal_time_constant_s: self.thermal_time_constant_s,
            ambient_c: self.ambient_c,
            winding_derate_start_c: self.winding_derate_start_c,
            winding_derate_end_c: self.winding_derate_end_c,
            stage_derate_start_c: self.stage_derate_start_c,
            stage_derate_end_c: self.stage_derate_end_c,
            brake_on_v: self.brake_on_v,
            brake_off_v: self.brake_off_v,
            brake_max_on_s: self.brake_max_on_s,
        }
    }
}

impl SensorlessRecord {
    /// The plausible nominal bus voltages \[V\].
    pub const BUS_RANGE_V: core::ops::RangeInclusive<f32> = 1.0..=1000.0;
    /// The largest `observer_above_rad_s` [rad/s, mechanical] (about
    /// 100 000 rpm).
    pub const MAX_OBSERVER_ABOVE_RAD_S: f32 = 10_000.0;

    /// Check every value (see the field docs) against the record's
    /// `limits`.
    pub fn validate(&self, limits: &LimitsRecord) -> Result<(), Invalid> {
        check(
            self.start_current_a.is_finite()
                && self.start_current_a > 0.0
                && self.start_current_a <= limits.max_current_a,
            "sensorless.start_current_a",
        )?;
        check(
            self.bus_voltage_v.is_finite() && Self::BUS_RANGE_V.contains(&self.bus_voltage_v),
            "sensorless.bus_voltage_v",
        )?;
        check(
            self.observer_above_rad_s.is_none_or(|w| {
                w.is_finite()
                    && w > 0.0
                    && w <= Self::MAX_OBSERVER_ABOVE_RAD_S
                    && self.beside_sensor == Some(BesideRole::HallSensorless)
            }),
            "sensorless.observer_above_rad_s",
        )
    }

    /// True when the drive runs without its angle sensor (no role beside
    /// it).
    pub fn replaces_sensor(&self) -> bool {
        self.beside_sensor.is_none()
    }
}

impl FieldRecord {
    /// Check every value with foc-core's rule (`FieldConfig::check`),
    /// one value at a time so the error names it: `max_id_a`,
    /// `voltage_margin`, `bandwidth_rad_s`, then `field_weakening`
    /// (it needs `max_id_a > 0`, a bandwidth and a voltage margin of at
    /// least foc-core's `MIN_VOLTAGE_MARGIN`).
    pub fn validate(&self) -> Result<(), Invalid> {
        let alone = |c: FieldConfig| c.check().is_ok();
        let off = FieldConfig::OFF;
        check(
            alone(FieldConfig {
                max_id_a: self.max_id_a,
                ..off
            }),
            "field.max_id_a",
        )?;
        check(
            alone(FieldConfig {
                voltage_margin: self.voltage_margin,
                ..off
            }),
            "field.voltage_margin",
        )?;
        check(
            alone(FieldConfig {
                bandwidth_rad_s: self.bandwidth_rad_s,
                ..off
            }),
            "field.bandwidth_rad_s",
        )?;
        check(alone(self.to_config()), "field.field_weakening")
    }

    /// foc-core's form.
    pub fn to_config(&self) -> FieldConfig {
        FieldConfig {
            mtpa: self.mtpa,
            field_weakening: self.field_weakening,
            max_id_a: self.max_id_a,
            voltage_margin: self.voltage_margin,
            bandwidth_rad_s: self.bandwidth_rad_s,
            short_circuit: self.short_circuit,
        }
    }

    /// The record's form of foc-core's.
    pub fn from_config(c: &FieldConfig) -> Self {
        Self {
            mtpa: c.mtpa,
            field_weakening: c.field_weakening,
            max_id_a: c.max_id_a,
            voltage_margin: c.voltage_margin,
            bandwidth_rad_s: c.bandwidth_rad_s,
            short_circuit: c.short_circuit,
        }
    }
}

impl MechanicsRecord {
    /// The plausible inertias [kg m^2]: from a small gimbal motor's rotor
    /// alone to a large servo with its load.
    pub const INERTIA_RANGE_KG_M2: core::ops::RangeInclusive<f32> = 1e-9..=10.0;
    /// The largest plausible viscous friction [N m s/rad].
    pub const MAX_VISCOUS_FRICTION_NM_S_PER_RAD: f32 = 100.0;
    /// The largest plausible Coulomb friction [N m].
    pub const MAX_COULOMB_FRICTION_NM: f32 = 1000.0;

    /// Check every value (see the field docs); finite values in the
    /// plausible ranges are also usable by foc-core
    /// (`Mechanics::is_usable`).
    pub fn validate(&self) -> Result<(), Invalid> {
        check(
            self.inertia_kg_m2.is_finite()
                && Self::INERTIA_RANGE_KG_M2.contains(&self.inertia_kg_m2),
            "mechanics.inertia_kg_m2",
        )?;
        check(
            non_negative(self.viscous_friction_nm_s_per_rad)
                && self.viscous_friction_nm_s_per_rad <= Self::MAX_VISCOUS_FRICTION_NM_S_PER_RAD,
            "mechanics.viscous_friction_nm_s_per_rad",
        )?;
        check(
            non_negative(self.coulomb_friction_nm)
                && self.coulomb_friction_nm <= Self::MAX_COULOMB_FRICTION_NM,
            "mechanics.coulomb_friction_nm",
        )?;
        Ok(())
    }

    /// The record of foc-core's mechanics.
    pub fn from_mechanics(m: &Mechanics) -> Self {
        Self {
            inertia_kg_m2: m.inertia_kg_m2,
            viscous_friction_nm_s_per_rad: m.viscous_friction_nm_s_per_rad,
            coulomb_friction_nm: m.coulomb_friction_nm,
        }
    }

    /// As foc-core's mechanics.
    pub fn to_mechanics(&self) -> Mechanics {
        Mechanics {
            inertia_kg_m2: self.inertia_kg_m2,
            viscous_friction_nm_s_per_rad: self.viscous_friction_nm_s_per_rad,
            coulomb_friction_nm: self.coulomb_friction_nm,
        }
    }
}

/// A soft stop foc-core accepts (`TravelConfig::is_valid`): each stored
/// value is checked alone in it (and the travel range with it), so a
/// refusal names its field.
pub(super) const SOFT_STOP_OK: TravelConfig = TravelConfig {
    fault_margin_rad: 0.0,
    brake_accel_rad_s2: 1.0,
    kv_a_per_rad_s: 1.0,
};

/// Joint settings foc-core accepts (`JointConfig::is_valid`), for the
/// same purpose.
pub(super) const JOINT_OK: JointConfig = JointConfig {
    travel: None,
    entry_blend_periods: 0,
    timeout_kd_nm_s_per_rad: 0.0,
};

impl JointRecord {
    /// The record of a joint setup and the impedance maxima of `l`.
    pub fn from_setup(j: &JointSetup, l: &Limits) -> Self {
        Self {
            gear_ratio: j.frame.gear_ratio(),
            rotor_at_zero_rad: j.frame.rotor_at_zero_rad(),
            travel_out_rad: j.travel_out_rad,
            fault_margin_rad: j.travel.fault_margin_rad,
            brake_accel_rad_s2: j.travel.brake_accel_rad_s2,
            kv_a_per_rad_s: j.travel.kv_a_per_rad_s,
            entry_blend_periods: j.joint.entry_blend_periods,
            timeout_kd_nm_s_per_rad: j.joint.timeout_kd_nm_s_per_rad,
            max_kp_nm_per_rad: l.max_kp_nm_per_rad,
            max_kd_nm_s_per_rad: l.max_kd_nm_s_per_rad,
        }
    }

    /// As foc-core's joint setup; its `joint.travel` is the soft stop with
    /// a travel range, `None` without (what `JointSetup::rotor_change`
    /// installs). An output frame foc-core refuses (`OutputFrame::check`)
    /// names its field.
    pub fn to_setup(&self) -> Result<JointSetup, Invalid> {
        let frame = OutputFrame::check(self.gear_ratio, self.rotor_at_zero_rad).map_err(|e| {
            invalid(match e {
                JointError::GearRatio => "joint.gear_ratio",
                JointError::Offset => "joint.rotor_at_zero_rad",
                // Not a frame error.
                JointError::Travel => "joint",
            })
        })?;
        let travel = self.soft_stop();
        Ok(JointSetup {
            frame,
            travel_out_rad: self.travel_out_rad,
            travel,
            joint: JointConfig {
                travel: self.travel_out_rad.map(|_| travel),
                entry_blend_periods: self.entry_blend_periods,
                timeout_kd_nm_s_per_rad: self.timeout_kd_nm_s_per_rad,
            },
        })
    }

    /// The soft stop's settings (rotor frame).
    pub fn soft_stop(&self) -> TravelConfig {
        TravelConfig {
            fault_margin_rad: self.fault_margin_rad,
            brake_accel_rad_s2: self.brake_accel_rad_s2,
            kv_a_per_rad_s: self.kv_a_per_rad_s,
        }
    }

    /// `l` as foc-core's limits with these impedance maxima (the position
    /// range `l`'s: the travel range replaces it in the stage, see
    /// `Settings::apply_to`).
    pub fn limits(&self, l: &LimitsRecord) -> Limits {
        Limits {
            max_kp_nm_per_rad: self.max_kp_nm_per_rad,
            max_kd_nm_s_per_rad: self.max_kd_nm_s_per_rad,
            ..l.to_limits()
        }
    }

    /// Check every value with foc-core's checks, the first bad one named
    /// by its TOML path (`joint.<field>`): the frame (`OutputFrame::check`);
    /// with a travel range, the range (`JointSetup::validate`) and each
    /// soft-stop value (`TravelConfig::is_valid`); the timeout damping
    /// (`JointConfig::is_valid`); the maxima, and the travel range in the
    /// rotor frame, as the limits in force (`Limits::validate`, on `l`,
    /// checked before); then the whole setup (`JointSetup::validate`).
    pub fn validate(&self, l: &LimitsRecord) -> Result<(), Invalid> {
        let s = self.to_setup()?;
        if s.travel_out_rad.is_some() {
            let range_alone = JointSetup {
                travel: SOFT_STOP_OK,
                joint: JOINT_OK,
                ..s
            };
            check(range_alone.validate().is_ok(), "joint.travel_out_rad")?;
            let t = s.travel;
            let fields = [
                (
                    TravelConfig {
                        fault_margin_rad: t.fault_margin_rad,
                        ..SOFT_STOP_OK
                    },
                    "joint.fault_margin_rad",
                ),
                (
                    TravelConfig {
                        brake_accel_rad_s2: t.brake_accel_rad_s2,
                        ..SOFT_STOP_OK
                    },
                    "joint.brake_accel_rad_s2",
                ),
                (
                    TravelConfig {
                        kv_a_per_rad_s: t.kv_a_per_rad_s,
                        ..SOFT_STOP_OK
                    },
                    "joint.kv_a_per_rad_s",
                ),
            ];
            for (one, field) in fields {
                check(one.is_valid(), field)?;
            }
        }
        check(
            s.joint.entry_blend_periods <= JointConfig::MAX_ENTRY_BLEND_PERIODS,
            "joint.entry_blend_periods",
        )?;
        check(
            JointConfig {
                travel: None,
                ..s.joint
            }
            .is_valid(),
            "joint.timeout_kd_nm_s_per_rad",
        )?;
        let range = s.rotor_change((l.min_position_rad, l.max_position_rad));
        let in_force = Limits {
            min_position_rad: range.min_position_rad,
            max_position_rad: range.max_position_rad,
            ..self.limits(l)
        };
        in_force.validate().map_err(|e| {
            invalid(match e {
                LimitsError::MaxStiffness => "joint.max_kp_nm_per_rad",
                LimitsError::MaxDamping => "joint.max_kd_nm_s_per_rad",
                LimitsError::MinPosition | LimitsError::MaxPosition => "joint.travel_out_rad",
                // `l`'s own values, checked before.
                LimitsError::MaxCurrent
                | LimitsError::MaxVelocity
                | LimitsError::OpenLoopVoltage
                | LimitsError::OpenLoopOmega => "limits",
            })
        })?;
        s.validate().map_err(|_| invalid("joint"))
    }
}

impl MotorRecord {
    /// The record of foc-core's motor parameters.
    pub fn from_params(m: &MotorParams) -> Self {
        Self {
            pole_pairs: m.pole_pairs,
            r_ohm: m.r_ohm,
            ld_h: m.ld_h,
            lq_h: m.lq_h,
            flux_linkage_wb: m.flux_linkage_wb,
        }
    }

    /// As foc-core's motor parameters.
    pub fn to_params(&self) -> MotorParams {
        MotorParams {
            pole_pairs: self.pole_pairs,
            r_ohm: self.r_ohm,
            ld_h: self.ld_h,
            lq_h: self.lq_h,
            flux_linkage_wb: self.flux_linkage_wb,
        }
    }
}

impl CurrentGainsRecord {
    /// The record of both axes' gains.
    pub fn from_gains(d: &CurrentPiGains, q: &CurrentPiGains) -> Self {
        Self {
            kp_d_v_per_a: d.kp_v_per_a,
            ki_d_v_per_a_s: d.ki_v_per_a_s,
            kp_q_v_per_a: q.kp_v_per_a,
            ki_q_v_per_a_s: q.ki_v_per_a_s,
        }
    }

    /// The d-axis gains.
    pub fn d(&self) -> CurrentPiGains {
        CurrentPiGains {
            kp_v_per_a: self.kp_d_v_per_a,
            ki_v_per_a_s: self.ki_d_v_per_a_s,
        }
    }

    /// The q-axis gains.
    pub fn q(&self) -> CurrentPiGains {
        CurrentPiGains {
            kp_v_per_a: self.kp_q_v_per_a,
            ki_v_per_a_s: self.ki_q_v_per_a_s,
        }
    }
}

/// One turn in units of the angle's least significant bit.
pub(super) const TURN_LSB: f64 = 4_294_967_296.0;

/// Radians in `[0, 2 pi)` of an electrical angle, correctly rounded to f32
/// (computed in f64, once at load or save, so the angle's 32 bits lose
/// only the final rounding). An angle within half an f32 step of a full
/// turn rounds to `2 pi`: it is stored as 0, the same angle wrapped.
pub fn angle_to_e_rad(a: ElectricalAngle) -> f32 {
    let r = (f64::from(a.to_bits()) * (core::f64::consts::TAU / TURN_LSB)) as f32;
    if r < TAU {
        r
    } else {
        0.0
    }
}

/// The electrical angle of radians, rounded to the nearest of its 2^32
/// steps (wrapping; non-finite gives zero). For radians in `[0.02, 2 pi)`,
/// `angle_to_e_rad(e_rad_to_angle(r)) == r` exactly; below, within one
/// angle step (1.5e-9 rad).
pub fn e_rad_to_angle(rad: f32) -> ElectricalAngle {
    if !rad.is_finite() {
        return ElectricalAngle::ZERO;
    }
    let turns = f64::from(rad) / core::f64::consts::TAU;
    // Fraction of a turn in [0, 1) (f32 radians are far below 2^63 turns).
    let mut frac = turns - (turns as i64) as f64;
    if frac < 0.0 {
        frac += 1.0;
    }
    // Round to the nearest step; a full turn wraps to 0.
    let steps = (frac * TURN_LSB + 0.5) as u64;
    ElectricalAngle::from_bits(steps as u32)
}

impl AngleRecord {
    /// The record of an angle calibration.
    pub fn from_calibration(a: &AngleCalibration) -> Self {
        Self {
            zero_offset_e_rad: angle_to_e_rad(a.zero_offset),
            reversed: a.reversed,
            pole_pairs: a.pole_pairs,
            sensor_counts_per_rev: a.sensor_counts_per_rev,
            sensorless_only: a.sensorless_only,
        }
    }

    /// As foc-core's angle calibration.
    pub fn to_calibration(&self) -> AngleCalibration {
        AngleCalibration {
            pole_pairs: self.pole_pairs,
            zero_offset: e_rad_to_angle(self.zero_offset_e_rad),
            reversed: self.reversed,
            sensor_counts_per_rev: self.sensor_counts_per_rev,
            sensorless_only: self.sensorless_only,
        }
    }
}

impl LimitsRecord {
    /// The record of foc-core's limits.
    pub fn from_limits(l: &Limits) -> Self {
        Self {
            max_current_a: l.max_current_a,
            max_velocity_rad_s: l.max_velocity_rad_s,
            min_position_rad: l.min_position_rad,
            max_position_rad: l.max_position_rad,
            max_open_loop_voltage_v: l.max_open_loop_voltage_v,
            max_open_loop_omega_e_rad_s: l.max_open_loop_omega_e_rad_s,
        }
    }

    /// As foc-core's limits, with the impedance maxima, which this part of
    /// the record does not hold, at `f32::MAX` (unbounded, but valid for
    /// `Limits::validate`). A record's maxima are its [`JointRecord`]'s
    /// ([`JointRecord::limits`]); a record without one keeps those of the
    /// settings it is applied on ([`DriveRecord::apply`]).
    pub fn to_limits(&self) -> Limits {
        Limits {
            max_current_a: self.max_current_a,
            max_velocity_rad_s: self.max_velocity_rad_s,
            min_position_rad: self.min_position_rad,
            max_position_rad: self.max_position_rad,
            max_open_loop_voltage_v: self.max_open_loop_voltage_v,
            max_open_loop_omega_e_rad_s: self.max_open_loop_omega_e_rad_s,
            max_kp_nm_per_rad: f32::MAX,
            max_kd_nm_s_per_rad: f32::MAX,
        }
    }
}
