//! The sensorless mission (`cargo xtask sim --sensorless`, design §27 and
//! §29): a board without an angle input (the angle is withheld from every
//! sample) boots sensorless, identifies the motor (resistance,
//! inductances, gains, the flux linkage on a turning field; the inertia is
//! the configuration's), derives its start from what it measured, and
//! runs through a start from standstill, a speed
//! step, a load step, a reversal through zero and a stop; on a salient
//! motor (high-frequency injection, design §28) also a hold at zero speed
//! under the rated load. Each segment must reach its speed (within 10 %,
//! in the commanded direction; zero within 1 % of the top speed) without
//! a fault; the angle in use (the observer's, or the injection's) against
//! the plant's true one is reported.

use super::{Command, Setup, Sim};
use crate::identify;
use foc_core::calibration::identification::IdentificationResult;
use foc_core::calibration::CalStep;
use foc_core::control::flux_observer::ObserverConfig;
use foc_core::control::sensorless::{Region, SensorlessConfig};

/// One segment's figures.
#[derive(Clone, Debug)]
pub struct SensorlessSegment {
    /// What it does.
    pub name: String,
    /// The speed commanded [rad/s, mechanical].
    pub target_rad_s: f32,
    /// First time the speed stayed within 10 % of the command \[s\] from
    /// the segment's start (`None`: not reached).
    pub reached_s: Option<f32>,
    /// The speed at the segment's end [rad/s, mechanical].
    pub end_rad_s: f32,
    /// The largest angle error of the observer or the injection while it
    /// drove the current loop over the segment's last fifth [rad,
    /// electrical].
    pub steady_angle_rad: f32,
    /// ... and over the whole segment.
    pub worst_angle_rad: f32,
    /// The largest motion against the commanded direction [rad,
    /// mechanical]: a start's backward motion; a reversal's includes the
    /// turns it takes to brake.
    pub backward_rad: f32,
    /// A fault that latched.
    pub fault: Option<foc_core::control::Fault>,
}

/// What the identification without the angle found, against the motor
/// file.
#[derive(Clone, Copy, Debug)]
pub struct SensorlessIdentification {
    /// The measured values.
    pub result: IdentificationResult,
    /// The motor file's: R \[ohm\], the incremental Ld at the bias current
    /// \[H\], Lq \[H\], flux linkage \[Wb\].
    pub truth: [f32; 4],
    /// Simulated time it took (after the current offsets) \[s\].
    pub time_s: f32,
}

impl SensorlessIdentification {
    /// The measured values in the order of [`Self::truth`].
    pub fn measured(&self) -> [f32; 4] {
        let r = &self.result;
        [r.r_ohm, r.ld_h, r.lq_h, r.flux_linkage_wb]
    }
}

/// The mission's result.
#[derive(Clone, Debug)]
pub struct SensorlessResult {
    /// The motor's name.
    pub motor: String,
    /// The identification without the angle: its figures, or why it
    /// failed (then no segment ran).
    pub identification: Result<SensorlessIdentification, String>,
    /// The segments in order.
    pub segments: Vec<SensorlessSegment>,
    /// The hand-over speed [rad/s, mechanical].
    pub handover_rad_s: f32,
    /// Below it, high-frequency injection (a salient motor) instead of the
    /// field.
    pub injection: bool,
}

impl SensorlessResult {
    /// What failed (empty: passed).
    pub fn failures(&self) -> Vec<String> {
        let id = self
            .identification
            .as_ref()
            .err()
            .map(|e| format!("identification without the angle: {e}"));
        id.into_iter()
            .chain(
                self.segments
                    .iter()
                    .filter_map(|s| match (s.fault, s.reached_s) {
                        (Some(f), _) => Some(format!("{}: fault {f:?}", s.name)),
                        (None, None) => Some(format!(
                            "{}: {:.1} rad/s not reached (ended at {:.1})",
                            s.name, s.target_rad_s, s.end_rad_s
                        )),
                        _ => None,
                    }),
            )
            .collect()
    }

    /// The identification's table (Markdown).
    fn identification_markdown(&self) -> String {
        let Ok(id) = &self.identification else {
            return String::new();
        };
        let names = ["R ohm", "Ld H (at the bias)", "Lq H", "flux linkage Wb"];
        let mut s = format!(
            "Identified without the angle in {:.2} s (simulated; no alignment, the flux linkage on a turning field, design §29):\n\n| value | identified | motor file | error |\n|---|---:|---:|---:|\n",
            id.time_s
        );
        for ((n, m), t) in names.iter().zip(id.measured()).zip(id.truth) {
            s += &format!(
                "| {n} | {} | {} | {:.1} % |\n",
                significant(m),
                significant(t),
                100.0 * (m / t - 1.0)
            );
        }
        s + "\n"
    }

    /// The summary as a Markdown table.
    pub fn to_markdown(&self) -> String {
        let mut s = format!(
            "### Sensorless mission: {}\n\n{}The observer takes over above {:.1} rad/s; below, {}.\n\n| segment | command rad/s | reached after s | at the end rad/s | angle error, last fifth rad(e) | angle error, worst rad(e) | against the command rad | fault |\n|---|---:|---:|---:|---:|---:|---:|---|\n",
            self.motor,
            self.identification_markdown(),
            self.handover_rad_s,
            if self.injection {
                "high-frequency injection (design §28)"
            } else {
                "the start's field (design §27)"
            }
        );
        for g in &self.segments {
            s += &format!(
                "| {} | {:.1} | {} | {:.1} | {:.3} | {:.3} | {:.3} | {} |\n",
                g.name,
                g.target_rad_s,
                g.reached_s
                    .map_or("not reached".into(), |t| format!("{t:.3}")),
                g.end_rad_s,
                g.steady_angle_rad,
                g.worst_angle_rad,
                g.backward_rad,
                g.fault.map_or("none".into(), |f| format!("{f:?}"))
            );
        }
        s += &format!("\n{}\n", super::SMOOTHNESS_SENSORLESS);
        let fails = self.failures();
        s += &format!(
            "\nResult: {}\n",
            if fails.is_empty() {
                "PASS".into()
            } else {
                format!("FAIL ({})", fails.join("; "))
            }
        );
        s
    }
}

/// `x` with four significant digits (0 and non-finite values with three
/// decimals).
pub(super) fn significant(x: f32) -> String {
    let decimals = if x != 0.0 && x.is_finite() {
        3 - x.abs().log10().floor() as i32
    } else {
        3
    };
    format!("{x:.*}", decimals.clamp(0, 9) as usize)
}

/// Runs the sensorless mission on `setup`.
pub fn run_sensorless_mission(setup: &Setup, progress: &mut dyn FnMut(f64)) -> SensorlessResult {
    let mut sim = Sim::new(setup, setup.sensorless_config(), false);
    let identification = identify_without_angle(&mut sim, setup);
    if identification.is_err() {
        return SensorlessResult {
            motor: setup.name.clone(),
            identification,
            segments: Vec::new(),
            handover_rad_s: f32::NAN,
            injection: false,
        };
    }
    rederive_start(setup, &mut sim);
    let config = *sim.cascade.current.config();
    let handover = config.sensorless.map_or(f32::NAN, |c| {
        c.handover_rad_s / f32::from(setup.motor.pole_pairs)
    });
    let top = setup.max_speed_rad_s().min(setup.max_mission_speed_rad_s());
    let rated_nm = setup.kt() * setup.rated_current_a;
    // (name, speed as a share of the top speed, load as a share of the
    // rated torque, seconds)
    let injection = config.sensorless.and_then(|c| c.hfi_config()).is_some();
    let plan = [
        ("start from standstill", 0.3, 0.0, 1.0),
        ("speed step", 0.6, 0.0, 0.6),
        ("load step (40 % rated)", 0.6, 0.4, 0.6),
        ("reversal through zero", -0.3, 0.0, 1.5),
        ("back to forward", 0.3, 0.0, 1.5),
        ("hold at zero speed, rated load (injection)", 0.0, 1.0, 1.0),
    ];
    let plan = &plan[..plan.len() - usize::from(!injection)];
    let total: f64 = plan.iter().map(|p| p.3).sum();
    let mut done = 0.0;
    let mut segments = Vec::new();
    for &(name, share, load, secs) in plan {
        let target = share * top;
        let tol = (0.1 * target.abs()).max(if target == 0.0 { 0.01 * top } else { 0.0 });
        let g = segment(
            &mut sim,
            setup,
            name,
            (target, tol),
            load * rated_nm,
            secs as f32,
        );
        let fault = g.fault.is_some();
        segments.push(g);
        done += secs;
        progress(done / total);
        if fault {
            break;
        }
    }
    SensorlessResult {
        motor: setup.name.clone(),
        identification,
        segments,
        handover_rad_s: handover,
        injection,
    }
}

/// The identification of a drive that runs sensorless, with the angle
/// withheld ([`identify::run_without_angle`]); its figures against the
/// motor file, or why it failed.
pub fn identify_without_angle(
    sim: &mut Sim,
    setup: &Setup,
) -> Result<SensorlessIdentification, String> {
    let cfg = identify::config(setup, setup.motor.pole_pairs);
    let out =
        identify::run_without_angle(sim, setup, cfg, &mut |_| {}).map_err(|e| e.to_string())?;
    let CalStep::Done(done) = out.step else {
        return Err(format!("{:?} in {:?}", out.step, out.stage));
    };
    let m = &setup.motor;
    let ld = m.ld_incremental_h(cfg.inductance.bias_current_a as _);
    Ok(SensorlessIdentification {
        result: done.result,
        truth: [m.r_ohm, ld, m.lq_h, m.flux_linkage_wb].map(|x| x as f32),
        time_s: out.periods as f32 / setup.pwm_hz(),
    })
}

/// The sensorless start derived again from the motor the drive holds now
/// (an identification's), with the configuration's inertia, the rated
/// current and the bench's bus (what the drive's service does after an
/// identification: `foc_store::settings::sensorless_config`).
pub fn rederive_start(setup: &Setup, sim: &mut Sim) {
    let c = sim.cascade.current.config();
    let observer = ObserverConfig {
        motor: c.current.motor,
        ts_s: c.current.ts_s,
        dead_time_s: c.supervisor.model.dead_time_s,
        current_floor_a: c.supervisor.model.floor_a,
    };
    let sl = SensorlessConfig::for_motor(
        observer,
        setup.rated_current_a.min(setup.max_current_a),
        setup.motor.inertia_kg_m2 as f32,
        setup.bench.bus_voltage_v as f32,
    );
    sim.cascade.current.set_sensorless(sl);
}

/// One segment: the command, the load, `secs` of simulation.
fn segment(
    sim: &mut Sim,
    setup: &Setup,
    name: &str,
    (target, tol): (f32, f32),
    load_nm: f32,
    secs: f32,
) -> SensorlessSegment {
    let hz = setup.pwm_hz();
    let n = (secs * hz) as usize;
    let dir = target.signum();
    let _ = sim.cascade.command(Command::Velocity { rad_s: target });
    sim.load_nm = load_nm;
    let x0 = sim.plant.position_rad() as f32;
    let mut g = SensorlessSegment {
        name: name.into(),
        target_rad_s: target,
        reached_s: None,
        end_rad_s: 0.0,
        steady_angle_rad: 0.0,
        worst_angle_rad: 0.0,
        backward_rad: 0.0,
        fault: None,
    };
    for k in 0..n {
        // The observer's angle is of the period's sample: the rotor's angle
        // then, not after the step (a period's turn later).
        let theta_sampled = sim.plant.theta_e();
        let mut sample = sim.sample();
        sample.angle = None;
        sim.step_with(&sample);
        let fb = *sim.cascade.feedback();
        if let Some(f) = fb.first_fault {
            g.fault = Some(f);
            break;
        }
        let w = sim.plant.omega_m_rad_s() as f32;
        if (w - target).abs() <= tol {
            g.reached_s.get_or_insert(k as f32 / hz);
        } else {
            g.reached_s = None;
        }
        let x = sim.plant.position_rad() as f32 - x0;
        g.backward_rad = g.backward_rad.max(-x * dir);
        let stage = &sim.cascade.current;
        if matches!(
            stage.sensorless_region(),
            Some(Region::Observer | Region::Hfi)
        ) {
            if let Some(sl) = stage.sensorless() {
                let e = sl.angle().diff_radians(theta_sampled).abs();
                g.worst_angle_rad = g.worst_angle_rad.max(e);
                if k * 5 >= n * 4 {
                    g.steady_angle_rad = g.steady_angle_rad.max(e);
                }
            }
        }
    }
    g.end_rad_s = sim.plant.omega_m_rad_s() as f32;
    g
}
