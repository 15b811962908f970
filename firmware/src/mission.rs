//! The scripted mission of the emulated board (firmware in the loop).
//!
//! Runs in the `housekeeping` task (priority 1, every 400 PWM periods =
//! 20 ms of simulated time) and drives the *unchanged* control tasks through
//! the command mailbox, as the command channel would, while it sets the
//! simulated load and injects a fault through the board's `sim` handle:
//!
//! 1. start-up (current-offset calibration, sensor check, motor
//!    identification) must finish; the identified R, L (5 %), flux linkage
//!    (10 %), electrical zero (2 deg), direction and pole pairs are checked
//!    against the simulated motor;
//! 2. velocity step to 100 rad/s: within 2 rad/s after 0.3 s;
//! 3. load step (0.1 N m, about 40 % of the 10 A limit): speed back within
//!    2 rad/s after 0.3 s;
//! 4. position move of +30 rad: within 0.05 rad and at rest after 0.8 s;
//! 5. injected encoder jump (90 deg): the supervisor latches
//!    `AngleSensorImplausible` and the bridge is off at the next check;
//! 6. fault removed: the bridge stays off until the explicit clear; then
//!    cleared, velocity 50 rad/s: running again;
//! 7. no current-loop overrun during the whole run.
//!
//! With the semihosting argument `mission=panic` it instead panics during
//! the position move; the panic handler must leave the bridge off.
//!
//! With `mission=store-save`, `store-boot` or `store-corrupt` the store
//! missions run instead (see `store_mission`).
//!
//! With the semihosting argument `mission=e2e` the mission stays passive: it posts
//! nothing, checks nothing and never exits, so that only the command
//! channel (USART2, `cargo xtask e2e`) drives the drive.
//! The outcome is the QEMU exit status (see [`exit`]).

use board_support::board::sim::{self, SimFault};
use foc_core::calibration::identification::IdentificationResult;
use foc_core::control::{Command, CommandSlot, Fault, Feedback, Mode};

/// Exit status: mission passed.
pub const EXIT_PASSED: u32 = 0;
/// Exit status: a mission check failed.
pub const EXIT_FAILED: u32 = 1;
/// Exit status: panic, and the bridge was NOT in the safe state.
pub const EXIT_PANIC_UNSAFE: u32 = 2;
/// Exit status: panic, bridge in the safe state (expected in the panic run).
pub const EXIT_PANIC_SAFE: u32 = 3;
/// Exit status: HardFault.
pub const EXIT_HARDFAULT: u32 = 4;

/// End the emulation with `code` as QEMU's exit status
/// (semihosting SYS_EXIT_EXTENDED, reason ADP_Stopped_ApplicationExit).
pub fn exit(code: u32) -> ! {
    sim::exit(code)
}

/// True when QEMU passed `mission=panic` as a semihosting argument.
pub fn panic_run_requested() -> bool {
    board_support::board::args().mission() == "panic"
}

/// True when QEMU passed `mission=e2e` as a semihosting argument (passive
/// mission).
pub fn e2e_run_requested() -> bool {
    board_support::board::args().mission() == "e2e"
}

/// Log one check's verdict (`mission: PASS ...` / `mission: FAIL ...`,
/// which `cargo xtask qemu` counts); true when it passed.
pub fn report(ok: bool, what: &str) -> bool {
    if ok {
        defmt::info!("mission: PASS {}", what);
    } else {
        defmt::error!("mission: FAIL {}", what);
    }
    ok
}

/// Mission steps.
#[derive(Clone, Copy, PartialEq, Eq, defmt::Format)]
enum Step {
    WaitStartup,
    Velocity,
    Load,
    Position,
    Fault,
    Clear,
    Recover,
    Break,
    BreakClear,
    AfterBreak,
    Done,
}

/// The mission state machine.
pub struct Mission {
    step: Step,
    since: u32,
    target_rad: f32,
    /// Plant position minus firmware position when the move starts (the
    /// firmware counts turns from its last tracker reset).
    truth_offset_rad: f32,
    panic_run: bool,
    passive: bool,
    failures: u32,
}

/// Periods of simulated time in `s` seconds.
fn periods(s: f32) -> u32 {
    (s * board_support::board::PWM_FREQUENCY_HZ as f32) as u32
}

impl Mission {
    /// New mission; `panic_run` selects the forced-panic variant,
    /// `passive` the command-channel test (the mission does nothing).
    pub const fn new(panic_run: bool, passive: bool) -> Self {
        Self {
            step: Step::WaitStartup,
            since: 0,
            target_rad: 0.0,
            truth_offset_rad: 0.0,
            panic_run,
            passive,
            failures: 0,
        }
    }

    fn check(&mut self, ok: bool, what: &str) {
        if !report(ok, what) {
            self.failures += 1;
        }
    }

    fn go(&mut self, next: Step, now: u32, slot: &mut CommandSlot, cmd: Option<Command>) {
        self.step = next;
        self.since = now;
        if let Some(c) = cmd {
            slot.post(c);
        }
        defmt::info!("mission: -> {}", next);
    }

    /// The firmware identified the simulated motor at start-up: compare
    /// with the plant's true values (issue 9's accuracy requirements).
    fn check_calibration(&mut self, identified: Option<IdentificationResult>) {
        let Some(r) = identified else {
            self.check(false, "motor identified at start-up");
            return;
        };
        let m = board_support::board::SIM_MOTOR;
        let rel = |x: f32, t: f32| (x - t).abs() / t;
        defmt::info!(
            "mission: identified R {=f32} % Ld {=f32} % Lq {=f32} % psi {=f32} % off the plant; zero {=f32} deg(e)",
            100.0 * (r.r_ohm / m.r_ohm - 1.0),
            100.0 * (r.ld_h / m.ld_h - 1.0),
            100.0 * (r.lq_h / m.lq_h - 1.0),
            100.0 * (r.flux_linkage_wb / m.flux_linkage_wb - 1.0),
            r.angle.zero_offset.to_signed_radians().to_degrees()
        );
        self.check(
            rel(r.r_ohm, m.r_ohm) < 0.05
                && rel(r.ld_h, m.ld_h) < 0.05
                && rel(r.lq_h, m.lq_h) < 0.05,
            "identified R, Ld, Lq within 5 %",
        );
        self.check(
            rel(r.flux_linkage_wb, m.flux_linkage_wb) < 0.10,
            "identified flux linkage within 10 %",
        );
        // The plant's encoder zero is on the d axis: the true offset is 0.
        self.check(
            r.angle.zero_offset.to_signed_radians().to_degrees().abs() < 2.0
                && !r.angle.reversed
                && r.pole_pairs == m.pole_pairs,
            "electrical zero within 2 deg(e), direction and pole pairs exact",
        );
    }

    /// One housekeeping tick. Returns an exit status when finished.
    pub fn tick(
        &mut self,
        fb: &Feedback,
        slot: &mut CommandSlot,
        drive: &DriveState,
    ) -> Option<u32> {
        let DriveState {
            running,
            overruns,
            identified,
        } = *drive;
        if self.passive {
            if self.step == Step::WaitStartup && running {
                defmt::info!("mission: passive (e2e): waiting for the command channel");
                self.step = Step::Done;
            }
            return None;
        }
        let now = fb.period;
        let t = sim::truth();
        let elapsed = now.wrapping_sub(self.since);
        defmt::info!(
            "t {=f32} s mode {} w {=f32} (true {=f32}) rad/s p {=f32} (true {=f32}) rad iq {=f32} A fault {}",
            t.time_s,
            fb.mode,
            fb.velocity_rad_s,
            t.omega_m_rad_s,
            fb.position_rad,
            t.position_rad,
            fb.i_dq_a.q,
            fb.first_fault
        );
        match self.step {
            Step::WaitStartup => {
                if running {
                    self.check_calibration(identified);
                    self.go(
                        Step::Velocity,
                        now,
                        slot,
                        Some(Command::Velocity { rad_s: 100.0 }),
                    );
                } else if t.time_s > 20.0 {
                    self.check(false, "start-up (calibration, identification) within 20 s");
                    return Some(EXIT_FAILED);
                }
            }
            Step::Velocity if elapsed >= periods(0.3) => {
                self.check(
                    (fb.velocity_rad_s - 100.0).abs() < 2.0
                        && (t.omega_m_rad_s - 100.0).abs() < 2.0,
                    "velocity 100 rad/s within 2 rad/s",
                );
                sim::set_load_torque_nm(0.1);
                self.go(Step::Load, now, slot, None);
            }
            Step::Load if elapsed >= periods(0.3) => {
                self.check(
                    (t.omega_m_rad_s - 100.0).abs() < 2.0,
                    "0.1 N m load step rejected within 2 rad/s",
                );
                sim::set_load_torque_nm(0.0);
                self.target_rad = fb.position_rad + 30.0;
                self.truth_offset_rad = t.position_rad - fb.position_rad;
                let target = self.target_rad;
                self.go(
                    Step::Position,
                    now,
                    slot,
                    Some(Command::Position { rad: target }),
                );
            }
            Step::Position if self.panic_run && elapsed >= periods(0.2) => {
                defmt::warn!("mission: forcing a panic during the move");
                // The QEMU panic run's whole point (a test script in the
                // emulated firmware; issue 33 moves it out).
                #[allow(clippy::panic)]
                {
                    panic!("forced panic (QEMU panic run)");
                }
            }
            Step::Position if elapsed >= periods(0.8) => {
                self.check(
                    (fb.position_rad - self.target_rad).abs() < 0.05
                        && (t.position_rad - fb.position_rad - self.truth_offset_rad).abs() < 0.05,
                    "position move +30 rad within 0.05 rad",
                );
                self.check(t.omega_m_rad_s.abs() < 1.0, "at rest after the move");
                sim::inject(SimFault::EncoderJump(1024));
                self.go(Step::Fault, now, slot, None);
            }
            Step::Fault => {
                self.check(
                    fb.first_fault == Some(Fault::AngleSensorImplausible),
                    "encoder jump latched as implausible angle",
                );
                self.check(
                    fb.mode == Mode::Disabled && !sim::outputs_on() && !t.bridge_enabled,
                    "bridge in the safe state after the fault",
                );
                // Remove the cause first; clear once it is gone (the
                // encoder jumping back would otherwise trip again).
                sim::inject(SimFault::None);
                self.go(Step::Clear, now, slot, None);
            }
            Step::Clear => {
                self.check(
                    fb.mode == Mode::Disabled && !sim::outputs_on(),
                    "bridge still off until the explicit clear",
                );
                slot.request_clear();
                self.go(
                    Step::Recover,
                    now,
                    slot,
                    Some(Command::Velocity { rad_s: 50.0 }),
                );
            }
            Step::Recover if elapsed >= periods(0.4) => {
                self.check(fb.faults.is_empty(), "fault cleared");
                self.check(
                    (t.omega_m_rad_s - 50.0).abs() < 2.0,
                    "running again at 50 rad/s after the clear",
                );
                sim::raise_break();
                self.go(Step::Break, now, slot, None);
            }
            Step::Break => {
                self.check(
                    fb.first_fault == Some(Fault::GateDriverFault) && sim::break_latched(),
                    "timer break latched as a gate-driver fault",
                );
                self.check(
                    !sim::outputs_on() && sim::on_periods_after_break() == 0,
                    "bridge never on after the break",
                );
                // A command without a clear: refused, the bridge stays off.
                self.go(
                    Step::BreakClear,
                    now,
                    slot,
                    Some(Command::Velocity { rad_s: 50.0 }),
                );
            }
            Step::BreakClear if elapsed >= periods(0.05) => {
                self.check(
                    !sim::outputs_on()
                        && sim::break_latched()
                        && sim::on_periods_after_break() == 0,
                    "break latch holds until the explicit clear",
                );
                slot.request_clear();
                self.go(
                    Step::AfterBreak,
                    now,
                    slot,
                    Some(Command::Velocity { rad_s: 50.0 }),
                );
            }
            Step::AfterBreak if elapsed >= periods(0.4) => {
                self.check(
                    fb.faults.is_empty() && !sim::break_latched(),
                    "break released by the clear",
                );
                self.check(
                    (t.omega_m_rad_s - 50.0).abs() < 2.0,
                    "running again at 50 rad/s after the break",
                );
                self.check(overruns == 0, "no current-loop overrun");
                slot.post(Command::Disable);
                self.step = Step::Done;
                return Some(if self.failures == 0 {
                    EXIT_PASSED
                } else {
                    EXIT_FAILED
                });
            }
            _ => {}
        }
        None
    }
}

/// The mission instance, used only by the `housekeeping` task.
static MISSION: cortex_m::interrupt::Mutex<core::cell::RefCell<Option<Mission>>> =
    cortex_m::interrupt::Mutex::new(core::cell::RefCell::new(None));

/// What the mission reads of the drive besides its feedback.
#[derive(Clone, Copy)]
pub struct DriveState {
    /// Start-up finished (phase `Run`).
    pub running: bool,
    /// Current-loop overruns so far.
    pub overruns: u32,
    /// The last successful identification.
    pub identified: Option<IdentificationResult>,
}

/// One housekeeping tick of the mission (creates it on first use).
pub fn tick(fb: &Feedback, slot: &mut CommandSlot, drive: &DriveState) -> Option<u32> {
    let mut mission = cortex_m::interrupt::free(|cs| MISSION.borrow(cs).borrow_mut().take())
        .unwrap_or_else(|| Mission::new(panic_run_requested(), e2e_run_requested()));
    let out = mission.tick(fb, slot, drive);
    cortex_m::interrupt::free(|cs| MISSION.borrow(cs).replace(Some(mission)));
    out
}

/// Panic under emulation: the bridge was already disabled by the handler;
/// let the plant run a few periods, then exit with the safe/unsafe verdict.
pub fn panic_exit() -> ! {
    let start = sim::truth().periods;
    let mut spins = 0u32;
    while sim::truth().periods < start + 20 && spins < 50_000_000 {
        spins += 1;
    }
    let t = sim::truth();
    let safe = !sim::outputs_on() && !t.bridge_enabled && sim::emergency_latched();
    if safe {
        defmt::info!(
            "panic: bridge in the safe state ({=u64} periods later)",
            t.periods - start
        );
        exit(EXIT_PANIC_SAFE)
    } else {
        defmt::error!("panic: bridge NOT in the safe state");
        exit(EXIT_PANIC_UNSAFE)
    }
}
