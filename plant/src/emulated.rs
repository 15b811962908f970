//! The emulated board's motor and inverter (the QEMU firmware's plant,
//! `board_support::board::SIM_MOTOR` / `sim_config`), here so that the
//! host bench can simulate the very same motor and compare its figures
//! with the emulated firmware's (`cargo xtask e2e`, the scope's current
//! step).

use crate::plant::{BenchConfig, DSaturation, MotorParams, PwmMode, SensorConfig, Shunts};

/// PWM frequency of the emulated board \[Hz\].
pub const PWM_FREQUENCY_HZ: u32 = 20_000;
/// Simulated dead time \[ns\].
pub const DEAD_TIME_NS: u32 = 200;
/// Current ADC range \[A\].
pub const MAX_MEASURABLE_CURRENT_A: f32 = 40.0;

/// The simulated motor (a small 7-pole-pair outrunner).
pub const MOTOR: MotorParams = MotorParams {
    pole_pairs: 7,
    r_ohm: 0.2,
    ld_h: 60e-6,
    lq_h: 60e-6,
    flux_linkage_wb: 0.005,
    inertia_kg_m2: 5e-5,
    viscous_friction_nm_s_per_rad: 1e-5,
    coulomb_friction_nm: 0.002,
    d_saturation: DSaturation::NONE,
};

/// The simulated inverter and sensors: 24 V bus, 200 ns dead time,
/// 12-bit current ADC with noise and an offset, 3 shunts, 4096-count
/// encoder.
pub fn bench_config() -> BenchConfig {
    BenchConfig {
        pwm_frequency_hz: PWM_FREQUENCY_HZ as _,
        substeps: 4,
        bus_voltage_v: 24.0,
        source_resistance_ohm: 0.05,
        dead_time_s: DEAD_TIME_NS as crate::real::Real * 1e-9,
        pwm_mode: PwmMode::Averaged,
        compute_delay_periods: 0,
        sensors: SensorConfig {
            adc_bits: 12,
            current_full_scale_a: MAX_MEASURABLE_CURRENT_A as _,
            current_noise_lsb_rms: 1.0,
            current_offset_a: [0.12, -0.08, 0.05],
            shunts: Shunts::Three,
            encoder_counts_per_rev: 4096,
            encoder_offset_rad: 0.0,
            bus_full_scale_v: 72.0,
            bus_noise_lsb_rms: 0.5,
            seed: 7,
        },
    }
}
