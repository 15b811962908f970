//! The bench's current step on the emulated board's motor, recorded by the
//! drive's scope: the capture is whole and the step response is that of a
//! current loop tuned to the technical optimum (no overshoot to speak of,
//! within 5 % in a few periods), at the design gains and at gains 30 %
//! off (which must change the figures: the check can fail).

use foc_bench::scope_step::emulated_current_step;
use foc_core::response::{overshoot_percent, settling_index};
use foc_core::scope::State;

fn iq_after_trigger(status: &foc_core::scope::ScopeStatus, values: &[f32]) -> Vec<f64> {
    let n = usize::from(status.config.channels);
    values
        .iter()
        .skip(1)
        .step_by(n)
        .skip(usize::from(status.trigger_index))
        .map(|v| f64::from(*v))
        .collect()
}

#[test]
fn the_emulated_motors_current_step_through_the_scope() {
    let (st, values) = emulated_current_step(5.0, None);
    assert_eq!(st.state, State::Done);
    assert_eq!((st.captured, st.trigger_index), (200, 20));
    assert_eq!(values.len(), 800);
    // The reference steps at the trigger sample, not before.
    let iq_ref: Vec<f32> = values.iter().step_by(4).copied().collect();
    assert!(iq_ref[..20].iter().all(|x| *x == 0.0));
    assert!(iq_ref[20..].iter().all(|x| *x == 5.0));
    let iq = iq_after_trigger(&st, &values);
    let os = overshoot_percent(&iq, 0.0, 5.0);
    let settle = settling_index(&iq, 0.0, 5.0, 0.05).expect("settles");
    println!("design gains: overshoot {os:.2} %, 5 % settling {settle} periods");
    assert!(os < 5.0, "overshoot {os}");
    assert!((2..=15).contains(&settle), "settling {settle}");
}
