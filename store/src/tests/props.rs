//! Property tests: round trips through the envelope, the store, TOML and
//! the settings; decode never panics.

use crate::fake::FakeFlash;
use crate::record::{
    AngleRecord, CoggingRecord, CorrectionRecord, Counts, CurrentGainsRecord, DividersRecord,
    DriveRecord, JointRecord, Label, LimitsRecord, MechanicsRecord, MotorRecord, PositionRecord,
    PowerRecord, SensorlessRecord, SpeedRecord, WatchdogReaction, WatchdogRecord, MAX_RECORD_BYTES,
};
use crate::settings::Settings;
use crate::store::Store;
use core::f32::consts::TAU;
use foc_core::control::MotorParams;
use foc_core::drive::cascade::CascadeConfig;
use proptest::prelude::*;

fn pos() -> impl Strategy<Value = f32> {
    prop_oneof![1e-6f32..1e-3, 1e-3f32..10.0, 10.0f32..1e6]
}

fn non_neg() -> impl Strategy<Value = f32> {
    prop_oneof![Just(0.0f32), pos()]
}

/// A limit: `>= 0` or `inf` (off).
fn limit() -> impl Strategy<Value = f32> {
    prop_oneof![non_neg(), Just(f32::INFINITY)]
}

/// An ordered window `(start, end)`; `end` may be `inf` (off).
fn window(lo: f32, hi: f32) -> impl Strategy<Value = (f32, f32)> {
    (lo..hi, prop_oneof![0.0f32..(hi - lo), Just(f32::INFINITY)])
        .prop_map(|(start, width)| (start, start + width))
}

prop_compose! {
    fn power()(
        regen in window(1.0, 100.0),
        limits in (limit(), limit(), limit(), limit()),
        id_max in limit(),
        brake_max in limit(),
        thermal in (pos(), non_neg(), -40.0f32..60.0),
        winding in window(-40.0, 300.0),
        stage in window(-40.0, 300.0),
        brake in window(1.0, 100.0),
    ) -> PowerRecord {
        PowerRecord {
            regen_start_v: regen.0, regen_end_v: regen.1, regen_id_max_a: id_max,
            bus_current_motoring_max_a: limits.0, bus_current_regen_max_a: limits.1,
            power_motoring_max_w: limits.2, power_regen_max_w: limits.3,
            thermal_resistance_k_per_w: thermal.0, thermal_time_constant_s: thermal.1,
            ambient_c: thermal.2,
            winding_derate_start_c: winding.0, winding_derate_end_c: winding.1,
            stage_derate_start_c: stage.0, stage_derate_end_c: stage.1,
            brake_off_v: brake.0, brake_on_v: brake.1, brake_max_on_s: brake_max,
        }
    }
}

/// Plausible mechanics: inertias over the whole accepted range (bounds
/// included), frictions from 0 to their bounds.
fn mechanics() -> impl Strategy<Value = MechanicsRecord> {
    (
        prop_oneof![
            Just(1e-9f32),
            1e-9f32..1e-6,
            1e-6f32..1e-3,
            1e-3f32..10.0,
            Just(10.0f32)
        ],
        prop_oneof![
            Just(0.0f32),
            0.0f32..1e-3,
            0.0f32..=MechanicsRecord::MAX_VISCOUS_FRICTION_NM_S_PER_RAD
        ],
        prop_oneof![
            Just(0.0f32),
            0.0f32..0.1,
            0.0f32..=MechanicsRecord::MAX_COULOMB_FRICTION_NM
        ],
    )
        .prop_map(|(j, b, c)| MechanicsRecord {
            inertia_kg_m2: j,
            viscous_friction_nm_s_per_rad: b,
            coulomb_friction_nm: c,
        })
}

prop_compose! {
    /// A plausible joint: gear ratios of either sign over the whole
    /// accepted range (bounds included), a home offset, a travel range or
    /// none, the soft stop, the entry blend, the timeout damping and the
    /// impedance maxima.
    fn joint()(
        gear_ratio in prop_oneof![
            Just(0.01f32), Just(-10_000.0f32), 0.01f32..=10_000.0, -10_000.0f32..=-0.01, Just(1.0f32)
        ],
        rotor_at_zero_rad in prop_oneof![Just(0.0f32), -100.0f32..100.0],
        range in proptest::option::of((-100.0f32..100.0, 0.1f32..200.0)),
        soft_stop in (non_neg(), pos(), pos()),
        entry_blend_periods in 0..=foc_core::control::joint::JointConfig::MAX_ENTRY_BLEND_PERIODS,
        timeout_kd_nm_s_per_rad in non_neg(),
        maxima in (non_neg(), non_neg()),
    ) -> JointRecord {
        JointRecord {
            gear_ratio,
            rotor_at_zero_rad,
            travel_out_rad: range.map(|(lo, width)| (lo, lo + width)),
            fault_margin_rad: soft_stop.0,
            brake_accel_rad_s2: soft_stop.1,
            kv_a_per_rad_s: soft_stop.2,
            entry_blend_periods,
            timeout_kd_nm_s_per_rad,
            max_kp_nm_per_rad: maxima.0,
            max_kd_nm_s_per_rad: maxima.1,
        }
    }
}

/// A valid `[field]` table or none (boxed: the record's strategy is deep
/// enough without it). Field weakening only where foc-core's rule takes
/// it (a current, a bandwidth, a voltage margin).
fn field() -> BoxedStrategy<Option<crate::record::FieldRecord>> {
    proptest::option::of((any::<[bool; 3]>(), 0.0f32..1e5, 0.0f32..=0.5, 0.0f32..1e5))
        .prop_map(|f| {
            f.map(
                |([mtpa, fw, sc], max_id_a, voltage_margin, bandwidth_rad_s)| {
                    let f = crate::record::FieldRecord {
                        mtpa,
                        field_weakening: fw,
                        max_id_a,
                        voltage_margin,
                        bandwidth_rad_s,
                        short_circuit: sc,
                    };
                    crate::record::FieldRecord {
                        field_weakening: fw && f.to_config().check().is_ok(),
                        ..f
                    }
                },
            )
        })
        .boxed()
}

/// A table's switch, its peak as a share of what the check takes
/// (below 1) and `n` counts.
fn table(n: usize) -> BoxedStrategy<Option<(bool, f32, std::vec::Vec<i16>)>> {
    proptest::option::of((
        any::<bool>(),
        prop_oneof![Just(0.0f32), 0.0f32..0.99],
        proptest::collection::vec(-32767i16..=32767, n),
    ))
    .boxed()
}

/// Valid tables for a current limit `max_current_a`: the anticogging map
/// (its peak within the limit) and the angle correction (within
/// foc-core's bound), or none.
fn tables(
    cogging: Option<(bool, f32, std::vec::Vec<i16>)>,
    correction: Option<(bool, f32, std::vec::Vec<i16>)>,
    max_current_a: f32,
) -> (Option<CoggingRecord>, Option<CorrectionRecord>) {
    use foc_core::control::angle_correction::MAX_CORRECTION_RAD;
    (
        cogging.map(|(enabled, share, t)| CoggingRecord {
            enabled,
            scale_a: max_current_a * share / 32767.0,
            table: Counts::from_slice(&t).unwrap(),
        }),
        correction.map(|(enabled, share, t)| CorrectionRecord {
            enabled,
            scale_rad: MAX_CORRECTION_RAD * share / 32767.0,
            table: Counts::from_slice(&t).unwrap(),
        }),
    )
}

fn label() -> impl Strategy<Value = Label> {
    "[ -~]{0,32}".prop_map(|s| Label::try_from(s.as_str()).unwrap())
}

fn reaction() -> impl Strategy<Value = WatchdogReaction> {
    prop_oneof![
        Just(WatchdogReaction::Disable),
        Just(WatchdogReaction::Stop),
        Just(WatchdogReaction::Hold)
    ]
}

/// [`valid_record_tree`] boxed: its value tree is large, and a test takes
/// two of them (the test thread's stack).
fn valid_record() -> BoxedStrategy<DriveRecord> {
    valid_record_tree().boxed()
}

prop_compose! {
    fn valid_record_tree()(
        label in label(),
        pwm in 1u32..200_000,
        pole_pairs in 1u8..=50,
        motor in (pos(), pos(), pos(), non_neg()),
        gains in (pos(), pos(), pos(), pos()),
        cal in proptest::option::of((0.0f32..TAU, any::<bool>(), any::<u32>())),
        lim in (pos(), pos(), -1e4f32..0.0, 0.0f32..1e4, non_neg(), non_neg()),
        speed in (non_neg(), non_neg()),
        position in (pos(), 0.0f32..=1.0, pos()),
        dividers in (1u16.., 1u16..),
        watchdog in (any::<u32>(), reaction()),
        power in proptest::option::of(power()),
        mechanics in proptest::option::of(mechanics()),
        joint in proptest::option::of(joint()),
        sensorless in proptest::option::of((0.0f32..=1.0, 1.0f32..=1000.0)),
        field in field(),
        cogging in table(foc_core::control::cogging::COGGING_BINS),
        correction in table(foc_core::control::angle_correction::CORRECTION_BINS),
    ) -> DriveRecord {
        let (cogging, angle_correction) = tables(cogging, correction, lim.0);
        // Mechanics need a torque constant (flux > 0); sensorless needs
        // them (the build's have none here).
        let mechanics = mechanics.filter(|_| motor.3 > 0.0);
        let sensorless = sensorless.filter(|_| {
            mechanics.is_some() && joint.is_none_or(|j: JointRecord| j.travel_out_rad.is_none())
        });
        DriveRecord {
            label,
            pwm_frequency_hz: pwm,
            motor: MotorRecord { pole_pairs, r_ohm: motor.0, ld_h: motor.1, lq_h: motor.2, flux_linkage_wb: motor.3 },
            current_gains: CurrentGainsRecord {
                kp_d_v_per_a: gains.0, ki_d_v_per_a_s: gains.1, kp_q_v_per_a: gains.2, ki_q_v_per_a_s: gains.3,
            },
            calibration: cal.map(|(z, reversed, counts)| AngleRecord {
                zero_offset_e_rad: z, reversed, pole_pairs, sensor_counts_per_rev: counts,
                sensorless_only: reversed && counts == 0,
            }),
            limits: LimitsRecord {
                max_current_a: lim.0, max_velocity_rad_s: lim.1,
                min_position_rad: lim.2, max_position_rad: lim.3 + 1.0,
                max_open_loop_voltage_v: lim.4, max_open_loop_omega_e_rad_s: lim.5,
            },
            speed: SpeedRecord { kp_a_per_rad_s: speed.0, ki_a_per_rad: speed.1 },
            position: PositionRecord {
                kp_per_s: position.0,
                // A fraction of the limit, but never 0.
                max_velocity_rad_s: (lim.1 * position.1).max(lim.1 * 1e-3),
                max_acceleration_rad_s2: position.2,
            },
            dividers: DividersRecord { speed: dividers.0, position: dividers.1 },
            watchdog: WatchdogRecord { timeout_periods: watchdog.0, reaction: watchdog.1 },
            power,
            mechanics,
            joint,
            // A share of the current limit (never 0).
            sensorless: sensorless.map(|(share, bus)| SensorlessRecord {
                start_current_a: (lim.0 * share).max(lim.0 * 1e-3),
                bus_voltage_v: bus,
                beside_sensor: None,
                observer_above_rad_s: None,
            }),
            field,
            cogging,
            angle_correction,
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    #[test]
    fn valid_records_round_trip_through_the_envelope(r in valid_record()) {
        prop_assert_eq!(r.validate(), Ok(()));
        let mut buf = [0u8; MAX_RECORD_BYTES];
        let n = r.encode(&mut buf).unwrap();
        prop_assert_eq!(DriveRecord::decode(&buf[..n]), Ok(r));
    }

    #[test]
    fn valid_records_round_trip_through_the_store(r in valid_record(), other in valid_record()) {
        let mut f = FakeFlash::<2, 8192, 4>::new();
        let mut s = Store::new(&mut f, 0..16384).unwrap();
        s.save(&other).unwrap();
        s.save(&r).unwrap();
        prop_assert_eq!(s.load(), Ok(Some(r.clone())));
        let _ = s.into_flash();
        prop_assert_eq!(Store::new(&mut f, 0..16384).unwrap().load(), Ok(Some(r)));
    }

    #[test]
    fn valid_records_round_trip_through_toml(r in valid_record()) {
        let text = crate::text::to_toml(&r);
        prop_assert_eq!(crate::text::from_toml(&text), Ok(r), "{}", text);
    }

    #[test]
    fn decode_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        let _ = DriveRecord::decode(&bytes);
    }

    #[test]
    fn decode_of_a_mutated_envelope_never_panics(r in valid_record(), at in any::<usize>(), byte in any::<u8>()) {
        let mut buf = [0u8; MAX_RECORD_BYTES];
        let n = r.encode(&mut buf).unwrap();
        buf[at % n] = byte;
        if let Ok(d) = DriveRecord::decode(&buf[..n]) {
            // Only the unchanged byte decodes.
            prop_assert_eq!(d, r);
        }
    }

    #[test]
    fn settings_round_trip_through_a_record(
        pole_pairs in 1u8..=30,
        r_ohm in 0.01f32..10.0,
        ld_h in 1e-5f32..1e-2,
        lq_ratio in 1.0f32..3.0,
        flux in 1e-4f32..0.1,
        pwm in prop_oneof![Just(8_000u32), Just(16_000), Just(20_000), Just(40_000)],
        max_current_a in 0.5f32..50.0,
        calibrated in any::<bool>(),
        zero_offset_e_rad in 0.02f32..TAU,
        reversed in any::<bool>(),
        counts in any::<u32>(),
        watchdog in (any::<u32>(), reaction()),
        mechanics in proptest::option::of(mechanics()),
        joint in proptest::option::of(joint()),
    ) {
        let motor = MotorParams { pole_pairs, r_ohm, ld_h, lq_h: ld_h * lq_ratio, flux_linkage_wb: flux };
        let build = CascadeConfig::for_motor(motor, pwm as f32, max_current_a);
        let mut s = Settings::from_cascade(&build);
        s.watchdog = WatchdogRecord { timeout_periods: watchdog.0, reaction: watchdog.1 };
        let base = s;
        // Identified mechanics, on a base without any.
        let mechanics = mechanics.map(|m| m.to_mechanics());
        if let Some(m) = &mechanics {
            prop_assert!(s.set_mechanics(m));
        }
        // A joint set up by the user (else the build's).
        if let Some(j) = &joint {
            s.joint = j.to_setup().unwrap();
            s.limits = j.limits(&crate::record::LimitsRecord::from_limits(&s.limits));
        }
        if calibrated {
            s.calibrated = true;
            s.angle.zero_offset = crate::record::e_rad_to_angle(zero_offset_e_rad);
            s.angle.reversed = reversed;
            s.angle.sensor_counts_per_rev = counts;
            prop_assert!(s.permit().is_some());
        } else {
            prop_assert!(s.permit().is_none());
        }
        let r = DriveRecord::from_settings(&Label::try_from("x").unwrap(), pwm, &s);
        prop_assert_eq!(r.calibration.is_some(), calibrated);
        prop_assert_eq!(r.mechanics.map(|m| m.to_mechanics()), mechanics);
        if let Some(j) = joint {
            prop_assert_eq!(r.joint, Some(j));
        }
        prop_assert_eq!(r.apply(&base, pwm), Ok(s));
        // Applied on itself too (what a reload at start-up does).
        prop_assert_eq!(r.apply(&s, pwm), Ok(s));
        prop_assert_eq!(DriveRecord::from_settings(&r.label, pwm, &s), r);
        // The configuration the drive runs: the settings in force, the
        // mechanics installed by foc-core.
        let c = s.apply_to(&build);
        prop_assert_eq!(c.mechanics, mechanics);
        // The stage's position range: the travel range in the rotor frame
        // (the limits' own without one), and the joint settings.
        let j = s.joint.rotor_change((s.limits.min_position_rad, s.limits.max_position_rad));
        prop_assert_eq!(
            (c.current.limits.min_position_rad, c.current.limits.max_position_rad),
            (j.min_position_rad, j.max_position_rad)
        );
        prop_assert_eq!(c.current.joint, j.joint);
        prop_assert_eq!(c.current.field, s.field);
        prop_assert_eq!(c.current.limits.max_kp_nm_per_rad, s.limits.max_kp_nm_per_rad);
        let back = Settings::from_cascade(&c);
        prop_assert_eq!((back.speed, back.position, back.mechanics), (s.speed, s.position, s.mechanics));
        if let Some(m) = &mechanics {
            let mut derived = build;
            prop_assert!(derived.set_mechanics(m));
            prop_assert_eq!(c.current.observer, derived.current.observer);
            prop_assert_eq!(c.position.accel_ff_a_per_rad_s2, derived.position.accel_ff_a_per_rad_s2);
        }
    }

    #[test]
    fn joint_values_out_of_range_are_refused_whole(
        r in valid_record(),
        j in joint(),
        range in (-100.0f32..100.0, 0.1f32..200.0),
        which in 0usize..8,
        bad in prop_oneof![Just(f32::NAN), Just(f32::INFINITY), Just(f32::NEG_INFINITY)],
    ) {
        let mut r = r;
        let mut j = j;
        // With a travel range, so the soft stop is checked too.
        j.travel_out_rad = Some((range.0, range.0 + range.1));
        let field = match which {
            0 => { j.gear_ratio = bad; "joint.gear_ratio" }
            1 => { j.rotor_at_zero_rad = bad; "joint.rotor_at_zero_rad" }
            2 => { j.fault_margin_rad = bad; "joint.fault_margin_rad" }
            3 => { j.brake_accel_rad_s2 = bad; "joint.brake_accel_rad_s2" }
            4 => { j.kv_a_per_rad_s = bad; "joint.kv_a_per_rad_s" }
            5 => { j.timeout_kd_nm_s_per_rad = bad; "joint.timeout_kd_nm_s_per_rad" }
            6 => { j.max_kp_nm_per_rad = bad; "joint.max_kp_nm_per_rad" }
            _ => { j.max_kd_nm_s_per_rad = bad; "joint.max_kd_nm_s_per_rad" }
        };
        r.joint = Some(j);
        prop_assert_eq!(r.validate(), Err(crate::Invalid { field }));
        let base = Settings::from_cascade(&CascadeConfig::for_motor(
            r.motor.to_params(), r.pwm_frequency_hz as f32, 5.0,
        ));
        prop_assert_eq!(r.apply(&base, r.pwm_frequency_hz), Err(crate::Invalid { field }));
        prop_assert!(crate::text::from_toml(&crate::text::to_toml(&r)).unwrap_err().contains(field));
    }

    #[test]
    fn mechanics_out_of_range_are_refused_whole(
        r in valid_record(),
        m in mechanics(),
        which in 0usize..3,
        bad in prop_oneof![
            Just(f32::NAN), Just(f32::INFINITY), Just(f32::NEG_INFINITY),
            -1e6f32..0.0, 1e4f32..1e30,
        ],
    ) {
        let mut r = r;
        r.motor.flux_linkage_wb = r.motor.flux_linkage_wb.max(1e-3);
        let mut m = m;
        let field = match which {
            0 => { m.inertia_kg_m2 = bad; "mechanics.inertia_kg_m2" }
            1 => { m.viscous_friction_nm_s_per_rad = bad; "mechanics.viscous_friction_nm_s_per_rad" }
            _ => { m.coulomb_friction_nm = bad; "mechanics.coulomb_friction_nm" }
        };
        r.mechanics = Some(m);
        prop_assert_eq!(r.validate(), Err(crate::Invalid { field }));
        let base = Settings::from_cascade(&CascadeConfig::for_motor(
            r.motor.to_params(), r.pwm_frequency_hz as f32, 5.0,
        ));
        prop_assert_eq!(r.apply(&base, r.pwm_frequency_hz), Err(crate::Invalid { field }));
        prop_assert!(crate::text::from_toml(&crate::text::to_toml(&r)).unwrap_err().contains(field));
    }
}
