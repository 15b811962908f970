//! The CANopen node's [`CanDevice`] on the link: the board's identity, the
//! link watchdog in force, and the 0x1010 "save" of the communication
//! settings (only while quiet, as a configuration save).

use crate::link::Link;
use crate::records::{store_error, RecordStore};
use foc_canopen::node::{CanDevice, CommSettings, Identity};
use foc_protocol::message::ErrorCode;
use foc_protocol::WatchdogConfig;

impl<S: RecordStore> CanDevice for Link<'_, S> {
    fn identity(&self) -> Identity {
        self.view().service.board().can_identity
    }
    fn link_setting(&self) -> WatchdogConfig {
        Link::link_setting(self)
    }
    fn save_comm(&mut self, s: &CommSettings) -> Result<(), ErrorCode> {
        self.quiet()?;
        self.store_mut()?
            .save_can(&s.to_record())
            .map_err(store_error)?;
        crate::log_info!("store: CAN settings saved");
        Ok(())
    }
}
