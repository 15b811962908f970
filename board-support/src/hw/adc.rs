//! ADC1: phase currents by injected conversions triggered by TIM1, bus
//! voltage by software-started regular conversions.
//!
//! The HAL has no injected-conversion API, so this is register-level (RM0090
//! section 13 / RM0390 section 13 / RM0368 section 11, ADC):
//!
//! - `ADC_CCR.ADCPRE = 01`: ADCCLK = PCLK2 / 4 (21 MHz at PCLK2 = 84 MHz,
//!   22.5 MHz at 90 MHz; the limit is 36 MHz);
//! - `CR1.SCAN = 1` (needed for a sequence), `JEOCIE = 1`, 12 bits;
//! - `CR2.JEXTSEL = 0001` (TIM1_TRGO), `JEXTEN = 01` (rising edge), `ADON`;
//! - `JSQR`: with `JL = n - 1` the sequence occupies the *last* n `JSQx`
//!   fields (RM0090 13.13.12); results land in `JDR1..n` in order;
//! - the regular group (one channel, `SQ1`) is started by `SWSTART`;
//!   a trigger of the injected group interrupts it and it resumes after.
//!
//! `read_currents` must run after `JEOC` (the `CURRENT_IRQ` handler).
//!
//! # Bus voltage and power-stage thermistor (regular group)
//!
//! [`RegularBus`] converts one regular channel at a time (`SQR1.L = 0`, one
//! conversion per `SWSTART`, `CR2.EOCS = 1`: `EOC` after each regular
//! conversion; RM0090 13.3.3 channel selection, 13.3.4 single conversion
//! mode, 13.13.9 SQR1, 13.13.11 SQR3, 13.13.1 SR). Without a thermistor
//! `SQ1` always holds the bus channel, as before. With one
//! ([`RegularBus::with_thermistor`]) each completed conversion is stored as
//! the newest value of the channel that was in `SQ1`, and the *other*
//! channel is written to `SQ1` before the next `SWSTART`: VBUS and the
//! thermistor alternate, each refreshed every other read (the firmware
//! reads once per PWM period: the bus voltage is at most two periods old).
//! `SQR3` is written only between `EOC` and `SWSTART`, while the regular
//! group is idle, so a sequence change never lands in the middle of a
//! conversion. The thermistor's sample time is set by
//! [`set_regular_sample_time`].

use crate::logic::scaling::{CurrentScale, VoltageScale};
use crate::logic::thermistor::{NtcDivider, ThermistorError};
use crate::pac;
use foc_core::frames::Abc;
use foc_core::hal::{BusVoltage, CurrentSense, PhaseCurrents};

/// ADC sample time codes (`SMPx`), in ADC clock cycles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleTime {
    /// 3 cycles.
    Cycles3 = 0,
    /// 15 cycles.
    Cycles15 = 1,
    /// 28 cycles.
    Cycles28 = 2,
    /// 56 cycles.
    Cycles56 = 3,
    /// 84 cycles.
    Cycles84 = 4,
    /// 112 cycles.
    Cycles112 = 5,
    /// 144 cycles.
    Cycles144 = 6,
    /// 480 cycles.
    Cycles480 = 7,
}

/// Which phases the shunts measure.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shunts {
    /// Three shunts: channels for A, B, C.
    Three([u8; 3]),
    /// Two shunts on phases B and C (A = -B - C): channels for B, C.
    BC([u8; 2]),
}

/// Current-sense error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "_hal", derive(defmt::Format))]
pub enum AdcError {
    /// No new injected sample since the last read (`JEOC` clear).
    NotReady,
}

/// Phase currents from ADC1 injected conversions.
pub struct InjectedCurrents {
    shunts: Shunts,
    scale: CurrentScale,
    offsets: Abc,
    regs: Adc1Regs,
}

/// Where a driver finds ADC1's registers: the peripheral (RM0090 13.13),
/// or, for the instruction counts under QEMU (which models no injected
/// group), a block of RAM laid out like it (`with_registers`). Reaching
/// them through this pointer costs the same instructions as through the
/// PAC's constant address (one load of the base either way).
#[derive(Clone, Copy)]
struct Adc1Regs(*const pac::adc1::RegisterBlock);

// SAFETY: the pointer is ADC1's fixed address (or a `'static` block the
// bench owns); the drivers holding it are the only users of the registers
// they touch, as with the PAC's `ADC1` token, which is `Send`.
unsafe impl Send for Adc1Regs {}

impl Adc1Regs {
    const PERIPHERAL: Self = Self(pac::ADC1::ptr());

    #[inline(always)]
    fn get(&self) -> &pac::adc1::RegisterBlock {
        // SAFETY: see the type's docs: a valid register block for 'static.
        unsafe { &*self.0 }
    }
}

fn set_sample_time(adc: &pac::adc1::RegisterBlock, ch: u8, smp: SampleTime) {
    let s = smp as u32;
    // SAFETY: SMPR1 holds channels 10..18, SMPR2 0..9, 3 bits each
    // (RM0090 13.13.4-5); every 3-bit value is a valid sample time.
    unsafe {
        if ch >= 10 {
            let sh = 3 * (ch as u32 - 10);
            adc.smpr1()
                .modify(|r, w| w.bits((r.bits() & !(7 << sh)) | (s << sh)));
        } else {
            let sh = 3 * ch as u32;
            adc.smpr2()
                .modify(|r, w| w.bits((r.bits() & !(7 << sh)) | (s << sh)));
        }
    }
}

/// Sample time of one more regular channel (e.g. a thermistor) of an ADC
/// set up by [`setup_adc1`] (`SMPRx`, RM0090 13.13.4-5).
pub fn set_regular_sample_time(adc: &pac::ADC1, channel: u8, smp: SampleTime) {
    set_sample_time(adc, channel, smp);
}

/// Configure ADC1 (clock already enabled and reset by the caller, analog
/// pins already in analog mode): injected `channels` triggered by TIM1 TRGO,
/// one regular channel `bus_channel`, and start the first bus conversion.
pub fn setup_adc1(
    adc: &pac::ADC1,
    common: &pac::ADC_COMMON,
    injected: &[u8],
    current_smp: SampleTime,
    bus_channel: u8,
    bus_smp: SampleTime,
) {
    let n = injected.len().clamp(1, 4);
    // SAFETY (whole block): ADC1 / ADC common registers, RM0090 13.13; all
    // `bits` values are in range (channels < 19, JL < 4, prescaler code).
    unsafe {
        common.ccr().modify(|_, w| w.adcpre().bits(0b01));
        adc.cr2().write(|w| w.adon().clear_bit());
        adc.cr1()
            .write(|w| w.scan().set_bit().jeocie().set_bit().res().bits(0b00));
        for ch in injected.iter().take(n) {
            set_sample_time(adc, *ch, current_smp);
        }
        set_sample_time(adc, bus_channel, bus_smp);
        // Injected sequence in the last n JSQ fields (JSQ(4-n+1)..JSQ4).
        let mut jsqr: u32 = ((n as u32) - 1) << 20;
        for (i, ch) in injected.iter().take(n).enumerate() {
            let field = 4 - n + i; // 0-based JSQ index
            jsqr |= ((*ch as u32) & 0x1F) << (5 * field);
        }
        adc.jsqr().write(|w| w.bits(jsqr));
        // Regular: one conversion, channel in SQ1.
        adc.sqr1().write(|w| w.l().bits(0));
        adc.sqr3().write(|w| w.sq1().bits(bus_channel & 0x1F));
        adc.cr2().write(|w| {
            w.adon().set_bit().eocs().set_bit();
            w.jextsel().bits(0b0001).jexten().bits(0b01)
        });
    }
    // t_STAB after ADON (RM0090 13.3.6): a few microseconds; the caller's
    // later set-up takes longer, and the first result is discarded anyway.
    cortex_m::asm::delay(1_000);
    // SAFETY: clear the flags (rc_w0), start the first regular conversion.
    unsafe {
        adc.sr().write(|w| w.bits(0));
        adc.cr2().modify(|_, w| w.swstart().set_bit());
    }
}

impl InjectedCurrents {
    /// Phase currents from an ADC set up by [`setup_adc1`] with the shunt
    /// channels in the order of `shunts`.
    pub const fn new(shunts: Shunts, scale: CurrentScale) -> Self {
        Self {
            shunts,
            scale,
            offsets: Abc::new(0.0, 0.0, 0.0),
            regs: Adc1Regs::PERIPHERAL,
        }
    }

    /// The same driver on a RAM copy of ADC1's registers (the emulated
    /// board's instruction counts of a real board's register path).
    ///
    /// # Safety
    /// `regs` must stay valid for as long as the driver is used, and be
    /// used only by ADC1 drivers (as ADC1 itself is shared by
    /// [`InjectedCurrents`] and [`RegularBus`]).
    #[cfg(feature = "qemu")]
    pub unsafe fn with_registers(mut self, regs: *const pac::adc1::RegisterBlock) -> Self {
        self.regs = Adc1Regs(regs);
        self
    }

    /// Raw `JDR1..3` values (for diagnostics / calibration).
    pub fn raw(&self) -> [u16; 3] {
        // Read-only access to ADC1 JDRx (RM0090 13.13.10).
        let adc = self.regs.get();
        [
            adc.jdr(0).read().jdata().bits(),
            adc.jdr(1).read().jdata().bits(),
            adc.jdr(2).read().jdata().bits(),
        ]
    }

    /// The conversion from counts to amperes.
    pub const fn scale(&self) -> &CurrentScale {
        &self.scale
    }
}

impl CurrentSense for InjectedCurrents {
    type Error = AdcError;

    fn read_currents(&mut self) -> Result<PhaseCurrents, AdcError> {
        // SAFETY: ADC1 SR / JDRx (RM0090 13.13.1, 13.13.10). SR bits are
        // rc_w0 and the PAC's write() puts 1 in the untouched ones, so only
        // JEOC (and JSTRT) are cleared, never the regular group's EOC.
        let adc = self.regs.get();
        if adc.sr().read().jeoc().bit_is_clear() {
            return Err(AdcError::NotReady);
        }
        let r = self.raw();
        adc.sr().write(|w| w.jeoc().clear_bit().jstrt().clear_bit());
        let s = &self.scale;
        Ok(match self.shunts {
            Shunts::Three(_) => PhaseCurrents::ThreePhase(Abc::new(
                s.amps(r[0]) - self.offsets.a,
                s.amps(r[1]) - self.offsets.b,
                s.amps(r[2]) - self.offsets.c,
            )),
            Shunts::BC(_) => {
                let b = s.amps(r[0]) - self.offsets.b;
                let c = s.amps(r[1]) - self.offsets.c;
                // Phase A derived; foc-core's TwoPhase derives c = -a - b,
                // which gives back the measured c.
                PhaseCurrents::TwoPhase {
                    a_a: -b - c,
                    b_a: b,
                }
            }
        })
    }

    fn offsets_a(&self) -> Abc {
        self.offsets
    }

    fn set_offsets_a(&mut self, offsets: Abc) {
        self.offsets = match self.shunts {
            Shunts::Three(_) => offsets,
            // B and C are measured; A has no offset of its own.
            Shunts::BC(_) => Abc::new(0.0, offsets.b, offsets.c),
        };
    }
}

/// Bus-voltage (or thermistor) error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "_hal", derive(defmt::Format))]
pub enum BusError {
    /// No conversion has completed yet.
    NotReady,
    /// The thermistor reads open or shorted (not a temperature).
    Thermistor(ThermistorError),
}

/// A power-stage thermistor on a regular ADC channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Thermistor {
    /// ADC1 channel (0..=18).
    pub channel: u8,
    /// Counts to deg C, with open / short detection.
    pub divider: NtcDivider,
}

/// Bus voltage (and, where the board has one, the power-stage thermistor)
/// from the ADC1 regular group, one software-started conversion at a time:
/// each [`BusVoltage::read_bus_voltage_v`] takes the newest completed
/// result and starts the next conversion (module docs).
pub struct RegularBus {
    scale: VoltageScale,
    bus_channel: u8,
    thermistor: Option<Thermistor>,
    /// The channel now in `SQ1` (being converted or done) is the
    /// thermistor's.
    converting_thermistor: bool,
    last_v: Option<f32>,
    last_thermistor_counts: Option<u16>,
    regs: Adc1Regs,
}

impl RegularBus {
    /// Bus voltage reader (ADC set up by [`setup_adc1`], which starts the
    /// first conversion of `bus_channel`).
    pub const fn new(scale: VoltageScale, bus_channel: u8) -> Self {
        Self {
            scale,
            bus_channel,
            thermistor: None,
            converting_thermistor: false,
            last_v: None,
            last_thermistor_counts: None,
            regs: Adc1Regs::PERIPHERAL,
        }
    }

    /// The same reader on a RAM copy of ADC1's registers (see
    /// [`InjectedCurrents::with_registers`]).
    ///
    /// # Safety
    /// As [`InjectedCurrents::with_registers`].
    #[cfg(feature = "qemu")]
    pub unsafe fn with_registers(mut self, regs: *const pac::adc1::RegisterBlock) -> Self {
        self.regs = Adc1Regs(regs);
        self
    }

    /// Also read `thermistor`, alternating with the bus channel (set its
    /// sample time with [`set_regular_sample_time`]).
    pub const fn with_thermistor(mut self, thermistor: Thermistor) -> Self {
        self.thermistor = Some(thermistor);
        self
    }

    /// Newest raw thermistor reading (diagnostics).
    pub const fn thermistor_counts(&self) -> Option<u16> {
        self.last_thermistor_counts
    }
}

impl BusVoltage for RegularBus {
    type Error = BusError;

    fn read_bus_voltage_v(&mut self) -> Result<f32, BusError> {
        // SAFETY: ADC1 SR/DR/CR2/SQR3 (RM0090 13.13.1-3, 13.13.11,
        // 13.13.14). Reading DR clears EOC; SWSTART and SQR3 are only
        // written here (after init); CR2 is not written by the current-sense
        // ISR; SQR3 is written while the regular group is idle (after EOC,
        // before SWSTART); every channel written is < 19.
        let adc = self.regs.get();
        if adc.sr().read().eoc().bit_is_set() {
            let counts = adc.dr().read().data().bits();
            if self.converting_thermistor {
                self.last_thermistor_counts = Some(counts);
            } else {
                self.last_v = Some(self.scale.volts(counts));
            }
            if let Some(t) = self.thermistor {
                self.converting_thermistor = !self.converting_thermistor;
                let ch = if self.converting_thermistor {
                    t.channel
                } else {
                    self.bus_channel
                };
                adc.sqr3().write(|w| unsafe { w.sq1().bits(ch & 0x1F) });
            }
            adc.cr2().modify(|_, w| w.swstart().set_bit());
        } else if adc.sr().read().ovr().bit_is_set() {
            // Overrun (RM0090 13.8.2): conversions stopped; start the same
            // channel again.
            adc.sr().write(|w| w.ovr().clear_bit());
            adc.cr2().modify(|_, w| w.swstart().set_bit());
        }
        self.last_v.ok_or(BusError::NotReady)
    }

    fn read_temperature_c(&mut self) -> Option<Result<f32, BusError>> {
        let t = self.thermistor?;
        Some(match self.last_thermistor_counts {
            None => Err(BusError::NotReady),
            Some(c) => t.divider.temperature_c(c, 12).map_err(BusError::Thermistor),
        })
    }
}
