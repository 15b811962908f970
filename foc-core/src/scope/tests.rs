use super::*;
use crate::control::{Command, Fault, Feedback};

/// Feedback of period `k` with `iq` as the measured q current.
fn fb(k: u32, iq: f32) -> Feedback {
    let mut f = Feedback::INIT;
    f.period = k;
    f.i_dq_a.q = iq;
    f
}

fn scope(cfg: ScopeConfig) -> Scope<[f32; 64]> {
    let mut s = Scope::new([0.0; 64]);
    s.configure(cfg).unwrap();
    s
}

fn iq_config(samples: u16, pre: u16, trigger: TriggerKind) -> ScopeConfig {
    let mut c = ScopeConfig::new(&[Signal::IqA]);
    c.samples = samples;
    c.pre_trigger = pre;
    c.trigger = trigger;
    c
}

fn read_all<B: AsRef<[f32]> + AsMut<[f32]>>(s: &Scope<B>) -> ([f32; 64], usize) {
    let mut v = [f32::NAN; 64];
    let n = s.read(0, &mut v);
    (v, n)
}

#[test]
fn keeps_pre_trigger_samples_across_the_ring_wrap() {
    // 10 samples, 4 before the trigger; 50 periods armed before a forced trigger.
    let mut s = scope(iq_config(10, 4, TriggerKind::Manual));
    s.arm(&Feedback::INIT);
    for k in 0..50 {
        s.record(&fb(k, k as f32));
    }
    s.force().unwrap();
    for k in 50..100 {
        s.record(&fb(k, k as f32));
    }
    let st = s.status();
    assert_eq!(st.state, State::Done);
    assert_eq!(
        (st.captured, st.trigger_index, st.trigger_period),
        (10, 4, 50)
    );
    let (v, n) = read_all(&s);
    assert_eq!(n, 10);
    let want: [f32; 10] = core::array::from_fn(|i| 46.0 + i as f32);
    assert_eq!(&v[..10], &want);
}

#[test]
fn an_early_trigger_keeps_what_there_is() {
    let mut s = scope(iq_config(10, 6, TriggerKind::Manual));
    s.arm(&Feedback::INIT);
    s.record(&fb(0, 0.0));
    s.record(&fb(1, 1.0));
    s.force().unwrap();
    for k in 2..30 {
        s.record(&fb(k, k as f32));
    }
    let st = s.status();
    assert_eq!((st.captured, st.trigger_index), (2 + 4, 2));
    let (v, n) = read_all(&s);
    assert_eq!(&v[..n], &[0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
}

#[test]
fn a_new_command_triggers_not_the_one_in_force_when_armed() {
    let mut s = scope(iq_config(8, 2, TriggerKind::Command));
    let mut f = fb(0, 0.0);
    f.active = Command::Torque { iq_a: 0.5 };
    s.arm(&f);
    for k in 0..20 {
        f.period = k;
        s.record(&f);
    }
    assert_eq!(s.status().state, State::Armed);
    f.active = Command::Torque { iq_a: 1.0 };
    for k in 20..40 {
        f.period = k;
        s.record(&f);
    }
    let st = s.status();
    assert_eq!(
        (st.state, st.trigger_period, st.trigger_index),
        (State::Done, 20, 2)
    );
}

#[test]
fn a_new_fault_triggers() {
    let mut s = scope(iq_config(4, 1, TriggerKind::Fault));
    let mut f = fb(0, 0.0);
    f.faults.insert(Fault::CommandTimeout);
    s.arm(&f);
    s.record(&f);
    assert_eq!(s.status().state, State::Armed);
    f.faults.insert(Fault::BusOverVoltage);
    f.period = 1;
    s.record(&f);
    assert_eq!(s.status().state, State::Triggered);
    assert_eq!(s.status().trigger_period, 1);
}

#[test]
fn level_triggers_see_their_edge_only() {
    let ramp = |s: &mut Scope<[f32; 64]>, up: bool| {
        for k in 0..20u32 {
            let x = if up { k as f32 } else { 20.0 - k as f32 };
            s.record(&fb(k, x));
        }
    };
    for (kind, up, fires) in [
        (TriggerKind::Rising, true, true),
        (TriggerKind::Rising, false, false),
        (TriggerKind::Falling, false, true),
        (TriggerKind::Falling, true, false),
        (TriggerKind::Either, true, true),
        (TriggerKind::Either, false, true),
    ] {
        let mut c = iq_config(4, 1, kind);
        c.trigger_signal = Signal::IqA;
        c.level = 9.5;
        let mut s = scope(c);
        s.arm(&Feedback::INIT);
        ramp(&mut s, up);
        let st = s.status();
        assert_eq!(st.state != State::Armed, fires, "{kind:?} up={up}");
        if fires {
            // Rising: 10 is the first sample at or above 9.5; falling: 9 (20 - 11).
            let want = if up { 10 } else { 11 };
            assert_eq!(st.trigger_period, want, "{kind:?}");
        }
    }
}

#[test]
fn divider_records_every_kth_period_and_a_trigger_waits_for_the_next_sample() {
    let mut c = iq_config(6, 2, TriggerKind::Command);
    c.divider = 5;
    let mut s = scope(c);
    let mut f = fb(0, 0.0);
    s.arm(&f);
    for k in 0..100u32 {
        f.period = k;
        f.i_dq_a.q = k as f32;
        if k == 22 {
            f.active = Command::Torque { iq_a: 1.0 };
        }
        s.record(&f);
    }
    let st = s.status();
    // Samples at periods 0, 5, 10, ...: the change at 22 is recorded at 25.
    assert_eq!((st.state, st.trigger_period), (State::Done, 25));
    let (v, n) = read_all(&s);
    assert_eq!(&v[..n], &[15.0, 20.0, 25.0, 30.0, 35.0, 40.0]);
}

#[test]
fn several_signals_are_interleaved_sample_major() {
    let mut c = ScopeConfig::new(&[Signal::IqA, Signal::PositionRad, Signal::Target]);
    c.samples = 3;
    c.trigger = TriggerKind::Manual;
    let mut s = scope(c);
    s.arm(&Feedback::INIT);
    s.force().unwrap();
    for k in 0..3u32 {
        let mut f = fb(k, k as f32);
        f.position_rad = 10.0 + k as f32;
        f.active = Command::Velocity { rad_s: 7.0 };
        s.record(&f);
    }
    let (v, n) = read_all(&s);
    assert_eq!(&v[..n], &[0.0, 10.0, 7.0, 1.0, 11.0, 7.0, 2.0, 12.0, 7.0]);
    // Reading from an offset, and past the end.
    let mut w = [0.0; 4];
    assert_eq!(s.read(7, &mut w), 2);
    assert_eq!(&w[..2], &[12.0, 7.0]);
    assert_eq!(s.read(9, &mut w), 0);
    assert_eq!(s.values(), 9);
}

#[test]
fn bad_configurations_are_refused_whole() {
    let mut s = scope(iq_config(10, 2, TriggerKind::Manual));
    let before = *s.config();
    let good = iq_config(10, 2, TriggerKind::Manual);
    let mut cases = [good; 7];
    cases[0].channels = 0;
    cases[1].channels = 9;
    cases[2].divider = 0;
    cases[3].samples = 1;
    cases[4].samples = 65; // 64 values, one signal
    cases[5].pre_trigger = 10;
    cases[6].trigger = TriggerKind::Rising;
    cases[6].level = f32::NAN;
    let want = [
        ScopeError::Channels,
        ScopeError::Channels,
        ScopeError::Divider,
        ScopeError::Samples,
        ScopeError::Samples,
        ScopeError::PreTrigger,
        ScopeError::Level,
    ];
    for (c, e) in cases.iter().zip(want) {
        assert_eq!(s.configure(*c), Err(e));
        assert_eq!(*s.config(), before);
    }
    // Two signals in 64 values: at most 32 samples; 0 means all of them.
    let mut c = ScopeConfig::new(&[Signal::IqA, Signal::IdA]);
    c.samples = 33;
    assert_eq!(s.configure(c), Err(ScopeError::Samples));
    c.samples = 0;
    s.configure(c).unwrap();
    assert_eq!(s.config().samples, 32);
}

#[test]
fn nothing_is_read_or_forced_outside_its_state() {
    let mut s = scope(iq_config(4, 1, TriggerKind::Manual));
    assert_eq!(s.force(), Err(ScopeError::State));
    let mut v = [0.0; 4];
    assert_eq!(s.read(0, &mut v), 0);
    s.arm(&Feedback::INIT);
    s.record(&fb(0, 1.0));
    assert_eq!(s.read(0, &mut v), 0);
    // A new configuration drops the capture and stops recording.
    s.configure(iq_config(4, 1, TriggerKind::Manual)).unwrap();
    assert_eq!(s.status().state, State::Idle);
    assert_eq!(s.status().captured, 0);
}

#[test]
fn idle_and_done_record_nothing() {
    let mut s = scope(iq_config(2, 0, TriggerKind::Manual));
    for k in 0..10 {
        s.record(&fb(k, 5.0));
    }
    assert_eq!(s.status().captured, 0);
    s.arm(&Feedback::INIT);
    s.force().unwrap();
    s.record(&fb(0, 1.0));
    s.record(&fb(1, 2.0));
    assert_eq!(s.status().state, State::Done);
    s.record(&fb(2, 3.0));
    let (v, n) = read_all(&s);
    assert_eq!(&v[..n], &[1.0, 2.0]);
}

#[test]
fn signal_codes_round_trip() {
    for (i, s) in Signal::ALL.iter().enumerate() {
        assert_eq!(*s as u8 as usize, i);
        assert_eq!(Signal::from_code(i as u8), Some(*s));
    }
    assert_eq!(Signal::from_code(Signal::ALL.len() as u8), None);
    for k in 0..=5 {
        assert_eq!(TriggerKind::from_code(k).map(|t| t as u8), Some(k));
    }
    assert_eq!(TriggerKind::from_code(6), None);
}
