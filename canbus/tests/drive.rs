//! The real drive on the host ([`HostDrive`]) and on the bus
//! ([`DriveNode`] with the stand-in protocol).

use foc_canbus::bus::{Bus, Origin, PortKind};
use foc_canbus::drive_node::{DriveNode, MiniProtocol};
use foc_canopen::CanFrame;
use foc_core::control::{Command, Mode};
use foc_protocol::config::StoreOp;
use foc_protocol::device::{DeviceContext, WatchdogConfig};
use foc_protocol::message::SpeedGains;
use foc_simdrive::{FaultKind, HostDrive};

const LINK: WatchdogConfig = WatchdogConfig {
    timeout_periods: 20_000,
    reaction: foc_core::control::stage::TimeoutReaction::Stop,
};

#[test]
fn velocity_command_reaches_the_speed_on_the_plant() {
    let mut d = HostDrive::new();
    assert!(d.is_calibrated());
    assert_eq!(d.mode(), Mode::Disabled);
    d.post(Command::Velocity { rad_s: 100.0 }).unwrap();
    d.step_periods(8000); // 0.4 s
    assert_eq!(d.mode(), Mode::Velocity);
    let w = d.plant_velocity_rad_s();
    assert!((w - 100.0).abs() < 2.0, "plant at {w} rad/s");
    assert!((d.telemetry().velocity_rad_s - 100.0).abs() < 2.0);
    assert!(d.faults().0.is_empty());
    assert_eq!(d.periods(), 8000);
}

#[test]
fn a_save_survives_a_power_cycle() {
    let mut d = HostDrive::new();
    assert_eq!(d.stored_record(), Ok(None));
    let mut g = SpeedGains {
        kp_a_per_rad_s: d.settings().speed.kp_a_per_rad_s,
        ki_a_per_rad: d.settings().speed.ki_a_per_rad,
    };
    g.kp_a_per_rad_s *= 1.5;
    d.set_speed_gains(g).unwrap();
    d.store(StoreOp::Save, &[], LINK).unwrap();
    d.power_cycle();
    assert_eq!(d.settings().speed.kp_a_per_rad_s, g.kp_a_per_rad_s);
    assert_eq!(d.boot_link_setting(), Some(LINK));
    assert!(d.stored_record().unwrap().is_some());
    assert!(d.is_calibrated());
    // Still drives after the reset.
    d.post(Command::Velocity { rad_s: 50.0 }).unwrap();
    d.step_periods(6000);
    assert!((d.plant_velocity_rad_s() - 50.0).abs() < 2.0);
    // No save while enabled; erase when disabled, then defaults at boot.
    assert!(d.store(StoreOp::Save, &[], LINK).is_err());
    d.post(Command::Disable).unwrap();
    d.store(StoreOp::Erase, &[], LINK).unwrap();
    d.power_cycle();
    assert_ne!(d.settings().speed.kp_a_per_rad_s, g.kp_a_per_rad_s);
    assert_eq!(d.boot_link_setting(), None);
}

#[test]
fn injected_faults_trip_the_drive() {
    for kind in [FaultKind::EncoderStuck, FaultKind::PhaseShort] {
        let mut d = HostDrive::new();
        d.post(Command::Velocity { rad_s: 100.0 }).unwrap();
        d.step_periods(4000);
        assert!(d.faults().0.is_empty());
        d.inject(kind);
        d.step_periods(4000);
        let (faults, first) = d.faults();
        assert!(!faults.is_empty(), "{kind:?} tripped nothing");
        assert_eq!(d.mode(), Mode::Disabled, "{kind:?}: {first:?}");
        // A power cycle brings it back healthy.
        d.power_cycle();
        assert!(d.faults().0.is_empty());
    }
}

fn frame(id: u16, d: &[u8]) -> CanFrame {
    CanFrame::new(id, d).unwrap()
}

/// Velocity [rad/s] and fault code of each node's last TPDO.
fn last_tpdo(out: &[(u32, CanFrame)], id: u16) -> (f32, u8) {
    let f = out
        .iter()
        .rev()
        .find(|(_, f)| f.id == 0x180 + id)
        .unwrap()
        .1;
    let d = f.data();
    (f32::from_le_bytes([d[0], d[1], d[2], d[3]]), d[5])
}

#[test]
fn drives_on_the_bus_and_a_fault_on_one_node() {
    let mut bus = Bus::new(1000);
    for id in 1..=3 {
        bus.add_node(Box::new(DriveNode::new(id, MiniProtocol::for_drive)));
    }
    bus.boot();
    bus.add_port(1, PortKind::Client);
    bus.open_port(1);
    let boot: Vec<u16> = bus.take_outbox().iter().map(|(_, f)| f.id).collect();
    assert_eq!(boot, [0x701, 0x702, 0x703]);
    let m = Origin::Port(1);
    bus.send(m, frame(0x201, &60f32.to_le_bytes()));
    bus.send(m, frame(0x202, &(-80f32).to_le_bytes()));
    for _ in 0..300 {
        bus.send(m, frame(0x080, &[]));
    }
    let out = bus.take_outbox();
    let (w1, _) = last_tpdo(&out, 1);
    let (w2, _) = last_tpdo(&out, 2);
    let (w3, _) = last_tpdo(&out, 3);
    assert!((w1 - 60.0).abs() < 2.0, "{w1}");
    assert!((w2 + 80.0).abs() < 2.0, "{w2}");
    assert!(w3.abs() < 0.5, "{w3}");
    // Heartbeats at 100, 200 and 300 ms.
    assert_eq!(out.iter().filter(|(_, f)| f.id == 0x702).count(), 3);
    // Node 1's encoder breaks: its EMCY, and only its.
    assert_eq!(bus.control("fault 1 encoder"), "ok fault 1 encoder");
    for _ in 0..200 {
        bus.send(m, frame(0x080, &[]));
    }
    let out = bus.take_outbox();
    let emcy: Vec<u16> = out
        .iter()
        .filter(|(_, f)| (0x081..=0x0FF).contains(&f.id))
        .map(|(_, f)| f.id)
        .collect();
    assert_eq!(emcy, [0x081]);
    assert_ne!(last_tpdo(&out, 1).1, 0);
    let (w2, code2) = last_tpdo(&out, 2);
    assert!((w2 + 80.0).abs() < 2.0 && code2 == 0, "{w2} {code2}");
    // Reset node 1: it boots healthy, and runs again on command.
    assert_eq!(bus.control("reset 1"), "ok reset 1");
    bus.send(m, frame(0x201, &30f32.to_le_bytes()));
    for _ in 0..300 {
        bus.send(m, frame(0x080, &[]));
    }
    let out = bus.take_outbox();
    assert_eq!(out[0].1, frame(0x701, &[0]));
    let (w1, code1) = last_tpdo(&out, 1);
    assert!((w1 - 30.0).abs() < 2.0 && code1 == 0, "{w1} {code1}");
    assert_eq!(bus.now_us(), 800_000);
}
