//! The bus over TCP with the fake node: a Rust SLCAN client against the
//! binary's library entry ([`foc_canbus::start`]).

mod common;

use common::{f, Client, Rx};
use foc_canbus::{start, NodeKind, Options};

fn fake_bus(nodes: u8) -> foc_canbus::server::Server {
    start(&Options {
        nodes,
        node: NodeKind::Fake,
        ..Options::default()
    })
    .unwrap()
}

#[test]
fn boot_ups_reach_a_late_master_and_frames_are_routed() {
    let server = fake_bus(3);
    std::thread::sleep(std::time::Duration::from_millis(50));
    let mut a = Client::open(server.addr());
    a.wait_count(0x703, 1);
    // The open sequence's three commands are answered (the empty line is not), then the backlog.
    assert_eq!(&a.rx[..3], &[Rx::Ok, Rx::Ok, Rx::Ok]);
    assert_eq!(
        a.frames(),
        vec![f(0x701, &[0]), f(0x702, &[0]), f(0x703, &[0])]
    );
    let mut b = Client::open(server.addr());
    b.wait_until(|rx| rx.len() >= 3);
    // a -> b (and the nodes), node 2 echoes its SDO to both.
    a.frame(0x123, &[1, 2, 3]);
    a.frame(0x602, &[0x40, 0x00, 0x10, 0x00]);
    b.wait_count(0x582, 1);
    assert_eq!(
        b.frames(),
        vec![
            f(0x123, &[1, 2, 3]),
            f(0x602, &[0x40, 0, 0x10, 0]),
            f(0x582, &[0x40, 0, 0x10, 0])
        ]
    );
    a.wait_count(0x582, 1);
    // a does not get its own frames back.
    assert!(!a.frames().iter().any(|x| x.id == 0x123 || x.id == 0x602));
    // Version queries.
    a.raw(b"V\rN\r");
    a.wait_until(|rx| rx.iter().filter(|r| **r == Rx::Other).count() >= 2);
    server.shutdown();
}

/// 150 SYNCs with SDO requests in between: the whole received sequence.
fn sync_scenario() -> (Vec<foc_canopen::CanFrame>, String) {
    let server = fake_bus(3);
    let mut c = Client::open(server.addr());
    for k in 0..150u16 {
        c.frame(0x080, &[]);
        if k % 7 == 0 {
            c.frame(0x600 + 1 + k % 3, &[k as u8]);
        }
    }
    c.wait_count(0x183, 150);
    let time = server.control("time");
    server.shutdown();
    (c.frames(), time)
}

#[test]
fn sync_advances_time_deterministically() {
    let (one, time) = sync_scenario();
    // The last TPDO answers the 150th SYNC, at 149 ms, 2980 periods run.
    let last = one.iter().rev().find(|x| x.id == 0x181).unwrap();
    assert_eq!(&last.data()[..4], &149_000u32.to_le_bytes());
    assert_eq!(&last.data()[4..], &2980u32.to_le_bytes());
    assert_eq!(time, "ok 150000");
    // Heartbeats at 100 ms of bus time, between the 100th and 101st TPDO.
    let hb: Vec<_> = one.iter().filter(|x| x.id == 0x701).collect();
    assert_eq!(hb.len(), 2, "boot-up and one heartbeat");
    let (two, _) = sync_scenario();
    assert_eq!(one, two);
}

#[test]
fn control_lines() {
    let server = fake_bus(3);
    let mut c = Client::open(server.addr());
    c.wait_count(0x703, 1);
    assert_eq!(server.control("nodes"), "ok 1 2 3");
    assert_eq!(server.control("bus-off 2 3"), "ok bus-off 2 until 3000");
    // Node 2 hears nothing and says nothing: node 1's answer comes, 2's not.
    c.frame(0x602, &[9]);
    c.frame(0x601, &[8]);
    c.wait_count(0x581, 1);
    c.settle(50);
    assert!(!c.frames().iter().any(|x| x.id == 0x582));
    for _ in 0..3 {
        c.frame(0x080, &[]);
    }
    // Recovered after 3 ms of bus time: it says so, and answers again.
    c.wait_count(0x082, 1);
    assert_eq!(
        c.frames().iter().find(|x| x.id == 0x082).unwrap().data(),
        &[0, 0x81, 0]
    );
    c.frame(0x602, &[7]);
    c.wait_count(0x582, 1);
    // Reset: boot-up again.
    assert_eq!(server.control("reset 3"), "ok reset 3");
    c.wait_count(0x703, 2);
    // Fault: an EMCY at the next tick.
    assert_eq!(
        server.control("fault 1 encoder"),
        "ok node 1 fake fault encoder"
    );
    c.frame(0x080, &[]);
    c.wait_count(0x081, 1);
    for bad in [
        "fault 9 encoder",
        "bus-off 1",
        "bus-off 1 x",
        "reset 0",
        "reset 1 2",
        "bogus",
        "",
    ] {
        assert!(server.control(bad).starts_with("err "), "{bad:?}");
    }
    assert_eq!(server.control("time"), "ok 4000");
    server.shutdown();
}

#[test]
fn malformed_lines_are_ignored_without_harm() {
    let server = fake_bus(1);
    let mut a = Client::open(server.addr());
    a.wait_count(0x701, 1);
    let mut b = Client::open(server.addr());
    b.wait_until(|rx| rx.len() >= 3);
    let mut junk = Vec::new();
    junk.extend_from_slice(b"garbage\rt12\rt8000\rt1239\rd1230\r");
    junk.extend_from_slice(&[b'x'; 300]);
    junk.extend_from_slice(b"\r\x00\xff\rT1FFFFFFF0\rt1231AB\r");
    a.raw(&junk);
    b.wait_count(0x123, 1);
    assert_eq!(b.frames(), vec![f(0x123, &[0xAB])]);
    a.wait_until(|rx| rx.iter().filter(|r| **r == Rx::Bell).count() >= 7);
    // A client that leaves in the middle of a line changes nothing.
    let mut c = Client::open(server.addr());
    c.raw(b"t12");
    drop(c);
    // A frame before the channel is open is refused with BEL.
    let mut d = Client::connect(server.addr());
    d.raw(b"t1230\r");
    d.wait_until(|rx| rx.contains(&Rx::Bell));
    a.frame(0x601, &[1]);
    a.wait_count(0x581, 1);
    b.wait_count(0x581, 1);
    assert!(!b.frames().iter().any(|x| x.id == 0x123 && x.len == 0));
    server.shutdown();
}
