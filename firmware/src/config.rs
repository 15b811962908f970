//! Build-time configuration of the drive: the motor attached to each board,
//! loop rates, limits. Every value carries its unit in its name.
//!
//! The motor values are the defaults for the motor each board is usually
//! paired with; a different motor needs its own values (or the
//! identification routines).

use foc_core::control::dead_time::DeadTimeCompensation;
use foc_core::control::power::PowerLimitsConfig;
use foc_core::control::{Command, MotorParams};
use foc_core::drive::cascade::CascadeConfig;

/// Speed loop every N current-loop periods (20 kHz / 10 = 2 kHz).
pub const SPEED_DIVIDER: u16 = 10;
/// Position loop every M current-loop periods (20 kHz / 20 = 1 kHz).
pub const POSITION_DIVIDER: u16 = 20;
/// Housekeeping (telemetry, start-up sequencing) every K periods (50 Hz at 20 kHz).
pub const HOUSEKEEPING_DIVIDER: u32 = 400;

/// The telemetry stream task runs every this many periods (1 kHz at 20
/// kHz): the stream's finest spacing. The rate is capped by what the
/// command UART carries (`foc_protocol::device::max_stream_hz`): about
/// 190 Hz at 115200 baud.
pub const STREAM_DIVIDER: u32 = 20;

/// Values the scope buffer holds (design §22): 16 KiB of RAM, 1024
/// samples of 4 signals (or 512 of 8, 4096 of 1).
pub const SCOPE_VALUES: usize = 4096;
/// Current-loop budget as a fraction of the PWM period; a longer run raises
/// the overrun fault (moteus fails builds beyond about 66 %).
pub const CURRENT_LOOP_BUDGET_FRACTION: f32 = 0.6;
/// PWM periods of bridge-off averaging for the current-offset calibration.
pub const OFFSET_CAL_SAMPLES: u32 = 1024;
/// Largest acceptable current-sensor offset [A].
pub const OFFSET_CAL_MAX_A: f32 = 0.5;
/// Largest acceptable current-sensor noise (standard deviation) [A].
pub const OFFSET_CAL_MAX_NOISE_A: f32 = 0.1;
/// Consecutive good angle readings required by the start-up sensor check.
pub const SENSOR_CHECK_READS: u32 = 64;
/// Independent-watchdog timeout [ms].
pub const WATCHDOG_TIMEOUT_MS: u32 = 50;

/// Run the motor identification (R, L, gains, sensor alignment and
/// pole-pair check, flux linkage) at start-up. On the emulated board yes:
/// its mission starts with it. On real boards no: the motor may not be free
/// to turn at power-up; they start uncalibrated (closed-loop commands are
/// refused) until identification is run on command.
pub const IDENTIFY_AT_STARTUP: bool = cfg!(feature = "qemu");

/// [`IDENTIFY_AT_STARTUP`], except on the emulated board started with
/// `identify=off`, which boots as a real board does (to show that a board
/// with a damaged store comes up uncalibrated; the boot-from-store runs
/// keep the start-up identification configured: the stored calibration
/// must replace it).
pub fn identify_at_start_up() -> bool {
    #[cfg(feature = "qemu")]
    if !board_support::board::args().identify_at_start_up {
        return false;
    }
    IDENTIFY_AT_STARTUP
}

/// The identification's settings for this board's motor: test current
/// (a third of the current limit), open-loop voltage limit [V].
pub fn identification(
    pwm_frequency_hz: f32,
) -> foc_core::calibration::identification::IdentificationConfig {
    let (motor, max_current_a) = MOTOR;
    let mut c = foc_core::calibration::identification::IdentificationConfig::new(
        motor.pole_pairs,
        pwm_frequency_hz,
        max_current_a / 3.0,
        6.0,
    );
    // The encoder's resolution lets the alignment remove the half-count
    // bias of a counting sensor.
    #[cfg(feature = "qemu")]
    {
        c.alignment.sensor_counts_per_rev = if board_support::board::args().absolute_sensor {
            board_support::board::SIM_AS5047P_COUNTS_PER_REV
        } else {
            board_support::board::sim_config()
                .sensors
                .encoder_counts_per_rev
        };
    }
    #[cfg(not(feature = "qemu"))]
    if let Some(counts) = board_support::board::ANGLE_SOURCE.counts_per_rev() {
        c.alignment.sensor_counts_per_rev = counts;
    }
    c
}

/// Command applied once start-up has finished. `None`: stay disabled and
/// wait for a command (the default, and the only safe choice for a board
/// whose motor is unknown). A slow velocity demo would be
/// `Some(Command::Velocity { rad_s: 5.0 })`.
pub const START_COMMAND: Option<Command> = None;

/// The motor on the board and its current limit [A].
#[cfg(any(
    feature = "nucleo-f446re-ihm07m1",
    feature = "nucleo-f401re-ihm07m1",
    not(any(feature = "odrive-v3", feature = "qemu"))
))]
pub const MOTOR: (MotorParams, f32) = (
    // iPower GM4108H-120T gimbal motor (11 pole pairs, about 11 ohm):
    // the class of motor the X-NUCLEO-IHM07M1 (L6230, 1.4 A rms) drives.
    MotorParams {
        pole_pairs: 11,
        r_ohm: 11.1,
        ld_h: 5.0e-3,
        lq_h: 5.0e-3,
        flux_linkage_wb: 0.028,
    },
    1.0,
);

/// The motor on the board and its current limit [A].
#[cfg(feature = "odrive-v3")]
pub const MOTOR: (MotorParams, f32) = (
    // ODrive D5065-270KV (7 pole pairs, 39 mohm, about 16 uH).
    MotorParams {
        pole_pairs: 7,
        r_ohm: 0.039,
        ld_h: 16.0e-6,
        lq_h: 16.0e-6,
        flux_linkage_wb: 0.0029,
    },
    20.0,
);

// The board's hall decoder must count the same pole pairs as the motor.
#[cfg(not(any(feature = "odrive-v3", feature = "qemu")))]
const _: () = {
    if let board_support::board::AngleSource::Hall(h) = board_support::board::ANGLE_SOURCE {
        assert!(
            h.pole_pairs == MOTOR.0.pole_pairs,
            "hall pole pairs differ from config::MOTOR"
        );
    }
};

/// The motor on the board and its current limit [A]: the simulated motor.
#[cfg(feature = "qemu")]
pub const MOTOR: (MotorParams, f32) = {
    let m = board_support::board::SIM_MOTOR;
    (
        MotorParams {
            pole_pairs: m.pole_pairs,
            r_ohm: m.r_ohm,
            ld_h: m.ld_h,
            lq_h: m.lq_h,
            flux_linkage_wb: m.flux_linkage_wb,
        },
        10.0,
    )
};

/// The cascade configuration for this board and motor.
pub fn cascade(pwm_frequency_hz: f32) -> CascadeConfig {
    let (motor, max_current_a) = MOTOR;
    #[cfg(feature = "qemu")]
    let mut c = CascadeConfig::for_motor_with_inertia(
        motor,
        pwm_frequency_hz,
        max_current_a,
        board_support::board::SIM_MOTOR.inertia_kg_m2,
    );
    #[cfg(not(feature = "qemu"))]
    let mut c = CascadeConfig::for_motor(motor, pwm_frequency_hz, max_current_a);
    // Real boards sample the phase currents one after another on one ADC
    // (three injected conversions, about 3 us) around the PWM centre while
    // the low sides conduct: leave that window open by capping the voltage
    // at 80 % of the linear range ((1 - 0.8) x 50 us / 2 = 5 us at 20 kHz).
    #[cfg(not(feature = "qemu"))]
    {
        c.current.current.max_modulation = 0.80;
    }
    c.rates.speed_divider = SPEED_DIVIDER;
    c.rates.position_divider = POSITION_DIVIDER;
    // The sensor's resolution is known before any calibration (the
    // supervisor's angle-step limit never goes below a few counts).
    c.current.angle.sensor_counts_per_rev = identification(pwm_frequency_hz)
        .alignment
        .sensor_counts_per_rev;
    // Hall sensors: the decoder's reading jumps a whole sector when it
    // resynchronises (start, reversal, stall timeout): never call that a
    // slip.
    #[cfg(not(feature = "qemu"))]
    if let board_support::board::AngleSource::Hall(_) = board_support::board::ANGLE_SOURCE {
        c.current.supervisor.angle_step_floor_rad =
            1.5 * core::f32::consts::TAU / (6.0 * f32::from(motor.pole_pairs.max(1)));
    }
    // The model check (design §24) corrects the applied voltage by the
    // bridge's dead time and allows for it near a current's zero.
    c.current.supervisor.model.dead_time_s = board_support::board::DEAD_TIME_NS as f32 * 1e-9;
    // The current loop cancels it (design §31): the smooth sign's band a
    // share of the current limit.
    c.current.current.dead_time = DeadTimeCompensation::for_current_limit(
        c.current.supervisor.model.dead_time_s,
        max_current_a,
    );
    c.current.power = Some(power_limits(&c));
    c
}

/// The board's power limits (design §18): `PowerLimitsConfig::for_board`
/// (regen ramp below the over-voltage threshold, winding-temperature
/// derating, stage derating where the board measures its temperature; no
/// supply-current or power limit: those depend on the supply, see the
/// book's Power limits chapter), with the brake chopper where the board has a brake output
/// (`BRAKE_OUTPUT`; on the emulated board a run-time option,
/// `board::brake_output()`: semihosting `brake=OHMS`).
pub fn power_limits(c: &CascadeConfig) -> PowerLimitsConfig {
    use board_support::board;
    let p = PowerLimitsConfig::for_board(
        &c.current.supervisor,
        c.current.current.motor,
        board::STAGE_TEMPERATURE_SENSOR,
    );
    #[cfg(feature = "qemu")]
    let brake_output = board::brake_output();
    #[cfg(not(feature = "qemu"))]
    let brake_output = board::BRAKE_OUTPUT;
    if brake_output {
        p.with_brake_resistor()
    } else {
        p
    }
}
