//! The `foc-canbus` binary (stdin control channel, `listening` line) and
//! a relay participant (the emulated firmware's UART chardev server).

mod common;

use common::{f, Client, Rx};
use foc_canbus::{start, NodeKind, Options};
use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::process::{Command, Stdio};

#[test]
fn the_binary_serves_and_answers_control_lines() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_foc-canbus"))
        .args(["--nodes", "2", "--first-id", "10", "--node", "fake"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let mut stdin = child.stdin.take().unwrap();
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    let addr = line
        .trim()
        .strip_prefix("listening ")
        .unwrap_or_else(|| panic!("{line:?}"))
        .parse()
        .unwrap();
    let mut c = Client::open(addr);
    c.wait_count(0x70B, 1);
    assert_eq!(c.frames(), vec![f(0x70A, &[0]), f(0x70B, &[0])]);
    let mut ask = |q: &str| {
        writeln!(stdin, "{q}").unwrap();
        let mut a = String::new();
        out.read_line(&mut a).unwrap();
        a.trim().to_string()
    };
    assert_eq!(ask("nodes"), "ok 10 11");
    assert_eq!(ask("bus-off 10 2"), "ok bus-off 10 until 2000");
    assert_eq!(ask("fault 11 encoder"), "ok node 11 fake fault encoder");
    assert!(ask("reset 12").starts_with("err "));
    assert_eq!(ask("quit"), "ok quit");
    assert!(child.wait().unwrap().success());
}

#[test]
fn a_relay_is_a_participant() {
    let uart = TcpListener::bind("127.0.0.1:0").unwrap();
    let server = start(&Options {
        nodes: 1,
        node: NodeKind::Fake,
        relays: vec![format!("tcp:{}", uart.local_addr().unwrap())],
        ..Options::default()
    })
    .unwrap();
    let (stream, _) = uart.accept().unwrap();
    let mut relay = Client::from_stream(stream);
    let mut master = Client::open(server.addr());
    master.wait_count(0x701, 1);
    // The relay's node boots: the master sees it.
    relay.raw(b"t7050\r");
    master.wait_count(0x705, 1);
    // The master's frames reach the relay (and the hosted node's answers).
    master.frame(0x605, &[0x40, 0x00, 0x10, 0x00]);
    master.frame(0x601, &[0x40]);
    master.frame(0x080, &[]);
    relay.wait_count(0x181, 1);
    assert_eq!(
        relay.frames(),
        vec![
            f(0x605, &[0x40, 0, 0x10, 0]),
            f(0x601, &[0x40]),
            f(0x581, &[0x40]),
            f(0x080, &[]),
            f(0x181, &[0, 0, 0, 0, 0, 0, 0, 0]),
        ]
    );
    // No command answers on a relay.
    relay.raw(b"V\r");
    relay.settle(50);
    assert!(!relay
        .rx
        .iter()
        .any(|r| *r != Rx::Ok && !matches!(r, Rx::Frame(_))));
    // A listen-only master may not send.
    let mut listener = Client::connect(server.addr());
    listener.raw(b"L\rt1230\r");
    listener.wait_until(|rx| rx.contains(&Rx::Bell));
    server.shutdown();
}
