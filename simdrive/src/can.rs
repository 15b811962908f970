//! The CANopen node's [`CanDevice`] on the drive (feature `canopen`): the
//! identity of the host test bus's drives, the link-watchdog setting loaded
//! at boot, and the communication settings a 0x1010 "save" keeps in the
//! drive's flash next to its configuration record, so a power cycle boots
//! the node with them.

use crate::HostDrive;
use foc_canopen::eds::EdsInfo;
use foc_canopen::node::{CanDevice, CommSettings, Identity};
use foc_protocol::device::WatchdogConfig;
use foc_protocol::message::ErrorCode;

/// The identity the simulated drives report (0x1018, 0x1008, 0x1009): the
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

impl HostDrive {
    /// The CAN node's saved communication settings, if any.
    pub fn saved_comm(&self) -> Option<CommSettings> {
        self.comm
    }

    /// The communication settings stored in the flash (at power-on).
    pub(crate) fn load_comm(&mut self) {
        self.comm = match self.store_mut().map(|s| s.load_can()) {
            Some(Ok(Some(r))) => CommSettings::from_record(&r).ok(),
            _ => None,
        };
    }
}

/// The service's rules (`foc_service::Link`'s `CanDevice`), as on a board.
impl CanDevice for HostDrive {
    fn identity(&self) -> Identity {
        self.view_parts().1.board().can_identity
    }
    fn link_setting(&self) -> WatchdogConfig {
        self.link_setting_in_force()
    }
    fn save_comm(&mut self, s: &CommSettings) -> Result<(), ErrorCode> {
        self.with_link(|l| l.save_comm(s))?;
        self.comm = Some(*s);
        Ok(())
    }
}
