//! The drive's per-period call, as the firmware's current-loop task makes
//! it: inputs from the mailboxes, `Drive::step` on the emulated board's
//! hardware (sensor reads and PWM write included), the feedback and status
//! published to memory the other tasks read: the firmware's own
//! `Drive::run_period`. Measured in every mode, at
//! the voltage limit, on command arrival and on faults; the speed and
//! position stages run between periods (untimed), as the firmware's lower
//! priority tasks do.

use super::{measure_rig, report, Stats};
use board_support::board;
use foc_core::calibration::offsets::OffsetLimits;
use foc_core::calibration::Calibrated;
use foc_core::control::angle_correction::{AngleCorrection, CORRECTION_BINS};
use foc_core::control::cogging::{CoggingMap, COGGING_BINS};
use foc_core::control::joint::{Impedance, JointConfig};
use foc_core::control::power::PowerLimitsConfig;
use foc_core::control::stage::{PositionStage, SpeedStage, VelocityRef};
use foc_core::control::{Command, CommandSlot, Feedback, Mode};
use foc_core::drive::cascade::CascadeConfig;
use foc_core::drive::{
    AngleKind, ConfigChange, Drive, JointChange, LifecycleConfig, Mail, Refusal, Status,
};

/// The emulated board's drive, as in the firmware.
pub type BoardDrive = Drive<board::Pwm, board::Currents, board::Angle, board::Bus, board::Brake>;

/// The firmware's state around the drive: mailboxes and published values.
pub struct Rig {
    drive: BoardDrive,
    /// The operator's command mailbox (`Shared::command`).
    pub slot: CommandSlot,
    /// The current stage's part of the configuration mailbox.
    mailbox: Option<ConfigChange>,
    /// The timer break's flag (`Shared::break_fired`).
    pub break_fired: bool,
    iq_ref_a: f32,
    /// Published feedback (`Shared::feedback`).
    pub published: Feedback,
    status: Status,
    speed: SpeedStage,
    position: PositionStage,
    vref: VelocityRef,
    run_slower: (bool, bool),
    /// The verdict on the last period's configuration change.
    last_change: Option<Result<(), Refusal>>,
}

/// The emulated board's configuration as the firmware builds it
/// (`config::cascade`: the simulated motor with its inertia, 10 A, the
/// board's power limits from `PowerLimitsConfig::for_board`, no brake
/// resistor, the current loop's dead-time compensation from
/// `board::DEAD_TIME_NS`), rebuilt here: the bench cannot reach the
/// firmware's private `config` module. Not set here: the sensor's counts
/// per turn for the supervisor's angle-step floor (the default floor
/// applies).
pub fn cascade() -> CascadeConfig {
    let m = board::SIM_MOTOR;
    let motor = super::motor();
    let mut c = CascadeConfig::for_motor_with_inertia(
        motor,
        board::PWM_FREQUENCY_HZ as f32,
        10.0,
        m.inertia_kg_m2,
    );
    c.current.power = Some(PowerLimitsConfig::for_board(
        &c.current.supervisor,
        motor,
        board::STAGE_TEMPERATURE_SENSOR,
    ));
    c.current.current.dead_time = super::dead_time_compensation();
    c
}

impl Rig {
    /// The drive from reset through its start-up (offsets, sensor check,
    /// the configured calibration installed as if restored from the store:
    /// the simulated encoder's zero is on the d axis), disabled.
    pub fn start(b: board::Board) -> Self {
        let cfg = cascade();
        let stored = Calibrated::supplied(cfg.current.angle, cfg.current.current).ok();
        let life = LifecycleConfig {
            offsets: Some(OffsetLimits {
                samples: 64,
                max_offset_a: 0.5,
                max_noise_a: 0.2,
            }),
            sensor_check_reads: 8,
            identification: None,
            identify_at_start_up: false,
            speed_divider: cfg.rates.speed_divider,
            position_divider: cfg.rates.position_divider,
            angle_kind: AngleKind::Absolute,
            stored,
        };
        let drive =
            Drive::new(b.pwm, b.currents, b.angle, b.bus, cfg.current, life).with_brake(b.brake);
        let mut rig = Self {
            drive,
            slot: CommandSlot::INIT,
            mailbox: None,
            break_fired: false,
            iq_ref_a: 0.0,
            published: Feedback::INIT,
            status: Status {
                running: false,
                mode: Mode::Disabled,
                faulted: false,
                calibrated: false,
                sensorless: false,
                injection: false,
                calibration: foc_core::drive::Progress::Idle,
            },
            speed: SpeedStage::new(cfg.speed),
            position: PositionStage::new(cfg.position),
            vref: VelocityRef::default(),
            run_slower: (false, false),
            last_change: None,
        };
        rig.run(200);
        rig
    }

    /// The firmware's per-period work: `Drive::run_period`, as `current_loop`
    /// calls it. Not included (firmware/src/main.rs `current_loop`): the
    /// interrupt's entry and exit, the RTIC lock of each shared resource
    /// (a BASEPRI raise and restore with `isb`s, about 6-8 instructions
    /// each, seven per period, eight when an event is logged), the DWT
    /// timing and its record, the run counter, the pends of the slower
    /// loops, the refusal and event logging (design §20).
    #[inline(never)]
    pub fn period(&mut self) {
        let mail = Mail {
            command: self.slot,
            iq_ref_a: self.iq_ref_a,
            change: &mut self.mailbox,
            gate_fault: core::mem::take(&mut self.break_fired) || board::gate_driver_fault(),
        };
        let out = self
            .drive
            .run_period(mail, &mut self.published, &mut self.status);
        self.run_slower = (out.run_speed, out.run_position);
        self.last_change = out.change;
    }

    /// The lower-priority tasks the period pended (untimed).
    pub fn slower(&mut self) {
        let (speed, position) = core::mem::take(&mut self.run_slower);
        if speed {
            self.iq_ref_a = self.speed.step(&self.published, self.vref);
        }
        if position {
            self.vref = self.position.step(&self.published);
        }
    }

    /// `n` periods with physics and the slower loops, untimed.
    pub fn run(&mut self, n: u32) {
        for _ in 0..n {
            board::sim::step_physics();
            self.period();
            self.slower();
        }
    }

    /// The verdict on the last period's configuration change.
    pub fn last_change(&self) -> Option<Result<(), Refusal>> {
        self.last_change
    }

    /// Posts a configuration change for the next period.
    pub fn set_mailbox(&mut self, change: ConfigChange) {
        self.mailbox = Some(change);
    }

    /// The drive (its hardware, for the breakdown's parts).
    pub fn drive_mut(&mut self) -> &mut BoardDrive {
        &mut self.drive
    }

    /// The status published last.
    pub fn status(&self) -> Status {
        self.status
    }
}

/// What a scenario must have shown, checked after it (a bench whose
/// inputs missed their case fails).
struct Expect {
    mode: Mode,
    bridge_on: bool,
    faulted: bool,
    min_voltage_limited: u32,
    /// Every timed period applied a configuration change.
    changes_applied: bool,
}

impl Expect {
    /// Closed loop in `mode`, bridge on, no fault, nothing else asked.
    const fn running(mode: Mode) -> Self {
        Self {
            mode,
            bridge_on: true,
            faulted: false,
            min_voltage_limited: 0,
            changes_applied: false,
        }
    }

    /// Bridge off, disabled, `faulted` or not.
    const fn off(faulted: bool) -> Self {
        Self {
            mode: Mode::Disabled,
            bridge_on: false,
            faulted,
            min_voltage_limited: 0,
            changes_applied: false,
        }
    }
}

/// One scenario: `setup` once, `prep` before each timed period.
fn scenario(
    rig: &mut Rig,
    baseline: u32,
    name: &str,
    setup: fn(&mut Rig),
    prep: fn(&mut Rig, u32),
    expect: Expect,
) -> Stats {
    setup(rig);
    let (mut limited, mut applied) = (0u32, 0u32);
    let stats = measure_rig(rig, baseline, 64, prep, &mut |r: &Rig| {
        limited += u32::from(r.published.voltage_limited);
        applied += u32::from(r.last_change == Some(Ok(())));
    });
    report(name, stats);
    let fb = &rig.published;
    // Every scenario keeps the calibration (a change that revoked it would
    // fail here, not in the next scenario).
    let ok = fb.mode == expect.mode
        && rig.drive.pwm_is_on() == expect.bridge_on
        && rig.status().calibrated
        && rig.status().faulted == expect.faulted
        && limited >= expect.min_voltage_limited
        && (applied == 64) == expect.changes_applied;
    defmt::println!(
        "INFO {=str}: mode {}, calibrated {}, faulted {}, bridge on {}, voltage-limited periods {=u32}/64, changes applied {=u32}/64, faults {=u32:#x}",
        name,
        fb.mode,
        rig.status().calibrated,
        rig.status().faulted,
        rig.drive.pwm_is_on(),
        limited,
        applied,
        fb.faults.0
    );
    if !ok {
        defmt::println!("BENCH-FAILED scenario {=str} missed its case", name);
        super::mission_exit(1);
    }
    stats
}

trait BridgeState {
    fn pwm_is_on(&self) -> bool;
}

impl BridgeState for BoardDrive {
    fn pwm_is_on(&self) -> bool {
        use foc_core::hal::PwmDriver;
        self.pwm.is_enabled()
    }
}

fn nothing(_: &mut Rig, _: u32) {}

/// An impedance hold at `p` [rad, rotor] with a tenth of the stiffness and
/// damping limits (design §21).
fn impedance_at(p: f32) -> Command {
    let l = cascade().current.limits;
    Command::Impedance(Impedance {
        position_rad: p,
        velocity_rad_s: 1.0,
        kp_nm_per_rad: 0.001 * l.max_kp_nm_per_rad,
        kd_nm_s_per_rad: 0.01 * l.max_kd_nm_s_per_rad,
        torque_ff_nm: 0.0,
        torque_limit_nm: f32::INFINITY,
    })
}

/// Travel limits 50 rad either side of `p` [rad, rotor], the soft stop
/// computed every period (design §21).
fn travel_around(p: f32) -> ConfigChange {
    let c = cascade();
    ConfigChange {
        joint: Some(JointChange {
            min_position_rad: p - 50.0,
            max_position_rad: p + 50.0,
            joint: JointConfig {
                travel: Some(c.default_travel()),
                ..c.current.joint
            },
        }),
        ..ConfigChange::default()
    }
}

/// The change the firmware makes when it adopts a stored record
/// (`comms::adopt`: limits, current loop, dividers, power limits, the
/// calibration permit, the mechanics and the d-current reference), with
/// the values in force:
/// applied whole while disabled, the stage stays calibrated. (A calibration
/// request merged into it would start a routine instead.)
fn same_configuration() -> ConfigChange {
    let c = cascade();
    ConfigChange {
        limits: Some(c.current.limits),
        current: Some(c.current.current),
        dividers: Some((c.rates.speed_divider, c.rates.position_divider)),
        power: Some(c.current.power),
        permit: Calibrated::supplied(c.current.angle, c.current.current).ok(),
        mechanics: c.mechanics,
        field: Some(c.current.field),
        ..ConfigChange::default()
    }
}

/// Install an anticogging map and an angle correction (design §32, §33)
/// of made-up values in the disabled drive: what a drive with both
/// calibrations stored runs.
#[inline(never)]
fn install_tables(r: &mut Rig) {
    r.slot.post(Command::Disable);
    r.run(4);
    let mut amps = [0.0f32; COGGING_BINS];
    for (k, a) in amps.iter_mut().enumerate() {
        *a = 0.05 * ((k % 43) as f32 - 21.0) / 21.0;
    }
    let mut rad = [0.0f32; CORRECTION_BINS];
    for (k, e) in rad.iter_mut().enumerate() {
        *e = 0.004 * ((k % 128) as f32 - 64.0) / 64.0;
    }
    let ok = match (
        CoggingMap::from_amps(&amps),
        AngleCorrection::from_rad(&rad),
        r.drive_mut().stage_while_disabled(),
    ) {
        (Ok(m), Ok(c), Some(stage)) => {
            stage.set_cogging(&m).is_ok() && stage.set_angle_correction(&c).is_ok()
        }
        _ => false,
    };
    if !ok {
        defmt::println!("BENCH-FAILED the tables were not installed");
        super::mission_exit(1);
    }
}

/// Every scenario; returns the worst case over all.
pub fn measure_all(rig: &mut Rig, baseline: u32) -> Stats {
    let runs = [
        scenario(
            rig,
            baseline,
            "drive period: disabled (bridge off)",
            |r| r.slot.post(Command::Disable),
            nothing,
            Expect::off(false),
        ),
        scenario(
            rig,
            baseline,
            "drive period: disabled, a stored record's configuration applied",
            |_| {},
            |r, _| r.mailbox = Some(same_configuration()),
            Expect {
                changes_applied: true,
                ..Expect::off(false)
            },
        ),
        scenario(
            rig,
            baseline,
            "drive period: torque 1 A",
            |r| {
                r.slot.post(Command::Torque { iq_a: 1.0 });
                r.run(100);
            },
            nothing,
            Expect::running(Mode::Torque),
        ),
        scenario(
            rig,
            baseline,
            "drive period: torque steps +-5 A, a new command every period",
            |_| {},
            |r, k| {
                let iq_a = if (k / 8) % 2 == 0 { 5.0 } else { -5.0 };
                r.slot.post(Command::Torque { iq_a });
            },
            Expect::running(Mode::Torque),
        ),
        scenario(
            rig,
            baseline,
            "drive period: velocity 150 rad/s (speed stage between periods)",
            |r| {
                r.slot.post(Command::Velocity { rad_s: 150.0 });
                r.run(400);
            },
            nothing,
            Expect::running(Mode::Velocity),
        ),
        scenario(
            rig,
            baseline,
            "drive period: velocity 420 rad/s (voltage limit, back-EMF)",
            |r| {
                r.slot.post(Command::Velocity { rad_s: 420.0 });
                r.run(2000);
            },
            nothing,
            Expect {
                min_voltage_limited: 32,
                ..Expect::running(Mode::Velocity)
            },
        ),
        scenario(
            rig,
            baseline,
            "drive period: position move (trajectory, speed and position stages)",
            |r| {
                let target = r.published.position_rad + 20.0;
                r.slot.post(Command::Position { rad: target });
                r.run(50);
            },
            nothing,
            Expect::running(Mode::Position),
        ),
        super::sweeps::drive_run(
            rig,
            baseline,
            "drive period: encoder linearisation, every period of a whole run",
            |c| c.calibrate_encoder = true,
            6.0,
        ),
        super::sweeps::drive_run(
            rig,
            baseline,
            "drive period: anticogging calibration, every period of a whole run",
            |c| c.calibrate_cogging = true,
            24.0,
        ),
        scenario(
            rig,
            baseline,
            "drive period: impedance, travel limits, a new command every 20 periods (1 kHz)",
            |r| {
                let p = r.published.position_rad;
                r.mailbox = Some(travel_around(p));
                r.slot.post(impedance_at(p));
                r.run(100);
            },
            |r, k| {
                if k % 20 == 0 {
                    r.slot.post(impedance_at(r.published.position_rad));
                }
            },
            Expect::running(Mode::Impedance),
        ),
        scenario(
            rig,
            baseline,
            "drive period: torque 1 A, anticogging map and angle correction on",
            |r| {
                install_tables(r);
                r.slot.post(Command::Torque { iq_a: 1.0 });
                r.run(100);
            },
            nothing,
            Expect::running(Mode::Torque),
        ),
        scenario(
            rig,
            baseline,
            "drive period: fault found (break input, after a clear)",
            |r| r.slot.post(Command::Torque { iq_a: 1.0 }),
            |r, _| {
                r.slot.request_clear();
                r.slot.post(Command::Torque { iq_a: 1.0 });
                r.break_fired = true;
            },
            Expect::off(true),
        ),
        scenario(
            rig,
            baseline,
            "drive period: fault latched (safe state)",
            |r| r.break_fired = true,
            nothing,
            Expect::off(true),
        ),
    ];
    let mut worst = runs[0];
    for s in &runs[1..] {
        worst.min = worst.min.min(s.min);
        worst.max = worst.max.max(s.max);
        worst.median = worst.median.max(s.median);
    }
    worst.mean = runs.iter().map(|s| s.mean).sum::<f32>() / runs.len() as f32;
    report(
        "drive per-period call, every scenario above (worst case; median: the largest scenario median)",
        worst,
    );
    worst
}
