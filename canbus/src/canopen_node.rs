//! The CANopen node ([`foc_canopen::node::Node`], CiA 301 + CiA 402) over
//! the host drive: the protocol of the drives the bus hosts by default.
//!
//! [`HostDrive`] is the node's [`CanDevice`]: its identity is the emulated
//! board's, its link-watchdog setting the one loaded at boot, and the
//! communication settings a 0x1010 "save" keeps live in the drive's flash
//! next to its configuration record (`HostDrive::save_comm`), so a power
//! cycle (`reset <id>` on the control channel) boots the node with them.

use crate::bus::BusState;
use crate::drive_node::DriveProtocol;
use crate::host_drive::HostDrive;
use foc_canopen::eds::EdsInfo;
use foc_canopen::node::{CanDevice, CommSettings, Identity, Node};
use foc_canopen::CanFrame;
use foc_protocol::device::WatchdogConfig;
use foc_protocol::message::ErrorCode;

/// The identity the hosted drives report (0x1018, 0x1008, 0x1009): the
/// EDS's vendor, product and revision numbers (the project has no CiA
/// vendor ID: 0, none assigned).
pub const IDENTITY: Identity = Identity {
    vendor_id: EdsInfo::FOC_DRIVE.vendor_number,
    product_code: EdsInfo::FOC_DRIVE.product_number,
    revision: EdsInfo::FOC_DRIVE.revision_number,
    serial: 0,
    device_name: "rust-foc drive (host test bus)",
    hardware_version: "emulated board + plant",
};

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

/// The service's rules (`foc_service::Link`'s `CanDevice`), as on a board.
impl CanDevice for HostDrive {
    fn identity(&self) -> Identity {
        self.view_parts().1.board().can_identity
    }
    fn link_setting(&self) -> WatchdogConfig {
        self.boot_link_setting().unwrap_or(WatchdogConfig::OFF)
    }
    fn save_comm(&mut self, s: &CommSettings) -> Result<(), ErrorCode> {
        self.with_link(|l| l.save_comm(s))?;
        self.comm_saved(*s);
        Ok(())
    }
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
