//! [`DriveNode`]: a [`HostDrive`] with a CAN protocol on top, hosted on
//! the bus. The protocol is a [`DriveProtocol`]: the bus's calls with the
//! drive handed in as the device context.
//!
//! # Adapter slot: `foc_canopen::node::Node`
//!
//! The CANopen node (CiA 301 + CiA 402) plugs in here once it lands, as
//! `impl DriveProtocol for foc_canopen::node::Node` forwarding each call
//! (`boot(now_us, drive, out)`, `on_frame(frame, now_us, drive, out)`,
//! `tick(now_us, drive, out)`, `on_bus_state(state, now_us, drive, out)`
//! with [`BusState`] mapped onto the node's), [`HostDrive`] implementing
//! the node's `CanDevice` (`identity()`, `link_setting()`, `save_comm()`
//! on top of its [`foc_protocol::device::DeviceContext`]), and
//! `DriveNode::new(id, |id| Node::new(CommSettings { node_id: id,
//! bitrate_kbit: 1000, heartbeat_ms, consumer }))`; then `--node canopen`
//! in the binary. Until then [`MiniProtocol`] stands in.

use crate::bus::{BusNode, BusState};
use crate::fake::periods_between;
use foc_canopen::CanFrame;
use foc_core::control::Command;
use foc_protocol::device::DeviceContext;
use foc_simdrive::{FaultKind, HostDrive};

/// A CAN protocol over the drive: the bus's calls, with the drive as the
/// device context (see [`crate::bus::BusNode`] for when each is called).
pub trait DriveProtocol: Send {
    /// Power-on (send the boot-up message).
    fn boot(&mut self, now_us: u64, drive: &mut HostDrive, out: &mut dyn FnMut(CanFrame));
    /// A frame from another participant.
    fn on_frame(
        &mut self,
        frame: &CanFrame,
        now_us: u64,
        drive: &mut HostDrive,
        out: &mut dyn FnMut(CanFrame),
    );
    /// Once per ms of bus time.
    fn tick(&mut self, now_us: u64, drive: &mut HostDrive, out: &mut dyn FnMut(CanFrame));
    /// The controller's state changed.
    fn on_bus_state(
        &mut self,
        state: BusState,
        now_us: u64,
        drive: &mut HostDrive,
        out: &mut dyn FnMut(CanFrame),
    );
}

/// The drive and its protocol on the bus.
pub struct DriveNode<P> {
    id: u8,
    /// The drive.
    pub drive: HostDrive,
    /// The protocol.
    pub protocol: P,
    make: fn(u8, &HostDrive) -> P,
}

impl<P: DriveProtocol> DriveNode<P> {
    /// Node `id`: a drive on a blank flash and `make(id)`'s protocol
    /// (`make` builds it again at every power cycle).
    pub fn new(id: u8, make: fn(u8, &HostDrive) -> P) -> Self {
        let drive = HostDrive::new();
        let protocol = make(id, &drive);
        Self {
            id,
            drive,
            protocol,
            make,
        }
    }
}

impl<P: DriveProtocol> BusNode for DriveNode<P> {
    fn node_id(&self) -> u8 {
        self.id
    }
    fn boot(&mut self, now_us: u64, out: &mut dyn FnMut(CanFrame)) {
        self.protocol.boot(now_us, &mut self.drive, out);
    }
    fn on_frame(&mut self, frame: &CanFrame, now_us: u64, out: &mut dyn FnMut(CanFrame)) {
        self.protocol.on_frame(frame, now_us, &mut self.drive, out);
    }
    fn tick(&mut self, now_us: u64, out: &mut dyn FnMut(CanFrame)) {
        self.protocol.tick(now_us, &mut self.drive, out);
    }
    fn advance(&mut self, from_us: u64, to_us: u64) {
        let n = periods_between(from_us, to_us, u64::from(self.drive.pwm_hz()));
        self.drive
            .step_periods(u32::try_from(n).unwrap_or(u32::MAX));
    }
    fn on_bus_state(&mut self, state: BusState, now_us: u64, out: &mut dyn FnMut(CanFrame)) {
        self.protocol
            .on_bus_state(state, now_us, &mut self.drive, out);
    }
    fn power_cycle(&mut self) {
        self.drive.power_cycle();
        self.protocol = (self.make)(self.id, &self.drive);
    }
    fn inject_fault(&mut self, kind: &str) -> Result<String, String> {
        let k = FaultKind::parse(kind).ok_or_else(|| {
            format!("unknown fault {kind:?} (encoder, short, open-phase, nan-current, clear)")
        })?;
        self.drive.inject(k);
        Ok(format!("fault {} {kind}", self.id))
    }
}

/// A minimal stand-in protocol over the real drive (until the CANopen
/// node lands), CANopen-shaped COB-IDs, little-endian:
///
/// | frame | meaning |
/// |---|---|
/// | boot | boot-up `0x700+id [0x00]` |
/// | every 100 ms | heartbeat `0x700+id [0x05]` |
/// | `0x200+id [f32]` | velocity command [rad/s]; `0x200+id []`: disable |
/// | `0x300+id []` | clear faults |
/// | SYNC `0x080` | `0x180+id [velocity f32, mode u8, fault code u8]` (the drive's estimate) |
/// | a new fault latched | EMCY `0x080+id [0x00, 0x10, 0x01, fault code]` |
#[derive(Clone, Debug)]
pub struct MiniProtocol {
    id: u8,
    faulted: bool,
}

impl MiniProtocol {
    /// For node `id`.
    pub fn new(id: u8) -> Self {
        Self { id, faulted: false }
    }
    /// For node `id` (the signature [`DriveNode::new`] takes).
    pub fn for_drive(id: u8, _drive: &HostDrive) -> Self {
        Self::new(id)
    }
    fn frame(&self, base: u16, data: &[u8]) -> Option<CanFrame> {
        CanFrame::new(base + u16::from(self.id), data)
    }
}

impl DriveProtocol for MiniProtocol {
    fn boot(&mut self, _now_us: u64, _drive: &mut HostDrive, out: &mut dyn FnMut(CanFrame)) {
        if let Some(f) = self.frame(0x700, &[0]) {
            out(f);
        }
    }
    fn on_frame(
        &mut self,
        f: &CanFrame,
        _now_us: u64,
        drive: &mut HostDrive,
        out: &mut dyn FnMut(CanFrame),
    ) {
        let id = u16::from(self.id);
        match f.id {
            0x080 => {
                let t = drive.telemetry();
                let mut d = [0u8; 6];
                d[..4].copy_from_slice(&t.velocity_rad_s.to_le_bytes());
                d[4] = t.mode as u8;
                d[5] = t.fault_code;
                if let Some(r) = self.frame(0x180, &d) {
                    out(r);
                }
            }
            x if x == 0x200 + id => match f.data() {
                [] => {
                    let _ = drive.post(Command::Disable);
                }
                [a, b, c, d] => {
                    let rad_s = f32::from_le_bytes([*a, *b, *c, *d]);
                    if rad_s.is_finite() {
                        let _ = drive.post(Command::Velocity { rad_s });
                    }
                }
                _ => {}
            },
            x if x == 0x300 + id => drive.clear_faults(),
            _ => {}
        }
    }
    fn tick(&mut self, now_us: u64, drive: &mut HostDrive, out: &mut dyn FnMut(CanFrame)) {
        let (faults, first) = drive.faults();
        let faulted = !faults.is_empty();
        if faulted && !self.faulted {
            let code = first.map_or(0, |f| f.code());
            if let Some(f) = self.frame(0x080, &[0x00, 0x10, 0x01, code]) {
                out(f);
            }
        }
        self.faulted = faulted;
        if now_us.is_multiple_of(100_000) {
            if let Some(f) = self.frame(0x700, &[0x05]) {
                out(f);
            }
        }
    }
    fn on_bus_state(
        &mut self,
        _state: BusState,
        _now_us: u64,
        _drive: &mut HostDrive,
        _out: &mut dyn FnMut(CanFrame),
    ) {
    }
}
