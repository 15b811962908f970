//! Which angle the current loop uses this period: the regions and their
//! changes (see the module docs of [`super`]).

use super::Sensorless;
use crate::frames::Dq;

/// Where a sensorless drive runs (module docs of [`super`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Region {
    /// Bridge off or no closed-loop command.
    Idle,
    /// The current is ramped up along a held angle: the rotor turns onto
    /// it.
    Align,
    /// The current loop runs on the field's angle, which the drive turns
    /// (I/f).
    Field,
    /// The current loop runs on the observer's angle (closed loop).
    Observer,
    /// Injection: the estimate settles, no current (design §28).
    HfiSettle,
    /// Injection: the polarity test's d pulses.
    HfiPolarity,
    /// Injection: the closed loop runs on its angle.
    Hfi,
}

impl Region {
    /// True in the injection's regions.
    pub fn injects(self) -> bool {
        matches!(self, Region::HfiSettle | Region::HfiPolarity | Region::Hfi)
    }

    /// True where the outer loops wait (the start: alignment, field,
    /// injection's settling and polarity test).
    pub fn starting(self) -> bool {
        matches!(
            self,
            Region::Align | Region::Field | Region::HfiSettle | Region::HfiPolarity
        )
    }
}

/// A change of the current loop's frame this period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Switch {
    /// None.
    Stay,
    /// To a frame `old - new` \[rad\] behind the old one: a dq vector of
    /// the old frame is turned by this angle to read in the new one.
    Turn {
        /// `old - new` \[rad, electrical\].
        rotate_rad: f32,
        /// True: to the observer's frame; false: to the field's.
        to_observer: bool,
    },
}

/// The observer did not agree with the field in time (module docs of
/// [`super`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LostLock;

impl Sensorless {
    /// Decide this period's region. `closed`: a closed-loop command is
    /// active; `target_rad_s`: the field's target speed [rad/s,
    /// electrical] (the velocity command; 0 in the other modes); `i_now`:
    /// the current measured in the last period, in the loop's frame \[A\]
    /// (the field is placed on it when the observer lets go).
    pub fn step(&mut self, closed: bool, target_rad_s: f32, i_now: Dq) -> Result<Switch, LostLock> {
        if !closed {
            self.region = Region::Idle;
            return Ok(Switch::Stay);
        }
        let switch = match self.region {
            Region::Idle if self.hfi.is_some() => {
                self.start_hfi();
                Ok(Switch::Stay)
            }
            Region::Idle => {
                self.start_align();
                Ok(Switch::Stay)
            }
            Region::Align => self.align(target_rad_s).map(|()| Switch::Stay),
            Region::Field => self.turn_field(target_rad_s),
            Region::Observer if self.hfi.is_some() => Ok(self.follow_observer_to_hfi()),
            Region::Observer => Ok(self.follow_observer(i_now)),
            Region::HfiSettle | Region::HfiPolarity => self.settle_hfi(),
            Region::Hfi => self.run_hfi(target_rad_s),
        };
        // No injection response for as long as the observer may take to
        // agree: the injection does not reach the motor.
        if let (Some(h), true) = (self.hfi.as_ref(), self.region.injects()) {
            if h.silent_periods() > self.cfg.lock_periods.max(1) {
                return Err(LostLock);
            }
        }
        self.damp();
        let on_observer = self.region == Region::Observer;
        self.observer.set_low_speed_scaling(on_observer);
        self.observer.set_locked(on_observer);
        switch
    }

    /// The damping's lead: the field's speed less the rotor's, as the
    /// observer sees it, times the damping time (bounded).
    fn damp(&mut self) {
        let w_obs = self.observer.speed_rad_s();
        let slip = self.field_rad_s - w_obs;
        // On the turning field the observer's speed is worth little until
        // the field or the rotor nears the hand-over speed: the damping
        // grows with the faster of the two (a rotor handed back to a field
        // that stops swings about it as fast as it came).
        let weight = match self.region {
            Region::Field => {
                (self.field_rad_s.abs().max(w_obs.abs()) / self.cfg.handover_rad_s).min(1.0)
            }
            _ => 1.0,
        };
        let lead = self.cfg.damping_s * weight * slip;
        self.lead_rad = if lead.is_finite() {
            crate::clamp(lead, -super::DAMPING_MAX_RAD, super::DAMPING_MAX_RAD)
        } else {
            0.0
        };
    }

    /// The alignment starts at the observer's angle (where the rotor was
    /// when the drive last ran; zero after a reset).
    fn start_align(&mut self) {
        self.region = Region::Align;
        self.field = self.observer.angle();
        self.field_rad_s = 0.0;
        self.field_a = 0.0;
        self.periods = 0;
        self.agree = 0;
        self.waited = 0;
        self.blend_a = 0.0;
        self.align_turned_rad = 0.0;
    }

    /// The current up in a straight line over the rise, then held. A rotor
    /// the observer sees turn against the commanded direction by more than
    /// [`super::ALIGN_SLIP_RAD`] slips past the field: lost.
    fn align(&mut self, target_rad_s: f32) -> Result<(), LostLock> {
        if target_rad_s != 0.0
            && self.align_turned_rad * target_rad_s.signum() < -super::ALIGN_SLIP_RAD
        {
            return Err(LostLock);
        }
        self.periods = self.periods.saturating_add(1);
        let rise = self.cfg.rise_periods.max(1) as f32;
        self.field_a = self.cfg.current_a * (self.periods as f32 / rise).min(1.0);
        if self.periods >= self.cfg.align_periods {
            // The rotor stands on the current (less a load's angle): the
            // observer starts from there.
            self.observer.place(self.current_angle());
            // (Not a motion: the mechanical angle does not take the jump.)
            self.last_angle = self.observer.angle();
            self.region = Region::Field;
        }
        Ok(())
    }

    /// The field's speed towards the target, its angle on; the hand-over
    /// when the observer agrees long enough.
    fn turn_field(&mut self, target_rad_s: f32) -> Result<Switch, LostLock> {
        let c = &self.cfg;
        let ts = c.observer.ts_s;
        let up = c.current_a / c.rise_periods.max(1) as f32;
        self.field_a = (self.field_a + up).min(c.current_a);
        let dv = c.accel_rad_s2 * ts;
        // The field goes no faster than a quarter above the hand-over
        // speed: the observer takes over a rotor at a steady speed,
        // carrying its load (not accelerating), and the speed loop
        // takes it on from there.
        let top = 1.25 * c.handover_rad_s;
        let target = if target_rad_s.is_finite() {
            crate::clamp(target_rad_s, -top, top)
        } else {
            0.0
        };
        self.field_rad_s += crate::clamp(target - self.field_rad_s, -dv, dv);
        let steady = self.field_rad_s == target;
        self.field = self.field.add_radians(self.field_rad_s * ts);
        let w = self.field_rad_s;
        let w_obs = self.observer.speed_rad_s();
        // Against the commanded direction (the field's without a command,
        // or under a field at rest) faster than the release speed: the
        // rotor does not follow, whatever the field's speed (a load that
        // drives it backwards). (Not against the field: in a reversal the
        // rotor braked by the speed loop crosses zero ahead of the field
        // it is handed back to.)
        let way = if target != 0.0 { target } else { w };
        let against = w_obs.abs() >= c.release_rad_s && w_obs * way <= 0.0;
        if w.abs() < c.handover_rad_s && !against {
            self.agree = 0;
            self.waited = 0;
            return Ok(Switch::Stay);
        }
        let agrees = steady && (w_obs - w).abs() <= 0.2 * w.abs();
        self.agree = if agrees {
            self.agree.saturating_add(1)
        } else {
            0
        };
        self.waited = self.waited.saturating_add(1);
        // Against the field: given only the time to agree; a stop (no
        // commanded direction) gives the rotor's swing about the field the
        // time out to settle (it comes in as fast as the release speed, on
        // the braking current's angle, and the damper takes it down).
        let grace = if target == 0.0 {
            c.lock_timeout_periods
        } else {
            c.lock_periods
        };
        if against && self.waited > grace.max(1) {
            return Err(LostLock);
        }
        if self.agree >= c.lock_periods.max(1) {
            let rotate_rad = self.current_angle().diff_radians(self.observer.angle());
            self.region = Region::Observer;
            self.waited = 0;
            // The field's d current, taken down over the blend.
            self.blend_a = self.field_a * libm::cosf(rotate_rad);
            self.blend_step_a = self.blend_a / c.blend_periods.max(1) as f32;
            return Ok(Switch::Turn {
                rotate_rad,
                to_observer: true,
            });
        }
        if self.waited > c.lock_timeout_periods.min(u32::MAX - 1) {
            return Err(LostLock);
        }
        Ok(Switch::Stay)
    }

    /// The observer's angle while it sees the rotor; below the release
    /// speed the field takes over at the start current, placed where it
    /// gives the torque of the q current in force (`asin(iq / I)` ahead of
    /// the rotor, at most a quarter turn): the torque carries on, and the
    /// rotor sits on the field's spring inside its stable half. (Placed on
    /// the current vector itself, a braking q current put the field a
    /// quarter turn behind the rotor, and its current's rise to the start
    /// current then multiplied the braking torque at the spring's edge:
    /// the rotor swung backwards and latched `ObserverLostLock`.)
    fn follow_observer(&mut self, i_now: Dq) -> Switch {
        let w = self.observer.speed_rad_s();
        if w.abs() >= self.cfg.release_rad_s {
            return Switch::Stay;
        }
        let obs = self.observer.angle();
        let i = self.cfg.current_a;
        let share = if i > 0.0 && i_now.q.is_finite() {
            crate::clamp(i_now.q / i, -1.0, 1.0)
        } else {
            0.0
        };
        let at = libm::asinf(share);
        self.field = obs.add_radians(at);
        self.field_rad_s = w;
        self.field_a = i;
        self.region = Region::Field;
        self.agree = 0;
        self.waited = 0;
        self.blend_a = 0.0;
        Switch::Turn {
            rotate_rad: obs.diff_radians(self.field),
            to_observer: false,
        }
    }

    /// Injection starts from the observer's angle (where the rotor was
    /// when the drive last ran), at rest.
    fn start_hfi(&mut self) {
        if let Some(h) = self.hfi.as_mut() {
            h.place(self.observer.angle(), 0.0);
        }
        self.region = Region::HfiSettle;
        self.periods = 0;
        self.agree = 0;
        self.waited = 0;
        self.blend_a = 0.0;
        self.polarity = super::Polarity::default();
    }

    /// The settling, then the polarity test; at its end the estimate is
    /// turned if it sat on the south pole (the current loop's frame turns
    /// with it), the observer is placed on it and the closed loop starts.
    /// Responses too close to tell the polarity: lost.
    fn settle_hfi(&mut self) -> Result<Switch, LostLock> {
        use crate::control::hfi::PolarityResult;
        let Some(h) = self.hfi.as_mut() else {
            return Ok(Switch::Stay);
        };
        let c = *h.config();
        if self.region == Region::HfiSettle {
            self.periods = self.periods.saturating_add(1);
            if self.periods >= c.settle_periods {
                // On the q axis (a start exactly a quarter turn off): a
                // quarter turn and the settling again, once (`agree`
                // counts the turns here).
                if h.on_q_axis() && self.agree == 0 {
                    h.turn_quarter();
                    // (Not a motion.)
                    self.last_angle = h.angle();
                    self.agree = 1;
                    self.periods = 0;
                    return Ok(Switch::Stay);
                }
                self.agree = 0;
                self.region = Region::HfiPolarity;
            }
            return Ok(Switch::Stay);
        }
        let Some(result) = self.polarity.step(&c, h.response_a()) else {
            return Ok(Switch::Stay);
        };
        let switch = match result {
            PolarityResult::Unknown => return Err(LostLock),
            PolarityResult::Flip => {
                h.flip();
                // The loop's frame turns half a turn (old - new = pi).
                Switch::Turn {
                    rotate_rad: core::f32::consts::PI,
                    to_observer: false,
                }
            }
            PolarityResult::Right => Switch::Stay,
        };
        self.observer.place(h.angle());
        // (Not a motion: the mechanical angle does not take the turn.)
        self.last_angle = h.angle();
        self.region = Region::Hfi;
        self.periods = 0;
        self.runaway = 0;
        Ok(switch)
    }

    /// The closed loop on the injection's angle; above the hand-over
    /// speed, once the observer agrees (angle within 0.3 rad, speed within
    /// a fifth) for [`SensorlessConfig::lock_periods`], on the observer's.
    /// Above it for [`SensorlessConfig::lock_timeout_periods`] without
    /// agreement: lost. A stall: a velocity command `target_rad_s` [rad/s,
    /// electrical] at or above the hand-over speed while the rotor stays
    /// below the release speed for as long (a locked rotor, a load beyond
    /// the current limit): lost too.
    fn run_hfi(&mut self, target_rad_s: f32) -> Result<Switch, LostLock> {
        let Some(h) = self.hfi.as_ref() else {
            return Ok(Switch::Stay);
        };
        let c = &self.cfg;
        let w = h.speed_rad_s();
        let stalled = target_rad_s.abs() >= c.handover_rad_s && w.abs() < c.release_rad_s;
        self.periods = if stalled {
            self.periods.saturating_add(1)
        } else {
            0
        };
        if self.periods > c.lock_timeout_periods {
            return Err(LostLock);
        }
        if w.abs() < c.handover_rad_s {
            self.agree = 0;
            // The injection says (nearly) still while the observer sees the
            // rotor turn at twice the hand-over speed: the injection follows
            // no rotor (an open phase leaves it a plausible response along
            // the other two phases' axis, where it stays) and a load turns
            // the rotor unopposed. The observer's voltage model is wrong
            // then too and its speed erratic, so the count goes up in such
            // periods and down in the others: lost after a net
            // `lock_periods`.
            self.waited = 0;
            let w_obs = self.observer.speed_rad_s();
            let runaway = w.abs() < c.release_rad_s && w_obs.abs() >= 2.0 * c.handover_rad_s;
            self.runaway = if runaway {
                self.runaway.saturating_add(1)
            } else {
                self.runaway.saturating_sub(1)
            };
            if self.runaway > c.lock_periods.max(1) {
                return Err(LostLock);
            }
            return Ok(Switch::Stay);
        }
        self.runaway = 0;
        let apart = h.angle().diff_radians(self.observer.angle());
        let w_obs = self.observer.speed_rad_s();
        let agrees = libm::fabsf(apart) < 0.3 && (w_obs - w).abs() <= 0.2 * w.abs();
        self.agree = if agrees {
            self.agree.saturating_add(1)
        } else {
            0
        };
        self.waited = self.waited.saturating_add(1);
        if self.agree >= c.lock_periods.max(1) {
            self.region = Region::Observer;
            self.waited = 0;
            self.last_angle = self.observer.angle();
            return Ok(Switch::Turn {
                rotate_rad: apart,
                to_observer: true,
            });
        }
        if self.waited > c.lock_timeout_periods.min(u32::MAX - 1) {
            return Err(LostLock);
        }
        Ok(Switch::Stay)
    }

    /// On the observer with injection configured: below the release speed
    /// the injection takes over from the observer's angle and speed (the
    /// same frame: nothing turns).
    fn follow_observer_to_hfi(&mut self) -> Switch {
        let w = self.observer.speed_rad_s();
        if w.abs() >= self.cfg.release_rad_s {
            return Switch::Stay;
        }
        if let Some(h) = self.hfi.as_mut() {
            h.place(self.observer.angle(), w);
        }
        self.region = Region::Hfi;
        self.agree = 0;
        self.waited = 0;
        self.runaway = 0;
        self.periods = 0;
        self.blend_a = 0.0;
        Switch::Stay
    }

    /// The field's current \[A\] (along the field's angle).
    pub fn field_current_a(&self) -> f32 {
        self.field_a
    }
}
