//! Physics checks of the plant: each asserts a law the model could violate.

use foc_bench::plant::{
    BenchConfig, Cogging, DSaturation, EncoderFault, Mechanics, MotorParams, Phase, PhaseShort,
    Plant, PwmMode, SensorConfig, Shunts,
};
use foc_bench::real::Real;
use foc_core::angle::ElectricalAngle;
use foc_core::hal::PhaseCurrents;
use foc_core::transforms;

fn motor() -> MotorParams {
    MotorParams {
        pole_pairs: 4,
        r_ohm: 0.5,
        ld_h: 1.0e-3,
        lq_h: 1.6e-3,
        flux_linkage_wb: 0.02,
        inertia_kg_m2: 2e-4,
        viscous_friction_nm_s_per_rad: 0.0,
        coulomb_friction_nm: 0.0,
        d_saturation: DSaturation::NONE,
    }
}

fn cfg() -> BenchConfig {
    BenchConfig {
        pwm_frequency_hz: 15_000.0,
        substeps: 16,
        bus_voltage_v: 24.0,
        compute_delay_periods: 0,
        sensors: SensorConfig::ideal(),
        ..BenchConfig::default()
    }
}

/// Duties that make the motor see `v_dq` during the next period (angle taken
/// at mid-period), computed with foc-core's own transforms: if the plant's
/// frame and foc-core's disagree, the tests using this fail.
fn duties_for(plant: &Plant, vd: Real, vq: Real) -> [f32; 3] {
    let t = plant.config().period_s();
    let theta = plant.theta_e_rad() + plant.omega_e_rad_s() * 0.5 * t;
    let (s, c) = libm::sincosf(theta as f32);
    let v = transforms::inverse_clarke(transforms::inverse_park(
        foc_core::frames::Dq::new(vd as f32, vq as f32),
        s,
        c,
    ));
    let vb = plant.v_bus_v() as f32;
    [0.5 + v.a / vb, 0.5 + v.b / vb, 0.5 + v.c / vb]
}

#[test]
fn locked_rotor_step_is_first_order_with_ld_and_lq() {
    let m = motor();
    for (axis, theta_e, l) in [
        ("d", 0.0, m.ld_h),
        ("q", -core::f64::consts::FRAC_PI_2, m.lq_h),
    ] {
        let mut p = Plant::new(m, cfg());
        p.set_rotor_angle(theta_e / m.pole_pairs as Real);
        p.set_mechanics(Mechanics::Locked);
        // Phase A up, B and C down: the voltage vector lies on the A axis.
        let delta = 0.02f32;
        let duties = [0.5 + delta, 0.5 - delta / 2.0, 0.5 - delta / 2.0];
        let v = 24.0 * delta as Real; // phase-A voltage to the star point: V_bus (d_a - mean d)
        let i_final = v / m.r_ohm;
        let tau = l / m.r_ohm;
        let t = p.config().period_s();
        let mut worst: Real = 0.0;
        for k in 1..=600 {
            let meas = p.step_period(duties, true, 0.0);
            let expected = i_final * (1.0 - (-(k as Real) * t / tau).exp());
            let ia = meas.currents.to_abc().a as Real;
            worst = worst.max((ia - expected).abs() / i_final);
            // The current lies on the A axis: d at theta_e = 0, q at -90 deg.
            let (on, off) = if axis == "d" {
                (p.id_a(), p.iq_a())
            } else {
                (p.iq_a(), -p.id_a())
            };
            assert!(
                (on - ia).abs() < 1e-3 * i_final && off.abs() < 1e-3 * i_final,
                "{axis}"
            );
        }
        assert!(
            worst < 0.01,
            "{axis} axis: worst error {:.3} %",
            worst * 100.0
        );
    }
}

#[test]
fn computation_delay_holds_new_duties_one_period() {
    let mut c = cfg();
    c.compute_delay_periods = 1;
    let mut p = Plant::new(motor(), c);
    p.set_mechanics(Mechanics::Locked);
    let step = [0.6f32, 0.45, 0.45];
    let m1 = p.step_period(step, true, 0.0);
    assert!(m1.currents.to_abc().a.abs() < 1e-4, "applied without delay");
    let m2 = p.step_period(step, true, 0.0);
    assert!(
        m2.currents.to_abc().a > 0.05,
        "not applied after one period"
    );
}

/// Phasor of `x(t)` at `w` [rad/s] by correlation over whole cycles.
fn phasor(samples: &[(Real, Real)], w: Real) -> (Real, Real) {
    let (mut re, mut im) = (0.0, 0.0);
    for (t, x) in samples {
        re += x * (w * t).cos();
        im -= x * (w * t).sin();
    }
    let n = samples.len() as Real;
    let (re, im) = (2.0 * re / n, 2.0 * im / n);
    ((re * re + im * im).sqrt(), im.atan2(re))
}

#[test]
fn open_circuit_back_emf_amplitude_and_phase_order() {
    let m = motor();
    for dir in [1.0, -1.0] {
        let mut p = Plant::new(m, cfg());
        let w_m = dir * 40.0; // rad/s: line-to-line EMF peak 5.5 V < 24 V bus
        p.set_mechanics(Mechanics::ConstantSpeed(w_m));
        let we = w_m * m.pole_pairs as Real;
        let t = p.config().period_s();
        let cycles = 4.0;
        let n = (cycles * core::f64::consts::TAU / we.abs() / t).round() as usize;
        let mut va = Vec::new();
        let mut vb = Vec::new();
        let mut vc = Vec::new();
        for _ in 0..n {
            let tm = p.time_s() + 0.5 * t;
            p.step_period([0.5; 3], false, 0.0);
            let v = p.terminal_voltages_avg_v();
            let mean = (v[0] + v[1] + v[2]) / 3.0;
            va.push((tm, v[0] - mean));
            vb.push((tm, v[1] - mean));
            vc.push((tm, v[2] - mean));
            assert!(
                p.phase_currents_a().iter().all(|i| *i == 0.0),
                "EMF below bus drove current"
            );
        }
        let (amp_a, ph_a) = phasor(&va, we.abs());
        let (amp_b, ph_b) = phasor(&vb, we.abs());
        let (_, ph_c) = phasor(&vc, we.abs());
        let expected = we.abs() * m.flux_linkage_wb;
        for amp in [amp_a, amp_b] {
            assert!(
                (amp - expected).abs() < 0.01 * expected,
                "amplitude {amp} vs {expected}"
            );
        }
        // B lags A by 120 deg and C lags B by 120 deg for positive speed.
        let lag = |x: Real, y: Real| (x - y).rem_euclid(core::f64::consts::TAU).to_degrees();
        let (ab, bc) = (lag(ph_a, ph_b), lag(ph_b, ph_c));
        let want = if dir > 0.0 { 120.0 } else { 240.0 };
        assert!(
            (ab - want).abs() < 1.0 && (bc - want).abs() < 1.0,
            "dir {dir}: {ab} {bc}"
        );
    }
}

#[test]
fn applying_the_back_emf_gives_zero_current() {
    // The voltage that drives no current is the back-EMF: vq = w_e psi.
    let m = motor();
    let mut p = Plant::new(m, cfg());
    let w_m = 60.0;
    p.set_mechanics(Mechanics::ConstantSpeed(w_m));
    let we = w_m * m.pole_pairs as Real;
    let mut worst: Real = 0.0;
    for _ in 0..3000 {
        let d = duties_for(&p, 0.0, we * m.flux_linkage_wb);
        p.step_period(d, true, 0.0);
        worst = worst.max(p.id_a().hypot(p.iq_a()));
    }
    // Short-circuit current for scale.
    let isc = we * m.flux_linkage_wb / m.r_ohm.hypot(we * m.lq_h);
    assert!(
        worst < 0.02 * isc,
        "residual {worst} A vs short-circuit {isc} A"
    );
}

#[test]
fn constant_iq_accelerates_at_te_over_j() {
    let m = motor();
    let mut p = Plant::new(m, cfg());
    // Small enough that the voltage stays in the linear range over the run.
    let iq = 2.0;
    p.set_currents_dq(0.0, iq);
    let t = p.config().period_s();
    let mut w_start = None;
    let n = 1500;
    for k in 0..n {
        let we = p.omega_e_rad_s();
        // Steady-state voltages for (0, iq) at the present speed.
        let d = duties_for(&p, -we * m.lq_h * iq, m.r_ohm * iq + we * m.flux_linkage_wb);
        p.step_period(d, true, 0.0);
        assert!(
            (p.iq_a() - iq).abs() < 0.03 * iq && p.id_a().abs() < 0.03 * iq,
            "k {k}"
        );
        if k == 499 {
            w_start = Some(p.omega_m_rad_s());
        }
    }
    let w0 = w_start.unwrap();
    let accel = (p.omega_m_rad_s() - w0) / ((n - 500) as Real * t);
    let expected = 1.5 * m.pole_pairs as Real * m.flux_linkage_wb * iq / m.inertia_kg_m2;
    assert!(
        (accel - expected).abs() < 0.01 * expected,
        "{accel} vs {expected}"
    );
    assert!(
        p.omega_m_rad_s() > 0.0,
        "positive iq must turn the rotor forward"
    );
}

/// A saturated d axis: from rest, a d voltage pulse reaches `+c` in
/// `Ld (c - f c / 2) / V` and `-c` in `Ld (c + f c / 2) / V` (negligible
/// R): the current along the magnet meets less inductance.
#[test]
fn d_saturation_lowers_the_inductance_along_the_magnet() {
    let mut m = motor();
    m.r_ohm = 1e-4;
    m.d_saturation = DSaturation {
        fraction: 0.2,
        current_a: 2.0,
    };
    let v = 0.2;
    for sign in [1.0, -1.0] {
        let mut p = Plant::new(m, cfg());
        p.set_mechanics(Mechanics::Locked);
        let t = p.config().period_s();
        let mut periods = 0u32;
        while sign * p.id_a() < 2.0 && periods < 10_000 {
            p.step_period(duties_for(&p, sign * v, 0.0), true, 0.0);
            periods += 1;
        }
        let expected_s = m.ld_h * (2.0 - sign * 0.2 * 2.0 / 2.0) / v;
        let took_s = periods as Real * t;
        assert!(
            (took_s - expected_s).abs() < 0.02 * expected_s,
            "{sign:+}: {took_s} s against {expected_s} s"
        );
        // The flux reached: the magnet's plus or minus 1.8 or 2.2 mWb.
        let flux = m.d_flux_wb(p.id_a()) - m.flux_linkage_wb;
        assert!(
            (flux - v * took_s * sign).abs() < 0.03 * flux.abs(),
            "{flux}"
        );
    }
}

#[test]
fn energy_is_conserved_with_a_saturated_d_axis() {
    energy_balance_of(
        MotorParams {
            d_saturation: DSaturation {
                fraction: 0.3,
                current_a: 1.5,
            },
            ..motor()
        },
        (4.0, 2.5),
        PwmMode::Averaged,
        0.0,
        None,
    );
}

fn energy_balance(mode: PwmMode, dead_time_s: Real) {
    energy_balance_of(motor(), (4.0, -1.0), mode, dead_time_s, None);
}

/// Energy stored in the windings, the rotor's motion and the cogging
/// field \[J\].
fn stored_j(p: &Plant) -> Real {
    p.magnetic_energy_j() + p.kinetic_energy_j() + p.cogging_energy_j()
}

fn energy_balance_of(
    m: MotorParams,
    (iq, id): (Real, Real),
    mode: PwmMode,
    dead_time_s: Real,
    cogging: Option<Cogging>,
) {
    let mut m = m;
    m.viscous_friction_nm_s_per_rad = 2e-4;
    m.coulomb_friction_nm = 0.01;
    m.inertia_kg_m2 = 2e-3; // keeps the speed (and voltage) in the linear range
    let mut c = cfg();
    c.pwm_mode = mode;
    c.dead_time_s = dead_time_s;
    c.source_resistance_ohm = 0.2;
    let mut p = Plant::new(m, c);
    p.set_cogging(cogging);
    let e0 = stored_j(&p);
    let cogging_e0 = p.cogging_energy_j();
    for _ in 0..4000 {
        let we = p.omega_e_rad_s();
        let d = duties_for(
            &p,
            m.r_ohm * id - we * m.lq_h * iq,
            m.r_ohm * iq + we * m.d_flux_wb(id),
        );
        p.step_period(d, true, 0.05);
    }
    let e = *p.energy();
    let stored = stored_j(&p) - e0;
    let out = e.copper_j + e.friction_j + e.load_j + stored;
    assert!(e.supply_j > 0.1, "no energy moved: {e:?}");
    assert!(
        (e.supply_j - out).abs() < 0.002 * e.supply_j,
        "{mode:?}: supply {} J vs copper+friction+load+stored {} J",
        e.supply_j,
        out
    );
    // Shaft and cogging work split into friction, load and kinetic energy.
    let mech = e.friction_j + e.load_j + p.kinetic_energy_j();
    assert!((e.shaft_j + e.cogging_j - mech).abs() < 0.002 * e.shaft_j);
    // The cogging's work is minus its energy's change (0 without).
    let released = cogging_e0 - p.cogging_energy_j();
    assert!(
        (e.cogging_j - released).abs() < 1e-6 * e.shaft_j,
        "cogging work {} J vs released {released} J",
        e.cogging_j
    );
    // The bus sagged by R_source * i_dc.
    let sag = 24.0 - p.v_bus_avg_v();
    assert!(sag > 0.0 && p.supply_current_a() > 0.0);
    assert!(
        (sag - 0.2 * p.supply_current_a()).abs() < 0.05 * sag,
        "sag {sag} i_dc {} p_in {} w {}",
        p.supply_current_a(),
        p.input_power_w(),
        p.omega_m_rad_s()
    );
}

#[test]
fn energy_is_conserved_averaged() {
    energy_balance(PwmMode::Averaged, 0.0);
}

#[test]
fn energy_is_conserved_carrier_with_dead_time() {
    energy_balance(PwmMode::CarrierCompared, 500e-9);
}

#[test]
fn energy_is_conserved_with_cogging() {
    // 12 slots, 4 pole pairs: 24 cycles per turn, a tenth of the 0.48 N m.
    let cogging = Cogging::from_slots(12, 4, 0.05, 0.3);
    for mode in [PwmMode::Averaged, PwmMode::CarrierCompared] {
        energy_balance_of(motor(), (4.0, -1.0), mode, 300e-9, Some(cogging));
    }
}

#[test]
fn averaged_and_carrier_agree_on_the_centre_sample() {
    let m = motor();
    let run = |mode| {
        let mut c = cfg();
        c.pwm_mode = mode;
        let mut p = Plant::new(m, c);
        p.set_mechanics(Mechanics::ConstantSpeed(50.0));
        let mut out = Vec::new();
        for _ in 0..1500 {
            // Open-loop rotating voltage, same duties in both runs.
            let d = duties_for(&p, 0.5, 3.0 + 200.0 * m.flux_linkage_wb);
            let meas = p.step_period(d, true, 0.0);
            out.push(meas.currents.to_abc());
        }
        out
    };
    let a = run(PwmMode::Averaged);
    let c = run(PwmMode::CarrierCompared);
    let peak = a.iter().map(|x| x.a.abs()).fold(0.0f32, f32::max);
    let worst = a
        .iter()
        .zip(&c)
        .map(|(x, y)| (x.a - y.a).abs().max((x.b - y.b).abs()))
        .fold(0.0f32, f32::max);
    assert!(peak > 1.0, "peak {peak}");
    assert!(worst < 0.02 * peak, "worst {worst} A of peak {peak} A");
}

#[test]
fn dead_time_voltage_error_opposes_current() {
    let m = motor();
    let td = 1e-6;
    let steady = |delta: f32, dead: Real, mode| {
        let mut c = cfg();
        c.dead_time_s = dead;
        c.pwm_mode = mode;
        let mut p = Plant::new(m, c);
        p.set_mechanics(Mechanics::Locked);
        let d = [0.5 + delta, 0.5 - delta / 2.0, 0.5 - delta / 2.0];
        for _ in 0..1500 {
            p.step_period(d, true, 0.0);
        }
        p.phase_currents_a()[0]
    };
    for mode in [PwmMode::Averaged, PwmMode::CarrierCompared] {
        for delta in [0.03f32, -0.03] {
            let ideal = steady(delta, 0.0, mode);
            let with = steady(delta, td, mode);
            // Phase A error -sgn(i) V t_d f; B and C the opposite; A to star: 4/3 of it.
            let dv = -ideal.signum() * 24.0 * td * 15_000.0 * 4.0 / 3.0;
            let expected = dv / m.r_ohm;
            let got = with - ideal;
            assert!(
                got.signum() == -ideal.signum(),
                "{mode:?}: error must oppose the current"
            );
            assert!(
                (got - expected).abs() < 0.02 * expected.abs(),
                "{mode:?} {got} vs {expected}"
            );
        }
    }
}

#[test]
fn disabled_bridge_currents_decay_to_zero_and_stay() {
    let m = motor();
    let mut p = Plant::new(m, cfg());
    p.set_mechanics(Mechanics::ConstantSpeed(20.0));
    p.set_currents_dq(2.0, 5.0);
    let mut e_before = None;
    for k in 0..300 {
        p.step_period([0.5; 3], false, 0.0);
        if k == 0 {
            e_before = Some(p.energy().supply_j);
        }
    }
    assert!(
        p.phase_currents_a().iter().all(|i| *i == 0.0),
        "{:?}",
        p.phase_currents_a()
    );
    // The inductive energy went back to the bus through the diodes.
    assert!(e_before.unwrap() < 0.0);
}

#[test]
fn disabled_bridge_rectifies_when_emf_exceeds_bus() {
    let m = motor();
    let mut c = cfg();
    c.bus_voltage_v = 12.0;
    let mut p = Plant::new(m, c);
    p.set_speed(300.0); // line-to-line EMF peak = sqrt3 * 1200 * 0.02 = 41.6 V
    for _ in 0..3000 {
        p.step_period([0.5; 3], false, 0.0);
    }
    let e = *p.energy();
    assert!(e.supply_j < -0.5, "no regeneration: {e:?}");
    assert!(p.omega_m_rad_s() < 300.0 * 0.9, "no braking");
    // Kinetic energy lost = returned to bus + copper loss.
    let lost =
        0.5 * m.inertia_kg_m2 * (300.0f64 * 300.0) - p.kinetic_energy_j() - p.magnetic_energy_j();
    assert!(
        (lost - (-e.supply_j + e.copper_j)).abs() < 0.005 * lost,
        "{lost} vs {e:?}"
    );
    // Below the bus the rotor coasts with no current.
    let line_peak = 3f64.sqrt() * p.omega_e_rad_s().abs() * m.flux_linkage_wb;
    assert!(
        line_peak > 11.0 && line_peak < 12.5,
        "settled EMF {line_peak}"
    );
}

#[test]
fn sensors_quantise_and_faults_show_up() {
    let m = motor();
    let mut c = cfg();
    c.sensors = SensorConfig {
        current_full_scale_a: 20.0,
        encoder_counts_per_rev: 4096,
        shunts: Shunts::Two,
        ..SensorConfig::default()
    };
    let mut p = Plant::new(m, c);
    p.set_mechanics(Mechanics::Locked);
    p.set_rotor_angle(1.0);
    let d = [0.55f32, 0.475, 0.475];
    let mut meas = p.step_period(d, true, 0.0);
    for _ in 0..200 {
        meas = p.step_period(d, true, 0.0);
    }
    let lsb = 40.0 / 4096.0;
    let true_i = p.phase_currents_a();
    match meas.currents {
        PhaseCurrents::TwoPhase { a_a, b_a } => {
            assert!((a_a as Real - true_i[0]).abs() <= 0.5 * lsb + 1e-6);
            assert!((b_a as Real - true_i[1]).abs() <= 0.5 * lsb + 1e-6);
            // Quantised to the LSB.
            let q = a_a as Real / lsb;
            assert!((q - q.round()).abs() < 1e-3);
        }
        PhaseCurrents::ThreePhase(_) => panic!("two shunts configured"),
    }
    let enc = meas.angle.to_radians() as Real;
    let step = core::f64::consts::TAU / 4096.0;
    assert!(enc <= 1.0 + 1e-6 && 1.0 - enc < step, "encoder {enc}");
    // Bus reading within one LSB of 72 V / 4096.
    assert!((meas.v_bus_v as Real - 24.0).abs() < 72.0 / 4096.0);

    // Faults.
    p.faults_mut().encoder_reversed = true;
    let r = p.step_period(d, true, 0.0).angle.to_radians() as Real;
    assert!(
        (r - (core::f64::consts::TAU - 1.0)).abs() < 2.0 * step,
        "reversed {r}"
    );
    p.faults_mut().encoder_reversed = false;
    p.faults_mut().encoder = EncoderFault::Jump(1024);
    let j = p.step_period(d, true, 0.0).angle.to_radians() as Real;
    assert!(
        (j - (1.0 + core::f64::consts::FRAC_PI_2)).abs() < 2.0 * step,
        "jump {j}"
    );
    p.faults_mut().encoder = EncoderFault::Stuck;
    p.set_rotor_angle(2.0);
    let s = p.step_period(d, true, 0.0).angle.to_radians() as Real;
    assert!((s - j).abs() < 1e-6, "stuck moved");
    p.faults_mut().encoder = EncoderFault::None;

    p.faults_mut().nan_current = Some(Phase::B);
    assert!(!p.step_period(d, true, 0.0).currents.to_abc().is_finite());
    p.faults_mut().nan_current = None;
    p.faults_mut().current_reversed = Some(Phase::A);
    let rev = p.step_period(d, true, 0.0).currents.to_abc();
    assert!((rev.a as Real + p.phase_currents_a()[0]).abs() < lsb);
    p.faults_mut().current_reversed = None;
    p.faults_mut().current_offset_error_a = [0.5, 0.0, 0.0];
    let off = p.step_period(d, true, 0.0).currents.to_abc();
    assert!((off.a as Real - p.phase_currents_a()[0] - 0.5).abs() < lsb);
}

#[test]
fn disconnected_phase_and_phase_short() {
    let m = motor();
    let mut p = Plant::new(m, cfg());
    p.set_mechanics(Mechanics::Locked);
    p.faults_mut().disconnected_phase = Some(Phase::C);
    let d = [0.6f32, 0.4, 0.5];
    for _ in 0..500 {
        p.step_period(d, true, 0.0);
    }
    let i = p.phase_currents_a();
    assert!(i[2].abs() < 1e-6, "open phase carries {}", i[2]);
    // A and B in series: 2R, driven by the A-B line voltage 0.2 * 24 V.
    let expected = 0.2 * 24.0 / (2.0 * m.r_ohm);
    assert!(
        (i[0] - expected).abs() < 0.01 * expected && (i[1] + i[0]).abs() < 1e-6,
        "{i:?}"
    );

    let mut p = Plant::new(m, cfg());
    p.set_mechanics(Mechanics::Locked);
    let normal = p.step_period(d, true, 0.0).currents.to_abc();
    p.faults_mut().phase_short = Some(PhaseShort {
        a: Phase::A,
        b: Phase::B,
        r_ohm: 0.01,
    });
    let short = p.step_period(d, true, 0.0).currents.to_abc();
    assert!(
        short.a > 100.0 && short.b < -100.0,
        "{short:?} vs {normal:?}"
    );
    assert!(p.supply_current_a() > 50.0);
}

#[test]
fn bus_sag_fault_lowers_the_bus() {
    let mut p = Plant::new(motor(), cfg());
    p.faults_mut().bus_sag_v = 6.0;
    let m = p.step_period([0.5; 3], true, 0.0);
    assert!((m.v_bus_v - 18.0).abs() < 0.01);
}

#[test]
fn electrical_angle_matches_pole_pairs() {
    let mut p = Plant::new(motor(), cfg());
    p.set_rotor_angle(0.3);
    let e = p.theta_e();
    assert!((e.diff_radians(ElectricalAngle::from_radians(1.2))).abs() < 1e-5);
}
