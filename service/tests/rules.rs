//! The link's rules, once for every front end (firmware, CAN host bus,
//! `foc-ctl simulate`): each drives a motor through this crate's
//! [`Link`], so a rule tested here is the rule of all three.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing)]

use foc_core::control::{Command, Feedback, Limits, Mode, MotorParams};
use foc_core::drive::cascade::CascadeConfig;
use foc_core::drive::Status;
use foc_protocol::config::StoreOp;
use foc_protocol::message::{Calibration, ErrorCode};
use foc_protocol::{DeviceContext, Refusal, WatchdogConfig};
use foc_service::{Board, BootOutcome, Link, Pending, Service, Snapshot};
use foc_store::fake::FakeFlash;
use foc_store::{DriveRecord, Label, Store};

type Flash = FakeFlash<4, 4096, 4>;
const PWM_HZ: u32 = 20_000;
const MAX_CURRENT_A: f32 = 10.0;

fn board(zero_survives_reset: bool) -> Board {
    let motor = MotorParams {
        pole_pairs: 7,
        r_ohm: 0.1,
        ld_h: 40e-6,
        lq_h: 40e-6,
        flux_linkage_wb: 0.004,
    };
    let cascade = CascadeConfig::for_motor(motor, PWM_HZ as f32, MAX_CURRENT_A);
    let mut b = Board::new(cascade, PWM_HZ, MAX_CURRENT_A);
    b.zero_survives_reset = zero_survives_reset;
    b
}

fn store() -> Store<Flash> {
    Store::new(Flash::new(), 0..16384).unwrap()
}

/// Disabled, running, calibrated, nothing pending.
fn quiet_snapshot() -> Snapshot {
    Snapshot {
        feedback: Feedback::INIT,
        max_loop_cycles: 0,
        status: Status {
            running: true,
            mode: Mode::Disabled,
            faulted: false,
            calibrated: true,
            sensorless: false,
            injection: false,
            calibration: foc_core::drive::Progress::Idle,
        },
        identified: None,
        pending: Pending {
            command: Command::Disable,
            calibration: false,
        },
    }
}

fn link<'a>(
    s: &'a mut Service,
    snap: Snapshot,
    st: &'a mut Store<Flash>,
) -> Link<'a, Store<Flash>> {
    s.link(snap, Some(st), None, WatchdogConfig::OFF)
}

/// A record of `s`'s settings, calibrated, labelled "cal".
fn calibrated_record(s: &Service) -> DriveRecord {
    let mut set = *s.settings();
    set.calibrated = true;
    DriveRecord::from_settings(&Label::try_from("cal").unwrap(), PWM_HZ, &set)
}

#[test]
fn store_operations_wait_for_a_quiet_drive() {
    let mut s = Service::new(board(true));
    let mut st = store();
    let cases = [
        (
            Pending {
                command: Command::Velocity { rad_s: 1.0 },
                calibration: false,
            },
            false,
            ErrorCode::NotDisabled,
        ),
        // Decided (the host bus used to allow it): a calibration asked
        // for and not yet taken makes the drive busy.
        (
            Pending {
                command: Command::Disable,
                calibration: true,
            },
            false,
            ErrorCode::Busy,
        ),
        (
            Pending {
                command: Command::Disable,
                calibration: false,
            },
            true,
            ErrorCode::Busy,
        ),
    ];
    for (pending, brake_on, want) in cases {
        let mut snap = quiet_snapshot();
        snap.pending = pending;
        snap.feedback.power.brake_on = brake_on;
        let mut l = link(&mut s, snap, &mut st);
        for op in [StoreOp::Save, StoreOp::Erase, StoreOp::Load] {
            assert_eq!(l.store(op, &[], WatchdogConfig::OFF), Err(want), "{op:?}");
        }
        assert!(!l.out.touches_config());
    }
    assert_eq!(st.load().unwrap(), None, "nothing was written");
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    assert_eq!(l.store(StoreOp::Save, &[], WatchdogConfig::OFF), Ok(None));
    assert!(st.load().unwrap().is_some());
}

#[test]
fn a_stored_calibration_applies_only_where_the_sensor_zero_survives_a_reset() {
    for survives in [true, false] {
        let mut s = Service::new(board(survives));
        let rec = calibrated_record(&s);
        let mut st = store();
        st.save(&rec).unwrap();
        let mut l = link(&mut s, quiet_snapshot(), &mut st);
        l.store(StoreOp::Load, &[], WatchdogConfig::OFF).unwrap();
        let change = l.out.config.current.unwrap();
        assert_eq!(change.permit.is_some(), survives, "survives {survives}");
        assert_eq!(s.settings().calibrated, survives);
        // At boot too.
        let (booted, outcome) = Service::boot(board(survives), Some(&mut st));
        assert_eq!(
            outcome,
            BootOutcome::Loaded {
                calibrated: survives
            }
        );
        assert_eq!(booted.settings().calibrated, survives);
        assert_eq!(booted.label().as_str(), "cal");
    }
}

#[test]
fn limits_above_the_hardware_are_refused() {
    let mut s = Service::new(board(true));
    let mut st = store();
    let before = *s.settings();
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    let too_much = Limits {
        max_current_a: MAX_CURRENT_A * 1.01,
        ..l.limits()
    };
    assert_eq!(l.set_limits(too_much), Err(Refusal::Unsupported));
    assert!(!l.out.touches_config());
    let at_limit = Limits {
        max_current_a: MAX_CURRENT_A,
        max_velocity_rad_s: 500.0,
        ..l.limits()
    };
    assert_eq!(l.set_limits(at_limit), Ok(()));
    let out = l.out;
    assert_eq!(out.config.current.unwrap().limits, Some(at_limit));
    assert_eq!(out.config.speed.unwrap().current_limit_a, MAX_CURRENT_A);
    assert_eq!(s.settings().limits, at_limit);
    assert_ne!(before.limits, at_limit);
    // A record above the hardware's limit is refused whole.
    let mut big = *s.settings();
    big.limits.max_current_a = 5000.0;
    big.speed.kp_a_per_rad_s *= 2.0;
    let rec = DriveRecord::from_settings(&Label::new(), PWM_HZ, &big);
    let mut buf = [0u8; foc_protocol::config::MAX_RECORD];
    let n = rec.encode(&mut buf).unwrap();
    let settled = *s.settings();
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    for op in [StoreOp::Apply, StoreOp::ApplyAndSave] {
        assert_eq!(
            l.store(op, &buf[..n], WatchdogConfig::OFF),
            Err(ErrorCode::BadRecord)
        );
    }
    assert!(!l.out.touches_config());
    assert_eq!(*s.settings(), settled, "nothing applied");
    assert_eq!(st.load().unwrap(), None, "nothing saved");
}

#[test]
fn a_record_for_another_motor_changes_nothing() {
    let mut s = Service::new(board(true));
    let mut other = *s.settings();
    other.current.motor.pole_pairs = 11;
    let rec = DriveRecord::from_settings(&Label::new(), PWM_HZ, &other);
    let mut st = store();
    st.save(&rec).unwrap();
    let before = *s.settings();
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    assert_eq!(
        l.store(StoreOp::Load, &[], WatchdogConfig::OFF),
        Err(ErrorCode::BadRecord)
    );
    assert!(!l.out.touches_config());
    assert_eq!(*s.settings(), before);
    let (_, outcome) = Service::boot(board(true), Some(&mut st));
    assert!(matches!(outcome, BootOutcome::Refused(_)), "{outcome:?}");
}

#[test]
fn a_failed_save_applies_nothing() {
    let mut s = Service::new(board(true));
    let mut changed = *s.settings();
    changed.speed.kp_a_per_rad_s *= 2.0;
    let rec = DriveRecord::from_settings(&Label::new(), PWM_HZ, &changed);
    let mut buf = [0u8; foc_protocol::config::MAX_RECORD];
    let n = rec.encode(&mut buf).unwrap();
    let mut flash = Flash::new();
    flash.cut_power_after_words(0);
    let mut st = Store::new(flash, 0..16384).unwrap();
    let before = *s.settings();
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    assert_eq!(
        l.store(StoreOp::ApplyAndSave, &buf[..n], WatchdogConfig::OFF),
        Err(ErrorCode::StoreFailed)
    );
    assert!(!l.out.touches_config());
    assert_eq!(*s.settings(), before);
}

#[test]
fn calibration_requests_follow_the_board() {
    for identifies in [true, false] {
        let mut b = board(true);
        b.identifies = identifies;
        let mut s = Service::new(b);
        let mut st = store();
        let mut l = link(&mut s, quiet_snapshot(), &mut st);
        assert_eq!(
            l.start_calibration(Calibration::Alignment),
            Err(Refusal::Unsupported)
        );
        let id = l.start_calibration(Calibration::Identification);
        assert_eq!(id.is_ok(), identifies);
        assert_eq!(l.start_calibration(Calibration::Offsets), Ok(()));
        let c = l.out.config.current.unwrap();
        assert!(c.calibrate_offsets);
        assert_eq!(c.identify, identifies);
        assert!(l.out.config.calibration_pending());
    }
}

#[test]
fn a_travel_range_that_leaves_the_position_target_outside_is_refused() {
    let mut s = Service::new(board(true));
    let mut st = store();
    let mut snap = quiet_snapshot();
    snap.pending.command = Command::Position { rad: 5.0 };
    let mut l = link(&mut s, snap, &mut st);
    let mut j = l.joint();
    j.travel_out_rad = Some((-1.0, 1.0));
    assert_eq!(l.set_joint(j), Err(Refusal::NotDisabled));
    j.travel_out_rad = Some((-10.0, 10.0));
    assert_eq!(l.set_joint(j), Ok(()));
    assert!(l.out.config.current.unwrap().joint.is_some());
}

#[test]
fn a_keep_alive_posts_nothing_and_a_clear_comes_before_the_command() {
    let mut s = Service::new(board(true));
    let mut st = store();
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    l.keep_alive();
    assert!(!l.out.touches_command());
    l.clear_faults();
    l.post(Command::Velocity { rad_s: 3.0 }).unwrap();
    let mut slot = foc_core::control::CommandSlot::INIT;
    l.out.apply_command(&mut slot);
    assert_eq!(slot.command, Command::Velocity { rad_s: 3.0 });
    assert_eq!((slot.seq, slot.clear_seq), (1, 1));
}

/// A record that runs sensorless (design §27) is applied whole: the
/// settings keep it, the change for the drive carries the configuration
/// derived from it; without the rotor's mechanics (this board's build has
/// none) it is refused and nothing changes.
#[test]
fn a_sensorless_record_reaches_the_drive_and_needs_mechanics() {
    use foc_core::control::Mechanics;
    use foc_store::record::SensorlessRecord;
    let mut s = Service::new(board(true));
    assert_eq!(s.board().cascade.mechanics, None);
    let mut st = store();
    let sensorless = SensorlessRecord {
        start_current_a: 4.0,
        bus_voltage_v: 24.0,
        beside_sensor: None,
        observer_above_rad_s: None,
    };
    let mut set = *s.settings();
    set.sensorless = Some(sensorless);
    let bare = DriveRecord::from_settings(&Label::new(), PWM_HZ, &set);
    let mut buf = [0u8; foc_protocol::config::MAX_RECORD];
    let n = bare.encode(&mut buf).unwrap();
    let before = *s.settings();
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    assert_eq!(
        l.store(StoreOp::Apply, &buf[..n], WatchdogConfig::OFF),
        Err(ErrorCode::BadRecord)
    );
    assert!(!l.out.touches_config());
    assert_eq!(*s.settings(), before);
    // With mechanics it applies; the drive's change carries the derived
    // configuration.
    assert!(set.set_mechanics(&Mechanics {
        inertia_kg_m2: 2e-5,
        viscous_friction_nm_s_per_rad: 0.0,
        coulomb_friction_nm: 0.0,
    }));
    let rec = DriveRecord::from_settings(&Label::new(), PWM_HZ, &set);
    let n = rec.encode(&mut buf).unwrap();
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    assert!(l
        .store(StoreOp::Apply, &buf[..n], WatchdogConfig::OFF)
        .is_ok());
    assert!(l.out.touches_config());
    assert_eq!(s.settings().sensorless, Some(sensorless));
    let change = s.full_change().current.unwrap();
    let derived = change.sensorless.unwrap().expect("sensorless");
    assert_eq!((derived.current_a, derived.bus_voltage_v), (4.0, 24.0));
    assert_eq!(derived.observer.motor, s.settings().current.motor);
    assert_eq!(change.beside, Some(None));
    // Beside the sensor (limp-home): the drive stays on its sensor, the
    // change carries the observer beside it.
    set.sensorless = Some(SensorlessRecord {
        beside_sensor: Some(foc_store::record::BesideRole::LimpHome),
        ..sensorless
    });
    let rec = DriveRecord::from_settings(&Label::new(), PWM_HZ, &set);
    let n = rec.encode(&mut buf).unwrap();
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    assert!(l
        .store(StoreOp::Apply, &buf[..n], WatchdogConfig::OFF)
        .is_ok());
    let change = s.full_change().current.unwrap();
    assert_eq!(change.sensorless, Some(None));
    let beside = change.beside.unwrap().expect("beside");
    assert!(beside.limp_home && beside.observer_above_rad_s.is_none());
    assert_eq!(beside.sensorless, derived);
    // Back to running sensorless for what follows.
    set.sensorless = Some(sensorless);
    let rec = DriveRecord::from_settings(&Label::new(), PWM_HZ, &set);
    let n = rec.encode(&mut buf).unwrap();
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    assert!(l
        .store(StoreOp::Apply, &buf[..n], WatchdogConfig::OFF)
        .is_ok());
    // The angle source the drive reports.
    let mut snap = quiet_snapshot();
    snap.status.sensorless = true;
    let l = link(&mut s, snap, &mut st);
    assert_eq!(
        l.param(foc_protocol::message::ParamId::AngleSource),
        Some(1.0)
    );
    // Limp-home, and the observer beside the sensor driving the loop.
    use foc_core::control::AngleInUse;
    for (sensorless, in_use, code) in [
        (true, AngleInUse::LimpHome, 3.0),
        (false, AngleInUse::Observer, 2.0),
        (false, AngleInUse::Sensor, 0.0),
    ] {
        let mut snap = quiet_snapshot();
        snap.status.sensorless = sensorless;
        snap.feedback.angle_in_use = in_use;
        let l = link(&mut s, snap, &mut st);
        assert_eq!(
            l.param(foc_protocol::message::ParamId::AngleSource),
            Some(code)
        );
        assert_eq!(l.telemetry().angle_in_use, in_use);
    }
}

/// A calibration made without the sensor (design §29) on a board with a
/// counting encoder (4096 counts, its zero lost at reset): saved, it boots
/// calibrated and reaches the drive as a `sensorless_only` permit (it has
/// no zero to lose); the drive's stage then unlocks the closed loop only
/// while it runs sensorless (foc-core's `CurrentStage::is_calibrated`).
#[test]
fn a_calibration_made_without_the_sensor_boots_on_an_incremental_encoder_board() {
    use foc_core::control::stage::AngleCalibration;
    let encoder_board = || {
        let mut b = board(false);
        b.base.angle.sensor_counts_per_rev = 4096;
        b
    };
    let s = Service::new(encoder_board());
    let mut set = *s.settings();
    set.angle = AngleCalibration::sensorless(7, 4096);
    set.calibrated = true;
    let rec = DriveRecord::from_settings(&Label::try_from("nosensor").unwrap(), PWM_HZ, &set);
    assert!(rec.calibration.is_some_and(|c| c.sensorless_only));
    let mut st = store();
    st.save(&rec).unwrap();
    let (booted, outcome) = Service::boot(encoder_board(), Some(&mut st));
    assert_eq!(outcome, BootOutcome::Loaded { calibrated: true });
    let permit = booted.full_change().current.unwrap().permit;
    assert!(permit.is_some_and(|p| p.angle().sensorless_only));
    // A calibration made with the encoder on the same board: its zero is
    // lost at reset, so it is not installed (the rule this one is the
    // exception to).
    set.angle = AngleCalibration {
        sensorless_only: false,
        ..set.angle
    };
    let rec = DriveRecord::from_settings(&Label::try_from("encoder").unwrap(), PWM_HZ, &set);
    st.save(&rec).unwrap();
    let (booted, outcome) = Service::boot(encoder_board(), Some(&mut st));
    assert_eq!(outcome, BootOutcome::Loaded { calibrated: false });
    assert!(booted.full_change().current.unwrap().permit.is_none());
}

/// `board(true)` on halls: 48 counts a turn on 7 pole pairs, a coarse
/// angle sensor.
fn hall_board() -> Board {
    let mut cascade = board(true).cascade;
    cascade.current.angle.sensor_counts_per_rev = 48;
    let mut b = Board::new(cascade, PWM_HZ, MAX_CURRENT_A);
    b.zero_survives_reset = true;
    b
}

/// The d-current reference (design §30) through the link, as every front
/// end sends it: its parameters read, and written one at a time through
/// the protocol, the whole judged with the drive's rule; bad values and
/// field weakening on halls refused, changing nothing; a record carries
/// it (checked whole against the board), a record without one the
/// motor's defaults.
#[test]
fn the_field_settings_are_admitted_whole_or_refused_with_nothing_changed() {
    use foc_core::control::field::FieldConfig;
    use foc_protocol::device::DeviceState;
    use foc_protocol::message::{ParamId, Request, Response};
    let mut s = Service::new(board(true));
    let mut st = store();
    let mut dev = DeviceState::new();
    let mut seq = 0u16;
    let mut send = |s: &mut Service, st: &mut Store<Flash>, id, value| {
        seq += 1;
        let mut l = link(s, quiet_snapshot(), st);
        let r = dev.handle(&mut l, seq, 0, &Request::SetParam { id, value });
        (r, l.out.config.current.and_then(|c| c.field))
    };
    let defaults = s.settings().field;
    let motor = s.board().cascade.current.current.motor;
    assert_eq!(
        defaults,
        FieldConfig::for_motor(&motor, MAX_CURRENT_A, PWM_HZ as f32)
    );
    let read = |s: &mut Service, st: &mut Store<Flash>, id| {
        link(s, quiet_snapshot(), st).param(id).unwrap()
    };
    assert_eq!(read(&mut s, &mut st, ParamId::FieldWeakening), 0.0);
    assert_eq!(read(&mut s, &mut st, ParamId::MaxIdA), defaults.max_id_a);
    // One setting at a time: the drive gets the whole reference.
    let (r, change) = send(&mut s, &mut st, ParamId::FieldWeakening, 1.0);
    assert_eq!(r, Response::Ack);
    let on = FieldConfig {
        field_weakening: true,
        ..defaults
    };
    assert_eq!((s.settings().field, change), (on, Some(on)));
    let (r, _) = send(&mut s, &mut st, ParamId::MaxIdA, 6.5);
    assert_eq!(r, Response::Ack);
    let (r, _) = send(&mut s, &mut st, ParamId::ShortCircuit, 1.0);
    assert_eq!(r, Response::Ack);
    let (r, _) = send(&mut s, &mut st, ParamId::Mtpa, 1.0);
    assert_eq!(r, Response::Ack);
    let set = FieldConfig {
        mtpa: true,
        max_id_a: 6.5,
        short_circuit: true,
        ..on
    };
    assert_eq!(s.settings().field, set);
    assert_eq!(read(&mut s, &mut st, ParamId::MaxIdA), 6.5);
    assert_eq!(read(&mut s, &mut st, ParamId::Mtpa), 1.0);
    assert_eq!(read(&mut s, &mut st, ParamId::ShortCircuit), 1.0);
    assert_eq!(s.full_change().current.unwrap().field, Some(set));
    // Bad values: refused by the protocol (the value named), or by the
    // drive's rule (field weakening without a current); nothing changes.
    for (id, value, want) in [
        (
            ParamId::MaxIdA,
            f32::NAN,
            ErrorCode::OutOfRange { field: 1 },
        ),
        (ParamId::MaxIdA, -1.0, ErrorCode::OutOfRange { field: 1 }),
        (
            ParamId::FieldWeakening,
            0.5,
            ErrorCode::OutOfRange { field: 1 },
        ),
        (
            ParamId::MaxCurrentA,
            1.0,
            ErrorCode::OutOfRange { field: 0 },
        ),
        (ParamId::MaxIdA, 0.0, ErrorCode::Unsupported),
    ] {
        let (r, change) = send(&mut s, &mut st, id, value);
        assert_eq!(r, Response::Nack(want), "{id:?} {value}");
        assert_eq!((s.settings().field, change), (set, None), "{id:?}");
    }
    // Saved and loaded: the record carries it.
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    l.store(StoreOp::Save, &[], WatchdogConfig::OFF).unwrap();
    let rec = st.load().unwrap().unwrap();
    assert_eq!(
        rec.field,
        Some(foc_store::record::FieldRecord::from_config(&set))
    );
    let (booted, _) = Service::boot(board(true), Some(&mut st));
    assert_eq!(booted.settings().field, set);
    assert_eq!(booted.cascade().current.field, set);
    // On halls: the record with field weakening is refused, whole, with
    // the reason; so is the parameter. MTPA and the short circuit are
    // fine.
    let halls = hall_board();
    assert_eq!(
        foc_service::records::admit(&halls, &rec).map(|_| ()),
        Err(foc_store::Invalid {
            field: "field.field_weakening"
        })
    );
    let mut h = Service::new(halls);
    let before = *h.settings();
    let mut buf = [0u8; foc_protocol::config::MAX_RECORD];
    let n = rec.encode(&mut buf).unwrap();
    let mut l = link(&mut h, quiet_snapshot(), &mut st);
    assert_eq!(
        l.store(StoreOp::Apply, &buf[..n], WatchdogConfig::OFF),
        Err(ErrorCode::BadRecord)
    );
    assert!(!l.out.touches_config());
    assert_eq!(*h.settings(), before);
    let (r, change) = send(&mut h, &mut st, ParamId::FieldWeakening, 1.0);
    assert_eq!((r, change), (Response::Nack(ErrorCode::Unsupported), None));
    assert_eq!(*h.settings(), before);
    let (r, _) = send(&mut h, &mut st, ParamId::Mtpa, 1.0);
    assert_eq!(r, Response::Ack);
    assert!(h.settings().field.mtpa);
    // A record's values out of range: refused, named.
    for (bad, field) in [
        (
            FieldConfig {
                voltage_margin: 0.7,
                ..set
            },
            "field.voltage_margin",
        ),
        (
            FieldConfig {
                max_id_a: f32::NAN,
                ..set
            },
            "field.max_id_a",
        ),
    ] {
        let mut r = rec.clone();
        r.field = Some(foc_store::record::FieldRecord::from_config(&bad));
        assert_eq!(
            foc_service::records::admit(s.board(), &r).map(|_| ()),
            Err(foc_store::Invalid { field })
        );
    }
    // A record without one (an older schema's): the motor's defaults.
    let mut old = rec.clone();
    old.field = None;
    let a = foc_service::records::admit(s.board(), &old).unwrap();
    assert_eq!(a.field, defaults);
}

/// An identification that finds a salient motor with a small
/// characteristic current re-derives the d-current reference (design
/// §30): MTPA on, the short circuit on, the deepest weakening no deeper
/// than 0.75 psi/Ld; field weakening stays as set. The drive gets it.
#[test]
fn an_identification_rederives_the_d_current_reference() {
    use foc_core::calibration::identification::IdentificationResult;
    use foc_core::control::permit::Calibrated;
    use foc_service::Identified;
    let mut s = Service::new(board(true));
    let before = s.settings().field;
    assert!(!before.mtpa && !before.short_circuit, "{before:?}");
    // The identified motor: Lq 50 % above Ld, psi/Ld = 5 A.
    let motor = MotorParams {
        pole_pairs: 7,
        r_ohm: 0.1,
        ld_h: 800e-6,
        lq_h: 1200e-6,
        flux_linkage_wb: 0.004,
    };
    let c = s.cascade();
    let mut current = c.current.current;
    current.motor = motor;
    let angle = c.current.angle;
    let permit = Calibrated::supplied(angle, current).unwrap();
    let result = IdentificationResult {
        r_ohm: motor.r_ohm,
        ld_h: motor.ld_h,
        lq_h: motor.lq_h,
        flux_linkage_wb: motor.flux_linkage_wb,
        mechanics: None,
        angle,
        pole_pairs: 7,
    };
    s.fold_identification(Some(Identified {
        result,
        permit,
        count: 1,
    }));
    let after = s.settings().field;
    assert!(after.mtpa && after.short_circuit, "{after:?}");
    assert!((after.max_id_a - 0.75 * 5.0).abs() < 1e-3, "{after:?}");
    assert_eq!(after.field_weakening, before.field_weakening);
    let pending = s.take_pending();
    assert_eq!(pending.current.and_then(|c| c.field), Some(after));
}

/// The tables of the tests: a 0.3 A, 12-cycle cogging map and a 5 mrad
/// eccentric correction, both on.
fn tables() -> foc_store::settings::Tables {
    use foc_core::control::angle_correction::{AngleCorrection, CORRECTION_BINS};
    use foc_core::control::cogging::{CoggingMap, COGGING_BINS};
    let tau = core::f32::consts::TAU;
    let amps: [f32; COGGING_BINS] =
        core::array::from_fn(|k| 0.3 * (12.0 * tau * (k as f32 + 0.5) / 512.0).sin());
    let rad: [f32; CORRECTION_BINS] =
        core::array::from_fn(|k| 0.005 * (tau * (k as f32 + 0.5) / 256.0).sin());
    foc_store::settings::Tables {
        cogging: CoggingMap::from_amps(&amps).unwrap(),
        angle_correction: AngleCorrection::from_rad(&rad).unwrap(),
    }
}

/// A stored record's tables: where the sensor's reading keeps its zero
/// across a reset both apply; on an incremental encoder the correction is
/// dropped, and the map stored with it too; loaded at boot and by
/// `Load`/`Apply` (the outbox asks the owner to install them, never in
/// the configuration change); saved back with the record.
#[test]
fn stored_tables_are_admitted_per_board_and_reach_the_owner_outside_the_mailbox() {
    use foc_store::settings::Tables;
    for survives in [true, false] {
        let s = Service::new(board(survives));
        let rec = calibrated_record(&s).with_tables(&tables());
        let mut st = store();
        st.save(&rec).unwrap();
        // On an incremental encoder the correction is dropped, and the map
        // measured on it with it (design §32).
        let want = if survives { tables() } else { Tables::NONE };
        let (booted, _) = Service::boot(board(survives), Some(&mut st));
        assert_eq!(*booted.tables(), want, "boot, survives {survives}");
        let mut s = Service::new(board(survives));
        let mut l = link(&mut s, quiet_snapshot(), &mut st);
        l.store(StoreOp::Load, &[], WatchdogConfig::OFF).unwrap();
        assert!(l.out.tables, "the owner installs them");
        assert!(l.out.config.current.is_some());
        assert_eq!(*s.tables(), want, "load, survives {survives}");
        // The live record (what a save writes) carries them.
        let live = s.live_record(WatchdogConfig::OFF);
        assert_eq!(Tables::of_record(&live), want);
    }
    // Applied into a stage: whole.
    let mut s = Service::new(board(true));
    let mut st = store();
    st.save(&calibrated_record(&s).with_tables(&tables()))
        .unwrap();
    link(&mut s, quiet_snapshot(), &mut st)
        .store(StoreOp::Load, &[], WatchdogConfig::OFF)
        .unwrap();
    let mut stage = foc_core::control::stage::CurrentStage::new(s.cascade().current);
    assert_eq!(s.install_tables(&mut stage), Ok(()));
    assert_eq!(Tables::of_stage(&stage), tables());
}

/// The switches: on without a table is `NotCalibrated`; with one, the
/// switch reaches the tables in force and the outbox asks the owner to
/// install them (never the mailbox's change); not while a command waits;
/// read back as parameters with the peaks.
#[test]
fn the_table_switches_need_a_table_and_a_quiet_drive() {
    use foc_protocol::message::ParamId;
    let mut s = Service::new(board(true));
    let mut st = store();
    for id in [ParamId::Anticogging, ParamId::EncoderLinearisation] {
        let mut l = link(&mut s, quiet_snapshot(), &mut st);
        assert_eq!(l.set_param(id, 1.0), Err(Refusal::NotCalibrated), "{id:?}");
        assert!(!l.out.tables);
        assert_eq!(l.param(id), Some(0.0));
        assert_eq!(l.set_param(id, 0.0), Ok(()), "off is always taken");
    }
    // A calibration measured both (the stage holds them).
    let mut stage = foc_core::control::stage::CurrentStage::new(s.cascade().current);
    assert_eq!(tables().install(&mut stage), Ok(()));
    s.take_measured_tables(1, &stage);
    assert_eq!(s.tables_seen(), 1);
    assert_eq!(*s.tables(), tables());
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    assert_eq!(l.param(ParamId::Anticogging), Some(1.0));
    let peak = l.param(ParamId::AnticoggingPeakA).unwrap();
    assert!((peak - 0.3).abs() < 1e-3, "{peak}");
    let peak = l.param(ParamId::EncoderCorrectionPeakRad).unwrap();
    assert!((peak - 0.005).abs() < 1e-4, "{peak}");
    assert_eq!(l.set_param(ParamId::Anticogging, 0.0), Ok(()));
    assert!(l.out.tables && l.out.config.current.is_none());
    assert_eq!(l.param(ParamId::Anticogging), Some(0.0));
    assert_eq!(l.set_param(ParamId::EncoderLinearisation, 0.0), Ok(()));
    assert!(!s.tables().cogging.enabled && !s.tables().angle_correction.enabled);
    assert_eq!(s.install_tables(&mut stage), Ok(()));
    assert!(!stage.cogging().enabled && !stage.angle_correction().enabled);
    // A command waiting in the mailbox: not now.
    let mut snap = quiet_snapshot();
    snap.pending.command = Command::Velocity { rad_s: 1.0 };
    let mut l = link(&mut s, snap, &mut st);
    assert_eq!(
        l.set_param(ParamId::Anticogging, 1.0),
        Err(Refusal::NotDisabled)
    );
    assert!(!l.out.tables);
    // Saved with the switches as they stand.
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    assert_eq!(l.set_param(ParamId::Anticogging, 1.0), Ok(()));
    l.store(StoreOp::Save, &[], WatchdogConfig::OFF).unwrap();
    let saved = st.load().unwrap().unwrap();
    assert!(saved.cogging.unwrap().enabled);
    assert!(!saved.angle_correction.unwrap().enabled);
    // The same count again takes nothing.
    let other = foc_core::control::stage::CurrentStage::new(s.cascade().current);
    s.take_measured_tables(1, &other);
    assert!(s.tables().has_cogging());
}

/// A current limit below the map's peak would make the configuration
/// unsaveable: refused, nothing changes.
#[test]
fn limits_below_the_anticogging_peak_are_refused() {
    let mut s = Service::new(board(true));
    let mut st = store();
    let mut stage = foc_core::control::stage::CurrentStage::new(s.cascade().current);
    tables().install(&mut stage).unwrap();
    s.take_measured_tables(1, &stage);
    let before = s.settings().limits;
    let mut l = link(&mut s, quiet_snapshot(), &mut st);
    let low = Limits {
        max_current_a: 0.25,
        ..before
    };
    assert_eq!(l.set_limits(low), Err(Refusal::Unsupported));
    assert!(!l.out.touches_config());
    let ok = Limits {
        max_current_a: 0.5,
        ..before
    };
    assert_eq!(l.set_limits(ok), Ok(()));
}

/// A stage that refuses the tables (its current limit below the map's
/// peak) keeps its own, and they become the ones in force again.
#[test]
fn tables_the_stage_refuses_fall_back_to_the_stages() {
    use foc_store::settings::Tables;
    let mut s = Service::new(board(true));
    let mut st = store();
    st.save(&calibrated_record(&s).with_tables(&tables()))
        .unwrap();
    link(&mut s, quiet_snapshot(), &mut st)
        .store(StoreOp::Load, &[], WatchdogConfig::OFF)
        .unwrap();
    let mut cfg = s.cascade().current;
    cfg.limits.max_current_a = 0.1;
    let mut stage = foc_core::control::stage::CurrentStage::new(cfg);
    assert_eq!(
        s.install_tables(&mut stage).unwrap_err().field,
        "cogging.table"
    );
    assert_eq!(Tables::of_stage(&stage), Tables::NONE, "nothing installed");
    assert_eq!(*s.tables(), Tables::NONE);
    s.tables_not_installed(&stage);
    assert_eq!(*s.tables(), Tables::NONE);
}

/// The sweeps are asked of the drive through the configuration change's
/// flags, after the drive's own rule on the snapshot and the angle
/// calibration in force: uncalibrated, halls, sensorless are refused at
/// once; a request waiting makes the store busy.
#[test]
fn the_sweep_calibrations_follow_the_drives_rule() {
    for routine in [Calibration::Anticogging, Calibration::EncoderLinearisation] {
        let mut s = Service::new(board(true));
        let mut st = store();
        let mut l = link(&mut s, quiet_snapshot(), &mut st);
        assert_eq!(l.start_calibration(routine), Ok(()));
        let c = l.out.config.current.unwrap();
        assert_eq!(
            (c.calibrate_cogging, c.calibrate_encoder),
            (
                routine == Calibration::Anticogging,
                routine == Calibration::EncoderLinearisation
            )
        );
        assert!(l.out.config.calibration_pending());
        assert_eq!(
            l.store(StoreOp::Save, &[], WatchdogConfig::OFF),
            Err(ErrorCode::Busy)
        );
        let mut snap = quiet_snapshot();
        snap.status.calibrated = false;
        let mut l = link(&mut s, snap, &mut st);
        assert_eq!(l.start_calibration(routine), Err(Refusal::NotCalibrated));
        assert!(!l.out.touches_config());
        let mut snap = quiet_snapshot();
        snap.status.sensorless = true;
        let mut l = link(&mut s, snap, &mut st);
        assert_eq!(l.start_calibration(routine), Err(Refusal::Unsupported));
        let mut h = Service::new(hall_board());
        let mut l = link(&mut h, quiet_snapshot(), &mut st);
        assert_eq!(l.start_calibration(routine), Err(Refusal::Unsupported));
        assert!(!l.out.touches_config());
        // A command waiting in the mailbox (the status not yet showing
        // it): the sweep would overtake it.
        let mut snap = quiet_snapshot();
        snap.pending.command = Command::Velocity { rad_s: 0.0 };
        let mut l = link(&mut s, snap, &mut st);
        assert_eq!(l.start_calibration(routine), Err(Refusal::NotDisabled));
        assert!(!l.out.touches_config());
    }
}
