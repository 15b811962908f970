//! The speed and position stages: the outer loops with their mode logic,
//! run every N periods.

use super::*;

/// What the position stage hands the speed stage.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VelocityRef {
    /// Velocity reference [rad/s, mechanical].
    pub rad_s: f32,
    /// Torque feed-forward as a q current \[A\].
    pub iq_ff_a: f32,
}

/// The speed stage: runs every N periods.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpeedStage {
    speed: SpeedLoop,
    last_mode: Mode,
    iq_ref_a: f32,
}

impl SpeedStage {
    /// New stage.
    pub fn new(config: SpeedLoopConfig) -> Self {
        Self {
            speed: SpeedLoop::new(config),
            last_mode: Mode::Disabled,
            iq_ref_a: 0.0,
        }
    }
    /// The speed loop.
    pub fn speed_loop(&mut self) -> &mut SpeedLoop {
        &mut self.speed
    }
    /// One step: returns the q-current reference \[A\] for the current stage.
    /// Outside velocity/position modes it tracks the active current
    /// reference so that entering those modes is bumpless.
    pub fn step(&mut self, fb: &Feedback, from_position: VelocityRef) -> f32 {
        // (A sensorless start runs its own field and reports open loop
        // under a velocity or position command: the loop waits, design §27.)
        let (w_ref, ff) = match fb.active {
            Command::Velocity { rad_s } if fb.mode == Mode::Velocity => (Some(rad_s), 0.0),
            Command::Position { .. } if fb.mode == Mode::Position => {
                (Some(from_position.rad_s), from_position.iq_ff_a)
            }
            _ => (None, 0.0),
        };
        let entering = !matches!(self.last_mode, Mode::Velocity | Mode::Position);
        let model_starts = fb.mode == Mode::Velocity && self.last_mode != Mode::Velocity;
        self.last_mode = fb.mode;
        self.iq_ref_a = match w_ref {
            Some(w) => {
                if entering {
                    // Bumpless: the current in force, less what the
                    // disturbance feed-forward already adds.
                    let dob = self.speed.disturbance_ff_a(fb.disturbance_rad_s2);
                    self.speed.preload(fb.i_dq_ref_a.q - dob);
                }
                if model_starts {
                    // The reference model starts where the rotor is.
                    self.speed.start_model(fb.velocity_rad_s);
                }
                // Within the current limit and the power limits' window.
                // (Plain comparisons: `f32::max` is branchy on the M4F.)
                let lim = fb.current_limit_a;
                let (p_lo, p_hi) = (fb.power.iq_min_a, fb.power.iq_max_a);
                let lo = if p_lo > -lim { p_lo } else { -lim };
                let hi = if p_hi < lim { p_hi } else { lim };
                // The travel limits' soft stop may push back (a window
                // without 0); the speed loop's stays at 0 there and the
                // current stage pushes.
                let lo = if lo > 0.0 { 0.0 } else { lo };
                let hi = if hi < 0.0 { 0.0 } else { hi };
                if fb.mode == Mode::Velocity {
                    // A step of the operator's reference: through the
                    // reference model (two degrees of freedom).
                    self.speed
                        .step_model(w, fb.velocity_rad_s, fb.disturbance_rad_s2, lim, lo, hi)
                } else {
                    // The trajectory is already smooth, with its own
                    // acceleration feed-forward.
                    self.speed.step_in(
                        w,
                        fb.velocity_rad_s,
                        ff + self.speed.disturbance_ff_a(fb.disturbance_rad_s2),
                        lo,
                        hi,
                    )
                }
            }
            None => {
                self.speed.preload(fb.i_dq_ref_a.q);
                fb.i_dq_ref_a.q
            }
        };
        self.iq_ref_a
    }
}

/// The position stage: runs every M periods.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PositionStage {
    pos: PositionLoop,
    last_mode: Mode,
    last_target: f32,
}

impl PositionStage {
    /// New stage.
    pub fn new(config: PositionLoopConfig) -> Self {
        Self {
            pos: PositionLoop::new(config),
            last_mode: Mode::Disabled,
            last_target: 0.0,
        }
    }
    /// The position loop.
    pub fn position_loop(&self) -> &PositionLoop {
        &self.pos
    }
    /// Replace the position-loop configuration.
    pub fn set_config(&mut self, c: PositionLoopConfig) {
        self.pos.set_config(c);
    }
    /// One step: returns the velocity reference (and acceleration
    /// feed-forward) for the speed stage. Outside position mode it returns
    /// the measured velocity and no feed-forward.
    pub fn step(&mut self, fb: &Feedback) -> VelocityRef {
        let position = match fb.active {
            Command::Position { rad } if fb.mode == Mode::Position => Some(rad),
            _ => None,
        };
        let w = if let Some(rad) = position {
            if self.last_mode != Mode::Position {
                self.pos.start_move(fb.position_rad, fb.velocity_rad_s, rad);
            } else if rad != self.last_target {
                self.pos.retarget(rad);
            }
            self.last_target = rad;
            let w = self.pos.step(fb.position_rad);
            VelocityRef {
                rad_s: w,
                iq_ff_a: self.pos.current_feed_forward_a(),
            }
        } else {
            VelocityRef {
                rad_s: fb.velocity_rad_s,
                iq_ff_a: 0.0,
            }
        };
        self.last_mode = fb.mode;
        w
    }
}
