//! The mission's field-weakening segment (design §30): with field
//! weakening turned on (`CurrentStage::set_field`), from rest to a speed
//! above base speed, held, a load step there, back to rest, and field
//! weakening turned off again.
//!
//! The top speed is 2.2 x the drive model's no-load base speed where the
//! model allows it, else 60 % of the way from base speed to the model's
//! top speed (`Field::max_speed_rad_s`), and at most 80 % of the mission's
//! resolved speed ([`Setup::max_mission_speed_rad_s`]). The segment is
//! skipped, its reason stated, where the drive refuses field weakening (a
//! coarse angle sensor: halls) or where 1.2 x base speed is beyond that
//! 80 %. The same rules as the bench test `tests/tests/field_weakening.rs`.

use super::*;
use foc_core::control::field::FieldConfig;

/// The top speed over base speed where the model allows it.
pub const FIELD_WEAKENING_TOP_PER_BASE: f32 = 2.2;

/// Where the model allows [`FIELD_WEAKENING_TOP_PER_BASE`], the speed
/// reached over base speed must be at least this (issue 37's goal on the
/// interior-PM file).
pub const FIELD_WEAKENING_GOAL_PER_BASE: f64 = 2.0;

/// Elsewhere the top speed is this share of the way from base speed to
/// the model's top speed (torque left for the load).
const MODEL_SHARE: f32 = 0.6;

/// The share of [`Setup::max_mission_speed_rad_s`] the segment may use
/// (one electrical turn per 12.5 PWM periods).
const RESOLVED_SHARE: f32 = 0.8;

/// The segment runs where this multiple of base speed is within the
/// resolved share.
const MIN_PER_BASE: f32 = 1.2;

/// The hold at the top speed before the load step \[s\].
const HOLD_S: f64 = 0.2;

/// The speeds are averaged over this long at the end of a hold \[s\].
const MEAN_S: f64 = 0.05;

/// At most this long to come to rest before the segment \[s\].
const REST_S: f64 = 0.5;

/// Periods to reach `w` [rad/s] from rest at a third of the current
/// limit's acceleration, at least 0.3 s.
fn periods_to(setup: &Setup, w: f32) -> usize {
    let acc = setup.kt() * setup.max_current_a / 3.0 / setup.motor.inertia_kg_m2 as f32;
    secs(setup, (w / acc).max(0.3) as f64)
}

/// The segment's simulated time at most, for the progress bar \[s\]:
/// from the setup's no-load speed (the drive's model is not known yet).
pub(super) fn field_weakening_expected_s(setup: &Setup) -> f64 {
    let top = (FIELD_WEAKENING_TOP_PER_BASE * setup.max_speed_rad_s())
        .min(RESOLVED_SHARE * setup.max_mission_speed_rad_s());
    let n = periods_to(setup, top) as f64 / setup.bench.pwm_frequency_hz as f64;
    2.5 * n + HOLD_S + 0.1
}

/// The highest torque the motor gives at electrical speed `w_e` [rad/s]
/// within the current limit and the voltage circle `v` \[V\] [N m]:
/// `v_d = R id - w Lq iq`, `v_q = R iq + w (psi + Ld id)`, searched over
/// the current's angle.
fn model_torque_at(setup: &Setup, w_e: f32, v: f32) -> f32 {
    let m = &setup.motor;
    let (psi, ld, lq) = (m.flux_linkage_wb as f32, m.ld_h as f32, m.lq_h as f32);
    let r = m.r_ohm as f32;
    let p = m.pole_pairs as f32;
    let mut best = 0.0f32;
    for k in 0..=1000 {
        let beta = k as f32 / 1000.0 * std::f32::consts::FRAC_PI_2;
        // The largest current along this angle whose voltage fits.
        let fits = |i: f32| {
            let (id, iq) = (-i * beta.sin(), i * beta.cos());
            (r * id - w_e * lq * iq).hypot(r * iq + w_e * (psi + ld * id)) <= v
        };
        let (mut lo, mut hi) = (0.0f32, setup.max_current_a);
        if fits(hi) {
            lo = hi;
        } else if fits(lo) {
            for _ in 0..40 {
                let mid = 0.5 * (lo + hi);
                if fits(mid) {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
        } else {
            continue;
        }
        let (id, iq) = (-lo * beta.sin(), lo * beta.cos());
        best = best.max(1.5 * p * iq * (psi + (ld - lq) * id));
    }
    best
}

/// The peaks seen while the segment runs.
struct Peaks {
    /// Largest |phase current| \[A\] (the plant's).
    phase_a: f64,
    /// Highest bus voltage \[V\] (the plant's).
    bus_v: f64,
    /// Most negative d current \[A\] (the plant's).
    id_a: f64,
}

impl Mission<'_> {
    /// Segment 8, field weakening: see the module docs. Run last, on the
    /// plain source (the braking segment's DC link removed).
    pub(super) fn field_weakening(&mut self) -> FieldWeakeningSegment {
        let setup = self.setup;
        let wall = Instant::now();
        let stage = self.sim.cascade.current.config();
        let (off, pp) = (stage.field, stage.current.motor.pole_pairs);
        let v_t = (1.0 - off.voltage_margin) * stage.current.max_modulation / 3f32.sqrt()
            * setup.bench.bus_voltage_v as f32;
        let v_bus = setup.bench.bus_voltage_v as f32;
        // The drive's own model (identified flux linkage), no torque.
        let base = self.sim.cascade.current.field().max_speed_rad_s(v_bus, pp);
        let on = FieldConfig {
            field_weakening: true,
            ..off
        };
        if let Err(e) = self.sim.cascade.current.set_field(on) {
            return FieldWeakeningSegment::Skipped(format!("refused by the drive: {e}"));
        }
        let resolved = RESOLVED_SHARE * setup.max_mission_speed_rad_s();
        if !(base > 0.0 && MIN_PER_BASE * base < resolved) {
            self.sim.cascade.current.set_field(off).ok();
            return FieldWeakeningSegment::Skipped(format!(
                "base speed {base:.1} rad/s: {MIN_PER_BASE} x base is beyond the bench's resolved speed ({resolved:.1} rad/s, one electrical turn per 12.5 PWM periods)"
            ));
        }
        let model = self.sim.cascade.current.field().max_speed_rad_s(v_bus, pp);
        let allowed = (base + MODEL_SHARE * (model - base)).min(resolved);
        let top = (FIELD_WEAKENING_TOP_PER_BASE * base).min(allowed);
        let goal = (FIELD_WEAKENING_TOP_PER_BASE * base <= allowed)
            .then_some(FIELD_WEAKENING_GOAL_PER_BASE);
        // Half the rated torque, or half what the motor gives at the top
        // speed where that is less.
        let load = (0.5 * setup.kt() * setup.rated_current_a)
            .min(0.5 * model_torque_at(setup, top * pp as f32, v_t));
        let faults0: Vec<_> = self.sim.cascade.feedback().faults.iter().collect();
        let start = self.sim.rows();
        let mut peaks = Peaks {
            phase_a: 0.0,
            bus_v: 0.0,
            id_a: 0.0,
        };
        self.sim.load_nm = 0.0;
        self.come_to_rest(0.01 * top, &mut peaks);
        let n = periods_to(setup, top);
        self.velocity_measured(top, n, &mut peaks);
        let reached = self.velocity_measured(top, secs(setup, HOLD_S), &mut peaks);
        self.sim.load_nm = load;
        let loaded = self.velocity_measured(top, (n / 2).max(secs(setup, HOLD_S)), &mut peaks);
        self.sim.load_nm = 0.0;
        self.velocity_measured(0.0, n, &mut peaks);
        let end_rad_s = self.sim.plant.omega_m_rad_s() as f64;
        // At rest the weakening d current is back at 0: off at once.
        let refused_off = self.sim.cascade.current.set_field(off).err();
        self.velocity_measured(0.0, secs(setup, MEAN_S), &mut peaks);
        self.end_segment("field weakening", start);
        let field = self.sim.cascade.current.field();
        let still_on = match refused_off {
            Some(e) => Some(format!("turning it off was refused: {e}")),
            None if field.config().field_weakening || field.weakening_id_a() != 0.0 => {
                Some(format!("d current {:.3} A", field.weakening_id_a()))
            }
            None => None,
        };
        FieldWeakeningSegment::Ran(FieldWeakeningFigures {
            base_rad_s: base as f64,
            model_top_rad_s: model as f64,
            commanded_rad_s: top as f64,
            reached_rad_s: reached,
            ratio_goal: goal,
            load_nm: load as f64,
            loaded_rad_s: loaded,
            end_rad_s,
            min_id_a: peaks.id_a,
            max_id_a: f64::from(off.max_id_a.min(setup.max_current_a)),
            peak_phase_a: peaks.phase_a,
            limit_a: self.sim.cascade.current.config().limits.max_current_a as f64,
            peak_bus_v: peaks.bus_v,
            faults: self
                .sim
                .cascade
                .feedback()
                .faults
                .iter()
                .filter(|f| !faults0.contains(f))
                .map(|f| f.name().to_string())
                .collect(),
            still_on,
            time_s: (self.sim.rows() - start) as f64 / setup.bench.pwm_frequency_hz as f64,
            wall_time_s: wall.elapsed().as_secs_f64(),
        })
    }

    /// 0 rad/s commanded until the speed is within `tol` [rad/s] for 20 ms
    /// (at most [`REST_S`]).
    fn come_to_rest(&mut self, tol: f32, peaks: &mut Peaks) {
        let setup = self.setup;
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: 0.0 })
            .ok();
        let mut still = 0;
        for _ in 0..secs(setup, REST_S) {
            self.step_measured(peaks);
            let w = self.sim.plant.omega_m_rad_s() as f32;
            still = if w.abs() < tol { still + 1 } else { 0 };
            if still >= secs(setup, 0.02) {
                break;
            }
        }
    }

    /// `w` [rad/s] commanded for `n` periods: the mean true speed over
    /// the last [`MEAN_S`] of them [rad/s].
    fn velocity_measured(&mut self, w: f32, n: usize, peaks: &mut Peaks) -> f64 {
        self.sim
            .cascade
            .command(Command::Velocity { rad_s: w })
            .ok();
        let tail = secs(self.setup, MEAN_S).min(n).max(1);
        let mut sum = 0.0;
        for k in 0..n {
            self.step_measured(peaks);
            if k + tail >= n {
                sum += self.sim.plant.omega_m_rad_s() as f64;
            }
        }
        sum / tail as f64
    }

    /// One period, its peaks noted.
    fn step_measured(&mut self, peaks: &mut Peaks) {
        self.sim.step();
        self.progress.tick(&self.sim);
        let plant = &self.sim.plant;
        for i in plant.phase_currents_a() {
            peaks.phase_a = peaks.phase_a.max((i as f64).abs());
        }
        peaks.bus_v = peaks.bus_v.max(plant.v_bus_v() as f64);
        peaks.id_a = peaks.id_a.min(plant.id_a() as f64);
    }
}
