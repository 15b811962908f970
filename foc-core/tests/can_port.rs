//! `hal::CanPort` through a fake port: a generic user sees frames, errors
//! and the bus state only through the trait.
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use embedded_can::{nb::Can, Error, ErrorKind, Frame, Id, StandardId};
use foc_core::hal::{BusState, CanPort};

#[derive(Clone, Debug, PartialEq)]
struct TestFrame {
    id: Id,
    remote: bool,
    len: usize,
    data: [u8; 8],
}

impl Frame for TestFrame {
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        let mut d = [0; 8];
        d.get_mut(..data.len())?.copy_from_slice(data);
        Some(Self {
            id: id.into(),
            remote: false,
            len: data.len(),
            data: d,
        })
    }
    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        (dlc <= 8).then(|| Self {
            id: id.into(),
            remote: true,
            len: dlc,
            data: [0; 8],
        })
    }
    fn is_extended(&self) -> bool {
        matches!(self.id, Id::Extended(_))
    }
    fn is_remote_frame(&self) -> bool {
        self.remote
    }
    fn id(&self) -> Id {
        self.id
    }
    fn dlc(&self) -> usize {
        self.len
    }
    fn data(&self) -> &[u8] {
        if self.remote {
            &[]
        } else {
            &self.data[..self.len]
        }
    }
}

/// Three transmit mailboxes, a receive queue, an overrun flag and a bus
/// state the test sets.
struct FakePort {
    tx: Vec<TestFrame>,
    rx: Vec<TestFrame>,
    overrun: bool,
    state: BusState,
}

impl Can for FakePort {
    type Frame = TestFrame;
    type Error = ErrorKind;

    fn transmit(&mut self, f: &TestFrame) -> nb::Result<Option<TestFrame>, ErrorKind> {
        if self.state.is_bus_off() || self.tx.len() >= 3 {
            return Err(nb::Error::WouldBlock);
        }
        self.tx.push(f.clone());
        Ok(None)
    }

    fn receive(&mut self) -> nb::Result<TestFrame, ErrorKind> {
        if std::mem::take(&mut self.overrun) {
            return Err(nb::Error::Other(ErrorKind::Overrun));
        }
        if self.rx.is_empty() {
            Err(nb::Error::WouldBlock)
        } else {
            Ok(self.rx.remove(0))
        }
    }
}

impl CanPort for FakePort {
    fn bus_state(&self) -> BusState {
        self.state
    }
}

/// What a node's I/O task does: drain the receive side (counting
/// overruns), then send its heartbeat unless off the bus.
fn service<P: CanPort>(port: &mut P, node: u8, state: u8) -> (usize, usize, bool) {
    let (mut received, mut overruns) = (0, 0);
    loop {
        match port.receive() {
            Ok(_) => received += 1,
            Err(nb::Error::Other(e)) if e.kind() == ErrorKind::Overrun => overruns += 1,
            Err(nb::Error::Other(_)) | Err(nb::Error::WouldBlock) => break,
        }
    }
    let sent = !port.bus_state().is_bus_off()
        && StandardId::new(0x700 + u16::from(node))
            .and_then(|id| P::Frame::new(id, &[state]))
            .is_some_and(|f| port.transmit(&f).is_ok());
    (received, overruns, sent)
}

fn frame(id: u16, data: &[u8]) -> TestFrame {
    TestFrame::new(StandardId::new(id).unwrap(), data).unwrap()
}

#[test]
fn generic_user_sends_and_receives_through_the_trait() {
    let mut port = FakePort {
        tx: vec![],
        rx: vec![
            frame(0x000, &[0x01, 0x05]),
            frame(0x605, &[0x40, 0, 0x10, 0]),
        ],
        overrun: true,
        state: BusState::ErrorActive,
    };
    assert_eq!(service(&mut port, 5, 0x05), (2, 1, true));
    assert_eq!(port.tx, vec![frame(0x705, &[0x05])]);
}

#[test]
fn bus_off_stops_sending_and_recovery_resumes_it() {
    let mut port = FakePort {
        tx: vec![],
        rx: vec![],
        overrun: false,
        state: BusState::BusOff,
    };
    assert_eq!(service(&mut port, 1, 0x7F), (0, 0, false));
    assert!(port.tx.is_empty());
    port.state = BusState::ErrorPassive;
    assert!(!port.bus_state().is_bus_off());
    assert_eq!(service(&mut port, 1, 0x7F), (0, 0, true));
    assert_eq!(port.tx, vec![frame(0x701, &[0x7F])]);
}

#[test]
fn full_mailboxes_would_block() {
    let mut port = FakePort {
        tx: vec![],
        rx: vec![],
        overrun: false,
        state: BusState::ErrorActive,
    };
    for _ in 0..3 {
        assert_eq!(port.transmit(&frame(0x181, &[1, 2])), Ok(None));
    }
    assert_eq!(
        port.transmit(&frame(0x181, &[1, 2])),
        Err(nb::Error::WouldBlock)
    );
}
