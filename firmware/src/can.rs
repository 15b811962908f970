//! The CANopen node (CiA 301 + CiA 402, [`foc_canopen::node::Node`],
//! host-tested there) on the board's CAN port: glue only.
//!
//! Boards with a CAN port (`board::HAS_CAN`; firmware feature `can`, set by
//! `odrive-v3` and `qemu`): the ODrive's bxCAN (`board::Can` =
//! `CanBus`) and the emulated board's SLCAN UART (`board::Can` =
//! `SlcanPort`, USART3). Elsewhere [`CanNode`] is an empty type and
//! nothing here is compiled in.
//!
//! - `init`: [`CanNode::start`] reads the node settings from the store
//!   (`Store::load_can_or_default`; the defaults, node 1 at 1 Mbit/s with
//!   a 100 ms heartbeat, when there is no store or it fails, logged) and
//!   joins the bus at their bit rate. The node boots (boot-up message,
//!   pre-operational) at the first service, within a millisecond.
//! - Service ([`CanNode::receive`], [`CanNode::tick`]), in the `stream`
//!   task (priority 1, 1 kHz, and at once when a frame arrives: see
//!   [`on_can_interrupt`]): every received frame to `Node::on_frame`, then
//!   `Node::on_bus_state` when the port's state changed, then `Node::tick`.
//!   Each call's [`Link`](crate::comms::Link) (the node's `CanDevice`, a
//!   snapshot of the shared state) hands back an outbox, committed into
//!   the drive's mailboxes before the next frame, as the `serial` task
//!   does for the command channel.
//! - Time: the current loop's period counter (`Feedback::period`, PWM
//!   periods) extended to 64 bits, in microseconds. Under QEMU this is the
//!   emulated drive's time, not the host's nor the host test bus's.
//! - Transmit: every frame the node produces goes to `port.transmit`
//!   (the ODrive's port queues it and fills its mailboxes in order; the
//!   tick's `port.poll` drains the queue); a full queue drops the frame
//!   (counted in [`CanCounters::tx_dropped`], never a wait).
//! - NMT "reset node": the node reacts per 0x6007 (a running drive is
//!   faulted or disabled), puts the profile back to its power-on values
//!   (disable voltage, default parameters, zero targets) and resets its
//!   communication with the saved settings (node ID, heartbeat times);
//!   this glue then re-times the port to the saved bit rate when it
//!   differs (the boot-up message is queued before that: at the old
//!   rate). The processor is not reset.
//! - One master at a time: a command the node posts feeds the command
//!   channel's link watchdog ([`Comms::can_posted`]), and the profile
//!   re-posts its command every tick while enabled, so a serial command
//!   is overwritten within a millisecond.

use crate::comms::{Comms, Outbox, Snapshot};
use crate::persist::BoardStore;
use board_support::board;
use board_support::board::Bitrate;
use embedded_can::nb::Can as _;
use foc_canopen::node::{BusState, CommSettings, Node};
use foc_canopen::CanFrame;
use foc_core::hal::CanPort as _;

/// Frames the port's frame type (`bxcan::Frame`, `CanFrame`).
type PortFrame = <board::Can as embedded_can::nb::Can>::Frame;

/// Bound of one receive call: frames (and receive errors) taken before it
/// gives up until the next service.
const RX_BOUND: usize = 64;

/// Counters (wrapping; for the log and a debugger).
#[derive(Clone, Copy, Debug, Default, defmt::Format)]
pub struct CanCounters {
    /// Frames received and handed to the node.
    pub rx_frames: u32,
    /// Receive errors (a bxCAN FIFO overrun: frames lost).
    pub rx_errors: u32,
    /// Frames sent.
    pub tx_frames: u32,
    /// Frames the node produced that the port did not take (transmit
    /// buffer full, not started, bus-off) or handed back.
    pub tx_dropped: u32,
}

/// The current loop's period counter as 64-bit microseconds.
#[derive(Clone, Copy, Debug, Default)]
struct PeriodClock {
    last: u32,
    periods: u64,
}

impl PeriodClock {
    /// Microseconds at `period` (a wrapping counter; a period older than
    /// the last one seen, from an earlier snapshot, does not move time
    /// back).
    fn now_us(&mut self, period: u32) -> u64 {
        let d = period.wrapping_sub(self.last);
        if d < u32::MAX / 2 {
            self.last = period;
            self.periods = self.periods.wrapping_add(u64::from(d));
        }
        self.periods.saturating_mul(1_000_000) / u64::from(board::PWM_FREQUENCY_HZ)
    }
}

/// The node, its port and its clock (module docs).
pub struct CanNode {
    port: board::Can,
    node: Node,
    clock: PeriodClock,
    bus_state: BusState,
    booted: bool,
    counters: CanCounters,
}

/// Send `f` on `port` without waiting (dropped and counted when refused).
fn send(port: &mut board::Can, counters: &mut CanCounters, f: CanFrame) {
    let sent = f.to_frame::<PortFrame>().map(|fr| port.transmit(&fr));
    match sent {
        Some(Ok(None)) => counters.tx_frames = counters.tx_frames.wrapping_add(1),
        Some(Ok(Some(_))) => {
            counters.tx_frames = counters.tx_frames.wrapping_add(1);
            counters.tx_dropped = counters.tx_dropped.wrapping_add(1);
        }
        Some(Err(_)) | None => counters.tx_dropped = counters.tx_dropped.wrapping_add(1),
    }
}

/// The stored node settings, or the defaults (logged) when there are none
/// or they cannot be read.
fn stored_settings(store: Option<&mut BoardStore>) -> CommSettings {
    let Some(store) = store else {
        defmt::info!("can: no store: default node settings");
        return CommSettings::DEFAULT;
    };
    match store.load_can_or_default() {
        Ok(r) => CommSettings::from_record(&r).unwrap_or_else(|e| {
            defmt::error!("can: stored settings refused ({}): defaults", e);
            CommSettings::DEFAULT
        }),
        Err(e) => {
            defmt::error!("can: stored settings unreadable ({}): defaults", e);
            CommSettings::DEFAULT
        }
    }
}

impl CanNode {
    /// The node with the stored settings (module docs), its port started
    /// at their bit rate. In `init`, before the watchdog starts.
    pub fn start(mut port: board::Can, store: Option<&mut BoardStore>) -> Self {
        let settings = stored_settings(store);
        let rate = Bitrate::from_kbit(settings.bitrate_kbit()).unwrap_or(Bitrate::DEFAULT);
        if let Err(e) = port.start(rate) {
            defmt::error!("can: port not started: {}", e);
        }
        defmt::info!(
            "can: node {=u8}, {=u16} kbit/s",
            settings.node_id(),
            settings.bitrate_kbit()
        );
        Self {
            port,
            node: Node::new(settings),
            clock: PeriodClock::default(),
            bus_state: BusState::ErrorActive,
            booted: false,
            counters: CanCounters::default(),
        }
    }

    /// Service the port's interrupt source before [`Self::receive`] (the
    /// SLCAN UART moves its bytes here; bxCAN needs nothing).
    pub fn service_port(&mut self) {
        #[cfg(feature = "qemu")]
        self.port.on_interrupt();
    }

    /// Counters.
    pub fn counters(&self) -> CanCounters {
        self.counters
    }

    /// Boot the node once (boot-up message).
    fn boot_once(&mut self, now_us: u64, link: &mut crate::comms::Link<'_>) {
        if self.booted {
            return;
        }
        self.booted = true;
        let Self {
            port,
            node,
            counters,
            ..
        } = self;
        node.boot(now_us, link, &mut |f| send(port, counters, f));
    }

    /// After an NMT reset node: the port to the saved bit rate.
    fn after_reset_request(&mut self) {
        if !self.node.take_reset_request() {
            return;
        }
        let kbit = self.node.settings().bitrate_kbit();
        let rate = Bitrate::from_kbit(kbit).unwrap_or(Bitrate::DEFAULT);
        if rate != self.port.bitrate() {
            defmt::info!("can: reset node: {=u16} kbit/s", kbit);
            if let Err(e) = self.port.start(rate) {
                defmt::error!("can: port not restarted: {}", e);
            }
        }
    }

    /// The next received frame to the node, with `snap` (the shared state
    /// now) as its drive: the outbox to commit, or `None` when no frame
    /// is waiting (call again after committing).
    pub fn receive(&mut self, comms: &mut Comms, snap: Snapshot) -> Option<Outbox> {
        for _ in 0..RX_BOUND {
            let frame = match self.port.receive() {
                Ok(f) => f,
                Err(nb::Error::WouldBlock) => return None,
                Err(nb::Error::Other(_)) => {
                    self.counters.rx_errors = self.counters.rx_errors.wrapping_add(1);
                    continue;
                }
            };
            // An extended identifier (not CANopen's): ignored.
            let Some(frame) = CanFrame::from_frame(&frame) else {
                continue;
            };
            self.counters.rx_frames = self.counters.rx_frames.wrapping_add(1);
            let now_us = self.clock.now_us(snap.feedback.period);
            let mut link = comms.can_link(snap);
            self.boot_once(now_us, &mut link);
            let Self {
                port,
                node,
                counters,
                ..
            } = self;
            node.on_frame(&frame, now_us, &mut link, &mut |f| send(port, counters, f));
            let out = link.out;
            comms.can_posted(&out);
            self.after_reset_request();
            return Some(out);
        }
        None
    }

    /// The node's time step (at 1 kHz or more): boot-up the first time,
    /// the port's bus state when it changed, `Node::tick`. Returns the
    /// outbox to commit.
    pub fn tick(&mut self, comms: &mut Comms, snap: Snapshot) -> Outbox {
        let now_us = self.clock.now_us(snap.feedback.period);
        let mut link = comms.can_link(snap);
        self.boot_once(now_us, &mut link);
        self.port.poll();
        let state = self.port.bus_state();
        let changed = state != self.bus_state;
        self.bus_state = state;
        let Self {
            port,
            node,
            counters,
            ..
        } = self;
        let mut out = |f| send(port, counters, f);
        if changed {
            node.on_bus_state(state, now_us, &mut link, &mut out);
        }
        node.tick(now_us, &mut link, &mut out);
        let outbox = link.out;
        comms.can_posted(&outbox);
        self.after_reset_request();
        outbox
    }
}

/// The CAN port's interrupt (`board::CAN_RX_IRQ`: a frame in bxCAN's FIFO
/// 0, a byte on the SLCAN UART), outside RTIC: it masks its own line
/// (both sources stay pending until the frames are read) and pends the
/// `stream` task, which reads them and unmasks it ([`unmask_interrupt`]).
/// It shares no RTIC resource. (RTIC 2.4 sets up the NVIC line of a
/// hardware task even when the task is compiled out with `#[cfg]`, which
/// boards without these vectors, the F401, cannot build.)
pub fn on_can_interrupt() {
    cortex_m::peripheral::NVIC::mask(board::CAN_RX_IRQ);
    rtic::pend(board_support::pac::Interrupt::EXTI4);
}

/// Unmask [`on_can_interrupt`]'s line (after the frames were read).
pub fn unmask_interrupt() {
    // SAFETY: the line's handler shares no RTIC resource and RTIC's
    // locks do not use NVIC masks (BASEPRI on the Cortex-M4): unmasking it
    // cannot break a critical section.
    unsafe { cortex_m::peripheral::NVIC::unmask(board::CAN_RX_IRQ) };
}

/// Set the interrupt's priority to the lowest (RTIC priority 1's) and
/// unmask it. In `init`.
pub fn enable_interrupt(nvic: &mut cortex_m::peripheral::NVIC) {
    use board_support::pac::NVIC_PRIO_BITS;
    let lowest = ((1u8 << NVIC_PRIO_BITS) - 1) << (8 - NVIC_PRIO_BITS);
    // SAFETY: as `unmask_interrupt`; the priority of a line RTIC does not
    // manage changes no RTIC ceiling.
    unsafe { nvic.set_priority(board::CAN_RX_IRQ, lowest) };
    unmask_interrupt();
}

#[cfg(feature = "odrive-v3")]
use board_support::pac::interrupt;

#[cfg(feature = "odrive-v3")]
#[interrupt]
fn CAN1_RX0() {
    on_can_interrupt();
}

#[cfg(feature = "qemu")]
use board_support::pac::interrupt;

#[cfg(feature = "qemu")]
#[interrupt]
fn USART3() {
    on_can_interrupt();
}
