//! What the simulated board is: its motor and inverter ([`Options::setup`]),
//! how it starts ([`Start`]), and the facts the device service checks
//! against ([`board`]).

use foc_bench::mission::Setup;
use foc_bench::scope_step::emulated_setup;
use foc_core::calibration::offsets::OffsetLimits;
use foc_core::calibration::Calibrated;
use foc_core::drive::cascade::CascadeConfig;
use foc_core::drive::{AngleKind, LifecycleConfig};
use foc_service::Board;

/// Version the simulated drives report.
pub const FIRMWARE_VERSION: [u8; 3] = [0, 1, 0];

/// Values the scope of a [`Start::FromReset`] drive holds (the firmware's).
pub const SCOPE_VALUES: usize = 4096;

/// How the drive starts at power-on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Start {
    /// Calibrated from the bench's knowledge (the exact angle calibration
    /// and the configuration's gains), the current offsets installed, no
    /// identification on command: the CAN test bus's drives.
    Calibrated,
    /// As a board from reset: the offset calibration and the sensor
    /// check, then uncalibrated until an identification on command or a
    /// calibration stored in the flash and admitted at boot.
    FromReset,
}

/// The simulated board.
#[derive(Clone, Debug)]
pub struct Options {
    /// Motor, inverter and sensors (the plant) and the current ratings.
    /// The board's hardware current limit is `setup.max_current_a`.
    pub setup: Setup,
    /// How the drive starts.
    pub start: Start,
    /// Values the scope holds (0: no scope).
    pub scope_values: usize,
    /// Mechanical end stops `(low, high)` [rad, the drive's rotor frame]:
    /// the rotor stops dead there (infinite: none).
    pub end_stops_rad: (f32, f32),
}

impl Default for Options {
    /// The CAN test bus's drive: the emulated board's motor and inverter,
    /// [`Start::Calibrated`], no scope, no end stops.
    fn default() -> Self {
        Self {
            setup: emulated_setup(),
            start: Start::Calibrated,
            scope_values: 0,
            end_stops_rad: (f32::NEG_INFINITY, f32::INFINITY),
        }
    }
}

impl Options {
    /// `foc-ctl simulate`'s drive on `setup`: [`Start::FromReset`], the
    /// firmware's scope, no end stops.
    pub fn simulator(setup: Setup) -> Self {
        Self {
            setup,
            start: Start::FromReset,
            scope_values: SCOPE_VALUES,
            end_stops_rad: (f32::NEG_INFINITY, f32::INFINITY),
        }
    }
}

/// The board's facts for the device service: the setup's configuration,
/// its PWM frequency, a hardware current limit of the setup's maximum
/// current, a stored electrical zero that stays right across a power
/// cycle (every power-on starts the plant's rotor and encoder where the
/// last one did), the scope's size. [`Start::Calibrated`] adds the exact
/// angle calibration to the build-time settings and takes away the
/// identification on command.
pub fn board(opts: &Options) -> Board {
    let setup = &opts.setup;
    let pwm_hz = setup.bench.pwm_frequency_hz as u32;
    let mut b = Board::new(setup.cascade_config(), pwm_hz, setup.max_current_a);
    b.zero_survives_reset = true;
    b.firmware_version = FIRMWARE_VERSION;
    b.scope_values = u32::try_from(opts.scope_values).unwrap_or(u32::MAX);
    if opts.start == Start::Calibrated {
        b.base.angle = setup.true_angle_calibration();
        b.base.calibrated = true;
        b.identifies = false;
    }
    #[cfg(feature = "canopen")]
    {
        b.can_identity = crate::can::IDENTITY;
    }
    b
}

/// The lifecycle of a [`Start::FromReset`] drive: the bench's offset
/// limits and sensor check, the bench's identification settings for the
/// motor ([`foc_bench::identify::config`]), no identification at start-up,
/// `config`'s loop dividers, the `stored` calibration (an absolute angle:
/// see [`board`]).
pub fn lifecycle(
    setup: &Setup,
    config: &CascadeConfig,
    stored: Option<Calibrated>,
) -> LifecycleConfig {
    let pp = setup.motor.pole_pairs;
    LifecycleConfig {
        offsets: Some(OffsetLimits {
            samples: foc_bench::identify::OFFSET_SAMPLES,
            max_offset_a: 0.1 * setup.max_current_a,
            max_noise_a: 0.05 * setup.max_current_a,
        }),
        sensor_check_reads: foc_bench::identify::SENSOR_CHECK_READS,
        identification: Some(foc_bench::identify::config(setup, pp)),
        identify_at_start_up: false,
        speed_divider: config.rates.speed_divider,
        position_divider: config.rates.position_divider,
        angle_kind: AngleKind::Absolute,
        stored,
    }
}
