//! The joint on the device side (design §21): impedance commands, the
//! output frame, `SetJoint`, homing and the link watchdog in impedance mode,
//! against a [`RecordingContext`] (and, for an end-stop search, a point
//! rotor with a stop integrated in the test).
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use foc_core::control::homing::{EndStop, HomingMethod};
use foc_core::control::joint::Impedance;
use foc_core::control::stage::TimeoutReaction;
use foc_core::control::{Command, Fault, Limits, Mode};
use foc_protocol::device::tests_support::RecordingContext;
use foc_protocol::device::{DeviceState, WatchdogConfig};
use foc_protocol::joint::NO_JOINT;
use foc_protocol::message::*;

fn handle(dev: &mut DeviceState, ctx: &mut RecordingContext, seq: u16, r: Request) -> Response {
    dev.handle(ctx, seq, u32::from(seq), &r)
}

fn oor(field: u8) -> Response {
    Response::Nack(ErrorCode::OutOfRange { field })
}

/// Rotor frame, inside the recording context's limits (kp <= 50, kd <= 2).
fn impedance() -> Impedance {
    Impedance {
        position_rad: 1.0,
        velocity_rad_s: 0.5,
        kp_nm_per_rad: 10.0,
        kd_nm_s_per_rad: 0.5,
        torque_ff_nm: 0.1,
        torque_limit_nm: f32::INFINITY,
    }
}

/// 20:1, reversed, the output's zero at rotor 3 rad, no travel range.
fn geared() -> JointSettings {
    JointSettings {
        gear_ratio: -20.0,
        rotor_at_zero_rad: 3.0,
        travel_out_rad: None,
        fault_margin_rad: 0.5,
        brake_accel_rad_s2: 200.0,
        kv_a_per_rad_s: 0.05,
        entry_blend_periods: 200,
        timeout_kd_nm_s_per_rad: 0.0,
    }
}

fn geared_ctx() -> RecordingContext {
    RecordingContext {
        joint: geared().to_setup().unwrap(),
        ..Default::default()
    }
}

fn close(a: f32, b: f32) -> bool {
    (a - b).abs() <= 1e-5 * (1.0 + b.abs())
}

/// Every request is Nack'd with `want`, and the context is not touched.
fn refused(ctx: RecordingContext, cases: Vec<(Request, Response)>) {
    for (i, (req, want)) in cases.into_iter().enumerate() {
        let mut c = ctx;
        let mut dev = DeviceState::new();
        let got = handle(&mut dev, &mut c, i as u16 + 1, req);
        assert_eq!(got, want, "{req:?}");
        assert_eq!(c, ctx, "context touched by {req:?}");
        assert_eq!(dev.homing_state(), HomingState::Idle);
    }
}

#[test]
fn bad_impedance_commands_name_their_field_and_change_nothing() {
    type Edit = fn(&mut Impedance);
    let cases: [(Edit, u8); 10] = [
        (|i| i.position_rad = f32::NAN, 1),
        (|i| i.velocity_rad_s = f32::INFINITY, 2),
        (|i| i.kp_nm_per_rad = f32::NAN, 3),
        (|i| i.kd_nm_s_per_rad = f32::NAN, 4),
        (|i| i.torque_ff_nm = f32::NEG_INFINITY, 5),
        (|i| i.torque_limit_nm = f32::NAN, 6),
        (|i| i.torque_limit_nm = -1.0, 6),
        (|i| i.kp_nm_per_rad = -1.0, 3),
        (|i| i.kd_nm_s_per_rad = 2.5, 4),
        (|i| i.position_rad = 100.5, 1),
    ];
    let cases = cases
        .into_iter()
        .map(|(edit, field)| {
            let mut i = impedance();
            edit(&mut i);
            (Request::SetCommand(Command::Impedance(i)), oor(field))
        })
        .collect();
    refused(RecordingContext::default(), cases);
    // Not calibrated: impedance is closed loop.
    refused(
        RecordingContext {
            calibrated: false,
            ..Default::default()
        },
        vec![(
            Request::SetCommand(Command::Impedance(impedance())),
            Response::Nack(ErrorCode::NotCalibrated),
        )],
    );
    // A valid one reaches the context as it is (identity frame).
    let mut ctx = RecordingContext::default();
    let mut dev = DeviceState::new();
    let cmd = Command::Impedance(impedance());
    assert_eq!(
        handle(&mut dev, &mut ctx, 1, Request::SetCommand(cmd)),
        Response::Ack
    );
    assert_eq!(ctx.posted, Some(cmd));
    assert_eq!(ctx.mode, Mode::Impedance);
}

#[test]
fn bad_limits_and_joints_name_their_field_and_change_nothing() {
    let l = RecordingContext::default().limits;
    let joint = |edit: fn(&mut JointSettings)| {
        let mut j = geared();
        j.travel_out_rad = Some((-1.0, 2.0));
        edit(&mut j);
        Request::SetJoint(j)
    };
    let cases = vec![
        (
            Request::SetLimits(Limits {
                max_kp_nm_per_rad: -1.0,
                ..l
            }),
            oor(6),
        ),
        (
            Request::SetLimits(Limits {
                max_kd_nm_s_per_rad: f32::NAN,
                ..l
            }),
            oor(7),
        ),
        // Limits out of order.
        (
            Request::SetLimits(Limits {
                min_position_rad: 5.0,
                max_position_rad: -5.0,
                ..l
            }),
            oor(3),
        ),
        (joint(|j| j.gear_ratio = 0.0), oor(0)),
        (joint(|j| j.gear_ratio = f32::NAN), oor(0)),
        (joint(|j| j.gear_ratio = -2e4), oor(0)),
        (joint(|j| j.rotor_at_zero_rad = f32::INFINITY), oor(1)),
        (joint(|j| j.travel_out_rad = Some((f32::NAN, 1.0))), oor(3)),
        // Travel range out of order, or empty.
        (joint(|j| j.travel_out_rad = Some((2.0, -1.0))), oor(4)),
        (joint(|j| j.travel_out_rad = Some((1.0, 1.0))), oor(4)),
        (joint(|j| j.fault_margin_rad = -0.1), oor(5)),
        (joint(|j| j.brake_accel_rad_s2 = 0.0), oor(6)),
        (joint(|j| j.kv_a_per_rad_s = f32::NAN), oor(7)),
        (joint(|j| j.timeout_kd_nm_s_per_rad = -1.0), oor(9)),
        // A range that is one point in the rotor frame (f32 rounding).
        (
            joint(|j| {
                j.gear_ratio = 1.0;
                j.rotor_at_zero_rad = 1e10;
                j.travel_out_rad = Some((-1e-3, 1e-3));
            }),
            oor(4),
        ),
    ];
    refused(RecordingContext::default(), cases);
}

#[test]
fn a_joint_is_set_and_read_back_and_retransmissions_are_not_run_twice() {
    let mut ctx = RecordingContext::default();
    let mut dev = DeviceState::new();
    let j = JointSettings {
        travel_out_rad: Some((-1.0, 2.0)),
        ..geared()
    };
    assert_eq!(
        handle(&mut dev, &mut ctx, 1, Request::ReadJoint),
        Response::Joint(JointSettings::from_setup(&NO_JOINT))
    );
    assert_eq!(
        handle(&mut dev, &mut ctx, 2, Request::SetJoint(j)),
        Response::Ack
    );
    let calls = ctx.calls;
    assert_eq!(
        handle(&mut dev, &mut ctx, 2, Request::SetJoint(j)),
        Response::Ack
    );
    assert_eq!(ctx.calls, calls);
    assert_eq!(
        handle(&mut dev, &mut ctx, 3, Request::ReadJoint),
        Response::Joint(j)
    );
    // The travel range narrows the position range commands are checked
    // against: output 2.5 is beyond it (rotor 3 - 50 = -47, inside the
    // motor's +-100).
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            4,
            Request::SetCommand(Command::Position { rad: 2.5 })
        ),
        oor(1)
    );
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            5,
            Request::SetCommand(Command::Position { rad: 1.5 })
        ),
        Response::Ack
    );
    assert_eq!(ctx.posted, Some(Command::Position { rad: -27.0 }));
}

#[test]
fn commands_and_telemetry_travel_in_the_output_frame() {
    let mut ctx = geared_ctx();
    let mut dev = DeviceState::new();
    // Output frame: 400 N m/rad at the output is 1 N m/rad at the rotor.
    let out = Impedance {
        position_rad: 0.5,
        velocity_rad_s: 0.1,
        kp_nm_per_rad: 400.0,
        kd_nm_s_per_rad: 40.0,
        torque_ff_nm: 2.0,
        torque_limit_nm: 10.0,
    };
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            1,
            Request::SetCommand(Command::Impedance(out))
        ),
        Response::Ack
    );
    let Some(Command::Impedance(rot)) = ctx.posted else {
        panic!("{:?}", ctx.posted)
    };
    for (got, want) in [
        (rot.position_rad, 3.0 - 20.0 * 0.5),
        (rot.velocity_rad_s, -2.0),
        (rot.kp_nm_per_rad, 1.0),
        (rot.kd_nm_s_per_rad, 0.1),
        (rot.torque_ff_nm, -0.1),
        (rot.torque_limit_nm, 0.5),
    ] {
        assert!(close(got, want), "{rot:?}");
    }
    // The maxima are the rotor's: 50 N m/rad there is 20000 at the output.
    let stiff = |kp| {
        Request::SetCommand(Command::Impedance(Impedance {
            kp_nm_per_rad: kp,
            ..out
        }))
    };
    assert_eq!(
        handle(&mut dev, &mut ctx, 2, stiff(20_000.0)),
        Response::Ack
    );
    assert_eq!(handle(&mut dev, &mut ctx, 3, stiff(20_400.0)), oor(3));
    // Velocity and position commands; torque (a current) unchanged.
    for (seq, c, want) in [
        (
            4,
            Command::Velocity { rad_s: 1.5 },
            Command::Velocity { rad_s: -30.0 },
        ),
        (
            5,
            Command::Position { rad: -0.25 },
            Command::Position { rad: 8.0 },
        ),
        (
            6,
            Command::Torque { iq_a: 2.0 },
            Command::Torque { iq_a: 2.0 },
        ),
    ] {
        assert_eq!(
            handle(&mut dev, &mut ctx, seq, Request::SetCommand(c)),
            Response::Ack
        );
        assert_eq!(ctx.posted, Some(want));
    }
    // Telemetry: rotor -17 rad is output 1 rad, rotor 40 rad/s output -2.
    ctx.sample.position_rad = -17.0;
    ctx.sample.velocity_rad_s = 40.0;
    ctx.sample.i_q_a = 1.25;
    let Response::Telemetry(t) = handle(&mut dev, &mut ctx, 7, Request::ReadTelemetry) else {
        panic!()
    };
    assert!(
        close(t.position_rad, 1.0) && close(t.velocity_rad_s, -2.0),
        "{t:?}"
    );
    assert_eq!(t.i_q_a, 1.25);
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            8,
            Request::StartTelemetry(TelemetryRate::EveryPeriods(10))
        ),
        Response::Ack
    );
    let Some((_, Response::Stream(s))) = dev.poll(&mut ctx, 100) else {
        panic!()
    };
    assert_eq!(s, t);
}

#[test]
fn homing_to_the_present_position_sets_the_frame_at_once() {
    let mut ctx = geared_ctx();
    let mut dev = DeviceState::new();
    ctx.sample.position_rad = 7.0;
    let req = Request::StartHoming(HomingStart {
        method: HomingMethod::Present,
        home_output_rad: 0.25,
    });
    assert_eq!(handle(&mut dev, &mut ctx, 1, req), Response::Ack);
    assert_eq!(
        handle(&mut dev, &mut ctx, 2, Request::ReadHoming),
        Response::Homing(HomingState::Done)
    );
    // Same gear; the output reads 0.25 at rotor 7: zero at 7 + 20 * 0.25.
    assert_eq!(ctx.joint.frame.gear_ratio(), -20.0);
    assert!(close(ctx.joint.frame.rotor_at_zero_rad(), 12.0));
    assert!(close(ctx.joint.frame.position_to_output(7.0), 0.25));
    assert_eq!(ctx.posted, None);
    let Response::Telemetry(t) = handle(&mut dev, &mut ctx, 3, Request::ReadTelemetry) else {
        panic!()
    };
    assert!(close(t.position_rad, 0.25));
}

/// Output frame (20:1 reversed): -0.1 rad/s is +2 rad/s at the rotor, the
/// back-off 1 rad, the longest travel 20 rad at the rotor.
fn end_stop() -> EndStop {
    EndStop {
        velocity_rad_s: -0.1,
        current_a: 2.0,
        detect_fraction: 0.7,
        confirm_s: 0.02,
        backoff_rad: 0.05,
        max_travel_rad: 1.0,
    }
}

fn start_end_stop(dev: &mut DeviceState, ctx: &mut RecordingContext, home_out: f32) -> Response {
    let req = Request::StartHoming(HomingStart {
        method: HomingMethod::EndStop(end_stop()),
        home_output_rad: home_out,
    });
    handle(dev, ctx, 1, req)
}

/// A point rotor (1e-3 kg m^2) on the impedance law of the posted
/// command (50 us steps), a stiff stop above `stop_rad` \[rotor\]; the
/// device polled every millisecond. Returns the peak q current \[A\].
fn run_plant(dev: &mut DeviceState, ctx: &mut RecordingContext, stop_rad: f32, ms: u32) -> f32 {
    let kt = ctx.kt_nm_per_a;
    let (mut p, mut v, mut peak) = (ctx.sample.position_rad, 0.0f32, 0.0f32);
    // The law's reference advances with its velocity, as the current
    // stage's does; a new command starts it again.
    let (mut last, mut p_ref) = (None, 0.0f32);
    for _ in 0..ms {
        let mut iq = 0.0;
        for _ in 0..20 {
            if ctx.posted != last {
                last = ctx.posted;
                if let Some(Command::Impedance(c)) = last {
                    p_ref = c.position_rad;
                }
            }
            let t = match ctx.posted {
                Some(Command::Impedance(c)) => (c.kp_nm_per_rad * (p_ref - p)
                    + c.kd_nm_s_per_rad * (c.velocity_rad_s - v)
                    + c.torque_ff_nm)
                    .clamp(-c.torque_limit_nm, c.torque_limit_nm),
                _ => 0.0,
            };
            if let Some(Command::Impedance(c)) = ctx.posted {
                p_ref += c.velocity_rad_s * 5e-5;
            }
            iq = t / kt;
            peak = peak.max(iq.abs());
            let wall = if p > stop_rad {
                -1e4 * (p - stop_rad) - 5.0 * v
            } else {
                0.0
            };
            v += (t + wall) / 1e-3 * 5e-5;
            p += v * 5e-5;
        }
        ctx.sample.period += 20;
        ctx.sample.position_rad = p;
        ctx.sample.velocity_rad_s = v;
        ctx.sample.i_q_a = iq;
        ctx.sample.mode = ctx.mode;
        dev.poll(ctx, ctx.sample.period);
        if dev.homing_state() != HomingState::Running {
            break;
        }
    }
    peak
}

#[test]
fn homing_to_an_end_stop_in_the_output_frame() {
    let mut ctx = geared_ctx();
    // The watchdog is armed by the search and fed while it runs.
    let mut dev = DeviceState::with_auto_watchdog(WatchdogConfig {
        timeout_periods: 100,
        reaction: TimeoutReaction::Stop,
    });
    dev.poll(&mut ctx, 0);
    assert_eq!(start_end_stop(&mut dev, &mut ctx, -0.5), Response::Ack);
    assert_eq!(dev.homing_state(), HomingState::Running);
    let Some(Command::Impedance(first)) = ctx.posted else {
        panic!()
    };
    // A spring dragged at +2 rad/s (rotor), at most 2 A.
    assert!(close(first.velocity_rad_s, 2.0) && first.kp_nm_per_rad > 0.0);
    assert!(close(first.torque_limit_nm, 0.2));
    let peak = run_plant(&mut dev, &mut ctx, 5.0, 10_000);
    assert_eq!(dev.homing_state(), HomingState::Done);
    assert!(peak <= 2.0 * 1.001, "{peak} A");
    assert!(ctx.faults.is_empty(), "{:?}", ctx.first_fault);
    // The stop (rotor 5, pressed 2e-5 rad in) reads -0.5 at the output.
    let out = ctx.joint.frame.position_to_output(5.0);
    assert!((out + 0.5).abs() < 1e-3, "{out}");
    assert_eq!(ctx.joint.frame.gear_ratio(), -20.0);
    // Backed off towards the output's positive side: the rotor's negative.
    assert!(ctx.sample.position_rad < 4.5, "{}", ctx.sample.position_rad);
    assert_eq!(
        handle(&mut dev, &mut ctx, 9, Request::ReadHoming),
        Response::Homing(HomingState::Done)
    );
}

#[test]
fn homing_without_a_stop_fails_and_disables() {
    let mut ctx = geared_ctx();
    let mut dev = DeviceState::new();
    assert_eq!(start_end_stop(&mut dev, &mut ctx, 0.0), Response::Ack);
    run_plant(&mut dev, &mut ctx, 1e6, 30_000);
    assert_eq!(
        dev.homing_state(),
        HomingState::Failed(HomingFailure::NoStop)
    );
    assert_eq!(ctx.posted, Some(Command::Disable));
    // The frame is the one before.
    assert_eq!(ctx.joint, geared().to_setup().unwrap());
}

#[test]
fn a_host_command_aborts_homing() {
    let mut ctx = geared_ctx();
    let mut dev = DeviceState::new();
    assert_eq!(start_end_stop(&mut dev, &mut ctx, 0.0), Response::Ack);
    run_plant(&mut dev, &mut ctx, 5.0, 50);
    assert_eq!(dev.homing_state(), HomingState::Running);
    // Refused requests do not abort it; SetJoint waits for it.
    assert_eq!(
        handle(
            &mut dev,
            &mut ctx,
            2,
            Request::SetCommand(Command::Velocity { rad_s: f32::NAN })
        ),
        oor(1)
    );
    assert_eq!(
        handle(&mut dev, &mut ctx, 3, Request::SetJoint(geared())),
        Response::Nack(ErrorCode::Busy)
    );
    assert_eq!(dev.homing_state(), HomingState::Running);
    let hold = Command::Velocity { rad_s: 0.0 };
    assert_eq!(
        handle(&mut dev, &mut ctx, 4, Request::SetCommand(hold)),
        Response::Ack
    );
    assert_eq!(
        dev.homing_state(),
        HomingState::Failed(HomingFailure::Aborted)
    );
    run_plant(&mut dev, &mut ctx, 5.0, 50);
    assert_eq!(ctx.posted, Some(hold));
}

#[test]
fn bad_homing_requests_name_their_field_and_change_nothing() {
    let req = |edit: fn(&mut EndStop), home: f32| {
        let mut e = end_stop();
        edit(&mut e);
        Request::StartHoming(HomingStart {
            method: HomingMethod::EndStop(e),
            home_output_rad: home,
        })
    };
    let cases = vec![
        (req(|_| {}, f32::NAN), oor(1)),
        (req(|e| e.current_a = f32::NAN, 0.0), oor(3)),
        (req(|e| e.velocity_rad_s = 0.0, 0.0), oor(2)),
        // 30 rad/s at the output is 600 at the rotor: above 500.
        (req(|e| e.velocity_rad_s = 30.0, 0.0), oor(2)),
        (req(|e| e.current_a = 20.0, 0.0), oor(3)),
        (req(|e| e.detect_fraction = 1.5, 0.0), oor(4)),
        (req(|e| e.confirm_s = -1.0, 0.0), oor(5)),
        (req(|e| e.backoff_rad = 0.0, 0.0), oor(6)),
        (req(|e| e.max_travel_rad = -1.0, 0.0), oor(7)),
        // A back-off so short that its spring is above the stiffness limit.
        (req(|e| e.backoff_rad = 1e-6, 0.0), oor(6)),
    ];
    refused(geared_ctx(), cases);
    refused(
        RecordingContext {
            calibrated: false,
            ..geared_ctx()
        },
        vec![(req(|_| {}, 0.0), Response::Nack(ErrorCode::NotCalibrated))],
    );
}

#[test]
fn link_watchdog_in_impedance_mode_damps_then_disables() {
    for reaction in [TimeoutReaction::Stop, TimeoutReaction::Disable] {
        let mut dev = DeviceState::with_watchdog(WatchdogConfig {
            timeout_periods: 100,
            reaction,
        });
        let mut ctx = RecordingContext::default();
        ctx.joint.joint.timeout_kd_nm_s_per_rad = 0.2;
        ctx.sample.position_rad = 2.5;
        dev.poll(&mut ctx, 0);
        let cmd = Command::Impedance(impedance());
        assert_eq!(
            handle(&mut dev, &mut ctx, 1, Request::SetCommand(cmd)),
            Response::Ack
        );
        dev.poll(&mut ctx, 100);
        assert_eq!(ctx.posted, Some(cmd));
        // Silence: damping only (the command's 0.5 > the joint's 0.2).
        dev.poll(&mut ctx, 150);
        assert_eq!(
            ctx.posted,
            Some(Command::Impedance(Impedance {
                position_rad: 2.5,
                velocity_rad_s: 0.0,
                kp_nm_per_rad: 0.0,
                kd_nm_s_per_rad: 0.5,
                torque_ff_nm: 0.0,
                torque_limit_nm: f32::INFINITY,
            })),
            "{reaction:?}"
        );
        assert!(ctx.faults.is_empty());
        dev.poll(&mut ctx, 199);
        assert!(ctx.faults.is_empty());
        // A second timeout: disabled.
        dev.poll(&mut ctx, 250);
        assert!(ctx.faults.contains(Fault::CommandTimeout), "{reaction:?}");
        assert_eq!(ctx.mode, Mode::Disabled);
    }
    // The joint's timeout damping when the command's is smaller.
    let mut dev = DeviceState::with_watchdog(WatchdogConfig {
        timeout_periods: 100,
        reaction: TimeoutReaction::Hold,
    });
    let mut ctx = RecordingContext::default();
    ctx.joint.joint.timeout_kd_nm_s_per_rad = 1.0;
    dev.poll(&mut ctx, 0);
    let cmd = Command::Impedance(impedance());
    assert_eq!(
        handle(&mut dev, &mut ctx, 1, Request::SetCommand(cmd)),
        Response::Ack
    );
    dev.poll(&mut ctx, 101);
    let Some(Command::Impedance(d)) = ctx.posted else {
        panic!()
    };
    assert_eq!((d.kp_nm_per_rad, d.kd_nm_s_per_rad), (0.0, 1.0));
}

#[test]
fn field_names_for_people() {
    let r = Request::SetCommand(Command::Impedance(impedance()));
    assert_eq!(r.field_name(3), Some("kp_nm_per_rad"));
    assert_eq!(r.field_name(7), None);
    assert_eq!(
        Request::SetJoint(geared()).field_name(4),
        Some("travel_max_rad")
    );
    assert_eq!(Request::Ping.field_name(0), None);
}

#[test]
fn a_joint_without_travel_has_one_layout() {
    use foc_protocol::frame::{decode_payload, FrameErrorKind, CRC};
    let body = |flag: u8, lo: f32| {
        let mut p = vec![0x17u8, 1, 0];
        for x in [-20.0f32, 3.0] {
            p.extend(x.to_le_bytes());
        }
        p.push(flag);
        for x in [lo, 0.0, 0.5, 200.0, 0.05] {
            p.extend(x.to_le_bytes());
        }
        p.extend(200u32.to_le_bytes());
        p.extend(0.01f32.to_le_bytes());
        let crc = CRC.checksum(&p);
        p.extend(crc.to_le_bytes());
        p
    };
    let p = decode_payload::<Request>(&body(0, 0.0)).unwrap();
    assert_eq!(
        p.msg,
        Request::SetJoint(JointSettings {
            travel_out_rad: None,
            timeout_kd_nm_s_per_rad: 0.01,
            ..geared()
        })
    );
    assert_eq!(
        decode_payload::<Request>(&body(0, -1.0)).unwrap_err().kind,
        FrameErrorKind::BadField(3)
    );
    assert_eq!(
        decode_payload::<Request>(&body(2, 0.0)).unwrap_err().kind,
        FrameErrorKind::BadField(2)
    );
}

/// An end-stop search runs without the travel range (the stop is usually
/// beyond it, and the range is in the frame homing moves): it is off from
/// the start, back in the new frame when done, back as it was when the
/// homing fails.
#[test]
fn homing_suspends_the_travel_range_and_puts_it_back() {
    let mut with_travel = geared_ctx();
    with_travel.joint.travel_out_rad = Some((-0.1, 0.1));
    let travel = with_travel.joint.travel_out_rad;
    let mut ctx = with_travel;
    let mut dev = DeviceState::new();
    assert_eq!(start_end_stop(&mut dev, &mut ctx, -0.5), Response::Ack);
    assert_eq!(ctx.joint.travel_out_rad, None);
    run_plant(&mut dev, &mut ctx, 5.0, 10_000);
    assert_eq!(dev.homing_state(), HomingState::Done);
    assert_eq!(ctx.joint.travel_out_rad, travel);
    assert!((ctx.joint.frame.position_to_output(5.0) + 0.5).abs() < 1e-3);
    // No stop: failed, disabled, the joint as it was.
    let mut ctx = with_travel;
    let mut dev = DeviceState::new();
    assert_eq!(start_end_stop(&mut dev, &mut ctx, 0.0), Response::Ack);
    run_plant(&mut dev, &mut ctx, 1e6, 30_000);
    assert_eq!(
        dev.homing_state(),
        HomingState::Failed(HomingFailure::NoStop)
    );
    assert_eq!(ctx.posted, Some(Command::Disable));
    assert_eq!(ctx.joint, with_travel.joint);
}
