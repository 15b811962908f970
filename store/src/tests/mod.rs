//! Tests of the whole crate: records, settings, the store under power cuts
//! and garbage, wear, TOML.

mod can_tests;
mod power_cut;
#[cfg(feature = "std")]
mod props;
mod record_tests;
#[cfg(feature = "std")]
mod settings_text;
mod store_tests;

use crate::record::{
    example, AngleRecord, CurrentGainsRecord, DividersRecord, DriveRecord, JointRecord, Label,
    LimitsRecord, MechanicsRecord, MotorRecord, PositionRecord, PowerRecord, SensorlessRecord,
    SpeedRecord, WatchdogReaction, WatchdogRecord,
};

/// Record A of the tests: the example without its `[field]` table and
/// its tables (as every schema before 8 held it, so the older versions'
/// goldens decode to it; [`record_tests`]' `field_record` has a `[field]`
/// table, `tables_record` tables).
pub(crate) fn record_a() -> DriveRecord {
    DriveRecord {
        field: None,
        cogging: None,
        angle_correction: None,
        ..example()
    }
}

/// Record B: differs from A in every part (so a mix would be visible).
pub(crate) fn record_b() -> DriveRecord {
    let mut r = record_a();
    r.label = Label::try_from("second record, other motor").unwrap();
    r.pwm_frequency_hz = 16_000;
    r.motor.pole_pairs = 4;
    r.motor.r_ohm = 0.5;
    r.motor.ld_h = 1e-4;
    r.current_gains.kp_q_v_per_a = 0.9;
    r.calibration = Some(AngleRecord {
        zero_offset_e_rad: 4.5,
        reversed: false,
        pole_pairs: 4,
        sensor_counts_per_rev: 16_384,
        sensorless_only: false,
    });
    r.limits.max_current_a = 10.0;
    r.speed.ki_a_per_rad = 3.0;
    r.position.kp_per_s = 12.0;
    r.dividers.speed = 8;
    r.watchdog.reaction = WatchdogReaction::Hold;
    r.power = None;
    r.mechanics = None;
    r.joint = None;
    r
}

/// Record B with both tables (schema 9): a 12-cycle cogging map of 0.3 A
/// (switched on) and an eccentric sensor's correction of 5 mrad (kept
/// switched off); 1.5 KB more than B, the size of record a calibrated
/// drive writes.
pub(crate) fn record_t() -> DriveRecord {
    use foc_core::control::angle_correction::{AngleCorrection, CORRECTION_BINS};
    use foc_core::control::cogging::{CoggingMap, COGGING_BINS};
    let mut amps = [0.0f32; COGGING_BINS];
    for (k, a) in amps.iter_mut().enumerate() {
        *a = 0.3 * f32::sin(12.0 * core::f32::consts::TAU * (k as f32 + 0.5) / 512.0);
    }
    let mut rad = [0.0f32; CORRECTION_BINS];
    for (k, r) in rad.iter_mut().enumerate() {
        *r = 0.005 * f32::sin(core::f32::consts::TAU * (k as f32 + 0.5) / 256.0);
    }
    let mut correction = AngleCorrection::from_rad(&rad).unwrap();
    correction.enabled = false;
    DriveRecord {
        cogging: Some(crate::record::CoggingRecord::from_map(
            &CoggingMap::from_amps(&amps).unwrap(),
        )),
        angle_correction: Some(crate::record::CorrectionRecord::from_correction(
            &correction,
        )),
        ..record_b()
    }
}

/// The largest record: 32-character label, every option `Some`, every
/// varint at its widest.
pub(crate) fn largest_record() -> DriveRecord {
    DriveRecord {
        label: Label::try_from("~~~~~~~~~~~~~~~~~~~~~~~~~~~~~~~~").unwrap(),
        pwm_frequency_hz: u32::MAX,
        motor: MotorRecord {
            pole_pairs: u8::MAX,
            r_ohm: f32::MAX,
            ld_h: f32::MAX,
            lq_h: f32::MAX,
            flux_linkage_wb: f32::MAX,
        },
        current_gains: CurrentGainsRecord {
            kp_d_v_per_a: f32::MAX,
            ki_d_v_per_a_s: f32::MAX,
            kp_q_v_per_a: f32::MAX,
            ki_q_v_per_a_s: f32::MAX,
        },
        calibration: Some(AngleRecord {
            zero_offset_e_rad: 6.0,
            reversed: true,
            pole_pairs: u8::MAX,
            sensor_counts_per_rev: u32::MAX,
            sensorless_only: true,
        }),
        limits: LimitsRecord {
            max_current_a: f32::MAX,
            max_velocity_rad_s: f32::MAX,
            min_position_rad: f32::MIN,
            max_position_rad: f32::MAX,
            max_open_loop_voltage_v: f32::MAX,
            max_open_loop_omega_e_rad_s: f32::MAX,
        },
        speed: SpeedRecord {
            kp_a_per_rad_s: f32::MAX,
            ki_a_per_rad: f32::MAX,
        },
        position: PositionRecord {
            kp_per_s: f32::MAX,
            max_velocity_rad_s: f32::MAX,
            max_acceleration_rad_s2: f32::MAX,
        },
        dividers: DividersRecord {
            speed: u16::MAX,
            position: u16::MAX,
        },
        watchdog: WatchdogRecord {
            timeout_periods: u32::MAX,
            reaction: WatchdogReaction::Hold,
        },
        power: Some(PowerRecord {
            regen_start_v: f32::MAX,
            regen_end_v: f32::MAX,
            regen_id_max_a: f32::MAX,
            bus_current_motoring_max_a: f32::MAX,
            bus_current_regen_max_a: f32::MAX,
            power_motoring_max_w: f32::MAX,
            power_regen_max_w: f32::MAX,
            thermal_resistance_k_per_w: f32::MAX,
            thermal_time_constant_s: f32::MAX,
            ambient_c: f32::MAX,
            winding_derate_start_c: f32::MAX,
            winding_derate_end_c: f32::MAX,
            stage_derate_start_c: f32::MAX,
            stage_derate_end_c: f32::MAX,
            brake_on_v: f32::MAX,
            brake_off_v: f32::MAX,
            brake_max_on_s: f32::MAX,
        }),
        mechanics: Some(MechanicsRecord {
            inertia_kg_m2: f32::MAX,
            viscous_friction_nm_s_per_rad: f32::MAX,
            coulomb_friction_nm: f32::MAX,
        }),
        joint: Some(JointRecord {
            gear_ratio: f32::MAX,
            rotor_at_zero_rad: f32::MAX,
            travel_out_rad: Some((f32::MIN, f32::MAX)),
            fault_margin_rad: f32::MAX,
            brake_accel_rad_s2: f32::MAX,
            kv_a_per_rad_s: f32::MAX,
            entry_blend_periods: u32::MAX,
            timeout_kd_nm_s_per_rad: f32::MAX,
            max_kp_nm_per_rad: f32::MAX,
            max_kd_nm_s_per_rad: f32::MAX,
        }),
        sensorless: Some(SensorlessRecord {
            start_current_a: f32::MAX,
            bus_voltage_v: f32::MAX,
            beside_sensor: Some(crate::record::BesideRole::HallSensorless),
            observer_above_rad_s: Some(f32::MAX),
        }),
        field: Some(crate::record::FieldRecord {
            mtpa: true,
            field_weakening: true,
            max_id_a: f32::MAX,
            voltage_margin: f32::MAX,
            bandwidth_rad_s: f32::MAX,
            short_circuit: true,
        }),
        // Fixed width: every count takes two bytes whatever its value.
        cogging: Some(crate::record::CoggingRecord {
            enabled: true,
            scale_a: f32::MAX,
            table: crate::record::Counts([i16::MIN; foc_core::control::cogging::COGGING_BINS]),
        }),
        angle_correction: Some(crate::record::CorrectionRecord {
            enabled: true,
            scale_rad: f32::MAX,
            table: crate::record::Counts(
                [i16::MIN; foc_core::control::angle_correction::CORRECTION_BINS],
            ),
        }),
    }
}
