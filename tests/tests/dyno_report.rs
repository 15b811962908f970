//! The simulated dynamometer's report (issue 36): each sweep titled by its
//! own sweep, every quantity once, the speed command beside the speed,
//! legends in words, a least span on every plotted axis, the phase current
//! and modulation index measured, a test speed that is checked; and the
//! mission's braking segment sized from the motor file.

// `Real` is f64 or f32 by feature: a cast to or from it is a no-op in one of the two.
#![allow(clippy::unnecessary_cast)]

use foc_bench::dyno::{self, SpeedError, Sweep, TestSpeed};
use foc_bench::mission::{braking_dc_link, Setup};
use foc_bench::report::{DynoHeader, DynoReport, DynoRow};
use foc_core::control::power::PowerLimitsConfig;
use std::path::{Path, PathBuf};

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("foc-bench-dyno-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn motor(file: &str) -> Setup {
    Setup::load(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("motors")
            .join(file),
    )
    .unwrap()
}

fn header() -> DynoHeader {
    DynoHeader {
        motor_model: "M153".into(),
        ..DynoHeader::default()
    }
}

/// A load sweep's rows as the dyno writes them: the speed held within
/// 0.03 rpm of 137 rpm, with its command, the drive's figures and the
/// regenerated energy (no DC link: no bus current).
fn load_rows() -> Vec<DynoRow> {
    (0..=10)
        .map(|k| {
            let t = 3.125 * k as f64;
            let rpm = 137.0 + 0.03 * ((k * 7) % 3) as f64 / 2.0;
            DynoRow::new(26.0, 0.7 * t + 0.2, 18.0 * t + 5.0, rpm, t)
                .with_speed_command(137.0)
                .with_drive(1.37 * t + 0.45, 0.477 + 0.005 * t)
                .with_regen(0.0)
        })
        .collect()
}

/// The numbers among the SVG's text elements (the tick labels, ...).
fn svg_numbers(svg: &str) -> Vec<f64> {
    svg.split('>')
        .filter_map(|s| s.split('<').next())
        .filter_map(|t| t.trim().parse::<f64>().ok())
        .collect()
}

#[test]
fn every_sweep_is_titled_by_its_own_sweep() {
    let rows = load_rows();
    let dir = temp_dir("titles");
    for (sweep, words) in [
        (Sweep::Load, "load sweep"),
        (Sweep::Voltage, "supply-voltage sweep"),
        (Sweep::Regen, "regen sweep"),
    ] {
        let report = DynoReport {
            header: &header(),
            sweep: Some(sweep),
            rows: &rows,
        };
        let [csv, md, svg] = report
            .write(&dir, &format!("dyno-{}", sweep.name()))
            .unwrap();
        let svg = std::fs::read_to_string(svg).unwrap();
        assert!(
            svg.contains(&format!("({words})")),
            "{}: title without `{words}`",
            sweep.name()
        );
        for other in ["load sweep", "supply-voltage sweep", "regen sweep"] {
            if other != words {
                assert!(!svg.contains(&format!("({other})")), "{words}: {other}");
            }
        }
        let md = std::fs::read_to_string(md).unwrap();
        assert!(
            md.starts_with(&format!("# Performance Curve Report ({words})")),
            "{md}"
        );
        let csv = std::fs::read_to_string(csv).unwrap();
        assert!(csv.contains(&format!("# Sweep: {words}")));
    }
}

#[test]
fn a_quantity_is_drawn_and_printed_once() {
    let rows = load_rows();
    let report = DynoReport {
        header: &header(),
        sweep: Some(Sweep::Load),
        rows: &rows,
    };
    // No DC link: the bus current is the supply current, not repeated.
    let headings = report.headings();
    assert!(!headings.contains(&"Bus current [A]"), "{headings:?}");
    let mut unique = headings.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(unique.len(), headings.len(), "{headings:?}");
    let md = report.markdown();
    assert_eq!(md.matches("Supply current [A]").count(), 1);
    assert!(!md.contains("Bus current"));
    let dir = temp_dir("once");
    let [_, _, svg] = report.write(&dir, "dyno-load").unwrap();
    let svg = std::fs::read_to_string(svg).unwrap();
    assert!(!svg.contains("bus current"));
    // Each quantity's legend once (the panels' labels name the axis).
    for legend in [
        "supply current [A]",
        "speed command [rpm]",
        "input power [W]",
    ] {
        assert_eq!(svg.matches(legend).count(), 1, "{legend}");
    }
    // With a DC link the bus current differs and is shown.
    let linked: Vec<DynoRow> = rows.iter().map(|r| r.with_bus(0.9, 0.0)).collect();
    let report = DynoReport {
        header: &header(),
        sweep: Some(Sweep::Load),
        rows: &linked,
    };
    assert!(report.headings().contains(&"Bus current [A]"));
}

#[test]
fn the_command_and_the_drive_figures_are_columns_and_lines() {
    let rows = load_rows();
    let report = DynoReport {
        header: &header(),
        sweep: Some(Sweep::Voltage),
        rows: &rows,
    };
    let headings = report.headings();
    let speed = headings.iter().position(|h| *h == "Speed [rpm]").unwrap();
    assert_eq!(
        headings[speed + 1],
        "Speed command [rpm]",
        "beside the speed"
    );
    assert!(headings.contains(&"Phase current [A peak]"));
    assert!(headings.contains(&"Modulation index"));
    let md = report.markdown();
    assert!(md.contains("Phase current: the amplitude (peak)"));
    assert!(md.contains("sqrt(3) |v| / v_bus"));
    let dir = temp_dir("command");
    let [_, _, svg] = report.write(&dir, "dyno-voltage").unwrap();
    let svg = std::fs::read_to_string(svg).unwrap();
    for legend in [
        "speed command [rpm]",
        "speed [rpm]",
        "phase current [A peak]",
        "modulation index",
        "torque [N m]",
    ] {
        assert!(svg.contains(legend), "{legend} missing");
    }
    // Words, not the CSV-style column names.
    for raw in [
        "speed_rpm",
        "supply_current_a",
        "input_power_w",
        "efficiency_percent",
    ] {
        assert!(!svg.contains(raw), "{raw}");
    }
}

#[test]
fn a_flat_speed_is_drawn_flat() {
    let rows = load_rows();
    let report = DynoReport {
        header: &header(),
        sweep: Some(Sweep::Load),
        rows: &rows,
    };
    let dir = temp_dir("span");
    let [_, _, svg] = report.write(&dir, "dyno-load").unwrap();
    let svg = std::fs::read_to_string(svg).unwrap();
    // The speed panel's tick labels: the numbers near 137 rpm. Autoscaled
    // to the data they would span 0.03 rpm; with the least span (1 % of
    // 137 rpm plus 1 rpm) at least 2 rpm.
    let ticks: Vec<f64> = svg_numbers(&svg)
        .into_iter()
        .filter(|v| (130.0..145.0).contains(v))
        .collect();
    let lo = ticks.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = ticks.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    assert!(hi - lo >= 2.0, "speed ticks {ticks:?}");
    // The rule itself.
    let min = foc_bench::report::dyno_min_span("rpm");
    let (lo, hi) = foc_plot::fit_range_min([137.0, 137.03], min).unwrap();
    assert!(hi - lo >= 0.01 * 137.03 + 1.0, "{lo} {hi}");
}

#[test]
fn the_test_speed_is_checked_and_used() {
    let setup = motor("m153-source.toml");
    let no_load = setup.max_speed_rad_s();
    let e = TestSpeed::new(&setup, 1.2 * no_load).unwrap_err();
    assert!(matches!(e, SpeedError::AboveNoLoad { .. }), "{e:?}");
    let text = e.to_string();
    assert!(text.contains("no-load speed"), "{text}");
    for bad in [0.0, -5.0, f32::NAN] {
        assert!(matches!(
            TestSpeed::new(&setup, bad),
            Err(SpeedError::NotPositive(_))
        ));
    }
    // The defaults as before: half the no-load speed (load, regen), 80 %
    // (voltage, at the nominal bus).
    let half = TestSpeed::default_for(&setup, Sweep::Load).rad_s();
    assert!((half - 0.5 * no_load).abs() < 1e-4);
    let v = TestSpeed::default_for(&setup, Sweep::Voltage).rad_s();
    assert!((v - 0.8 * no_load).abs() < 1e-4);

    // A short regen sweep at a speed of our choosing: the command is the
    // speed asked for, the drive holds it, and the figures are measured.
    let w = 0.3 * no_load;
    let speed = TestSpeed::new(&setup, w).unwrap();
    let run = dyno::run_dyno(&setup, Sweep::Regen, 1, speed, &mut |_| {});
    assert!(run.faults.is_empty(), "{:?}", run.faults);
    assert_eq!(run.rows.len(), 2);
    let cmd_rpm = w as f64 * 60.0 / std::f64::consts::TAU;
    for r in &run.rows {
        let c = r.speed_command_rpm.unwrap();
        assert!((c - cmd_rpm).abs() < 1e-3, "{c} {cmd_rpm}");
        assert!((r.speed_rpm - cmd_rpm).abs() < 0.02 * cmd_rpm, "{r:?}");
        assert!(r.bus_current_a.is_none(), "no DC link: no bus column");
        assert!(r.regen_energy_j.is_some());
    }
    // Without load the voltage is about the back-EMF: p psi w over the
    // linear range v_bus / sqrt 3.
    let m = run.rows[0].modulation_index.unwrap();
    let emf = setup.motor.pole_pairs as f64 * setup.motor.flux_linkage_wb as f64 * w as f64;
    let m_emf = emf / (26.0 / 3f64.sqrt());
    assert!(
        (m - m_emf).abs() < 0.05 * m_emf,
        "m {m}, back-EMF alone {m_emf}"
    );
    // Generating, the resistive drop lowers it.
    assert!(run.rows[1].modulation_index.unwrap() < m);
    // At the rated overhauling torque the phase current is the rated
    // current's (peak) within a few per cent.
    let i = run.rows[1].phase_current_a.unwrap();
    let rated = setup.rated_current_a as f64;
    assert!(
        (i - rated).abs() < 0.05 * rated,
        "{i} A peak, rated {rated}"
    );
    assert!(run.rows[1].torque_nm < 0.0);
    let md = run.report().markdown();
    assert!(md.starts_with("# Performance Curve Report (regen sweep)"));
}

#[test]
fn modulation_index_convention() {
    // Phase voltages of amplitude a v_bus: m = sqrt(3) a; 1 on the
    // inscribed circle (a = 1 / sqrt 3), 0.866 at sine-PWM's limit (a = 1/2).
    for (a, m) in [(1.0 / 3f32.sqrt(), 1.0), (0.5, 0.866_025)] {
        for k in 0..12 {
            let th = k as f32 * 0.5;
            let d = [0.0f32, -2.094_395, 2.094_395].map(|p| 0.5 + a * (th + p).cos());
            assert!((dyno::modulation_index(d) - m).abs() < 1e-5, "{d:?}");
        }
    }
    // The common mode drops out.
    assert!(dyno::modulation_index([0.3, 0.3, 0.3]).abs() < 1e-9);
}

#[test]
fn braking_link_follows_the_motor_file() {
    let rule = |setup: &Setup| {
        let supervisor = setup.cascade_config().current.supervisor;
        let limits = PowerLimitsConfig::for_board(
            &supervisor,
            setup.cascade_config().current.current.motor,
            false,
        )
        .with_brake_resistor();
        (braking_dc_link(setup, &supervisor), limits)
    };
    for file in foc_bench::motor_file::all_motor_files() {
        let setup = Setup::load(&file).unwrap();
        let (link, limits) = rule(&setup);
        link.validate().unwrap();
        let v_bus = setup.bench.bus_voltage_v as f64;
        let v_ov = setup.cascade_config().current.supervisor.bus_over_voltage_v as f64;
        let (v_on, v_end) = (limits.brake_on_v as f64, limits.regen_end_v as f64);
        let (c, r) = (link.c_f as f64, link.brake_resistor_ohm.unwrap() as f64);
        let i_max = setup.max_current_a as f64;
        let t_pwm = 1.0 / setup.bench.pwm_frequency_hz as f64;
        // The bus's time constant on the regen ramp at least 10 periods.
        let tau = c * (v_end - v_on) / i_max;
        assert!(tau >= 10.0 * t_pwm * (1.0 - 1e-6), "{file:?}: {tau} s");
        // The winding's energy at the maximum current fits between V_on
        // and V_ov.
        let l = (setup.motor.ld_h as f64).max(setup.motor.lq_h as f64);
        let e_winding = 0.75 * l * i_max * i_max;
        let e_cap = 0.5 * c * (v_ov * v_ov - v_on * v_on);
        assert!(e_cap >= e_winding * (1.0 - 1e-6), "{file:?}");
        // No larger than the larger need.
        assert!(
            (tau / (10.0 * t_pwm) - 1.0).abs() < 1e-6 || (e_cap / e_winding - 1.0).abs() < 1e-6,
            "{file:?}"
        );
        // PWM ripple at the maximum current below 1 %.
        assert!(i_max * t_pwm / (8.0 * c) < 0.01 * v_bus, "{file:?}");
        // The resistor: the rated current at the chopper's switch-on voltage.
        assert!(
            (v_on / r - setup.rated_current_a as f64).abs() < 1e-3,
            "{file:?}"
        );
        assert!((link.v_source_v as f64 - v_bus).abs() < 1e-9);
    }
    // The 540 V, 2.2 kW interior-PM drive: a couple of hundred uF and
    // about a hundred ohms (3.5 kW at the switch-on voltage), as such
    // drives have; not the ODrive's 1880 uF and 2 ohm (which would take
    // 290 A, 165 kW, at 574 V).
    let (ipm, limits) = rule(&motor("ipm-2k2-540v.toml"));
    let v_on = limits.brake_on_v as f64;
    let (c, r) = (ipm.c_f as f64, ipm.brake_resistor_ohm.unwrap() as f64);
    assert!((100e-6..500e-6).contains(&c), "{c} F");
    assert!((50.0..300.0).contains(&r), "{r} ohm");
    let p = v_on * v_on / r;
    assert!((2.2e3..6.6e3).contains(&p), "{p} W at {v_on} V");
    // M153 (26 V, 60 A max, 42 A rated): 12.3 mF, a resistor sized for
    // its rated current.
    let (m153, _) = rule(&motor("m153-source.toml"));
    let c = m153.c_f as f64;
    assert!((c - 12.31e-3).abs() < 0.01e-3, "{c} F");
    assert!((m153.brake_resistor_ohm.unwrap() as f64 - 0.658).abs() < 0.001);
}
