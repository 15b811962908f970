//! Board modules; exactly one is compiled, chosen by cargo feature, and
//! re-exported as `crate::board`.

use crate::hw::PinId;

#[cfg(any(feature = "nucleo-f446re-ihm07m1", feature = "nucleo-f401re-ihm07m1"))]
mod ihm07m1;

#[cfg(any(
    feature = "nucleo-f446re-ihm07m1",
    feature = "nucleo-f401re-ihm07m1",
    feature = "qemu"
))]
pub mod ihm07m1_analog;

#[cfg(feature = "nucleo-f446re-ihm07m1")]
pub mod nucleo_f446re_ihm07m1;

#[cfg(feature = "nucleo-f401re-ihm07m1")]
pub mod nucleo_f401re_ihm07m1;

#[cfg(feature = "odrive-v3")]
pub mod odrive_v3;

#[cfg(feature = "qemu")]
pub mod qemu;

#[cfg(feature = "qemu")]
pub mod qemu_store;

/// A status LED (no-op on boards without one).
pub struct Led {
    pin: Option<PinId>,
}

impl Led {
    /// LED on `pin` (already a push-pull output), or none.
    pub const fn new(pin: Option<PinId>) -> Self {
        Self { pin }
    }
    /// Switch on (`true`) or off.
    pub fn set(&mut self, on: bool) {
        if let Some(p) = self.pin {
            p.set(on);
        }
    }
    /// Toggle.
    pub fn toggle(&mut self) {
        if let Some(p) = self.pin {
            p.set(!p.is_set_high());
        }
    }
}
