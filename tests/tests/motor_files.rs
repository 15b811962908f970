//! Every file in tests/motors/ loads, validates and runs in the plant.

// `Real` is f64 or f32 by feature: a cast to or from it is a no-op in one of the two.
#![allow(clippy::unnecessary_cast)]

use foc_bench::motor_file::MotorFile;
use foc_bench::plant::{Mechanics, Plant};

#[test]
fn every_motor_file_loads_and_simulates() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("motors");
    let mut names = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) != Some("toml") {
            continue;
        }
        let f = MotorFile::load(&path).unwrap_or_else(|e| panic!("{e}"));
        assert!(f.source.len() > 20, "{}: source too vague", path.display());
        let m = f.motor_params();
        m.validate().unwrap();
        // Locked-rotor DC: 5 % duty difference gives V/R within 1 %.
        let mut cfg = f.bench_config();
        cfg.compute_delay_periods = 0;
        let mut p = Plant::new(m, cfg);
        p.set_mechanics(Mechanics::Locked);
        let delta = 0.1 * f.rated_current_a * f.r_ohm / f.bus_voltage_v;
        let d = [
            0.5 + delta as f32,
            0.5 - delta as f32 / 2.0,
            0.5 - delta as f32 / 2.0,
        ];
        let tau = f.ld_h.max(f.lq_h) / f.r_ohm;
        let periods = (12.0 * tau * f.pwm_frequency_hz) as usize + 10;
        for _ in 0..periods {
            p.step_period(d, true, 0.0);
        }
        let expected = f.bus_voltage_v * (delta as f32 as f64) / f.r_ohm;
        let ia = p.phase_currents_a()[0];
        assert!(
            (ia - expected).abs() < 0.01 * expected,
            "{}: {ia} vs {expected}",
            f.name
        );
        names.push(f.name);
    }
    assert!(
        names.len() >= 4,
        "expected at least 4 motor files, found {names:?}"
    );
    assert!(names.iter().any(|n| n.starts_with("M153")));
}

#[test]
fn every_motor_file_states_its_imperfections() {
    let files = foc_bench::motor_file::all_motor_files();
    assert!(files.len() >= 6, "{files:?}");
    for path in files {
        let f = MotorFile::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let imp = f.imperfections();
        let who = &f.name;
        // Every file gives every imperfection, and says it is assumed.
        for field in [
            "slots",
            "cogging_torque_nm",
            "sensor_first_harmonic_rad",
            "dead_time_ns",
        ] {
            assert!(
                f.assumed.iter().any(|a| a.contains(field)),
                "{who}: `{field}` not in `assumed`"
            );
        }
        let c = imp.cogging.unwrap_or_else(|| panic!("{who}: no cogging"));
        c.validate().unwrap();
        let (slots, poles) = (f.slots.unwrap(), 2 * f.pole_pairs as u32);
        assert!(c.cycles_per_turn.is_multiple_of(slots) && c.cycles_per_turn.is_multiple_of(poles));
        let rated_nm = 1.5 * f.pole_pairs as f64 * f.flux_linkage_wb() * f.rated_current_a;
        let share = c.amplitude_nm as f64 / rated_nm;
        assert!(
            (0.003..=0.04).contains(&share),
            "{who}: cogging {share} of rated"
        );
        assert!(imp.dead_time_s > 0.0 && imp.dead_time_s < 1.01e-6, "{who}");
        // A sensor with counts to resolve it has an error; a hall-like one not.
        match imp.sensor_error {
            Some(e) => e.validate().unwrap(),
            None => assert!(f.encoder_counts_per_rev < 100, "{who}: no sensor error"),
        }
        // Applied, the plant runs and its cogging shows on the shaft.
        let mut cfg = f.bench_config();
        imp.apply_bench(&mut cfg);
        let mut p = Plant::new(f.motor_params(), cfg);
        imp.apply_plant(&mut p);
        p.set_mechanics(Mechanics::ConstantSpeed(1.0));
        for _ in 0..50 {
            let m = p.step_period([0.5; 3], false, 0.0);
            assert!(m.angle.to_radians().is_finite());
        }
        assert_eq!(p.shaft_torque_nm(), p.cogging_torque_nm(), "{who}");
        assert!(p.cogging_torque_nm().abs() <= c.amplitude_nm * 1.31);
    }
}
