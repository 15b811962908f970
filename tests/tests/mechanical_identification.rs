//! Mechanical identification (foc-core `calibration::mechanics`, the last
//! stage of `calibration::identification`) against the bench plant, for
//! every motor file: the whole identification runs through a real
//! `Cascade` from reset (`foc_bench::identify::run`), so the torque pulses
//! go through the current stage with the bench's sensors (quantised
//! encoder, noisy 12-bit current ADC), dead time and computation delay,
//! and the speed is the controller's own estimate.
//!
//! Requirements (issue 18): inertia within 10 % of the plant's; the
//! friction torque `Fc + B |w|` at the lowest and the highest speed of the
//! fit within 20 % of the plant's; the stage well under 2 s of simulated
//! time.

use foc_bench::identify::{self, config as id_config};
use foc_bench::mission::{Setup, Sim};
use foc_bench::plant::Plant;
use foc_core::calibration::identification::Step;
use foc_core::calibration::CalStep;
use std::path::PathBuf;

fn motor_files() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("motors");
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    v.sort();
    v
}

/// Simulated time a stage may take \[s\].
const STAGE_TIME_LIMIT_S: f64 = 2.0;

#[test]
fn identifies_inertia_and_friction_of_every_motor_file() {
    let mut report = String::new();
    let mut failures = Vec::new();
    for path in motor_files() {
        let s = Setup::load(&path).unwrap();
        let plant = Plant::new(s.motor, s.bench);
        let mut sim = Sim::with_plant(&s, plant, s.unidentified_config(), false);
        let cfg = id_config(&s, s.motor.pole_pairs);
        assert!(cfg.measure_mechanics, "{}", s.name);
        let mut stage_periods = 0usize;
        let out = identify::run(&mut sim, &s, cfg, &mut |sim| {
            if sim.cascade.lifecycle().identification_step() == Some(Step::Mechanics) {
                stage_periods += 1;
            }
        })
        .unwrap_or_else(|e| panic!("{}: {e}", s.name));
        let CalStep::Done(done) = out.step else {
            panic!("{}: {:?} in {:?}", s.name, out.step, out.stage)
        };
        let r = done
            .result
            .mechanics
            .unwrap_or_else(|| panic!("{}: no mechanical result", s.name));
        let m = s.motor;
        let stage_s = stage_periods as f64 / s.pwm_hz() as f64;
        let friction = |w: f64| m.coulomb_friction_nm + m.viscous_friction_nm_s_per_rad * w;
        let e_j = r.inertia_kg_m2 as f64 / m.inertia_kg_m2 - 1.0;
        let [lo, hi] = r.speeds_rad_s;
        let e_lo = r.friction_nm(lo) as f64 / friction(lo as f64) - 1.0;
        let e_hi = r.friction_nm(hi) as f64 / friction(hi as f64) - 1.0;
        let line = format!(
            "{}: J {:.4e} (plant {:.4e}, {:+.2} %), B {:.3e} (plant {:.3e}), Fc {:.4e} (plant {:.4e}), \
             friction {:+.2} % at {lo:.1} rad/s, {:+.2} % at {hi:.1} rad/s, {} rows, stage {stage_s:.2} s",
            s.name,
            r.inertia_kg_m2,
            m.inertia_kg_m2,
            100.0 * e_j,
            r.viscous_friction_nm_s_per_rad,
            m.viscous_friction_nm_s_per_rad,
            r.coulomb_friction_nm,
            m.coulomb_friction_nm,
            100.0 * e_lo,
            100.0 * e_hi,
            r.rows,
        );
        println!("{line}");
        report.push_str(&line);
        report.push('\n');
        if e_j.abs() >= 0.10 {
            failures.push(format!("{}: inertia {:+.2} %", s.name, 100.0 * e_j));
        }
        if e_lo.abs() >= 0.20 || e_hi.abs() >= 0.20 {
            failures.push(format!(
                "{}: friction {:+.2} % / {:+.2} %",
                s.name,
                100.0 * e_lo,
                100.0 * e_hi
            ));
        }
        if stage_s >= STAGE_TIME_LIMIT_S {
            failures.push(format!("{}: stage took {stage_s:.2} s", s.name));
        }
        // The mechanical step ends with the rotor (nearly) still.
        let w_end = sim.plant.omega_m_rad_s().abs();
        assert!(
            w_end <= 0.2 * hi as f64,
            "{}: {w_end} rad/s at the end",
            s.name
        );
    }
    let out =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/mechanical_identification.txt");
    let _ = std::fs::write(out, report);
    assert!(failures.is_empty(), "{failures:#?}");
}
