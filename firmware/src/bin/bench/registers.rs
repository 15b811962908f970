//! A real board's register path, counted under QEMU: the drivers of the
//! NUCLEO-F446RE + X-NUCLEO-IHM07M1 (`board_support::hw`, the shield's
//! scaling) doing one period's reads and writes. QEMU's STM32F405 models
//! neither ADC1's injected group nor TIM1, so the ADC and PWM drivers run
//! on RAM blocks laid out like those peripherals (`with_registers`,
//! `for_bench`), their flags set before each timed call; the encoder reads
//! QEMU's modelled TIM3 (the shield's board uses TIM2, here the emulated
//! board's period source; same code, another base address).

use super::{measure, report};
use board_support::boards::ihm07m1_analog as shield;
use board_support::hw::adc::{AdcError, BusError, InjectedCurrents, RegularBus, Shunts};
use board_support::hw::angle::{AngleError, AngleInput, QuadEncoder};
use board_support::hw::pwm::{PwmConfig, Tim1Pwm, Topology};
use board_support::pac;
use core::hint::black_box;
use core::ptr::{addr_of_mut, write_volatile};
use foc_core::angle::MechanicalAngle;
use foc_core::control::{io, BridgeCommand, Fault};
use foc_core::hal::{AngleSensor, BusVoltage, CurrentSense, PhaseCurrents};

/// ADC1 and TIM1 stand-ins (32 words each covers both register blocks).
static mut ADC_RAM: [u32; 32] = [0; 32];
static mut TIM_RAM: [u32; 32] = [0; 32];

/// ADC_SR bits (RM0090 13.13.1): EOC (regular), JEOC (injected).
const SR_EOC: u32 = 1 << 1;
const SR_JEOC: u32 = 1 << 2;
/// TIM1_BDTR.MOE (RM0090 17.4.18): the bridge is on.
const BDTR_MOE: u32 = 1 << 15;

fn adc_word(offset: usize) -> *mut u32 {
    // SAFETY: within the 32-word static; the bench is single-threaded.
    unsafe { addr_of_mut!(ADC_RAM).cast::<u32>().add(offset / 4) }
}

/// Measures the shield's per-period register path; returns the sum of the
/// items' worst cases.
pub fn measure_real_board(baseline: u32) -> u32 {
    let n = 64;
    let mut sum = 0;
    let adc = adc_word(0) as *const pac::adc1::RegisterBlock;
    // JDR1..3 (0x3C..0x44) and DR (0x4C): mid-scale-ish readings.
    for (off, v) in [(0x3C, 2100), (0x40, 2000), (0x44, 2050), (0x4C, 1500)] {
        // SAFETY: the static's words, nothing else uses them.
        unsafe { write_volatile(adc_word(off), v) };
    }
    // SAFETY: the static outlives the drivers; only they use it.
    let mut currents = unsafe {
        InjectedCurrents::new(
            Shunts::Three(shield::CURRENT_CHANNELS),
            shield::CURRENT_SCALE,
        )
        .with_registers(adc)
    };
    let set_jeoc = &mut |_: u32| unsafe { write_volatile(adc_word(0), SR_JEOC | SR_EOC) };
    let s = measure(baseline, n, set_jeoc, &mut |_| {
        black_box(currents_part(&mut currents)).ok();
    });
    report(
        "real board: phase currents (IHM07M1, InjectedCurrents::read_currents)",
        s,
    );
    sum += s.max;

    // SAFETY: as above.
    let mut bus = unsafe {
        RegularBus::new(shield::BUS_SCALE, shield::BUS_CHANNEL)
            .with_thermistor(shield::THERMISTOR)
            .with_registers(adc)
    };
    let set_eoc = &mut |_: u32| unsafe { write_volatile(adc_word(0), SR_EOC) };
    let s = measure(baseline, n, set_eoc, &mut |_| {
        let _ = black_box(bus_part(&mut bus));
    });
    report(
        "real board: bus voltage and thermistor (RegularBus, alternating)",
        s,
    );
    sum += s.max;

    let mut angle = AngleInput::Encoder(QuadEncoder::<pac::TIM3>::new(4096, false));
    let s = measure(baseline, n, &mut |_| {}, &mut |_| {
        black_box(angle_part(&mut angle)).ok();
    });
    report(
        "real board: encoder (QuadEncoder::read_angle, QEMU's TIM3)",
        s,
    );
    sum += s.max;

    // SAFETY: BDTR at 0x44 of the TIM1 stand-in; MOE set: the bridge is on.
    let tim = unsafe {
        let base = addr_of_mut!(TIM_RAM).cast::<u32>();
        write_volatile(base.add(0x44 / 4), BDTR_MOE);
        base as *const pac::tim1::RegisterBlock
    };
    let cfg = PwmConfig {
        frequency_hz: 20_000,
        topology: Topology::ThreePwm,
        break_input: None,
        enable_pins: &[],
        enable_pins_in_disable: true,
    };
    // SAFETY: TIM1 is not used by the emulated board; the stand-in
    // outlives the driver.
    let mut pwm = unsafe { Tim1Pwm::for_bench(pac::TIM1::steal(), tim, 4200, cfg) };
    let s = measure(baseline, n, &mut |_| {}, &mut |k| {
        let x = 0.3 + 0.001 * k as f32;
        let _ = black_box(pwm_part(&mut pwm, black_box([x, 0.5, 0.7 - x])));
    });
    report("real board: PWM write (Tim1Pwm via io::apply)", s);
    sum + s.max
}

// Called through functions of their own (see `breakdown`).

#[inline(never)]
fn currents_part(c: &mut InjectedCurrents) -> Result<PhaseCurrents, AdcError> {
    c.read_currents()
}

#[inline(never)]
fn bus_part(b: &mut RegularBus) -> (Result<f32, BusError>, Option<Result<f32, BusError>>) {
    (b.read_bus_voltage_v(), b.read_temperature_c())
}

#[inline(never)]
fn angle_part(a: &mut AngleInput<pac::TIM3>) -> Result<MechanicalAngle, AngleError> {
    a.read_angle()
}

#[inline(never)]
fn pwm_part(pwm: &mut Tim1Pwm, duties: [f32; 3]) -> Result<(), Fault> {
    io::apply(pwm, BridgeCommand::Duties(duties))
}
