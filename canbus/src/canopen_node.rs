//! The CANopen node ([`foc_canopen::node::Node`], CiA 301 + CiA 402) over
//! the host drive: the protocol of the drives the bus hosts by default.
//!
//! [`HostDrive`] is the node's [`CanDevice`](foc_canopen::node::CanDevice): its identity is the emulated
//! board's, its link-watchdog setting the one loaded at boot, and the
//! communication settings a 0x1010 "save" keeps live in the drive's flash
//! next to its configuration record (`foc_simdrive::can`), so a power
//! cycle (`reset <id>` on the control channel) boots the node with them.

use crate::bus::BusState;
use crate::drive_node::DriveProtocol;
use crate::host_drive::HostDrive;
use foc_canopen::node::{CommSettings, Node};
use foc_canopen::CanFrame;

/// The identity the hosted drives report (0x1018, 0x1008, 0x1009).
pub use foc_simdrive::can::IDENTITY;

/// Heartbeat producer time of a node at first boot \[ms\].
pub const HEARTBEAT_MS: u16 = 100;

/// The node for drive `id` at boot: the communication settings the drive
/// saved, else node `id` at 1 Mbit/s with a 100 ms heartbeat and no
/// heartbeat consumer (the master configures 0x1016).
pub fn make(id: u8, drive: &HostDrive) -> Node {
    let settings = drive.saved_comm().unwrap_or_else(|| {
        CommSettings::new(id, 1000, HEARTBEAT_MS, None).unwrap_or(CommSettings::DEFAULT)
    });
    Node::new(settings)
}

impl DriveProtocol for Node {
    fn boot(&mut self, now_us: u64, drive: &mut HostDrive, out: &mut dyn FnMut(CanFrame)) {
        Node::boot(self, now_us, drive, out);
    }
    fn on_frame(
        &mut self,
        frame: &CanFrame,
        now_us: u64,
        drive: &mut HostDrive,
        out: &mut dyn FnMut(CanFrame),
    ) {
        Node::on_frame(self, frame, now_us, drive, out);
    }
    fn tick(&mut self, now_us: u64, drive: &mut HostDrive, out: &mut dyn FnMut(CanFrame)) {
        Node::tick(self, now_us, drive, out);
    }
    fn on_bus_state(
        &mut self,
        state: BusState,
        now_us: u64,
        drive: &mut HostDrive,
        out: &mut dyn FnMut(CanFrame),
    ) {
        Node::on_bus_state(self, state, now_us, drive, out);
    }
}
