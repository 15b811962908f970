//! Joint mode in the current stage: the impedance law's q current and the
//! travel range's soft stop.

use super::*;

impl CurrentStage {
    /// Replace the travel range (the limits' position range) and the
    /// joint settings (design §21), in any mode: refused whole when a
    /// value is invalid ([`Refusal::Unsupported`]) or an active position
    /// command's target is outside the new range
    /// ([`Refusal::NotDisabled`]). An active impedance law's reference is
    /// moved into the new range.
    pub fn set_joint(&mut self, j: &JointChange) -> Result<(), Refusal> {
        let l = Limits {
            min_position_rad: j.min_position_rad,
            max_position_rad: j.max_position_rad,
            ..self.config.limits
        };
        if l.validate().is_err() || !j.joint.is_valid() {
            return Err(Refusal::Unsupported);
        }
        let target = match self.state.active {
            Command::Position { rad } => Some(rad),
            _ => None,
        };
        if target.is_some_and(|p| !(l.min_position_rad <= p && p <= l.max_position_rad)) {
            return Err(Refusal::NotDisabled);
        }
        self.config.limits = l;
        self.config.joint = j.joint;
        let law = &mut self.state.impedance;
        law.p_min_rad = l.min_position_rad;
        law.p_max_rad = l.max_position_rad;
        law.p_ref_rad = clamp(law.p_ref_rad, l.min_position_rad, l.max_position_rad);
        Ok(())
    }

    /// Take an impedance command (validated): its law, and when the mode
    /// is entered, a blend from the current in force (bumpless entry).
    pub(super) fn start_impedance(&mut self, i: &Impedance, old: Mode) {
        let kt = self.config.current.motor.torque_constant_nm_per_a();
        let st = &mut self.state;
        st.impedance = ImpedanceLaw::new(i, kt, self.config.current.ts_s, &self.config.limits);
        if old != Mode::Impedance {
            let n = self.config.joint.entry_blend_periods;
            st.blend_from_a = match old {
                Mode::Torque | Mode::Velocity | Mode::Position => st.iq_interp_a,
                Mode::OpenLoop => st.last_i_dq.q,
                _ => 0.0,
            };
            st.blend_weight = if n > 0 { 1.0 } else { 0.0 };
            st.blend_step = if n > 0 { 1.0 / n as f32 } else { 1.0 };
        }
    }

    /// The impedance law's q current this period \[A\] (before the limits),
    /// blended from the current in force while the mode is being entered.
    #[inline(always)]
    pub(super) fn impedance_iq(&mut self) -> f32 {
        let p = self.tracker.position().to_radians();
        let v = self.joint_velocity_rad_s();
        let st = &mut self.state;
        let law = st.impedance.step(p, v);
        if st.blend_weight > 0.0 {
            let iq = law + st.blend_weight * (st.blend_from_a - law);
            st.blend_weight -= st.blend_step;
            iq
        } else {
            law
        }
    }

    /// The velocity the joint features use [rad/s]: the angle tracker's
    /// (model-free). A joint's external torques are large against the
    /// rotor's inertia and mostly balanced by the law, so the speed
    /// observer, which sees them only as an unmodelled disturbance learnt
    /// with its 25 Hz pole, lags where the tracker follows the motion
    /// itself. With a fine sensor it is the rate of the tracked angle
    /// (`omega + kp e`: no phase lag well inside the tracker's 80 Hz);
    /// with a coarse one, whose innovation jumps at every edge, the
    /// tracker's integrator (design §21).
    #[inline(always)]
    pub(super) fn joint_velocity_rad_s(&self) -> f32 {
        let w = self.tracker.velocity_rad_s();
        if self.state.interpolation.is_some() {
            w
        } else {
            w + self.config.tracker.kp_per_s * self.state.last_innovation_rad
        }
    }

    /// The travel limits (design §21): a position beyond the range by more
    /// than the margin trips [`Fault::TravelLimit`]; otherwise the soft
    /// stop's window clamps `iq_a`. Nothing without travel limits.
    #[inline(always)]
    pub(super) fn travel(&mut self, iq_a: f32) -> f32 {
        let Some(t) = self.config.joint.travel else {
            return iq_a;
        };
        let p = self.tracker.position().to_radians();
        let (lo_p, hi_p) = (
            self.config.limits.min_position_rad,
            self.config.limits.max_position_rad,
        );
        if t.exceeded(p, lo_p, hi_p) {
            self.supervisor.trip(Fault::TravelLimit);
        }
        // The braking deceleration's current, `a J / kt`, when the
        // observer knows `kt / J`.
        let per_a = self.config.observer.accel_per_a_rad_s2;
        let brake_a = if per_a > 0.0 {
            t.brake_accel_rad_s2 / per_a
        } else {
            0.0
        };
        let v = self.joint_velocity_rad_s();
        let (lo, hi) = t.window_a(p, v, (lo_p, hi_p), brake_a);
        self.state.travel_window_a = Some((lo, hi));
        let x = if iq_a > hi { hi } else { iq_a };
        let x = if x < lo { lo } else { x };
        // Pushing back is within the current limit too.
        let lim = self.config.limits.max_current_a;
        clamp(x, -lim, lim)
    }
}
