//! Independent watchdog (IWDG), fed only while the control loops run.
//!
//! Register sequence per RM0090 section 21.3 (identical on RM0390 / RM0368):
//! start with key 0xCCCC, unlock PR/RLR with 0x5555, program prescaler and
//! reload, feed with 0xAAAA. The IWDG runs from the ~32 kHz LSI; with /32
//! one reload count is about 1 ms. Once started it cannot be stopped.

use board_support::pac;

/// Start the watchdog with a timeout of `timeout_ms` (1..=4095 ms).
pub fn start(timeout_ms: u32) {
    // SAFETY: the IWDG is used only here and in `feed` (single writer per
    // call, KR writes are atomic); no other code owns it.
    let iwdg = unsafe { &*pac::IWDG::ptr() };
    let reload = timeout_ms.clamp(1, 0x0FFF) as u16;
    // Freeze the IWDG while a debugger halts the core (RM0090 38.16.4,
    // DBGMCU_APB1_FZ.DBG_IWDG_STOP); no effect without a debugger.
    // SAFETY: a read-modify-write of one debug-freeze bit at start-up.
    unsafe { &*pac::DBGMCU::ptr() }
        .apb1_fz()
        .modify(|_, w| w.dbg_iwdg_stop().set_bit());
    iwdg.kr().write(|w| w.key().start());
    iwdg.kr().write(|w| w.key().unlock());
    iwdg.pr().write(|w| w.pr().divide_by32());
    iwdg.rlr().write(|w| w.rl().set(reload));
    // PR/RLR updates complete when SR.PVU/RVU clear (a few LSI cycles);
    // bounded wait so emulators that do not model the IWDG cannot hang us.
    let mut n = 0u32;
    while iwdg.sr().read().bits() != 0 && n < 100_000 {
        n += 1;
    }
    feed();
}

/// Reload the watchdog counter.
#[inline]
pub fn feed() {
    // SAFETY: see `start`; a KR write has no other effect.
    let iwdg = unsafe { &*pac::IWDG::ptr() };
    iwdg.kr().write(|w| w.key().feed());
}

/// True when the last reset came from the independent watchdog
/// (`RCC_CSR.WDGRSTF`, RM0090 section 7.3.21); then clears the reset flags
/// (`RMVF`). Call once in `init`, before anything else reads `RCC_CSR`.
pub fn take_reset_flag() -> bool {
    // SAFETY: one read and one write of RCC_CSR at start-up, before the
    // board set-up (which does not use RCC_CSR); RMVF only clears flags.
    let rcc = unsafe { &*pac::RCC::ptr() };
    let was = rcc.csr().read().wdgrstf().bit_is_set();
    rcc.csr().modify(|_, w| w.rmvf().set_bit());
    was
}

/// Run `f` with the watchdog stretched to its longest timeout (prescaler
/// /256, reload 4095: about 32 s at the nominal 32 kHz LSI), then restore
/// `timeout_ms`. For the flash store only: erasing a 128 KiB sector of the
/// internal flash stalls instruction fetch, and so every task, for seconds
/// (RM0390 / RM0090 section 3.6; datasheet t_ERASE128KB), far beyond the
/// normal timeout. Callers keep the bridge off while `f` runs (the
/// protocol allows store operations only while disabled).
pub fn stretched<T>(timeout_ms: u32, f: impl FnOnce() -> T) -> T {
    // SAFETY: see `start`; PR/RLR writes after the unlock key only change
    // the timeout (RM0090 21.3.2).
    let iwdg = unsafe { &*pac::IWDG::ptr() };
    feed();
    iwdg.kr().write(|w| w.key().unlock());
    iwdg.pr().write(|w| w.pr().divide_by256());
    iwdg.rlr().write(|w| w.rl().set(0x0FFF));
    wait_update(iwdg);
    feed();
    let out = f();
    feed();
    iwdg.kr().write(|w| w.key().unlock());
    iwdg.pr().write(|w| w.pr().divide_by32());
    iwdg.rlr()
        .write(|w| w.rl().set(timeout_ms.clamp(1, 0x0FFF) as u16));
    wait_update(iwdg);
    feed();
    out
}

/// Wait (bounded, for emulators that do not model the IWDG) until the
/// prescaler and reload updates are done (SR.PVU/RVU clear).
fn wait_update(iwdg: &pac::iwdg::RegisterBlock) {
    let mut n = 0u32;
    while iwdg.sr().read().bits() != 0 && n < 100_000 {
        n += 1;
    }
}
