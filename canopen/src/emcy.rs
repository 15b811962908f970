//! EMCY producer (COB-ID 0x80 + node id), error register (0x1001) and
//! pre-defined error field (0x1003, newest first, up to 8 entries).
//!
//! An EMCY frame is 8 bytes: error code (u16 LE), error register (u8) and
//! five manufacturer bytes, of which byte 3 carries the drive's
//! [`Fault::code`] (0 when the error is not a drive fault).
//!
//! The drive's faults map onto the CiA 402 / CiA 301 error codes:
//!
//! | fault | code | meaning |
//! |---|---|---|
//! | OverCurrentPhase | 0x2320 | short circuit / peak over-current, output side |
//! | OverCurrentVector | 0x2310 | continuous over-current |
//! | CurrentSumMismatch | 0x2330 | earth leakage (phase currents do not sum to 0) |
//! | BusOverVoltage | 0x3210 | DC link over-voltage |
//! | BusUnderVoltage | 0x3220 | DC link under-voltage |
//! | OverTemperature | 0x4210 | excess temperature, device |
//! | PwmError | 0x5200 | device hardware, control |
//! | CurrentSenseError | 0x5210 | measurement circuit |
//! | BusSenseError | 0x5210 | measurement circuit (shared: byte 3 tells) |
//! | GateDriverFault | 0x5410 | power section, output stages |
//! | Watchdog | 0x6010 | software reset (watchdog) |
//! | LoopOverrun | 0x6010 | the control loop's timing watchdog (shared) |
//! | NonFinite | 0x6100 | internal software |
//! | CalibrationFailed | 0x6320 | parameter error |
//! | AngleSensorError | 0x7305 | incremental sensor 1 fault |
//! | AngleSensorImplausible | 0x7305 | same sensor (shared: byte 3 tells) |
//! | AngleSensorStuck | 0x7320 | position sensor (frozen reading or stall) |
//! | CommandTimeout | 0x8100 | communication (the link's command watchdog) |
//! | OverSpeed | 0x8400 | velocity / speed controller |
//! | SpeedRunaway | 0x8400 | speed controller (shared: byte 3 tells) |
//! | TravelLimit | 0x8612 | positioning controller, reference limit |
//! | ObserverLostLock | 0x7300 | sensor (the sensorless observer) |
//!
//! The node's own errors: following error 0x8611 (from the profile),
//! heartbeat consumer timeout 0x8130, bus-off recovered 0x8140, PDO
//! length error 0x8210 (too short) / 0x8220 (too long); 0x0000 is "error
//! reset / no error", sent once when every error is gone.
//!
//! ```
//! use foc_canopen::emcy::fault_code;
//! use foc_core::control::Fault;
//! assert_eq!(fault_code(Fault::BusOverVoltage), 0x3210);
//! ```

use foc_core::control::{Fault, FaultSet};

use crate::CanFrame;

/// Error reset / no error.
pub const NO_ERROR: u16 = 0x0000;
/// Heartbeat (life guard) error: the master's heartbeat timed out.
pub const HEARTBEAT: u16 = 0x8130;
/// Recovered from bus-off.
pub const BUS_OFF_RECOVERED: u16 = 0x8140;
/// PDO not processed: shorter than its mapping.
pub const PDO_LENGTH: u16 = 0x8210;
/// PDO longer than its mapping.
pub const PDO_LENGTH_EXCEEDED: u16 = 0x8220;
/// Following error (the profile's own fault).
pub const FOLLOWING_ERROR: u16 = 0x8611;

/// The EMCY error code of a drive fault (table in the module docs).
pub const fn fault_code(f: Fault) -> u16 {
    match f {
        Fault::OverCurrentPhase => 0x2320,
        Fault::OverCurrentVector => 0x2310,
        Fault::CurrentSumMismatch => 0x2330,
        Fault::BusOverVoltage => 0x3210,
        Fault::BusUnderVoltage => 0x3220,
        Fault::OverTemperature => 0x4210,
        Fault::PwmError => 0x5200,
        Fault::CurrentSenseError | Fault::BusSenseError => 0x5210,
        Fault::GateDriverFault => 0x5410,
        Fault::Watchdog | Fault::LoopOverrun => 0x6010,
        Fault::NonFinite => 0x6100,
        Fault::CalibrationFailed => 0x6320,
        Fault::AngleSensorError | Fault::AngleSensorImplausible => 0x7305,
        Fault::AngleSensorStuck => 0x7320,
        Fault::CommandTimeout => 0x8100,
        Fault::OverSpeed | Fault::SpeedRunaway => 0x8400,
        Fault::TravelLimit => 0x8612,
        Fault::ObserverLostLock => 0x7300,
    }
}

/// The error register bits (0x1001) an error code sets: bit 0 generic
/// (any error), 1 current, 2 voltage, 3 temperature, 4 communication,
/// 5 device profile, 7 manufacturer.
pub const fn register_bits(code: u16) -> u8 {
    if code == NO_ERROR {
        return 0;
    }
    let class = match code >> 12 {
        0x2 => 1 << 1,
        0x3 => 1 << 2,
        0x4 => 1 << 3,
        0x8 if code >> 8 == 0x86 => 1 << 5,
        0x8 => 1 << 4,
        0xF => 1 << 7,
        _ => 0,
    };
    1 | class
}

/// Entries of the pre-defined error field.
pub const HISTORY: usize = 8;

/// EMCY state: what was reported, the error register and the history.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Emcy {
    /// Drive faults already reported.
    reported: FaultSet,
    /// The profile fault already reported.
    profile: Option<u16>,
    /// Communication errors active (heartbeat lost, PDO length): their
    /// register bits.
    comm_bits: u8,
    /// Error register (0x1001).
    register: u8,
    /// 0x1003, newest first.
    history: [u32; HISTORY],
    /// Entries in `history`.
    count: u8,
    /// Something was reported since the last "no error".
    active: bool,
}

impl Default for Emcy {
    fn default() -> Self {
        Self::new()
    }
}

impl Emcy {
    /// No error.
    pub const fn new() -> Self {
        Self {
            reported: FaultSet::EMPTY,
            profile: None,
            comm_bits: 0,
            register: 0,
            history: [0; HISTORY],
            count: 0,
            active: false,
        }
    }

    /// Error register (0x1001).
    pub const fn register(&self) -> u8 {
        self.register
    }

    /// Number of entries in 0x1003.
    pub const fn count(&self) -> u8 {
        self.count
    }

    /// 0x1003 sub `n` (1 = newest); `None` past the count.
    pub fn history(&self, n: u8) -> Option<u32> {
        if n == 0 || n > self.count {
            return None;
        }
        self.history.get(usize::from(n - 1)).copied()
    }

    /// Clear the history (0x1003 sub 0 written 0).
    pub fn clear_history(&mut self) {
        self.history = [0; HISTORY];
        self.count = 0;
    }

    /// Send one EMCY (and record it in the history unless it is 0x0000).
    pub fn send(&mut self, cob_id: u16, code: u16, fault: u8, out: &mut dyn FnMut(CanFrame)) {
        if code != NO_ERROR {
            self.active = true;
            self.history.copy_within(0..HISTORY - 1, 1);
            self.history[0] = (u32::from(fault) << 16) | u32::from(code);
            self.count = self.count.saturating_add(1).min(HISTORY as u8);
        }
        let [lo, hi] = code.to_le_bytes();
        if let Some(f) = CanFrame::new(cob_id, &[lo, hi, self.register, fault, 0, 0, 0, 0]) {
            out(f);
        }
    }

    /// A communication error (heartbeat, bus-off, PDO length): sets its
    /// register bits while `latched` (cleared by [`Self::clear_comm`]) and
    /// sends its EMCY.
    pub fn comm_error(
        &mut self,
        cob_id: u16,
        code: u16,
        latched: bool,
        out: &mut dyn FnMut(CanFrame),
    ) {
        if latched {
            self.comm_bits |= register_bits(code);
        }
        self.register |= register_bits(code);
        self.send(cob_id, code, 0, out);
        if !latched {
            self.refresh_register();
        }
    }

    /// The latched communication errors are gone.
    pub fn clear_comm(&mut self) {
        self.comm_bits = 0;
    }

    fn refresh_register(&mut self) {
        let mut r = self.comm_bits;
        for f in self.reported.iter() {
            r |= register_bits(fault_code(f));
        }
        if let Some(c) = self.profile {
            r |= register_bits(c);
        }
        self.register = r;
    }

    /// Follow the drive's faults and the profile's: one EMCY per newly
    /// latched fault; 0x0000 once when every error is gone.
    pub fn update(
        &mut self,
        cob_id: u16,
        faults: FaultSet,
        profile: Option<u16>,
        out: &mut dyn FnMut(CanFrame),
    ) {
        let new = FaultSet(faults.0 & !self.reported.0);
        self.reported = faults;
        let new_profile = match (profile, self.profile) {
            (Some(c), None) => Some(c),
            _ => None,
        };
        self.profile = profile;
        self.refresh_register();
        for f in new.iter() {
            self.send(cob_id, fault_code(f), f.code(), out);
        }
        if let Some(c) = new_profile {
            self.send(cob_id, c, 0, out);
        }
        if self.active && self.register == 0 {
            self.active = false;
            self.send(cob_id, NO_ERROR, 0, out);
        }
    }
}
