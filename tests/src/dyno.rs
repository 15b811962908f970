//! Simulated dynamometer (design §12): the real cascade in velocity
//! mode on the plant, a brake (load torque) on the shaft, and the operating
//! points measured in steady state.
//!
//! Three sweeps ([`Sweep`]), each at a test
//! speed ([`TestSpeed`]: the speed command at the nominal bus, rotor,
//! mechanical; checked once against the motor's no-load speed):
//!
//! - [`Sweep::Load`]: speed command fixed (by default half the no-load
//!   speed, at most [`Setup::max_mission_speed_rad_s`]), load torque
//!   stepped from 0 to the rated torque (`kt * rated current`).
//! - [`Sweep::Voltage`]: supply voltage stepped from the nominal bus down
//!   to a tenth of it (as the source's report), speed command the test
//!   speed (by default 80 % of the no-load speed, capped as above) scaled
//!   by the voltage, load torque fixed at 30 % of rated. The supervisor's
//!   under-voltage limit is lowered to 5 % of nominal for it.
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
//! energy over the shaft angle travelled, speed is the mean shaft speed
//! (beside its command), the phase current is the mean amplitude `|i_dq|`
//! of the plant's currents (peak), the modulation index the mean of
//! `sqrt(3) |v| / v_bus` of the duties the bridge applied. The regenerated
//! energy is what went back into the source over the window,
//! `sum max(0, -P) T_pwm` with `P` each period's mean power at the source's
//! terminals (0 at motoring points). The bus current (the source's side
//! of a DC link) is recorded only with a DC link: the dyno's plain source
//! has none, and its bus current is the supply current.
//!
//! ```no_run
//! use foc_bench::{dyno, mission::Setup};
//! let setup = Setup::load("tests/motors/m153-source.toml").unwrap();
//! let speed = dyno::TestSpeed::new(&setup, 10.0).unwrap();
//! let run = dyno::run_dyno(&setup, dyno::Sweep::Load, 10, speed, &mut |_| {});
//! assert_eq!(run.rows.len(), 11);
//! print!("{}", run.report().markdown());
//! ```

use crate::mission::{align, Setup, Sim};
use crate::report::{DynoHeader, DynoReport, DynoRow};
use foc_core::control::Command;

/// Which quantity the sweep steps (the report's [`crate::report::DynoSweep`]).
pub use crate::report::DynoSweep as Sweep;

/// rad/s to rpm.
const RPM_PER_RAD_S: f64 = 60.0 / std::f64::consts::TAU;

/// The test speed: the speed command at the nominal bus [rad/s, rotor,
/// mechanical], above zero and at most the motor's no-load speed
/// ([`Setup::max_speed_rad_s`]) and the bench's highest
/// ([`Setup::max_mission_speed_rad_s`]). Checked once, here.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TestSpeed(f32);

/// Why a test speed is refused.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SpeedError {
    /// Not a number above 0 [rad/s] (the dyno turns forwards).
    NotPositive(f32),
    /// Above the no-load speed at the nominal bus: the drive cannot reach it.
    AboveNoLoad {
        /// The speed asked for [rad/s].
        rad_s: f32,
        /// The no-load speed [rad/s].
        no_load_rad_s: f32,
        /// The nominal bus \[V\].
        bus_v: f32,
    },
    /// Above the bench's highest speed (one electrical turn per 10 PWM periods).
    AboveBench {
        /// The speed asked for [rad/s].
        rad_s: f32,
        /// The bench's highest speed [rad/s].
        max_rad_s: f32,
    },
}

impl std::fmt::Display for SpeedError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let rpm = |w: f32| w as f64 * RPM_PER_RAD_S;
        match *self {
            SpeedError::NotPositive(w) => write!(
                f,
                "test speed {w} rad/s: give a speed above 0 rad/s (rotor, mechanical)"
            ),
            SpeedError::AboveNoLoad {
                rad_s,
                no_load_rad_s,
                bus_v,
            } => write!(
                f,
                "test speed {rad_s} rad/s ({:.0} rpm) is above the motor's no-load speed, {no_load_rad_s:.2} rad/s ({:.0} rpm) at the nominal {bus_v} V bus (95 % of the linear range): the drive cannot reach it; give at most {no_load_rad_s:.2} rad/s",
                rpm(rad_s),
                rpm(no_load_rad_s)
            ),
            SpeedError::AboveBench { rad_s, max_rad_s } => write!(
                f,
                "test speed {rad_s} rad/s is above the bench's highest, {max_rad_s:.1} rad/s (one electrical turn per 10 PWM periods)"
            ),
        }
    }
}

impl std::error::Error for SpeedError {}

impl TestSpeed {
    /// `rad_s` [rad/s, rotor, mechanical] if the motor can reach it.
    pub fn new(setup: &Setup, rad_s: f32) -> Result<Self, SpeedError> {
        let no_load_rad_s = setup.max_speed_rad_s();
        let max_rad_s = setup.max_mission_speed_rad_s();
        if !(rad_s.is_finite() && rad_s > 0.0) {
            Err(SpeedError::NotPositive(rad_s))
        } else if rad_s > no_load_rad_s {
            Err(SpeedError::AboveNoLoad {
                rad_s,
                no_load_rad_s,
                bus_v: setup.bench.bus_voltage_v as f32,
            })
        } else if rad_s > max_rad_s {
            Err(SpeedError::AboveBench { rad_s, max_rad_s })
        } else {
            Ok(Self(rad_s))
        }
    }

    /// The sweep's default: half the no-load speed for the load and regen
    /// sweeps, 80 % for the voltage sweep (at the nominal bus), at most
    /// the bench's highest speed.
    pub fn default_for(setup: &Setup, sweep: Sweep) -> Self {
        let share = match sweep {
            Sweep::Load | Sweep::Regen => 0.5,
            Sweep::Voltage => 0.8,
        };
        Self((share * setup.max_speed_rad_s()).min(setup.max_mission_speed_rad_s()))
    }

    /// The speed [rad/s, rotor, mechanical].
    pub fn rad_s(self) -> f32 {
        self.0
    }
}

/// A finished dynamometer run.
#[derive(Clone, Debug)]
pub struct DynoRun {
    /// What was swept.
    pub sweep: Sweep,
    /// The test speed (the speed command at the nominal bus).
    pub speed: TestSpeed,
    /// Report header.
    pub header: DynoHeader,
    /// One row per operating point.
    pub rows: Vec<DynoRow>,
    /// Faults latched during the run (names).
    pub faults: Vec<String>,
    /// The set points (load [N m], supply \[V\], speed command [rad/s]) per row.
    pub set_points: Vec<(f64, f64, f64)>,
}

impl DynoRun {
    /// The run's report (CSV, Markdown, SVG), titled by its sweep.
    pub fn report(&self) -> DynoReport<'_> {
        DynoReport {
            header: &self.header,
            sweep: Some(self.sweep),
            rows: &self.rows,
        }
    }
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

/// The modulation index `sqrt(3) |v| / v_bus` of duties `d`: the
/// amplitude-invariant Clarke transform of the duties (the common mode
/// drops out), `|v| / v_bus = sqrt(alpha^2 + beta^2)`.
pub fn modulation_index(d: [f32; 3]) -> f64 {
    let [a, b, c] = d.map(f64::from);
    let alpha = (2.0 * a - b - c) / 3.0;
    let beta = (b - c) / 3f64.sqrt();
    3f64.sqrt() * alpha.hypot(beta)
}

/// Measure one operating point at speed command `w_cmd_rad_s`: settle,
/// then average over `window_s`.
fn measure(sim: &mut Sim, w_cmd_rad_s: f32, settle_s: f64, window_s: f64) -> DynoRow {
    let f = sim.plant.config().pwm_frequency_hz as f64;
    sim.run((settle_s * f) as usize);
    let n = ((window_s * f) as usize).max(1);
    sim.plant.reset_energy();
    let p0 = sim.plant.position_rad() as f64;
    let (mut v, mut i, mut w) = (0.0, 0.0, 0.0);
    let (mut i_bus, mut regen_j) = (0.0, 0.0);
    let (mut i_phase, mut m) = (0.0, 0.0);
    for _ in 0..n {
        sim.step();
        v += sim.plant.v_bus_avg_v() as f64;
        i += sim.plant.supply_current_a() as f64;
        w += sim.plant.omega_m_rad_s() as f64;
        i_phase += (sim.plant.id_a() as f64).hypot(sim.plant.iq_a() as f64);
        m += modulation_index(sim.plant.applied_duties());
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
    let mean = |x: f64| x / n as f64;
    let row = DynoRow::new(
        mean(v),
        mean(i),
        e.supply_j as f64 / t,
        mean(w) * RPM_PER_RAD_S,
        torque,
    )
    .with_speed_command(w_cmd_rad_s as f64 * RPM_PER_RAD_S)
    .with_drive(mean(i_phase), mean(m));
    // Without a DC link the source's current is the supply current: not
    // repeated as a bus column.
    if sim.plant.dc_link().is_some() {
        row.with_bus(mean(i_bus), regen_j)
    } else {
        row.with_regen(regen_j)
    }
}

/// Run a sweep of `steps` steps (`steps + 1` rows for the load and regen
/// sweeps, `steps` rows for the voltage sweep) at the test speed `speed`
/// (the voltage sweep's command at the nominal bus, scaled with the
/// voltage). `progress` gets the fraction done.
pub fn run_dyno(
    setup: &Setup,
    sweep: Sweep,
    steps: usize,
    speed: TestSpeed,
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
            let w_cmd = speed.rad_s();
            ramp(&mut sim, 0.0, w_cmd);
            // The load opposes positive rotation: negative, it drives it.
            let sign = if sweep == Sweep::Regen { -1.0 } else { 1.0 };
            for k in 0..=steps {
                let load = sign * t_rated * k as f32 / steps as f32;
                sim.load_nm = load;
                rows.push(measure(&mut sim, w_cmd, settle, window));
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
                let w_cmd = speed.rad_s() * v / v_nom;
                ramp(&mut sim, w_prev, w_cmd);
                w_prev = w_cmd;
                sim.load_nm = load;
                rows.push(measure(&mut sim, w_cmd, settle, window));
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
        sweep,
        speed,
        header,
        rows,
        faults,
        set_points,
    }
}
