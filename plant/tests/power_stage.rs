//! DC link, brake chopper and thermal models of `foc_plant::power`, driven
//! open loop (no controller here): the duties put a chosen dq voltage on
//! the rotor angle the plant knows.

// `Real` is f64 or f32 by feature: a cast to or from it is a no-op in one of the two.
#![allow(clippy::unnecessary_cast)]

use core::cell::RefCell;
use foc_core::hal::BusVoltage;
use foc_plant::adapters::{BenchPwm, BenchSensors};
use foc_plant::plant::{BenchConfig, Mechanics, MotorParams, Plant};
use foc_plant::power::{DcLinkConfig, SourceKind, StageThermal, WindingThermal};
use foc_plant::real::{self, Real, TWO_PI_3};

/// Duties that put `(vd, vq)` \[V\] on the rotor, one period ahead (the
/// plant applies duties one period late and holds them for a period).
fn dq_duties(plant: &Plant, vd: Real, vq: Real) -> [f32; 3] {
    let t = plant.config().period_s();
    let th = plant.theta_e_rad() + 1.5 * plant.omega_e_rad_s() * t;
    let v_bus = plant.v_bus_v();
    [0.0, TWO_PI_3, -TWO_PI_3].map(|phi| {
        let v = vd * real::cos(th - phi) - vq * real::sin(th - phi);
        (0.5 + v / v_bus) as f32
    })
}

/// Back-EMF amplitude `w_e psi` \[V\].
fn back_emf(plant: &Plant) -> Real {
    plant.omega_e_rad_s() * plant.motor().flux_linkage_wb
}

fn plant_with(dc: Option<DcLinkConfig>) -> Plant {
    let mut plant = Plant::new(MotorParams::example(), BenchConfig::default());
    plant.set_dc_link(dc);
    plant
}

/// Regenerate from `w0` [rad/s] for `periods` with `vq = 0.5 E` (negative
/// torque) and return the highest bus voltage seen.
fn regen_peak(plant: &mut Plant, w0: Real, periods: u32) -> Real {
    plant.set_speed(w0);
    let mut peak: Real = 0.0;
    for _ in 0..periods {
        let d = dq_duties(plant, 0.0, 0.5 * back_emf(plant));
        plant.step_period(d, true, 0.0);
        peak = peak.max(plant.v_bus_v());
    }
    peak
}

#[test]
fn default_plant_has_no_power_stage_models() {
    let mut plant = Plant::new(MotorParams::example(), BenchConfig::default());
    assert!(plant.dc_link().is_none());
    assert!(plant.winding_temperature_c().is_none());
    assert!(plant.stage_temperature_c().is_none());
    assert_eq!(plant.capacitor_energy_j(), 0.0);
    plant.set_brake(true); // recorded, draws nothing without a DC link
    let m = plant.step_period([0.6, 0.45, 0.45], true, 0.0);
    assert_eq!(m.stage_temperature_c, None);
    assert_eq!(plant.energy().brake_j, 0.0);
    assert_eq!(plant.source_current_a(), plant.inverter_current_a());
    assert_eq!(plant.winding_resistance_ohm(), plant.motor().r_ohm);
}

#[test]
fn energy_balance_motoring_then_braking_into_a_non_sinking_link() {
    let motor = MotorParams {
        coulomb_friction_nm: 0.002,
        ..MotorParams::example()
    };
    let mut plant = Plant::new(motor, BenchConfig::default());
    plant.set_dc_link(Some(DcLinkConfig::odrive_v3().bench_supply(24.0, 15.0)));
    let ke0 = plant.kinetic_energy_j();
    let em0 = plant.magnetic_energy_j();
    let ec0 = plant.capacitor_energy_j();
    let mut v_peak: Real = 0.0;
    let mut braked = false;
    // 0.15 s motoring at vq = 4 V with a light load, then 0.15 s braking
    // (vq = 0.3 E) with the chopper on above 30 V and off below 28 V.
    for n in 0..4500 {
        let (vq, load) = if n < 2250 {
            (4.0, 0.005)
        } else {
            (0.3 * back_emf(&plant), 0.0)
        };
        if plant.v_bus_v() > 30.0 {
            plant.set_brake(true);
            braked = true;
        } else if plant.v_bus_v() < 28.0 {
            plant.set_brake(false);
        }
        let d = dq_duties(&plant, 0.0, vq);
        plant.step_period(d, true, load);
        v_peak = v_peak.max(plant.v_bus_v());
        assert!(plant.source_current_a() >= -1e-6);
    }
    assert!(braked, "the bus never reached the chopper threshold");
    let e = *plant.energy();
    let d_ke = plant.kinetic_energy_j() - ke0;
    let d_em = plant.magnetic_energy_j() - em0;
    let d_cap = plant.capacitor_energy_j() - ec0;
    let source = e.source_out_j - e.source_in_j;
    let sinks = e.copper_j + e.friction_j + e.load_j + d_ke + d_em + d_cap + e.esr_j + e.brake_j;
    let scale = e.source_out_j + e.brake_j + e.copper_j;
    let err = (source - sinks).abs() / scale;
    std::println!(
        "source {source:.6} J, sinks {sinks:.6} J (copper {:.4}, friction {:.4}, load {:.4}, \
         kinetic {d_ke:.6}, magnetic {d_em:.6}, capacitor {d_cap:.6}, esr {:.6}, brake {:.4}); \
         relative error {err:.3e}; capacitor integral {:.6} vs state {d_cap:.6}; bus peak {v_peak:.2} V",
        e.copper_j, e.friction_j, e.load_j, e.esr_j, e.brake_j, e.capacitor_j
    );
    assert_eq!(
        e.source_in_j, 0.0,
        "a non-sinking source takes nothing back"
    );
    assert!(e.brake_j > 0.1, "brake energy {}", e.brake_j);
    let tol = if cfg!(feature = "plant-f32") {
        2e-3
    } else {
        1e-6
    };
    assert!(err < tol, "energy balance error {err:e}");
    // The bus side alone: source = capacitor + ESR + brake + inverter.
    let bus_err = (source - (e.capacitor_j + e.esr_j + e.brake_j + e.supply_j)).abs() / scale;
    assert!(bus_err < tol, "bus balance error {bus_err:e}");
    // The capacitor integral matches its state.
    assert!((e.capacitor_j - d_cap).abs() / scale < tol);
}

#[test]
fn regeneration_charges_a_non_sinking_link_and_not_a_sinking_one() {
    let board = DcLinkConfig::odrive_v3();
    let mut non_sinking = plant_with(Some(board.bench_supply(24.0, 10.0)));
    let peak_ns = regen_peak(&mut non_sinking, 500.0, 600);
    let mut sinking = plant_with(Some(board.battery(24.0, 0.02)));
    let peak_s = regen_peak(&mut sinking, 500.0, 600);
    std::println!("bus peak: non-sinking {peak_ns:.2} V, sinking {peak_s:.2} V");
    assert!(peak_ns > 30.0, "non-sinking peak {peak_ns}");
    assert!(peak_s < 25.0, "sinking peak {peak_s}");
    assert!(sinking.energy().source_in_j > 0.0);
    assert_eq!(non_sinking.energy().source_in_j, 0.0);
    assert_eq!(
        non_sinking.dc_link().map(|d| d.source),
        Some(SourceKind::NonSinking)
    );
    // Without a DC link the source absorbs everything: the bus stays put.
    let mut ideal = plant_with(None);
    assert!(regen_peak(&mut ideal, 500.0, 600) <= 24.0 + 1e-3);
}

#[test]
fn the_brake_resistor_clamps_the_bus() {
    let dc = DcLinkConfig::odrive_v3().bench_supply(24.0, 10.0);
    let mut plant = plant_with(Some(dc));
    plant.set_speed(500.0);
    let mut peak: Real = 0.0;
    for _ in 0..600 {
        // A chopper with hysteresis, as a drive would run it.
        let v = plant.v_bus_v();
        if v > 28.0 {
            plant.set_brake(true);
        } else if v < 26.0 {
            plant.set_brake(false);
        }
        let d = dq_duties(&plant, 0.0, 0.5 * back_emf(&plant));
        plant.step_period(d, true, 0.0);
        peak = peak.max(plant.v_bus_v());
    }
    std::println!(
        "bus peak with the chopper: {peak:.2} V, brake {:.3} J",
        plant.brake_energy_j()
    );
    assert!(peak < 29.0, "peak {peak}");
    assert!(plant.brake_energy_j() > 0.0);
    // Held on, the brake current is V / R.
    plant.set_brake(true);
    plant.step_period([0.5; 3], false, 0.0);
    let i = plant.brake_current_a();
    assert!((i - plant.v_bus_avg_v() / 2.0).abs() < 0.05 * i, "{i}");
}

#[test]
fn a_disabled_bridge_above_the_bus_rectifies_into_a_non_sinking_link() {
    // 1500 rad/s: line-to-line back-EMF peak sqrt(3) * 10500 * 0.0024 = 43.6 V.
    let mut plant = plant_with(Some(DcLinkConfig::odrive_v3().bench_supply(24.0, 10.0)));
    plant.set_mechanics(Mechanics::ConstantSpeed(1500.0));
    let mut peak: Real = 0.0;
    for _ in 0..3000 {
        plant.step_period([0.5; 3], false, 0.0);
        peak = peak.max(plant.v_bus_v());
    }
    std::println!("rectified bus: {peak:.2} V");
    assert!(peak > 35.0 && peak < 44.0, "{peak}");
}

#[test]
fn the_source_current_limit_holds() {
    let dc = DcLinkConfig::odrive_v3().bench_supply(24.0, 5.0);
    let mut plant = plant_with(Some(dc));
    plant.set_mechanics(Mechanics::Locked);
    let mut sagged = false;
    for _ in 0..3000 {
        // 3 V on the d axis of a locked 0.1 ohm motor: 30 A, 135 W > 120 W.
        let d = dq_duties(&plant, 3.0, 0.0);
        plant.step_period(d, true, 0.0);
        assert!(
            plant.source_current_a() <= 5.0 + 1e-4,
            "{}",
            plant.source_current_a()
        );
        sagged |= plant.v_bus_v() < 23.0;
    }
    assert!(
        sagged,
        "the capacitor did not discharge: {}",
        plant.v_bus_v()
    );
    assert!((plant.source_current_a() - 5.0).abs() < 1e-3);
}

#[test]
fn winding_temperature_rises_with_the_stated_time_constant() {
    let mut plant = Plant::new(MotorParams::example(), BenchConfig::default());
    plant.set_mechanics(Mechanics::Locked);
    let w = WindingThermal {
        r_th_k_per_w: 2.0,
        tau_s: 0.05,
        ambient_c: 25.0,
        copper_tempco: false,
    };
    plant.set_winding_thermal(Some(w));
    assert_eq!(plant.winding_temperature_c(), Some(25.0));
    // Settle the current first (its own time constant is 0.3 ms).
    for _ in 0..150 {
        let d = dq_duties(&plant, 1.0, 0.0);
        plant.step_period(d, true, 0.0);
    }
    plant.set_winding_temperature_c(25.0);
    plant.reset_energy();
    let t0 = plant.time_s();
    let f = plant.config().pwm_frequency_hz;
    let n_tau = (w.tau_s * f) as u32; // periods in one time constant
    let mut at_tau = 0.0;
    for n in 1..=5 * n_tau {
        let d = dq_duties(&plant, 1.0, 0.0);
        plant.step_period(d, true, 0.0);
        if n == n_tau {
            at_tau = plant.winding_temperature_c().unwrap_or(0.0);
        }
    }
    let p = plant.energy().copper_j / (plant.time_s() - t0) as Real;
    let rise = p * w.r_th_k_per_w;
    let t_end = plant.winding_temperature_c().unwrap_or(0.0);
    let e1 = 1.0 - real::exp(-(n_tau as Real) / (w.tau_s * f));
    std::println!(
        "P {p:.3} W, at tau {at_tau:.3} C, at 5 tau {t_end:.3} C, final {:.3} C",
        25.0 + rise
    );
    assert!((p - 15.0).abs() < 0.2, "copper loss {p}");
    assert!(
        (at_tau - (25.0 + rise * e1)).abs() < 0.01 * rise,
        "{at_tau}"
    );
    assert!((t_end - (25.0 + rise * (1.0 - real::exp(-5.0)))).abs() < 0.01 * rise);
}

#[test]
fn hot_copper_raises_the_resistance() {
    let mut plant = Plant::new(MotorParams::example(), BenchConfig::default());
    plant.set_mechanics(Mechanics::Locked);
    plant.set_winding_thermal(Some(WindingThermal {
        copper_tempco: true,
        tau_s: 1e6, // hold the temperature
        ..WindingThermal::example()
    }));
    plant.set_winding_temperature_c(120.0);
    let r = plant.winding_resistance_ohm();
    assert!((r - 0.1393).abs() < 1e-4, "{r}");
    for _ in 0..300 {
        let d = dq_duties(&plant, 1.0, 0.0);
        plant.step_period(d, true, 0.0);
    }
    // Steady state: id = vd / R(T).
    let id = plant.id_a();
    assert!((id - 1.0 / r).abs() < 0.02 * id, "id {id} vs {}", 1.0 / r);
}

#[test]
fn stage_temperature_reaches_the_drive_through_the_bench_adapter() {
    let mut p = Plant::new(MotorParams::example(), BenchConfig::default());
    p.set_mechanics(Mechanics::Locked);
    let st = StageThermal {
        tau_s: 0.02,
        ..StageThermal::x_nucleo_ihm07m1()
    };
    p.set_stage_thermal(Some(st));
    let plant = RefCell::new(p);
    let sensors = BenchSensors::new(&plant);
    let mut vb = sensors.bus_voltage();
    assert_eq!(vb.read_temperature_c(), None); // no sample yet
    let mut pwm = BenchPwm::new(&sensors, 1000);
    use foc_core::hal::PwmDriver;
    pwm.enable().ok();
    let mut last = None;
    for _ in 0..1500 {
        let d = dq_duties(&plant.borrow(), 0.15, 0.0); // about 1.5 A
        pwm.set_duties(d).ok();
        last = Some(pwm.step(0.0));
    }
    let m = last.map(|m| m.stage_temperature_c);
    let t = plant.borrow().stage_temperature_c().unwrap_or(0.0);
    // Conduction: 1.5 id^2 R_ds_on (sum of i_k^2 = 1.5 id^2), switching small.
    let i = plant.borrow().id_a();
    let p_cond = 1.5 * i * i * st.r_ds_on_ohm;
    std::println!("stage {t:.2} C, id {i:.2} A, conduction {p_cond:.2} W");
    assert!(t > 25.0 + 0.9 * p_cond * st.r_th_k_per_w, "{t}");
    assert_eq!(m, Some(Some(t as f32)));
    assert_eq!(vb.read_temperature_c(), Some(Ok(t as f32)));
}
