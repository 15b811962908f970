//! Every file in tests/motors/ loads, validates and runs in the plant.

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
