//! With the default configuration (no DC link, no brake, no thermal models)
//! the plant computes bit for bit what it computed before the power-stage
//! models were added: a fingerprint of a few scenarios recorded on the old
//! code, for the f64 and the f32 builds.

// `Real` is f64 or f32 by feature: a cast to or from it is a no-op in one of the two.
#![allow(clippy::unnecessary_cast)]

use foc_plant::plant::{BenchConfig, Faults, MotorParams, Phase, PhaseShort, Plant, PwmMode};

/// A scenario that touches every electrical path: driven bridge with a
/// rotating voltage, dead time, source resistance, carrier comparison, a
/// phase short, then the disabled bridge (diodes) while the rotor spins.
fn fingerprint(mode: PwmMode) -> u64 {
    let cfg = BenchConfig {
        pwm_mode: mode,
        dead_time_s: 300e-9,
        source_resistance_ohm: 0.05,
        ..BenchConfig::default()
    };
    let mut plant = Plant::new(MotorParams::example(), cfg);
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut mix = |x: f64| {
        h ^= x.to_bits();
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    };
    for n in 0..3000u32 {
        let th = plant.theta_e_rad() as f32 + 1.8;
        let a = 0.12f32;
        let duties = [0.0f32, 1.0, 2.0]
            .map(|k| 0.5 + a * libm::cosf(th - k * 2.0 * core::f32::consts::PI / 3.0));
        if n == 1000 {
            plant.faults_mut().phase_short = Some(PhaseShort {
                a: Phase::A,
                b: Phase::B,
                r_ohm: 2.0,
            });
        }
        if n == 1500 {
            *plant.faults_mut() = Faults::default();
            plant.set_speed(900.0);
        }
        let enabled = n < 2000;
        let m = plant.step_period(duties, enabled, 0.01);
        mix(m.v_bus_v as f64);
        mix(m.currents.to_abc().a as f64);
        mix(plant.iq_a() as f64);
        mix(plant.id_a() as f64);
        mix(plant.omega_m_rad_s() as f64);
        mix(plant.v_bus_avg_v() as f64);
        mix(plant.supply_current_a() as f64);
    }
    let e = *plant.energy();
    for x in [
        e.supply_j,
        e.copper_j,
        e.shaft_j,
        e.friction_j,
        e.load_j,
        e.short_j,
    ] {
        mix(x as f64);
    }
    h
}

#[test]
fn default_plant_is_bit_for_bit_unchanged() {
    let got = [
        fingerprint(PwmMode::Averaged),
        fingerprint(PwmMode::CarrierCompared),
    ];
    std::println!("fingerprints: {:#018x} {:#018x}", got[0], got[1]);
    let expected: [u64; 2] = if cfg!(feature = "plant-f32") {
        [0x4182_1319_eaaf_62dd, 0x17aa_dbd3_caaf_62dd]
    } else {
        [0x25f4_ec9d_9332_82ee, 0x3a8b_96a7_3a31_5bb4]
    };
    assert_eq!(got, expected);
}
