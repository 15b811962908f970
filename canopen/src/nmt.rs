//! NMT slave (CiA 301 §7.3.2): the node's communication state, the NMT
//! commands (COB-ID 0x000: `[command, node id or 0]`), the heartbeat
//! producer (0x700 + id, 0x1017) and the heartbeat consumer (0x1016 sub 1).
//!
//! ```
//! use foc_canopen::nmt::{NmtCommand, NmtState};
//! assert_eq!(NmtCommand::parse(&[0x01, 0], 5), Some(NmtCommand::Start));
//! assert_eq!(NmtCommand::parse(&[0x01, 6], 5), None);
//! assert_eq!(NmtState::PreOperational.heartbeat_byte(), 0x7F);
//! ```

/// The NMT state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NmtState {
    /// Before [`crate::node::Node::boot`] (and during a reset).
    Initialising,
    /// SDO, SYNC, EMCY, heartbeat; no PDO.
    PreOperational,
    /// Everything.
    Operational,
    /// NMT and heartbeat only.
    Stopped,
}

impl NmtState {
    /// The state byte of a heartbeat frame.
    pub const fn heartbeat_byte(self) -> u8 {
        match self {
            Self::Initialising => 0x00,
            Self::Stopped => 0x04,
            Self::Operational => 0x05,
            Self::PreOperational => 0x7F,
        }
    }
    /// SDO allowed.
    pub const fn sdo(self) -> bool {
        matches!(self, Self::PreOperational | Self::Operational)
    }
    /// PDO allowed.
    pub const fn pdo(self) -> bool {
        matches!(self, Self::Operational)
    }
}

/// An NMT command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NmtCommand {
    /// 0x01: start remote node (-> operational).
    Start,
    /// 0x02: stop remote node (-> stopped).
    Stop,
    /// 0x80: enter pre-operational.
    EnterPreOperational,
    /// 0x81: reset node (application and communication).
    ResetNode,
    /// 0x82: reset communication.
    ResetCommunication,
}

impl NmtCommand {
    /// The command in an NMT frame's data if it addresses `node_id` (or
    /// all nodes, 0); `None` otherwise or when malformed (DLC != 2).
    pub fn parse(data: &[u8], node_id: u8) -> Option<Self> {
        let &[cs, target] = data else {
            return None;
        };
        if target != 0 && target != node_id {
            return None;
        }
        match cs {
            0x01 => Some(Self::Start),
            0x02 => Some(Self::Stop),
            0x80 => Some(Self::EnterPreOperational),
            0x81 => Some(Self::ResetNode),
            0x82 => Some(Self::ResetCommunication),
            _ => None,
        }
    }

    /// The state after this command from `s` (resets go through
    /// initialisation, handled by the node).
    pub const fn next(self, s: NmtState) -> NmtState {
        match (self, s) {
            (_, NmtState::Initialising) => NmtState::Initialising,
            (Self::Start, _) => NmtState::Operational,
            (Self::Stop, _) => NmtState::Stopped,
            (Self::EnterPreOperational, _) => NmtState::PreOperational,
            (Self::ResetNode | Self::ResetCommunication, _) => NmtState::Initialising,
        }
    }
}

/// Heartbeat producer: a frame every `period_ms` (0: off).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeartbeatProducer {
    period_ms: u16,
    next_us: u64,
}

impl HeartbeatProducer {
    /// Off.
    pub const fn new() -> Self {
        Self {
            period_ms: 0,
            next_us: 0,
        }
    }

    /// Start (or restart when the period changed) at `now_us`: the first
    /// heartbeat one period later.
    pub fn configure(&mut self, period_ms: u16, now_us: u64) {
        if period_ms != self.period_ms {
            self.period_ms = period_ms;
            self.next_us = now_us.saturating_add(u64::from(period_ms) * 1000);
        }
    }

    /// Restart at `now_us` (after the boot-up frame).
    pub fn restart(&mut self, period_ms: u16, now_us: u64) {
        self.period_ms = period_ms;
        self.next_us = now_us.saturating_add(u64::from(period_ms) * 1000);
    }

    /// True when a heartbeat is due now (then scheduled one period on).
    pub fn poll(&mut self, now_us: u64) -> bool {
        if self.period_ms == 0 || now_us < self.next_us {
            return false;
        }
        let p = u64::from(self.period_ms) * 1000;
        self.next_us = self.next_us.saturating_add(p);
        if self.next_us <= now_us {
            // Late by more than a period: do not send a burst.
            self.next_us = now_us.saturating_add(p);
        }
        true
    }
}

impl Default for HeartbeatProducer {
    fn default() -> Self {
        Self::new()
    }
}

/// Heartbeat consumer of one producer (the master): 0x1016 sub 1 =
/// `node id << 16 | time ms`. It starts counting at the producer's first
/// heartbeat; a timeout is reported once, until the next heartbeat.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeartbeatConsumer {
    entry: u32,
    last_us: Option<u64>,
    expired: bool,
}

/// What a consumer event means.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConsumerEvent {
    /// The producer's heartbeat timed out.
    Lost,
    /// A heartbeat arrived after a timeout.
    Recovered,
}

impl HeartbeatConsumer {
    /// Monitoring nothing.
    pub const fn new() -> Self {
        Self {
            entry: 0,
            last_us: None,
            expired: false,
        }
    }

    /// The producer node id and time of an entry (`None`: off).
    pub const fn decode(entry: u32) -> Option<(u8, u16)> {
        let node = ((entry >> 16) & 0xFF) as u8;
        let ms = (entry & 0xFFFF) as u16;
        if node == 0 || node > 127 || ms == 0 {
            None
        } else {
            Some((node, ms))
        }
    }

    /// Follow 0x1016 sub 1: a changed entry restarts monitoring.
    pub fn configure(&mut self, entry: u32) {
        if entry != self.entry {
            *self = Self {
                entry,
                ..Self::new()
            };
        }
    }

    /// True while timed out.
    pub const fn expired(&self) -> bool {
        self.expired
    }

    /// A heartbeat frame from `node` at `now_us`.
    pub fn on_heartbeat(&mut self, node: u8, now_us: u64) -> Option<ConsumerEvent> {
        let (n, _) = Self::decode(self.entry)?;
        if n != node {
            return None;
        }
        self.last_us = Some(now_us);
        if self.expired {
            self.expired = false;
            return Some(ConsumerEvent::Recovered);
        }
        None
    }

    /// [`ConsumerEvent::Lost`] once when the time passed without a heartbeat.
    pub fn poll(&mut self, now_us: u64) -> Option<ConsumerEvent> {
        let (_, ms) = Self::decode(self.entry)?;
        let last = self.last_us?;
        if !self.expired && now_us.saturating_sub(last) > u64::from(ms) * 1000 {
            self.expired = true;
            return Some(ConsumerEvent::Lost);
        }
        None
    }
}

impl Default for HeartbeatConsumer {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn producer_does_not_burst_after_a_stall() {
        let mut p = HeartbeatProducer::new();
        p.restart(100, 0);
        assert!(!p.poll(99_999));
        assert!(p.poll(100_000));
        // Stalled for a second: one beat, then one period on.
        assert!(p.poll(1_100_000));
        assert!(!p.poll(1_150_000));
        assert!(p.poll(1_200_000));
    }

    #[test]
    fn consumer_ignores_other_nodes_and_restarts_on_a_new_entry() {
        let mut c = HeartbeatConsumer::new();
        c.configure((1 << 16) | 50);
        assert_eq!(c.poll(10_000_000), None, "not before the first heartbeat");
        assert_eq!(c.on_heartbeat(2, 0), None);
        assert_eq!(c.poll(10_000_000), None);
        assert_eq!(c.on_heartbeat(1, 0), None);
        assert_eq!(c.poll(50_000), None);
        assert_eq!(c.poll(50_001), Some(ConsumerEvent::Lost));
        assert!(c.expired());
        c.configure((1 << 16) | 60);
        assert!(!c.expired());
        assert_eq!(c.poll(1_000_000), None);
        assert_eq!(HeartbeatConsumer::decode(0x0080_0010), None, "node 128");
        assert_eq!(HeartbeatConsumer::decode(0x0001_0000), None, "time 0");
    }

    #[test]
    fn commands_and_transitions() {
        assert_eq!(
            NmtCommand::parse(&[0x81, 0], 3),
            Some(NmtCommand::ResetNode)
        );
        assert_eq!(
            NmtCommand::parse(&[0x82, 3], 3),
            Some(NmtCommand::ResetCommunication)
        );
        assert_eq!(NmtCommand::parse(&[0x02], 3), None);
        assert_eq!(
            NmtCommand::Stop.next(NmtState::Operational),
            NmtState::Stopped
        );
        assert_eq!(
            NmtCommand::Start.next(NmtState::Initialising),
            NmtState::Initialising
        );
        assert!(!NmtState::Stopped.sdo());
        assert!(!NmtState::PreOperational.pdo());
    }
}
