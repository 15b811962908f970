//! # The RTIC v2 FOC application
//!
//! One binary per board (`cargo xtask build --board <name>`). Tasks, from
//! the highest priority down:
//!
//! | task | bound to | priority | rate (20 kHz PWM) | does |
//! |---|---|---|---|---|
//! | `bridge_break` | `TIM1_BRK_TIM9` | 5 | on fault | timer break / gate-driver fault: bridge off, latch `GateDriverFault` |
//! | `current_loop` | `ADC` (injected end of conversion, triggered by TIM1 at the PWM centre) | 4 | every PWM period, 20 kHz | glue: read the shared inputs, `Drive::run_period` once (sensors, lifecycle, bridge; feedback and status written in place), pend the slower loops, time itself |
//! | `speed_loop` | `EXTI1` (pended by `current_loop`) | 3 | every `SPEED_DIVIDER` = 10 periods, 2 kHz | `SpeedStage::step`: velocity PI -> `iq_ref` |
//! | `position_loop` | `EXTI2` (pended by `current_loop`) | 2 | every `POSITION_DIVIDER` = 20 periods, 1 kHz | `PositionStage::step`: trajectory + P -> velocity reference |
//! | `housekeeping` | `EXTI3` (pended by `current_loop`) | 1 | every 400 periods, 50 Hz | start-up command, telemetry log, command-channel poll (link watchdog, homing steps, streamed telemetry too, as `stream` does) |
//! | `stream` | `EXTI4` (pended by `current_loop`, and by the CAN interrupt) | 1 | every `STREAM_DIVIDER` = 20 periods, 1 kHz | boards with CAN: the CANopen node (received frames, tick); the telemetry stream (`DeviceState::poll_stream`): a sample when one is due, up to what the UART carries (about 190 Hz at 115200 baud) |
//! | `serial` | `USART2` (`board::SERIAL_IRQ`, the command UART) | 1 | per received / sent byte | command channel: bytes to `DeviceState::on_byte`, replies queued (see `comms`) |
//! | (CAN) | `board::CAN_RX_IRQ` (`CAN1_RX0` on the ODrive, `USART3` under QEMU; boards with CAN only) | lowest (as 1) | per received frame / byte | outside RTIC, shares nothing: masks itself and pends `stream`, which runs the CANopen node (see `can`) and unmasks it |
//! | `idle` | - | 0 | background | feeds the watchdog only while the current loop runs |
//!
//! `EXTI1..4` are used only as software-pended vectors: no EXTI line is
//! configured, so nothing else can trigger them.
//!
//! Start-up is decided by `foc_core::drive` (host-tested there, and run by
//! the bench's simulations): clocks and pins (`board::init`, bridge off),
//! current-offset calibration (1024 periods with the bridge off, rejected
//! when far from mid-scale or noisy), an angle-sensor check, then (emulated
//! board, or `config::IDENTIFY_AT_STARTUP`) the motor identification, then
//! the disabled mode, waiting for a command (`config::START_COMMAND` is
//! `None` by default). Until an identification (at start-up or on command)
//! has succeeded the current stage is uncalibrated and refuses torque,
//! velocity and position commands: a motor never runs closed loop on an
//! unknown electrical zero.
//!
//! The tables kept with the configuration (the anticogging map and the
//! angle correction, 1.5 KB) never cross the configuration mailbox: the
//! stored ones are installed in `init` before the interrupt runs, later
//! ones from priority 1 under the `drive` lock with the bridge off, and a
//! table a calibration measured is taken back the same way (see `comms`).
//!
//! Safety: any fault latched by the supervisor puts the bridge in the safe
//! state in the same period. The panic and HardFault handlers call
//! `board::emergency_disable()` before anything else, then log.
#![no_std]
#![no_main]

#[cfg(feature = "can")]
mod can;
mod comms;
mod config;
mod events;
mod persist;
mod timing;
mod watchdog;

use board_support::board;
use core::sync::atomic::AtomicU32;
#[cfg(not(feature = "qemu"))]
use defmt_rtt as _;
#[cfg(feature = "qemu")]
use defmt_semihosting as _;

/// Boards without a CAN port: the `can` shared resource is empty (no
/// node, no code, no RAM).
#[cfg(not(feature = "can"))]
mod can {
    /// Nothing: the board has no CAN port.
    pub struct CanNode;
}

// The firmware's `can` feature and the board's CAN port go together.
const _: () = assert!(board::HAS_CAN == cfg!(feature = "can"));

/// Current-loop runs; `idle` feeds the watchdog only when this advances.
static CURRENT_LOOP_RUNS: AtomicU32 = AtomicU32::new(0);

/// `comms::snapshot` of a task's shared resources (`cx.shared`).
macro_rules! snapshot {
    ($s:expr) => {
        comms::snapshot(
            &mut $s.feedback,
            &mut $s.timing,
            &mut $s.status,
            &mut $s.identified,
            &mut $s.command,
            &mut $s.config_request,
        )
    };
}

/// `comms::commit` of `out` into a task's shared resources (`cx.shared`),
/// then the tables it asks for (`comms::install_tables`, under the drive's
/// lock).
macro_rules! commit {
    ($s:expr, $out:expr) => {{
        comms::commit($out, &mut $s.command, &mut $s.config_request);
        comms::install_tables($out, &mut $s.drive, &mut $s.comms);
    }};
}

/// `comms::take_measured_tables` with a task's shared resources: before a
/// link, the tables a calibration measured into the service.
macro_rules! take_measured_tables {
    ($s:expr) => {
        comms::take_measured_tables(&mut $s.tables_measured, &mut $s.drive, &mut $s.comms)
    };
}

#[rtic::app(device = board_support::pac, peripherals = true)]
mod app {
    use super::{can, comms, config, events, persist, timing, watchdog, CURRENT_LOOP_RUNS};
    use board_support::board;
    use board_support::pac::Interrupt;
    use core::sync::atomic::Ordering;
    use foc_core::calibration::offsets::OffsetLimits;
    use foc_core::calibration::Calibrated;
    use foc_core::control::power::ActiveLimit;
    use foc_core::control::stage::{PositionStage, SpeedStage, VelocityRef};
    use foc_core::control::{CommandSlot, Fault, Feedback, Mode};
    use foc_core::drive::cascade::CascadeConfig;
    use foc_core::drive::{Drive, LifecycleConfig, Mail, Status};

    /// The board's drive: its hardware (and brake resistor switch), current
    /// stage and lifecycle.
    pub type BoardDrive =
        Drive<board::Pwm, board::Currents, board::Angle, board::Bus, board::Brake>;

    /// Status before the first period: starting, disabled, uncalibrated.
    const STARTING: Status = Status {
        running: false,
        mode: Mode::Disabled,
        faulted: false,
        calibrated: false,
        sensorless: false,
        injection: false,
        calibration: foc_core::drive::Progress::Idle,
    };

    #[shared]
    struct Shared {
        /// Command mailbox. Written by `housekeeping` (prio 1: start
        /// command, link watchdog) and `serial` (prio 1:
        /// commands, keep-alives, fault clears from the link); read by
        /// `current_loop` (prio 4).
        command: CommandSlot,
        /// Feedback published every period. Written by `current_loop` (4);
        /// read by `speed_loop` (3), `position_loop` (2), `housekeeping` (1).
        feedback: Feedback,
        /// q-current reference [A]. Written by `speed_loop` (3); read by
        /// `current_loop` (4).
        iq_ref_a: f32,
        /// Velocity reference and torque feed-forward. Written by
        /// `position_loop` (2); read by `speed_loop` (3).
        velocity_ref: VelocityRef,
        /// Current-loop timing. Written by `current_loop` (4); read by
        /// `housekeeping` (1).
        timing: timing::LoopTiming,
        /// Set by `bridge_break` (5) when the break input fired; taken
        /// (cleared) by `current_loop` (4), which latches the fault.
        break_fired: bool,
        /// The drive's status (started, mode, faulted, calibrated): what the
        /// command channel's rules look at. Written by `current_loop` (4)
        /// every period; read by `housekeeping` (1) and `serial` (1).
        status: Status,
        /// The last successful identification and the permit it gave.
        /// Written by `current_loop` (4) when one ends; read by
        /// `housekeeping` and `serial` (1).
        identified: Option<comms::Identified>,
        /// Configuration changes from the command channel. Written (merged)
        /// by `serial` and `housekeeping` (1); each part taken by its owner:
        /// `current` by `current_loop` (4) (applied or refused whole by the
        /// drive), `speed` by `speed_loop` (3), `position` by
        /// `position_loop` (2), at their next run.
        config_request: comms::ConfigMailbox,
        /// The scope (design §22). Recorded by `current_loop` (4) every
        /// period; configured, armed and read by `serial` (1), one short
        /// lock per request.
        scope: comms::BoardScope,
        /// The command channel (UART, decoder, protocol state, settings).
        /// Used by `serial`, `housekeeping` and `stream`, all priority 1, so
        /// never contended.
        comms: comms::Comms,
        /// The CANopen node and its port (`can`; empty on boards without
        /// CAN). Used by `stream` (priority 1) only.
        can: can::CanNode,
        /// The drive (hardware, current stage, lifecycle). Stepped by
        /// `current_loop` (4) every period; locked by `serial`, `stream`
        /// and `housekeeping` (1) only to move the tables kept with the
        /// configuration in or out of its stage with the bridge off
        /// (`comms::install_tables`, `comms::take_measured_tables`: about
        /// 3.5k cycles, the current loop held off meanwhile).
        drive: BoardDrive,
        /// Tables measured by a calibration since reset (anticogging map,
        /// angle correction). Counted by `current_loop` (4) on their
        /// events; read by the priority-1 tasks before each link.
        tables_measured: u32,
    }

    #[local]
    struct Local {
        /// `current_loop` only: periods since reset (housekeeping rate).
        tick: u32,
        /// `speed_loop` only.
        speed: SpeedStage,
        /// `position_loop` only.
        position: PositionStage,
        /// `housekeeping` only: start command posted.
        started: bool,
        /// `housekeeping` only: the power limit last logged.
        power_limit: ActiveLimit,
        /// `idle` only: last run count seen.
        seen_runs: u32,
    }

    #[init(local = [scope_buf: [f32; config::SCOPE_VALUES] = [0.0; config::SCOPE_VALUES]])]
    fn init(cx: init::Context) -> (Shared, Local) {
        let mut cp = cx.core;
        cp.DCB.enable_trace();
        cp.DWT.enable_cycle_counter();
        let watchdog_reset = watchdog::take_reset_flag();
        let b = board::init(cx.device);
        // The stored configuration, or the build-time one (see `persist`).
        let mut boot = persist::boot(b.store);
        // The CANopen node with its stored settings, on the started port.
        #[cfg(feature = "can")]
        let can_node = {
            let n = can::CanNode::start(b.can, boot.store.as_mut());
            can::enable_interrupt(&mut cp.NVIC);
            n
        };
        #[cfg(not(feature = "can"))]
        let can_node = can::CanNode;
        let cfg = boot.service.cascade();
        // The service kept a calibration only where the sensor's zero
        // survives a reset; the lifecycle checks that again.
        let life = lifecycle_config(&cfg, boot.service.settings().permit());
        let mut drive =
            Drive::new(b.pwm, b.currents, b.angle, b.bus, cfg.current, life).with_brake(b.brake);
        // The stored tables, before the interrupt runs (never in a
        // configuration change).
        if let Some(stage) = drive.stage_while_disabled() {
            if boot.service.install_tables(stage).is_err() {
                defmt::warn!("store: the stored tables were not installed");
            }
        }
        if watchdog_reset {
            defmt::error!("reset by the watchdog");
            drive.trip(Fault::Watchdog);
        }
        // The ODrive's DRV8301 is configured over SPI in `board::init`.
        #[cfg(feature = "odrive-v3")]
        if b.gate_driver_config.is_err() {
            defmt::error!("DRV8301 configuration failed");
            drive.trip(Fault::GateDriverFault);
        }
        let budget = current_loop_budget_logged();
        watchdog::start(config::WATCHDOG_TIMEOUT_MS);
        (
            shared_resources(
                comms::Comms::new(b.serial, boot),
                can_node,
                drive,
                budget,
                foc_core::scope::Scope::new(&mut cx.local.scope_buf[..]),
            ),
            Local {
                tick: 0,
                speed: SpeedStage::new(cfg.speed),
                position: PositionStage::new(cfg.position),
                started: false,
                power_limit: ActiveLimit::None,
                seen_runs: 0,
            },
        )
    }

    /// The lifecycle's start-up (offset calibration, sensor check,
    /// identification) from the build-time configuration, the loop rates of
    /// `cfg` and the board's angle input, with the `stored` calibration.
    fn lifecycle_config(cfg: &CascadeConfig, stored: Option<Calibrated>) -> LifecycleConfig {
        let angle_kind = board::angle_kind();
        LifecycleConfig {
            offsets: Some(OffsetLimits {
                samples: config::OFFSET_CAL_SAMPLES,
                max_offset_a: config::OFFSET_CAL_MAX_A,
                max_noise_a: config::OFFSET_CAL_MAX_NOISE_A,
            }),
            sensor_check_reads: config::SENSOR_CHECK_READS,
            identification: Some(config::identification(board::PWM_FREQUENCY_HZ as f32)),
            identify_at_start_up: config::identify_at_start_up(),
            speed_divider: cfg.rates.speed_divider,
            position_divider: cfg.rates.position_divider,
            angle_kind,
            stored,
        }
    }

    /// The current loop's budget [CPU cycles per PWM period], logged with
    /// the board's name and loop rates.
    fn current_loop_budget_logged() -> f32 {
        let budget = (board::SYSCLK_HZ as f32 / board::PWM_FREQUENCY_HZ as f32)
            * config::CURRENT_LOOP_BUDGET_FRACTION;
        defmt::info!(
            "{}: {} Hz PWM, speed /{}, position /{}, budget {} cycles",
            board::NAME,
            board::PWM_FREQUENCY_HZ,
            config::SPEED_DIVIDER,
            config::POSITION_DIVIDER,
            budget as u32
        );
        budget
    }

    /// The shared resources at start-up: empty mailboxes, nothing measured
    /// yet, the status [`STARTING`], the command channel `comms`, the CAN
    /// node `can`, the `drive` and the `scope`; the current loop's timing
    /// with its `budget` [cycles].
    fn shared_resources(
        comms: comms::Comms,
        can: can::CanNode,
        drive: BoardDrive,
        budget: f32,
        scope: comms::BoardScope,
    ) -> Shared {
        Shared {
            command: CommandSlot::INIT,
            feedback: Feedback::INIT,
            iq_ref_a: 0.0,
            velocity_ref: VelocityRef::default(),
            timing: timing::LoopTiming {
                budget_cycles: budget as u32,
                ..Default::default()
            },
            break_fired: false,
            status: STARTING,
            identified: None,
            config_request: comms::ConfigMailbox::EMPTY,
            comms,
            can,
            scope,
            drive,
            tables_measured: 0,
        }
    }

    #[idle(local = [seen_runs])]
    fn idle(cx: idle::Context) -> ! {
        loop {
            let runs = CURRENT_LOOP_RUNS.load(Ordering::Relaxed);
            if runs != *cx.local.seen_runs {
                *cx.local.seen_runs = runs;
                watchdog::feed();
            }
            cortex_m::asm::wfi();
        }
    }

    /// Timer break input / gate-driver fault: bridge off at once.
    #[task(binds = TIM1_BRK_TIM9, priority = 5, shared = [break_fired])]
    fn bridge_break(mut cx: bridge_break::Context) {
        board::emergency_disable();
        board::break_isr_ack();
        cx.shared.break_fired.lock(|b| *b = true);
    }

    /// The current loop: every PWM period, at the ADC end of conversion.
    /// Glue only: the drive decides (`foc_core::drive`).
    #[task(
        binds = ADC,
        priority = 4,
        shared = [command, feedback, iq_ref_a, timing, break_fired, status, identified, config_request, scope, drive, tables_measured],
        local = [tick]
    )]
    fn current_loop(mut cx: current_loop::Context) {
        let t0 = timing::now_cycles();
        let command = cx.shared.command.lock(|c| *c);
        let iq_ref_a = cx.shared.iq_ref_a.lock(|x| *x);
        let gate_fault = cx.shared.break_fired.lock(core::mem::take) || board::gate_driver_fault();
        // Each lock raises and restores BASEPRI (RTIC 2 does so even at the
        // ceiling: about 6 instructions each, not counted by the bench);
        // the drive writes the feedback and status in place; the scope
        // records the period's feedback (one comparison while idle).
        let out = (
            cx.shared.config_request,
            cx.shared.feedback,
            cx.shared.status,
            cx.shared.scope,
            &mut cx.shared.drive,
        )
            .lock(|request, feedback, status, scope, drive| {
                let mail = Mail {
                    command,
                    iq_ref_a,
                    change: &mut request.current,
                    gate_fault,
                };
                let out = drive.run_period(mail, feedback, status);
                scope.record(feedback);
                out
            });
        if let Some(e) = out.event {
            // A table measured: the priority-1 tasks take it into the
            // service before their next link (`comms`).
            if matches!(
                e,
                foc_core::drive::Event::CoggingMeasured { .. }
                    | foc_core::drive::Event::EncoderLinearised { .. }
            ) {
                cx.shared.tables_measured.lock(|n| *n = n.wrapping_add(1));
            }
            if let Some(result) = events::log(&e, *cx.local.tick) {
                let c = cx.shared.drive.lock(|d| *d.stage().config());
                if let Ok(permit) = Calibrated::supplied(c.angle, c.current) {
                    cx.shared.identified.lock(|x| {
                        let count = x.map_or(0, |i| i.count).wrapping_add(1);
                        *x = Some(comms::Identified {
                            result,
                            permit,
                            count,
                        });
                    });
                }
            }
        }
        if let Some(Err(r)) = out.change {
            defmt::warn!("configuration change refused: {}", r);
        }
        *cx.local.tick = cx.local.tick.wrapping_add(1);
        pend_slower_loops(out.run_speed, out.run_position, *cx.local.tick);
        CURRENT_LOOP_RUNS.fetch_add(1, Ordering::Relaxed);
        let dt = timing::now_cycles().wrapping_sub(t0);
        // Overrun: over the cycle budget, or the next period's conversion
        // (the interrupt that triggers this task) already pending again.
        let repended = cortex_m::peripheral::NVIC::is_pending(board::CURRENT_IRQ);
        // A run stretched by a flash stall (a store operation, bridge off),
        // or held off while the tables moved under the drive's lock, is not
        // an overrun of the control code.
        if cx.shared.timing.lock(|tm| tm.record(dt, repended))
            && !persist::flash_busy()
            && !comms::tables_busy()
        {
            cx.shared.drive.lock(|d| d.trip(Fault::LoopOverrun));
        }
    }

    /// Pend the speed and position loops when the drive says so, the
    /// stream every `STREAM_DIVIDER` periods, and
    /// housekeeping every `HOUSEKEEPING_DIVIDER` periods.
    fn pend_slower_loops(speed: bool, position: bool, tick: u32) {
        if speed {
            rtic::pend(Interrupt::EXTI1);
        }
        if position {
            rtic::pend(Interrupt::EXTI2);
        }
        if tick.is_multiple_of(config::HOUSEKEEPING_DIVIDER) {
            rtic::pend(Interrupt::EXTI3);
        }
        if tick.is_multiple_of(config::STREAM_DIVIDER) {
            rtic::pend(Interrupt::EXTI4);
        }
    }

    /// The speed loop: every `SPEED_DIVIDER` periods.
    #[task(binds = EXTI1, priority = 3, shared = [feedback, iq_ref_a, velocity_ref, config_request], local = [speed])]
    fn speed_loop(mut cx: speed_loop::Context) {
        if let Some(c) = cx.shared.config_request.lock(|m| m.speed.take()) {
            cx.local.speed.speed_loop().set_config(c);
        }
        let fb = cx.shared.feedback.lock(|f| *f);
        let vr = cx.shared.velocity_ref.lock(|v| *v);
        let iq = cx.local.speed.step(&fb, vr);
        cx.shared.iq_ref_a.lock(|x| *x = iq);
    }

    /// The position loop: every `POSITION_DIVIDER` periods.
    #[task(binds = EXTI2, priority = 2, shared = [feedback, velocity_ref, config_request], local = [position])]
    fn position_loop(mut cx: position_loop::Context) {
        if let Some(c) = cx.shared.config_request.lock(|m| m.position.take()) {
            cx.local.position.set_config(c);
        }
        let fb = cx.shared.feedback.lock(|f| *f);
        let vr = cx.local.position.step(&fb);
        cx.shared.velocity_ref.lock(|v| *v = vr);
    }

    /// The command channel: bytes from the UART to the protocol, replies
    /// back; each request's changes committed before the next is read.
    #[task(
        binds = USART2,
        priority = 1,
        shared = [command, feedback, timing, status, identified, config_request, comms, scope, drive, tables_measured]
    )]
    fn serial(mut cx: serial::Context) {
        let mut scope = comms::ScopeLock(cx.shared.scope);
        cx.shared.comms.lock(|c| c.serial.on_interrupt());
        // Bounded: every frame takes at least one byte of the RX ring.
        for _ in 0..board_support::hw::serial::RX_CAPACITY {
            take_measured_tables!(cx.shared);
            let snap = snapshot!(cx.shared);
            let Some(out) = cx.shared.comms.lock(|c| c.receive(snap, &mut scope)) else {
                break;
            };
            commit!(cx.shared, &out);
        }
    }

    /// The telemetry stream: a sample when one is due (its rate is the
    /// host's, up to the UART's capacity), at 1 kHz. On boards with CAN
    /// first the CANopen node (`can`): received frames, then its tick;
    /// the CAN interrupt pends this task too.
    #[task(binds = EXTI4, priority = 1, shared = [feedback, timing, status, identified, config_request, command, comms, can, drive, tables_measured])]
    fn stream(mut cx: stream::Context) {
        #[cfg(feature = "can")]
        can_service(&mut cx);
        // Nothing more to do (and, on boards without CAN, no lock at the
        // current loop's priority) while the stream is off.
        if cx.shared.comms.lock(|c| c.device.telemetry_every()) == 0 {
            return;
        }
        let snap = snapshot!(cx.shared);
        cx.shared
            .comms
            .lock(|c| c.stream(snap, snap.feedback.period));
    }

    /// The CANopen node: every received frame (each with a fresh
    /// snapshot, its changes committed before the next), then the tick,
    /// then the CAN interrupt unmasked again (`can::on_can_interrupt`).
    #[cfg(feature = "can")]
    fn can_service(cx: &mut stream::Context) {
        use rtic::Mutex as _;
        cx.shared.can.lock(|n| n.service_port());
        // Bounded: every pass takes a frame from the port.
        for _ in 0..board_support::hw::serial::RX_CAPACITY {
            take_measured_tables!(cx.shared);
            let snap = snapshot!(cx.shared);
            let comms = &mut cx.shared.comms;
            let Some(out) = cx.shared.can.lock(|n| comms.lock(|c| n.receive(c, snap))) else {
                break;
            };
            commit!(cx.shared, &out);
        }
        let snap = snapshot!(cx.shared);
        let comms = &mut cx.shared.comms;
        let out = cx.shared.can.lock(|n| comms.lock(|c| n.tick(c, snap)));
        commit!(cx.shared, &out);
        can::unmask_interrupt();
    }

    /// Housekeeping: start-up command, command-channel poll and telemetry, at 50 Hz.
    #[task(
        binds = EXTI3,
        priority = 1,
        shared = [command, feedback, timing, status, identified, config_request, comms, drive, tables_measured],
        local = [started, power_limit]
    )]
    fn housekeeping(mut cx: housekeeping::Context) {
        take_measured_tables!(cx.shared);
        let mut snap = snapshot!(cx.shared);
        let (fb, status) = (snap.feedback, snap.status);
        if status.running && !*cx.local.started {
            *cx.local.started = true;
            if let Some(cmd) = config::START_COMMAND {
                cx.shared.command.lock(|c| c.post(cmd));
                // The link below sees the mailbox as it is now.
                snap.pending.command = cmd;
            }
        }
        let tm = cx.shared.timing.lock(|t| *t);
        super::log_power_limit(cx.local.power_limit, &fb);
        // Command channel: link watchdog and streamed telemetry.
        let out = cx.shared.comms.lock(|c| c.poll(snap, fb.period));
        commit!(cx.shared, &out);
        defmt::debug!(
            "mode {} w {} rad/s p {} rad iq {} A fault {} loop max {} cyc",
            fb.mode,
            fb.velocity_rad_s,
            fb.position_rad,
            fb.i_dq_a.q,
            fb.first_fault,
            tm.max_cycles
        );
    }
}

/// Log when the power limit that cuts the current changes (design §18):
/// which one, and the share of the current limit left.
fn log_power_limit(
    last: &mut foc_core::control::power::ActiveLimit,
    fb: &foc_core::control::Feedback,
) {
    let p = &fb.power;
    if p.active != *last {
        *last = p.active;
        defmt::info!(
            "power limit: {} ({=f32} % of the current limit left; winding {=f32} C, stage {=f32} C, bus {=f32} V)",
            p.active,
            100.0 * p.factor,
            p.winding_c,
            p.stage_c,
            fb.v_bus_v
        );
    }
}

/// Panic: bridge off first, then log, then stop in a HardFault.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    board::emergency_disable();
    defmt::error!("panic: {}", defmt::Display2Format(info));
    board::after_panic()
}

/// HardFault: bridge off first, then log, then wait for the watchdog.
#[cortex_m_rt::exception]
unsafe fn HardFault(ef: &cortex_m_rt::ExceptionFrame) -> ! {
    board::emergency_disable();
    defmt::error!("HardFault at pc {=u32:#x}", ef.pc());
    board::after_hardfault()
}

/// Runs in `defmt::panic!` and friends: same path as a Rust panic.
#[defmt::panic_handler]
fn defmt_panic() -> ! {
    board::emergency_disable();
    cortex_m::asm::udf()
}
