//! `foc_core::drive::Drive` over fake hardware: the bridge stays off during
//! start-up, offsets reach the current sensing, a supplied permit unlocks
//! closed loop, and a hardware fault latch (a timer break) is one-way until
//! the operator's explicit clear.
// Test support outside `#[test]` functions: unwrapping and indexing here fails the build or the test,
// which is what it should do (the no-panic lints are for the MCU's code).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use foc_core::angle::MechanicalAngle;
use foc_core::calibration::offsets::OffsetLimits;
use foc_core::calibration::Calibrated;
use foc_core::control::power::PowerLimitsConfig;
use foc_core::control::{Command, CommandSlot, Fault, Feedback, Mode, MotorParams};
use foc_core::drive::cascade::CascadeConfig;
use foc_core::drive::{
    AngleKind, ConfigChange, Drive, Event, Inputs, LifePhase, LifecycleConfig, Mail, Output,
    Refusal, Status,
};
use foc_core::frames::Abc;
use foc_core::hal::{AngleSensor, BrakeOutput, BusVoltage, CurrentSense, PhaseCurrents, PwmDriver};

/// A PWM with a break latch like the STM32 boards': set by the break,
/// refused `enable` while set, released only by `release_fault_latch`.
#[derive(Default)]
struct Pwm {
    on: bool,
    latched: bool,
    enables_refused: u32,
}

impl PwmDriver for Pwm {
    type Error = ();
    fn period_counts(&self) -> u16 {
        4200
    }
    fn set_compare(&mut self, _: [u16; 3]) -> Result<(), ()> {
        Ok(())
    }
    fn enable(&mut self) -> Result<(), ()> {
        if self.latched {
            self.enables_refused += 1;
            return Err(());
        }
        self.on = true;
        Ok(())
    }
    fn disable(&mut self) {
        self.on = false;
    }
    fn is_enabled(&self) -> bool {
        self.on
    }
    fn release_fault_latch(&mut self) {
        self.latched = false;
    }
}

/// Currents with a constant sensor offset of 0.1 A on phase A.
#[derive(Default)]
struct Cs {
    offsets: Abc,
}
impl CurrentSense for Cs {
    type Error = ();
    fn read_currents(&mut self) -> Result<PhaseCurrents, ()> {
        Ok(PhaseCurrents::TwoPhase {
            a_a: 0.1 - self.offsets.a,
            b_a: -self.offsets.b,
        })
    }
    fn offsets_a(&self) -> Abc {
        self.offsets
    }
    fn set_offsets_a(&mut self, o: Abc) {
        self.offsets = o;
    }
}
struct Enc;
impl AngleSensor for Enc {
    type Error = ();
    fn read_angle(&mut self) -> Result<MechanicalAngle, ()> {
        Ok(MechanicalAngle::ZERO)
    }
}
struct Bus;
impl BusVoltage for Bus {
    type Error = ();
    fn read_bus_voltage_v(&mut self) -> Result<f32, ()> {
        Ok(24.0)
    }
}

/// One period, the feedback written into a scratch copy.
fn step<B: BusVoltage, K: BrakeOutput>(
    d: &mut Drive<Pwm, Cs, Enc, B, K>,
    inputs: &Inputs,
) -> Output {
    let mut fb = Feedback::INIT;
    d.step(inputs, &mut fb)
}

fn drive() -> (Drive<Pwm, Cs, Enc, Bus>, CascadeConfig) {
    drive_with(AngleKind::Incremental, false, |_| None)
}

/// A drive whose lifecycle holds the permit `stored(cfg)` from its store.
fn drive_with(
    kind: AngleKind,
    identify_at_start_up: bool,
    stored: impl Fn(&CascadeConfig) -> Option<Calibrated>,
) -> (Drive<Pwm, Cs, Enc, Bus>, CascadeConfig) {
    let motor = MotorParams {
        pole_pairs: 7,
        r_ohm: 0.1,
        ld_h: 40e-6,
        lq_h: 40e-6,
        flux_linkage_wb: 0.004,
    };
    let cfg = CascadeConfig::for_motor(motor, 20_000.0, 10.0);
    let life = LifecycleConfig {
        offsets: Some(OffsetLimits {
            samples: 16,
            max_offset_a: 0.5,
            max_noise_a: 0.1,
        }),
        sensor_check_reads: 4,
        identification: identify_at_start_up.then(|| {
            foc_core::calibration::identification::IdentificationConfig::new(7, 20_000.0, 1.0, 2.0)
        }),
        identify_at_start_up,
        speed_divider: 10,
        position_divider: 20,
        angle_kind: kind,
        stored: stored(&cfg),
    };
    let d = Drive::new(Pwm::default(), Cs::default(), Enc, Bus, cfg.current, life);
    (d, cfg)
}

#[test]
fn start_up_then_supplied_permit_then_break_latch_until_clear() {
    let (mut d, cfg) = drive();
    let mut slot = CommandSlot::INIT;
    let mut inputs = Inputs::new(slot, 0.0);
    for _ in 0..20 {
        step(&mut d, &inputs);
        assert!(!d.pwm.on, "bridge on during start-up");
    }
    assert_eq!(d.lifecycle().phase(), LifePhase::Run);
    assert!(
        (d.currents.offsets.a - 0.1).abs() < 1e-6,
        "offsets installed"
    );

    // A supplied permit, applied at the period boundary.
    let permit = Calibrated::supplied(cfg.current.angle, cfg.current.current).unwrap();
    let change = ConfigChange {
        permit: Some(permit),
        ..ConfigChange::default()
    };
    inputs.change = Some(&change);
    assert_eq!(step(&mut d, &inputs).change, Some(Ok(())));
    inputs.change = None;
    assert!(d.status().calibrated);
    slot.post(Command::Torque { iq_a: 1.0 });
    inputs.command = slot;
    step(&mut d, &inputs);
    assert!(d.pwm.on);

    // The break fires: the board turned the outputs off and latched.
    d.pwm.on = false;
    d.pwm.latched = true;
    inputs.gate_fault = true;
    step(&mut d, &inputs);
    inputs.gate_fault = false;
    assert_eq!(
        d.stage().supervisor().first_fault(),
        Some(Fault::GateDriverFault)
    );
    // A new command while faulted: refused; the bridge stays off.
    slot.post(Command::Torque { iq_a: 1.0 });
    inputs.command = slot;
    for _ in 0..5 {
        step(&mut d, &inputs);
        assert!(!d.pwm.on);
    }
    assert!(d.pwm.latched, "latch released without a clear");
    // The explicit clear releases the latch; the next command runs.
    slot.request_clear();
    inputs.command = slot;
    step(&mut d, &inputs);
    assert!(!d.pwm.latched);
    slot.post(Command::Torque { iq_a: 1.0 });
    inputs.command = slot;
    step(&mut d, &inputs);
    assert!(d.pwm.on);
    assert_eq!(d.pwm.enables_refused, 0);
}

/// The firmware's side of `Drive::run_period`: its mailboxes and the
/// copies the other tasks read.
struct Firmware {
    mailbox: Option<ConfigChange>,
    feedback: Feedback,
    status: Status,
    slot: CommandSlot,
}

impl Firmware {
    fn new(status: Status) -> Self {
        Self {
            mailbox: None,
            feedback: Feedback::INIT,
            status,
            slot: CommandSlot::INIT,
        }
    }

    /// One period, as `current_loop` makes it.
    fn period(&mut self, d: &mut Drive<Pwm, Cs, Enc, Bus>, gate_fault: bool) -> Output {
        let mail = Mail {
            command: self.slot,
            iq_ref_a: 0.0,
            change: &mut self.mailbox,
            gate_fault,
        };
        d.run_period(mail, &mut self.feedback, &mut self.status)
    }
}

/// `Drive::run_period`, as the firmware calls it: a change waiting in the
/// mailbox is applied once (the mailbox is empty after the period, its
/// verdict is in the output), the feedback is written into
/// the caller's copy in `Run` and left alone during start-up, the status
/// is published every period, and the command and gate flag come from the
/// mail each period.
#[test]
fn run_period_takes_a_change_once_and_publishes_in_place() {
    let (mut d, cfg) = drive();
    let mut fw = Firmware::new(d.status());
    fw.feedback.period = 12_345; // a marker: start-up must not touch it
    for _ in 0..20 {
        fw.period(&mut d, false);
    }
    assert_eq!(d.lifecycle().phase(), LifePhase::Run);
    assert_eq!(fw.feedback.period, 12_345, "start-up wrote the feedback");
    assert!(fw.status.running && !fw.status.calibrated);

    // A permit in the mailbox: applied this period, once.
    let permit = Calibrated::supplied(cfg.current.angle, cfg.current.current).unwrap();
    fw.mailbox = Some(ConfigChange {
        permit: Some(permit),
        ..ConfigChange::default()
    });
    let out = fw.period(&mut d, false);
    assert_eq!(out.change, Some(Ok(())));
    assert!(fw.mailbox.is_none());
    assert!(fw.status.calibrated, "status not published");
    assert_ne!(fw.feedback.period, 12_345, "feedback not written in Run");
    let out = fw.period(&mut d, false);
    assert_eq!(out.change, None, "a change applied twice");

    // The command from the mail: torque, bridge on, published.
    fw.slot.post(Command::Torque { iq_a: 1.0 });
    let before = fw.feedback.period;
    fw.period(&mut d, false);
    assert!(d.pwm.on);
    assert_eq!(fw.feedback.period, before.wrapping_add(1));
    assert_eq!(fw.feedback.mode, Mode::Torque);
    assert_eq!(fw.status.mode, Mode::Torque);
    // A change while running: refused whole, the mailbox emptied anyway
    // (the verdict goes back to the operator), nothing changed.
    let limits_before = *d.stage().config();
    fw.mailbox = Some(ConfigChange {
        limits: Some(cfg.current.limits),
        ..ConfigChange::default()
    });
    let out = fw.period(&mut d, false);
    assert_eq!(out.change, Some(Err(Refusal::NotDisabled)));
    assert!(fw.mailbox.is_none());
    assert_eq!(*d.stage().config(), limits_before);
    assert!(d.pwm.on);
    // The gate flag from the mail: latched, bridge off, published.
    fw.period(&mut d, true);
    assert!(!d.pwm.on);
    assert!(fw.status.faulted);
    assert_eq!(fw.feedback.first_fault, Some(Fault::GateDriverFault));
}

/// The break fires while the period's inputs were already read (no fault
/// flag yet): `enable` is refused, the fault latched, the bridge off.
#[test]
fn break_between_reading_the_inputs_and_driving_the_bridge() {
    let (mut d, cfg) = drive();
    let mut slot = CommandSlot::INIT;
    let mut inputs = Inputs::new(slot, 0.0);
    for _ in 0..20 {
        step(&mut d, &inputs);
    }
    let permit = Calibrated::supplied(cfg.current.angle, cfg.current.current).unwrap();
    let change = ConfigChange {
        permit: Some(permit),
        ..ConfigChange::default()
    };
    inputs.change = Some(&change);
    step(&mut d, &inputs);
    inputs.change = None;
    slot.post(Command::Torque { iq_a: 1.0 });
    inputs.command = slot;
    d.pwm.latched = true; // the break fired, the flag not seen yet
    step(&mut d, &inputs);
    assert!(!d.pwm.on);
    assert_eq!(d.pwm.enables_refused, 1);
    assert_eq!(d.stage().supervisor().first_fault(), Some(Fault::PwmError));
    step(&mut d, &inputs);
    assert!(!d.pwm.on);
}

/// Start-up from reset: the events seen, whether the bridge ever conducted.
fn start_up(d: &mut Drive<Pwm, Cs, Enc, Bus>, periods: u32) -> (Vec<Event>, bool) {
    let inputs = Inputs::new(CommandSlot::INIT, 0.0);
    let mut events = Vec::new();
    let mut bridge_on = false;
    for _ in 0..periods {
        let out = step(d, &inputs);
        bridge_on |= d.pwm.on;
        events.extend(out.event);
    }
    (events, bridge_on)
}

fn permit(cfg: &CascadeConfig) -> Option<Calibrated> {
    Calibrated::supplied(cfg.current.angle, cfg.current.current).ok()
}

#[test]
fn a_stored_permit_calibrates_absolute_and_hall_sensors_at_boot_without_motion() {
    for kind in [AngleKind::Absolute, AngleKind::Hall] {
        // Identification at start-up is configured: the stored calibration
        // replaces it.
        let (mut d, _) = drive_with(kind, true, permit);
        let (events, bridge_on) = start_up(&mut d, 20);
        assert_eq!(d.lifecycle().phase(), LifePhase::Run, "{kind:?}");
        assert!(d.status().calibrated, "{kind:?}: permit installed");
        assert!(!bridge_on, "{kind:?}: no motion before the first command");
        assert_eq!(events.last(), Some(&Event::CalibrationRestored), "{kind:?}");
        assert!(!events.contains(&Event::IdentificationStarted), "{kind:?}");
        // And it unlocks closed loop.
        let mut slot = CommandSlot::INIT;
        slot.post(Command::Torque { iq_a: 1.0 });
        step(&mut d, &Inputs::new(slot, 0.0));
        assert!(d.pwm.on, "{kind:?}: torque accepted");
    }
}

#[test]
fn an_incremental_encoder_ignores_a_stored_zero() {
    // Without start-up identification: uncalibrated, closed loop refused.
    let (mut d, _) = drive_with(AngleKind::Incremental, false, permit);
    let (events, bridge_on) = start_up(&mut d, 20);
    assert_eq!(d.lifecycle().phase(), LifePhase::Run);
    assert!(!d.status().calibrated);
    assert!(!bridge_on);
    assert_eq!(events.last(), Some(&Event::StartUpDone));
    // With it: the identification runs as if nothing were stored.
    let (mut d, _) = drive_with(AngleKind::Incremental, true, permit);
    let (events, _) = start_up(&mut d, 20);
    assert_eq!(events.last(), Some(&Event::IdentificationStarted));
    assert_eq!(d.lifecycle().phase(), LifePhase::Identify);
}

#[test]
fn no_stored_permit_means_start_up_as_before() {
    for kind in [AngleKind::Absolute, AngleKind::Hall, AngleKind::Incremental] {
        let (mut d, _) = drive_with(kind, false, |_| None);
        let (events, _) = start_up(&mut d, 20);
        assert!(!d.status().calibrated, "{kind:?}");
        assert_eq!(events.last(), Some(&Event::StartUpDone), "{kind:?}");
    }
}

/// A bus whose voltage the test sets.
struct SetBus(f32);
impl BusVoltage for SetBus {
    type Error = ();
    fn read_bus_voltage_v(&mut self) -> Result<f32, ()> {
        if self.0.is_nan() {
            Err(())
        } else {
            Ok(self.0)
        }
    }
}

/// A brake switch that counts its switchings.
#[derive(Default)]
struct Brake {
    on: bool,
    switchings: u32,
}
impl BrakeOutput for Brake {
    fn set_brake(&mut self, on: bool) {
        self.switchings += u32::from(self.on != on);
        self.on = on;
    }
    fn is_brake_on(&self) -> bool {
        self.on
    }
}

type BrakeDrive = Drive<Pwm, Cs, Enc, SetBus, Brake>;

/// A drive with a settable bus and a brake switch, its stage made by
/// `stage` from the 7-pole-pair test motor's cascade, with `offsets`.
fn brake_drive(
    offsets: Option<OffsetLimits>,
    stage: impl Fn(&CascadeConfig) -> foc_core::control::stage::CurrentStageConfig,
) -> (BrakeDrive, CascadeConfig) {
    let motor = MotorParams {
        pole_pairs: 7,
        r_ohm: 0.1,
        ld_h: 40e-6,
        lq_h: 40e-6,
        flux_linkage_wb: 0.004,
    };
    let cfg = CascadeConfig::for_motor(motor, 20_000.0, 10.0);
    let life = LifecycleConfig {
        offsets,
        sensor_check_reads: 4,
        identification: None,
        identify_at_start_up: false,
        speed_divider: 10,
        position_divider: 20,
        angle_kind: AngleKind::Incremental,
        stored: None,
    };
    let d = Drive::new(
        Pwm::default(),
        Cs::default(),
        Enc,
        SetBus(24.0),
        stage(&cfg),
        life,
    )
    .with_brake(Brake::default());
    (d, cfg)
}

#[test]
fn the_brake_follows_the_power_limits_chopper_with_hysteresis_and_goes_off_with_them() {
    let (mut d, cfg) = brake_drive(None, |c| c.current);
    let motor = cfg.current.current.motor;
    let mut inputs = Inputs::new(CommandSlot::INIT, 0.0);
    let steps = |d: &mut BrakeDrive, inputs: &Inputs, v: f32| {
        d.bus.0 = v;
        for _ in 0..3 {
            step(d, inputs);
        }
        d.brake.on
    };
    for _ in 0..10 {
        step(&mut d, &inputs);
    }
    assert_eq!(d.lifecycle().phase(), LifePhase::Run);
    // No power limits: the brake never conducts (below the over-voltage
    // threshold, 30 V).
    assert!(!steps(&mut d, &inputs, 29.0));
    // Limits with a brake resistor, given with another motor model: the
    // stage's motor replaces it.
    let mut other = motor;
    other.r_ohm = 5.0;
    let p =
        PowerLimitsConfig::for_board(&cfg.current.supervisor, other, false).with_brake_resistor();
    d.bus.0 = 24.0;
    let change = ConfigChange {
        power: Some(Some(p)),
        ..ConfigChange::default()
    };
    inputs.change = Some(&change);
    step(&mut d, &inputs);
    inputs.change = None;
    let installed = d.stage().config().power.expect("installed");
    assert_eq!(installed.motor, cfg.current.current.motor);
    let (on_v, off_v) = (p.brake_on_v, p.brake_off_v);
    assert!(off_v < on_v && on_v < cfg.current.supervisor.bus_over_voltage_v);
    assert!(!steps(&mut d, &inputs, off_v - 0.1));
    assert!(steps(&mut d, &inputs, on_v + 0.1), "on above brake_on_v");
    assert!(steps(&mut d, &inputs, 0.5 * (on_v + off_v)), "hysteresis");
    assert!(
        !steps(&mut d, &inputs, off_v - 0.1),
        "off below brake_off_v"
    );
    assert!(steps(&mut d, &inputs, on_v + 0.1));
    // A failed bus reading: off (never switched on blindly).
    assert!(!steps(&mut d, &inputs, f32::NAN));
    assert!(steps(&mut d, &inputs, on_v + 0.1));
    // Power limits switched off: the brake goes off with them.
    let change = ConfigChange {
        power: Some(None),
        ..ConfigChange::default()
    };
    inputs.change = Some(&change);
    step(&mut d, &inputs);
    assert!(!d.brake.on);
    assert!(d.stage().config().power.is_none());
    assert_eq!(d.brake.switchings, 6);
}

#[test]
fn the_brake_works_during_the_start_up_calibrations_and_its_guard_locks_it_out() {
    let offsets = OffsetLimits {
        samples: 64,
        max_offset_a: 0.5,
        max_noise_a: 0.1,
    };
    let (mut d, _) = brake_drive(Some(offsets), |c| {
        let p = PowerLimitsConfig::for_board(&c.current.supervisor, c.current.current.motor, false)
            .with_brake_resistor();
        let mut stage = c.current;
        stage.power = Some(p);
        stage
    });
    let p = d.stage().config().power.expect("configured");
    let inputs = Inputs::new(CommandSlot::INIT, 0.0);
    step(&mut d, &inputs);
    assert_eq!(d.lifecycle().phase(), LifePhase::OffsetCalibration);
    // A coasting motor pumps the bus during the offset calibration.
    d.bus.0 = p.brake_on_v + 0.5;
    step(&mut d, &inputs);
    assert_eq!(d.lifecycle().phase(), LifePhase::OffsetCalibration);
    assert!(d.brake.on, "brake on while calibrating");
    d.bus.0 = p.brake_off_v - 0.5;
    step(&mut d, &inputs);
    assert!(!d.brake.on);
    // A supply that holds the bus above the thresholds: the guard locks
    // the brake out after brake_max_on_s (1 s = 20 000 periods).
    d.bus.0 = p.brake_on_v + 0.5;
    let mut on_periods = 0;
    for _ in 0..25_000 {
        step(&mut d, &inputs);
        on_periods += u32::from(d.brake.on);
    }
    assert!(!d.brake.on, "locked out");
    assert!(
        (19_990..=20_001).contains(&on_periods),
        "{on_periods} periods on"
    );
    assert!(!d.pwm.on);
}
