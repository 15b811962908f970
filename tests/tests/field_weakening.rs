//! Beyond base speed (design §30, issue 37) on every motor file in
//! `tests/motors/`:
//!
//! - MTPA: torque per ampere at the rated and at the maximum current
//!   against `id = 0`, rotor driven at a tenth of base speed (the plant's
//!   torque, measured), and against the model's figure;
//! - field weakening: the highest speed reached from rest / the no-load
//!   base speed at the rated bus (goal >= 2 on the interior-PM file), the
//!   torque available at 1.5 x base speed against the model's optimum on
//!   the voltage ellipse and the current circle;
//! - transitions: from rest to the top speed and back, a reversal, a rated
//!   load step at the top and a bus sagging by 15 % at the top: no fault,
//!   the current within the limit, the bus within its trip, and no braking
//!   beyond the current limit when field weakening is left;
//! - the safe state by speed: a fault at the top speed into a non-sinking
//!   DC link, peak bus voltage and peak phase current freewheeling and
//!   with the active short circuit.
//!
//! Each test prints its figures per motor.

use foc_bench::mission::control_motor;
use foc_bench::mission::{Setup, Sim};
use foc_bench::motor_file::all_motor_files;
use foc_bench::plant::Mechanics;
use foc_bench::power::{DcLinkConfig, SourceKind};
use foc_core::control::field::{is_salient, mtpa_id_a, Field};
use foc_core::control::{BridgeCommand, Command, Fault};

fn setups() -> Vec<(String, Setup)> {
    all_motor_files()
        .iter()
        .map(|p| {
            let stem = p.file_stem().unwrap().to_string_lossy().into_owned();
            let mut s = Setup::load(p).unwrap();
            s.bench.sensors.encoder_offset_rad = 0.0;
            (stem, s)
        })
        .collect()
}

/// A calibrated simulation, field weakening on or off.
fn sim(s: &Setup, fw: bool) -> Sim {
    let mut c = s.cascade_config();
    c.current.field.field_weakening = fw;
    Sim::new_calibrated(s, c, false)
}

/// The drive's d-current reference for this setup (the model's figures).
fn field(s: &Setup, fw: bool) -> Field {
    let c = sim(s, fw);
    *c.cascade.current.field()
}

/// No-load base speed without field weakening [rad/s, mechanical]: the
/// field-weakening target voltage over `p psi`.
fn base_speed(s: &Setup) -> f32 {
    field(s, false).max_speed_rad_s(s.bench.bus_voltage_v as f32, s.motor.pole_pairs)
}

/// The speed the transitions run at: 2.2 x base on a motor whose
/// characteristic current is within the limit, else 60 % of the way from
/// base speed to the model's top speed (torque left for a load); within
/// the mission's resolved speed (one electrical turn per 12.5 periods).
fn top_speed(s: &Setup) -> f32 {
    let f = field(s, true);
    let model = f.max_speed_rad_s(s.bench.bus_voltage_v as f32, s.motor.pole_pairs);
    let base = base_speed(s);
    let w = (2.2 * base).min(base + 0.6 * (model - base));
    w.min(0.8 * s.max_mission_speed_rad_s())
}

/// Runs `n` periods; the first fault, the peak phase current [A] and the
/// highest bus voltage [V].
fn run(sim: &mut Sim, n: usize) -> (Option<Fault>, f32, f32) {
    let (mut i_peak, mut v_peak) = (0.0f32, 0.0f32);
    for _ in 0..n {
        sim.step();
        for i in sim.plant.phase_currents_a() {
            i_peak = i_peak.max(i.abs() as f32);
        }
        v_peak = v_peak.max(sim.plant.v_bus_v() as f32);
        if let Some(f) = sim.cascade.feedback().first_fault {
            return (Some(f), i_peak, v_peak);
        }
    }
    (None, i_peak, v_peak)
}

/// Periods to reach `w` from rest at a third of the current limit's
/// acceleration, at least 0.3 s.
fn periods_to(s: &Setup, w: f32) -> usize {
    let acc = s.kt() * s.max_current_a / 3.0 / s.motor.inertia_kg_m2 as f32;
    ((w / acc).max(0.3) * s.pwm_hz()) as usize
}

/// The drive takes the rotor from rest to `w` itself (velocity mode), then
/// a dyno holds it there. (A rotor spun by the dyno with the bridge off
/// above the rectifying speed drives current through the diodes before
/// the drive starts: not the drive's to control.)
fn spin_up_then_hold(sim: &mut Sim, s: &Setup, w: f32) -> Option<Fault> {
    sim.cascade.command(Command::Velocity { rad_s: w }).unwrap();
    let (fault, _, _) = run(sim, periods_to(s, w));
    sim.plant.set_mechanics(Mechanics::ConstantSpeed(w as f64));
    fault
}

/// Mean plant torque [N m] and current magnitude [A] over `n` periods.
fn mean_torque(sim: &mut Sim, n: usize) -> (f32, f32) {
    let (mut t, mut i) = (0.0, 0.0);
    for _ in 0..n {
        sim.step();
        t += sim.plant.torque_nm();
        i += sim.plant.id_a().hypot(sim.plant.iq_a());
    }
    let f = sim.cascade.feedback().first_fault;
    assert!(f.is_none(), "{f:?}");
    ((t / n as f64) as f32, (i / n as f64) as f32)
}

/// Field weakening is within the bench's resolved speed on this motor,
/// and its angle sensor is a fine one (halls are refused, design §30).
fn resolved(stem: &str, s: &Setup) -> bool {
    if !field(s, true).config().field_weakening {
        println!("{stem}: field weakening refused on a coarse angle sensor (halls)");
        return false;
    }
    let ok = 1.2 * base_speed(s) < 0.8 * s.max_mission_speed_rad_s();
    if !ok {
        println!(
            "{stem}: base speed {:.0} rad/s: above it is beyond the bench's resolved speed \
             ({:.0} rad/s); skipped",
            base_speed(s),
            0.8 * s.max_mission_speed_rad_s()
        );
    }
    ok
}

/// The q current whose MTPA point has magnitude `i_a`.
fn mtpa_iq_for(s: &Setup, i_a: f32) -> f32 {
    let m = &s.motor;
    let dl = (m.lq_h - m.ld_h) as f32;
    let (mut lo, mut hi) = (0.0f32, i_a);
    for _ in 0..60 {
        let iq = 0.5 * (lo + hi);
        let id = mtpa_id_a(m.flux_linkage_wb as f32, dl, iq);
        if id.hypot(iq) > i_a {
            hi = iq;
        } else {
            lo = iq;
        }
    }
    lo
}

#[test]
fn mtpa_gains_torque_per_amp_on_salient_motors_only() {
    for (stem, s) in setups() {
        let base = base_speed(&s);
        let salient = is_salient(&control_motor(&s.motor));
        let mut figures = Vec::new();
        for i_a in [s.rated_current_a, 0.8 * s.max_current_a] {
            let torque = |mtpa: bool| {
                let mut c = s.cascade_config();
                c.current.field.mtpa = mtpa;
                let mut sim = Sim::new_calibrated(&s, c, false);
                sim.plant
                    .set_mechanics(Mechanics::ConstantSpeed(0.1 * base as f64));
                // The torque asked (as the q current at id = 0) whose
                // MTPA point has magnitude `i_a`.
                let iq = if mtpa {
                    let m = &s.motor;
                    let iq_m = mtpa_iq_for(&s, i_a);
                    let dl = (m.lq_h - m.ld_h) as f32;
                    let id_m = mtpa_id_a(m.flux_linkage_wb as f32, dl, iq_m);
                    iq_m * (1.0 - dl * id_m / m.flux_linkage_wb as f32)
                } else {
                    i_a
                };
                sim.cascade.command(Command::Torque { iq_a: iq }).unwrap();
                sim.run((0.05 * s.pwm_hz()) as usize);
                let (t, i) = mean_torque(&mut sim, (0.02 * s.pwm_hz()) as usize);
                assert!((i - i_a).abs() < 0.03 * i_a, "{stem}: |i| {i} for {i_a}");
                t
            };
            let (t0, t1) = (torque(false), torque(true));
            let gain = 100.0 * (t1 / t0 - 1.0);
            // The model's gain (unsaturated inductances).
            let m = &s.motor;
            let iq = mtpa_iq_for(&s, i_a);
            let id = mtpa_id_a(m.flux_linkage_wb as f32, (m.lq_h - m.ld_h) as f32, iq);
            let model = 100.0
                * ((iq * (m.flux_linkage_wb as f32 - (m.lq_h - m.ld_h) as f32 * id))
                    / (i_a * m.flux_linkage_wb as f32)
                    - 1.0);
            figures.push(format!(
                "at {i_a:.1} A: {t0:.3} -> {t1:.3} N m, {gain:+.2} % (model {model:+.2} %)"
            ));
            if salient {
                assert!(
                    gain > 0.5 * model,
                    "{stem}: MTPA gain {gain} % < half of {model} %"
                );
                assert!(gain > 0.0, "{stem}");
            } else {
                assert!(gain.abs() < 0.5, "{stem}: not salient, {gain} %");
            }
        }
        println!(
            "{stem}: {}; {}",
            if salient {
                "salient, MTPA acts"
            } else {
                "not salient, MTPA does not act"
            },
            figures.join("; ")
        );
    }
}

#[test]
fn field_weakening_extends_the_speed_range() {
    for (stem, s) in setups() {
        if !resolved(&stem, &s) {
            continue;
        }
        let base = base_speed(&s);
        let target = top_speed(&s);
        let mut sim = sim(&s, true);
        sim.cascade
            .command(Command::Velocity { rad_s: target })
            .unwrap();
        let (fault, i_peak, _) = run(&mut sim, periods_to(&s, target));
        let reached = sim.plant.omega_m_rad_s() as f32;
        let id = sim.cascade.feedback().i_dq_ref_a.d;
        println!(
            "{stem}: base {base:.1} rad/s, reached {reached:.1} rad/s = {:.2} x base \
             (commanded {target:.1}), id {id:.2} A, peak phase current {i_peak:.2} A \
             (limit {:.1} A)",
            reached / base,
            s.max_current_a
        );
        assert_eq!(fault, None, "{stem}");
        assert!(
            (reached - target).abs() < 0.02 * target,
            "{stem}: {reached} of {target}"
        );
        assert!(reached > 1.05 * base, "{stem}: no speed gained");
        assert!(i_peak < 1.1 * s.max_current_a, "{stem}: {i_peak} A");
        if stem.starts_with("ipm") {
            assert!(reached / base >= 2.0, "{stem}: goal 2 x base");
        }
    }
}

/// The highest torque the model allows at electrical speed `w_e` within
/// the current circle, `|id| <= max_id` and the voltage circle `v` [N m]:
/// `v_d = R id - w Lq iq`, `v_q = R iq + w (psi + Ld id)`.
fn model_torque_at(s: &Setup, w_e: f32, v: f32) -> f32 {
    let max_id = field(s, true).config().max_id_a;
    let m = &s.motor;
    let (psi, ld, lq) = (m.flux_linkage_wb as f32, m.ld_h as f32, m.lq_h as f32);
    let r = m.r_ohm as f32;
    let p = m.pole_pairs as f32;
    let n = 400;
    let mut best = 0.0f32;
    for a in 0..=n {
        let id = -max_id * a as f32 / n as f32;
        let iq_max = (s.max_current_a * s.max_current_a - id * id)
            .max(0.0)
            .sqrt();
        for b in 0..=n {
            let iq = iq_max * b as f32 / n as f32;
            let fits = (r * id - w_e * lq * iq).hypot(r * iq + w_e * (psi + ld * id)) <= v;
            if fits {
                best = best.max(1.5 * p * iq * (psi + (ld - lq) * id));
            }
        }
    }
    best
}

#[test]
fn torque_at_one_and_a_half_times_base_speed_meets_the_model() {
    for (stem, s) in setups() {
        let base = base_speed(&s);
        let w = 1.5 * base;
        if !resolved(&stem, &s) || w > 0.8 * s.max_mission_speed_rad_s() {
            continue;
        }
        let model_top =
            field(&s, true).max_speed_rad_s(s.bench.bus_voltage_v as f32, s.motor.pole_pairs);
        if w > 0.9 * model_top {
            println!("{stem}: 1.5 x base is beyond the model's top speed ({model_top:.1} rad/s); skipped");
            continue;
        }
        let vbus = s.bench.bus_voltage_v as f32;
        let v_t = 0.95 * 0.95 * vbus / 3f32.sqrt();
        let model = model_torque_at(&s, w * s.motor.pole_pairs as f32, v_t);
        if model < 0.2 * s.kt() * s.max_current_a {
            println!(
                "{stem}: at 1.5 x base the model leaves {model:.3} N m (the resistive drop): \
                 skipped"
            );
            continue;
        }
        let mut sim = sim(&s, true);
        assert_eq!(spin_up_then_hold(&mut sim, &s, w), None, "{stem}");
        sim.cascade
            .command(Command::Torque {
                iq_a: s.max_current_a,
            })
            .unwrap();
        sim.run((0.1 * s.pwm_hz()) as usize);
        let (t, _) = mean_torque(&mut sim, (0.02 * s.pwm_hz()) as usize);
        let fb = sim.cascade.feedback();
        println!(
            "{stem}: at {w:.1} rad/s (1.5 x base): {t:.3} N m, model {model:.3} N m ({:.1} %), \
             id {:.2} A, iq {:.2} A",
            100.0 * t / model,
            fb.i_dq_a.d,
            fb.i_dq_a.q
        );
        assert!(t > 0.85 * model, "{stem}: {t} N m of {model}");
        assert!(t < 1.1 * model, "{stem}: {t} N m of {model}");
    }
}

#[test]
fn transitions_above_base_speed_keep_current_control() {
    let mut failures = Vec::new();
    for (stem, s) in setups() {
        if !resolved(&stem, &s) {
            continue;
        }
        let top = top_speed(&s);
        let f = field(&s, true);
        let vbus = s.bench.bus_voltage_v;
        let pp = s.motor.pole_pairs;
        // The load: half the rated torque, or half what the model leaves
        // at the top speed where that is less.
        let v_t = 0.95 * 0.95 * vbus as f32 / 3f32.sqrt();
        let load =
            (0.5 * s.kt() * s.rated_current_a).min(0.5 * model_torque_at(&s, top * pp as f32, v_t));
        // The sagged bus's speed: the top, or 80 % of what the model
        // reaches on 85 % of the bus.
        let sag_w = top.min(0.8 * f.max_speed_rad_s(0.85 * vbus as f32, pp));
        let mut sim = sim(&s, true);
        let mut worst = (0.0f32, 0.0f32);
        let mut seg = |sim: &mut Sim, name: &str, w: f32, load: f32, n: usize| {
            sim.load_nm = load;
            sim.cascade.command(Command::Velocity { rad_s: w }).unwrap();
            let (fault, i_peak, v_peak) = run(sim, n);
            worst = (worst.0.max(i_peak), worst.1.max(v_peak));
            if fault.is_some() || i_peak >= 1.1 * s.max_current_a {
                Err(format!(
                    "{stem}: {name} to {w:.1} rad/s: {fault:?}, {i_peak:.2} A"
                ))
            } else {
                Ok(sim.plant.omega_m_rad_s() as f32)
            }
        };
        let n = periods_to(&s, top);
        let mut run_all = |sim: &mut Sim| -> Result<(f32, f32, f32), String> {
            seg(sim, "up", top, 0.0, n)?;
            let w_loaded = seg(sim, "load step", top, load, n / 2)?;
            // The bus sags by 15 % (a battery under load) and comes back.
            sim.plant.config_mut().bus_voltage_v = 0.85 * vbus;
            let w_sag = seg(sim, "bus sag", sag_w, load, n / 2)?;
            sim.plant.config_mut().bus_voltage_v = vbus;
            seg(sim, "bus back", top, 0.0, n / 2)?;
            let w_rev = seg(sim, "reversal", -top, 0.0, 2 * n)?;
            seg(sim, "stop", 0.0, 0.0, n)?;
            Ok((w_loaded, w_sag, w_rev))
        };
        match run_all(&mut sim) {
            Err(e) => failures.push(e),
            Ok((w_loaded, w_sag, w_rev)) => {
                println!(
                    "{stem}: top {top:.1} rad/s; load {load:.3} N m: {w_loaded:.1} rad/s; \
                     bus at 85 %: {w_sag:.1} (commanded {sag_w:.1}); reversed {w_rev:.1}; \
                     peak phase current {:.2} A (limit {:.1}), peak bus {:.1} V",
                    worst.0, s.max_current_a, worst.1
                );
                if (w_rev + top).abs() > 0.03 * top {
                    failures.push(format!("{stem}: reversal {w_rev}"));
                }
                if sim.plant.omega_m_rad_s().abs() > 0.02 * top as f64 {
                    failures.push(format!("{stem}: stop"));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// A non-sinking DC link of the motor's size (the mission's braking
/// segment's capacitor rule is not needed here: a fixed 10 J/V^2 scale).
fn non_sinking(s: &Setup) -> DcLinkConfig {
    let v = s.bench.bus_voltage_v;
    // Capacitance: 20 periods of the rated power's current per volt.
    let p_rated = (s.kt() * s.rated_current_a * base_speed(s)) as f64;
    let c = 20.0 * p_rated / (v * v * s.bench.pwm_frequency_hz);
    DcLinkConfig {
        c_f: c.max(50e-6),
        esr_ohm: 0.0,
        v_source_v: v,
        r_source_ohm: 0.02,
        i_source_max_a: 1.0e3,
        source: SourceKind::NonSinking,
        brake_resistor_ohm: None,
    }
}

#[test]
fn a_fault_at_top_speed_short_circuits_instead_of_pumping_the_bus() {
    for (stem, s) in setups() {
        if !resolved(&stem, &s) {
            continue;
        }
        let top = top_speed(&s);
        let base = base_speed(&s);
        let mut out = Vec::new();
        for short in [false, true] {
            let mut c = s.cascade_config();
            c.current.field.field_weakening = true;
            c.current.field.short_circuit = short;
            // Over-voltage trip out of the way: the peak is the figure.
            c.current.supervisor.bus_over_voltage_v = 1.0e4;
            let mut sim = Sim::new_calibrated(&s, c, false);
            assert_eq!(spin_up_then_hold(&mut sim, &s, top), None, "{stem}");
            // Light load at the top speed (the dyno holds it), on a
            // non-sinking DC link from here on.
            sim.cascade.command(Command::Torque { iq_a: 0.0 }).unwrap();
            sim.plant.set_dc_link(Some(non_sinking(&s)));
            sim.run((0.05 * s.pwm_hz()) as usize);
            let f = sim.cascade.feedback().first_fault;
            assert!(f.is_none(), "{stem}: {f:?} before the fault");
            // The back-EMF's line-to-line peak against the bus at the fault.
            let m = &s.motor;
            let emf_ll = 3f32.sqrt() * top * m.pole_pairs as f32 * m.flux_linkage_wb as f32;
            let v_at_fault = sim.plant.v_bus_v() as f32;
            sim.cascade.report_fault(Fault::LoopOverrun);
            let (mut i_peak, mut v_peak) = (0.0f32, 0.0f32);
            let mut shorted = false;
            for _ in 0..(0.1 * s.pwm_hz()) as usize {
                let b = sim.step();
                shorted |= b == BridgeCommand::ShortCircuit;
                for i in sim.plant.phase_currents_a() {
                    i_peak = i_peak.max(i.abs() as f32);
                }
                v_peak = v_peak.max(sim.plant.v_bus_v() as f32);
            }
            assert_eq!(
                shorted,
                short && emf_ll > 1.01 * v_at_fault,
                "{stem}: short circuit {short} at {:.2} x base, back-EMF {emf_ll:.1} V \
                 line to line, bus {v_at_fault:.1} V",
                top / base
            );
            out.push((i_peak, v_peak));
        }
        if out.len() < 2 {
            continue;
        }
        println!(
            "{stem}: fault at {top:.1} rad/s ({:.2} x base): freewheeling peak bus {:.1} V, \
             phase {:.2} A; short circuit peak bus {:.1} V, phase {:.2} A",
            top / base,
            out[0].1,
            out[0].0,
            out[1].1,
            out[1].0
        );
        let vbus = s.bench.bus_voltage_v as f32;
        if top > 1.15 * base {
            assert!(
                out[1].1 < 1.05 * vbus,
                "{stem}: the short circuit kept the bus"
            );
            assert!(out[0].1 > out[1].1, "{stem}");
        }
    }
}

/// Switching field weakening off at the top speed does not brake: it
/// stays in force until its d current is back at 0 (design §30), so the
/// speed and the current stay where they were.
#[test]
fn switching_field_weakening_off_at_speed_does_not_brake() {
    let mut failures = Vec::new();
    for (stem, s) in setups() {
        if !resolved(&stem, &s) {
            continue;
        }
        let top = top_speed(&s);
        let mut sim = sim(&s, true);
        sim.cascade
            .command(Command::Velocity { rad_s: top })
            .unwrap();
        let (fault, _, _) = run(&mut sim, periods_to(&s, top));
        assert_eq!(fault, None, "{stem}");
        let mut off = *sim.cascade.current.config();
        off.field.field_weakening = false;
        sim.cascade.current.set_field(off.field).unwrap();
        let id_before = sim.cascade.feedback().i_dq_ref_a.d;
        let (mut w_min, mut t_min) = (f32::INFINITY, f32::INFINITY);
        let mut fault = None;
        for _ in 0..(0.1 * s.pwm_hz()) as usize {
            sim.step();
            w_min = w_min.min(sim.plant.omega_m_rad_s() as f32);
            t_min = t_min.min(sim.plant.torque_nm() as f32);
            fault = fault.or(sim.cascade.feedback().first_fault);
        }
        let id_after = sim.cascade.feedback().i_dq_ref_a.d;
        println!(
            "{stem}: field weakening switched off at {top:.1} rad/s: slowest {w_min:.1} rad/s, \
             least torque {t_min:.3} N m, id {id_before:.2} -> {id_after:.2} A, {fault:?}"
        );
        let max_t = s.kt() * s.max_current_a;
        if fault.is_some() || w_min < 0.98 * top || t_min < -0.05 * max_t {
            failures.push(format!("{stem}: {fault:?}, {w_min} rad/s, {t_min} N m"));
        }
        // Below base speed it is off for good: back at rest, no d current.
        sim.cascade
            .command(Command::Velocity { rad_s: 0.0 })
            .unwrap();
        let (fault, _, _) = run(&mut sim, periods_to(&s, top));
        let id_rest = sim.cascade.current.field().weakening_id_a();
        if fault.is_some() || id_rest != 0.0 {
            failures.push(format!(
                "{stem}: at rest {fault:?}, weakening id {id_rest} A"
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The power limits' regen ramp and the position loop above base speed:
/// from the top speed a stop into a non-sinking DC link (the mission's
/// braking link, no brake resistor) keeps the bus below its trip with no
/// fault while the regen limit holds the braking; a position move whose
/// trajectory cruises at the top speed reaches its target.
#[test]
fn regen_limit_and_position_moves_above_base_speed() {
    use foc_bench::mission::braking_dc_link;
    use foc_core::control::power::PowerLimitsConfig;
    let mut failures = Vec::new();
    for (stem, s) in setups() {
        if !resolved(&stem, &s) {
            continue;
        }
        let top = top_speed(&s);
        let base = base_speed(&s);
        // (a) regen ramp.
        let mut c = s.cascade_config();
        c.current.field.field_weakening = true;
        let motor = c.current.current.motor;
        c.current.power = Some(PowerLimitsConfig::for_board(
            &c.current.supervisor,
            motor,
            false,
        ));
        let trip = c.current.supervisor.bus_over_voltage_v;
        let mut link = braking_dc_link(&s, &c.current.supervisor);
        link.source = SourceKind::NonSinking;
        link.brake_resistor_ohm = None;
        let mut sim = Sim::new_calibrated(&s, c, false);
        sim.cascade
            .command(Command::Velocity { rad_s: top })
            .unwrap();
        let (fault, _, _) = run(&mut sim, periods_to(&s, top));
        sim.plant.set_dc_link(Some(link));
        sim.cascade
            .command(Command::Velocity { rad_s: 0.0 })
            .unwrap();
        // The d reference stays within the deeper of the weakening's
        // bound and the regen ramp's braking alone (design §30).
        let max_id = sim.cascade.current.field().config().max_id_a;
        let mut id_min = 0.0f32;
        let (mut fault2, mut i_peak, mut v_peak) = (None, 0.0f32, 0.0f32);
        for _ in 0..(0.3 * s.pwm_hz()) as usize {
            let (f, i, v) = run(&mut sim, 1);
            id_min = id_min.min(sim.cascade.feedback().i_dq_ref_a.d);
            fault2 = fault2.or(f);
            i_peak = i_peak.max(i);
            v_peak = v_peak.max(v);
            if f.is_some() {
                break;
            }
        }
        // The regen ramp alone may ask up to the current limit on d (its
        // `regen_id_max_a` is not bounded by default); the two are not
        // summed.
        let d_bound = max_id.max(s.max_current_a);
        if id_min < -1.001 * d_bound {
            failures.push(format!("{stem}: d reference {id_min} A beyond {d_bound} A"));
        }
        let w_end = sim.plant.omega_m_rad_s() as f32;
        println!(
            "{stem}: stop from {top:.1} rad/s into {:.0} uF, non-sinking: peak bus {v_peak:.1} V \
             (trip {trip:.1} V), peak phase {i_peak:.2} A, deepest d reference {id_min:.2} A, \
             {w_end:.1} rad/s after 0.3 s, \
             {:?}",
            link.c_f * 1e6,
            fault.or(fault2)
        );
        if fault.or(fault2).is_some() || v_peak >= trip || w_end >= 0.99 * top {
            failures.push(format!(
                "{stem}: regen {:?}, {v_peak} V, {w_end} rad/s",
                fault.or(fault2)
            ));
        }
        // (b) position move cruising at the top speed.
        let mut c = s.cascade_config();
        c.current.field.field_weakening = true;
        c.position.max_velocity_rad_s = top;
        let a = c.position.max_acceleration_rad_s2;
        let distance = top * top / a + 0.2 * top;
        let mut sim = Sim::new_calibrated(&s, c, false);
        sim.cascade
            .command(Command::Position { rad: distance })
            .unwrap();
        let n = ((2.0 * top / a + 0.2 + 0.5) * s.pwm_hz()) as usize;
        let mut w_max = 0.0f32;
        let mut fault = None;
        for _ in 0..n {
            sim.step();
            w_max = w_max.max(sim.plant.omega_m_rad_s() as f32);
            fault = fault.or(sim.cascade.feedback().first_fault);
        }
        let err = sim.cascade.feedback().position_rad - distance;
        println!(
            "{stem}: position move of {distance:.1} rad cruising at {:.2} x base: \
             final error {err:.4} rad, {fault:?}",
            w_max / base
        );
        if fault.is_some() || err.abs() > 0.01 || w_max < 1.1 * base {
            failures.push(format!(
                "{stem}: position {fault:?}, error {err}, {w_max} rad/s"
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The short circuit is released to freewheeling as the speed falls
/// (below 90 % of the rectifying speed), and a fault that forbids
/// switching (the gate driver) turns everything off at any speed.
#[test]
fn the_short_circuit_is_released_as_the_speed_falls() {
    for (stem, s) in setups() {
        if !stem.starts_with("ipm") {
            continue;
        }
        let top = top_speed(&s);
        let m = &s.motor;
        let vbus = s.bench.bus_voltage_v as f32;
        let rectify = vbus / (3f32.sqrt() * m.pole_pairs as f32 * m.flux_linkage_wb as f32);
        let mut sim = sim(&s, true);
        assert_eq!(spin_up_then_hold(&mut sim, &s, top), None, "{stem}");
        sim.cascade.report_fault(Fault::LoopOverrun);
        // The dyno slows the rotor from the top speed to rest in 0.4 s.
        let n = (0.4 * s.pwm_hz()) as usize;
        let mut released_at = None;
        for k in 0..n {
            let w = top * (1.0 - k as f32 / n as f32);
            sim.plant.set_mechanics(Mechanics::ConstantSpeed(w as f64));
            let b = sim.step();
            if k > 2 && w > rectify {
                assert_eq!(b, BridgeCommand::ShortCircuit, "{stem} at {w} rad/s");
            }
            if b == BridgeCommand::SafeState && released_at.is_none() {
                released_at = Some(w);
            }
            if released_at.is_some() {
                assert_eq!(
                    b,
                    BridgeCommand::SafeState,
                    "{stem} at {w}: released for good"
                );
            }
        }
        let released = released_at.expect("released");
        println!(
            "{stem}: short circuit from {top:.1} rad/s, released at {released:.1} rad/s \
             ({:.2} of the rectifying speed {rectify:.1} rad/s)",
            released / rectify
        );
        assert!((released / rectify - 0.9).abs() < 0.03, "{stem}");
        // An angle-sensor fault at the top speed (the reading lost): the
        // speed just before it is the one judged by, the short circuit.
        let mut other = self::sim(&s, true);
        assert_eq!(spin_up_then_hold(&mut other, &s, top), None, "{stem}");
        let mut shorted = 0;
        for _ in 0..20 {
            let mut smp = other.sample();
            smp.angle = None;
            shorted += usize::from(other.step_with(&smp) == BridgeCommand::ShortCircuit);
        }
        assert_eq!(
            other.cascade.feedback().first_fault,
            Some(Fault::AngleSensorError),
            "{stem}"
        );
        assert!(shorted >= 19, "{stem}: {shorted} of 20 periods shorted");
        // A gate-driver fault at the top speed: everything off.
        let mut other = self::sim(&s, true);
        assert_eq!(spin_up_then_hold(&mut other, &s, top), None, "{stem}");
        other.cascade.report_fault(Fault::GateDriverFault);
        for _ in 0..10 {
            assert_eq!(other.step(), BridgeCommand::SafeState, "{stem}");
        }
    }
}

/// The sensor supervision (design §24) expects the voltage field weakening
/// applies: with the plant's R and L 30 % off the drive's model either way
/// (and its winding at 120 deg C), up to the top speed, a load step there
/// and back to rest trip nothing.
#[test]
fn supervision_stays_quiet_above_base_speed_with_the_model_off() {
    use foc_bench::plant::{MotorParams, Plant};
    let mut failures = Vec::new();
    for (stem, s) in setups() {
        if !resolved(&stem, &s) {
            continue;
        }
        let top = top_speed(&s);
        let m = s.motor;
        let scaled = |r: foc_bench::real::Real, l: foc_bench::real::Real| MotorParams {
            r_ohm: m.r_ohm * r,
            ld_h: m.ld_h * l,
            lq_h: m.lq_h * l,
            ..m
        };
        for (name, plant_motor) in [
            ("R +30 %, L -30 %", scaled(1.3, 0.7)),
            ("R -30 %, L +30 %", scaled(0.7, 1.3)),
            ("R +30 % at 120 C, L +30 %", scaled(1.3 * 1.39, 1.3)),
        ] {
            let mut c = s.cascade_config();
            c.current.field.field_weakening = true;
            let mut sim = Sim::with_plant(&s, Plant::new(plant_motor, s.bench), c, false);
            sim.cascade.set_calibration(&s.supplied_calibration(&c));
            // The top speed the plant reaches may be lower than the
            // model's: 90 % of it.
            let w = 0.9 * top;
            sim.cascade.command(Command::Velocity { rad_s: w }).unwrap();
            let (f1, i1, _) = run(&mut sim, periods_to(&s, w));
            let (f2, i2) = if f1.is_none() {
                sim.cascade
                    .command(Command::Velocity { rad_s: 0.0 })
                    .unwrap();
                let (f2, i2, _) = run(&mut sim, periods_to(&s, w));
                (f2, i2)
            } else {
                (None, 0.0)
            };
            let margin = sim.cascade.current.model_check().peak_ratio();
            let reached = sim.plant.omega_m_rad_s();
            println!(
                "{stem}, {name}: to {w:.1} rad/s and back: {:?} (at {reached:.1} rad/s), \
                 peak phase {:.2} A, model-check margin {margin:.2}",
                f1.or(f2),
                i1.max(i2)
            );
            // A speed a hotter, more resistive plant cannot reach trips
            // `SpeedRunaway` (its job); a sensor fault would be false.
            if let Some(f) = f1.or(f2) {
                if f != Fault::SpeedRunaway {
                    failures.push(format!("{stem}, {name}: {f:?}"));
                }
            }
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// A closed-loop start with the bridge off above base speed is refused
/// (design §30): the rotor turning at twice base speed in the short
/// circuit, faults cleared, a velocity command: the drive stays off, no
/// over-current, the bus at its level; below base speed it starts.
#[test]
fn a_start_above_base_speed_is_refused() {
    for (stem, s) in setups() {
        if !stem.starts_with("ipm") {
            continue;
        }
        let top = top_speed(&s);
        let base = base_speed(&s);
        let mut c = s.cascade_config();
        c.current.field.field_weakening = true;
        let mut sim = Sim::new_calibrated(&s, c, false);
        assert_eq!(spin_up_then_hold(&mut sim, &s, top), None, "{stem}");
        sim.cascade.report_fault(Fault::LoopOverrun);
        sim.run(10);
        sim.cascade.clear_faults();
        sim.run(2);
        sim.cascade
            .command(Command::Velocity { rad_s: top })
            .unwrap();
        let (fault, i_peak, v_peak) = run(&mut sim, (0.05 * s.pwm_hz()) as usize);
        let mode = sim.cascade.feedback().mode;
        println!(
            "{stem}: velocity command at {:.2} x base after a fault: mode {mode:?}, {fault:?}, \
             peak phase {i_peak:.2} A, peak bus {v_peak:.1} V",
            top / base
        );
        assert_eq!(fault, None, "{stem}");
        assert_eq!(mode, foc_core::control::Mode::Disabled, "{stem}");
        assert!(v_peak < 1.05 * s.bench.bus_voltage_v as f32, "{stem}");
        // Below base speed the same command is taken.
        sim.plant
            .set_mechanics(Mechanics::ConstantSpeed(0.5 * base as f64));
        sim.run((0.02 * s.pwm_hz()) as usize);
        sim.cascade
            .command(Command::Velocity { rad_s: 0.5 * base })
            .unwrap();
        sim.run(10);
        assert_eq!(
            sim.cascade.feedback().mode,
            foc_core::control::Mode::Velocity,
            "{stem}"
        );
    }
}
