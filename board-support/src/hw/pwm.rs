//! TIM1 centre-aligned three-phase PWM with a safe state.
//!
//! Set-up (RM0090 section 17 / RM0390 section 16 / RM0368 section 12, TIM1
//! advanced-control timer):
//!
//! - `CR1.CMS = 01` centre-aligned mode 1, `ARPE = 1`, `CKD = 00`
//!   (`t_DTS` = timer clock); `PSC`/`ARR` from
//!   [`crate::logic::pwm_timing::centre_aligned`];
//! - channels 1..3 in PWM mode 1 with preload (`OCxM = 110`, `OCxPE = 1`):
//!   the high side conducts while `CNT < CCRx`, so duty = `CCRx / ARR`;
//! - channel 4 in PWM mode 2 with `CCR4 = ARR - 1` and `CR2.MMS = 111`
//!   (`TRGO = OC4REF`): a rising `TRGO` edge just before the counter peak,
//!   where every low-side switch conducts, triggers the ADC injected group;
//! - complementary outputs with dead time `BDTR.DTG` for 6-PWM boards, or
//!   only CH1..3 plus enable pins (3-PWM + EN) for drivers with their own
//!   dead time;
//! - `BDTR.OSSI = OSSR = 1`, `OISx = OISxN = 0`: with `MOE = 0` every output
//!   is driven to its idle level, low = switch off; `AOE = 0` (only software
//!   sets `MOE`); `BKE`/`BKP` where the board wires BKIN; `LOCK = 1` freezes
//!   DTG, BKE, BKP, AOE, OISx after set-up;
//! - `DBGMCU_APB2_FZ.DBG_TIM1_STOP = 1`: a debugger halt stops TIM1 and
//!   disables its outputs as if `MOE` were cleared (RM0090 17.3.20).
//!
//! The active short circuit is `PwmDriver::short_circuit`'s default
//! (`CCRx = 0`, then `enable`), not overridden: in centre-aligned PWM
//! mode 1 a compare of 0 holds `OCxREF` low for the whole period (RM0090
//! 17.3.10, RM0390 16.3.10, RM0368 12.3.10, figure "Center-aligned PWM
//! waveforms (ARR=8)": `CCRx = 0`, `OCxREF` '0'), so every high side stays
//! off and every low side on, on 6-PWM as `OCxN`, the complement of
//! `OCxREF` out of the dead-time generator (17.3.11), on 3-PWM + EN as IN
//! low with EN high (the L6230's low side), from the next update event
//! like any duty (entered with `MOE = 0`, the last duties run until then:
//! at most half a period).

use crate::hw::PinId;
use crate::logic::dead_time::{encode_dead_time, DeadTime};
use crate::logic::pwm_timing::{centre_aligned, PwmTiming, PwmTimingError};
use crate::pac;
use core::sync::atomic::{AtomicBool, Ordering};
use foc_core::hal::PwmDriver;

/// Polarity of the TIM1 break input.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BreakPolarity {
    /// Break when BKIN is low.
    ActiveLow,
    /// Break when BKIN is high.
    ActiveHigh,
}

/// Output stage topology.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Topology {
    /// CH1..3 and CH1N..3N, hardware dead time of `dead_time_ns`.
    SixPwm {
        /// Dead time [ns] (rounded up by the DTG encoding).
        dead_time_ns: u32,
    },
    /// CH1..3 only; the driver inserts its own dead time.
    ThreePwm,
}

/// Configuration of [`Tim1Pwm`].
#[derive(Clone, Copy, Debug)]
pub struct PwmConfig {
    /// PWM frequency [Hz].
    pub frequency_hz: u32,
    /// 6-PWM with dead time, or 3-PWM.
    pub topology: Topology,
    /// Break input, if the board wires one.
    pub break_input: Option<BreakPolarity>,
    /// Pins that must be high for the bridge to conduct (driven low in the
    /// safe state).
    pub enable_pins: &'static [PinId],
    /// If false, `disable()` leaves the enable pins alone and only
    /// [`safe_state_hard`] drives them low (ODrive: EN_GATE low resets the
    /// DRV8301's SPI configuration).
    pub enable_pins_in_disable: bool,
}

/// Why the bridge was not enabled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "_hal", derive(defmt::Format))]
pub enum PwmError {
    /// The break flag is set: call `break_isr_ack` first (and clear the
    /// cause).
    BreakActive,
    /// A compare value above the period was asked for.
    CompareOutOfRange,
    /// The enable pins are low although they should stay high (gate driver
    /// shut down by `emergency_disable`): re-run `init`.
    GateDriverOff,
}

/// TIM1 centre-aligned PWM, implementing [`PwmDriver`].
pub struct Tim1Pwm {
    arr: u16,
    cfg: PwmConfig,
    dead_time: Option<DeadTime>,
    _tim: pac::TIM1,
    /// TIM1's registers for the per-period accesses (`CCRx`, `BDTR`
    /// read): the peripheral, or the bench's RAM copy (`for_bench`).
    regs: Tim1Regs,
}

/// TIM1's register block (RM0090 17.4), or a RAM block laid out like it
/// for the instruction counts under QEMU (which does not model TIM1).
/// Reaching it through this pointer costs the same instructions as the
/// PAC's constant address (one load of the base either way).
#[derive(Clone, Copy)]
struct Tim1Regs(*const pac::tim1::RegisterBlock);

// SAFETY: TIM1's fixed address (or a `'static` block the bench owns), used
// only by the driver that owns the `TIM1` token.
unsafe impl Send for Tim1Regs {}

impl Tim1Regs {
    #[inline(always)]
    fn get(&self) -> &pac::tim1::RegisterBlock {
        // SAFETY: see the type's docs: a valid register block for 'static.
        unsafe { &*self.0 }
    }
}

/// Timings worked out for a configuration.
pub fn timings(tim_clk_hz: u32, frequency_hz: u32) -> Result<PwmTiming, PwmTimingError> {
    centre_aligned(tim_clk_hz, frequency_hz)
}

impl Tim1Pwm {
    /// Configure TIM1 (clock already enabled and reset by the caller,
    /// output pins already in their alternate function). The outputs are
    /// off (`MOE = 0`, enable pins low) and the counter runs on return.
    pub fn new(tim: pac::TIM1, tim_clk_hz: u32, cfg: PwmConfig) -> Result<Self, PwmTimingError> {
        let t = timings(tim_clk_hz, cfg.frequency_hz)?;
        for p in cfg.enable_pins {
            p.set(false);
        }
        let dead_time = match cfg.topology {
            Topology::SixPwm { dead_time_ns } => Some(encode_dead_time(tim_clk_hz, dead_time_ns)),
            Topology::ThreePwm => None,
        };
        let six = dead_time.is_some();
        // SAFETY (whole block): TIM1 is owned (`tim`); register fields as in
        // RM0090 17.4 (RM0390 16.4, RM0368 12.4). `bits` writes are for
        // multi-bit fields whose every value is valid.
        unsafe {
            write_time_base(&tim, &t);
            write_channels(&tim, t.arr, six);
            write_break_and_dead_time(&tim, dead_time, cfg.break_input);
            start_counter(&tim);
        }
        Ok(Self {
            arr: t.arr,
            cfg,
            dead_time,
            _tim: tim,
            regs: Tim1Regs(pac::TIM1::ptr()),
        })
    }

    /// A driver whose per-period accesses (`set_compare`, `is_enabled`)
    /// go to a RAM copy of TIM1's registers, nothing configured: the
    /// emulated board's instruction counts of a real board's PWM write.
    ///
    /// # Safety
    /// `regs` must stay valid, and be used by nothing else, while the
    /// driver is used; `tim` is stolen by the caller, so nothing else may
    /// use the real TIM1 meanwhile.
    #[cfg(feature = "qemu")]
    pub unsafe fn for_bench(
        tim: pac::TIM1,
        regs: *const pac::tim1::RegisterBlock,
        arr: u16,
        cfg: PwmConfig,
    ) -> Self {
        Self {
            arr,
            cfg,
            dead_time: None,
            _tim: tim,
            regs: Tim1Regs(regs),
        }
    }

    /// The dead time in use (`None` for 3-PWM).
    pub fn dead_time(&self) -> Option<DeadTime> {
        self.dead_time
    }
}

// The steps of `Tim1Pwm::new`, in the order it calls them (the order of
// the register writes matters).
//
// # Safety (each)
// The caller owns TIM1 (`tim`) and has enabled its clock and reset it;
// register fields as in RM0090 17.4 (RM0390 16.4, RM0368 12.4).

/// Counter stopped, then the time base: `PSC`, `ARR` from `t`, `RCR = 0`.
///
/// # Safety
/// See above: TIM1 owned, clocked and reset.
unsafe fn write_time_base(tim: &pac::TIM1, t: &PwmTiming) {
    // Counter stopped while configuring.
    tim.cr1().write(|w| w.cen().clear_bit());
    // BDTR is written exactly once, later (`write_break_and_dead_time`),
    // with every field: its
    // LOCK bits can be written only once after reset (any BDTR
    // write freezes them, RM0090 17.4.18). MOE is 0 after the reset
    // the caller did, so the outputs stay off meanwhile.
    tim.psc().write(|w| w.psc().bits(t.psc));
    tim.arr().write(|w| w.arr().bits(t.arr));
    tim.rcr().write(|w| w.rep().bits(0));
}

/// The channels: CH1..3 in PWM mode 1 at half duty, CH4 in PWM mode 2 at
/// `arr - 1` (the ADC trigger), outputs (complementary ones if `six`)
/// enabled active high, `TRGO = OC4REF`, idle levels low.
///
/// # Safety
/// See above: TIM1 owned, clocked and reset.
unsafe fn write_channels(tim: &pac::TIM1, arr: u16, six: bool) {
    // CH1..3: PWM mode 1 + preload; CH4: PWM mode 2 + preload.
    tim.ccmr1_output().write(|w| {
        w.oc1m().bits(0b110).oc1pe().set_bit();
        w.oc2m().bits(0b110).oc2pe().set_bit()
    });
    tim.ccmr2_output().write(|w| {
        w.oc3m().bits(0b110).oc3pe().set_bit();
        w.oc4m().bits(0b111).oc4pe().set_bit()
    });
    for i in 0..3 {
        tim.ccr(i).write(|w| w.ccr().bits(arr / 2));
    }
    tim.ccr(3).write(|w| w.ccr().bits(arr - 1));
    // Active-high outputs; CC4 has no pin (OC4REF is internal).
    tim.ccer().write(|w| {
        w.cc1e().set_bit().cc2e().set_bit().cc3e().set_bit();
        w.cc1ne().bit(six).cc2ne().bit(six).cc3ne().bit(six)
    });
    // TRGO = OC4REF; idle levels low; no COM preload.
    tim.cr2().write(|w| {
        w.mms().bits(0b111);
        w.ois1().clear_bit().ois2().clear_bit().ois3().clear_bit();
        w.ois1n()
            .clear_bit()
            .ois2n()
            .clear_bit()
            .ois3n()
            .clear_bit()
    });
}

/// `BDTR`, in its first and only write: dead time, off-state selections,
/// `MOE = AOE = 0`, the break input, `LOCK = 1`; then the break interrupt
/// if the board wires a break input.
///
/// # Safety
/// See above: TIM1 owned, clocked and reset; `BDTR` not written since.
unsafe fn write_break_and_dead_time(
    tim: &pac::TIM1,
    dead_time: Option<DeadTime>,
    break_input: Option<BreakPolarity>,
) {
    let dtg = dead_time.map(|d| d.dtg).unwrap_or(0);
    tim.bdtr().write(|w| {
        w.dtg().bits(dtg).ossi().set_bit().ossr().set_bit();
        w.aoe().clear_bit().moe().clear_bit();
        // LOCK level 1 (DTG, BKE, BKP, AOE frozen until reset), in
        // this first and only full write (see above).
        w.lock().bits(0b01);
        match break_input {
            Some(p) => w.bke().set_bit().bkp().bit(p == BreakPolarity::ActiveHigh),
            None => w.bke().clear_bit(),
        }
    });
    if break_input.is_some() {
        tim.dier().write(|w| w.bie().set_bit());
    }
}

/// Preloads loaded and flags cleared, TIM1 frozen on a debugger halt, then
/// the counter started centre-aligned with auto-reload preload.
///
/// # Safety
/// See above: TIM1 owned and configured by the steps before.
unsafe fn start_counter(tim: &pac::TIM1) {
    // Load PSC/ARR/CCR preload registers, then clear the flags.
    tim.egr().write(|w| w.ug().set_bit());
    tim.sr().write(|w| w.bits(0));
    // Stop TIM1 and disable its outputs on a debugger halt.
    (*pac::DBGMCU::ptr())
        .apb2_fz()
        .modify(|_, w| w.dbg_tim1_stop().set_bit());
    tim.cr1()
        .write(|w| w.cms().bits(0b01).arpe().set_bit().cen().set_bit());
}

impl PwmDriver for Tim1Pwm {
    type Error = PwmError;

    fn period_counts(&self) -> u16 {
        self.arr
    }

    fn set_compare(&mut self, compare: [u16; 3]) -> Result<(), PwmError> {
        let mut out = Ok(());
        // CCR1..3 of the owned TIM1 (RM0090 17.4.14-16); preloaded, so the
        // new values apply at the next update event.
        let tim = self.regs.get();
        for (i, c) in compare.iter().enumerate() {
            let c = if *c > self.arr {
                out = Err(PwmError::CompareOutOfRange);
                self.arr
            } else {
                *c
            };
            tim.ccr(i).write(|w| unsafe { w.ccr().bits(c) });
        }
        out
    }

    fn enable(&mut self) -> Result<(), PwmError> {
        // SAFETY: TIM1 SR/BDTR (RM0090 17.4.5, 17.4.18). In a critical
        // section so that a fault ISR cannot run between setting MOE and the
        // enable pins and be undone.
        cortex_m::interrupt::free(|_| {
            let tim = unsafe { &*pac::TIM1::ptr() };
            // The break flag, or its software latch (the break ISR clears
            // the flag; the latch holds until the operator's clear).
            if tim.sr().read().bif().bit_is_set() || BREAK_LATCHED.load(Ordering::SeqCst) {
                return Err(PwmError::BreakActive);
            }
            if !self.cfg.enable_pins_in_disable
                && self.cfg.enable_pins.iter().any(|p| !p.is_set_high())
            {
                return Err(PwmError::GateDriverOff);
            }
            tim.bdtr().modify(|_, w| w.moe().set_bit());
            for p in self.cfg.enable_pins {
                p.set(true);
            }
            Ok(())
        })
    }

    fn disable(&mut self) {
        safe_state_moe();
        if self.cfg.enable_pins_in_disable {
            for p in self.cfg.enable_pins {
                p.set(false);
            }
        }
    }

    fn release_fault_latch(&mut self) {
        release_break_latch();
    }

    fn is_enabled(&self) -> bool {
        // Read of TIM1 BDTR (RM0090 17.4.18).
        self.regs.get().bdtr().read().moe().bit_is_set()
    }
}

/// Clear `BDTR.MOE`: all TIM1 outputs go to their idle (off) level
/// (RM0090 17.4.18, OSSI = 1). Usable from any context.
#[inline]
pub fn safe_state_moe() {
    // SAFETY: MOE is the main output enable; clearing it only ever turns
    // outputs off. Concurrent writers of BDTR are excluded by `enable`'s
    // critical section; this RMW may be interrupted only by another clear.
    unsafe {
        (*pac::TIM1::ptr())
            .bdtr()
            .modify(|_, w| w.moe().clear_bit());
    }
}

/// `MOE = 0` and every pin of `enable_pins` low.
pub fn safe_state_hard(enable_pins: &[PinId]) {
    safe_state_moe();
    for p in enable_pins {
        p.set(false);
    }
}

/// Clear the TIM1 break flag (`SR.BIF`, RM0090 17.4.5). `MOE` stays 0 (AOE =
/// 0): the outputs stay off until `PwmDriver::enable`.
pub fn break_flag_clear() {
    BREAK_LATCHED.store(true, Ordering::SeqCst);
    // SAFETY: TIM1_SR flags are rc_w0: writing 0 to BIF clears it, the
    // other fields are written 1 (no effect) by the PAC's write().
    unsafe {
        (*pac::TIM1::ptr()).sr().write(|w| w.bif().clear_bit());
    }
    safe_state_moe();
}

/// Set by [`break_flag_clear`] (the break ISR) before it clears the
/// hardware flag: `enable` refuses while it is set, so no code path turns
/// the outputs on again after a break, in that period or any later one,
/// until the operator's explicit fault clear ([`release_break_latch`],
/// through `PwmDriver::release_fault_latch`).
static BREAK_LATCHED: AtomicBool = AtomicBool::new(false);

/// Release the break latch (after the operator's explicit fault clear).
/// The hardware flag itself is not touched: a break input still active
/// sets it again and `enable` keeps refusing.
pub fn release_break_latch() {
    BREAK_LATCHED.store(false, Ordering::SeqCst);
}
