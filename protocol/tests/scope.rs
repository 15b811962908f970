//! The scope's requests on the device side: validation field by field
//! (nothing changes on a Nack), states, and a capture read out in chunks.
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use foc_core::control::{Command, Feedback};
use foc_core::scope::{ScopeConfig, Signal, State, TriggerKind};
use foc_protocol::device::tests_support::RecordingContext;
use foc_protocol::device::DeviceState;
use foc_protocol::frame::{encode, FrameDecoder, MAX_FRAME};
use foc_protocol::message::*;
use std::sync::atomic::{AtomicU32, Ordering};

/// Each request with its own CRC, so none is taken for a retransmission.
fn handle(dev: &mut DeviceState, ctx: &mut RecordingContext, r: Request) -> Response {
    static N: AtomicU32 = AtomicU32::new(1);
    dev.handle(ctx, 1, N.fetch_add(1, Ordering::Relaxed), &r)
}

fn config(samples: u16, pre: u16) -> ScopeConfig {
    let mut c = ScopeConfig::new(&[Signal::IqRefA, Signal::IqA]);
    c.samples = samples;
    c.pre_trigger = pre;
    c.trigger = TriggerKind::Command;
    c
}

fn nack(field: u8) -> Response {
    Response::Nack(ErrorCode::OutOfRange { field })
}

#[test]
fn bad_configurations_are_refused_by_field_and_change_nothing() {
    let (mut dev, mut ctx) = (DeviceState::new(), RecordingContext::default());
    assert_eq!(
        handle(&mut dev, &mut ctx, Request::SetScope(config(20, 2))),
        Response::Ack
    );
    let before = ctx;
    let mut cases = vec![];
    // 64 values, two signals: 32 samples at most.
    cases.push((config(33, 2), nack(9)));
    cases.push((config(1, 0), nack(9)));
    cases.push((config(20, 20), nack(10)));
    let mut c = config(20, 2);
    c.divider = 0;
    cases.push((c, nack(8)));
    let mut c = config(20, 2);
    c.trigger = TriggerKind::Falling;
    c.level = f32::INFINITY;
    cases.push((c, nack(13)));
    for (c, want) in cases {
        assert_eq!(
            handle(&mut dev, &mut ctx, Request::SetScope(c)),
            want,
            "{c:?}"
        );
        assert_eq!(ctx, before, "{c:?}");
    }
}

#[test]
fn bad_signal_codes_are_refused_at_the_frame() {
    let mut wire = [0u8; MAX_FRAME];
    let n = encode(5, &Request::SetScope(config(20, 2)), &mut wire).unwrap();
    // Re-encode with slot 1 unknown (0x40), slot 2 used after unused,
    // no signal: decode the raw body through a hand-made frame.
    let body_cases: [(&[u8; 8], u8); 3] = [
        (&[3, 0x40, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF], 1),
        (&[3, 0xFF, 1, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF], 2),
        (&[0xFF; 8], 0),
    ];
    assert!(n > 0);
    for (signals, field) in body_cases {
        let mut body = signals.to_vec();
        body.extend_from_slice(&1u16.to_le_bytes());
        body.extend_from_slice(&20u16.to_le_bytes());
        body.extend_from_slice(&2u16.to_le_bytes());
        body.extend_from_slice(&[1, 1]);
        body.extend_from_slice(&0f32.to_le_bytes());
        let mut payload = vec![0x50, 9, 0];
        payload.extend_from_slice(&body);
        let crc = foc_protocol::frame::CRC.checksum(&payload);
        payload.extend_from_slice(&crc.to_le_bytes());
        let mut buf = [0u8; MAX_FRAME];
        let m = foc_protocol::frame::cobs_encode(&payload, &mut buf).unwrap();
        let mut framed = buf[..m].to_vec();
        framed.push(0);
        let (mut dev, mut ctx) = (DeviceState::new(), RecordingContext::default());
        let mut dec = FrameDecoder::new();
        let mut reply = None;
        for b in framed {
            if let Some(f) = dec.feed::<Request>(b) {
                reply = Some(dev.handle_frame(&mut ctx, f));
            }
        }
        assert_eq!(reply, Some((9, nack(field))));
    }
}

#[test]
fn trigger_and_data_need_their_state() {
    let (mut dev, mut ctx) = (DeviceState::new(), RecordingContext::default());
    let state = Response::Nack(ErrorCode::ScopeState);
    assert_eq!(handle(&mut dev, &mut ctx, Request::TriggerScope), state);
    assert_eq!(
        handle(&mut dev, &mut ctx, Request::ReadScopeData { offset: 0 }),
        state
    );
    assert_eq!(handle(&mut dev, &mut ctx, Request::ArmScope), Response::Ack);
    assert_eq!(
        handle(&mut dev, &mut ctx, Request::ReadScopeData { offset: 0 }),
        state
    );
    assert_eq!(
        handle(&mut dev, &mut ctx, Request::TriggerScope),
        Response::Ack
    );
    // Without a scope: unsupported.
    ctx.scope = None;
    for r in [
        Request::ArmScope,
        Request::ReadScope,
        Request::SetScope(config(4, 1)),
    ] {
        assert_eq!(
            handle(&mut dev, &mut ctx, r),
            Response::Nack(ErrorCode::Unsupported)
        );
    }
}

#[test]
fn a_command_step_is_captured_and_read_in_chunks() {
    let (mut dev, mut ctx) = (DeviceState::new(), RecordingContext::default());
    let mut c = config(30, 5);
    c.divider = 2;
    assert_eq!(
        handle(&mut dev, &mut ctx, Request::SetScope(c)),
        Response::Ack
    );
    assert_eq!(handle(&mut dev, &mut ctx, Request::ArmScope), Response::Ack);
    let mut fb = Feedback::INIT;
    for k in 0..200u32 {
        fb.period = k;
        if k == 41 {
            fb.active = Command::Torque { iq_a: 2.0 };
            fb.i_dq_ref_a.q = 2.0;
        }
        fb.i_dq_a.q = k as f32;
        ctx.scope.as_mut().unwrap().record(&fb);
    }
    let Response::Scope(rep) = handle(&mut dev, &mut ctx, Request::ReadScope) else {
        panic!("no report");
    };
    let st = rep.status;
    assert_eq!(st.state, State::Done);
    assert_eq!(
        (st.captured, st.trigger_index, st.trigger_period),
        (30, 5, 42)
    );
    assert_eq!(st.capacity, 64);
    assert!((rep.sample_period_s - 2.0 / 20_000.0).abs() < 1e-9);
    let mut values = vec![];
    loop {
        let offset = values.len() as u16;
        match handle(&mut dev, &mut ctx, Request::ReadScopeData { offset }) {
            Response::ScopeData(d) if d.count > 0 => {
                assert_eq!(d.offset, offset);
                values.extend_from_slice(d.values());
            }
            Response::ScopeData(_) => break,
            other => panic!("{other:?}"),
        }
    }
    assert_eq!(values.len(), 60);
    // Samples at even periods; the trigger sample (index 5) is period 42.
    let iq: Vec<f32> = values.iter().skip(1).step_by(2).copied().collect();
    let want: Vec<f32> = (0..30).map(|k| (32 + 2 * k) as f32).collect();
    assert_eq!(iq, want);
    let iq_ref: Vec<f32> = values.iter().step_by(2).copied().collect();
    assert!(iq_ref[..5].iter().all(|&x| x == 0.0));
    assert!(iq_ref[5..].iter().all(|&x| x == 2.0));
    assert_eq!(
        handle(&mut dev, &mut ctx, Request::ReadScopeData { offset: 61 }),
        nack(0)
    );
}
