//! A real motor's imperfections that the ideal model leaves out: the
//! cogging torque of the magnets on the stator teeth, and the angle
//! sensor's error over a turn. Both are off by default
//! ([`Plant::set_cogging`], [`Plant::set_angle_sensor_error`]); off, the
//! plant computes bit for bit what it did without them.
//!
//! # Cogging
//!
//! The magnets see a reluctance that varies with the rotor's mechanical
//! angle `theta`, `N = lcm(slots, 2 p)` times per turn. Its potential
//! energy and the torque it puts on the rotor (`T = -dE/dtheta`), with
//! `x = N theta + phi`, fundamental `A` and second-harmonic share `s`:
//!
//! ```text
//! E(theta) = A / N (cos x + s/2 cos 2x)          [J]
//! T(theta) = A (sin x + s sin 2x)                [N m]
//! ```
//!
//! Both have zero mean over a turn. The torque acts on a free rotor beside
//! the electromagnetic torque (and inside the stiction test), integrated
//! with the rest of the state; its work on the rotor is
//! [`EnergyAccount::cogging_j`] `= -Delta E`.
//!
//! # Angle-sensor error
//!
//! An off-axis magnet or an eccentric disc makes the sensor read
//! `theta + e(theta)` of the physical disc's angle `theta` (mechanical
//! radians), quantised after the error is added:
//!
//! ```text
//! e(theta) = a1 sin(theta + phi1) + a2 sin(2 theta + phi2)
//! ```
//!
//! ```
//! use foc_plant::plant::{BenchConfig, Cogging, MotorParams, Plant};
//! let c = Cogging::from_slots(12, 7, 0.01, 0.3);
//! assert_eq!(c.cycles_per_turn, 84);
//! assert!(c.validate().is_ok());
//! let mut plant = Plant::new(MotorParams::example(), BenchConfig::default());
//! plant.set_cogging(Some(c));
//! plant.set_rotor_angle(0.01);
//! assert_eq!(plant.cogging_torque_nm(), c.torque_nm(0.01));
//! ```

use super::*;

/// Cogging torque of a slotted stator (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cogging {
    /// Cogging cycles per mechanical turn, `lcm(slots, 2 p)`.
    pub cycles_per_turn: u32,
    /// Peak of the fundamental \[N m\].
    pub amplitude_nm: Real,
    /// Amplitude of the harmonic at `2 cycles_per_turn` over the
    /// fundamental's (0 to 1).
    pub second_harmonic_share: Real,
    /// Phase of the fundamental in cogging-cycle radians (`x = N theta +
    /// phase_rad`) \[rad\].
    pub phase_rad: Real,
}

impl Cogging {
    /// The cogging of `slots` stator slots against `pole_pairs` pairs of
    /// magnets: `lcm(slots, 2 pole_pairs)` cycles per turn, fundamental
    /// `amplitude_nm` \[N m\], second harmonic `second_share` of it, phase 0.
    pub fn from_slots(slots: u32, pole_pairs: u8, amplitude_nm: Real, second_share: Real) -> Self {
        Self {
            cycles_per_turn: lcm(slots, 2 * pole_pairs as u32),
            amplitude_nm,
            second_harmonic_share: second_share,
            phase_rad: 0.0,
        }
    }

    /// Check every field is physical.
    pub fn validate(&self) -> Result<(), ParamError> {
        if self.cycles_per_turn == 0 {
            return Err(ParamError::NotPositive("cycles_per_turn"));
        }
        non_negative(self.amplitude_nm, "amplitude_nm")?;
        let s = self.second_harmonic_share;
        if !(s.is_finite() && (0.0..=1.0).contains(&s)) {
            return Err(ParamError::Negative("second_harmonic_share (0 to 1)"));
        }
        finite(self.phase_rad, "phase_rad")
    }

    /// The cogging angle `x = N theta + phi` at mechanical angle `theta_m_rad`.
    fn cycle_angle_rad(&self, theta_m_rad: Real) -> Real {
        self.cycles_per_turn as Real * theta_m_rad + self.phase_rad
    }

    /// Torque on the rotor at mechanical angle `theta_m_rad` \[N m\]
    /// (`-dE/dtheta` of [`Cogging::energy_j`]).
    pub fn torque_nm(&self, theta_m_rad: Real) -> Real {
        let x = self.cycle_angle_rad(theta_m_rad);
        self.amplitude_nm * (real::sin(x) + self.second_harmonic_share * real::sin(2.0 * x))
    }

    /// Potential energy of the rotor at mechanical angle `theta_m_rad`
    /// \[J\] (zero mean over a turn).
    pub fn energy_j(&self, theta_m_rad: Real) -> Real {
        let x = self.cycle_angle_rad(theta_m_rad);
        let n = self.cycles_per_turn.max(1) as Real;
        self.amplitude_nm / n
            * (real::cos(x) + 0.5 * self.second_harmonic_share * real::cos(2.0 * x))
    }
}

/// Error of the angle sensor over a turn (see the module docs), in
/// mechanical radians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorError {
    /// Once-per-turn amplitude (eccentricity) \[rad\].
    pub first_rad: Real,
    /// Phase of the once-per-turn term \[rad\].
    pub first_phase_rad: Real,
    /// Twice-per-turn amplitude \[rad\].
    pub second_rad: Real,
    /// Phase of the twice-per-turn term \[rad\].
    pub second_phase_rad: Real,
}

impl SensorError {
    /// Once- and twice-per-turn amplitudes \[rad\], phases 0.
    pub const fn new(first_rad: Real, second_rad: Real) -> Self {
        Self {
            first_rad,
            first_phase_rad: 0.0,
            second_rad,
            second_phase_rad: 0.0,
        }
    }

    /// Check every field is physical.
    pub fn validate(&self) -> Result<(), ParamError> {
        non_negative(self.first_rad, "first_rad")?;
        finite(self.first_phase_rad, "first_phase_rad")?;
        non_negative(self.second_rad, "second_rad")?;
        finite(self.second_phase_rad, "second_phase_rad")
    }

    /// What the sensor reads minus the true angle, at the disc's true
    /// mechanical angle `theta_m_rad` \[rad\].
    pub fn error_rad(&self, theta_m_rad: Real) -> Real {
        self.first_rad * real::sin(theta_m_rad + self.first_phase_rad)
            + self.second_rad * real::sin(2.0 * theta_m_rad + self.second_phase_rad)
    }
}

/// Least common multiple (0 when either is 0).
fn lcm(a: u32, b: u32) -> u32 {
    if a == 0 || b == 0 {
        return 0;
    }
    let (mut x, mut y) = (a, b);
    while y != 0 {
        (x, y) = (y, x % y);
    }
    a / x * b
}

/// `x` finite, else [`ParamError::Negative`] naming it.
fn finite(x: Real, name: &'static str) -> Result<(), ParamError> {
    if x.is_finite() {
        Ok(())
    } else {
        Err(ParamError::Negative(name))
    }
}

impl Plant {
    /// Add (`Some`) or remove (`None`, the default) the cogging torque.
    /// Parameters are used as given; call [`Cogging::validate`] first when
    /// they come from a user.
    pub fn set_cogging(&mut self, cogging: Option<Cogging>) {
        self.cogging = cogging;
    }
    /// The cogging model, if any.
    pub fn cogging(&self) -> Option<&Cogging> {
        self.cogging.as_ref()
    }
    /// Cogging torque on the rotor at its present angle \[N m\] (0 without).
    pub fn cogging_torque_nm(&self) -> Real {
        self.cogging.map_or(0.0, |c| c.torque_nm(self.theta_m))
    }
    /// Cogging potential energy at the present angle \[J\] (0 without).
    pub fn cogging_energy_j(&self) -> Real {
        self.cogging.map_or(0.0, |c| c.energy_j(self.theta_m))
    }
    /// Torque the motor puts on its shaft at the present state \[N m\]:
    /// electromagnetic ([`Plant::torque_nm`]) plus cogging, friction
    /// excluded (what a torque transducer between this rotor and a dyno
    /// reads).
    pub fn shaft_torque_nm(&self) -> Real {
        self.torque_nm() + self.cogging_torque_nm()
    }

    /// Add (`Some`) or remove (`None`, the default) the angle sensor's
    /// error (both [`AngleSensorKind`]s; encoder faults act on top).
    pub fn set_angle_sensor_error(&mut self, error: Option<SensorError>) {
        self.sensor_error = error;
    }
    /// The angle sensor's error model, if any.
    pub fn angle_sensor_error(&self) -> Option<&SensorError> {
        self.sensor_error.as_ref()
    }
    /// Error of the angle reading at the present angle, before
    /// quantisation \[rad\] (0 without): [`SensorError::error_rad`] of the
    /// true angle; an incremental encoder, zeroed at power-on, less the
    /// error at its zero.
    pub fn angle_sensor_error_rad(&self) -> Real {
        match (self.sensor_error, self.angle_sensor) {
            (None, _) => 0.0,
            (Some(e), AngleSensorKind::Absolute { .. }) => e.error_rad(self.theta_m),
            (Some(e), AngleSensorKind::Incremental) => {
                e.error_rad(self.theta_m) - e.error_rad(self.sensor_zero_m_rad)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Relative tolerance of one result computed two ways: tight in f64,
    /// loose in f32 (`plant-f32`), where the cogging angle `N theta` of a
    /// few hundred radians keeps about five digits.
    const TOL: Real = if cfg!(feature = "plant-f32") {
        1e-2
    } else {
        1e-6
    };

    /// A motor whose only losses are the given friction (no current flows
    /// with the bridge off at these speeds).
    fn motor(viscous_nm_s_per_rad: Real, coulomb_nm: Real) -> MotorParams {
        MotorParams {
            viscous_friction_nm_s_per_rad: viscous_nm_s_per_rad,
            coulomb_friction_nm: coulomb_nm,
            ..MotorParams::example()
        }
    }

    /// 12 slots against the example's 7 pole pairs: 84 cycles per turn.
    fn cogging(amplitude_nm: Real, second_share: Real) -> Cogging {
        Cogging {
            phase_rad: 0.4,
            ..Cogging::from_slots(12, 7, amplitude_nm, second_share)
        }
    }

    /// The bottom of a cogging well (`x = pi`) \[rad\].
    fn well_bottom_rad(c: &Cogging) -> Real {
        (real::PI - c.phase_rad) / c.cycles_per_turn as Real
    }

    #[test]
    fn lcm_of_slots_and_poles() {
        assert_eq!(Cogging::from_slots(36, 21, 1.0, 0.0).cycles_per_turn, 252);
        assert_eq!(Cogging::from_slots(12, 7, 1.0, 0.0).cycles_per_turn, 84);
        assert_eq!(Cogging::from_slots(12, 4, 1.0, 0.0).cycles_per_turn, 24);
        assert_eq!(Cogging::from_slots(36, 3, 1.0, 0.0).cycles_per_turn, 36);
        assert_eq!(Cogging::from_slots(18, 8, 1.0, 0.0).cycles_per_turn, 144);
        assert_eq!(Cogging::from_slots(0, 7, 1.0, 0.0).cycles_per_turn, 0);
    }

    #[test]
    fn validate_names_the_field() {
        assert_eq!(cogging(0.01, 0.3).validate(), Ok(()));
        let bad = |c: Cogging| c.validate().unwrap_err();
        assert_eq!(
            bad(Cogging::from_slots(0, 7, 0.01, 0.3)),
            ParamError::NotPositive("cycles_per_turn")
        );
        assert_eq!(
            bad(cogging(-0.01, 0.3)),
            ParamError::Negative("amplitude_nm")
        );
        assert!(
            matches!(bad(cogging(0.01, 1.5)), ParamError::Negative(n) if n.starts_with("second_harmonic_share"))
        );
        assert_eq!(SensorError::new(0.005, 0.002).validate(), Ok(()));
        assert_eq!(
            SensorError::new(-0.005, 0.0).validate(),
            Err(ParamError::Negative("first_rad"))
        );
        let nan_phase = SensorError {
            second_phase_rad: Real::NAN,
            ..SensorError::new(0.0, 0.0)
        };
        assert_eq!(
            nan_phase.validate(),
            Err(ParamError::Negative("second_phase_rad"))
        );
    }

    #[test]
    fn torque_is_periodic_zero_mean_and_minus_the_energy_slope() {
        let c = cogging(0.02, 0.3);
        let period = TAU / c.cycles_per_turn as Real;
        let n = 4096;
        let (mut sum, mut peak) = (0.0, 0.0 as Real);
        for k in 0..n {
            let th = TAU * k as Real / n as Real;
            let t = c.torque_nm(th);
            sum += t;
            peak = peak.max(t.abs());
            assert!((c.torque_nm(th + period) - t).abs() < TOL * c.amplitude_nm);
            // Central difference: truncation ~1e-5 A at this step.
            let h = 1e-3 * period;
            let slope = (c.energy_j(th + h) - c.energy_j(th - h)) / (2.0 * h);
            assert!(
                (t + slope).abs() < (1e-4 + TOL) * c.amplitude_nm,
                "{t} vs {slope}"
            );
        }
        assert!(sum.abs() / (n as Real) < TOL * c.amplitude_nm, "mean {sum}");
        assert!(peak > c.amplitude_nm, "peak {peak}");
    }

    #[test]
    fn constant_speed_sweep_reads_the_formula_and_its_work() {
        let c = cogging(0.02, 0.3);
        let mut plant = Plant::new(motor(0.0, 0.0), BenchConfig::default());
        plant.set_cogging(Some(c));
        plant.set_mechanics(Mechanics::ConstantSpeed(30.0));
        let e0 = plant.cogging_energy_j();
        for _ in 0..400 {
            plant.step_period([0.5; 3], false, 0.0);
            let x = c.cycles_per_turn as Real * plant.theta_m_rad() + c.phase_rad;
            let formula = 0.02 * (real::sin(x) + 0.3 * real::sin(2.0 * x));
            assert!((plant.cogging_torque_nm() - formula).abs() < 1e-3 * TOL * c.amplitude_nm);
            assert_eq!(
                plant.shaft_torque_nm(),
                plant.torque_nm() + plant.cogging_torque_nm()
            );
        }
        // The work it did is minus its energy's change (0 over whole cycles).
        let work = plant.energy().cogging_j;
        let expected = e0 - plant.cogging_energy_j();
        assert!(
            (work - expected).abs() < TOL * c.amplitude_nm,
            "{work} vs {expected}"
        );
        // It does not move a driven rotor.
        assert_eq!(plant.omega_m_rad_s(), 30.0);
    }

    #[test]
    fn released_in_a_well_the_rotor_oscillates_settles_and_balances_energy() {
        let c = cogging(0.02, 0.3);
        let bottom = well_bottom_rad(&c);
        let start = bottom + 0.3 * real::PI / c.cycles_per_turn as Real;
        let mut plant = Plant::new(motor(5e-3, 0.0), BenchConfig::default());
        plant.set_cogging(Some(c));
        plant.start_rotor_at(start);
        let e0 = plant.cogging_energy_j();
        let mut crossed = false;
        for _ in 0..6000 {
            plant.step_period([0.5; 3], false, 0.0);
            crossed |= plant.theta_m_rad() < bottom;
            assert_eq!(plant.id_a(), 0.0);
        }
        let left = plant.theta_m_rad() - bottom;
        assert!(crossed, "never passed the bottom");
        assert!(left.abs() < 1e-3 * (start - bottom), "{left}");
        assert!(
            plant.omega_m_rad_s().abs() < 1e-3,
            "{}",
            plant.omega_m_rad_s()
        );
        // Work of the cogging = -(its energy change) = friction + kinetic.
        let e = *plant.energy();
        let released = e0 - plant.cogging_energy_j();
        assert!(released > 0.0);
        assert!((e.cogging_j - released).abs() < TOL * released, "{e:?}");
        let sinks = e.friction_j + plant.kinetic_energy_j();
        assert!(
            (e.cogging_j - sinks).abs() < (1e-4 + TOL) * released,
            "{e:?}"
        );
        assert_eq!(e.shaft_j, 0.0);
    }

    #[test]
    fn stiction_holds_against_cogging_within_the_friction() {
        let c = cogging(0.02, 0.0);
        let n = c.cycles_per_turn as Real;
        // Where the cogging pulls with 0.4 A (below Tc) or with A (above).
        let at = |sin_x: Real| (real::PI + libm::asin(sin_x as f64) as Real - c.phase_rad) / n;
        let run = |theta: Real, load_nm: f32| {
            let mut plant = Plant::new(motor(1e-4, 0.01), BenchConfig::default());
            plant.set_cogging(Some(c));
            plant.start_rotor_at(theta);
            for _ in 0..3000 {
                plant.step_period([0.5; 3], false, load_nm);
            }
            plant
        };
        let held = run(at(0.4), 0.0);
        assert!(
            (held.theta_m_rad() - at(0.4)).abs() < 1e-6,
            "{}",
            held.theta_m_rad()
        );
        // A's pull of 0.02 N m less a 0.015 N m load is within Tc.
        let loaded = run(at(-1.0), 0.015);
        assert!((loaded.theta_m_rad() - at(-1.0)).abs() < 1e-6);
        // Unloaded, A's pull is above Tc: it moves and sticks where the
        // cogging is within the friction.
        let moved = run(at(-1.0), 0.0);
        assert!((moved.theta_m_rad() - at(-1.0)).abs() > 1e-3);
        assert_eq!(moved.omega_m_rad_s(), 0.0);
        assert!(moved.cogging_torque_nm().abs() <= 0.01 + 1e-9);
    }

    /// Sensor reading minus `expected` \[rad\], wrapped to `(-pi, pi]`.
    fn reading_error(plant: &mut Plant, expected: Real) -> Real {
        let m = plant.step_period([0.5; 3], false, 0.0);
        let d = m.angle.to_radians() as Real - expected;
        d - TAU * real::floor(d / TAU + 0.5)
    }

    #[test]
    fn sensor_reads_its_error_within_a_count() {
        let err = SensorError {
            first_rad: 0.005,
            first_phase_rad: 0.3,
            second_rad: 0.002,
            second_phase_rad: 1.0,
        };
        let count = TAU / BenchConfig::default().sensors.encoder_counts_per_rev as Real;
        for kind in [
            AngleSensorKind::Absolute {
                mounting_offset_rad: 0.0,
            },
            AngleSensorKind::Incremental,
        ] {
            let mut plant = Plant::new(motor(0.0, 0.0), BenchConfig::default());
            plant.start_rotor_at(0.7);
            plant.set_angle_sensor(kind);
            plant.set_angle_sensor_error(Some(err));
            plant.set_mechanics(Mechanics::ConstantSpeed(20.0));
            let zero = plant.sensor_zero_m_rad;
            let mut seen = 0.0 as Real;
            for _ in 0..6000 {
                // The sample is taken at the end of the period.
                let th = plant.theta_m_rad() + 20.0 * plant.config().period_s();
                let expected = match kind {
                    AngleSensorKind::Absolute { .. } => err.error_rad(th),
                    AngleSensorKind::Incremental => err.error_rad(th) - err.error_rad(zero),
                };
                let d = reading_error(&mut plant, th - zero);
                assert!(
                    (d - expected).abs() <= count + 1e-6,
                    "{kind:?}: {d} vs {expected}"
                );
                assert!((plant.angle_sensor_error_rad() - expected).abs() < 1e-3 * TOL);
                seen = seen.max(d.abs());
            }
            assert!(seen > 0.006, "{kind:?}: largest error {seen}");
        }
    }

    #[test]
    fn encoder_faults_act_on_top_of_the_error() {
        let mut plant = Plant::new(motor(0.0, 0.0), BenchConfig::default());
        plant.set_angle_sensor_error(Some(SensorError::new(0.005, 0.0)));
        plant.set_rotor_angle(1.0);
        let clean = plant.step_period([0.5; 3], false, 0.0).angle;
        plant.faults_mut().encoder = EncoderFault::Jump(100);
        let jumped = plant.step_period([0.5; 3], false, 0.0).angle;
        let cpr = plant.config().sensors.encoder_counts_per_rev;
        let step = (1u64 << 32) / cpr as u64;
        assert_eq!(
            jumped.to_bits().wrapping_sub(clean.to_bits()) as u64,
            100 * step
        );
    }

    /// A short run through the bridge on and off, its trace of readings
    /// and states.
    fn trace(plant: &mut Plant) -> [u64; 4] {
        let mut h = [0u64; 4];
        for n in 0..600u32 {
            let th = plant.theta_e_rad() as f32 + 1.8;
            let d = [0.0f32, 1.0, 2.0].map(|k| 0.5 + 0.1 * libm::cosf(th - k * 2.094_395));
            let m = plant.step_period(d, n < 400, 0.002);
            let x = [
                m.angle.to_bits() as u64,
                (m.currents.to_abc().a as f64).to_bits(),
                (plant.omega_m_rad_s() as f64).to_bits(),
                (plant.iq_a() as f64).to_bits(),
            ];
            for k in 0..4 {
                h[k] = (h[k] ^ x[k]).wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
        h
    }

    #[test]
    fn none_leaves_the_plant_bit_identical() {
        let m = motor(1e-5, 0.002);
        let mut plain = Plant::new(m, BenchConfig::default());
        let mut off = Plant::new(m, BenchConfig::default());
        off.set_cogging(Some(cogging(0.02, 0.3)));
        off.set_angle_sensor_error(Some(SensorError::new(0.005, 0.002)));
        off.set_cogging(None);
        off.set_angle_sensor_error(None);
        assert_eq!(trace(&mut plain), trace(&mut off));
        assert_eq!(plain.energy(), off.energy());
        assert_eq!(off.energy().cogging_j, 0.0);
        assert_eq!(off.cogging_torque_nm(), 0.0);
        assert_eq!(off.angle_sensor_error_rad(), 0.0);
        // And with them on, the run differs.
        let mut on = Plant::new(m, BenchConfig::default());
        on.set_cogging(Some(cogging(0.02, 0.3)));
        let mut fresh = Plant::new(m, BenchConfig::default());
        assert_ne!(trace(&mut fresh), trace(&mut on));
    }
}
