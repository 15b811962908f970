//! The node with the real CiA 402 profile. Ignored until the profile's
//! bodies.

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
