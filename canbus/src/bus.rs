//! The virtual CAN bus: hosted nodes and external ports (SLCAN clients,
//! relays) in simulated time. No I/O: the server ([`crate::server`])
//! feeds it frames and writes out what it hands to the ports.
//!
//! # Delivery
//!
//! Every frame one participant sends is delivered to every other
//! participant, in order. One inbound frame is processed completely
//! before the next: it goes to every node (in the order they were added)
//! and every open port; the frames nodes answer with are queued behind it
//! and delivered the same way, until the queue is empty. The order is
//! therefore a function of the inbound frames alone.
//!
//! # Time
//!
//! Bus time is simulated, never the wall clock, so results do not depend
//! on the machine's speed. It starts at 0 and only a SYNC frame (COB-ID
//! `0x080`) moves it: once the SYNC and everything it caused has been
//! delivered (synchronous PDOs answer it at the SYNC's time), the bus
//! advances by the communication cycle period ([`Bus::cycle_us`], default
//! [`DEFAULT_CYCLE_US`]) in steps of at most 1 ms, each step: every node's
//! drive and plant run the step's PWM periods ([`BusNode::advance`]), bus
//! time moves to the step's end, bus-off timers expire, then every node's
//! [`BusNode::tick`] runs once (once per ms of bus time) and its frames are
//! delivered. Every other frame is handled at the current bus time.
//!
//! A master that wants time to pass sends SYNCs (and its heartbeat in
//! lockstep: a heartbeat consumer on the nodes judges it in bus time).
//!
//! # Boot and late clients
//!
//! [`Bus::boot`] boots every node at time 0. Frames that reach the ports
//! before any *client* port has opened its channel (SLCAN `O`) are kept
//! (at most [`BACKLOG`] frames) and handed to the first client that
//! opens, so a master that connects later still sees the boot-up
//! messages. After that a frame reaches the ports open at that moment.
//!
//! ```
//! use foc_canbus::bus::{Bus, Origin, PortKind};
//! use foc_canbus::fake::FakeNode;
//! use foc_canopen::CanFrame;
//! let mut bus = Bus::new(1000);
//! bus.add_node(Box::new(FakeNode::new(1)));
//! bus.boot();
//! bus.add_port(7, PortKind::Client);
//! bus.open_port(7);
//! // The boot-up message was kept for the first client.
//! assert_eq!(bus.take_outbox()[0].1, CanFrame::new(0x701, &[0]).unwrap());
//! bus.send(Origin::Port(7), CanFrame::new(0x080, &[]).unwrap());
//! assert_eq!(bus.now_us(), 1000);
//! ```

use foc_canopen::CanFrame;
use std::collections::VecDeque;

/// Default communication cycle period \[us\].
pub const DEFAULT_CYCLE_US: u32 = 1000;
/// COB-ID of the SYNC frame.
pub const SYNC_ID: u16 = 0x080;
/// Frames kept for the first client (boot-up messages and what follows).
pub const BACKLOG: usize = 4096;
/// Longest bus time one tick step covers \[us\].
pub const TICK_US: u64 = 1000;

/// A node's CAN controller state (the hardware layer's).
pub use foc_core::hal::BusState;

/// A node hosted on the bus: a CANopen node with its drive. Every method
/// gets the bus time \[us\] and an `out` to send frames with (delivered
/// after the call returns, in the order sent).
///
/// The real one is [`crate::drive_node::DriveNode`] (the drive with a
/// protocol on top); [`crate::fake::FakeNode`] is a stand-in for tests.
pub trait BusNode: Send {
    /// The node ID (1..=127).
    fn node_id(&self) -> u8;
    /// Power-on: initialise and send the boot-up message.
    fn boot(&mut self, now_us: u64, out: &mut dyn FnMut(CanFrame));
    /// A frame from another participant.
    fn on_frame(&mut self, frame: &CanFrame, now_us: u64, out: &mut dyn FnMut(CanFrame));
    /// Once per ms of bus time (after [`Self::advance`]).
    fn tick(&mut self, now_us: u64, out: &mut dyn FnMut(CanFrame));
    /// Run the drive and its plant from bus time `from_us` to `to_us`.
    fn advance(&mut self, from_us: u64, to_us: u64);
    /// The controller's state changed.
    fn on_bus_state(&mut self, state: BusState, now_us: u64, out: &mut dyn FnMut(CanFrame));
    /// Power-cycle the drive (persistent storage kept); [`Self::boot`]
    /// follows.
    fn power_cycle(&mut self);
    /// Inject a fault of `kind` into the drive's plant or sensors: a
    /// description, or why not.
    fn inject_fault(&mut self, kind: &str) -> Result<String, String>;
}

/// An external port's handle (chosen by the caller, unique).
pub type PortId = u32;

/// What an external port is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PortKind {
    /// An SLCAN client (a master): receives frames while its channel is
    /// open.
    Client,
    /// A relay (e.g. the emulated firmware's UART): always open, never
    /// takes the backlog.
    Relay,
}

/// Who sent a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Origin {
    /// The hosted node at this index ([`Bus::add_node`]'s order).
    Node(usize),
    /// An external port.
    Port(PortId),
}

/// One frame on the bus, as traced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TraceEntry {
    /// Bus time \[us\].
    pub time_us: u64,
    /// Sender.
    pub origin: Origin,
    /// The frame.
    pub frame: CanFrame,
}

struct Hosted {
    node: Box<dyn BusNode>,
    /// Bus-off until this bus time \[us\].
    bus_off_until: Option<u64>,
}

struct Port {
    id: PortId,
    kind: PortKind,
    open: bool,
}

/// The virtual bus (see the module docs).
pub struct Bus {
    nodes: Vec<Hosted>,
    ports: Vec<Port>,
    now_us: u64,
    cycle_us: u32,
    /// Frames for the first client (`None` once one opened).
    backlog: Option<Vec<CanFrame>>,
    queue: VecDeque<(Origin, CanFrame)>,
    outbox: Vec<(PortId, CanFrame)>,
    pending_syncs: u32,
    trace: Option<Vec<TraceEntry>>,
}

impl Bus {
    /// An empty bus at time 0 with this communication cycle period \[us\]
    /// (0 is taken as [`DEFAULT_CYCLE_US`]).
    pub fn new(cycle_us: u32) -> Self {
        Self {
            nodes: Vec::new(),
            ports: Vec::new(),
            now_us: 0,
            cycle_us: if cycle_us == 0 {
                DEFAULT_CYCLE_US
            } else {
                cycle_us
            },
            backlog: Some(Vec::new()),
            queue: VecDeque::new(),
            outbox: Vec::new(),
            pending_syncs: 0,
            trace: None,
        }
    }

    /// Record every frame on the bus ([`Self::trace`]).
    pub fn record_trace(&mut self) {
        self.trace.get_or_insert_with(Vec::new);
    }

    /// The frames recorded so far (empty unless [`Self::record_trace`]).
    pub fn trace(&self) -> &[TraceEntry] {
        self.trace.as_deref().unwrap_or(&[])
    }

    /// Bus time \[us\].
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// The communication cycle period a SYNC advances the bus by \[us\].
    pub fn cycle_us(&self) -> u32 {
        self.cycle_us
    }

    /// Host a node (not booted yet: [`Self::boot`]); its index.
    pub fn add_node(&mut self, node: Box<dyn BusNode>) -> usize {
        self.nodes.push(Hosted {
            node,
            bus_off_until: None,
        });
        self.nodes.len() - 1
    }

    /// Node IDs of the hosted nodes, in order.
    pub fn node_ids(&self) -> Vec<u8> {
        self.nodes.iter().map(|h| h.node.node_id()).collect()
    }

    /// The hosted node with this node ID.
    pub fn node_mut(&mut self, node_id: u8) -> Option<&mut dyn BusNode> {
        let i = self.index_of(node_id)?;
        Some(self.nodes.get_mut(i)?.node.as_mut())
    }

    fn index_of(&self, node_id: u8) -> Option<usize> {
        self.nodes.iter().position(|h| h.node.node_id() == node_id)
    }

    /// Boot every node at the current bus time and deliver their frames.
    pub fn boot(&mut self) {
        for i in 0..self.nodes.len() {
            self.boot_node(i);
        }
        self.process();
    }

    fn boot_node(&mut self, i: usize) {
        let now = self.now_us;
        let mut out = Vec::new();
        if let Some(h) = self.nodes.get_mut(i) {
            h.node.boot(now, &mut |f| out.push(f));
        }
        self.emit(i, out);
    }

    /// Queue what node `i` sent (dropped while it is bus-off).
    fn emit(&mut self, i: usize, frames: Vec<CanFrame>) {
        let off = self.nodes.get(i).is_none_or(|h| h.bus_off_until.is_some());
        if !off {
            self.queue
                .extend(frames.into_iter().map(|f| (Origin::Node(i), f)));
        }
    }

    /// Attach an external port (closed; a relay is open at once).
    pub fn add_port(&mut self, id: PortId, kind: PortKind) {
        self.ports.retain(|p| p.id != id);
        self.ports.push(Port {
            id,
            kind,
            open: kind == PortKind::Relay,
        });
    }

    /// Open a port's channel: from now on it receives the bus's frames
    /// (the first client to open also gets the backlog).
    pub fn open_port(&mut self, id: PortId) {
        let Some(p) = self.ports.iter_mut().find(|p| p.id == id) else {
            return;
        };
        p.open = true;
        if p.kind == PortKind::Client {
            if let Some(backlog) = self.backlog.take() {
                self.outbox.extend(backlog.into_iter().map(|f| (id, f)));
            }
        }
    }

    /// Close a port's channel (it stays attached).
    pub fn close_port(&mut self, id: PortId) {
        if let Some(p) = self.ports.iter_mut().find(|p| p.id == id) {
            p.open = p.kind == PortKind::Relay;
        }
    }

    /// True when the port is attached and open.
    pub fn port_open(&self, id: PortId) -> bool {
        self.ports.iter().any(|p| p.id == id && p.open)
    }

    /// Detach a port.
    pub fn remove_port(&mut self, id: PortId) {
        self.ports.retain(|p| p.id != id);
    }

    /// The frames for the ports since the last call, in order.
    pub fn take_outbox(&mut self) -> Vec<(PortId, CanFrame)> {
        std::mem::take(&mut self.outbox)
    }

    /// `frame` sent by `from`: delivered, with everything it causes (a
    /// SYNC advances the time), before this returns.
    pub fn send(&mut self, from: Origin, frame: CanFrame) {
        if let Origin::Node(i) = from {
            self.emit(i, vec![frame]);
        } else {
            self.queue.push_back((from, frame));
        }
        self.process();
    }

    /// Deliver the queue; run the cycles of the SYNCs seen.
    fn process(&mut self) {
        loop {
            self.drain();
            if self.pending_syncs == 0 {
                break;
            }
            self.pending_syncs -= 1;
            self.advance(u64::from(self.cycle_us));
        }
    }

    /// Deliver queued frames until none are left.
    fn drain(&mut self) {
        while let Some((from, frame)) = self.queue.pop_front() {
            let now = self.now_us;
            if let Some(t) = self.trace.as_mut() {
                t.push(TraceEntry {
                    time_us: now,
                    origin: from,
                    frame,
                });
            }
            if frame.id == SYNC_ID && !frame.rtr {
                self.pending_syncs = self.pending_syncs.saturating_add(1);
            }
            for i in 0..self.nodes.len() {
                if from == Origin::Node(i) {
                    continue;
                }
                let mut out = Vec::new();
                match self.nodes.get_mut(i) {
                    Some(h) if h.bus_off_until.is_none() => {
                        h.node.on_frame(&frame, now, &mut |f| out.push(f))
                    }
                    _ => continue,
                }
                self.emit(i, out);
            }
            let mut to_client = false;
            for p in &self.ports {
                if p.open && from != Origin::Port(p.id) {
                    self.outbox.push((p.id, frame));
                    to_client |= p.kind == PortKind::Client;
                }
            }
            if !to_client {
                if let Some(b) = self.backlog.as_mut() {
                    if b.len() < BACKLOG {
                        b.push(frame);
                    }
                }
            }
        }
    }

    /// Advance bus time by `dt_us` (see the module docs: steps of at most
    /// 1 ms, drives run, then ticks). [`Self::send`] of a SYNC does this;
    /// a test may call it directly.
    pub fn advance(&mut self, dt_us: u64) {
        let end = self.now_us.saturating_add(dt_us);
        while self.now_us < end {
            let from = self.now_us;
            let next_ms = (from / TICK_US + 1) * TICK_US;
            let to = next_ms.min(end);
            for h in &mut self.nodes {
                h.node.advance(from, to);
            }
            self.now_us = to;
            for i in 0..self.nodes.len() {
                let recover = self
                    .nodes
                    .get(i)
                    .and_then(|h| h.bus_off_until)
                    .is_some_and(|t| t <= to);
                if recover {
                    let mut out = Vec::new();
                    if let Some(h) = self.nodes.get_mut(i) {
                        h.bus_off_until = None;
                        h.node
                            .on_bus_state(BusState::ErrorActive, to, &mut |f| out.push(f));
                    }
                    self.emit(i, out);
                }
            }
            if to.is_multiple_of(TICK_US) {
                for i in 0..self.nodes.len() {
                    let mut out = Vec::new();
                    if let Some(h) = self.nodes.get_mut(i) {
                        h.node.tick(to, &mut |f| out.push(f));
                    }
                    self.emit(i, out);
                }
            }
            self.drain();
        }
    }

    /// Put node `node_id`'s controller off the bus for `ms` of bus time
    /// (it gets [`BusState::BusOff`] now and [`BusState::ErrorActive`]
    /// when it recovers).
    pub fn bus_off(&mut self, node_id: u8, ms: u64) -> Result<(), String> {
        let i = self
            .index_of(node_id)
            .ok_or_else(|| format!("no node {node_id}"))?;
        let now = self.now_us;
        let until = now.saturating_add(ms.saturating_mul(1000));
        if let Some(h) = self.nodes.get_mut(i) {
            h.bus_off_until = Some(until);
            // Whatever it sends now is lost: it is off the bus.
            h.node.on_bus_state(BusState::BusOff, now, &mut |_| {});
        }
        Ok(())
    }

    /// Power-cycle node `node_id` and boot it again now.
    pub fn reset(&mut self, node_id: u8) -> Result<(), String> {
        let i = self
            .index_of(node_id)
            .ok_or_else(|| format!("no node {node_id}"))?;
        if let Some(h) = self.nodes.get_mut(i) {
            h.node.power_cycle();
            h.bus_off_until = None;
        }
        self.boot_node(i);
        self.process();
        Ok(())
    }

    /// One control line (see [`crate::control`]): the answer line.
    pub fn control(&mut self, line: &str) -> String {
        match crate::control::run(self, line) {
            Ok(s) => format!("ok {s}").trim_end().to_string(),
            Err(e) => format!("err {e}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fake::FakeNode;

    fn f(id: u16, d: &[u8]) -> CanFrame {
        CanFrame::new(id, d).unwrap()
    }

    #[test]
    fn frames_reach_everyone_but_the_sender() {
        let mut bus = Bus::new(1000);
        bus.add_node(Box::new(FakeNode::new(1)));
        bus.add_node(Box::new(FakeNode::new(2)));
        bus.boot();
        bus.add_port(1, PortKind::Client);
        bus.add_port(2, PortKind::Client);
        bus.open_port(1);
        bus.open_port(2);
        let backlog = bus.take_outbox();
        assert_eq!(backlog.len(), 2);
        assert!(backlog.iter().all(|(p, _)| *p == 1));
        bus.send(Origin::Port(1), f(0x123, &[1]));
        assert_eq!(bus.take_outbox(), vec![(2, f(0x123, &[1]))]);
        // The fake node echoes SDO requests: the answer reaches both ports.
        bus.send(Origin::Port(1), f(0x601, &[0x40]));
        let out = bus.take_outbox();
        assert_eq!(out[0], (2, f(0x601, &[0x40])));
        assert!(out.contains(&(1, f(0x581, &[0x40]))));
        assert!(out.contains(&(2, f(0x581, &[0x40]))));
    }

    #[test]
    fn sync_advances_time_and_ticks() {
        let mut bus = Bus::new(2500);
        bus.add_node(Box::new(FakeNode::new(3)));
        bus.boot();
        bus.add_port(1, PortKind::Client);
        bus.open_port(1);
        bus.take_outbox();
        bus.send(Origin::Port(1), f(SYNC_ID, &[]));
        assert_eq!(bus.now_us(), 2500);
        bus.send(Origin::Port(1), f(SYNC_ID, &[]));
        assert_eq!(bus.now_us(), 5000);
        let out = bus.take_outbox();
        // The TPDO answers the second SYNC at 2500 us, 50 periods run.
        let tpdo: Vec<_> = out.iter().filter(|(_, fr)| fr.id == 0x183).collect();
        assert_eq!(tpdo.len(), 2);
        assert_eq!(&tpdo[1].1.data()[..4], &2500u32.to_le_bytes());
        assert_eq!(&tpdo[1].1.data()[4..], &50u32.to_le_bytes());
    }

    #[test]
    fn bus_off_drops_both_ways_then_recovers() {
        let mut bus = Bus::new(1000);
        bus.add_node(Box::new(FakeNode::new(1)));
        bus.boot();
        bus.add_port(1, PortKind::Client);
        bus.open_port(1);
        bus.take_outbox();
        bus.bus_off(1, 2).unwrap();
        bus.send(Origin::Port(1), f(0x601, &[1]));
        assert!(bus.take_outbox().is_empty());
        bus.send(Origin::Port(1), f(SYNC_ID, &[]));
        bus.send(Origin::Port(1), f(SYNC_ID, &[]));
        // Recovered at 2 ms: the fake node announces it (EMCY-like frame).
        let out = bus.take_outbox();
        assert!(out.iter().any(|(_, fr)| fr.id == 0x081), "{out:?}");
        bus.send(Origin::Port(1), f(0x601, &[1]));
        assert!(bus.take_outbox().contains(&(1, f(0x581, &[1]))));
    }
}
