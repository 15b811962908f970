//! Simulated dynamometer (design §12): the real cascade in velocity
//! mode on the plant, a brake (load torque) on the shaft, and the operating
//! points measured in steady state.
//!
//! Three sweeps:
//!
//! - [`Sweep::Load`]: speed command fixed (half the no-load speed, at most
//!   [`Setup::max_mission_speed_rad_s`]), load
//!   torque stepped from 0 to the rated torque (`kt * rated current`).
//! - [`Sweep::Voltage`]: supply voltage stepped from the nominal bus down to
//!   a tenth of it (as the source's report), speed command 80 % of the
//!   no-load speed (capped as above) scaled by the voltage, load torque fixed at 30 % of rated. The
//!   supervisor's under-voltage limit is lowered to 5 % of nominal for it.
//! - [`Sweep::Regen`]: the load sweep's speed command, an *overhauling*
//!   load (it drives the shaft forwards, as a vehicle downhill or a lowered
//!   weight) stepped from 0 to the rated torque: the drive brakes and
//!   returns energy to the supply (generator points, negative input and
//!   mechanical power; the efficiency column is then electrical out over
//!   mechanical in).
//!
//! Every figure is *measured* on the plant over a window after settling:
//! supply voltage and current are the plant's period averages, input power
//! is the supply energy over the window, torque is the brake's absorbed
//! energy over the shaft angle travelled, speed is the mean shaft speed.
//! The bus columns: the bus current is the mean current at the source's
//! terminals (the dyno's plain source: the same as the supply current; with
//! a DC link, the source's side of the capacitor), and the regenerated
//! energy is what went back into the source over the window,
//! `sum max(0, -P) T_pwm` with `P` each period's mean power at the source's
//! terminals (0 at motoring points).
//!
//! ```no_run
//! use foc_bench::{dyno, mission::Setup};
//! let setup = Setup::load("tests/motors/m153-source.toml").unwrap();
//! let run = dyno::run_dyno(&setup, dyno::Sweep::Load, 10, &mut |_| {});
//! assert_eq!(run.rows.len(), 11);
//! ```

use crate::mission::{align, Setup, Sim};
use crate::report::{DynoHeader, DynoRow};
use foc_core::control::Command;

/// Which quantity the sweep steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sweep {
    /// Load-torque steps at a fixed speed command.
    Load,
    /// Supply-voltage steps with a speed command proportional to the voltage.
    Voltage,
    /// Overhauling-load steps at a fixed speed command (regeneration).
    Regen,
}

impl Sweep {
    /// `load` or `voltage`.
    pub fn name(self) -> &'static str {
        match self {
            Sweep::Load => "load",
            Sweep::Voltage => "voltage",
            Sweep::Regen => "regen",
        }
    }
}

/// A finished dynamometer run.
#[derive(Clone, Debug)]
pub struct DynoRun {
    /// Report header.
    pub header: DynoHeader,
    /// One row per operating point.
    pub rows: Vec<DynoRow>,
    /// Faults latched during the run (names).
    pub faults: Vec<String>,
    /// The set points (load [N m], supply \[V\], speed command [rad/s]) per row.
    pub set_points: Vec<(f64, f64, f64)>,
}

/// Today's date (UTC) as `YYYY-MM-DD`, from the system clock.
pub fn today() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs()) as i64;
    // Civil from days (H. Hinnant's algorithm).
    let z = secs.div_euclid(86_400) + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + if m <= 2 { 1 } else { 0 };
    format!("{y:04}-{m:02}-{d:02}")
}

/// Measure one operating point: settle, then average over `window_s`.
fn measure(sim: &mut Sim, settle_s: f64, window_s: f64) -> DynoRow {
    let f = sim.plant.config().pwm_frequency_hz as f64;
    sim.run((settle_s * f) as usize);
    let n = ((window_s * f) as usize).max(1);
    sim.plant.reset_energy();
    let p0 = sim.plant.position_rad() as f64;
    let (mut v, mut i, mut w) = (0.0, 0.0, 0.0);
    let (mut i_bus, mut regen_j) = (0.0, 0.0);
    for _ in 0..n {
        sim.step();
        v += sim.plant.v_bus_avg_v() as f64;
        i += sim.plant.supply_current_a() as f64;
        w += sim.plant.omega_m_rad_s() as f64;
        let i_src = sim.plant.source_current_a() as f64;
        i_bus += i_src;
        // The period's mean power at the source's terminals: exact without
        // a DC link (the inverter's input power), the product of the
        // period means with one (the capacitor holds the voltage).
        let p = if sim.plant.dc_link().is_some() {
            sim.plant.v_bus_avg_v() as f64 * i_src
        } else {
            sim.plant.input_power_w() as f64
        };
        if p < 0.0 {
            regen_j -= p / f;
        }
    }
    let t = n as f64 / f;
    let e = *sim.plant.energy();
    let angle = sim.plant.position_rad() as f64 - p0;
    let torque = if angle.abs() > 1e-9 {
        e.load_j as f64 / angle
    } else {
        0.0
    };
    let w = w / n as f64;
    DynoRow::new(
        v / n as f64,
        i / n as f64,
        e.supply_j as f64 / t,
        w * 60.0 / std::f64::consts::TAU,
        torque,
    )
    .with_bus(i_bus / n as f64, regen_j)
}

/// Run a sweep of `steps` steps (`steps + 1` rows for the load and regen
/// sweeps, `steps` rows for the voltage sweep). `progress` gets the
/// fraction done.
pub fn run_dyno(
    setup: &Setup,
    sweep: Sweep,
    steps: usize,
    progress: &mut dyn FnMut(f64),
) -> DynoRun {
    let steps = steps.max(1);
    let mut config = setup.cascade_config();
    let v_nom = setup.bench.bus_voltage_v as f32;
    if sweep == Sweep::Voltage {
        config.current.supervisor.bus_under_voltage_v = 0.05 * v_nom;
    }
    let mut sim = Sim::new(setup, config, false);
    sim.set_rotor_angle(0.7);
    align(&mut sim, setup);
    let kt = setup.kt();
    let j = setup.motor.inertia_kg_m2 as f32;
    let t_rated = kt * setup.rated_current_a;
    let accel = 0.3 * kt * setup.max_current_a / j;
    let f = setup.bench.pwm_frequency_hz as f64;
    let div = config.rates.speed_divider.max(1) as usize;
    // Ramp the speed command to `to` at `accel`.
    let ramp = |sim: &mut Sim, from: f32, to: f32| {
        let n = (((to - from).abs() / accel) as f64 * f).max(1.0) as usize;
        for k in 0..n {
            if k % div == 0 {
                let w = from + (to - from) * k as f32 / n as f32;
                sim.cascade.command(Command::Velocity { rad_s: w }).ok();
            }
            sim.step();
        }
        sim.cascade.command(Command::Velocity { rad_s: to }).ok();
    };
    let mut rows = Vec::new();
    let mut set_points = Vec::new();
    let (settle, window) = (0.35, 0.1);
    match sweep {
        Sweep::Load | Sweep::Regen => {
            let w_cmd = (0.5 * setup.max_speed_rad_s()).min(setup.max_mission_speed_rad_s());
            ramp(&mut sim, 0.0, w_cmd);
            // The load opposes positive rotation: negative, it drives it.
            let sign = if sweep == Sweep::Regen { -1.0 } else { 1.0 };
            for k in 0..=steps {
                let load = sign * t_rated * k as f32 / steps as f32;
                sim.load_nm = load;
                rows.push(measure(&mut sim, settle, window));
                set_points.push((load as f64, v_nom as f64, w_cmd as f64));
                progress((k + 1) as f64 / (steps + 1) as f64);
            }
        }
        Sweep::Voltage => {
            let load = 0.3 * t_rated;
            let mut w_prev = 0.0;
            for k in 0..steps {
                let v = v_nom * (steps - k) as f32 / steps as f32;
                sim.plant.config_mut().bus_voltage_v = v as crate::real::Real;
                let w_cmd = (0.8 * setup.max_speed_rad_s()).min(setup.max_mission_speed_rad_s())
                    * v
                    / v_nom;
                ramp(&mut sim, w_prev, w_cmd);
                w_prev = w_cmd;
                sim.load_nm = load;
                rows.push(measure(&mut sim, settle, window));
                set_points.push((load as f64, v as f64, w_cmd as f64));
                progress((k + 1) as f64 / steps as f64);
            }
        }
    }
    let fb = *sim.cascade.feedback();
    let faults = fb.faults.iter().map(|f| f.name().to_string()).collect();
    let header = DynoHeader {
        project_no: "RUST-FOC".into(),
        report_no: format!("SIM-{}-{}", sweep.name().to_uppercase(), today()),
        motor_model: setup.name.clone(),
        test_motor_no: format!("simulated plant (sensor seed {})", setup.bench.sensors.seed),
        report_date: today(),
        tested_by: "cargo xtask dyno (simulation)".into(),
        approved_by: "not approved (simulation)".into(),
    };
    DynoRun {
        header,
        rows,
        faults,
        set_points,
    }
}
