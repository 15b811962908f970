//! The store missions of the emulated board (design §17): `cargo xtask
//! qemu` runs the firmware three times on one store file (semihosting
//! `store=`), with the emulated absolute sensor (`sensor=absolute`):
//!
//! 1. `mission=store-save`: identification at start-up, then the
//!    configuration (with the identified calibration) is saved and read
//!    back equal;
//! 2. `mission=store-boot`: the rotor starts somewhere else (`rotor=`);
//!    start-up must install the stored calibration without identifying,
//!    be calibrated within 100 ms of reset, move the rotor less than
//!    0.01 rad before the first command, and accept a torque command that
//!    accelerates the rotor as the plant's torque constant says (a wrong
//!    electrical zero would give less torque, or the wrong way);
//! 3. `mission=store-corrupt` (the host damaged the file): boots
//!    uncalibrated and refuses the torque command.
//!
//! Runs in `housekeeping` (every 400 periods, 20 ms), like the main
//! mission; every step is bounded in emulated time.

use crate::mission::{EXIT_FAILED, EXIT_PASSED};
use board_support::board::{self, sim};
use core::sync::atomic::{AtomicU32, Ordering};
use foc_core::control::{Command, CommandSlot, Feedback, Mode};

/// Current-loop periods from reset to the first calibrated period of a
/// start-up from the store (`u32::MAX`: not yet). Written by the current
/// loop when the lifecycle reports `CalibrationRestored`.
pub static CALIBRATED_AT_PERIOD: AtomicU32 = AtomicU32::new(u32::MAX);

/// Which store mission.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum StoreMission {
    /// Run 1: identify, save.
    Save,
    /// Run 2: boot from the store.
    Boot,
    /// Run 3: boot from a damaged store.
    Corrupt,
}

impl StoreMission {
    /// From the `mission=` argument.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "store-save" => Some(Self::Save),
            "store-boot" => Some(Self::Boot),
            "store-corrupt" => Some(Self::Corrupt),
            _ => None,
        }
    }
}

/// What the drive looks like to the mission this tick.
pub struct View<'a> {
    /// Latest feedback.
    pub fb: &'a Feedback,
    /// Start-up finished.
    pub running: bool,
    /// Closed loop allowed (offsets and a permit).
    pub calibrated: bool,
    /// An identification has succeeded since reset.
    pub identified: bool,
}

#[derive(Clone, Copy, PartialEq, Eq, defmt::Format)]
enum Step {
    WaitStartup,
    Torque,
}

/// A store mission's state.
pub struct Run {
    mission: StoreMission,
    step: Step,
    since_s: f32,
    max_motion_rad: f32,
    /// The bridge conducted during start-up (any period, counted by the
    /// emulated board's physics).
    bridge_on_at_start_up: bool,
    omega_at_command_rad_s: f32,
    failures: u32,
}

/// Emulated seconds allowed for start-up (identification included).
const STARTUP_LIMIT_S: f32 = 20.0;
/// Torque-command test: q current [A] and duration [s].
const TEST_IQ_A: f32 = 2.0;
const TEST_TIME_S: f32 = 0.05;

impl Run {
    /// A new run of `mission`.
    pub const fn new(mission: StoreMission) -> Self {
        Self {
            mission,
            step: Step::WaitStartup,
            since_s: 0.0,
            max_motion_rad: 0.0,
            bridge_on_at_start_up: false,
            omega_at_command_rad_s: 0.0,
            failures: 0,
        }
    }

    fn check(&mut self, ok: bool, what: &str) {
        if !crate::mission::report(ok, what) {
            self.failures += 1;
        }
    }

    fn verdict(&self) -> u32 {
        if self.failures == 0 {
            EXIT_PASSED
        } else {
            EXIT_FAILED
        }
    }

    /// One housekeeping tick; `save` saves the configuration in force and
    /// reads it back (true: saved and equal). Returns an exit status when
    /// finished.
    pub fn tick(
        &mut self,
        v: &View<'_>,
        slot: &mut CommandSlot,
        save: &mut dyn FnMut() -> bool,
    ) -> Option<u32> {
        let t = sim::truth();
        let motion = (t.position_rad - board::args().rotor_start_rad).abs();
        if self.step == Step::WaitStartup {
            self.max_motion_rad = self.max_motion_rad.max(motion);
            self.bridge_on_at_start_up |= sim::on_periods() > 0;
            if !v.running {
                if t.time_s > STARTUP_LIMIT_S {
                    self.check(false, "start-up within 20 s");
                    return Some(EXIT_FAILED);
                }
                return None;
            }
        }
        match (self.mission, self.step) {
            (StoreMission::Save, _) => {
                self.check(v.identified && v.calibrated, "identified at start-up");
                self.check(save(), "configuration saved and read back equal");
                Some(self.verdict())
            }
            (StoreMission::Boot, Step::WaitStartup) => {
                self.check_boot(v);
                self.start_torque(slot, t.omega_m_rad_s, t.time_s);
                None
            }
            (StoreMission::Corrupt, Step::WaitStartup) => {
                self.check(!v.calibrated, "boots uncalibrated from a damaged store");
                self.check(!v.identified, "no identification");
                self.start_torque(slot, t.omega_m_rad_s, t.time_s);
                None
            }
            (_, Step::Torque) if t.time_s - self.since_s >= TEST_TIME_S => {
                let elapsed_s = t.time_s - self.since_s;
                self.check_torque(v, t.omega_m_rad_s, t.bridge_enabled, elapsed_s);
                slot.post(Command::Disable);
                Some(self.verdict())
            }
            (_, Step::Torque) => None,
        }
    }

    fn check_boot(&mut self, v: &View<'_>) {
        let at = CALIBRATED_AT_PERIOD.load(Ordering::Relaxed);
        let ms = at as f32 * 1000.0 / board::PWM_FREQUENCY_HZ as f32;
        defmt::info!(
            "mission: calibrated from the store {=f32} ms after reset ({=u32} periods); rotor moved {=f32} rad before the first command",
            ms,
            at,
            self.max_motion_rad
        );
        self.check(
            v.calibrated && !v.identified,
            "calibrated from the store, no identification",
        );
        self.check(
            at != u32::MAX && ms < 100.0,
            "calibrated within 100 ms of reset",
        );
        self.check(
            self.max_motion_rad < 0.01 && !self.bridge_on_at_start_up,
            "rotor moved < 0.01 rad before the first command, bridge off throughout",
        );
    }

    fn start_torque(&mut self, slot: &mut CommandSlot, omega_rad_s: f32, now_s: f32) {
        slot.post(Command::Torque { iq_a: TEST_IQ_A });
        self.omega_at_command_rad_s = omega_rad_s;
        self.since_s = now_s;
        self.step = Step::Torque;
        defmt::info!("mission: torque {=f32} A", TEST_IQ_A);
    }

    fn check_torque(&mut self, v: &View<'_>, omega_rad_s: f32, bridge_on: bool, elapsed_s: f32) {
        let m = board::SIM_MOTOR;
        let kt = 1.5 * f32::from(m.pole_pairs) * m.flux_linkage_wb;
        let expected = kt * TEST_IQ_A / m.inertia_kg_m2 * elapsed_s;
        let gained = omega_rad_s - self.omega_at_command_rad_s;
        defmt::info!(
            "mission: speed gained {=f32} rad/s in {=f32} s (rigid rotor, ideal torque: {=f32})",
            gained,
            elapsed_s,
            expected
        );
        match self.mission {
            StoreMission::Corrupt => self.check(
                !bridge_on && v.fb.mode == Mode::Disabled && gained.abs() < 0.05 * expected,
                "torque refused: bridge off, rotor still",
            ),
            _ => self.check(
                v.fb.mode == Mode::Torque && gained > 0.8 * expected && gained < 1.1 * expected,
                "torque command accepted, acceleration as the torque constant says (within -20/+10 %)",
            ),
        }
    }
}

/// The store mission named on the command line, if any.
pub fn requested() -> Option<StoreMission> {
    StoreMission::from_name(board::args().mission())
}

static RUN: cortex_m::interrupt::Mutex<core::cell::RefCell<Option<Run>>> =
    cortex_m::interrupt::Mutex::new(core::cell::RefCell::new(None));

/// One housekeeping tick of store mission `m` (created on first use); see
/// [`Run::tick`].
pub fn tick(
    m: StoreMission,
    v: &View<'_>,
    slot: &mut CommandSlot,
    save: &mut dyn FnMut() -> bool,
) -> Option<u32> {
    let mut run = cortex_m::interrupt::free(|cs| RUN.borrow(cs).borrow_mut().take())
        .unwrap_or_else(|| Run::new(m));
    let out = run.tick(v, slot, save);
    cortex_m::interrupt::free(|cs| RUN.borrow(cs).replace(Some(run)));
    out
}
