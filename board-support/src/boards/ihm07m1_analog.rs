//! The X-NUCLEO-IHM07M1 shield's analog front end: ADC channels, shunt
//! amplifier, bus divider and thermistor (see `ihm07m1` for the board).
//! Separate so that the emulated board's bench can count the instructions
//! of the shield's real register path with the same scaling.

use crate::hw::adc::Thermistor;
use crate::logic::scaling::{CurrentScale, VoltageScale};

/// ADC channels of the three shunts (U, V, W).
pub const CURRENT_CHANNELS: [u8; 3] = [0, 11, 10];
/// ADC channel of the bus voltage.
pub const BUS_CHANNEL: u8 = 1;
/// ADC channel of the power-stage NTC (PC2).
pub const THERMISTOR_CHANNEL: u8 = 12;
/// The power-stage NTC as the bus reader converts it.
pub const THERMISTOR: Thermistor = Thermistor {
    channel: THERMISTOR_CHANNEL,
    divider: crate::logic::thermistor::IHM07M1,
};

/// Shunt resistance [ohm].
pub const SHUNT_OHM: f32 = 0.33;
/// Current amplifier gain magnitude [V/V] (the amplifier inverts).
pub const CURRENT_GAIN: f32 = 1.53;
/// Bus divider ratio `(169k + 9.31k) / 9.31k`.
pub const BUS_DIVIDER_RATIO: f32 = (169_000.0 + 9_310.0) / 9_310.0;
/// ADC reference [V] (VDDA = 3.3 V on the NUCLEO-64).
pub const VREF_V: f32 = 3.3;

/// Current conversion: nominal mid-scale bias; the residual offset is the
/// firmware's calibration (`CurrentSense::set_offsets_a`).
pub const CURRENT_SCALE: CurrentScale =
    CurrentScale::new(SHUNT_OHM, CURRENT_GAIN, VREF_V, 12, 2048.0, -1.0);
/// Bus-voltage conversion.
pub const BUS_SCALE: VoltageScale = VoltageScale::ratio(BUS_DIVIDER_RATIO, VREF_V, 12);
