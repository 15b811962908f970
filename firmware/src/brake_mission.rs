//! The braking mission of the emulated board (design §18, issue 17):
//! the firmware binary brakes the simulated motor into a supply that cannot
//! sink current. `cargo xtask qemu` runs it twice:
//!
//! - `mission=brake supply=nonsinking`: the emulated plant has a DC link
//!   (the ODrive v3 preset's 1880 uF fed by a non-sinking 24 V supply) and
//!   no brake resistor: only the regen ramp of the power limits
//!   (`config::power_limits`) keeps the bus below the over-voltage fault;
//! - `mission=brake supply=nonsinking brake=2`: the same with a 2 ohm brake
//!   resistor switched by the firmware's chopper (`board::brake_output()`).
//!
//! Steps, each bounded in simulated PWM periods:
//!
//! 1. start-up as in the main mission (current offsets, sensor check,
//!    identification: the only way the emulated drive gets calibrated
//!    without a store), within 20 s;
//! 2. velocity [`top_speed_rad_s`] (three quarters of the motor's no-load
//!    speed on the 24 V bus): reached within 2 % in [`SPIN_UP_LIMIT_S`];
//! 3. velocity 0: the board's stop watch records the true bus voltage and
//!    speed every period; the stop is over once the true speed has stayed
//!    below [`STOP_SPEED_RAD_S`] for [`HOLD_S`], and fails past the run's
//!    stop-time bound ([`StopBounds`]).
//!
//! Checks (`mission: PASS/FAIL`, counted by `cargo xtask qemu`): the peak
//! true bus voltage below the over-voltage threshold, no fault latched,
//! stopped within the bound; with a brake resistor, also energy dissipated
//! in it. Figures (peak bus voltage, stop time, brake energy, kinetic
//! energy at the stop command) are logged on one `brake:` line.
//!
//! Runs in `housekeeping` (every 400 periods, 20 ms), like the main
//! mission.

use crate::mission::{report, EXIT_FAILED, EXIT_PASSED};
use board_support::board::{self, sim};
use foc_core::control::{Command, CommandSlot, Feedback, Mode};

/// Emulated seconds allowed for start-up (identification included).
const STARTUP_LIMIT_S: f32 = 20.0;
/// Time allowed to reach the top speed [s].
pub const SPIN_UP_LIMIT_S: f32 = 0.5;
/// Speed below which the rotor counts as stopped [rad/s].
pub const STOP_SPEED_RAD_S: f32 = 2.0;
/// The rotor must stay below [`STOP_SPEED_RAD_S`] this long to end the
/// stop [s].
pub const HOLD_S: f32 = 0.1;

/// The bus voltage the top speed is chosen for [V] (the emulated supply).
const SUPPLY_V: f32 = 24.0;
/// Share of the no-load speed commanded (voltage headroom for the current
/// loop at speed).
const TOP_SPEED_SHARE: f32 = 0.75;

/// The velocity commanded before the stop [rad/s]: [`TOP_SPEED_SHARE`] of
/// the simulated motor's no-load speed on [`SUPPLY_V`] with space-vector
/// modulation (phase voltage amplitude `V_bus / sqrt(3)` against the
/// back-EMF `psi p w`): about 297 rad/s for `board::SIM_MOTOR`.
pub fn top_speed_rad_s() -> f32 {
    let m = board::SIM_MOTOR;
    let back_emf_v_per_rad_s = m.flux_linkage_wb * f32::from(m.pole_pairs);
    TOP_SPEED_SHARE * SUPPLY_V / (libm::sqrtf(3.0) * back_emf_v_per_rad_s)
}

/// The stop-time bound of a run [s].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StopBounds {
    /// Stopped (below [`STOP_SPEED_RAD_S`] for good) within this [s].
    pub stop_s: f32,
}

impl StopBounds {
    /// Regen ramp only: the capacitor takes a tenth of the rotor's kinetic
    /// energy (2.25 J at the top speed; 1880 uF from 24 to 28.5 V: 0.22 J)
    /// before the ramp closes the regenerating window; the rest goes into
    /// the winding through the ramp's d-axis braking current (measured
    /// 0.16 s). Without that the motor would coast on friction for
    /// seconds.
    pub const REGEN_ONLY: Self = Self { stop_s: 0.4 };
    /// With the 2 ohm brake resistor the chopper holds the bus near its
    /// 25.5 V threshold and takes most of the energy: the speed loop
    /// brakes unhindered (measured 0.11 s).
    pub const WITH_BRAKE: Self = Self { stop_s: 0.2 };

    /// The bound for this run's options.
    pub fn for_run() -> Self {
        if board::brake_output() {
            Self::WITH_BRAKE
        } else {
            Self::REGEN_ONLY
        }
    }
}

#[derive(Clone, Copy, PartialEq, Eq, defmt::Format)]
enum Step {
    WaitStartup,
    SpinUp,
    Stop,
}

/// The braking mission's state.
pub struct Run {
    step: Step,
    /// Period of the last step change.
    since: u64,
    bounds: StopBounds,
    /// Peak true bus voltage during the spin-up [V] (the speed loop's
    /// overshoot regenerates too).
    spin_up_peak_v: f32,
    failures: u32,
}

/// Periods of simulated time in `s` seconds.
fn periods(s: f32) -> u64 {
    (s * board::PWM_FREQUENCY_HZ as f32) as u64
}

/// Seconds of simulated time in `n` periods.
fn seconds(n: u64) -> f32 {
    n as f32 / board::PWM_FREQUENCY_HZ as f32
}

impl Run {
    /// A new run.
    pub const fn new(bounds: StopBounds) -> Self {
        Self {
            step: Step::WaitStartup,
            since: 0,
            bounds,
            spin_up_peak_v: 0.0,
            failures: 0,
        }
    }

    fn check(&mut self, ok: bool, what: &str) {
        if !report(ok, what) {
            self.failures += 1;
        }
    }

    fn go(&mut self, next: Step, now: u64, slot: &mut CommandSlot, cmd: Command) {
        self.step = next;
        self.since = now;
        slot.post(cmd);
        defmt::info!("mission: -> {}", next);
    }

    fn finish(&mut self, slot: &mut CommandSlot) -> Option<u32> {
        slot.post(Command::Disable);
        defmt::info!(
            "brake: run ended at {=f32} s simulated",
            sim::truth().time_s
        );
        Some(if self.failures == 0 {
            EXIT_PASSED
        } else {
            EXIT_FAILED
        })
    }

    /// One housekeeping tick (`running`: start-up finished). Returns an
    /// exit status when finished.
    pub fn tick(&mut self, fb: &Feedback, running: bool, slot: &mut CommandSlot) -> Option<u32> {
        let t = sim::truth();
        let elapsed = t.periods.saturating_sub(self.since);
        match self.step {
            Step::WaitStartup => {
                if running {
                    let top = top_speed_rad_s();
                    defmt::info!(
                        "mission: brake run, velocity {=f32} rad/s then 0; brake output {=bool}",
                        top,
                        board::brake_output()
                    );
                    self.check(fb.faults.is_empty(), "start-up without fault");
                    // Watch the bus from the spin-up on.
                    sim::start_stop_watch(STOP_SPEED_RAD_S);
                    self.go(
                        Step::SpinUp,
                        t.periods,
                        slot,
                        Command::Velocity { rad_s: top },
                    );
                } else if t.time_s > STARTUP_LIMIT_S {
                    self.check(false, "start-up (calibration, identification) within 20 s");
                    return Some(EXIT_FAILED);
                }
                None
            }
            Step::SpinUp => {
                let top = top_speed_rad_s();
                let reached = (t.omega_m_rad_s - top).abs() < 0.02 * top
                    && fb.mode == Mode::Velocity
                    && fb.faults.is_empty();
                if !reached && elapsed < periods(SPIN_UP_LIMIT_S) && fb.faults.is_empty() {
                    return None;
                }
                self.spin_up_peak_v = sim::stop_watch().map_or(f32::NAN, |w| w.peak_v_bus_v);
                defmt::info!(
                    "mission: {=f32} rad/s after {=f32} s, bus {=f32} V (peak {=f32} V)",
                    t.omega_m_rad_s,
                    seconds(elapsed),
                    t.v_bus_v,
                    self.spin_up_peak_v
                );
                self.check(reached, "top speed reached within 2 % in 0.5 s, no fault");
                if !reached {
                    return self.finish(slot);
                }
                // Re-armed: the stop's own peak and stop time.
                sim::start_stop_watch(STOP_SPEED_RAD_S);
                self.go(
                    Step::Stop,
                    t.periods,
                    slot,
                    Command::Velocity { rad_s: 0.0 },
                );
                None
            }
            Step::Stop => {
                let Some(w) = sim::stop_watch() else {
                    self.check(false, "stop watch armed");
                    return self.finish(slot);
                };
                let held = w
                    .last_above_period
                    .map_or(elapsed, |p| t.periods.saturating_sub(p));
                let fault = !fb.faults.is_empty();
                let over = elapsed >= periods(self.bounds.stop_s + HOLD_S);
                if held < periods(HOLD_S) && !fault && !over {
                    return None;
                }
                self.check_stop(fb, &w, t.brake_energy_j);
                self.finish(slot)
            }
        }
    }

    fn check_stop(&mut self, fb: &Feedback, w: &sim::StopWatch, brake_energy_j: f32) {
        let cfg = crate::config::cascade(board::PWM_FREQUENCY_HZ as f32);
        let over_voltage_v = cfg.current.supervisor.bus_over_voltage_v;
        let stop_s = seconds(w.settle_periods());
        let brake_j = brake_energy_j - w.brake_energy_at_arm_j;
        defmt::info!(
            "brake: peak bus {=f32} V (spin-up {=f32} V, over-voltage at {=f32} V), stopped below {=f32} rad/s after {=f32} s, brake energy {=f32} J, kinetic energy at the command {=f32} J",
            w.peak_v_bus_v,
            self.spin_up_peak_v,
            over_voltage_v,
            STOP_SPEED_RAD_S,
            stop_s,
            brake_j,
            w.kinetic_energy_at_arm_j
        );
        self.check(
            w.peak_v_bus_v < over_voltage_v && self.spin_up_peak_v < over_voltage_v,
            "peak bus voltage (spin-up and stop) below the over-voltage threshold",
        );
        self.check(
            fb.faults.is_empty() && fb.first_fault.is_none(),
            "no fault latched during the stop",
        );
        let stopped = w.settle_periods() > 0 && stop_s <= self.bounds.stop_s;
        if board::brake_output() {
            self.check(
                stopped,
                "stopped (below 2 rad/s for good) within 0.2 s with the brake resistor",
            );
            self.check(brake_j > 0.0, "the brake resistor absorbed energy");
        } else {
            self.check(
                stopped,
                "stopped (below 2 rad/s for good) within 0.4 s on the regen limit",
            );
        }
    }
}

/// True when QEMU passed `mission=brake`.
pub fn requested() -> bool {
    board::args().mission() == "brake"
}

static RUN: cortex_m::interrupt::Mutex<core::cell::RefCell<Option<Run>>> =
    cortex_m::interrupt::Mutex::new(core::cell::RefCell::new(None));

/// One housekeeping tick of the braking mission (created on first use);
/// see [`Run::tick`].
pub fn tick(fb: &Feedback, running: bool, slot: &mut CommandSlot) -> Option<u32> {
    let mut run = cortex_m::interrupt::free(|cs| RUN.borrow(cs).borrow_mut().take())
        .unwrap_or_else(|| Run::new(StopBounds::for_run()));
    let out = run.tick(fb, running, slot);
    cortex_m::interrupt::free(|cs| RUN.borrow(cs).replace(Some(run)));
    out
}
