//! The operator's commands: the mailbox (clears, new commands), admission
//! against the limits and the permit, the command timeout.

use super::*;

/// What to do when commands stop arriving.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TimeoutReaction {
    /// Latch [`Fault::CommandTimeout`] (bridge off).
    Disable,
    /// Switch to velocity 0.
    Stop,
    /// Hold the current position.
    Hold,
}

impl CurrentStage {
    /// Latch a fault found by the caller (overrun, gate driver, PWM error...).
    /// The next [`Self::step`] returns the safe state.
    pub fn report_fault(&mut self, f: Fault) {
        self.supervisor.trip(f);
        self.state.active = Command::Disable;
    }

    /// True when `slot` requests a fault clear this stage has not yet
    /// performed (it does so at the start of its next step, before it
    /// looks at the command).
    pub fn clear_pending(&self, slot: &CommandSlot) -> bool {
        slot.clear_seq != self.state.last_clear_seq
    }

    /// Take `slot`'s command and fault-clear numbers as seen without acting
    /// on them: after an identification, neither the operator's earlier
    /// command nor a clear sent during it acts later.
    pub fn sync_mailbox(&mut self, slot: &CommandSlot) {
        self.state.last_seq = slot.seq;
        self.state.last_clear_seq = slot.clear_seq;
    }

    /// Perform `slot`'s pending fault clear now (the step would do it
    /// first thing): the caller then latches faults it found this period,
    /// which the clear must not erase.
    /// Returns true when a clear was performed.
    pub fn take_clear(&mut self, slot: &CommandSlot) -> bool {
        if slot.clear_seq != self.state.last_clear_seq {
            self.state.last_clear_seq = slot.clear_seq;
            self.supervisor.clear();
            return true;
        }
        false
    }

    /// Commands refused so far (invalid, sent while faulted, closed-loop
    /// without a calibration, or needing the angle sensor while
    /// sensorless).
    pub fn rejected_commands(&self) -> u32 {
        self.state.rejected
    }

    /// The active command.
    pub fn active(&self) -> Command {
        self.state.active
    }

    pub(super) fn accept(&mut self, cmd: Command) {
        let faulted = self.supervisor.is_faulted();
        if faulted
            || crate::control::admit(&cmd, &self.config.limits, faulted, self.is_calibrated())
                .is_err()
            || (self.sensorless_refuses(cmd.mode()))
            || (self.state.active.mode() == Mode::Disabled
                && cmd.mode().is_closed_loop()
                && self.too_fast_to_start())
        {
            self.state.rejected = self.state.rejected.wrapping_add(1);
            return;
        }
        let (old, new) = (self.state.active.mode(), cmd.mode());
        match (old, new) {
            (_, Mode::OpenLoop) => {
                // Entering open loop starts at the command's angle. A new
                // open-loop command while in open loop takes its angle when
                // that differs from the previous command's (re-positioning,
                // e.g. the second step of an alignment); one that only
                // changes the voltage or the speed keeps the running angle,
                // so a spinning field stays continuous.
                if let Command::OpenLoop { theta_e, .. } = cmd {
                    let keep = matches!(
                        self.state.active,
                        Command::OpenLoop { theta_e: prev, .. } if prev == theta_e
                    );
                    if !keep {
                        self.state.ol_theta = theta_e;
                    }
                }
            }
            (Mode::OpenLoop, Mode::Torque | Mode::Velocity | Mode::Position | Mode::Impedance) => {
                // Bumpless: the PIs continue from the open-loop voltage.
                let w_e = self.tracker.velocity_rad_s() * self.config.angle.pole_pairs as f32;
                self.current
                    .preload(self.state.last_out_v_dq, self.state.last_i_dq, w_e);
            }
            (Mode::Disabled, _) => self.current.reset(),
            _ => {}
        }
        if let Command::Velocity { .. } = cmd {
            self.supervisor.restart_runaway();
        }
        if let Command::Impedance(i) = cmd {
            self.start_impedance(&i, old);
        }
        self.state.timeout_damping = false;
        self.state.active = cmd;
    }

    /// Step 1: operator actions: clear first, then a new command.
    #[inline(always)]
    pub(super) fn take_operator_actions(&mut self, slot: &CommandSlot) {
        if slot.clear_seq != self.state.last_clear_seq {
            self.state.last_clear_seq = slot.clear_seq;
            self.supervisor.clear();
        }
        if slot.seq != self.state.last_seq {
            self.state.last_seq = slot.seq;
            self.state.age_periods = 0;
            self.accept(slot.command);
        }
    }

    /// Step 3: command timeout.
    #[inline(always)]
    pub(super) fn apply_command_timeout(&mut self) {
        if self.state.active.mode() == Mode::Disabled || self.config.command_timeout_periods == 0 {
            return;
        }
        self.state.age_periods = self.state.age_periods.saturating_add(1);
        if self.state.age_periods <= self.config.command_timeout_periods {
            return;
        }
        self.state.age_periods = 0;
        if let Command::Impedance(i) = self.state.active {
            // Impedance (design §21): damping only, then disable.
            if self.state.timeout_damping || !self.is_calibrated() {
                self.supervisor.trip(Fault::CommandTimeout);
            } else {
                let kd_min = self.config.joint.timeout_kd_nm_s_per_rad;
                let damping = Impedance {
                    position_rad: self.tracker.position().to_radians(),
                    velocity_rad_s: 0.0,
                    kp_nm_per_rad: 0.0,
                    kd_nm_s_per_rad: if i.kd_nm_s_per_rad > kd_min {
                        i.kd_nm_s_per_rad
                    } else {
                        kd_min
                    },
                    torque_ff_nm: 0.0,
                    torque_limit_nm: i.torque_limit_nm,
                };
                self.start_impedance(&damping, Mode::Impedance);
                self.state.active = Command::Impedance(damping);
                self.state.timeout_damping = true;
            }
            return;
        }
        match self.config.timeout_reaction {
            // Stop and Hold are closed-loop: without a calibration
            // (open loop) the timeout disables.
            TimeoutReaction::Disable => self.supervisor.trip(Fault::CommandTimeout),
            _ if !self.is_calibrated() => self.supervisor.trip(Fault::CommandTimeout),
            TimeoutReaction::Stop => self.accept(Command::Velocity { rad_s: 0.0 }),
            // Without the angle sensor (and without injection, which holds
            // one) there is no position to hold: stop.
            TimeoutReaction::Hold if self.sensorless_refuses(Mode::Position) => {
                self.accept(Command::Velocity { rad_s: 0.0 })
            }
            TimeoutReaction::Hold => {
                let p = self.tracker.position().to_radians();
                self.state.active = Command::Position { rad: p };
            }
        }
    }
}
