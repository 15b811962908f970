//! The live configuration ([`Settings`]) and its conversion to and from a
//! [`DriveRecord`].
//!
//! The record keeps what is tuned or identified (motor, gains, calibration,
//! limits, loop gains, dividers, watchdog, power limits, the rotor's
//! mechanics, the joint with the impedance maxima, the angle source, the
//! d-current reference); the rest (loop
//! periods, modulation, decoupling, anti-windup, delay compensation) comes
//! from the build-time settings the record is applied on
//! ([`DriveRecord::apply`]). The acceleration feed-forwards (`J / kt`)
//! follow the mechanics in force: foc-core's
//! `CascadeConfig::set_mechanics` derives them ([`Settings::set_mechanics`],
//! [`Settings::apply_to`]); without mechanics they are the build's.
//!
//! The tables kept with the configuration (the anticogging map, the angle
//! sensor's correction: 1.5 KB) are not settings: [`Tables`], apart, so
//! that [`Settings`] stays small enough to copy, and never in a
//! `ConfigChange` (which crosses the current loop's mailbox every period).
//!
//! ```
//! use foc_core::control::MotorParams;
//! use foc_core::drive::cascade::CascadeConfig;
//! use foc_store::{record::Label, DriveRecord, Settings};
//! let motor = MotorParams { pole_pairs: 7, r_ohm: 0.2, ld_h: 60e-6, lq_h: 60e-6, flux_linkage_wb: 0.004 };
//! let base = Settings::from_cascade(&CascadeConfig::for_motor(motor, 20_000.0, 5.0));
//! let record = DriveRecord::from_settings(&Label::new(), 20_000, &base);
//! assert_eq!(record.apply(&base, 20_000), Ok(base));
//! // A record made for another PWM frequency is refused.
//! assert_eq!(record.apply(&base, 16_000).unwrap_err().field, "pwm_frequency_hz");
//! ```

use foc_core::control::angle_correction::{AngleCorrection, AngleCorrectionError};
use foc_core::control::cogging::{CoggingMap, CoggingMapError};
use foc_core::control::current::CurrentLoopConfig;
use foc_core::control::field::FieldConfig;
use foc_core::control::joint::{JointSetup, OutputFrame};
use foc_core::control::permit::Calibrated;
use foc_core::control::position::PositionLoopConfig;
use foc_core::control::power::PowerLimitsConfig;
use foc_core::control::speed::SpeedLoopConfig;
use foc_core::control::stage::{AngleCalibration, CurrentStage, TimeoutReaction};
use foc_core::control::{Limits, Mechanics};
use foc_core::drive::cascade::CascadeConfig;

use crate::record::{
    AngleRecord, BesideRole, CoggingRecord, CorrectionRecord, CurrentGainsRecord, DividersRecord,
    DriveRecord, FieldRecord, Invalid, JointRecord, Label, LimitsRecord, MechanicsRecord,
    MotorRecord, PositionRecord, PowerRecord, SensorlessRecord, SpeedRecord, WatchdogReaction,
    WatchdogRecord,
};
use foc_core::control::flux_observer::ObserverConfig;
use foc_core::control::sensorless::SensorlessConfig;
use foc_core::control::stage::BesideConfig;

/// The configuration in force on the drive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settings {
    /// Command limits.
    pub limits: Limits,
    /// Current loop (motor, gains, period, modulation, ...).
    pub current: CurrentLoopConfig,
    /// The angle calibration in force (or the build-time one).
    pub angle: AngleCalibration,
    /// `angle` and the motor/gains in `current` come from an identification
    /// or a loaded record.
    pub calibrated: bool,
    /// Speed loop (its acceleration feed-forward `J / kt` from
    /// `mechanics` when there are any).
    pub speed: SpeedLoopConfig,
    /// Position loop (its acceleration feed-forward `J / kt` from
    /// `mechanics` when there are any).
    pub position: PositionLoopConfig,
    /// Speed / position loop dividers [current-loop periods].
    pub dividers: (u16, u16),
    /// Command watchdog.
    pub watchdog: WatchdogRecord,
    /// Power limits (design §18); `None`: off. Their motor model is
    /// `current.motor`'s.
    pub power: Option<PowerLimitsConfig>,
    /// The rotor's mechanics (identified or given); `None`: not known
    /// (the configuration's, see [`Self::apply_to`]).
    pub mechanics: Option<Mechanics>,
    /// The joint (design §21): output frame (gear ratio, home offset),
    /// travel range at the output and its soft stop, impedance entry and
    /// timeout. With a travel range, the position range in force is that
    /// range in the rotor frame (`limits`' own range without one).
    pub joint: JointSetup,
    /// Run without the angle sensor (design §27; [`sensorless_config`]
    /// derives the rest); `None`: on the angle sensor.
    pub sensorless: Option<SensorlessRecord>,
    /// The d-current reference and the safe state by speed (design §30):
    /// MTPA, field weakening (never on a coarse angle sensor: see
    /// [`field_refusal`]), the short circuit.
    pub field: FieldConfig,
}

/// The tables kept with the configuration, in foc-core's form: the
/// anticogging map (design §32) and the angle sensor's correction (design
/// §33), each with its switch. Installed in the current stage outside the
/// period's mailbox ([`Tables::install`]), read back from it after a
/// calibration measured one ([`Tables::of_stage`]).
///
/// ```
/// use foc_store::settings::Tables;
/// use foc_core::control::cogging::{CoggingMap, COGGING_BINS};
/// use foc_core::control::MotorParams;
/// use foc_core::control::stage::CurrentStage;
/// use foc_core::drive::cascade::CascadeConfig;
/// let m = MotorParams { pole_pairs: 7, r_ohm: 0.2, ld_h: 60e-6, lq_h: 60e-6, flux_linkage_wb: 0.004 };
/// let mut stage = CurrentStage::new(CascadeConfig::for_motor(m, 20_000.0, 5.0).current);
/// let mut amps = [0.0; COGGING_BINS];
/// amps[0] = 0.1;
/// let t = Tables { cogging: CoggingMap::from_amps(&amps).unwrap(), ..Tables::NONE };
/// assert_eq!(t.install(&mut stage), Ok(()));
/// assert_eq!(Tables::of_stage(&stage), t);
/// amps[0] = 6.0; // above the 5 A limit
/// let big = Tables { cogging: CoggingMap::from_amps(&amps).unwrap(), ..Tables::NONE };
/// assert_eq!(big.install(&mut stage).unwrap_err().field, "cogging.table");
/// assert_eq!(Tables::of_stage(&stage), t, "refused whole");
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tables {
    /// The anticogging map ([`CoggingMap::EMPTY`]: none).
    pub cogging: CoggingMap,
    /// The angle sensor's correction ([`AngleCorrection::NONE`]: none).
    pub angle_correction: AngleCorrection,
}

impl Tables {
    /// No tables.
    pub const NONE: Self = Self {
        cogging: CoggingMap::EMPTY,
        angle_correction: AngleCorrection::NONE,
    };

    /// The tables of a record (none where it holds none). The record's
    /// validation checks them.
    pub fn of_record(r: &DriveRecord) -> Self {
        Self {
            cogging: r
                .cogging
                .as_ref()
                .map_or(CoggingMap::EMPTY, CoggingRecord::to_map),
            angle_correction: r
                .angle_correction
                .as_ref()
                .map_or(AngleCorrection::NONE, CorrectionRecord::to_correction),
        }
    }

    /// The tables installed in `stage`.
    pub fn of_stage(stage: &CurrentStage) -> Self {
        Self {
            cogging: *stage.cogging(),
            angle_correction: *stage.angle_correction(),
        }
    }

    /// A map is held (not zero everywhere).
    pub fn has_cogging(&self) -> bool {
        self.cogging.peak_a() > 0.0
    }

    /// A correction is held (not zero everywhere).
    pub fn has_angle_correction(&self) -> bool {
        self.angle_correction.peak_rad() > 0.0
    }

    /// Install both in `stage` with the stage's own checks
    /// (`CurrentStage::set_cogging` against its current limit,
    /// `set_angle_correction`), or neither: the error names the table
    /// refused (`cogging.table`, `cogging.scale_a`,
    /// `angle_correction.table`, `angle_correction.scale_rad`). The
    /// owner calls it outside the period (at start-up, or with the bridge
    /// off under the stage's lock): a copy of 1.5 KB and three passes
    /// over the tables (the correction's check, which does not depend on
    /// the stage, first; then the map's, against the stage's limit, which
    /// alone decides whether both go in).
    pub fn install(&self, stage: &mut CurrentStage) -> Result<(), Invalid> {
        let correction = |e| Invalid {
            field: match e {
                AngleCorrectionError::BadScale => "angle_correction.scale_rad",
                _ => "angle_correction.table",
            },
        };
        self.angle_correction.check().map_err(correction)?;
        stage.set_cogging(&self.cogging).map_err(|e| Invalid {
            field: match e {
                CoggingMapError::BadScale => "cogging.scale_a",
                _ => "cogging.table",
            },
        })?;
        stage
            .set_angle_correction(&self.angle_correction)
            .map_err(correction)
    }
}

impl Settings {
    /// The settings of a cascade configuration (uncalibrated).
    pub fn from_cascade(c: &CascadeConfig) -> Self {
        Self {
            limits: c.current.limits,
            current: c.current.current,
            angle: c.current.angle,
            calibrated: false,
            speed: c.speed,
            position: c.position,
            dividers: (c.rates.speed_divider, c.rates.position_divider),
            watchdog: WatchdogRecord {
                timeout_periods: c.current.command_timeout_periods,
                reaction: reaction_record(c.current.timeout_reaction),
            },
            power: c.current.power,
            mechanics: c.mechanics,
            joint: JointSetup {
                frame: OutputFrame::IDENTITY,
                travel_out_rad: None,
                travel: c.default_travel(),
                joint: c.current.joint,
            },
            sensorless: sensorless_record(c),
            field: c.current.field,
        }
    }

    /// `base` with these settings in force (limits, current loop, angle
    /// calibration, power limits, speed and position loops, dividers,
    /// mechanics, the d-current reference); the rest of `base` (tracker,
    /// supervisor, rates, timeouts) is kept.
    ///
    /// With `mechanics` (these settings', else `base`'s), foc-core's
    /// `CascadeConfig::set_mechanics` runs first, on this motor, speed-loop
    /// period and current limit: it derives the speed observer's torque
    /// input and the acceleration feed-forwards of the speed and position
    /// loops from the inertia; the speed and position loops of these
    /// settings then go on top (their gains, tuned by the user, win over
    /// the ones derived from the inertia), all but those two
    /// feed-forwards. Mechanics foc-core refuses (not usable, no torque
    /// constant) change nothing: the loops are these settings' and the
    /// mechanics `base`'s. Last, the sensorless configuration is derived
    /// ([`sensorless_config`]; none when these settings run on the angle
    /// sensor or it cannot be derived).
    pub fn apply_to(&self, base: &CascadeConfig) -> CascadeConfig {
        let mut c = *base;
        c.current.limits = self.limits;
        let j = self
            .joint
            .rotor_change((self.limits.min_position_rad, self.limits.max_position_rad));
        c.current.limits.min_position_rad = j.min_position_rad;
        c.current.limits.max_position_rad = j.max_position_rad;
        c.current.joint = j.joint;
        c.current.current = self.current;
        c.current.angle = self.angle;
        c.current.power = self.power.map(|p| PowerLimitsConfig {
            motor: self.current.motor,
            ..p
        });
        c.speed = self.speed;
        c.position = self.position;
        c.rates.speed_divider = self.dividers.0;
        c.rates.position_divider = self.dividers.1;
        c.current.field = self.field;
        if let Some(m) = self.mechanics.or(base.mechanics) {
            if c.set_mechanics(&m) {
                c.speed = SpeedLoopConfig {
                    accel_ff_a_per_rad_s2: c.speed.accel_ff_a_per_rad_s2,
                    ..self.speed
                };
                c.position = PositionLoopConfig {
                    accel_ff_a_per_rad_s2: c.position.accel_ff_a_per_rad_s2,
                    ..self.position
                };
            }
        }
        let derived = self
            .sensorless
            .and_then(|sl| Some((sl, sensorless_config(&c, &sl)?)));
        c.current.sensorless = derived
            .filter(|(sl, _)| sl.replaces_sensor())
            .map(|(_, cfg)| cfg);
        let pp = f32::from(c.current.angle.pole_pairs.max(1));
        c.current.fallback = derived.and_then(|(sl, cfg)| beside_config(&sl, cfg, pp));
        c
    }

    /// Install the rotor's mechanics: `mechanics = Some(m)` and the
    /// acceleration feed-forwards of the speed and position loops the ones
    /// foc-core's `CascadeConfig::set_mechanics` derives for this motor
    /// (the gains stay: see [`Self::apply_to`]). Mechanics foc-core
    /// refuses (not usable, or this motor has no torque constant) change
    /// nothing and return false.
    pub fn set_mechanics(&mut self, m: &Mechanics) -> bool {
        // `apply_to` on a scratch configuration: only this motor, the
        // speed loop's period and current limit and `m` reach the
        // feed-forwards, whatever the scratch's other values.
        let scratch = CascadeConfig::for_motor(
            self.current.motor,
            1.0 / self.current.ts_s,
            self.limits.max_current_a,
        );
        let with = Settings {
            mechanics: Some(*m),
            ..*self
        };
        let c = with.apply_to(&scratch);
        if c.mechanics != Some(*m) {
            return false;
        }
        *self = Settings {
            speed: c.speed,
            position: c.position,
            ..with
        };
        true
    }

    /// The calibration permit these settings vouch for: `Some` only when
    /// `calibrated` and `Calibrated::supplied(self.angle, self.current)`
    /// accepts them.
    pub fn permit(&self) -> Option<Calibrated> {
        if self.calibrated {
            Calibrated::supplied(self.angle, self.current).ok()
        } else {
            None
        }
    }
}

/// The sensorless configuration (design §27) of `sl` on the cascade
/// configuration `c`: foc-core's `SensorlessConfig::for_motor` with the
/// current loop's motor and period, the model check's dead time and
/// current floor, `c`'s inertia, and `sl`'s start current and bus. `None`
/// when `c` has no mechanics or the values are not usable.
pub fn sensorless_config(c: &CascadeConfig, sl: &SensorlessRecord) -> Option<SensorlessConfig> {
    let observer = ObserverConfig {
        motor: c.current.current.motor,
        ts_s: c.current.current.ts_s,
        dead_time_s: c.current.supervisor.model.dead_time_s,
        current_floor_a: c.current.supervisor.model.floor_a,
    };
    SensorlessConfig::for_motor(
        observer,
        sl.start_current_a,
        c.mechanics?.inertia_kg_m2,
        sl.bus_voltage_v,
    )
}

/// The record's sensorless table of a cascade configuration: running
/// without the sensor, or the observer beside it (its role from the
/// fall-back's: halls + sensorless with a speed, limp-home, a check).
pub fn sensorless_record(c: &CascadeConfig) -> Option<SensorlessRecord> {
    if let Some(sl) = c.current.sensorless {
        return Some(SensorlessRecord {
            start_current_a: sl.current_a,
            bus_voltage_v: sl.bus_voltage_v,
            beside_sensor: None,
            observer_above_rad_s: None,
        });
    }
    let b = c.current.fallback?;
    let pp = f32::from(c.current.angle.pole_pairs.max(1));
    let role = match (b.observer_above_rad_s, b.limp_home) {
        (Some(_), _) => BesideRole::HallSensorless,
        (None, true) => BesideRole::LimpHome,
        (None, false) => BesideRole::Check,
    };
    Some(SensorlessRecord {
        start_current_a: b.sensorless.current_a,
        bus_voltage_v: b.sensorless.bus_voltage_v,
        beside_sensor: Some(role),
        observer_above_rad_s: b.observer_above_rad_s.map(|w| w / pp),
    })
}

/// The observer beside the sensor of `sl` (`None` when `sl` replaces the
/// sensor), on its derived configuration `cfg`, for `pole_pairs`.
pub fn beside_config(
    sl: &SensorlessRecord,
    cfg: SensorlessConfig,
    pole_pairs: f32,
) -> Option<BesideConfig> {
    let limp = BesideConfig::limp_home(cfg);
    Some(match sl.beside_sensor? {
        BesideRole::Check => BesideConfig {
            limp_home: false,
            ..limp
        },
        BesideRole::LimpHome => limp,
        BesideRole::HallSensorless => match sl.observer_above_rad_s {
            Some(w) => BesideConfig {
                observer_above_rad_s: Some(w * pole_pairs),
                ..limp
            },
            None => BesideConfig::hybrid(cfg),
        },
    })
}

/// Why the d-current reference `f` is refused with the angle calibration
/// `angle` (foc-core's one rule, `foc_core::drive::check_field`), as the
/// record field it concerns: field weakening on a coarse angle sensor
/// (halls) is `field.field_weakening`; an unusable value the field's own
/// name (as [`FieldRecord::validate`] gives it).
pub fn field_refusal(f: &FieldConfig, angle: &AngleCalibration) -> Option<Invalid> {
    foc_core::drive::check_field(f, angle).err()?;
    Some(match FieldRecord::from_config(f).validate() {
        Err(e) => e,
        // The rest of the rule: a coarse sensor.
        Ok(()) => Invalid {
            field: "field.field_weakening",
        },
    })
}

/// The record's form of foc-core's timeout reaction.
pub fn reaction_record(r: TimeoutReaction) -> WatchdogReaction {
    match r {
        TimeoutReaction::Disable => WatchdogReaction::Disable,
        TimeoutReaction::Stop => WatchdogReaction::Stop,
        TimeoutReaction::Hold => WatchdogReaction::Hold,
    }
}

/// foc-core's form of the record's watchdog reaction.
pub fn timeout_reaction(r: WatchdogReaction) -> TimeoutReaction {
    match r {
        WatchdogReaction::Disable => TimeoutReaction::Disable,
        WatchdogReaction::Stop => TimeoutReaction::Stop,
        WatchdogReaction::Hold => TimeoutReaction::Hold,
    }
}

impl DriveRecord {
    /// The record of these live settings (calibration = `Some(angle)` iff
    /// `s.calibrated`; the joint always, with the limits' impedance
    /// maxima).
    pub fn from_settings(label: &Label, pwm_frequency_hz: u32, s: &Settings) -> Self {
        Self {
            label: label.clone(),
            pwm_frequency_hz,
            motor: MotorRecord::from_params(&s.current.motor),
            current_gains: CurrentGainsRecord::from_gains(&s.current.d_gains, &s.current.q_gains),
            calibration: if s.calibrated {
                Some(AngleRecord::from_calibration(&s.angle))
            } else {
                None
            },
            limits: LimitsRecord::from_limits(&s.limits),
            speed: SpeedRecord {
                kp_a_per_rad_s: s.speed.kp_a_per_rad_s,
                ki_a_per_rad: s.speed.ki_a_per_rad,
            },
            position: PositionRecord {
                kp_per_s: s.position.kp_per_s,
                max_velocity_rad_s: s.position.max_velocity_rad_s,
                max_acceleration_rad_s2: s.position.max_acceleration_rad_s2,
            },
            dividers: DividersRecord {
                speed: s.dividers.0,
                position: s.dividers.1,
            },
            watchdog: s.watchdog,
            power: s.power.as_ref().map(PowerRecord::from_config),
            mechanics: s.mechanics.as_ref().map(MechanicsRecord::from_mechanics),
            joint: Some(JointRecord::from_setup(&s.joint, &s.limits)),
            sensorless: s.sensorless,
            field: Some(FieldRecord::from_config(&s.field)),
            cogging: None,
            angle_correction: None,
        }
    }

    /// This record with the tables `t` (a table zero everywhere is none:
    /// `None`).
    pub fn with_tables(self, t: &Tables) -> Self {
        Self {
            cogging: t.has_cogging().then(|| CoggingRecord::from_map(&t.cogging)),
            angle_correction: t
                .has_angle_correction()
                .then(|| CorrectionRecord::from_correction(&t.angle_correction)),
            ..self
        }
    }

    /// These settings with the record applied on top of `base` (the
    /// build-time ones). Validates the whole record first (nothing applied on
    /// any error); refuses a record made for another PWM frequency
    /// (`Invalid { field: "pwm_frequency_hz" }`); recomputes the speed and
    /// position loop periods from the dividers; sets the speed loop's
    /// current limit to `limits.max_current_a`; keeps base's current-loop
    /// period, modulation, decoupling, anti-windup and delay compensation,
    /// base's angle calibration (with the record's pole pairs) when the
    /// record has no calibration, base's power limits when it has none,
    /// base's mechanics when it has none, and base's joint and impedance
    /// maxima when it has no joint (else the record's:
    /// [`JointRecord::to_setup`], [`JointRecord::limits`]); the record's
    /// angle source always (`sensorless`; refused as
    /// `Invalid { field: "sensorless" }` without mechanics), and its
    /// d-current reference (without one, foc-core's
    /// `FieldConfig::for_motor` for the record's motor, current limit and
    /// PWM rate; field weakening on a coarse angle sensor refused as
    /// `Invalid { field: "field.field_weakening" }`, see
    /// [`field_refusal`]). With mechanics
    /// (the record's or base's), the acceleration feed-forwards are derived
    /// from them for the record's motor ([`Settings::set_mechanics`]);
    /// without, they are base's.
    pub fn apply(&self, base: &Settings, pwm_frequency_hz: u32) -> Result<Settings, Invalid> {
        self.validate()?;
        if self.pwm_frequency_hz != pwm_frequency_hz {
            return Err(Invalid {
                field: "pwm_frequency_hz",
            });
        }
        let pwm = pwm_frequency_hz as f32;
        let mut s = *base;
        match &self.joint {
            Some(j) => {
                s.limits = j.limits(&self.limits);
                s.joint = j.to_setup()?;
            }
            None => {
                s.limits = Limits {
                    max_kp_nm_per_rad: base.limits.max_kp_nm_per_rad,
                    max_kd_nm_s_per_rad: base.limits.max_kd_nm_s_per_rad,
                    ..self.limits.to_limits()
                }
            }
        }
        s.current.motor = self.motor.to_params();
        s.current.d_gains = self.current_gains.d();
        s.current.q_gains = self.current_gains.q();
        match &self.calibration {
            Some(c) => {
                s.angle = c.to_calibration();
                s.calibrated = true;
            }
            None => {
                s.angle.pole_pairs = self.motor.pole_pairs;
                s.calibrated = false;
            }
        }
        s.speed.ts_s = f32::from(self.dividers.speed) / pwm;
        s.speed.kp_a_per_rad_s = self.speed.kp_a_per_rad_s;
        s.speed.ki_a_per_rad = self.speed.ki_a_per_rad;
        s.speed.current_limit_a = self.limits.max_current_a;
        s.position.ts_s = f32::from(self.dividers.position) / pwm;
        s.position.kp_per_s = self.position.kp_per_s;
        s.position.max_velocity_rad_s = self.position.max_velocity_rad_s;
        s.position.max_acceleration_rad_s2 = self.position.max_acceleration_rad_s2;
        s.dividers = (self.dividers.speed, self.dividers.position);
        s.watchdog = self.watchdog;
        if let Some(p) = &self.power {
            s.power = Some(p.to_config(s.current.motor));
        }
        s.power = s.power.map(|p| PowerLimitsConfig {
            motor: s.current.motor,
            ..p
        });
        if let Some(m) = self.mechanics.as_ref().map(MechanicsRecord::to_mechanics) {
            s.mechanics = Some(m);
        }
        // Base's feed-forwards were derived for base's motor and loop
        // period; the validated record's mechanics are always accepted.
        if let Some(m) = s.mechanics {
            s.set_mechanics(&m);
        }
        // Sensorless needs the rotor's inertia (its start is derived from
        // it): the record's or base's mechanics.
        s.sensorless = self.sensorless;
        if s.sensorless.is_some() && s.mechanics.is_none() {
            return Err(Invalid {
                field: "sensorless",
            });
        }
        s.field = match &self.field {
            Some(f) => f.to_config(),
            None => FieldConfig::for_motor(&s.current.motor, self.limits.max_current_a, pwm),
        };
        if let Some(e) = field_refusal(&s.field, &s.angle) {
            return Err(e);
        }
        Ok(s)
    }
}
