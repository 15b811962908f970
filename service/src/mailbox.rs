//! What a frame asks of the drive, gathered while it is handled and
//! handed over after: the command part ([`Outbox::post`], a fault clear),
//! the configuration part ([`ConfigMailbox`], one part per loop that
//! owns it) and the tables ([`Outbox::tables`]: too large for a
//! mailbox, installed by the owner outside the period).

use foc_core::control::position::PositionLoopConfig;
use foc_core::control::speed::SpeedLoopConfig;
use foc_core::control::{Command, CommandSlot};
use foc_core::drive::ConfigChange;

/// Pending configuration changes, one part per owning loop.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ConfigMailbox {
    /// Taken by the current loop: the drive applies or refuses it whole.
    pub current: Option<ConfigChange>,
    /// Taken by the speed loop.
    pub speed: Option<SpeedLoopConfig>,
    /// Taken by the position loop.
    pub position: Option<PositionLoopConfig>,
}

impl ConfigMailbox {
    /// Nothing pending.
    pub const EMPTY: Self = Self {
        current: None,
        speed: None,
        position: None,
    };

    /// Merge `o` into the pending changes (newer values win).
    pub fn merge(&mut self, o: &ConfigMailbox) {
        if let Some(c) = o.current {
            self.change(c);
        }
        self.speed = o.speed.or(self.speed);
        self.position = o.position.or(self.position);
    }

    /// Merge `c` into the current loop's part.
    pub fn change(&mut self, c: ConfigChange) {
        self.current.get_or_insert_with(Default::default).merge(c);
    }

    /// A calibration request is waiting for the current loop.
    pub fn calibration_pending(&self) -> bool {
        self.current.is_some_and(|c| {
            c.identify || c.calibrate_offsets || c.calibrate_cogging || c.calibrate_encoder
        })
    }

    /// Nothing pending.
    pub fn is_empty(&self) -> bool {
        self.current.is_none() && self.speed.is_none() && self.position.is_none()
    }
}

/// Mutations a frame (or a poll) asked for, committed after it was
/// handled.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Outbox {
    /// Command to post.
    pub post: Option<Command>,
    /// Request a fault clear.
    pub clear: bool,
    /// Configuration changes.
    pub config: ConfigMailbox,
    /// The tables in force changed (a record applied, a switch written):
    /// the owner installs the service's tables in the current stage
    /// ([`crate::Service::install_tables`]) outside the period, with the
    /// bridge off (on a board under the drive's lock from its low
    /// priority: a copy of 1.5 KB is more than a period's mailbox may
    /// cost the interrupt).
    pub tables: bool,
}

impl Outbox {
    /// Apply the command part to the mailbox (clear first, as the current
    /// stage does: a command sent with a clear is taken after it).
    ///
    /// A keep-alive only feeds the link watchdog (the protocol does
    /// that): it never re-posts the last command, which after a fault
    /// clear or a timeout reaction would restart the motor on an old
    /// setpoint.
    pub fn apply_command(&self, slot: &mut CommandSlot) {
        if self.clear {
            slot.request_clear();
        }
        if let Some(c) = self.post {
            slot.post(c);
        }
    }

    /// True when something must be written to the command mailbox.
    pub fn touches_command(&self) -> bool {
        self.clear || self.post.is_some()
    }

    /// True when configuration changes are pending.
    pub fn touches_config(&self) -> bool {
        !self.config.is_empty()
    }

    /// Merge a later outbox into this one (its command and changes win).
    pub fn merge(&mut self, later: &Outbox) {
        self.post = later.post.or(self.post);
        self.clear |= later.clear;
        self.config.merge(&later.config);
        self.tables |= later.tables;
    }
}
