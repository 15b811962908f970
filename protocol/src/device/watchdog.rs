//! The link watchdog: a command or keep-alive within the timeout, or
//! the configured reaction.

use super::*;

/// Link watchdog: counts current-loop periods since the last valid command
/// or keep-alive and, when the count passes the timeout while the drive is
/// enabled, reacts as configured (the reactions of
/// [`foc_core::control::stage::TimeoutReaction`]):
///
/// - `Disable`: latch [`Fault::CommandTimeout`] (bridge off until cleared);
/// - `Stop`: post velocity 0;
/// - `Hold`: post a position command at the measured position.
///
/// A `Stop` or `Hold` leaves the bridge on: when the link stays silent for
/// a second timeout after it, the watchdog escalates to `Disable`.
///
/// In impedance mode the reaction is always the one design §21 asks for,
/// whatever is configured: damping only ([`LinkReaction::Damp`]: `kp = 0`,
/// no feed-forward, the command's damping), then `Disable` after a second
/// timeout ([`Self::react`]).
///
/// This watches the *link* from the communication task; the current stage's
/// `command_timeout_periods` stays as the backstop for a dead communication
/// task. Keep-alives refresh both (see [`DeviceContext::keep_alive`]).
///
/// ```
/// use foc_protocol::device::{CommandWatchdog, WatchdogConfig};
/// use foc_core::control::stage::TimeoutReaction;
/// let mut wd = CommandWatchdog::new(WatchdogConfig { timeout_periods: 100, reaction: TimeoutReaction::Stop });
/// assert_eq!(wd.tick(60, true), None);
/// wd.feed();
/// assert_eq!(wd.tick(60, true), None);
/// assert_eq!(wd.tick(60, true), Some(TimeoutReaction::Stop)); // 120 > 100
/// assert_eq!(wd.tick(60, true), None); // 180: reacted once
/// assert_eq!(wd.tick(60, true), Some(TimeoutReaction::Disable)); // 240 > 200
/// assert_eq!(wd.tick(60, true), None); // then nothing until fed again
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CommandWatchdog {
    config: WatchdogConfig,
    age_periods: u32,
    /// Reactions given since the last feed (0, 1, or 2 after escalating).
    reactions: u8,
    /// The first reaction left the bridge on: a second timeout disables.
    escalates: bool,
}

/// What the link watchdog asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkReaction {
    /// Latch [`Fault::CommandTimeout`] (bridge off).
    Disable,
    /// Velocity 0.
    Stop,
    /// Hold the measured position.
    Hold,
    /// Impedance mode: damping only (`kp = 0`, `v_ref = 0`, no
    /// feed-forward, the active damping), bridge on.
    Damp,
}

impl From<TimeoutReaction> for LinkReaction {
    fn from(r: TimeoutReaction) -> Self {
        match r {
            TimeoutReaction::Disable => Self::Disable,
            TimeoutReaction::Stop => Self::Stop,
            TimeoutReaction::Hold => Self::Hold,
        }
    }
}

impl CommandWatchdog {
    /// New watchdog, fed.
    pub const fn new(config: WatchdogConfig) -> Self {
        Self {
            config,
            age_periods: 0,
            reactions: 0,
            escalates: false,
        }
    }
    /// The configuration.
    pub const fn config(&self) -> WatchdogConfig {
        self.config
    }
    /// Replace the configuration (and feed).
    pub fn configure(&mut self, config: WatchdogConfig) {
        self.config = config;
        self.feed();
    }
    /// A valid command or keep-alive arrived.
    pub fn feed(&mut self) {
        self.age_periods = 0;
        self.reactions = 0;
    }
    /// Periods since the last feed (saturating).
    pub const fn age_periods(&self) -> u32 {
        self.age_periods
    }
    /// True after it fired, until fed.
    pub const fn expired(&self) -> bool {
        self.reactions > 0
    }
    /// Advance by `periods`; `enabled` is false while the drive is disabled
    /// (then the age is held at 0). Returns the reaction once when the
    /// timeout passes, and `Disable` once when a `Stop` or `Hold` was
    /// followed by a second timeout of silence.
    pub fn tick(&mut self, periods: u32, enabled: bool) -> Option<TimeoutReaction> {
        self.react(periods, enabled, false).map(|r| match r {
            LinkReaction::Stop => TimeoutReaction::Stop,
            LinkReaction::Hold => TimeoutReaction::Hold,
            LinkReaction::Disable | LinkReaction::Damp => TimeoutReaction::Disable,
        })
    }

    /// As [`Self::tick`], for a drive in impedance mode or not: in
    /// impedance mode the first reaction is [`LinkReaction::Damp`] (then
    /// `Disable` after a second timeout), whatever is configured.
    ///
    /// ```
    /// use foc_protocol::device::{CommandWatchdog, LinkReaction, WatchdogConfig};
    /// use foc_core::control::stage::TimeoutReaction;
    /// let mut wd = CommandWatchdog::new(WatchdogConfig { timeout_periods: 100, reaction: TimeoutReaction::Disable });
    /// assert_eq!(wd.react(120, true, true), Some(LinkReaction::Damp));
    /// assert_eq!(wd.react(70, true, true), None); // 190
    /// assert_eq!(wd.react(20, true, true), Some(LinkReaction::Disable)); // 210 > 200
    /// ```
    pub fn react(&mut self, periods: u32, enabled: bool, impedance: bool) -> Option<LinkReaction> {
        let t = self.config.timeout_periods;
        if t == 0 || !enabled {
            self.age_periods = 0;
            return None;
        }
        self.age_periods = self.age_periods.saturating_add(periods);
        match self.reactions {
            0 if self.age_periods > t => {
                self.reactions = 1;
                let r = if impedance {
                    LinkReaction::Damp
                } else {
                    LinkReaction::from(self.config.reaction)
                };
                self.escalates = r != LinkReaction::Disable;
                Some(r)
            }
            1 if self.escalates && self.age_periods > t.saturating_mul(2) => {
                self.reactions = 2;
                Some(LinkReaction::Disable)
            }
            _ => None,
        }
    }
}
