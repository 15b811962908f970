//! What the service must know of the board it runs on: the facts the
//! link's rules check against, passed in by the firmware (from its board
//! and build-time configuration) or by a host simulation (from its plant).

use foc_core::drive::cascade::CascadeConfig;
use foc_store::Settings;

/// The board's facts (see the module docs).
#[derive(Clone, Copy, Debug)]
pub struct Board {
    /// PWM frequency \[Hz\]: a record's gains must have been made for it.
    pub pwm_hz: u32,
    /// The hardware's current limit \[A\]: no configuration goes above it.
    pub max_current_a: f32,
    /// True when a stored electrical zero is still right after a reset
    /// (an absolute sensor or halls; not an incremental encoder).
    pub zero_survives_reset: bool,
    /// True when the drive can run the identification on command (a host
    /// simulation that starts calibrated from the plant's knowledge says
    /// no).
    pub identifies: bool,
    /// Firmware version reported in `Hello` and as a parameter.
    pub firmware_version: [u8; 3],
    /// Highest telemetry rate the link carries \[Hz\] (`None`: no limit).
    pub max_stream_hz: Option<f32>,
    /// Values the drive's scope holds (0: no scope).
    pub scope_values: u32,
    /// The build-time configuration (motor, loops, supervisor, power).
    pub cascade: CascadeConfig,
    /// The build-time settings a record is applied onto (uncalibrated on
    /// a real board; a simulation may start calibrated).
    pub base: Settings,
    /// The CANopen node's identity (0x1018, 0x1008, 0x1009).
    #[cfg(feature = "canopen")]
    pub can_identity: foc_canopen::node::Identity,
}

impl Board {
    /// A board with `cascade` as its build-time configuration, `pwm_hz` and
    /// a hardware current limit of `max_current_a`: settings from the
    /// configuration (uncalibrated), the zero of an incremental encoder
    /// (lost at reset), identification on command, version 0.0.0, no
    /// stream limit, no scope. Set the other facts on the result.
    pub fn new(cascade: CascadeConfig, pwm_hz: u32, max_current_a: f32) -> Self {
        Self {
            pwm_hz,
            max_current_a,
            zero_survives_reset: false,
            identifies: true,
            firmware_version: [0; 3],
            max_stream_hz: None,
            scope_values: 0,
            cascade,
            base: Settings::from_cascade(&cascade),
            #[cfg(feature = "canopen")]
            can_identity: foc_canopen::node::Identity {
                vendor_id: 0,
                product_code: 0,
                revision: 0,
                serial: 0,
                device_name: "rust-foc drive",
                hardware_version: "",
            },
        }
    }

    /// The bus voltage at which the drive trips `BusOverVoltage` \[V\]: the
    /// regen limit and the brake must act below it.
    pub fn bus_over_voltage_v(&self) -> f32 {
        self.cascade.current.supervisor.bus_over_voltage_v
    }

    /// The cascade configuration of `s` (the build-time one with `s`
    /// applied).
    pub fn cascade_of(&self, s: &Settings) -> CascadeConfig {
        s.apply_to(&self.cascade)
    }
}

/// `"1.2.3"` as `[1, 2, 3]`, at compile time for a constant (a version
/// with more than three parts keeps the first three; parts wrap at 256).
pub const fn parse_version(s: &str) -> [u8; 3] {
    let s = s.as_bytes();
    let mut out = [0u8; 3];
    let (mut i, mut part) = (0, 0);
    while i < s.len() && part < 3 {
        let c = match s.split_at(i).1.first() {
            Some(c) => *c,
            None => break,
        };
        if c == b'.' {
            part += 1;
        } else if c.is_ascii_digit() {
            let v = match part {
                0 => &mut out[0],
                1 => &mut out[1],
                _ => &mut out[2],
            };
            *v = v.wrapping_mul(10).wrapping_add(c - b'0');
        } else {
            break;
        }
        i += 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn versions_parse() {
        assert_eq!(parse_version("1.2.3"), [1, 2, 3]);
        assert_eq!(parse_version("0.10.0-rc1"), [0, 10, 0]);
        assert_eq!(parse_version("7"), [7, 0, 0]);
    }
}
