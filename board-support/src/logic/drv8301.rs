//! TI DRV8301 gate driver: SPI register encoding and status decoding
//! (datasheet SLOS719, section 7.6 "Register Maps").
//!
//! 16-bit frames, MSB first, SPI mode 1 (CPOL = 0, CPHA = 1), nSCS low for
//! the whole frame. Command: bit 15 `R/W` (1 = read), bits 14..11 address,
//! bits 10..0 data. The answer comes during the *next* frame: bit 15
//! `FRAME_FAULT`, bits 14..11 address, bits 10..0 data.
//!
//! ```
//! use board_support::logic::drv8301::*;
//! let c1 = Control1 { gate_current: GateCurrent::A1_7, gate_reset: false,
//!     pwm_mode: PwmMode::SixInputs, ocp_mode: OcpMode::LatchShutdown, oc_adj_set: 21 };
//! assert_eq!(write_frame(Register::Control1, c1.bits()), (0x02 << 11) | (21 << 6) | (1 << 4));
//! assert_eq!(Gain::from_gain(40), Some(Gain::G40));
//! ```

/// DRV8301 registers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Register {
    /// Status register 1 (read only).
    Status1 = 0x00,
    /// Status register 2 (read only).
    Status2 = 0x01,
    /// Control register 1.
    Control1 = 0x02,
    /// Control register 2.
    Control2 = 0x03,
}

/// Command frame reading `reg`.
pub const fn read_frame(reg: Register) -> u16 {
    0x8000 | ((reg as u16) << 11)
}

/// Command frame writing the 11 data bits `data` to `reg`.
pub const fn write_frame(reg: Register, data: u16) -> u16 {
    ((reg as u16) << 11) | (data & 0x07FF)
}

/// A decoded answer frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Answer {
    /// Bit 15: the previous frame was not a valid 16-bit frame.
    pub frame_fault: bool,
    /// Address the data belongs to.
    pub address: u8,
    /// 11 data bits.
    pub data: u16,
}

/// Decode an answer frame.
pub const fn decode_answer(frame: u16) -> Answer {
    Answer {
        frame_fault: frame & 0x8000 != 0,
        address: ((frame >> 11) & 0x0F) as u8,
        data: frame & 0x07FF,
    }
}

/// Peak gate drive current (`GATE_CURRENT`, control 1 bits 1..0).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GateCurrent {
    /// 1.7 A.
    A1_7 = 0b00,
    /// 0.7 A.
    A0_7 = 0b01,
    /// 0.25 A.
    A0_25 = 0b10,
}

/// PWM input mode (`PWM_MODE`, control 1 bit 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PwmMode {
    /// Six independent inputs.
    SixInputs = 0,
    /// Three inputs (the DRV8301 makes the complementary signals).
    ThreeInputs = 1,
}

/// Over-current protection mode (`OCP_MODE`, control 1 bits 5..4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OcpMode {
    /// Cycle-by-cycle current limit.
    CurrentLimit = 0b00,
    /// Latch shut-down on over-current.
    LatchShutdown = 0b01,
    /// Report only.
    ReportOnly = 0b10,
    /// Disabled.
    Disabled = 0b11,
}

/// `OC_ADJ_SET` code to the V_DS over-current threshold [V] (datasheet
/// table "OC_ADJ_SET"), index = code 0..=31.
pub const OC_ADJ_V: [f32; 32] = [
    0.060, 0.068, 0.076, 0.086, 0.097, 0.109, 0.123, 0.138, 0.155, 0.175, 0.197, 0.222, 0.250,
    0.282, 0.317, 0.358, 0.403, 0.454, 0.511, 0.576, 0.648, 0.730, 0.822, 0.926, 1.043, 1.175,
    1.324, 1.491, 1.679, 1.892, 2.131, 2.400,
];

/// Largest `OC_ADJ_SET` code whose threshold does not exceed `v` (code 0
/// below the table).
pub fn oc_adj_for_vds(v: f32) -> u8 {
    let mut code = 0u8;
    for (i, t) in OC_ADJ_V.iter().enumerate() {
        if *t <= v {
            code = i as u8;
        }
    }
    code
}

/// Control register 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Control1 {
    /// Gate drive peak current.
    pub gate_current: GateCurrent,
    /// Reset latched faults (self-clearing).
    pub gate_reset: bool,
    /// 6 or 3 PWM inputs.
    pub pwm_mode: PwmMode,
    /// Over-current protection mode.
    pub ocp_mode: OcpMode,
    /// V_DS threshold code 0..=31 (see [`OC_ADJ_V`]); values above are clamped.
    pub oc_adj_set: u8,
}

impl Control1 {
    /// The 11 data bits.
    pub const fn bits(&self) -> u16 {
        let oc = if self.oc_adj_set > 31 {
            31
        } else {
            self.oc_adj_set
        };
        (self.gate_current as u16)
            | ((self.gate_reset as u16) << 2)
            | ((self.pwm_mode as u16) << 3)
            | ((self.ocp_mode as u16) << 4)
            | ((oc as u16) << 6)
    }
}

/// OCTW pin reporting mode (`OCTW_MODE`, control 2 bits 1..0).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OctwMode {
    /// Over-temperature and over-current.
    OtAndOc = 0b00,
    /// Over-temperature only.
    OtOnly = 0b01,
    /// Over-current only.
    OcOnly = 0b10,
}

/// Shunt amplifier gain (`GAIN`, control 2 bits 3..2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gain {
    /// 10 V/V.
    G10 = 0b00,
    /// 20 V/V.
    G20 = 0b01,
    /// 40 V/V.
    G40 = 0b10,
    /// 80 V/V.
    G80 = 0b11,
}

impl Gain {
    /// Gain in V/V.
    pub const fn value(self) -> f32 {
        match self {
            Gain::G10 => 10.0,
            Gain::G20 => 20.0,
            Gain::G40 => 40.0,
            Gain::G80 => 80.0,
        }
    }
    /// From 10, 20, 40 or 80.
    pub const fn from_gain(g: u8) -> Option<Self> {
        match g {
            10 => Some(Gain::G10),
            20 => Some(Gain::G20),
            40 => Some(Gain::G40),
            80 => Some(Gain::G80),
            _ => None,
        }
    }
}

/// Control register 2.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Control2 {
    /// What the nOCTW pin reports.
    pub octw_mode: OctwMode,
    /// Shunt amplifier gain.
    pub gain: Gain,
    /// Short amplifier 1 inputs for offset calibration.
    pub dc_cal_ch1: bool,
    /// Short amplifier 2 inputs for offset calibration.
    pub dc_cal_ch2: bool,
    /// `OC_TOFF`: false = cycle by cycle, true = off-time control.
    pub oc_toff: bool,
}

impl Control2 {
    /// The 11 data bits.
    pub const fn bits(&self) -> u16 {
        (self.octw_mode as u16)
            | ((self.gain as u16) << 2)
            | ((self.dc_cal_ch1 as u16) << 4)
            | ((self.dc_cal_ch2 as u16) << 5)
            | ((self.oc_toff as u16) << 6)
    }
}

/// Status register 1 (and the `GVDD_OV` bit of status 2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "_hal", derive(defmt::Format))]
pub struct Status {
    /// Bit 10: any fault (mirrors the nFAULT pin).
    pub fault: bool,
    /// Bit 9: GVDD under-voltage.
    pub gvdd_uv: bool,
    /// Bit 8: PVDD under-voltage.
    pub pvdd_uv: bool,
    /// Bit 7: over-temperature shut-down.
    pub otsd: bool,
    /// Bit 6: over-temperature warning.
    pub otw: bool,
    /// Bits 5..0: over-current of FET (HA, LA, HB, LB, HC, LC) = bits 5..0.
    pub fet_oc: u8,
    /// Status 2 bit 7: GVDD over-voltage.
    pub gvdd_ov: bool,
    /// Status 2 bits 3..0: device ID.
    pub device_id: u8,
}

impl Status {
    /// Decode the data bits of status 1 and status 2.
    pub const fn decode(status1: u16, status2: u16) -> Self {
        Self {
            fault: status1 & (1 << 10) != 0,
            gvdd_uv: status1 & (1 << 9) != 0,
            pvdd_uv: status1 & (1 << 8) != 0,
            otsd: status1 & (1 << 7) != 0,
            otw: status1 & (1 << 6) != 0,
            fet_oc: (status1 & 0x3F) as u8,
            gvdd_ov: status2 & (1 << 7) != 0,
            device_id: (status2 & 0x0F) as u8,
        }
    }
    /// True when any fault or warning bit is set.
    pub const fn any(&self) -> bool {
        self.fault
            || self.gvdd_uv
            || self.pvdd_uv
            || self.otsd
            || self.otw
            || self.fet_oc != 0
            || self.gvdd_ov
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn frames() {
        assert_eq!(read_frame(Register::Status1), 0x8000);
        assert_eq!(read_frame(Register::Status2), 0x8800);
        assert_eq!(read_frame(Register::Control1), 0x9000);
        assert_eq!(read_frame(Register::Control2), 0x9800);
        assert_eq!(write_frame(Register::Control2, 0xFFFF), 0x1FFF);
        let a = decode_answer(0x9000 | 0x0555);
        assert_eq!(
            a,
            Answer {
                frame_fault: true,
                address: 2,
                data: 0x555
            }
        );
    }

    #[test]
    fn control_fields() {
        let c1 = Control1 {
            gate_current: GateCurrent::A0_25,
            gate_reset: true,
            pwm_mode: PwmMode::ThreeInputs,
            ocp_mode: OcpMode::Disabled,
            oc_adj_set: 99,
        };
        assert_eq!(
            c1.bits(),
            (31 << 6) | (0b11 << 4) | (1 << 3) | (1 << 2) | 0b10
        );
        for (g, bits) in [(10, 0), (20, 1), (40, 2), (80, 3)] {
            let c2 = Control2 {
                octw_mode: OctwMode::OcOnly,
                gain: Gain::from_gain(g).unwrap(),
                dc_cal_ch1: false,
                dc_cal_ch2: true,
                oc_toff: true,
            };
            assert_eq!(c2.bits(), 0b10 | (bits << 2) | (1 << 5) | (1 << 6));
            assert_eq!(c2.gain.value(), g as f32);
        }
        assert_eq!(Gain::from_gain(30), None);
    }

    #[test]
    fn oc_adj() {
        assert_eq!(oc_adj_for_vds(0.0), 0);
        assert_eq!(oc_adj_for_vds(0.730), 21);
        assert_eq!(oc_adj_for_vds(0.8), 21);
        assert_eq!(oc_adj_for_vds(10.0), 31);
        assert!(OC_ADJ_V.windows(2).all(|w| w[0] < w[1]));
    }

    #[test]
    fn status() {
        let s = Status::decode((1 << 10) | (1 << 7) | 0b100001, (1 << 7) | 0x1);
        assert!(s.fault && s.otsd && s.gvdd_ov && !s.otw && !s.pvdd_uv);
        assert_eq!(s.fet_oc, 0b100001);
        assert_eq!(s.device_id, 1);
        assert!(s.any());
        assert!(!Status::decode(0, 0).any());
    }

    proptest! {
        #[test]
        fn write_then_decode_roundtrip(data in 0u16..0x800, r in 0u8..4) {
            let reg = [Register::Status1, Register::Status2, Register::Control1, Register::Control2][r as usize];
            let a = decode_answer(write_frame(reg, data));
            prop_assert_eq!(a.address, r);
            prop_assert_eq!(a.data, data);
            prop_assert!(!a.frame_fault);
        }
    }
}
