//! # foc-canbus: a CAN test bus on the host (issue 22)
//!
//! Several drives, each the real drive code ([`host_drive::HostDrive`]:
//! foc-core's cascade against its own simulated plant) with its own node
//! ID, and any number of SLCAN-over-TCP clients (a third-party CANopen
//! master such as Python's `canopen` over python-can's `slcan`
//! interface) and relays (the emulated firmware's UART) share one virtual
//! CAN bus.
//!
//! - [`bus`]: the bus: delivery order, simulated time (a SYNC advances it
//!   by the communication cycle period), boot and the backlog for a late
//!   master, bus-off; the [`bus::BusNode`] trait a hosted node implements.
//! - [`host_drive`]: the real drive as a [`foc_protocol::device::DeviceContext`],
//!   with fault injection and a persistent store on a RAM flash.
//! - [`drive_node`]: a drive with a protocol on the bus; the adapter slot
//!   of the CANopen node (`foc_canopen::node::Node`) and
//!   [`drive_node::MiniProtocol`], a stand-in until it lands.
//! - [`fake`]: [`fake::FakeNode`], a stand-in node for the bus's tests.
//! - [`server`]: TCP, SLCAN framing ([`foc_canopen::slcan`]), relays.
//! - [`control`]: the control channel's lines (`fault`, `bus-off`,
//!   `reset`, `quit`).
//!
//! The binary `foc-canbus` is [`start`] with its options from the command
//! line and the control channel on stdin/stdout:
//!
//! ```text
//! foc-canbus --nodes 3 [--first-id 1] [--port 0] [--node drive|fake]
//!            [--cycle-us 1000] [--relay tcp:HOST:PORT ...]
//! ```
//!
//! ```no_run
//! use foc_canbus::{start, NodeKind, Options};
//! let server = start(&Options { nodes: 2, node: NodeKind::Fake, ..Options::default() })?;
//! println!("listening {}", server.addr());
//! assert_eq!(server.control("reset 1"), "ok reset 1");
//! # Ok::<(), std::io::Error>(())
//! ```
//!
//! # Where to start reading
//!
//! [`bus::Bus`] (the frames every node sees), then [`host_drive::HostDrive`]
//! (one simulated drive on it, with the firmware's link rules).
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod bus;
pub mod canopen_node;
pub mod control;
pub mod drive_node;
pub mod fake;
/// The real drive on the host (moved to its own crate, `foc-simdrive`,
/// which `foc-ctl simulate` serves too).
pub use foc_simdrive::drive as host_drive;
pub mod server;

use bus::Bus;
use std::net::TcpListener;

/// Which node the bus hosts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum NodeKind {
    /// The real drive under the CANopen node (CiA 301 + CiA 402).
    #[default]
    Canopen,
    /// The real drive under [`drive_node::MiniProtocol`] (a minimal
    /// stand-in protocol, for the bus's own tests).
    Drive,
    /// [`fake::FakeNode`] (no drive).
    Fake,
}

/// What to start.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Options {
    /// Number of hosted nodes.
    pub nodes: u8,
    /// Node ID of the first; the others follow.
    pub first_id: u8,
    /// The node hosted.
    pub node: NodeKind,
    /// Communication cycle period a SYNC advances the bus by \[us\].
    pub cycle_us: u32,
    /// TCP port on 127.0.0.1 (0: any free one).
    pub port: u16,
    /// Relays to connect out to (`HOST:PORT`, an optional `tcp:` prefix
    /// is dropped).
    pub relays: Vec<String>,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            nodes: 3,
            first_id: 1,
            node: NodeKind::Canopen,
            cycle_us: bus::DEFAULT_CYCLE_US,
            port: 0,
            relays: Vec::new(),
        }
    }
}

impl Options {
    /// The node IDs: `first_id..first_id + nodes`, `None` if any is
    /// outside 1..=127.
    pub fn node_ids(&self) -> Option<Vec<u8>> {
        (0..self.nodes)
            .map(|k| {
                self.first_id
                    .checked_add(k)
                    .filter(|id| (1..=127).contains(id))
            })
            .collect()
    }
}

/// The bus of `o` (nodes added, not booted).
pub fn build_bus(o: &Options) -> std::io::Result<Bus> {
    let ids = o.node_ids().ok_or_else(|| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "node IDs must lie in 1..=127",
        )
    })?;
    let mut bus = Bus::new(o.cycle_us);
    for id in ids {
        match o.node {
            NodeKind::Fake => bus.add_node(Box::new(fake::FakeNode::new(id))),
            NodeKind::Canopen => {
                bus.add_node(Box::new(drive_node::DriveNode::new(id, canopen_node::make)))
            }
            NodeKind::Drive => bus.add_node(Box::new(drive_node::DriveNode::new(
                id,
                drive_node::MiniProtocol::for_drive,
            ))),
        };
    }
    Ok(bus)
}

/// Build the bus of `o`, listen on `127.0.0.1:o.port`, boot the nodes and
/// serve (the binary's entry, without its stdin/stdout).
pub fn start(o: &Options) -> std::io::Result<server::Server> {
    let bus = build_bus(o)?;
    let listener = TcpListener::bind(("127.0.0.1", o.port))?;
    let relays: Vec<String> = o
        .relays
        .iter()
        .map(|r| r.strip_prefix("tcp:").unwrap_or(r).to_string())
        .collect();
    server::Server::spawn(bus, listener, &relays)
}
