//! # Running without an angle sensor (design §27)
//!
//! The flux observer ([`super::flux_observer`], design §26) gives the
//! rotor's angle once the back-EMF is well above what the drive's voltage
//! model gets wrong (the dead time, a warm winding). Below that speed the
//! drive runs the motor as a current-controlled stepper (I/f): a current
//! vector of fixed size whose angle the drive turns itself. The rotor
//! follows that field at a load angle of less than a quarter turn, so it
//! turns the way the field turns: forward only.
//!
//! The regions, in the order a start goes through them:
//!
//! | region | angle of the current loop | current | leaves when |
//! |---|---|---|---|
//! | `Idle` | none (bridge off) | none | a closed-loop command arrives |
//! | `Align` | held at the observer's last angle, plus the damper's lead | ramped up along it, then held | its time is over |
//! | `Field` | turned at a speed ramped towards the command (at most 1.25 times the hand-over speed), plus the damper's lead | along that angle, fixed size | at its speed, the observer agrees with the field for [`SensorlessConfig::lock_periods`] above the hand-over speed |
//! | `Observer` | the observer's | the closed loop's | the observer's speed falls below the release speed: back to `Field` from where the rotor is (with injection: to `Hfi`) |
//!
//! With high-frequency injection (a salient motor, design §28,
//! [`super::hfi`]) `HfiSettle` (the estimate settles, no current),
//! `HfiPolarity` (the saturation test's d pulses) and `Hfi` (the closed
//! loop on the injection's angle, to `Observer` above the hand-over speed
//! once the observer agrees) take the place of `Align` and `Field`.
//!
//! The damper (design §27): the current's angle leads the field by
//! [`SensorlessConfig::damping_s`] times the field's speed less the
//! observer's; on the turning field its weight grows with the field's
//! speed up to the hand-over speed. At the alignment's end the observer is
//! placed on the current's angle ([`FluxObserver::place`]); while the drive
//! runs on it, its magnitude correction is held to twice the speed at low
//! speed ([`FluxObserver::set_low_speed_scaling`]).
//!
//! Hand-over to the observer: the current loop's frame turns from the
//! field's angle to the observer's at the same current (its integrators
//! are turned with it); the q current that carried the rotor becomes the
//! speed loop's starting point, the d current is taken down in a straight
//! line over [`SensorlessConfig::blend_periods`]. Back to the field the
//! same way: the field is placed on the current vector in force.
//!
//! Lost lock: in `Field` above the hand-over speed the observer must agree
//! (its speed within a fifth of the field's, same sign) within
//! [`SensorlessConfig::lock_timeout_periods`]; if it does not, the rotor
//! does not follow the field (locked, stalled, a load beyond the start
//! current) or the observer does not follow the rotor, and
//! [`Fault::ObserverLostLock`](super::Fault::ObserverLostLock) latches.
//! In `Observer` a speed that falls below what the observer can see goes
//! back to `Field`, where the same rule applies: a locked rotor at speed
//! latches the fault after the field has come back up to the hand-over
//! speed plus the timeout. At any field speed, a rotor the observer sees
//! turning against the commanded direction (the field's without a
//! velocity command) faster than the release speed (a load that drives it
//! backwards) latches the fault after
//! [`SensorlessConfig::lock_periods`]. In `Observer` the motor-model check
//! (design §24) keeps running on the observer's angle; a model mismatch
//! there latches the same fault (the check cannot tell a wrong angle from
//! wrong current readings).

mod region;

pub use region::{LostLock, Region, Switch};

use super::flux_observer::{FluxObserver, ObserverConfig};
use super::hfi::{Hfi, HfiConfig, Polarity};
use super::MotorParams;
use crate::angle::{ElectricalAngle, MechanicalAngle};
use crate::frames::AlphaBeta;

/// The share of the start current's acceleration the field's ramp uses
/// (the rest is margin for a load and friction).
pub const RAMP_SHARE: f32 = 0.2;

/// The largest angle the field's damping adds \[rad, electrical\].
pub const DAMPING_MAX_RAD: f32 = core::f32::consts::FRAC_PI_2;

/// The hand-over speed's back-EMF against the voltage the drive's model
/// may get wrong (the dead time and 30 % of the resistance's drop at the
/// start current).
pub const HANDOVER_EMF_MARGIN: f32 = 2.5;

/// During the alignment the rotor swings onto the held field by at most
/// half an electrical turn; seen by the observer to turn against the
/// commanded direction by more than this [rad, electrical] it slips past
/// the field (a load stronger than the field's spring drives it):
/// [`Fault::ObserverLostLock`](super::Fault::ObserverLostLock) at once.
pub const ALIGN_SLIP_RAD: f32 = 3.0 * core::f32::consts::PI;

/// How the drive runs without an angle sensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorlessConfig {
    /// The observer's motor, period and inverter.
    pub observer: ObserverConfig,
    /// The current of the alignment and the field \[A\].
    pub current_a: f32,
    /// The bus voltage it was derived for \[V\].
    pub bus_voltage_v: f32,
    /// Periods of the alignment.
    pub align_periods: u32,
    /// Periods over which the current rises at the alignment's start.
    pub rise_periods: u32,
    /// The field's damping \[s\]: the current's angle leads the field by this
    /// times the field's speed less the observer's (bounded to
    /// [`DAMPING_MAX_RAD`]). A rotor left to a turning field swings about
    /// it like a pendulum with almost nothing to damp it; this is the
    /// damper.
    pub damping_s: f32,
    /// The field's acceleration [rad/s^2, electrical].
    pub accel_rad_s2: f32,
    /// Above this speed the observer takes over [rad/s, electrical].
    pub handover_rad_s: f32,
    /// Below this speed the field takes over again [rad/s, electrical].
    pub release_rad_s: f32,
    /// Periods the observer must agree with the field before it takes
    /// over.
    pub lock_periods: u32,
    /// Periods above the hand-over speed without agreement before
    /// [`Fault::ObserverLostLock`](super::Fault::ObserverLostLock); a
    /// rotor the observer sees turn against the commanded direction faster
    /// than the release speed gets [`Self::lock_periods`] only.
    pub lock_timeout_periods: u32,
    /// Periods over which the field's d current is taken down after the
    /// hand-over.
    pub blend_periods: u32,
    /// High-frequency injection at standstill and low speed instead of
    /// the alignment and the field, asked for: it runs where the motor in
    /// force is salient enough (design §28; [`Self::with_hfi`], its values
    /// [`Self::hfi_config`]). A flag, not
    /// the values: the configuration sits in front of the current stage's
    /// hot fields, and 40 more bytes there cost every period (`cargo xtask
    /// bench`).
    pub hfi: bool,
}

impl SensorlessConfig {
    /// Derived from the identified motor, the start current \[A\], the
    /// rotor's inertia \[kg m^2\] and the bus \[V\]:
    ///
    /// - the field's acceleration is [`RAMP_SHARE`] of what the start
    ///   current gives the bare rotor;
    /// - the alignment lasts four periods of the rotor's swing on the
    ///   start current's spring, at least 50 ms; its current rises over
    ///   2 ms (a load that pushes the rotor back has little time);
    /// - the field's damping is critical on that spring (`2 / w`);
    /// - the hand-over speed's back-EMF is [`HANDOVER_EMF_MARGIN`] times
    ///   the dead time's voltage plus 30 % of the resistance's drop, and at
    ///   least 1 % of the bus; the release speed is half of it;
    /// - the observer must agree for 5 ms (at least 50 periods) and has
    ///   0.5 s to do so; the d current goes down over 5 ms;
    /// - on a salient motor (saliency at least
    ///   [`super::hfi::SALIENCY_MIN`]) high-frequency injection replaces
    ///   the alignment and the field ([`Self::with_hfi`]; off with
    ///   [`Self::without_hfi`]).
    ///
    /// `None` when a value is not usable (not finite, not positive).
    pub fn for_motor(
        observer: ObserverConfig,
        start_current_a: f32,
        inertia_kg_m2: f32,
        v_bus_v: f32,
    ) -> Option<Self> {
        let m = observer.motor;
        let ts = observer.ts_s;
        let usable = crate::all_finite([start_current_a, inertia_kg_m2, v_bus_v, ts])
            && start_current_a > 0.0
            && inertia_kg_m2 > 0.0
            && v_bus_v > 0.0
            && ts > 0.0
            && m.flux_linkage_wb > 0.0
            && m.pole_pairs > 0;
        if !usable {
            return None;
        }
        let pp = f32::from(m.pole_pairs);
        let kt = m.torque_constant_nm_per_a();
        let accel = RAMP_SHARE * kt * start_current_a / inertia_kg_m2 * pp;
        // The alignment's spring: pp * kt * I [N m / rad, mechanical].
        let swing_rad_s = crate::sqrtf(pp * kt * start_current_a / inertia_kg_m2);
        let align_s = (4.0 * core::f32::consts::TAU / swing_rad_s).max(0.05);
        let v_err = v_bus_v * observer.dead_time_s / ts + 0.3 * m.r_ohm * start_current_a;
        let emf = (HANDOVER_EMF_MARGIN * v_err).max(0.01 * v_bus_v);
        let handover = emf / m.flux_linkage_wb;
        let periods = |s: f32| (s / ts) as u32;
        let c = Self {
            observer,
            current_a: start_current_a,
            bus_voltage_v: v_bus_v,
            align_periods: periods(align_s).max(2),
            rise_periods: periods(2e-3).max(1),
            damping_s: 2.0 / swing_rad_s,
            accel_rad_s2: accel,
            handover_rad_s: handover,
            release_rad_s: 0.5 * handover,
            lock_periods: periods(5e-3).max(50),
            lock_timeout_periods: periods(0.5),
            blend_periods: periods(5e-3).max(1),
            // Asked for; it runs where the motor in force allows it.
            hfi: true,
        };
        crate::all_finite([c.accel_rad_s2, c.handover_rad_s]).then_some(c)
    }

    /// Without injection: the alignment and the field start every motor.
    pub fn without_hfi(self) -> Self {
        Self { hfi: false, ..self }
    }

    /// The injection's values when it is on and the motor allows it
    /// ([`HfiConfig::for_motor`] from this configuration's motor, period,
    /// start current, the acceleration that current gives the bare rotor,
    /// and bus).
    pub fn hfi_config(&self) -> Option<HfiConfig> {
        if !self.hfi {
            return None;
        }
        HfiConfig::for_motor(
            &self.observer.motor,
            self.observer.ts_s,
            self.current_a,
            self.accel_rad_s2 / RAMP_SHARE,
            self.bus_voltage_v,
        )
    }

    /// With high-frequency injection below the hand-over speed, derived
    /// from the same motor, period, start current and bus
    /// ([`HfiConfig::for_motor`]); `None` when the motor is not salient
    /// enough ([`super::hfi::SALIENCY_MIN`]). [`Self::for_motor`] includes
    /// it where the motor allows it.
    pub fn with_hfi(self) -> Option<Self> {
        let c = Self { hfi: true, ..self };
        c.hfi_config().map(|_| c)
    }
}

/// The sensorless angle source: the observer and the region it runs in
/// (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sensorless {
    cfg: SensorlessConfig,
    observer: FluxObserver,
    region: Region,
    /// The field's angle and speed [rad/s, electrical].
    field: ElectricalAngle,
    field_rad_s: f32,
    /// The field's current now \[A\] (ramped up to `cfg.current_a`).
    field_a: f32,
    /// The damping's lead of the current's angle on the field \[rad\].
    lead_rad: f32,
    /// Periods in the region (alignment), agreeing, waiting for agreement.
    periods: u32,
    agree: u32,
    waited: u32,
    /// In `Hfi` below the hand-over speed: the net count of periods the
    /// observer saw a runaway the injection does not (its own counter: the
    /// hand-over's wait is `waited`).
    runaway: u32,
    /// The q current held from a hand-over until the speed stage's output
    /// changes, with that output at the hand-over \[A\].
    hold: Option<(f32, f32)>,
    /// The d current still added after a hand-over \[A\] and its step.
    blend_a: f32,
    blend_step_a: f32,
    /// A mechanical angle made from the observer's (for the position and
    /// speed tracking; its zero is arbitrary).
    mech: MechanicalAngle,
    last_angle: ElectricalAngle,
    /// The observer's angle turned during the alignment [rad, electrical].
    align_turned_rad: f32,
    /// The injection's estimator (when configured) and its polarity test.
    hfi: Option<Hfi>,
    polarity: Polarity,
}

impl Sensorless {
    /// Idle, the observer at angle zero.
    pub fn new(cfg: SensorlessConfig) -> Self {
        let mut observer = FluxObserver::new(cfg.observer);
        // Not known to follow the rotor until it drives (or agrees with a
        // sensor beside it): the flux linkage is not tracked before.
        observer.set_locked(false);
        Self {
            cfg,
            observer,
            region: Region::Idle,
            field: ElectricalAngle::ZERO,
            field_rad_s: 0.0,
            field_a: 0.0,
            lead_rad: 0.0,
            periods: 0,
            agree: 0,
            waited: 0,
            runaway: 0,
            hold: None,
            blend_a: 0.0,
            blend_step_a: 0.0,
            mech: MechanicalAngle::ZERO,
            last_angle: ElectricalAngle::ZERO,
            align_turned_rad: 0.0,
            hfi: cfg.hfi_config().map(Hfi::new),
            polarity: Polarity::default(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &SensorlessConfig {
        &self.cfg
    }

    /// A new motor (an identification, a permit): the observer starts
    /// again with it, the region is `Idle`.
    pub fn set_motor(&mut self, motor: MotorParams) {
        self.cfg.observer.motor = motor;
        // The injection is derived again for the new motor (none if it is
        // not salient).
        *self = Self::new(self.cfg);
    }

    /// The injection's estimator, when configured.
    pub fn hfi(&self) -> Option<&Hfi> {
        self.hfi.as_ref()
    }

    /// True when the drive holds torque at standstill (injection
    /// configured): torque, position and impedance commands are allowed.
    pub fn holds_torque_at_standstill(&self) -> bool {
        self.hfi.is_some()
    }

    /// The angle the current loop uses: the injection's in its regions,
    /// else the observer's.
    pub fn angle(&self) -> ElectricalAngle {
        match (&self.hfi, self.region.injects()) {
            (Some(h), true) => h.angle(),
            _ => self.observer.angle(),
        }
    }

    /// The speed of that angle [rad/s, electrical].
    pub fn speed_rad_s(&self) -> f32 {
        match (&self.hfi, self.region.injects()) {
            (Some(h), true) => h.speed_rad_s(),
            _ => self.observer.speed_rad_s(),
        }
    }

    /// The injection's d voltage for the period ahead \[V\] (0 outside its
    /// regions) and the mean current the current loop runs on there \[A\].
    pub fn injection(&mut self, i_ab: AlphaBeta) -> (f32, AlphaBeta) {
        match (self.hfi.as_mut(), self.region.injects()) {
            (Some(h), true) => (h.inject_v(), h.mean_current(i_ab)),
            _ => (0.0, i_ab),
        }
    }

    /// The d current of the polarity test this period \[A\] (0 outside it).
    pub fn polarity_current_a(&self) -> f32 {
        match (&self.hfi, self.region) {
            (Some(h), Region::HfiPolarity) => self.polarity.current_a(h.config()),
            _ => 0.0,
        }
    }

    /// The observer.
    pub fn observer(&self) -> &FluxObserver {
        &self.observer
    }

    /// The region in force.
    pub fn region(&self) -> Region {
        self.region
    }

    /// The mechanical angle made from the observer's (its zero is
    /// arbitrary).
    pub fn mechanical(&self) -> MechanicalAngle {
        self.mech
    }

    /// The field's angle.
    pub fn field_angle(&self) -> ElectricalAngle {
        self.field
    }

    /// The current's angle in `Align` and `Field`: the field's with the
    /// damping's lead.
    pub fn current_angle(&self) -> ElectricalAngle {
        self.field.add_radians(self.lead_rad)
    }

    /// The field's speed [rad/s, electrical].
    pub fn field_speed_rad_s(&self) -> f32 {
        self.field_rad_s
    }

    /// Period start: the observer takes the measured current \[A\];
    /// returns the mechanical angle made from its angle (`pole_pairs`
    /// electrical turns per turn; its zero is arbitrary).
    #[inline(always)]
    pub fn sense(&mut self, i_ab: AlphaBeta, pole_pairs: u8) -> MechanicalAngle {
        self.observer.update(i_ab);
        if let (Some(h), true) = (self.hfi.as_mut(), self.region.injects()) {
            h.update(i_ab);
        }
        let a = self.angle();
        let step = a.diff_radians(self.last_angle);
        self.last_angle = a;
        if self.region == Region::Align {
            self.align_turned_rad += step;
        }
        let pp = f32::from(pole_pairs.max(1));
        self.mech = self.mech.add_radians(step / pp);
        self.mech
    }

    /// Beside an angle sensor, each period: whether the observer agrees
    /// with it (its flux linkage is tracked only then). Its magnitude
    /// correction is held at low speed as when it drives the loop (a flux
    /// linkage off by a warm magnet costs less angle).
    pub fn set_agrees_with_sensor(&mut self, agrees: bool) {
        self.observer.set_locked(agrees);
        self.observer.set_low_speed_scaling(true);
    }

    /// Record the duties handed to the bridge and the bus they were
    /// computed for \[V\], or `None`: the bridge is off (the region goes
    /// back to `Idle`).
    #[inline(always)]
    pub fn record(&mut self, duties: Option<[f32; 3]>, v_bus_v: f32) {
        match duties {
            Some(d) => self.observer.record(d, v_bus_v),
            None => {
                if let (Some(h), true) = (self.hfi.as_ref(), self.region.injects()) {
                    // The best angle known: the next start begins there,
                    // and the mechanical angle does not take a jump.
                    self.observer.place(h.angle());
                    self.last_angle = h.angle();
                }
                self.observer.pause();
                self.region = Region::Idle;
                self.blend_a = 0.0;
            }
        }
    }

    /// Take over a turning rotor the observer follows (it ran beside a
    /// sensor that failed, design §27): straight to `Observer`, nothing
    /// held or blended, the mechanical angle going on from `mech`.
    pub fn take_over(&mut self, mech: MechanicalAngle) {
        self.region = Region::Observer;
        self.hold = None;
        self.blend_a = 0.0;
        self.agree = 0;
        self.waited = 0;
        self.mech = mech;
        self.last_angle = self.observer.angle();
    }

    /// Hold the q current `iq_a` \[A\] after a hand-over until the speed
    /// stage's output moves from `from_speed_a` (its next step, which
    /// starts from the held current).
    pub fn hold_iq(&mut self, iq_a: f32, from_speed_a: f32) {
        self.hold = Some((iq_a, from_speed_a));
    }

    /// The held q current \[A\], while the speed stage's output is still
    /// `from_speed_a`'s value at the hand-over.
    #[inline(always)]
    pub fn held_iq(&mut self, from_speed_a: f32) -> Option<f32> {
        match self.hold {
            Some((iq, at)) if at == from_speed_a && self.region == Region::Observer => Some(iq),
            _ => {
                self.hold = None;
                None
            }
        }
    }

    /// The d current the hand-over still adds this period \[A\].
    #[inline(always)]
    pub fn take_blend_a(&mut self) -> f32 {
        let b = self.blend_a;
        if b != 0.0 {
            let next = b - self.blend_step_a;
            self.blend_a = if (next > 0.0) == (b > 0.0) { next } else { 0.0 };
        }
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::Dq;

    fn observer() -> ObserverConfig {
        ObserverConfig {
            motor: MotorParams {
                pole_pairs: 7,
                r_ohm: 0.1,
                ld_h: 50e-6,
                lq_h: 50e-6,
                flux_linkage_wb: 0.005,
            },
            ts_s: 50e-6,
            dead_time_s: 0.0,
            current_floor_a: 0.05,
        }
    }

    fn config() -> SensorlessConfig {
        SensorlessConfig::for_motor(observer(), 5.0, 1e-5, 24.0).unwrap()
    }

    #[test]
    fn unusable_values_give_no_configuration() {
        for (i, j, v) in [
            (f32::NAN, 1e-5, 24.0),
            (5.0, 0.0, 24.0),
            (5.0, 1e-5, -1.0),
            (0.0, 1e-5, 24.0),
            (5.0, f32::INFINITY, 24.0),
        ] {
            assert!(SensorlessConfig::for_motor(observer(), i, j, v).is_none());
        }
        let mut o = observer();
        o.motor.flux_linkage_wb = 0.0;
        assert!(SensorlessConfig::for_motor(o, 5.0, 1e-5, 24.0).is_none());
    }

    /// The derived values follow the stated rules.
    #[test]
    fn derived_values_follow_the_rules() {
        let c = config();
        let m = observer().motor;
        let kt = m.torque_constant_nm_per_a();
        assert!(
            (c.accel_rad_s2 - RAMP_SHARE * kt * 5.0 / 1e-5 * 7.0).abs() < 1e-2 * c.accel_rad_s2
        );
        // 1 % of the bus dominates here (no dead time, small R).
        let emf = (HANDOVER_EMF_MARGIN * 0.3 * 0.1 * 5.0).max(0.24);
        assert!((c.handover_rad_s - emf / 0.005).abs() < 1e-3 * c.handover_rad_s);
        assert_eq!(c.release_rad_s, 0.5 * c.handover_rad_s);
        assert!(c.align_periods >= 1000); // at least 50 ms
        assert_eq!(c.rise_periods, 40); // 2 ms
    }

    /// A closed-loop command starts the alignment: the current rises over
    /// the rise, is held, and the field follows after the alignment's
    /// time; no closed loop: idle.
    #[test]
    fn alignment_then_field_then_idle() {
        let c = config();
        let mut s = Sensorless::new(c);
        assert_eq!(s.step(true, 1000.0, Dq::ZERO), Ok(Switch::Stay));
        assert_eq!(s.region(), Region::Align);
        let mut peak: f32 = 0.0;
        for k in 1..=c.align_periods {
            s.step(true, 1000.0, Dq::ZERO).unwrap();
            let expected = c.current_a * (k as f32 / c.rise_periods as f32).min(1.0);
            assert!((s.field_current_a() - expected).abs() < 1e-4);
            peak = peak.max(s.field_current_a());
        }
        assert_eq!(peak, c.current_a);
        assert_eq!(s.region(), Region::Field);
        s.step(false, 1000.0, Dq::ZERO).unwrap();
        assert_eq!(s.region(), Region::Idle);
    }

    /// A rotor that never turns (the observer sees nothing): the field
    /// goes no faster than a quarter above the hand-over speed, and the
    /// lock is lost after the timeout above the hand-over speed.
    #[test]
    fn a_field_the_observer_never_sees_loses_the_lock_in_time() {
        let c = config();
        let mut s = Sensorless::new(c);
        let target = 10.0 * c.handover_rad_s;
        let mut above = 0u32;
        for _ in 0..(c.align_periods + 1) {
            s.step(true, target, Dq::ZERO).unwrap();
        }
        let lost = loop {
            match s.step(true, target, Dq::ZERO) {
                Ok(_) => {
                    assert!(s.field_speed_rad_s() <= 1.25 * c.handover_rad_s * 1.0001);
                    assert_eq!(s.region(), Region::Field);
                    if s.field_speed_rad_s() >= c.handover_rad_s {
                        above += 1;
                    }
                    assert!(above <= c.lock_timeout_periods + 1, "never lost");
                }
                Err(e) => break e,
            }
        };
        assert_eq!(lost, LostLock);
        assert_eq!(above, c.lock_timeout_periods);
    }

    /// The hand-over's d current goes down in a straight line to zero.
    #[test]
    fn blend_goes_down_to_zero() {
        let mut s = Sensorless::new(config());
        s.blend_a = 3.0;
        s.blend_step_a = 1.0;
        let got: [f32; 5] = core::array::from_fn(|_| s.take_blend_a());
        assert_eq!(got, [3.0, 2.0, 1.0, 0.0, 0.0]);
    }
}
