//! The calibration sweeps' own work per period (design §32, §33): the
//! anticogging calibration and the encoder linearisation run inside the
//! current loop's interrupt, one step a period, on top of the drive's
//! velocity or torque period. Each routine is stepped through a whole
//! run, every period timed, on a rotor that follows its requests exactly
//! (a perfect speed loop, computed untimed between the steps).
//!
//! The runs are shortened (fast sweeps, short settles, few turns): the
//! work of a period does not depend on the speed or the length of the
//! run, only on what the period does (record a sample, fold, solve,
//! build the table), and every kind of period occurs in a short run.
//! The worst period is the figure; the median is that of 64 periods
//! spread over the run.

use super::{report, ticks, Stats, TICKS_PER_INSTRUCTION};
use core::f32::consts::TAU;
use core::hint::black_box;
use foc_core::angle::{ElectricalAngle, MechanicalAngle};
use foc_core::calibration::cogging::{CoggingCalConfig, CoggingCalibration};
use foc_core::calibration::encoder::{EncoderCalConfig, EncoderCalibration};
use foc_core::calibration::{CalInput, CalStep, ClosedLoopFeedback};
use foc_core::control::angle_correction::AngleCorrection;
use foc_core::control::cogging::CoggingMap;
use foc_core::control::Command;
use foc_core::drive::{ConfigChange, Progress};
use foc_core::frames::{Abc, Dq};

use super::drive::Rig;

/// Every period of a run, summarised.
pub struct Run {
    min: u32,
    max: u32,
    worst_period: u32,
    sum: u64,
    n: u32,
    spread: [u32; 64],
    spread_n: usize,
    every: u32,
}

impl Run {
    /// A run of about `planned` periods.
    pub fn new(planned: u32) -> Self {
        Self {
            min: u32::MAX,
            max: 0,
            worst_period: 0,
            sum: 0,
            n: 0,
            spread: [0; 64],
            spread_n: 0,
            every: (planned / 64).max(1),
        }
    }

    /// Adds a period of `t` SysTick ticks (`baseline` taken off).
    pub fn push(&mut self, baseline: u32, t: u32) {
        let c = (t.saturating_sub(baseline) as f32 / TICKS_PER_INSTRUCTION + 0.5) as u32;
        if c > self.max {
            self.max = c;
            self.worst_period = self.n;
        }
        self.min = self.min.min(c);
        self.sum += u64::from(c);
        if self.n.is_multiple_of(self.every) && self.spread_n < self.spread.len() {
            self.spread[self.spread_n] = c;
            self.spread_n += 1;
        }
        self.n += 1;
    }

    /// Its summary.
    pub fn stats(&mut self) -> Stats {
        let s = &mut self.spread[..self.spread_n.max(1)];
        s.sort_unstable();
        Stats {
            min: self.min,
            max: self.max,
            mean: self.sum as f32 / self.n.max(1) as f32,
            median: s[s.len() / 2],
        }
    }
}

/// The PWM period of the emulated board \[s\].
fn ts_s() -> f32 {
    1.0 / board_support::board::PWM_FREQUENCY_HZ as f32
}

/// Measures and reports both sweeps.
pub fn measure_sweeps(baseline: u32) {
    cogging(baseline);
    encoder(baseline);
}

/// The anticogging calibration on a 7-pole-pair rotor with a sixth
/// harmonic cogging: two passes, each a turn each way at 600 periods per
/// electrical turn (every point of the map seen), 10 ms settles.
fn cogging(baseline: u32) {
    const PP: u8 = 7;
    let hz = board_support::board::PWM_FREQUENCY_HZ as f32;
    let mut c = CoggingCalConfig::new(PP, hz, 10.0);
    c.sweep_e_rad_s = TAU * hz / 600.0;
    c.settle_s = 0.01;
    c.timeout_s = 2.0 * c.planned_s();
    let mut cal = CoggingCalibration::new(c);
    let mut run = Run::new((c.planned_s() * hz) as u32);
    let (mut theta, mut w_mech) = (ElectricalAngle::ZERO, 0.0f32);
    let mut n = 0u32;
    let end = loop {
        let iq = 0.3 * w_mech.signum() + 0.2 * libm::sinf(6.0 * theta.to_radians());
        let mut inp = CalInput::open_loop(Abc::default(), MechanicalAngle::ZERO, 24.0);
        if n > 0 {
            inp.closed_loop = Some(closed_loop(iq, w_mech, theta));
        }
        let mut out = None;
        run.push(
            baseline,
            ticks(&mut || out = Some(cal.step(black_box(&inp)))),
        );
        match out {
            Some(CalStep::Velocity { rad_s }) => w_mech = rad_s,
            other => break other,
        }
        theta = theta.add_radians(w_mech * PP as f32 * ts_s());
        n += 1;
    };
    finish(
        "calibration period: anticogging sweep (CoggingCalibration::step, every period of a run)",
        &mut run,
        end,
    );
}

/// The encoder linearisation on a sensor with an eccentricity and a
/// second harmonic: three turns each way at 20 turns per second after
/// the shortest settle.
fn encoder(baseline: u32) {
    let hz = board_support::board::PWM_FREQUENCY_HZ as f32;
    let mut c = EncoderCalConfig::new(hz, 10.0);
    c.speed_rad_s = 20.0 * TAU;
    c.turns = 3;
    c.settle_s = 0.2;
    c.timeout_s = 2.0 * c.planned_s();
    let mut cal = EncoderCalibration::new(c);
    let mut run = Run::new((c.planned_s() * hz) as u32);
    let (mut theta, mut w) = (0.3f32, 0.0f32);
    let mut n = 0u32;
    let end = loop {
        let e = 0.005 * libm::sinf(theta) + 0.0017 * libm::sinf(2.0 * theta + 0.4);
        let mut inp = CalInput::open_loop(
            Abc::default(),
            MechanicalAngle::from_radians(theta + e),
            24.0,
        );
        if n > 0 {
            inp.closed_loop = Some(closed_loop(0.2 * w.signum(), w, ElectricalAngle::ZERO));
        }
        let mut out = None;
        run.push(
            baseline,
            ticks(&mut || out = Some(cal.step(black_box(&inp)))),
        );
        match out {
            Some(CalStep::Velocity { rad_s }) => w = rad_s,
            Some(CalStep::Torque { .. }) => {}
            other => break other,
        }
        theta = wrap(theta + w * ts_s());
        n += 1;
    };
    finish(
        "calibration period: encoder linearisation (EncoderCalibration::step, every period of a run)",
        &mut run,
        end,
    );
}

/// `x` in `0 .. TAU` (a step of less than a turn from there).
fn wrap(x: f32) -> f32 {
    if x >= TAU {
        x - TAU
    } else if x < 0.0 {
        x + TAU
    } else {
        x
    }
}

fn closed_loop(iq_a: f32, w_rad_s: f32, theta_e: ElectricalAngle) -> ClosedLoopFeedback {
    ClosedLoopFeedback {
        v_dq_v: Dq::ZERO,
        i_dq_a: Dq::new(0.0, iq_a),
        velocity_rad_s: w_rad_s,
        theta_e,
    }
}

/// Reports a run; a run that did not finish is the bench failing.
fn finish(name: &str, run: &mut Run, end: Option<CalStep<()>>) {
    report(name, run.stats());
    defmt::println!(
        "INFO {=str}: {=u32} periods, the worst at period {=u32}, ended {}",
        name,
        run.n,
        run.worst_period,
        end
    );
    if end != Some(CalStep::Done(())) {
        defmt::println!("BENCH-FAILED {=str}: the sweep did not finish", name);
        super::mission_exit(1);
    }
}

/// The drive's whole per-period call, as in the firmware, through a whole
/// calibration (`ask` sets the request) on the emulated motor (its plant
/// untimed), from the disabled drive to the calibration's end: the
/// product's worst period while it calibrates. A calibration that fails or
/// does not end within a minute of emulated time fails the bench. Then
/// torque 1 A again, as the scenarios before left the drive.
pub fn drive_run(
    rig: &mut Rig,
    baseline: u32,
    name: &str,
    ask: fn(&mut ConfigChange),
    planned_s: f32,
) -> Stats {
    const LIMIT_PERIODS: u32 = 60 * board_support::board::PWM_FREQUENCY_HZ;
    // From standstill: the scenarios before left the rotor turning; it
    // coasts (at most 10 s).
    rig.slot.post(Command::Disable);
    for _ in 0..10 * board_support::board::PWM_FREQUENCY_HZ / 100 {
        rig.run(100);
        if rig.published.velocity_rad_s.abs() < 1.0 {
            break;
        }
    }
    let mut change = ConfigChange::default();
    ask(&mut change);
    rig.set_mailbox(change);
    // The median's 64 samples spread over the planned run.
    let mut run = Run::new((planned_s * board_support::board::PWM_FREQUENCY_HZ as f32) as u32);
    let mut end = Progress::Idle;
    while run.n < LIMIT_PERIODS {
        board_support::board::sim::step_physics();
        run.push(baseline, ticks(&mut || rig.period()));
        rig.slower();
        if run.n == 1 && rig.last_change() != Some(Ok(())) {
            defmt::println!(
                "BENCH-FAILED {=str}: the request was refused: {}, faults {=u32:#x}",
                name,
                rig.last_change(),
                rig.published.faults.0
            );
            super::mission_exit(1);
        }
        end = rig.status().calibration;
        if run.n > 1 && !matches!(end, Progress::Running(_)) {
            break;
        }
    }
    let stats = run.stats();
    report(name, stats);
    defmt::println!(
        "INFO {=str}: {=u32} periods, the worst at period {=u32}, ended {}",
        name,
        run.n,
        run.worst_period,
        end
    );
    if end != Progress::Done {
        defmt::println!("BENCH-FAILED {=str}: the calibration did not finish", name);
        super::mission_exit(1);
    }
    // The learnt tables out again: the scenarios after run without them.
    rig.slot.post(Command::Disable);
    rig.run(4);
    let cleared = rig.drive_mut().stage_while_disabled().is_some_and(|stage| {
        stage.set_cogging(&CoggingMap::EMPTY).is_ok()
            && stage.set_angle_correction(&AngleCorrection::NONE).is_ok()
    });
    if !cleared {
        defmt::println!(
            "BENCH-FAILED {=str}: the learnt tables were not cleared",
            name
        );
        super::mission_exit(1);
    }
    rig.slot.post(Command::Torque { iq_a: 1.0 });
    rig.run(100);
    stats
}
