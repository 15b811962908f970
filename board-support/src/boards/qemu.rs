//! The emulated board: QEMU's `netduinoplus2` machine (STM32F405, QEMU 7.2).
//!
//! QEMU models no RCC (so: HSI only, no clock set-up), no TIM1, no injected
//! ADC and no DWT cycle counter. This board therefore implements the
//! foc-core hardware traits on the test bench's motor and inverter plant
//! (`foc_plant::plant`, built `no_std` in f32) running on the emulated
//! Cortex-M4F itself:
//!
//! - TIM2's update interrupt stands in for the PWM period. Its handler is
//!   "the physics": it advances the plant by one PWM period
//!   (`1 / PWM_FREQUENCY_HZ` of simulated time) with the duties the current
//!   loop wrote last, latches what the ADC and encoder would sample at the
//!   PWM centre, then pends the `ADC` interrupt, so the firmware's current
//!   loop task runs exactly as on a real board (same vector, same priority).
//! - [`SimPwm`], [`SimCurrents`], [`SimAngle`], [`SimBus`] read and write
//!   that latched state.
//!
//! Power-stage temperature ([`STAGE_TEMPERATURE_SENSOR`] = true): the plant
//! runs a stage thermal model ([`SIM_STAGE_THERMAL`], starting at its
//! 25 deg C ambient); [`SimBus`]'s `read_temperature_c` returns the
//! temperature latched with the other measurements
//! (`Measurements::stage_temperature_c`), so the firmware's over-temperature
//! and derating path runs as on a board with a sensor. The model is a loss
//! estimate only: the plant's electrical behaviour and every other
//! measurement are unchanged.
//!
//! DC link and brake: by default the emulated plant has no DC link (an
//! ideal 24 V source behind 0.05 ohm, which takes any regenerated current
//! back). `supply=nonsinking` gives it [`sim_dc_link`]: the ODrive v3
//! preset's bulk capacitor fed by a 24 V bench supply that cannot sink
//! current, so a braking motor charges the capacitor. [`SimBrake`] switches
//! the plant's brake chopper (`Plant::set_brake`, applied at the start of
//! the next simulated period); `brake=OHMS` fits a brake resistor of that
//! value across the DC link and makes [`brake_output`] true, so the
//! firmware runs its chopper ([`BRAKE_OUTPUT`], false, is the default
//! without `brake=`). Without a resistor the command is recorded and draws
//! nothing (harmless). Off at `init` and in [`emergency_disable`].
//!
//! The TIM2 period in *emulated* time ([`EMULATED_PERIOD_US`]) is longer
//! than the simulated PWM period: the plant runs on the same emulated CPU,
//! and the firmware's lower-priority tasks must still get time. Simulated
//! physics time advances by exactly one PWM period per interrupt, whatever
//! the emulated clock does.
//!
//! [`sim`] is the handle on the plant (load torque, fault injection, the
//! true state) of the emulated bench: its instrument port (USART1, polled
//! by the physics, see [`crate::logic::instrument`]) and the bench binary.
//! The firmware never uses it.
//!
//! Options come from the semihosting command line ([`args`], see
//! [`crate::logic::emu_args`]): `store=PATH` backs [`StoreFlash`] with a
//! host file (`super::qemu_store`), `sensor=absolute` replaces the
//! incremental encoder by an absolute (AS5047P-like, 14-bit) sensor
//! mounted [`SIM_AS5047P_MOUNTING_OFFSET_RAD`] from the rotor's zero,
//! `rotor=X` starts the rotor at `X` rad, `supply=nonsinking` and
//! `brake=OHMS` configure the DC link (above), `identify=off` tells the
//! firmware to boot without the start-up identification. Without options the board behaves as before: incremental
//! encoder, rotor at 0, no DC link, reading exactly what it read before
//! the options existed.

pub use crate::hw::serial::CommandSerial;
use crate::hw::serial::SerialConfig;
pub use crate::hw::slcan::{SlcanError, SlcanPort};
pub use crate::logic::can::Bitrate;
use crate::pac;
use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use cortex_m::interrupt::{free, Mutex};
use foc_core::angle::MechanicalAngle;
use foc_core::drive::AngleKind;
use foc_core::frames::Abc;
use foc_core::hal::{AngleSensor, BrakeOutput, BusVoltage, CurrentSense, PhaseCurrents, PwmDriver};
use foc_plant::plant::{AngleSensorKind, BenchConfig, Measurements, MotorParams, Plant};
use foc_plant::power::{DcLinkConfig, StageThermal};
use pac::interrupt;

pub use super::qemu_store::{args, SimStoreError, StoreFlash, STORE_RANGE};
pub use super::Led;
pub use crate::logic::emu_args::{EmuArgs, EmuSupply};

/// Board name.
pub const NAME: &str = "QEMU netduinoplus2 (STM32F405) + simulated motor";
/// Core clock: the 16 MHz HSI (QEMU models no RCC).
pub const SYSCLK_HZ: u32 = 16_000_000;
/// Simulated PWM (= current-loop) frequency [Hz].
pub const PWM_FREQUENCY_HZ: u32 = 20_000;
/// The source's operating point.
pub const PWM_FREQUENCY_15K_HZ: u32 = 15_000;
/// Simulated dead time [ns].
pub const DEAD_TIME_NS: u32 = 200;
/// Current-loop interrupt (pended by the TIM2 handler).
pub const CURRENT_IRQ: pac::Interrupt = pac::Interrupt::ADC;
/// Break interrupt (never fires here).
pub const BREAK_IRQ: pac::Interrupt = pac::Interrupt::TIM1_BRK_TIM9;
/// No break input.
pub const HAS_BREAK_INPUT: bool = false;
/// A CAN port: QEMU's netduinoplus2 models no bxCAN, so the board's
/// [`Can`] carries the frames as SLCAN lines on USART3, QEMU's third
/// `-serial` device (start QEMU with `-serial null -serial null -serial
/// tcp:127.0.0.1:PORT,server=on,wait=off`; `foc-canbus --relay` joins it
/// to the host test bus).
pub const HAS_CAN: bool = true;
/// CAN receive interrupt: USART3's (a received SLCAN byte).
pub const CAN_RX_IRQ: pac::Interrupt = pac::Interrupt::USART3;
/// The CAN port: SLCAN over USART3 ([`crate::hw::slcan`]).
pub type Can = SlcanPort;
/// Command UART interrupt: USART2, QEMU's second `-serial` device (start
/// QEMU with `-serial null -serial tcp:127.0.0.1:PORT,server,nowait`).
pub const SERIAL_IRQ: pac::Interrupt = pac::Interrupt::USART2;
/// Nominal baud rate (QEMU's USART model ignores BRR: bytes move at the
/// speed of the character back-end).
pub const SERIAL_BAUD: u32 = 115_200;
/// Power-stage current limit [A].
pub const MAX_PHASE_CURRENT_A: f32 = 20.0;
/// Current ADC range [A].
pub const MAX_MEASURABLE_CURRENT_A: f32 = 40.0;
/// Bus range [V].
pub const BUS_VOLTAGE_MIN_V: f32 = 10.0;
/// Bus range [V].
pub const BUS_VOLTAGE_MAX_V: f32 = 30.0;
/// No brake resistor in the emulated plant by default (no DC link
/// configured): [`SimBrake`] switches the plant's chopper command, which
/// draws nothing. The option `brake=OHMS` fits one: see [`brake_output`].
pub const BRAKE_OUTPUT: bool = false;

/// True when the emulated plant has a brake resistor (`brake=OHMS`), so
/// the firmware runs its brake chopper; [`BRAKE_OUTPUT`] (false) without.
pub fn brake_output() -> bool {
    args().brake_resistor_ohm.is_some()
}

/// The emulated plant models the power stage's temperature
/// ([`SIM_STAGE_THERMAL`]); [`SimBus`] reads it.
pub const STAGE_TEMPERATURE_SENSOR: bool = true;
/// TIM2 update period in emulated time [us] (see the module docs).
pub const EMULATED_PERIOD_US: u32 = 250;
/// Input clock of QEMU's STM32F2xx/F405 timer model (its `clock-frequency`
/// is fixed at 1 GHz by the SoC model, whatever RCC says).
pub const QEMU_TIMER_CLOCK_HZ: u32 = 1_000_000_000;
/// Compare-value range of the emulated PWM (as a 168 MHz TIM1 at 20 kHz).
pub const PERIOD_COUNTS: u16 = 4200;

/// The simulated motor (a small 7-pole-pair outrunner):
/// [`foc_plant::emulated::MOTOR`], shared with the host bench so that
/// both simulate the same motor.
pub const SIM_MOTOR: MotorParams = foc_plant::emulated::MOTOR;

/// The simulated inverter and sensors ([`foc_plant::emulated::bench_config`]):
/// 24 V bus, 200 ns dead time, 12-bit current ADC with noise and an offset,
/// 3 shunts, 4096-count encoder.
pub fn sim_config() -> BenchConfig {
    foc_plant::emulated::bench_config()
}

const _: () = assert!(
    foc_plant::emulated::PWM_FREQUENCY_HZ == PWM_FREQUENCY_HZ
        && foc_plant::emulated::DEAD_TIME_NS == DEAD_TIME_NS
        && foc_plant::emulated::MAX_MEASURABLE_CURRENT_A == MAX_MEASURABLE_CURRENT_A
);

/// The emulated power stage's thermal model: the plant's ODrive v3 preset
/// (`StageThermal::odrive_v3`: a MOSFET bridge of the simulated inverter's
/// class, R_ds_on 3.4 mOhm, 20 ns switching, 8 K/W, 30 s, body diodes
/// 0.8 V; assumed values, see `foc_plant::power`), starting at its 25 deg C
/// ambient. At the simulated currents it warms by a few kelvin at most.
pub const SIM_STAGE_THERMAL: StageThermal = StageThermal::odrive_v3();

/// The emulated DC link of `supply=nonsinking`: the ODrive v3 preset's
/// bulk capacitor (`DcLinkConfig::odrive_v3`: 4 x 470 uF, 15 mOhm ESR,
/// assumed values, see `foc_plant::power`) fed by a 24 V bench supply that
/// cannot sink current (20 mOhm), with a 20 A current limit: generous for
/// a spin-up at the 10 A phase-current limit (at most about 8 A from the
/// supply at 24 V); `brake_resistor_ohm` from `brake=` (none without).
pub fn sim_dc_link(brake_resistor_ohm: Option<f32>) -> DcLinkConfig {
    DcLinkConfig {
        brake_resistor_ohm: brake_resistor_ohm.map(|r| r as _),
        ..DcLinkConfig::odrive_v3().bench_supply(24.0, 20.0)
    }
}

/// Mounting offset of the emulated absolute sensor (`sensor=absolute`):
/// the rotor's mechanical angle at which it reads 0 [rad]. Non-zero so that
/// a stored calibration is meaningfully non-trivial.
pub const SIM_AS5047P_MOUNTING_OFFSET_RAD: f32 = 0.9;
/// Counts per turn of the emulated absolute sensor (AS5047P: 14 bits).
pub const SIM_AS5047P_COUNTS_PER_REV: u32 = 1 << 14;

/// What the angle sensor tells at reset: `Absolute` with
/// `sensor=absolute`, else `Incremental` (from [`args`]).
pub fn angle_kind() -> AngleKind {
    if args().absolute_sensor {
        AngleKind::Absolute
    } else {
        AngleKind::Incremental
    }
}

/// The plant as the options ask: sensor model, rotor start angle, DC link.
fn sim_plant(args: &EmuArgs) -> Plant {
    let mut plant = Plant::new(SIM_MOTOR, sim_config());
    if args.absolute_sensor {
        plant.config_mut().sensors.encoder_counts_per_rev = SIM_AS5047P_COUNTS_PER_REV;
        plant.set_angle_sensor(AngleSensorKind::Absolute {
            mounting_offset_rad: SIM_AS5047P_MOUNTING_OFFSET_RAD,
        });
    }
    plant.start_rotor_at(args.rotor_start_rad);
    plant.set_stage_thermal(Some(SIM_STAGE_THERMAL));
    match args.supply {
        EmuSupply::Ideal => {}
        EmuSupply::NonSinking => plant.set_dc_link(Some(sim_dc_link(args.brake_resistor_ohm))),
    }
    plant
}

struct World {
    plant: Plant,
    load_nm: f32,
    /// Stop watch of [`sim::start_stop_watch`] (`None`: not armed).
    watch: Option<sim::StopWatch>,
}

static WORLD: Mutex<RefCell<Option<World>>> = Mutex::new(RefCell::new(None));

/// What the "ADC" and the encoder latched at the last PWM centre: written by
/// the physics (TIM2, priority 0), read by the drivers below. Kept apart from
/// [`WORLD`] in a plain `Cell` (no `RefCell` borrow flag, no `Option` of the
/// whole plant), so that each driver read is one short critical section and
/// a load of the fields it needs.
#[derive(Clone, Copy)]
struct Latch {
    /// Phase currents as sampled (hardware offsets included).
    currents: PhaseCurrents,
    /// Encoder reading.
    angle: MechanicalAngle,
    /// Bus voltage [V].
    v_bus_v: f32,
    /// Power-stage temperature [deg C] (`None` without the plant's model).
    stage_temperature_c: Option<f32>,
    /// A sample has been latched since start-up.
    valid: bool,
    /// Not yet read by [`SimCurrents::read_currents`].
    fresh: bool,
}

static LATCH: Mutex<Cell<Latch>> = Mutex::new(Cell::new(Latch {
    currents: PhaseCurrents::TwoPhase { a_a: 0.0, b_a: 0.0 },
    angle: MechanicalAngle::ZERO,
    v_bus_v: 0.0,
    stage_temperature_c: None,
    valid: false,
    fresh: false,
}));

/// Duties the PWM driver wrote last (read by the physics), also a plain
/// `Cell` apart from [`WORLD`].
static DUTIES: Mutex<Cell<[f32; 3]>> = Mutex::new(Cell::new([0.5; 3]));
/// Bridge outputs on (written by the PWM driver, cleared by emergency_disable).
static BRIDGE_ON: AtomicBool = AtomicBool::new(false);
/// Set by emergency_disable: the outputs stay off until reset.
static EMERGENCY: AtomicBool = AtomicBool::new(false);
/// The (simulated) timer break fired: `enable` refuses until the
/// operator's clear releases it (`release_fault_latch`), as on the boards.
static BREAK_LATCH: AtomicBool = AtomicBool::new(false);
/// Periods the bridge conducted while the break latch was set (must stay 0).
static ON_AFTER_BREAK: AtomicU32 = AtomicU32::new(0);
/// Periods the bridge conducted since reset.
static ON_PERIODS: AtomicU32 = AtomicU32::new(0);
/// Brake chopper command (written by [`SimBrake`], cleared by
/// `emergency_disable`), applied to the plant by the physics each period.
static BRAKE_CMD: AtomicBool = AtomicBool::new(false);

/// The emulated PWM stage.
pub struct SimPwm {
    _private: (),
}

/// Error of the emulated PWM.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimPwmError {
    /// A compare value above the period.
    OutOfRange,
    /// `emergency_disable` ran: the outputs stay off until reset.
    EmergencyOff,
}

impl PwmDriver for SimPwm {
    type Error = SimPwmError;
    fn period_counts(&self) -> u16 {
        PERIOD_COUNTS
    }
    fn set_compare(&mut self, compare: [u16; 3]) -> Result<(), Self::Error> {
        if compare.iter().any(|&c| c > PERIOD_COUNTS) {
            return Err(SimPwmError::OutOfRange);
        }
        let d = compare.map(|c| c as f32 / PERIOD_COUNTS as f32);
        free(|cs| DUTIES.borrow(cs).set(d));
        Ok(())
    }
    fn enable(&mut self) -> Result<(), Self::Error> {
        if EMERGENCY.load(Ordering::SeqCst) || BREAK_LATCH.load(Ordering::SeqCst) {
            return Err(SimPwmError::EmergencyOff);
        }
        BRIDGE_ON.store(true, Ordering::SeqCst);
        Ok(())
    }
    fn disable(&mut self) {
        BRIDGE_ON.store(false, Ordering::SeqCst);
    }
    fn is_enabled(&self) -> bool {
        BRIDGE_ON.load(Ordering::SeqCst)
    }
    fn release_fault_latch(&mut self) {
        BREAK_LATCH.store(false, Ordering::SeqCst);
    }
}

/// The emulated current ADC.
pub struct SimCurrents {
    offsets: Abc,
}

/// Error of the emulated ADC.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimAdcError {
    /// No new sample since the last read (the TIM2 "conversion" did not run).
    NotReady,
}

/// The latched sample, if any (fresh or not).
#[inline(always)]
fn latched() -> Option<Latch> {
    let l = free(|cs| LATCH.borrow(cs).get());
    if l.valid {
        Some(l)
    } else {
        None
    }
}

impl CurrentSense for SimCurrents {
    type Error = SimAdcError;
    fn read_currents(&mut self) -> Result<PhaseCurrents, Self::Error> {
        // Take the sample if it is fresh (one critical section).
        let m = free(|cs| {
            let cell = LATCH.borrow(cs);
            let mut l = cell.get();
            if l.fresh {
                l.fresh = false;
                cell.set(l);
                Some(l)
            } else {
                None
            }
        })
        .ok_or(SimAdcError::NotReady)?;
        let o = self.offsets;
        Ok(match m.currents {
            PhaseCurrents::TwoPhase { a_a, b_a } => PhaseCurrents::TwoPhase {
                a_a: a_a - o.a,
                b_a: b_a - o.b,
            },
            PhaseCurrents::ThreePhase(i) => {
                PhaseCurrents::ThreePhase(Abc::new(i.a - o.a, i.b - o.b, i.c - o.c))
            }
        })
    }
    fn offsets_a(&self) -> Abc {
        self.offsets
    }
    fn set_offsets_a(&mut self, offsets: Abc) {
        self.offsets = offsets;
    }
}

/// The emulated encoder.
pub struct SimAngle {
    _private: (),
}

/// Error of the emulated encoder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimAngleError {
    /// No sample yet.
    NotReady,
}

impl AngleSensor for SimAngle {
    type Error = SimAngleError;
    fn read_angle(&mut self) -> Result<MechanicalAngle, Self::Error> {
        latched().map(|m| m.angle).ok_or(SimAngleError::NotReady)
    }
}

/// The emulated bus-voltage measurement.
pub struct SimBus {
    _private: (),
}

impl BusVoltage for SimBus {
    type Error = SimAngleError;
    fn read_bus_voltage_v(&mut self) -> Result<f32, Self::Error> {
        latched().map(|m| m.v_bus_v).ok_or(SimAngleError::NotReady)
    }
    /// The plant's power-stage temperature, latched with the other
    /// measurements; `None` only if the plant had no stage model.
    fn read_temperature_c(&mut self) -> Option<Result<f32, Self::Error>> {
        match latched() {
            None => Some(Err(SimAngleError::NotReady)),
            Some(m) => m.stage_temperature_c.map(Ok),
        }
    }
}

/// The emulated brake chopper: the plant's `set_brake`, applied by the
/// physics at the start of each simulated period. Without a DC link (the
/// default) the plant records the command and draws nothing.
pub struct SimBrake {
    _private: (),
}

impl BrakeOutput for SimBrake {
    fn set_brake(&mut self, on: bool) {
        // After `emergency_disable` the bridge stays off until reset; so
        // does the brake.
        let on = on && !EMERGENCY.load(Ordering::SeqCst);
        BRAKE_CMD.store(on, Ordering::SeqCst);
    }
    fn is_brake_on(&self) -> bool {
        BRAKE_CMD.load(Ordering::SeqCst)
    }
}

/// PWM driver type.
pub type Pwm = SimPwm;
/// Current-sense type.
pub type Currents = SimCurrents;
/// Angle-sensor type.
pub type Angle = SimAngle;
/// Bus-voltage (and stage-temperature) type.
pub type Bus = SimBus;
/// Brake-chopper type.
pub type Brake = SimBrake;

/// The board's drivers.
pub struct Board {
    /// PWM stage.
    pub pwm: Pwm,
    /// Phase currents.
    pub currents: Currents,
    /// Encoder.
    pub angle: Angle,
    /// Bus voltage and stage temperature.
    pub bus: Bus,
    /// The plant's brake chopper command, off.
    pub brake: Brake,
    /// No LED.
    pub led: Led,
    /// Command UART: USART2 (QEMU `-serial` number two).
    pub serial: CommandSerial,
    /// The CAN port: SLCAN over USART3 (QEMU `-serial` number three), not
    /// started until `can.start(..)`.
    pub can: Can,
    /// The configuration store: a host file through semihosting
    /// (`store=PATH`), failing every operation without one.
    pub store: StoreFlash,
}

/// Create the plant, start TIM2 as the period source
/// ([`start_period_timer`]), bridge off.
///
/// First reads the options ([`args`]) from the semihosting command line and
/// opens the store file they name.
pub fn init(dp: pac::Peripherals) -> Board {
    let args = super::qemu_store::init_args();
    let plant = sim_plant(args);
    reset_world(plant);
    start_period_timer(&dp.RCC, &dp.TIM2);
    let serial = command_serial(&dp.RCC, dp.USART2);
    let can = can_port(&dp.RCC, dp.USART3);
    instrument_port(&dp.RCC, dp.USART1);
    Board {
        pwm: SimPwm { _private: () },
        currents: SimCurrents {
            offsets: Abc::default(),
        },
        angle: SimAngle { _private: () },
        bus: SimBus { _private: () },
        brake: SimBrake { _private: () },
        led: Led::new(None),
        serial,
        can,
        store: StoreFlash::open(args),
    }
}

/// The simulated world from scratch: `plant` with no load and no watch,
/// duties centred, no sample latched; bridge and brake off.
fn reset_world(plant: Plant) {
    free(|cs| {
        WORLD.borrow(cs).replace(Some(World {
            plant,
            load_nm: 0.0,
            watch: None,
        }));
        DUTIES.borrow(cs).set([0.5; 3]);
        let l = LATCH.borrow(cs);
        l.set(Latch {
            valid: false,
            fresh: false,
            ..l.get()
        });
    });
    BRIDGE_ON.store(false, Ordering::SeqCst);
    BRAKE_CMD.store(false, Ordering::SeqCst);
}

/// TIM2 as the period source, its interrupt unmasked.
///
/// TIM2 (RM0090 section 18): prescaler to 1 MHz from QEMU's timer clock
/// ([`QEMU_TIMER_CLOCK_HZ`]), auto-reload for [`EMULATED_PERIOD_US`],
/// update interrupt enabled. Its
/// NVIC priority stays 0 (the highest, above every RTIC task).
fn start_period_timer(rcc: &pac::RCC, tim: &pac::TIM2) {
    // RCC_APB1ENR.TIM2EN (RM0090 7.3.13); harmless where RCC is not modelled.
    rcc.apb1enr().modify(|_, w| w.tim2en().set_bit());
    tim.psc()
        .write(|w| w.psc().set((QEMU_TIMER_CLOCK_HZ / 1_000_000 - 1) as u16));
    tim.arr().write(|w| w.arr().set(EMULATED_PERIOD_US - 1));
    tim.egr().write(|w| w.ug().set_bit());
    tim.sr().write(|w| w.uif().clear_bit());
    tim.dier().write(|w| w.uie().set_bit());
    tim.cr1().write(|w| w.cen().set_bit());
    // SAFETY: TIM2's handler below only touches the plant (inside a
    // critical section) and pends ADC; unmasking it cannot break RTIC's
    // resource locking because it shares no RTIC resource.
    unsafe { cortex_m::peripheral::NVIC::unmask(pac::Interrupt::TIM2) };
}

/// The command UART: USART2 (QEMU `-serial` number two).
fn command_serial(rcc: &pac::RCC, usart2: pac::USART2) -> CommandSerial {
    // Command UART: RCC_APB1ENR.USART2EN (RM0090 7.3.13; QEMU does not
    // model the RCC, so no ready flag is waited on). No GPIO set-up: QEMU
    // models no GPIO alternate functions.
    rcc.apb1enr().modify(|_, w| w.usart2en().set_bit());
    CommandSerial::usart2(
        usart2,
        SerialConfig {
            baud: SERIAL_BAUD,
            pclk_hz: SYSCLK_HZ,
        },
    )
}

/// The CAN port: SLCAN over USART3 (QEMU `-serial` number three), not
/// started.
fn can_port(rcc: &pac::RCC, usart3: pac::USART3) -> Can {
    // CAN port: USART3, RCC_APB1ENR.USART3EN (RM0090 7.3.13; not modelled
    // by QEMU, set anyway as on hardware), no GPIO set-up (as USART2).
    rcc.apb1enr().modify(|_, w| w.usart3en().set_bit());
    SlcanPort::new(CommandSerial::usart3(
        usart3,
        SerialConfig {
            baud: SERIAL_BAUD,
            pclk_hz: SYSCLK_HZ,
        },
    ))
}

/// The emulated bench's instrument port on USART1, handed to the physics
/// ([`INSTRUMENT`]).
fn instrument_port(rcc: &pac::RCC, usart1: pac::USART1) {
    // Instrument port (the emulated bench's, see `instrument`): USART1,
    // RCC_APB2ENR.USART1EN (RM0090 7.3.14; not modelled by QEMU), polled
    // by the physics.
    rcc.apb2enr().modify(|_, w| w.usart1en().set_bit());
    let port = CommandSerial::usart1(
        usart1,
        SerialConfig {
            baud: SERIAL_BAUD,
            pclk_hz: SYSCLK_HZ,
        },
    );
    free(|cs| {
        INSTRUMENT
            .borrow(cs)
            .replace(Some(instrument::Port::new(port)))
    });
}

/// Bridge and brake off from any context (panic, HardFault); they stay
/// off until reset. (Only atomics: the plant itself may be borrowed by the
/// interrupted code; the physics applies the brake command next period.)
pub fn emergency_disable() {
    EMERGENCY.store(true, Ordering::SeqCst);
    BRIDGE_ON.store(false, Ordering::SeqCst);
    BRAKE_CMD.store(false, Ordering::SeqCst);
}

/// The break ISR ran ([`sim::raise_break`]): its `emergency_disable` was a
/// break, not a panic, so the permanent emergency latch becomes the break
/// latch, released by the operator's clear (as on the real boards).
pub fn break_isr_ack() {
    BREAK_LATCH.store(true, Ordering::SeqCst);
    EMERGENCY.store(false, Ordering::SeqCst);
}

/// No gate-driver fault pin.
pub fn gate_driver_fault() -> bool {
    false
}

/// Advance the plant by one PWM period and latch its sample.
fn step_physics() {
    let on = BRIDGE_ON.load(Ordering::SeqCst);
    if on {
        ON_PERIODS.fetch_add(1, Ordering::SeqCst);
    }
    if on && BREAK_LATCH.load(Ordering::SeqCst) {
        ON_AFTER_BREAK.fetch_add(1, Ordering::SeqCst);
    }
    free(|cs| {
        if let Some(w) = WORLD.borrow(cs).borrow_mut().as_mut() {
            w.plant.set_brake(BRAKE_CMD.load(Ordering::SeqCst));
            let m: Measurements = w.plant.step_period(DUTIES.borrow(cs).get(), on, w.load_nm);
            if let Some(watch) = w.watch.as_mut() {
                watch.record(&w.plant);
            }
            LATCH.borrow(cs).set(Latch {
                currents: m.currents,
                angle: m.angle,
                v_bus_v: m.v_bus_v,
                stage_temperature_c: m.stage_temperature_c,
                valid: true,
                fresh: true,
            });
        }
    });
}

/// The physics: one PWM period of the plant, then the "ADC" interrupt.
#[interrupt]
fn TIM2() {
    // SAFETY: TIM2 is used only by this board module; clearing UIF
    // (rc_w0, RM0090 18.4.5) has no other effect.
    let tim = unsafe { &*pac::TIM2::ptr() };
    tim.sr().write(|w| w.uif().clear_bit());
    step_physics();
    cortex_m::peripheral::NVIC::pend(CURRENT_IRQ);
    // The instrument port every 20 periods (1 ms at 20 kHz): QEMU's
    // register accesses are slow, and a request a millisecond late is
    // still a bench's reaction time.
    if INSTRUMENT_TICK
        .fetch_add(1, Ordering::Relaxed)
        .is_multiple_of(INSTRUMENT_EVERY)
    {
        instrument::poll();
    }
}

/// Periods between two polls of the instrument port.
const INSTRUMENT_EVERY: u32 = 20;
/// Periods counted for [`INSTRUMENT_EVERY`].
static INSTRUMENT_TICK: AtomicU32 = AtomicU32::new(0);

/// The instrument port (USART1), once `init` has set it up.
static INSTRUMENT: Mutex<RefCell<Option<instrument::Port>>> = Mutex::new(RefCell::new(None));

/// The emulated bench's instrument port (see
/// [`crate::logic::instrument`]): requests from the host on USART1, each
/// acted on the simulated world and answered, polled by the
/// physics (TIM2) every [`INSTRUMENT_EVERY`] periods. The firmware never
/// touches it.
mod instrument {
    use super::sim::{self, SimFault};
    use super::{free, CommandSerial, INSTRUMENT};
    use crate::logic::instrument::{LineBuf, Reply, Request};
    use core::fmt::Write as _;

    /// The UART and its line buffer.
    pub(super) struct Port {
        serial: CommandSerial,
        line: LineBuf,
    }

    impl Port {
        pub(super) fn new(serial: CommandSerial) -> Self {
            Self {
                serial,
                line: LineBuf::new(),
            }
        }
    }

    /// Take what arrived; act on complete requests (at most a few bytes a
    /// period: QEMU hands one byte per empty receive register).
    pub(super) fn poll() {
        let mut panic = false;
        free(|cs| {
            let mut cell = INSTRUMENT.borrow(cs).borrow_mut();
            let Some(p) = cell.as_mut() else {
                return;
            };
            p.serial.on_interrupt();
            while let Some(b) = p.serial.read_byte() {
                let Some(line) = p.line.push(b) else {
                    continue;
                };
                let mut reply = Reply::new();
                match Request::parse(line) {
                    Some(Request::Panic) => panic = true,
                    Some(r) => act(r, &mut reply),
                    None => {
                        let _ = reply.write_str("error");
                    }
                }
                let _ = reply.write_str("\n");
                p.serial.write(reply.as_bytes());
            }
            p.serial.on_interrupt();
        });
        if panic {
            // The emulated hardware fails inside its own interrupt: the
            // firmware's panic handler must leave the bridge safe.
            #[allow(clippy::panic)]
            {
                panic!("forced panic (instrument port)");
            }
        }
    }

    /// One request on the simulated world; its reply into `reply`.
    fn act(r: Request, reply: &mut Reply) {
        let ok = match r {
            Request::Load(nm) => {
                sim::set_load_torque_nm(nm);
                true
            }
            Request::Jump(n) => {
                sim::inject(SimFault::EncoderJump(n));
                true
            }
            Request::Stuck => {
                sim::inject(SimFault::EncoderStuck);
                true
            }
            Request::Clear => {
                sim::inject(SimFault::None);
                true
            }
            Request::Break => {
                sim::raise_break();
                true
            }
            Request::Watch(w) => {
                sim::start_stop_watch(w);
                true
            }
            Request::Truth => {
                let t = sim::truth();
                let _ = write!(
                    reply,
                    "truth {} {} {} {} {} {} {} {} {} {}",
                    t.time_s,
                    t.omega_m_rad_s,
                    t.position_rad,
                    u8::from(t.bridge_enabled),
                    u8::from(sim::outputs_on()),
                    u8::from(sim::break_latched()),
                    sim::on_periods_after_break(),
                    t.periods,
                    t.v_bus_v,
                    t.brake_energy_j
                );
                false
            }
            Request::WatchRead => {
                match sim::stop_watch() {
                    Some(w) => {
                        let _ = write!(
                            reply,
                            "watch {} {} {} {} {}",
                            w.peak_v_bus_v,
                            w.settle_periods(),
                            w.armed_at_period,
                            w.brake_energy_at_arm_j,
                            w.kinetic_energy_at_arm_j
                        );
                    }
                    None => {
                        let _ = reply.write_str("watch none");
                    }
                }
                false
            }
            Request::Panic => false,
        };
        if ok {
            let _ = reply.write_str("ok");
        }
    }
}

/// After a panic (the firmware's handler has turned the bridge off and
/// logged): let the simulated world run on for 20 periods, then end the
/// emulation with the verdict as QEMU's exit status: 3 when the bridge is
/// off and stayed off (the safe state), 2 otherwise.
pub fn after_panic() -> ! {
    // The physics may be the code that panicked (TIM2 cannot preempt
    // itself): step it by hand.
    for _ in 0..20 {
        step_physics();
    }
    let t = sim::truth();
    let safe = !sim::outputs_on() && !t.bridge_enabled && sim::emergency_latched();
    if safe {
        defmt::info!("panic: bridge in the safe state (20 periods later)");
        sim::exit(3)
    } else {
        defmt::error!("panic: bridge NOT in the safe state");
        sim::exit(2)
    }
}

/// After a HardFault (bridge off, logged): end the emulation, exit status 4.
pub fn after_hardfault() -> ! {
    sim::exit(4)
}

/// The test harness's handle on the simulated world.
pub mod sim {
    use super::{
        free, Ordering, BREAK_LATCH, BRIDGE_ON, EMERGENCY, ON_AFTER_BREAK, ON_PERIODS, WORLD,
    };
    use foc_plant::plant::{EncoderFault, Phase, PhaseShort, Plant};

    /// A fault to inject into the plant.
    #[derive(Clone, Copy, Debug, PartialEq)]
    pub enum SimFault {
        /// Remove every injected fault.
        None,
        /// Phase A shorted to phase B at the motor terminals.
        PhaseShort,
        /// Phase B's current channel reads NaN.
        NanCurrent,
        /// The encoder jumps by this many counts.
        EncoderJump(i32),
        /// The encoder freezes.
        EncoderStuck,
        /// The supply drops by this many volts.
        BusSag(f32),
    }

    /// The plant's true state (not what the sensors say).
    #[derive(Clone, Copy, Debug, Default, PartialEq)]
    pub struct Truth {
        /// Mechanical speed [rad/s].
        pub omega_m_rad_s: f32,
        /// Mechanical position, unwrapped [rad].
        pub position_rad: f32,
        /// Mechanical angle of the rotor, wrapped to `[0, 2 pi)` [rad] (the
        /// truth behind the sensor: no mounting offset, no quantisation).
        pub theta_m_rad: f32,
        /// d and q currents [A].
        pub id_a: f32,
        /// q current [A].
        pub iq_a: f32,
        /// Shaft torque [N m].
        pub torque_nm: f32,
        /// True when the bridge conducted during the last period.
        pub bridge_enabled: bool,
        /// Simulated PWM periods so far.
        pub periods: u64,
        /// Simulated time [s].
        pub time_s: f32,
        /// Bus voltage at the end of the last period [V] (the source's
        /// voltage behind its resistance without a DC link).
        pub v_bus_v: f32,
        /// Energy dissipated in the brake resistor since reset [J] (0
        /// without one).
        pub brake_energy_j: f32,
    }

    /// What the physics records every period once armed by
    /// [`start_stop_watch`]: a mission ticks every 400 periods (20 ms) and
    /// would miss a bus-voltage peak, or time a stop only to its tick.
    #[derive(Clone, Copy, Debug, Default, PartialEq)]
    pub struct StopWatch {
        /// Speed bound [rad/s] (mechanical, magnitude).
        pub speed_bound_rad_s: f32,
        /// Period at which the watch was armed.
        pub armed_at_period: u64,
        /// Highest bus voltage at the end of a period since armed [V].
        pub peak_v_bus_v: f32,
        /// Last period (since reset) at which the true speed was at or
        /// above the bound; `None`: below it since armed.
        pub last_above_period: Option<u64>,
        /// Brake-resistor energy when armed [J].
        pub brake_energy_at_arm_j: f32,
        /// Kinetic energy of the rotor when armed [J].
        pub kinetic_energy_at_arm_j: f32,
    }

    impl StopWatch {
        fn new(plant: &Plant, speed_bound_rad_s: f32) -> Self {
            let mut w = Self {
                speed_bound_rad_s,
                armed_at_period: plant.periods(),
                peak_v_bus_v: plant.v_bus_v(),
                last_above_period: None,
                brake_energy_at_arm_j: plant.brake_energy_j(),
                kinetic_energy_at_arm_j: plant.kinetic_energy_j(),
            };
            w.record(plant);
            w
        }

        /// One period of the physics.
        pub(super) fn record(&mut self, plant: &Plant) {
            self.peak_v_bus_v = self.peak_v_bus_v.max(plant.v_bus_v());
            if plant.omega_m_rad_s().abs() >= self.speed_bound_rad_s {
                self.last_above_period = Some(plant.periods());
            }
        }

        /// Periods from arming until the speed fell below the bound for
        /// the last time so far (0: below it since armed).
        pub fn settle_periods(&self) -> u64 {
            self.last_above_period
                .map_or(0, |p| p + 1 - self.armed_at_period)
        }
    }

    /// Arm (or re-arm) the stop watch: from the next period on, the physics
    /// records the peak bus voltage and the last period at which the true
    /// speed's magnitude was at or above `speed_bound_rad_s`.
    pub fn start_stop_watch(speed_bound_rad_s: f32) {
        free(|cs| {
            if let Some(w) = WORLD.borrow(cs).borrow_mut().as_mut() {
                w.watch = Some(StopWatch::new(&w.plant, speed_bound_rad_s));
            }
        });
    }

    /// The stop watch's record (`None` before [`start_stop_watch`]).
    pub fn stop_watch() -> Option<StopWatch> {
        free(|cs| WORLD.borrow(cs).borrow().as_ref().and_then(|w| w.watch))
    }

    /// Load torque opposing positive rotation [N m].
    pub fn set_load_torque_nm(nm: f32) {
        free(|cs| {
            if let Some(w) = WORLD.borrow(cs).borrow_mut().as_mut() {
                w.load_nm = nm;
            }
        });
    }

    /// Inject (or, with [`SimFault::None`], remove) a fault.
    pub fn inject(f: SimFault) {
        free(|cs| {
            if let Some(w) = WORLD.borrow(cs).borrow_mut().as_mut() {
                let faults = w.plant.faults_mut();
                match f {
                    SimFault::None => *faults = Default::default(),
                    SimFault::PhaseShort => {
                        faults.phase_short = Some(PhaseShort {
                            a: Phase::A,
                            b: Phase::B,
                            r_ohm: 0.01,
                        })
                    }
                    SimFault::NanCurrent => faults.nan_current = Some(Phase::B),
                    SimFault::EncoderJump(n) => faults.encoder = EncoderFault::Jump(n),
                    SimFault::EncoderStuck => faults.encoder = EncoderFault::Stuck,
                    SimFault::BusSag(v) => faults.bus_sag_v = v as _,
                }
            }
        });
    }

    /// The true state.
    pub fn truth() -> Truth {
        free(|cs| {
            WORLD
                .borrow(cs)
                .borrow()
                .as_ref()
                .map(|w| Truth {
                    omega_m_rad_s: w.plant.omega_m_rad_s(),
                    position_rad: w.plant.position_rad(),
                    theta_m_rad: w.plant.theta_m_rad(),
                    id_a: w.plant.id_a(),
                    iq_a: w.plant.iq_a(),
                    torque_nm: w.plant.torque_nm(),
                    bridge_enabled: w.plant.bridge_enabled(),
                    periods: w.plant.periods(),
                    time_s: w.plant.time_s() as f32,
                    v_bus_v: w.plant.v_bus_v(),
                    brake_energy_j: w.plant.brake_energy_j(),
                })
                .unwrap_or_default()
        })
    }

    /// Advance the plant one period by hand (for benchmarks that run with
    /// TIM2 masked) and latch a fresh sample; does not pend the ADC task.
    pub fn step_physics() {
        super::step_physics();
    }

    /// Stop the period source (TIM2 interrupt masked), for benchmarks.
    pub fn stop_period_source() {
        cortex_m::peripheral::NVIC::mask(crate::pac::Interrupt::TIM2);
    }

    /// True when the bridge outputs are commanded on.
    pub fn outputs_on() -> bool {
        BRIDGE_ON.load(Ordering::SeqCst)
    }

    /// Periods the bridge conducted since reset (counted by the physics).
    pub fn on_periods() -> u32 {
        ON_PERIODS.load(Ordering::SeqCst)
    }

    /// End the emulation with `code` as QEMU's exit status (semihosting
    /// `SYS_EXIT_EXTENDED`, reason `ADP_Stopped_ApplicationExit`; QEMU runs
    /// with semihosting enabled).
    pub fn exit(code: u32) -> ! {
        const SYS_EXIT_EXTENDED: usize = 0x20;
        const ADP_STOPPED_APPLICATION_EXIT: usize = 0x20026;
        // SAFETY: a semihosting call with a valid two-word parameter block.
        unsafe {
            cortex_m_semihosting::syscall(
                SYS_EXIT_EXTENDED,
                &[ADP_STOPPED_APPLICATION_EXIT, code as usize],
            );
        }
        loop {
            cortex_m::asm::bkpt();
        }
    }

    /// True once `emergency_disable` has run.
    pub fn emergency_latched() -> bool {
        EMERGENCY.load(Ordering::SeqCst)
    }

    /// Raise the timer break: pend `TIM1_BRK_TIM9`, whose handler (the
    /// firmware's `bridge_break`) turns the outputs off and latches.
    pub fn raise_break() {
        cortex_m::peripheral::NVIC::pend(crate::pac::Interrupt::TIM1_BRK_TIM9);
        cortex_m::asm::dsb();
        cortex_m::asm::isb();
    }

    /// True while the break latch holds.
    pub fn break_latched() -> bool {
        BREAK_LATCH.load(Ordering::SeqCst)
    }

    /// Periods the bridge conducted with the break latch set (0 expected).
    pub fn on_periods_after_break() -> u32 {
        ON_AFTER_BREAK.load(Ordering::SeqCst)
    }
}
