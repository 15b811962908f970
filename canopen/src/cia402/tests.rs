//! Unit tests of the profile on a small fake drive.

extern crate std;

use foc_core::control::{Command, CommandError, Fault, FaultSet, Feedback, Limits, Mode};
use foc_core::drive::Status;
use foc_protocol::device::{DeviceContext, Refusal};
use foc_protocol::message::{
    Calibration, CurrentGains, ParamId, PositionGains, SpeedGains, Telemetry,
};

use super::units::*;
use super::*;

/// A drive that records what it is given; its feedback is set by the test.
struct Fake {
    fb: Feedback,
    running: bool,
    calibrated: bool,
    /// It runs without its angle sensor.
    sensorless: bool,
    injection: bool,
    faults: FaultSet,
    first: Option<Fault>,
    posted: Option<Command>,
    posts: u32,
    clears: u32,
    /// Faults survive a clear (the condition persists).
    sticky: bool,
    limits: Limits,
}

impl Fake {
    fn new() -> Self {
        let mut fb = Feedback::INIT;
        fb.v_bus_v = 24.0;
        Self {
            fb,
            running: true,
            calibrated: true,
            sensorless: false,
            injection: false,
            faults: FaultSet::EMPTY,
            first: None,
            posted: None,
            posts: 0,
            clears: 0,
            sticky: false,
            limits: Limits {
                max_current_a: 10.0,
                max_velocity_rad_s: 500.0,
                min_position_rad: -1000.0,
                max_position_rad: 1000.0,
                max_open_loop_voltage_v: 12.0,
                max_open_loop_omega_e_rad_s: 1000.0,
                max_kp_nm_per_rad: 50.0,
                max_kd_nm_s_per_rad: 2.0,
            },
        }
    }
    fn trip(&mut self, f: Fault) {
        self.faults.insert(f);
        self.first = self.first.or(Some(f));
        self.fb.mode = Mode::Disabled;
    }
}

impl DeviceContext for Fake {
    fn post(&mut self, cmd: Command) -> Result<(), CommandError> {
        self.posted = Some(cmd);
        self.posts += 1;
        self.fb.mode = cmd.mode();
        Ok(())
    }
    fn keep_alive(&mut self) {}
    fn mode(&self) -> Mode {
        self.fb.mode
    }
    fn faults(&self) -> (FaultSet, Option<Fault>) {
        (self.faults, self.first)
    }
    fn clear_faults(&mut self) {
        self.clears += 1;
        if !self.sticky {
            self.faults = FaultSet::EMPTY;
            self.first = None;
        }
    }
    fn report_fault(&mut self, f: Fault) {
        self.trip(f);
    }
    fn limits(&self) -> Limits {
        self.limits
    }
    fn set_limits(&mut self, _: Limits) -> Result<(), Refusal> {
        Err(Refusal::Unsupported)
    }
    fn torque_constant_nm_per_a(&self) -> f32 {
        0.05
    }
    fn feedback(&self) -> Feedback {
        self.fb
    }
    fn status(&self) -> Status {
        Status {
            running: self.running,
            mode: self.fb.mode,
            faulted: !self.faults.is_empty(),
            calibrated: self.calibrated,
            sensorless: self.sensorless,
            injection: self.injection,
            calibration: foc_core::drive::Progress::Idle,
        }
    }
    fn set_current_gains(&mut self, _: CurrentGains) -> Result<(), Refusal> {
        Err(Refusal::Unsupported)
    }
    fn set_speed_gains(&mut self, _: SpeedGains) -> Result<(), Refusal> {
        Err(Refusal::Unsupported)
    }
    fn set_position_gains(&mut self, _: PositionGains) -> Result<(), Refusal> {
        Err(Refusal::Unsupported)
    }
    fn set_dividers(&mut self, _: u16, _: u16) -> Result<(), Refusal> {
        Err(Refusal::Unsupported)
    }
    fn start_calibration(&mut self, _: Calibration) -> Result<(), Refusal> {
        Err(Refusal::Unsupported)
    }
    fn is_calibrated(&self) -> bool {
        self.calibrated
    }
    fn param(&self, id: ParamId) -> Option<f32> {
        match id {
            ParamId::PositionKp => Some(40.0),
            ParamId::SpeedKp => Some(0.5),
            _ => None,
        }
    }
    fn telemetry(&self) -> Telemetry {
        Telemetry::ZERO
    }
    fn firmware_version(&self) -> [u8; 3] {
        [0, 1, 0]
    }
}

const SHUTDOWN: u16 = 0x06;
const SWITCH_ON: u16 = 0x07;
const ENABLE: u16 = 0x0F;
const DISABLE_VOLTAGE: u16 = 0x00;
const QUICK_STOP: u16 = 0x02;
const RESET: u16 = 0x80;

/// A started profile in switch on disabled, mode `m`.
fn started(m: OpMode) -> (Cia402, Fake) {
    let mut ctx = Fake::new();
    let mut p = Cia402::new();
    p.update(0, &mut ctx);
    p.write_mode(m as i8, 0, &mut ctx).unwrap();
    (p, ctx)
}

fn cw(p: &mut Cia402, ctx: &mut Fake, w: u16) -> State {
    p.write_controlword(w, 0, ctx);
    p.update(0, ctx);
    p.state()
}

/// Reach `s` from switch on disabled through the table.
fn reach(p: &mut Cia402, ctx: &mut Fake, s: State) {
    let path: &[u16] = match s {
        State::SwitchOnDisabled => &[],
        State::ReadyToSwitchOn => &[SHUTDOWN],
        State::SwitchedOn => &[SHUTDOWN, SWITCH_ON],
        State::OperationEnabled => &[SHUTDOWN, SWITCH_ON, ENABLE],
        _ => &[SHUTDOWN, SWITCH_ON, ENABLE, QUICK_STOP],
    };
    for w in path {
        cw(p, ctx, *w);
    }
    assert_eq!(p.state(), s);
}

/// The standard's masks and values of the statusword's state bits.
fn state_of(sw: u16) -> Option<State> {
    let table = [
        (0x4F, 0x00, State::NotReadyToSwitchOn),
        (0x4F, 0x40, State::SwitchOnDisabled),
        (0x6F, 0x21, State::ReadyToSwitchOn),
        (0x6F, 0x23, State::SwitchedOn),
        (0x6F, 0x27, State::OperationEnabled),
        (0x6F, 0x07, State::QuickStopActive),
        (0x4F, 0x0F, State::FaultReactionActive),
        (0x4F, 0x08, State::Fault),
    ];
    table
        .iter()
        .find(|(m, v, _)| sw & m == *v)
        .map(|(_, _, s)| *s)
}

#[test]
fn boot_not_ready_then_switch_on_disabled() {
    let mut ctx = Fake::new();
    ctx.running = false;
    let mut p = Cia402::new();
    p.update(0, &mut ctx);
    assert_eq!(p.state(), State::NotReadyToSwitchOn);
    assert_eq!(
        state_of(p.actuals.statusword),
        Some(State::NotReadyToSwitchOn)
    );
    assert_eq!(cw(&mut p, &mut ctx, SHUTDOWN), State::NotReadyToSwitchOn);
    ctx.running = true;
    p.update(1000, &mut ctx);
    assert_eq!(p.state(), State::SwitchOnDisabled);
    assert_eq!(p.actuals.statusword, 0x0250);
}

#[test]
fn every_transition_of_the_table_and_its_statusword() {
    use State as S;
    // (from, controlword, to, statusword)
    let table = [
        (S::SwitchOnDisabled, SHUTDOWN, S::ReadyToSwitchOn, 0x0231), // 2
        (S::ReadyToSwitchOn, SWITCH_ON, S::SwitchedOn, 0x0233),      // 3
        (S::ReadyToSwitchOn, ENABLE, S::OperationEnabled, 0x1237),   // 3 + 4 (csv: bit 12)
        (S::SwitchedOn, ENABLE, S::OperationEnabled, 0x1237),        // 4
        (S::OperationEnabled, SWITCH_ON, S::SwitchedOn, 0x0233),     // 5
        (S::SwitchedOn, SHUTDOWN, S::ReadyToSwitchOn, 0x0231),       // 6
        (
            S::ReadyToSwitchOn,
            DISABLE_VOLTAGE,
            S::SwitchOnDisabled,
            0x0250,
        ), // 7
        (S::ReadyToSwitchOn, QUICK_STOP, S::SwitchOnDisabled, 0x0250), // 7
        (S::OperationEnabled, SHUTDOWN, S::ReadyToSwitchOn, 0x0231), // 8
        (
            S::OperationEnabled,
            DISABLE_VOLTAGE,
            S::SwitchOnDisabled,
            0x0250,
        ), // 9
        (S::SwitchedOn, DISABLE_VOLTAGE, S::SwitchOnDisabled, 0x0250), // 10
        (S::SwitchedOn, QUICK_STOP, S::SwitchOnDisabled, 0x0250),    // 10
        (
            S::QuickStopActive,
            DISABLE_VOLTAGE,
            S::SwitchOnDisabled,
            0x0250,
        ), // 12
        (S::QuickStopActive, ENABLE, S::OperationEnabled, 0x1237),   // 16 (option 6)
    ];
    for (from, w, to, sw) in table {
        let (mut p, mut ctx) = started(OpMode::CyclicVelocity);
        p.params.quick_stop_option = 6;
        reach(&mut p, &mut ctx, from);
        assert_eq!(cw(&mut p, &mut ctx, w), to, "{from:?} --{w:#06x}-->");
        assert_eq!(p.actuals.statusword, sw, "{from:?} --{w:#06x}--> {to:?}");
        assert_eq!(state_of(sw), Some(to));
        let bridge = matches!(to, S::OperationEnabled | S::QuickStopActive);
        assert_eq!(ctx.fb.mode != Mode::Disabled, bridge, "{from:?} -> {to:?}");
    }
}

#[test]
fn quick_stop_from_enabled_is_transition_11() {
    let (mut p, mut ctx) = started(OpMode::CyclicVelocity);
    p.params.quick_stop_option = 6;
    reach(&mut p, &mut ctx, State::OperationEnabled);
    assert_eq!(cw(&mut p, &mut ctx, QUICK_STOP), State::QuickStopActive);
    // At rest: the ramp is done at once, target reached.
    assert_eq!(p.actuals.statusword, 0x0617);
    assert_eq!(ctx.posted, Some(Command::Velocity { rad_s: 0.0 }));
}

#[test]
fn invalid_controlwords_change_nothing() {
    use State as S;
    for from in [
        S::SwitchOnDisabled,
        S::ReadyToSwitchOn,
        S::SwitchedOn,
        S::OperationEnabled,
    ] {
        for w in 0u16..0x80 {
            let (mut p, mut ctx) = started(OpMode::CyclicVelocity);
            p.params.quick_stop_option = 6;
            reach(&mut p, &mut ctx, from);
            let posts = ctx.posts;
            let to = cw(&mut p, &mut ctx, w);
            let valid = state::decode(w).and_then(|c| state::next(from, c));
            match valid {
                Some(s) => assert_eq!(to, s),
                None => {
                    assert_eq!(to, from, "{from:?} {w:#x}");
                    // Only the update's re-post in operation enabled.
                    let repost = u32::from(from == S::OperationEnabled);
                    assert_eq!(ctx.posts, posts + repost);
                }
            }
        }
    }
}

#[test]
fn quick_stop_active_refuses_enable_for_options_ending_disabled() {
    let (mut p, mut ctx) = started(OpMode::CyclicVelocity);
    p.params.quick_stop_option = 2;
    reach(&mut p, &mut ctx, State::OperationEnabled);
    ctx.fb.velocity_rad_s = 50.0;
    assert_eq!(cw(&mut p, &mut ctx, QUICK_STOP), State::QuickStopActive);
    assert_eq!(cw(&mut p, &mut ctx, ENABLE), State::QuickStopActive);
    assert_eq!(p.actuals.statusword & 0x6F, 0x07);
}

#[test]
fn fault_reaction_fault_and_reset() {
    let (mut p, mut ctx) = started(OpMode::CyclicVelocity);
    reach(&mut p, &mut ctx, State::OperationEnabled);
    ctx.trip(Fault::BusOverVoltage);
    ctx.fb.mode = Mode::Velocity; // the drive has not stepped yet
    p.update(1000, &mut ctx);
    assert_eq!(p.state(), State::FaultReactionActive);
    assert_eq!(ctx.posted, Some(Command::Disable));
    assert_eq!(
        state_of(p.actuals.statusword),
        Some(State::FaultReactionActive)
    );
    p.update(2000, &mut ctx);
    assert_eq!(p.state(), State::Fault);
    assert_eq!(p.actuals.statusword, 0x0238);
    assert_eq!(p.actuals.error_code, 0x3210);
    // Commands other than fault reset are ignored.
    assert_eq!(cw(&mut p, &mut ctx, SHUTDOWN), State::Fault);
    // Reset while the condition persists: stays.
    ctx.sticky = true;
    assert_eq!(cw(&mut p, &mut ctx, RESET), State::Fault);
    assert_eq!(cw(&mut p, &mut ctx, 0), State::Fault);
    assert_eq!(p.actuals.statusword, 0x0218);
    ctx.sticky = false;
    assert_eq!(cw(&mut p, &mut ctx, RESET), State::SwitchOnDisabled);
    assert_eq!(ctx.clears, 2);
    assert_eq!(p.actuals.error_code, 0);
    // Bit 7 held high is no new reset; the table goes on after it drops.
    assert_eq!(cw(&mut p, &mut ctx, SHUTDOWN), State::ReadyToSwitchOn);
}

#[test]
fn enable_without_calibration_or_mode_warns_and_stays_switched_on() {
    let (mut p, mut ctx) = started(OpMode::CyclicVelocity);
    ctx.calibrated = false;
    reach(&mut p, &mut ctx, State::ReadyToSwitchOn);
    assert_eq!(cw(&mut p, &mut ctx, ENABLE), State::SwitchedOn);
    assert_eq!(p.actuals.statusword, 0x02B3);
    assert_eq!(ctx.posts, 0);
    ctx.calibrated = true;
    assert_eq!(cw(&mut p, &mut ctx, ENABLE), State::OperationEnabled);
    assert_eq!(p.actuals.statusword & STATUS_WARNING, 0);
    let (mut p, mut ctx) = started(OpMode::NoMode);
    reach(&mut p, &mut ctx, State::SwitchedOn);
    assert_eq!(cw(&mut p, &mut ctx, ENABLE), State::SwitchedOn);
    assert_ne!(p.actuals.statusword & STATUS_WARNING, 0);
}

/// Without the angle sensor only the velocity modes enable: a position or
/// torque mode warns and stays switched on; switching to one while
/// enabled leaves operation with the warning.
#[test]
fn a_sensorless_drive_enables_the_velocity_modes_only() {
    for m in [
        OpMode::ProfilePosition,
        OpMode::CyclicPosition,
        OpMode::ProfileTorque,
        OpMode::CyclicTorque,
    ] {
        let (mut p, mut ctx) = started(m);
        ctx.sensorless = true;
        reach(&mut p, &mut ctx, State::SwitchedOn);
        assert_eq!(cw(&mut p, &mut ctx, ENABLE), State::SwitchedOn, "{m:?}");
        assert_ne!(p.actuals.statusword & STATUS_WARNING, 0);
        assert_eq!(ctx.posts, 0);
    }
    let (mut p, mut ctx) = started(OpMode::ProfileVelocity);
    ctx.sensorless = true;
    reach(&mut p, &mut ctx, State::OperationEnabled);
    assert_eq!(p.state(), State::OperationEnabled);
    p.write_mode(OpMode::ProfilePosition as i8, 0, &mut ctx)
        .unwrap();
    assert_eq!(p.state(), State::SwitchedOn);
    assert_eq!(ctx.posted, Some(Command::Disable));
    assert_ne!(p.actuals.statusword & STATUS_WARNING, 0);
}

/// Sensorless with injection (a salient motor, design §28): the position
/// and torque modes enable as with a sensor.
#[test]
fn a_sensorless_drive_with_injection_enables_every_mode() {
    for m in [
        OpMode::ProfilePosition,
        OpMode::CyclicPosition,
        OpMode::ProfileTorque,
        OpMode::CyclicTorque,
    ] {
        let (mut p, mut ctx) = started(m);
        ctx.sensorless = true;
        ctx.injection = true;
        reach(&mut p, &mut ctx, State::SwitchedOn);
        assert_eq!(
            cw(&mut p, &mut ctx, ENABLE),
            State::OperationEnabled,
            "{m:?}"
        );
        assert_eq!(p.actuals.statusword & STATUS_WARNING, 0, "{m:?}");
    }
}

#[test]
fn unsupported_mode_is_invalid_and_changes_nothing() {
    let (mut p, mut ctx) = started(OpMode::ProfileVelocity);
    for m in [2i8, 5, 6, 7, 11, -1, i8::MAX] {
        assert_eq!(p.write_mode(m, 0, &mut ctx), Err(Abort::InvalidValue));
    }
    assert_eq!(p.mode(), OpMode::ProfileVelocity);
    assert_eq!(p.requested_mode(), 3);
    p.update(0, &mut ctx);
    assert_eq!(p.actuals.mode_display, 3);
}

#[test]
fn operation_enabled_posts_at_every_update() {
    let (mut p, mut ctx) = started(OpMode::CyclicVelocity);
    reach(&mut p, &mut ctx, State::OperationEnabled);
    p.targets.velocity_inc_s = INC_PER_REV; // 1 rev/s
    let n = ctx.posts;
    for k in 1..=10 {
        p.update(k * 1000, &mut ctx);
    }
    assert_eq!(ctx.posts, n + 10);
    let tau = core::f32::consts::TAU;
    assert_eq!(ctx.posted, Some(Command::Velocity { rad_s: tau }));
    // Beyond the limits: clamped, internal limit active.
    p.targets.velocity_inc_s = i32::MAX;
    p.update(20_000, &mut ctx);
    assert_eq!(ctx.posted, Some(Command::Velocity { rad_s: 500.0 }));
    assert_ne!(p.actuals.statusword & STATUS_INTERNAL_LIMIT, 0);
}

#[test]
fn quick_stop_ramps_then_disables_option_2() {
    let (mut p, mut ctx) = started(OpMode::ProfileVelocity);
    p.params.quick_stop_deceleration_inc_s2 = 10 * INC_PER_REV as u32; // 62.8 rad/s^2
    reach(&mut p, &mut ctx, State::OperationEnabled);
    ctx.fb.velocity_rad_s = core::f32::consts::TAU; // 1 rev/s: 0.1 s to stop
    assert_eq!(cw(&mut p, &mut ctx, QUICK_STOP), State::QuickStopActive);
    let mut t = 0;
    let mut last = f32::INFINITY;
    while p.state() == State::QuickStopActive && t < 200_000 {
        t += 1000;
        p.update(t, &mut ctx);
        if let Some(Command::Velocity { rad_s }) = ctx.posted {
            assert!(rad_s <= last && rad_s >= 0.0);
            last = rad_s;
            ctx.fb.velocity_rad_s = rad_s; // an ideal drive
        }
    }
    assert_eq!(p.state(), State::SwitchOnDisabled);
    assert_eq!(ctx.posted, Some(Command::Disable));
    assert!((95_000..=105_000).contains(&t), "{t}");
    // A drive that does not stop: disabled after the standstill time-out.
    let (mut p, mut ctx) = started(OpMode::ProfileVelocity);
    reach(&mut p, &mut ctx, State::OperationEnabled);
    ctx.fb.velocity_rad_s = 1.0;
    assert_eq!(cw(&mut p, &mut ctx, QUICK_STOP), State::QuickStopActive);
    let mut t = 0;
    while p.state() == State::QuickStopActive && t < 1_000_000 {
        t += 1000;
        p.update(t, &mut ctx);
    }
    assert_eq!(t, 1000 + STANDSTILL_TIMEOUT_US, "ramp done at once");
}

#[test]
fn quick_stop_option_0_disables_at_once() {
    let (mut p, mut ctx) = started(OpMode::ProfileVelocity);
    p.params.quick_stop_option = 0;
    reach(&mut p, &mut ctx, State::OperationEnabled);
    assert_eq!(cw(&mut p, &mut ctx, QUICK_STOP), State::SwitchOnDisabled);
    assert_eq!(ctx.posted, Some(Command::Disable));
}

#[test]
fn following_error_latches_the_profile_fault() {
    let (mut p, mut ctx) = started(OpMode::CyclicPosition);
    p.params.following_error_window_inc = 1000;
    p.params.following_error_timeout_ms = 5;
    reach(&mut p, &mut ctx, State::OperationEnabled);
    p.targets.position_inc = 2000; // the fake never moves
    let (mut t, mut err) = (0, 0);
    while p.profile_fault().is_none() && t < 100_000 {
        err = p.actuals.following_error_inc;
        t += 1000;
        p.update(t, &mut ctx);
    }
    assert_eq!(t, 6000, "trips after more than 5 ms outside");
    assert_eq!(p.profile_fault(), Some(0x8611));
    assert_eq!(p.state(), State::FaultReactionActive);
    assert_eq!(ctx.posted, Some(Command::Disable));
    assert_eq!(err, 2000);
    p.update(t + 1000, &mut ctx);
    assert_eq!(p.state(), State::Fault);
    assert_ne!(p.actuals.statusword & STATUS_MODE_13, 0);
    assert_eq!(p.actuals.error_code, 0x8611);
    assert_eq!(cw(&mut p, &mut ctx, RESET), State::SwitchOnDisabled);
    assert_eq!(p.profile_fault(), None);
    assert_eq!(p.actuals.statusword & STATUS_MODE_13, 0);
}

#[test]
fn pp_set_point_acknowledge_target_reached_and_halt() {
    let (mut p, mut ctx) = started(OpMode::ProfilePosition);
    reach(&mut p, &mut ctx, State::OperationEnabled);
    p.targets.position_inc = 1000;
    p.write_controlword(ENABLE | 0x10, 0, &mut ctx);
    p.update(1000, &mut ctx);
    assert_ne!(p.actuals.statusword & STATUS_MODE_12, 0, "acknowledged");
    p.write_controlword(ENABLE, 1000, &mut ctx);
    p.update(1000, &mut ctx);
    assert_eq!(p.actuals.statusword & STATUS_MODE_12, 0);
    // The fake follows the demand exactly.
    let mut t = 1000;
    for _ in 0..100 {
        t += 1000;
        ctx.fb.position_rad = p.demand().pos_rad;
        p.update(t, &mut ctx);
    }
    assert_eq!(p.actuals.position_inc, 1000);
    assert_ne!(p.actuals.statusword & STATUS_TARGET_REACHED, 0);
    // A relative move of 10 rev, halted midway.
    p.targets.position_inc = 10 * INC_PER_REV;
    p.write_controlword(ENABLE | 0x50, t, &mut ctx);
    for _ in 0..200 {
        t += 1000;
        ctx.fb.position_rad = p.demand().pos_rad;
        p.update(t, &mut ctx);
    }
    assert_eq!(p.actuals.statusword & STATUS_TARGET_REACHED, 0);
    p.write_controlword(ENABLE | 0x150, t, &mut ctx);
    for _ in 0..200 {
        t += 1000;
        ctx.fb.position_rad = p.demand().pos_rad;
        p.update(t, &mut ctx);
    }
    assert_eq!(p.demand().vel_rad_s, 0.0);
    assert_ne!(p.actuals.statusword & STATUS_TARGET_REACHED, 0);
    // Released: the move resumes to 1000 + 10 rev.
    p.write_controlword(ENABLE, t, &mut ctx);
    for _ in 0..3000 {
        t += 1000;
        ctx.fb.position_rad = p.demand().pos_rad;
        p.update(t, &mut ctx);
    }
    assert_eq!(p.actuals.position_inc, 1000 + 10 * INC_PER_REV);
    assert_ne!(p.actuals.statusword & STATUS_TARGET_REACHED, 0);
}

#[test]
fn connection_lost_per_0x6007() {
    for (option, to) in [
        (0, State::OperationEnabled),
        (1, State::FaultReactionActive),
        (2, State::SwitchOnDisabled),
        (3, State::QuickStopActive),
    ] {
        let (mut p, mut ctx) = started(OpMode::CyclicVelocity);
        p.params.abort_connection_option = option;
        reach(&mut p, &mut ctx, State::OperationEnabled);
        ctx.fb.velocity_rad_s = 100.0;
        p.connection_lost(0, &mut ctx);
        assert_eq!(p.state(), to, "0x6007 = {option}");
        let timeout = ctx.faults.contains(Fault::CommandTimeout);
        assert_eq!(timeout, option == 1);
    }
}

#[test]
fn check_params_cross_fields() {
    let p = Cia402::new();
    let d = Params::DEFAULT;
    assert_eq!(p.check_params(&d), Ok(()));
    let fast = Params {
        profile_velocity_inc_s: d.max_profile_velocity_inc_s + 1,
        ..d
    };
    assert_eq!(p.check_params(&fast), Err(Abort::ValueTooHigh));
    for bad in [
        Params {
            profile_deceleration_inc_s2: 0,
            ..d
        },
        Params {
            quick_stop_deceleration_inc_s2: 0,
            ..d
        },
        Params {
            profile_acceleration_inc_s2: 0,
            ..d
        },
        Params {
            quick_stop_option: 3,
            ..d
        },
        Params {
            abort_connection_option: 4,
            ..d
        },
        Params {
            torque_slope_permille_s: 0,
            ..d
        },
    ] {
        assert_eq!(p.check_params(&bad), Err(Abort::InvalidValue), "{bad:?}");
    }
}

#[test]
fn nan_from_the_drive_reads_zero() {
    let (mut p, mut ctx) = started(OpMode::CyclicVelocity);
    ctx.fb.position_rad = f32::NAN;
    ctx.fb.velocity_rad_s = f32::INFINITY;
    ctx.fb.v_bus_v = f32::NAN;
    ctx.fb.i_dq_a.q = f32::NAN;
    p.update(0, &mut ctx);
    let a = p.actuals;
    assert_eq!((a.position_inc, a.velocity_inc_s), (0, i32::MAX));
    assert_eq!((a.dc_link_mv, a.torque_permille), (0, 0));
    assert_eq!(a.statusword & STATUS_VOLTAGE_ENABLED, 0);
}

#[test]
fn unit_conversions_round_and_saturate() {
    assert_eq!(rad_to_inc(core::f32::consts::TAU), INC_PER_REV);
    assert_eq!(rad_to_inc(-core::f32::consts::PI), -32_768);
    assert_eq!(rad_to_inc(RAD_PER_INC * 0.49), 0);
    assert_eq!(rad_to_inc(RAD_PER_INC * 0.51), 1);
    assert_eq!(rad_to_inc(-RAD_PER_INC * 0.51), -1);
    assert_eq!(rad_to_inc(f32::NAN), 0);
    assert_eq!(rad_to_inc(f32::INFINITY), i32::MAX);
    assert_eq!(rad_to_inc(f32::NEG_INFINITY), i32::MIN);
    assert_eq!(rad_to_inc(1e12), i32::MAX);
    assert!(inc_to_rad(i32::MIN).is_finite() && inc_to_rad(i32::MIN) < -200_000.0);
    assert_eq!(sat_i16(1e9), i16::MAX);
    assert_eq!(sat_i16(-1e9), i16::MIN);
    assert_eq!(amps_to_permille(5.0, 10.0), 500);
    assert_eq!(amps_to_permille(1e9, 10.0), i16::MAX);
    assert_eq!(amps_to_permille(1.0, 0.0), 0);
    assert_eq!(permille_to_amps(250.0, 8.0), 2.0);
    assert_eq!(permille_to_amps(f32::NAN, 8.0), 0.0);
    assert_eq!(volts_to_mv(24.0), 24_000);
    assert_eq!(volts_to_mv(-1.0), 0);
    let l = Fake::new().limits;
    assert_eq!(rated_torque_mnm(0.05, &l), 500);
    assert_eq!(rated_current_ma(&l), 10_000);
    assert_eq!(rated_torque_mnm(f32::NAN, &l), 0);
}

#[test]
fn tq_ramps_with_the_slope_and_limits_to_0x6072() {
    let (mut p, mut ctx) = started(OpMode::ProfileTorque);
    p.params.torque_slope_permille_s = 1000; // rated per second
    p.params.max_torque_permille = 300;
    reach(&mut p, &mut ctx, State::OperationEnabled);
    p.targets.torque_permille = 500;
    p.update(100_000, &mut ctx); // 0.1 s: 100 permille = 1 A
    assert_eq!(ctx.posted, Some(Command::Torque { iq_a: 1.0 }));
    for k in 2..=10 {
        p.update(k * 100_000, &mut ctx);
    }
    assert_eq!(ctx.posted, Some(Command::Torque { iq_a: 3.0 }));
    assert_ne!(p.actuals.statusword & STATUS_TARGET_REACHED, 0);
    assert_ne!(p.actuals.statusword & STATUS_INTERNAL_LIMIT, 0);
}

#[test]
fn csp_ignores_the_stale_target_until_a_new_one() {
    let (mut p, mut ctx) = started(OpMode::CyclicPosition);
    p.targets.position_inc = 5 * INC_PER_REV; // stale
    ctx.fb.position_rad = 1.0;
    reach(&mut p, &mut ctx, State::OperationEnabled);
    p.update(1000, &mut ctx);
    assert_eq!(p.demand().pos_rad, 1.0);
    assert_eq!(p.actuals.statusword & STATUS_MODE_12, 0);
    p.targets.position_inc = rad_to_inc(1.0) + 10;
    p.update(2000, &mut ctx);
    assert_ne!(p.actuals.statusword & STATUS_MODE_12, 0);
    assert_eq!(p.actuals.position_demand_inc, rad_to_inc(1.0) + 10);
}

mod never_panics {
    use super::*;
    use proptest::prelude::*;

    fn any_f32() -> impl Strategy<Value = f32> {
        prop_oneof![
            Just(f32::NAN),
            Just(f32::INFINITY),
            Just(-f32::INFINITY),
            -1e6f32..1e6f32,
            any::<f32>(),
        ]
    }

    proptest! {
        /// Any controlwords, modes, targets and feedback (NaN included):
        /// no panic, the statusword always shows the state, and a posted
        /// command always passed the drive's rules.
        #[test]
        fn any_sequence(
            steps in proptest::collection::vec(
                (any::<u16>(), any::<i8>(), any::<i32>(), any_f32(), any_f32(), any::<bool>()),
                1..60,
            )
        ) {
            let mut ctx = Fake::new();
            let mut p = Cia402::new();
            let mut t = 0u64;
            for (w, m, target, pos, vel, fault) in steps {
                t += 700;
                ctx.fb.position_rad = pos;
                ctx.fb.velocity_rad_s = vel;
                if fault && w % 7 == 0 {
                    ctx.trip(Fault::OverSpeed);
                }
                p.targets.position_inc = target;
                p.targets.velocity_inc_s = target;
                p.targets.torque_permille = target as i16;
                let _ = p.write_mode(m, t, &mut ctx);
                p.write_controlword(w, t, &mut ctx);
                p.update(t, &mut ctx);
                if w % 11 == 0 {
                    p.connection_lost(t, &mut ctx);
                }
                prop_assert_eq!(state_of(p.actuals.statusword), Some(p.state()));
                if let Some(c) = ctx.posted {
                    let l = ctx.limits;
                    prop_assert!(c == Command::Disable || c.validate(&l).is_ok(), "{:?}", c);
                }
            }
        }
    }
}
