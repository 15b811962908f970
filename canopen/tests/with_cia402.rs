//! The node with the real CiA 402 profile.
// Test support outside `#[test]` functions: unwrapping and indexing a
// fixture is the test failing, which is what it should do.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

mod common;

use common::*;
use foc_canopen::cia402::Cia402;
use foc_canopen::node::{CommSettings, Node};
use foc_canopen::CanFrame;

#[test]

fn cia402_parameter_defaults_are_the_tables() {
    let real = Cia402::new();
    let fake = FakeProfile::new();
    assert_eq!(
        real.params, fake.params,
        "od/table.rs defaults vs Cia402::new"
    );
    assert_eq!(real.check_params(&real.params), Ok(()));
}

#[test]

fn node_with_cia402_boots_serves_sdo_and_pdo() {
    let mut dev = FakeDevice::new();
    let mut sent = Vec::new();
    let mut node = Node::new(CommSettings::new(ID, 1000, 100, None).unwrap());
    node.boot(0, &mut dev, &mut |f| sent.push(f));
    node.tick(1000, &mut dev, &mut |f| sent.push(f));
    assert!(node.read_object(0x6041, 0, &dev).is_ok());
    node.on_frame(
        &CanFrame::new(0, &[1, ID]).unwrap(),
        2000,
        &mut dev,
        &mut |f| sent.push(f),
    );
    // Shutdown over RPDO1, then a tick: the profile follows.
    node.on_frame(
        &CanFrame::new(0x205, &[0x06, 0]).unwrap(),
        3000,
        &mut dev,
        &mut |f| sent.push(f),
    );
    node.tick(4000, &mut dev, &mut |f| sent.push(f));
    assert_eq!(node.cia402().controlword(), 0x06);
    assert!(sent.iter().any(|f| f.id == 0x185));
}

/// A node, booted and operational, with the real profile.
fn operational() -> (Node, FakeDevice, Vec<CanFrame>) {
    let mut dev = FakeDevice::new();
    let mut sent = Vec::new();
    let mut node = Node::new(CommSettings::new(ID, 1000, 100, None).unwrap());
    node.boot(0, &mut dev, &mut |f| sent.push(f));
    node.tick(1000, &mut dev, &mut |f| sent.push(f));
    node.on_frame(
        &CanFrame::new(0, &[1, ID]).unwrap(),
        2000,
        &mut dev,
        &mut |f| sent.push(f),
    );
    (node, dev, sent)
}

#[test]
fn one_rpdo_is_one_data_set_the_controlword_acts_last() {
    let (mut node, mut dev, mut sent) = operational();
    for (t, cw) in [(3000, 0x06u8), (4000, 0x07)] {
        node.on_frame(
            &CanFrame::new(0x205, &[cw, 0]).unwrap(),
            t,
            &mut dev,
            &mut |f| sent.push(f),
        );
    }
    // RPDO2 (default: controlword + mode): enable operation with the mode
    // in the same frame. Applied in mapping order the enable would meet
    // "no mode" and be refused.
    node.on_frame(
        &CanFrame::new(0x305, &[0x0F, 0, 3]).unwrap(),
        5000,
        &mut dev,
        &mut |f| sent.push(f),
    );
    assert_eq!(node.cia402().requested_mode(), 3);
    assert_eq!(
        node.cia402().actuals.statusword & 0x6F,
        0x27,
        "operation enabled, statusword {:#06x}",
        node.cia402().actuals.statusword
    );
}

#[test]
fn two_targets_mapped_in_one_rpdo_both_count() {
    let (mut node, mut dev, mut sent) = operational();
    // RPDO4: target velocity + velocity offset (remapped the CiA 301 way).
    let w = |node: &mut Node, dev: &mut FakeDevice, i: u16, s: u8, d: &[u8]| {
        node.write_object(i, s, d, 3000, dev).unwrap();
    };
    w(
        &mut node,
        &mut dev,
        0x1403,
        1,
        &0x8000_0505u32.to_le_bytes(),
    );
    w(&mut node, &mut dev, 0x1603, 0, &[0]);
    w(
        &mut node,
        &mut dev,
        0x1603,
        1,
        &0x60FF_0020u32.to_le_bytes(),
    );
    w(
        &mut node,
        &mut dev,
        0x1603,
        2,
        &0x60B1_0020u32.to_le_bytes(),
    );
    w(&mut node, &mut dev, 0x1603, 0, &[2]);
    w(
        &mut node,
        &mut dev,
        0x1403,
        1,
        &0x0000_0505u32.to_le_bytes(),
    );
    let mut data = [0u8; 8];
    data[..4].copy_from_slice(&1000i32.to_le_bytes());
    data[4..].copy_from_slice(&500i32.to_le_bytes());
    node.on_frame(
        &CanFrame::new(0x505, &data).unwrap(),
        4000,
        &mut dev,
        &mut |f| sent.push(f),
    );
    let t = node.cia402().targets;
    assert_eq!((t.velocity_inc_s, t.velocity_offset_inc_s), (1000, 500));
}

/// Operational and in operation enabled (pv).
fn enabled() -> (Node, FakeDevice, Vec<CanFrame>) {
    let (mut node, mut dev, mut sent) = operational();
    for (t, data) in [
        (3000, &[0x06u8, 0, 3][..]),
        (4000, &[0x07, 0, 3]),
        (5000, &[0x0F, 0, 3]),
    ] {
        node.on_frame(
            &CanFrame::new(0x305, data).unwrap(),
            t,
            &mut dev,
            &mut |f| sent.push(f),
        );
    }
    assert_eq!(
        node.cia402().state(),
        foc_canopen::cia402::State::OperationEnabled
    );
    (node, dev, sent)
}

#[test]
fn nmt_stop_and_resets_are_a_connection_loss_for_a_running_drive() {
    use foc_canopen::cia402::State;
    // 0x6007 = 1 (default): the drive's CommandTimeout fault, bridge off.
    for nmt in [[0x02u8, ID], [0x82, ID], [0x81, ID], [0x02, 0]] {
        let (mut node, mut dev, mut sent) = enabled();
        node.on_frame(&CanFrame::new(0, &nmt).unwrap(), 6000, &mut dev, &mut |f| {
            sent.push(f)
        });
        assert!(
            matches!(
                node.cia402().state(),
                State::FaultReactionActive | State::Fault
            ),
            "NMT {nmt:02x?}: {:?}",
            node.cia402().state()
        );
        assert!(
            dev.ctx
                .faults
                .contains(foc_core::control::Fault::CommandTimeout),
            "{nmt:02x?}"
        );
        assert_eq!(dev.ctx.posted, Some(foc_core::control::Command::Disable));
    }
}
