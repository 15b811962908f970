//! The seam between the CiA 301 node and the drive profile: the few calls
//! the node makes into [`crate::cia402::Cia402`], as a trait, so that the
//! node's services can be tested with a fake profile and the profile with
//! a fake node.
//!
//! ```
//! use foc_canopen::profile::Profile;
//! fn statusword<P: Profile>(p: &P) -> u16 { p.actuals().statusword }
//! ```

use foc_protocol::device::DeviceContext;

use crate::cia402::{Actuals, Cia402, Params, State, Targets};
use crate::Abort;

/// What the node needs of a drive profile (see [`Cia402`] for the
/// meaning of each call).
pub trait Profile {
    /// Targets (0x607A, 0x60FF, 0x6071, 0x60B1, 0x60B2).
    fn targets(&self) -> &Targets;
    /// Targets, to write (already range-checked).
    fn targets_mut(&mut self) -> &mut Targets;
    /// Parameters.
    fn params(&self) -> &Params;
    /// Replace the parameters (after [`Self::check_params`] passed).
    fn set_params(&mut self, p: Params);
    /// Actual values.
    fn actuals(&self) -> &Actuals;
    /// The power state.
    fn state(&self) -> State;
    /// The last controlword written (0x6040).
    fn controlword(&self) -> u16;
    /// The requested mode (0x6060).
    fn requested_mode(&self) -> i8;
    /// Write 0x6040.
    fn write_controlword<C: DeviceContext>(&mut self, cw: u16, now_us: u64, ctx: &mut C);
    /// Write 0x6060.
    fn write_mode<C: DeviceContext>(
        &mut self,
        mode: i8,
        now_us: u64,
        ctx: &mut C,
    ) -> Result<(), Abort>;
    /// Check a whole parameter set.
    fn check_params(&self, p: &Params) -> Result<(), Abort>;
    /// Step the profile (SYNC and tick).
    fn update<C: DeviceContext>(&mut self, now_us: u64, ctx: &mut C);
    /// The connection to the master was lost.
    fn connection_lost<C: DeviceContext>(&mut self, now_us: u64, ctx: &mut C);
    /// The profile's own latched fault, as its EMCY code.
    fn profile_fault(&self) -> Option<u16>;
}

impl Profile for Cia402 {
    fn targets(&self) -> &Targets {
        &self.targets
    }
    fn targets_mut(&mut self) -> &mut Targets {
        &mut self.targets
    }
    fn params(&self) -> &Params {
        &self.params
    }
    fn set_params(&mut self, p: Params) {
        self.params = p;
    }
    fn actuals(&self) -> &Actuals {
        &self.actuals
    }
    fn state(&self) -> State {
        Cia402::state(self)
    }
    fn controlword(&self) -> u16 {
        Cia402::controlword(self)
    }
    fn requested_mode(&self) -> i8 {
        Cia402::requested_mode(self)
    }
    fn write_controlword<C: DeviceContext>(&mut self, cw: u16, now_us: u64, ctx: &mut C) {
        Cia402::write_controlword(self, cw, now_us, ctx)
    }
    fn write_mode<C: DeviceContext>(
        &mut self,
        mode: i8,
        now_us: u64,
        ctx: &mut C,
    ) -> Result<(), Abort> {
        Cia402::write_mode(self, mode, now_us, ctx)
    }
    fn check_params(&self, p: &Params) -> Result<(), Abort> {
        Cia402::check_params(self, p)
    }
    fn update<C: DeviceContext>(&mut self, now_us: u64, ctx: &mut C) {
        Cia402::update(self, now_us, ctx)
    }
    fn connection_lost<C: DeviceContext>(&mut self, now_us: u64, ctx: &mut C) {
        Cia402::connection_lost(self, now_us, ctx)
    }
    fn profile_fault(&self) -> Option<u16> {
        Cia402::profile_fault(self)
    }
}
