//! Power-stage protection (design §18) against the plant's DC link: a
//! motor braking from speed into a supply that cannot sink current charges
//! the bus capacitor; the drive's regen limit must keep the bus below the
//! over-voltage threshold (no fault) and still stop the motor, where the
//! drive without it trips `BusOverVoltage` and lets the motor coast.

use foc_bench::mission::{control_motor, Setup, Sim};
use foc_bench::plant::Plant;
use foc_bench::power::{DcLinkConfig, SourceKind};
use foc_core::control::power::{ActiveLimit, PowerLimitsConfig};
use foc_core::control::{Command, Fault};

fn cheetah() -> Setup {
    Setup::load(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/motors/hkc-cheetah.toml"
    ))
    .unwrap()
}

/// What a stop did.
#[derive(Debug)]
struct Stop {
    /// Highest bus voltage [V].
    peak_bus_v: f64,
    /// Time to |speed| < 2 rad/s [s] (None: not within the run).
    stop_s: Option<f64>,
    /// Faults latched.
    faults: Vec<Fault>,
    /// The regen limit was seen active.
    regen_limited: bool,
}

/// Spin to `w_rad_s` on a non-sinking supply with the board's capacitor
/// (ODrive v3 preset, no brake resistor), then command 0 rad/s.
fn stop_from(s: &Setup, w_rad_s: f32, limits: bool) -> Stop {
    let cfg = s.cascade_config();
    let mut plant = Plant::new(s.motor, s.bench);
    let mut link = DcLinkConfig::odrive_v3();
    link.brake_resistor_ohm = None;
    // The spin-up (with its speed overshoot) on a battery that sinks the
    // braking current; the stop on the non-sinking supply.
    link.i_source_max_a = 40.0;
    link.source = SourceKind::Sinking;
    link.v_source_v = s.bench.bus_voltage_v as _;
    plant.set_dc_link(Some(link));
    let mut sim = Sim::with_plant(s, plant, cfg, false);
    sim.cascade.set_calibration(&s.supplied_calibration(&cfg));
    if limits {
        let p =
            PowerLimitsConfig::for_board(&cfg.current.supervisor, control_motor(&s.motor), false);
        sim.cascade.current.set_power_limits(Some(p));
    }
    sim.cascade
        .command(Command::Velocity { rad_s: w_rad_s })
        .unwrap();
    let pwm = s.pwm_hz() as f64;
    sim.run((1.5 * pwm) as usize);
    assert!(
        (sim.plant.omega_m_rad_s() - w_rad_s as f64).abs() < 0.05 * w_rad_s as f64,
        "spun up: {} rad/s, feedback {:?}, bus {} V",
        sim.plant.omega_m_rad_s(),
        sim.cascade.feedback(),
        sim.plant.v_bus_v()
    );
    if let Some(l) = sim.plant.dc_link_mut() {
        l.source = SourceKind::NonSinking;
    }
    sim.cascade
        .command(Command::Velocity { rad_s: 0.0 })
        .unwrap();
    let mut stop = Stop {
        peak_bus_v: 0.0,
        stop_s: None,
        faults: Vec::new(),
        regen_limited: false,
    };
    for k in 0..(3.0 * pwm) as usize {
        sim.step();
        stop.peak_bus_v = stop.peak_bus_v.max(sim.plant.v_bus_v());
        let fb = sim.cascade.feedback();
        stop.regen_limited |= fb.power.active == ActiveLimit::Regen;
        if stop.stop_s.is_none() && sim.plant.omega_m_rad_s().abs() < 2.0 {
            stop.stop_s = Some(k as f64 / pwm);
        }
    }
    stop.faults = sim.cascade.feedback().faults.iter().collect();
    stop
}

#[test]
fn a_stop_into_a_non_sinking_supply_stays_below_the_over_voltage_threshold() {
    let s = cheetah();
    let ov = s.cascade_config().current.supervisor.bus_over_voltage_v as f64;
    let without = stop_from(&s, 150.0, false);
    let with = stop_from(&s, 150.0, true);
    println!(
        "over-voltage threshold {ov} V; without the regen limit: {without:?}; with it: {with:?}"
    );
    // Without the limit the braking energy lifts the bus over the threshold.
    assert!(without.peak_bus_v > ov, "{without:?}");
    assert!(
        without.faults.contains(&Fault::BusOverVoltage),
        "{without:?}"
    );
    // With it: below the threshold, no fault, stopped.
    assert!(with.peak_bus_v < ov, "{with:?}");
    assert!(with.faults.is_empty(), "{with:?}");
    assert!(with.regen_limited, "{with:?}");
    assert!(with.stop_s.is_some(), "{with:?}");
}
