//! The bench's side of the scope's current step (design §22): the
//! emulated board's motor and inverter ([`foc_plant::emulated`]) under the
//! same control code, stepped and recorded by the same
//! [`foc_core::scope::Scope`] the firmware runs. `cargo xtask e2e` compares
//! the emulated firmware's capture (through `foc-ctl tune current`) with
//! this one.

use crate::mission::{control_motor, Setup, Sim};
use foc_core::control::Command;
use foc_core::drive::cascade::CascadeConfig;
use foc_core::scope::{Scope, ScopeConfig, ScopeStatus, Signal, State, TriggerKind};
use foc_plant::emulated;

/// Current limit of the emulated board's configuration \[A\].
pub const MAX_CURRENT_A: f32 = 10.0;

/// The emulated board on the bench: its motor and inverter, the encoder's
/// zero at the rotor's d axis (as in QEMU).
pub fn emulated_setup() -> Setup {
    Setup {
        name: "emulated board (QEMU plant)".into(),
        motor: emulated::MOTOR,
        bench: emulated::bench_config(),
        rated_current_a: MAX_CURRENT_A,
        max_current_a: MAX_CURRENT_A,
    }
}

/// The scope configuration of a current step (as `foc-ctl tune current`'s):
/// q-current reference and measurement, d current, q voltage, every
/// period, 200 samples, 20 before the step, triggered by the command.
pub fn current_step_scope() -> ScopeConfig {
    let mut c = ScopeConfig::new(&[Signal::IqRefA, Signal::IqA, Signal::IdA, Signal::VqV]);
    c.samples = 200;
    c.pre_trigger = 20;
    c.trigger = TriggerKind::Command;
    c
}

/// A q-current step of `step_a` from 0 A on the emulated board's motor,
/// the rotor free, with the current-loop gains `kp` [V/A], `ki` [V/(A s)]
/// on both axes (`None`: the design gains): the finished capture's status
/// and values (sample-major, as the drive's read-out).
pub fn emulated_current_step(step_a: f32, gains: Option<(f32, f32)>) -> (ScopeStatus, Vec<f32>) {
    let setup = emulated_setup();
    let pwm = setup.bench.pwm_frequency_hz as f32;
    let mut config = CascadeConfig::for_motor(control_motor(&setup.motor), pwm, MAX_CURRENT_A);
    // As the firmware configures it (`config::cascade`): the model check
    // and the current loop know the board's dead time (design §24, §31).
    let dead_time_s = setup.bench.dead_time_s as f32;
    config.current.supervisor.model.dead_time_s = dead_time_s;
    config.current.current.dead_time =
        foc_core::control::dead_time::DeadTimeCompensation::for_current_limit(
            dead_time_s,
            MAX_CURRENT_A,
        );
    if let Some((kp, ki)) = gains {
        for g in [
            &mut config.current.current.d_gains,
            &mut config.current.current.q_gains,
        ] {
            g.kp_v_per_a = kp;
            g.ki_v_per_a_s = ki;
        }
    }
    let mut sim = Sim::new_calibrated(&setup, config, false);
    // The firmware calibrates its current offsets at start-up.
    let o = setup.bench.sensors.current_offset_a;
    sim.set_current_offsets(foc_core::frames::Abc::new(
        o[0] as f32,
        o[1] as f32,
        o[2] as f32,
    ));
    let mut scope = Scope::new(vec![0.0f32; 4096]);
    let _ = scope.configure(current_step_scope());
    sim.cascade.command(Command::Torque { iq_a: 0.0 }).ok();
    sim.run(100);
    scope.arm(sim.cascade.feedback());
    let step = |sim: &mut Sim, scope: &mut Scope<Vec<f32>>| {
        sim.step();
        scope.record(sim.cascade.feedback());
    };
    for _ in 0..40 {
        step(&mut sim, &mut scope);
    }
    sim.cascade.command(Command::Torque { iq_a: step_a }).ok();
    for _ in 0..1000 {
        if scope.status().state == State::Done {
            break;
        }
        step(&mut sim, &mut scope);
    }
    let mut values = vec![0.0; scope.values()];
    scope.read(0, &mut values);
    (scope.status(), values)
}
