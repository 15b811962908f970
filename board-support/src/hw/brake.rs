//! ODrive v3.x brake resistor on the AUX half-bridge
//! ([`foc_core::hal::BrakeOutput`]).
//!
//! # Hardware (sources, read for this module; unverified on a board)
//!
//! - AUX_L = PB10 (TIM2_CH3), AUX_H = PB11 (TIM2_CH4), both AF1: ODrive
//!   firmware `Board/v3/Inc/main.h` (`AUX_L_Pin` / `AUX_H_Pin`) and
//!   `Board/v3/Src/tim.c` (`HAL_TIM_MspPostInit`, "PB10 TIM2_CH3, PB11
//!   TIM2_CH4"; the code comment in `MotorControl/low_level.cpp`,
//!   `safety_critical_apply_brake_resistor_timings`: "ch3 is low side, ch4
//!   is high side").
//! - Polarity: both gate inputs active high. The ODrive firmware's safe
//!   values drive both pins low: CH3 in PWM mode 2 with `CC3P = 1`
//!   (active low) and `CCR3 = 0` (reference always active, so the pin is
//!   always low); CH4 in PWM mode 2, `CC4P = 0`, `CCR4 = ARR + 1`
//!   (reference never active, pin low) (`tim.c` `MX_TIM2_Init`,
//!   `low_level.cpp` `safety_critical_disarm_brake_resistor`).
//! - Which FET dumps the energy: the **high side** (AUX_H). The resistor
//!   sits between the AUX switch node and ground; the firmware's brake duty
//!   `D = I_brake R / V_bus` is the fraction of the period AUX_H is on
//!   (`high_on = period (1 - D)` with CH4 active for `CNT >= CCR4`,
//!   `low_level.cpp` `update_brake_current`), and the ODrive developers
//!   confirm the low-side FETs "aren't actually used to turn the brake on"
//!   and that the resistor's negative terminal is GND (ODrive forum,
//!   "BRAKE_CURRENT_OUT_OF_RANGE after short through Brake Resistor",
//!   discourse.odriverobotics.com/t/3716).
//! - AUX_L on together with AUX_H shorts the bus through the two FETs
//!   (shoot-through). Here AUX_L is a GPIO output held low for good: it is
//!   never driven high by this crate, so the two can never conduct at once
//!   (the firmware's newer versions also drive only CCR4,
//!   `brake_resistor.cpp`).
//!
//! # Why the timer and not a plain GPIO for AUX_H
//!
//! The high-side gate supply is a bootstrap capacitor: it recharges only
//! while the switch node is low, i.e. while AUX_H is off. Held on for good
//! the gate voltage sags and the FET ends up half on, in its linear region,
//! which overheats it. The ODrive firmware therefore never exceeds 95 %
//! duty ("Duty limit at 95% to allow bootstrap caps to charge",
//! `brake_resistor.cpp`; 90 % in older `low_level.cpp`). So "brake on" is
//! TIM2_CH4 PWM at [`BRAKE_PWM_HZ`] and [`BRAKE_ON_DUTY`] (the resistor
//! then dissipates `D V^2 / R`); "off" is `CCR4 = 0`.
//!
//! TIM2 (RM0090 18.4): up-counting, edge-aligned, `PSC = 0`,
//! `ARR = f_tim / f_pwm - 1`, CH4 in PWM mode 1 (`OC4M = 110`: the output
//! is active while `CNT < CCR4`, RM0090 18.3.9) without preload
//! (`OC4PE = 0`: a new `CCR4` acts at once, so "off" does not wait for the
//! next update), active high (`CC4P = 0`), enabled (`CC4E = 1`). With
//! `CCR4 = 0` the output is never active.
//!
//! # Off from any context
//!
//! [`aux_off_hard`] (called by the board's `emergency_disable`): `CCR4 = 0`
//! (one store), both pins' output latches low (`BSRR`, atomic) and PB11
//! switched from its timer function to a plain output (`MODER`), so the
//! FET is off even if the timer state were corrupted. A brake stuck on
//! with the software dead (panic, HardFault) would keep a resistor sized
//! for short braking pulses across the full bus until it burns, and keep
//! draining the supply. After it, [`AuxBrake::set_brake`] keeps the output
//! off until the board's `init` runs again.

use crate::hw::{PinId, Port};
use crate::pac;
use core::sync::atomic::{AtomicBool, Ordering};
use foc_core::hal::BrakeOutput;

/// AUX low-side gate input (TIM2_CH3), held low for good.
pub const AUX_L: PinId = PinId::new(Port::B, 10);
/// AUX high-side gate input (TIM2_CH4, AF1): the brake switch.
pub const AUX_H: PinId = PinId::new(Port::B, 11);
/// PWM frequency of the chopper while on [Hz] (the ODrive firmware's TIM2
/// runs at 84 MHz / (2 x 4096) = 10.25 kHz).
pub const BRAKE_PWM_HZ: u32 = 10_000;
/// High-side duty while on: the largest the bootstrap supply allows
/// (module docs).
pub const BRAKE_ON_DUTY: f32 = 0.95;

/// Set by [`aux_off_hard`]: the output stays off until `init` runs again.
static AUX_LATCHED_OFF: AtomicBool = AtomicBool::new(false);

/// The AUX high-side switch driven by TIM2_CH4.
pub struct AuxBrake {
    /// `CCR4` while on.
    on_compare: u32,
    on: bool,
}

impl AuxBrake {
    /// Set TIM2 up with the output off (`CCR4 = 0`) and the counter
    /// running. TIM2's clock must be enabled and the peripheral reset by the
    /// caller (RCC_APB1ENR.TIM2EN / RCC_APB1RSTR, RM0090 7.3.13 / 7.3.8),
    /// AUX_L and AUX_H must be push-pull outputs driven low; switch AUX_H to
    /// AF1 only after this returns. `timer_clk_hz` is TIM2's input clock.
    pub fn new(tim: pac::TIM2, timer_clk_hz: u32) -> Self {
        let period = (timer_clk_hz / BRAKE_PWM_HZ).max(2);
        // Duty in 0..=1 (BRAKE_ON_DUTY is a constant in range).
        let on_compare = (period as f32 * BRAKE_ON_DUTY) as u32;
        tim.cr1().reset();
        tim.psc().write(|w| w.psc().set(0));
        tim.arr().write(|w| w.arr().set(period - 1));
        tim.ccr4().write(|w| w.ccr().set(0));
        tim.ccmr2_output()
            .write(|w| w.oc4m().pwm_mode1().oc4pe().clear_bit());
        tim.ccer().write(|w| w.cc4e().set_bit().cc4p().clear_bit());
        // Load PSC / ARR (UG), then count.
        tim.egr().write(|w| w.ug().set_bit());
        tim.cr1().write(|w| w.arpe().set_bit().cen().set_bit());
        AUX_LATCHED_OFF.store(false, Ordering::SeqCst);
        Self {
            on_compare,
            on: false,
        }
    }
}

impl BrakeOutput for AuxBrake {
    fn set_brake(&mut self, on: bool) {
        let on = on && !AUX_LATCHED_OFF.load(Ordering::SeqCst);
        let ccr = if on { self.on_compare } else { 0 };
        // SAFETY: TIM2_CCR4 (RM0090 18.4.16), written only here and by
        // `aux_off_hard` (which writes 0, the safe value); one store.
        unsafe { (*pac::TIM2::ptr()).ccr4().write(|w| w.ccr().set(ccr)) };
        self.on = on;
    }

    fn is_brake_on(&self) -> bool {
        self.on && !AUX_LATCHED_OFF.load(Ordering::SeqCst)
    }
}

/// Brake off from any context (module docs, "Off from any context").
pub fn aux_off_hard() {
    AUX_LATCHED_OFF.store(true, Ordering::SeqCst);
    // SAFETY: TIM2_CCR4 = 0 (one store; never-active output); BSRR resets
    // (atomic, RM0090 8.4.7); GPIOB_MODER bits 23:22 = 01, general-purpose
    // output (RM0090 8.4.1): a read-modify-write that can race only with
    // GPIOB set-up in `init`, which does not run concurrently with a
    // safe-state request. Writes to a peripheral whose clock is still off
    // (before `init`) are ignored, and the pins are then inputs anyway.
    unsafe {
        (*pac::TIM2::ptr()).ccr4().write(|w| w.ccr().set(0));
    }
    AUX_H.set(false);
    AUX_L.set(false);
    let sh = 2 * AUX_H.pin as u32;
    unsafe {
        (*pac::GPIOB::ptr())
            .moder()
            .modify(|r, w| w.bits((r.bits() & !(0b11 << sh)) | (0b01 << sh)));
    }
}
