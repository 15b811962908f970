//! The motor under test: a motor file as the bench plant and the
//! drive's configuration for it.

use super::*;

/// The controller's motor parameters from the plant's (same values, `f32`).
pub fn control_motor(m: &plant::MotorParams) -> foc_core::control::MotorParams {
    foc_core::control::MotorParams {
        pole_pairs: m.pole_pairs,
        r_ohm: m.r_ohm as f32,
        ld_h: m.ld_h as f32,
        lq_h: m.lq_h as f32,
        flux_linkage_wb: m.flux_linkage_wb as f32,
    }
}

/// A motor on the bench: plant parameters, bench configuration, current ratings.
#[derive(Clone, Debug, PartialEq)]
pub struct Setup {
    /// Motor name.
    pub name: String,
    /// Plant motor parameters.
    pub motor: plant::MotorParams,
    /// Inverter, supply and sensors.
    pub bench: BenchConfig,
    /// Rated (continuous) current \[A\].
    pub rated_current_a: f32,
    /// Maximum current \[A\] (the controller's current limit).
    pub max_current_a: f32,
}

impl Setup {
    /// From a loaded motor file. The encoder's zero is put 1.234 rad away
    /// from the rotor d axis so that the alignment has something to find.
    pub fn from_file(f: &MotorFile) -> Self {
        let mut bench = f.bench_config();
        bench.sensors.encoder_offset_rad = 1.234;
        Self {
            name: f.name.clone(),
            motor: f.motor_params(),
            bench,
            rated_current_a: f.rated_current_a as f32,
            max_current_a: f.max_current_a as f32,
        }
    }

    /// Load a motor file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, MotorFileError> {
        MotorFile::load(path).map(|f| Self::from_file(&f))
    }

    /// PWM frequency \[Hz\].
    pub fn pwm_hz(&self) -> f32 {
        self.bench.pwm_frequency_hz as f32
    }

    /// Torque constant `1.5 p psi` [N m / A].
    pub fn kt(&self) -> f32 {
        control_motor(&self.motor).torque_constant_nm_per_a()
    }

    /// No-load speed at the nominal bus within the linear range [rad/s, mechanical].
    pub fn max_speed_rad_s(&self) -> f32 {
        let v_max = 0.95 * self.bench.bus_voltage_v as f32 / 3f32.sqrt();
        let k = self.motor.pole_pairs as f32 * self.motor.flux_linkage_wb as f32;
        if k > 0.0 {
            v_max / k
        } else {
            1.0e3
        }
    }

    /// Highest speed the mission and the dyno command [rad/s, mechanical]:
    /// one electrical turn per 10 PWM periods (0.63 rad electrical per
    /// period). foc-core compensates the 1.5-period delay of the voltage
    /// (`delay_compensation_periods`); this keeps the sampled electrical
    /// angle well resolved (it was one turn per 30 periods before the
    /// compensation, where the uncompensated lag was 18 deg).
    pub fn max_mission_speed_rad_s(&self) -> f32 {
        std::f32::consts::TAU * self.pwm_hz() / (10.0 * self.motor.pole_pairs as f32)
    }

    /// The controller configuration: [`CascadeConfig::for_motor_with_inertia`]
    /// (source tuning of the current loop) with the bench's inertia, the
    /// supervisor's bus limits at 60 % / 125 % of the nominal bus, and the
    /// position trajectory limited to 40 % of the no-load speed and to the
    /// acceleration 30 % of the maximum current gives.
    pub fn cascade_config(&self) -> CascadeConfig {
        let j = self.motor.inertia_kg_m2 as f32;
        let mut c = CascadeConfig::for_motor_with_inertia(
            control_motor(&self.motor),
            self.pwm_hz(),
            self.max_current_a,
            j,
        );
        let vbus = self.bench.bus_voltage_v as f32;
        c.current.supervisor.bus_over_voltage_v = 1.25 * vbus;
        c.current.supervisor.bus_under_voltage_v = 0.6 * vbus;
        c.current.limits.max_open_loop_voltage_v = vbus;
        c.position.max_velocity_rad_s = 0.4 * self.max_speed_rad_s();
        c.position.max_acceleration_rad_s2 = 0.3 * self.kt() * self.max_current_a / j;
        // The sensor's resolution is known before any calibration (the
        // supervisor's angle-step limit never goes below a few counts).
        c.current.angle.sensor_counts_per_rev = self.bench.sensors.encoder_counts_per_rev;
        // The bridge's dead time is the board's, known as the firmware
        // knows it (`board::DEAD_TIME_NS`, design §24): the model check
        // corrects for it ...
        c.current.supervisor.model.dead_time_s = self.bench.dead_time_s as f32;
        // ... and the current loop cancels it (design §31), as the
        // firmware's `config::cascade` sets it.
        c.current.current.dead_time =
            foc_core::control::dead_time::DeadTimeCompensation::for_current_limit(
                self.bench.dead_time_s as f32,
                self.max_current_a,
            );
        // The plant's mechanics, as a user who knows them would give them
        // (the mission installs the identified ones instead).
        c.set_mechanics(&self.mechanics());
        c
    }

    /// [`Self::cascade_config`] running without its angle sensor (design
    /// §27): the flux observer from the motor, the board's dead time and
    /// the model check's current floor; the start at the rated current.
    pub fn sensorless_config(&self) -> CascadeConfig {
        use foc_core::control::flux_observer::ObserverConfig;
        use foc_core::control::sensorless::SensorlessConfig;
        let mut c = self.cascade_config();
        let observer = ObserverConfig {
            motor: c.current.current.motor,
            ts_s: c.current.current.ts_s,
            dead_time_s: c.current.supervisor.model.dead_time_s,
            current_floor_a: c.current.supervisor.model.floor_a,
        };
        c.current.sensorless = SensorlessConfig::for_motor(
            observer,
            self.rated_current_a.min(self.max_current_a),
            self.motor.inertia_kg_m2 as f32,
            self.bench.bus_voltage_v as f32,
        );
        c
    }

    /// [`Self::cascade_config`] as a drive starts before its first
    /// identification: the rotor's mechanics not known (the speed
    /// observer without a model, no speed feed-forward). The
    /// identification measures them and the drive installs them.
    pub fn unidentified_config(&self) -> CascadeConfig {
        let mut c = self.cascade_config();
        c.clear_mechanics();
        c
    }

    /// The plant's mechanics (rotor frame).
    pub fn mechanics(&self) -> foc_core::control::Mechanics {
        foc_core::control::Mechanics {
            inertia_kg_m2: self.motor.inertia_kg_m2 as f32,
            viscous_friction_nm_s_per_rad: self.motor.viscous_friction_nm_s_per_rad as f32,
            coulomb_friction_nm: self.motor.coulomb_friction_nm as f32,
        }
    }
}

impl Setup {
    /// The angle calibration that is exact for this bench: the plant's
    /// encoder offset is known here (the mission itself *finds* it with
    /// [`crate::identify::run`] instead).
    pub fn true_angle_calibration(&self) -> AngleCalibration {
        let pp = self.motor.pole_pairs;
        AngleCalibration {
            pole_pairs: pp,
            zero_offset: MechanicalAngle::from_radians(
                -(self.bench.sensors.encoder_offset_rad as f32),
            )
            .to_electrical(pp),
            reversed: false,
            // The bench's encoder reads floor counts: let the stage add
            // the half count (see `AngleCalibration::sensor_counts_per_rev`).
            sensor_counts_per_rev: self.bench.sensors.encoder_counts_per_rev,
            sensorless_only: false,
        }
    }

    /// A calibration permit supplied from the bench's knowledge: the exact
    /// angle calibration and `config`'s current-loop configuration.
    pub fn supplied_calibration(&self, config: &CascadeConfig) -> Calibrated {
        Calibrated::supplied(self.true_angle_calibration(), config.current.current)
            .expect("plausible motor file")
    }
}

/// The controller's view of one plant sample.
pub fn sample_of(m: &Measurements) -> Sample {
    Sample {
        currents: Some(m.currents),
        angle: Some(m.angle),
        v_bus_v: Some(m.v_bus_v),
        // The power stage's temperature, where the plant models it.
        temperature_c: m.stage_temperature_c,
    }
}

/// `c` with the offsets `o` \[A\] removed.
pub fn remove_offsets(c: PhaseCurrents, o: Abc) -> PhaseCurrents {
    match c {
        PhaseCurrents::TwoPhase { a_a, b_a } => PhaseCurrents::TwoPhase {
            a_a: a_a - o.a,
            b_a: b_a - o.b,
        },
        PhaseCurrents::ThreePhase(i) => {
            PhaseCurrents::ThreePhase(Abc::new(i.a - o.a, i.b - o.b, i.c - o.c))
        }
    }
}
