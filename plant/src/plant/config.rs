//! The bench around the motor: PWM, shunts, sensors, angle sensor kind.

use super::*;

/// How the inverter output is modelled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PwmMode {
    /// Period-average terminal voltage in every sub-step (no ripple).
    Averaged,
    /// Centre-aligned triangle carrier compared per sub-step (ripple resolved).
    CarrierCompared,
}

/// Current-shunt arrangement.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shunts {
    /// Phases A and B measured ([`PhaseCurrents::TwoPhase`]).
    Two,
    /// All three measured ([`PhaseCurrents::ThreePhase`]).
    Three,
}

/// Sensor models.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorConfig {
    /// ADC resolution \[bits\] (12 on an STM32F4).
    pub adc_bits: u8,
    /// Current ADC range: `-fs .. +fs` maps to `0 .. 2^bits - 1` \[A\].
    pub current_full_scale_a: Real,
    /// Current-ADC noise, RMS \[LSB\].
    pub current_noise_lsb_rms: Real,
    /// Hardware offset of each current channel \[A\] (what calibration removes).
    pub current_offset_a: [Real; 3],
    /// Shunt arrangement.
    pub shunts: Shunts,
    /// Encoder counts per mechanical revolution.
    pub encoder_counts_per_rev: u32,
    /// Encoder zero relative to the rotor d axis (mechanical) \[rad\].
    pub encoder_offset_rad: Real,
    /// Bus-voltage ADC range `0 .. fs` \[V\].
    pub bus_full_scale_v: Real,
    /// Bus-voltage ADC noise, RMS \[LSB\].
    pub bus_noise_lsb_rms: Real,
    /// Seed of the noise generator.
    pub seed: u64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        Self {
            adc_bits: 12,
            current_full_scale_a: 60.0,
            current_noise_lsb_rms: 0.0,
            current_offset_a: [0.0; 3],
            shunts: Shunts::Three,
            encoder_counts_per_rev: 16_384,
            encoder_offset_rad: 0.0,
            bus_full_scale_v: 72.0,
            bus_noise_lsb_rms: 0.0,
            seed: 1,
        }
    }
}

impl SensorConfig {
    /// Ideal sensors: 24-bit ADCs, no noise, 2^24-count encoder.
    pub fn ideal() -> Self {
        Self {
            adc_bits: 24,
            current_full_scale_a: 1000.0,
            encoder_counts_per_rev: 1 << 24,
            bus_full_scale_v: 1000.0,
            ..Self::default()
        }
    }
}

/// What the rotor angle sensor reads relative to the rotor (chosen with
/// [`Plant::set_angle_sensor`]; [`SensorConfig::encoder_offset_rad`] and the
/// encoder faults apply on top, in both cases).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum AngleSensorKind {
    /// A counting encoder: reads 0 at power-on ([`Plant::new`],
    /// [`Plant::start_rotor_at`]) wherever the rotor is, and counts the
    /// rotor's motion from there. The default.
    Incremental,
    /// An absolute sensor (AS5047P-like): reads the true mechanical angle
    /// minus a fixed mounting offset from the first sample.
    Absolute {
        /// Mechanical angle of the rotor at which the sensor reads 0 \[rad\].
        mounting_offset_rad: Real,
    },
}

/// Inverter, supply and timing configuration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BenchConfig {
    /// PWM frequency \[Hz\] (one control period per PWM period).
    pub pwm_frequency_hz: Real,
    /// RK4 sub-steps per PWM period (8..32 typical).
    pub substeps: u32,
    /// DC source open-circuit voltage \[V\].
    pub bus_voltage_v: Real,
    /// DC source internal resistance \[ohm\] (the bus sags under load).
    pub source_resistance_ohm: Real,
    /// Dead time per switching edge \[s\].
    pub dead_time_s: Real,
    /// Inverter model.
    pub pwm_mode: PwmMode,
    /// Periods between the sample and the application of the duties (0 or 1).
    pub compute_delay_periods: u8,
    /// Sensor models.
    pub sensors: SensorConfig,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            pwm_frequency_hz: 15_000.0,
            substeps: 16,
            bus_voltage_v: 24.0,
            source_resistance_ohm: 0.0,
            dead_time_s: 0.0,
            pwm_mode: PwmMode::Averaged,
            compute_delay_periods: 1,
            sensors: SensorConfig::default(),
        }
    }
}

impl BenchConfig {
    /// PWM period \[s\].
    pub fn period_s(&self) -> Real {
        1.0 / self.pwm_frequency_hz
    }
}
