//! The drive's rules for commands and configuration changes, each written
//! once: the [`Lifecycle`](super::Lifecycle) applies them when it takes a
//! command or a change at a period boundary, and the command protocol
//! applies the very same functions to its snapshot of the drive's
//! [`Status`] for an immediate Nack (so a refused request changes nothing).
//!
//! ```
//! use foc_core::drive::{Progress, Refusal, Status};
//! use foc_core::control::{Command, CommandError, Mode};
//! let running = Status { running: true, mode: Mode::Torque, faulted: false, calibrated: true, sensorless: false, injection: false, calibration: Progress::Idle };
//! assert_eq!(running.check_config(), Err(Refusal::NotDisabled));
//! let starting = Status { running: false, mode: Mode::Disabled, ..running };
//! assert_eq!(starting.check_config(), Err(Refusal::Busy));
//! let idle = Status { mode: Mode::Disabled, calibrated: false, ..running };
//! assert_eq!(idle.check_config(), Ok(()));
//! # let limits = foc_core::drive::cascade::CascadeConfig::for_motor(
//! #     foc_core::control::MotorParams { pole_pairs: 7, r_ohm: 0.1, ld_h: 1e-4, lq_h: 1e-4, flux_linkage_wb: 0.01 },
//! #     20_000.0, 5.0).current.limits;
//! assert_eq!(idle.check_command(&Command::Torque { iq_a: 1.0 }, &limits), Err(CommandError::NotCalibrated));
//! // Without the angle sensor: velocity only (and open loop).
//! let sensorless = Status { mode: Mode::Disabled, sensorless: true, ..running };
//! assert_eq!(sensorless.check_command(&Command::Torque { iq_a: 1.0 }, &limits), Err(CommandError::NeedsAngleSensor));
//! assert_eq!(sensorless.check_command(&Command::Velocity { rad_s: 10.0 }, &limits), Ok(()));
//! // With injection (a salient motor) it holds torque at standstill.
//! let injection = Status { injection: true, ..sensorless };
//! assert_eq!(injection.check_command(&Command::Torque { iq_a: 1.0 }, &limits), Ok(()));
//! ```

use crate::control::current::CurrentLoopConfig;
use crate::control::field::FieldConfig;
pub use crate::control::joint::JointChange;
use crate::control::permit::Calibrated;
use crate::control::power::PowerLimitsConfig;
use crate::control::sensorless::SensorlessConfig;
use crate::control::stage::{AngleCalibration, BesideConfig, COARSE_FIELD_WEAKENING};
pub use crate::control::Refusal;
use crate::control::{admit, Command, CommandError, Fault, Limits, Mechanics, Mode};

/// What the rules look at: the drive's state as its owner last published it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    /// Start-up finished and no calibration running (phase `Run`).
    pub running: bool,
    /// The active mode.
    pub mode: Mode,
    /// A fault is latched.
    pub faulted: bool,
    /// Offsets calibrated and a calibration permit installed.
    pub calibrated: bool,
    /// The drive runs without its angle sensor (design §27).
    pub sensorless: bool,
    /// ... and holds torque at standstill with high-frequency injection
    /// (design §28; a salient motor).
    pub injection: bool,
    /// The calibration running, or how the last one ended (for the host).
    pub calibration: crate::drive::Progress,
}

impl Status {
    /// Limits, gains, dividers and the offset calibration: only once
    /// started ([`Refusal::Busy`]) and while disabled
    /// ([`Refusal::NotDisabled`]).
    pub fn check_config(&self) -> Result<(), Refusal> {
        if !self.running {
            return Err(Refusal::Busy);
        }
        if self.mode != Mode::Disabled {
            return Err(Refusal::NotDisabled);
        }
        Ok(())
    }

    /// A calibration (offsets, identification): as [`Self::check_config`],
    /// and not while a fault is latched ([`Refusal::Faulted`]).
    pub fn check_calibration(&self) -> Result<(), Refusal> {
        self.check_config()?;
        if self.faulted {
            return Err(Refusal::Faulted);
        }
        Ok(())
    }

    /// True when the rotor's angle is known only once it turns
    /// (sensorless without injection): torque, position and impedance
    /// commands are refused.
    pub fn angle_only_in_motion(&self) -> bool {
        self.sensorless && !self.injection
    }

    /// A command: [`admit`] (values, latched fault, calibration), no
    /// torque, position or impedance command while the angle is known
    /// only in motion ([`Self::angle_only_in_motion`],
    /// [`CommandError::NeedsAngleSensor`]), and while start-up or an identification runs only `Disable`
    /// ([`CommandError::Busy`]: the drive would take it only later).
    pub fn check_command(&self, cmd: &Command, limits: &Limits) -> Result<(), CommandError> {
        admit(cmd, limits, self.faulted, self.calibrated)?;
        if self.angle_only_in_motion() && cmd.mode().needs_angle_sensor() {
            return Err(CommandError::NeedsAngleSensor);
        }
        if !self.running && *cmd != Command::Disable {
            return Err(CommandError::Busy);
        }
        Ok(())
    }
}

/// A configuration change for the drive, applied at the start of a period.
/// Its settings (limits, current loop, dividers) are applied all together
/// or, when [`Status::check_config`] or [`Limits::validate`] refuses, not
/// at all; a calibration request is judged on its own
/// ([`Status::check_calibration`]), so a refused calibration never drops
/// settings the host was told were taken. Changes merge: a newer value
/// replaces a pending one.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ConfigChange {
    /// New command limits (checked with [`Limits::validate`]).
    pub limits: Option<Limits>,
    /// New current-loop configuration: installed with a new calibration
    /// permit for the stage's angle calibration when the stage is
    /// calibrated and the values pass the permit's check; otherwise it
    /// revokes the calibration.
    pub current: Option<CurrentLoopConfig>,
    /// New speed / position dividers \[periods\] (0 is taken as 1).
    pub dividers: Option<(u16, u16)>,
    /// New power limits (design §18): `Some(Some(cfg))` installs them
    /// (sanitized; their motor model is the current loop's; the winding
    /// estimate carries on), `Some(None)` switches them off.
    pub power: Option<Option<PowerLimitsConfig>>,
    /// A calibration permit to install (e.g. one stored after an earlier
    /// identification and checked with `Calibrated::supplied`): unlocks the
    /// closed-loop modes once the offsets are calibrated.
    pub permit: Option<Calibrated>,
    /// Re-run the current-offset calibration, bridge off
    /// ([`Status::check_calibration`]).
    pub calibrate_offsets: bool,
    /// Run the motor identification ([`Status::check_calibration`]).
    pub identify: bool,
    /// Measure the anticogging map (design §32): a slow sweep in both
    /// directions in velocity mode, so the drive must be calibrated
    /// ([`Status::check_calibration`], [`Refusal::NotCalibrated`]) and
    /// know its angle at low speed (an angle sensor, or injection).
    pub calibrate_cogging: bool,
    /// Learn the angle sensor's correction (design §33): turns at a
    /// constant speed both ways, so the same conditions as
    /// `calibrate_cogging`.
    pub calibrate_encoder: bool,
    /// Latch this fault (e.g. a link watchdog's `Disable` reaction); taken
    /// in any phase, never refused.
    pub fault: Option<Fault>,
    /// The rotor's mechanics for the speed observer's model (design §19),
    /// e.g. from a stored record; applied after `current` (its torque
    /// constant). Unusable values change nothing.
    pub mechanics: Option<Mechanics>,
    /// New travel range and joint settings (design §21): taken while
    /// running as well (homing moves the range), judged on its own.
    pub joint: Option<JointChange>,
    /// The angle source (design §27): `Some(Some(cfg))` runs without the
    /// angle sensor from the next enable, `Some(None)` on the sensor
    /// again. Applied after `current` (its motor is the current loop's).
    pub sensorless: Option<Option<SensorlessConfig>>,
    /// The flux observer beside the angle sensor (design §27: a check,
    /// limp-home, halls + sensorless): `Some(Some(cfg))` installs it (it
    /// runs while the drive is on its sensor), `Some(None)` removes it.
    /// Applied after `sensorless`.
    pub beside: Option<Option<BesideConfig>>,
    /// The d-current reference (design §30: MTPA, field weakening, the
    /// safe state by speed), whole. Checked with [`check_field`] on the
    /// angle calibration in force after the change (a `permit`'s, else
    /// the stage's); a configuration it refuses refuses the change's
    /// settings ([`Refusal::Unsupported`]). Applied after `current` and
    /// `permit` (its constants come from the motor and the limits).
    pub field: Option<FieldConfig>,
}

impl ConfigChange {
    /// Merge a newer change into this one.
    pub fn merge(&mut self, newer: ConfigChange) {
        self.limits = newer.limits.or(self.limits);
        self.current = newer.current.or(self.current);
        self.dividers = newer.dividers.or(self.dividers);
        self.power = newer.power.or(self.power);
        self.permit = newer.permit.or(self.permit);
        self.calibrate_offsets |= newer.calibrate_offsets;
        self.identify |= newer.identify;
        self.calibrate_cogging |= newer.calibrate_cogging;
        self.calibrate_encoder |= newer.calibrate_encoder;
        self.fault = self.fault.or(newer.fault);
        self.mechanics = newer.mechanics.or(self.mechanics);
        self.joint = newer.joint.or(self.joint);
        self.sensorless = newer.sensorless.or(self.sensorless);
        self.beside = newer.beside.or(self.beside);
        self.field = newer.field.or(self.field);
    }

    /// True when it carries settings (limits, current loop, dividers,
    /// power limits, a permit).
    pub fn has_settings(&self) -> bool {
        self.limits.is_some()
            || self.current.is_some()
            || self.dividers.is_some()
            || self.power.is_some()
            || self.permit.is_some()
            || self.mechanics.is_some()
            || self.sensorless.is_some()
            || self.beside.is_some()
            || self.field.is_some()
    }

    /// Why this change's d-current reference cannot be installed on a
    /// stage whose angle calibration is `angle` (the change's own permit,
    /// if it carries one, decides instead): [`check_field`]'s reason, or
    /// `None` (no field setting, or a usable one).
    pub fn field_refusal(&self, angle: &AngleCalibration) -> Option<&'static str> {
        let f = self.field?;
        let angle = self.permit.map_or(*angle, |p| p.angle());
        check_field(&f, &angle).err()
    }
}

/// The one rule for a d-current reference (design §30), the drive's and
/// every front end's: [`FieldConfig::check`] (`max_id_a` finite and
/// `>= 0`, `voltage_margin` within 0 .. 0.5, a finite bandwidth, field
/// weakening with `max_id_a > 0` and a bandwidth), and no field weakening
/// on a coarse angle sensor (halls, interpolated:
/// [`AngleCalibration::interpolation_half_count`]), whose half-count
/// window turns the weakening d current into q current
/// ([`COARSE_FIELD_WEAKENING`]). The error is the reason, in words.
///
/// ```
/// use foc_core::control::field::FieldConfig;
/// use foc_core::control::stage::{AngleCalibration, COARSE_FIELD_WEAKENING};
/// use foc_core::control::MotorParams;
/// use foc_core::drive::check_field;
/// let m = MotorParams { pole_pairs: 8, r_ohm: 0.2, ld_h: 3e-4, lq_h: 3e-4, flux_linkage_wb: 0.02 };
/// let on = FieldConfig { field_weakening: true, ..FieldConfig::for_motor(&m, 20.0, 20_000.0) };
/// use foc_core::angle::ElectricalAngle;
/// let encoder = AngleCalibration {
///     pole_pairs: 8,
///     zero_offset: ElectricalAngle::ZERO,
///     reversed: false,
///     sensor_counts_per_rev: 4096,
///     sensorless_only: false,
/// };
/// // Halls: 6 edges per electrical turn.
/// let halls = AngleCalibration { sensor_counts_per_rev: 48, ..encoder };
/// assert_eq!(check_field(&on, &encoder), Ok(()));
/// assert_eq!(check_field(&on, &halls), Err(COARSE_FIELD_WEAKENING));
/// let nan = FieldConfig { max_id_a: f32::NAN, ..on };
/// assert!(check_field(&nan, &encoder).unwrap_err().contains("max_id_a"));
/// ```
pub fn check_field(f: &FieldConfig, angle: &AngleCalibration) -> Result<(), &'static str> {
    f.check()?;
    if f.field_weakening && angle.interpolation_half_count().is_some() {
        return Err(COARSE_FIELD_WEAKENING);
    }
    Ok(())
}

/// A calibration that turns the rotor slowly on the closed loop and keeps
/// a table (requested with [`ConfigChange::calibrate_cogging`] and
/// [`ConfigChange::calibrate_encoder`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Sweep {
    /// The anticogging map (design §32).
    Cogging,
    /// The angle sensor's correction (design §33).
    Encoder,
}

impl Status {
    /// A sweep calibration alone, as the lifecycle judges its request
    /// (`Lifecycle`'s `check_calibration_request`; a front end applies it
    /// for an immediate refusal): [`Self::check_calibration`], calibrated
    /// ([`Refusal::NotCalibrated`]: it runs on the closed loop), and an
    /// angle it can measure with ([`Refusal::Unsupported`]): the map needs
    /// the angle at low speed, so not sensorless without injection
    /// ([`Self::angle_only_in_motion`]) nor on a coarse sensor (`angle`
    /// interpolated between hall edges: half a count is as wide as a
    /// cogging cycle) unless the drive runs sensorless; the correction
    /// needs the sensor read, so neither sensorless nor coarse. (Two
    /// calibrations in one request are the lifecycle's to refuse:
    /// [`Refusal::Busy`].)
    ///
    /// ```
    /// use foc_core::angle::ElectricalAngle;
    /// use foc_core::control::stage::AngleCalibration;
    /// use foc_core::control::{Mode, Refusal};
    /// use foc_core::drive::{Progress, Status, Sweep};
    /// let idle = Status { running: true, mode: Mode::Disabled, faulted: false, calibrated: true, sensorless: false, injection: false, calibration: Progress::Idle };
    /// let encoder = AngleCalibration { pole_pairs: 7, zero_offset: ElectricalAngle::ZERO, reversed: false, sensor_counts_per_rev: 4096, sensorless_only: false };
    /// let halls = AngleCalibration { sensor_counts_per_rev: 42, ..encoder };
    /// assert_eq!(idle.check_sweep(Sweep::Cogging, &encoder), Ok(()));
    /// assert_eq!(idle.check_sweep(Sweep::Cogging, &halls), Err(Refusal::Unsupported));
    /// let uncalibrated = Status { calibrated: false, ..idle };
    /// assert_eq!(uncalibrated.check_sweep(Sweep::Encoder, &encoder), Err(Refusal::NotCalibrated));
    /// let sensorless = Status { sensorless: true, ..idle };
    /// assert_eq!(sensorless.check_sweep(Sweep::Encoder, &encoder), Err(Refusal::Unsupported));
    /// ```
    pub fn check_sweep(&self, sweep: Sweep, angle: &AngleCalibration) -> Result<(), Refusal> {
        self.check_calibration()?;
        if !self.calibrated {
            return Err(Refusal::NotCalibrated);
        }
        let coarse = angle.interpolation_half_count().is_some();
        let measurable = match sweep {
            Sweep::Cogging => !self.angle_only_in_motion() && (!coarse || self.sensorless),
            Sweep::Encoder => !self.sensorless && !coarse,
        };
        if !measurable {
            return Err(Refusal::Unsupported);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::angle::MechanicalAngle;
    use crate::control::permit::Calibrated;
    use crate::control::stage::Sample;
    use crate::control::MotorParams;
    use crate::drive::cascade::{Cascade, CascadeConfig};
    use crate::hal::PhaseCurrents;

    /// A salient motor (its characteristic current `psi / Ld` = 10 A).
    fn cascade(counts_per_rev: u32) -> (Cascade, CascadeConfig) {
        let motor = MotorParams {
            pole_pairs: 8,
            r_ohm: 0.2,
            ld_h: 2e-3,
            lq_h: 3e-3,
            flux_linkage_wb: 0.02,
        };
        let mut cfg = CascadeConfig::for_motor(motor, 20_000.0, 20.0);
        cfg.current.angle.sensor_counts_per_rev = counts_per_rev;
        (Cascade::new(cfg), cfg)
    }

    /// One period; the change's verdict.
    fn step(c: &mut Cascade) -> Option<Result<(), Refusal>> {
        c.step(&Sample {
            currents: Some(PhaseCurrents::TwoPhase { a_a: 0.0, b_a: 0.0 }),
            angle: Some(MechanicalAngle::ZERO),
            v_bus_v: Some(24.0),
            temperature_c: None,
        });
        c.last_output().and_then(|o| o.change)
    }

    fn with_field(f: FieldConfig) -> ConfigChange {
        ConfigChange {
            field: Some(f),
            ..ConfigChange::default()
        }
    }

    /// A d-current reference is taken whole at the period boundary, on
    /// the stage and in its configuration.
    #[test]
    fn a_field_change_is_taken_whole() {
        let (mut c, cfg) = cascade(4096);
        let f = FieldConfig {
            mtpa: true,
            field_weakening: true,
            max_id_a: 7.5,
            voltage_margin: 0.1,
            bandwidth_rad_s: 500.0,
            short_circuit: false,
        };
        assert_ne!(cfg.current.field, f);
        c.request(with_field(f));
        assert_eq!(step(&mut c), Some(Ok(())));
        assert_eq!(c.current.config().field, f);
        assert_eq!(*c.current.field().config(), f);
    }

    /// Every unusable value, and field weakening on a coarse sensor
    /// (also one a permit in the same change installs), refuses the
    /// change's settings whole: nothing changes, the rule names why.
    #[test]
    fn a_bad_field_change_changes_nothing_and_names_why() {
        let (_, cfg) = cascade(4096);
        let base = FieldConfig {
            field_weakening: true,
            ..cfg.current.field
        };
        let bad: [(FieldConfig, &str); 6] = [
            (
                FieldConfig {
                    max_id_a: f32::NAN,
                    ..base
                },
                "max_id_a",
            ),
            (
                FieldConfig {
                    max_id_a: -1.0,
                    ..base
                },
                "max_id_a",
            ),
            (
                FieldConfig {
                    max_id_a: f32::INFINITY,
                    ..base
                },
                "max_id_a",
            ),
            (
                FieldConfig {
                    voltage_margin: 0.6,
                    ..base
                },
                "voltage_margin",
            ),
            (
                FieldConfig {
                    voltage_margin: f32::NAN,
                    ..base
                },
                "voltage_margin",
            ),
            (
                FieldConfig {
                    bandwidth_rad_s: f32::NAN,
                    ..base
                },
                "bandwidth_rad_s",
            ),
        ];
        for (f, why) in bad {
            let (mut c, cfg) = cascade(4096);
            let mut limits = cfg.current.limits;
            limits.max_current_a = 5.0;
            let ch = ConfigChange {
                limits: Some(limits),
                ..with_field(f)
            };
            assert!(
                ch.field_refusal(&cfg.current.angle)
                    .is_some_and(|r| r.contains(why)),
                "{f:?}"
            );
            c.request(ch);
            assert_eq!(step(&mut c), Some(Err(Refusal::Unsupported)), "{f:?}");
            assert_eq!(c.current.config().field, cfg.current.field, "{f:?}");
            assert_eq!(c.current.config().limits, cfg.current.limits, "{f:?}");
        }
        // Halls (48 counts on 8 pole pairs): no field weakening, MTPA and
        // the short circuit are fine.
        let (mut c, cfg) = cascade(48);
        let ch = with_field(base);
        assert_eq!(
            ch.field_refusal(&cfg.current.angle),
            Some(crate::control::stage::COARSE_FIELD_WEAKENING)
        );
        c.request(ch);
        assert_eq!(step(&mut c), Some(Err(Refusal::Unsupported)));
        assert_eq!(c.current.config().field, cfg.current.field);
        let ok = FieldConfig {
            mtpa: true,
            short_circuit: true,
            ..cfg.current.field
        };
        c.request(with_field(ok));
        assert_eq!(step(&mut c), Some(Ok(())));
        assert_eq!(c.current.config().field, ok);
        // On an encoder, with a permit for halls in the same change: judged
        // on the permit's angle.
        let (mut c, cfg) = cascade(4096);
        let mut halls = cfg.current.angle;
        halls.sensor_counts_per_rev = 48;
        let permit = Calibrated::supplied(halls, cfg.current.current).unwrap();
        let ch = ConfigChange {
            permit: Some(permit),
            ..with_field(base)
        };
        assert!(ch.field_refusal(&cfg.current.angle).is_some());
        c.request(ch);
        assert_eq!(step(&mut c), Some(Err(Refusal::Unsupported)));
        assert!(!c.is_calibrated(), "the permit was not installed either");
    }

    /// Like every setting, only while disabled.
    #[test]
    fn a_field_change_waits_for_the_drive_to_be_disabled() {
        let (mut c, cfg) = cascade(4096);
        c.set_calibration(&Calibrated::supplied(cfg.current.angle, cfg.current.current).unwrap());
        step(&mut c);
        c.command(crate::control::Command::Torque { iq_a: 1.0 })
            .unwrap();
        step(&mut c);
        let f = FieldConfig {
            mtpa: true,
            ..cfg.current.field
        };
        c.request(with_field(f));
        assert_eq!(step(&mut c), Some(Err(Refusal::NotDisabled)));
        assert_eq!(c.current.config().field, cfg.current.field);
    }

    /// The front ends' rule for a sweep calibration
    /// ([`Status::check_sweep`]) gives the lifecycle's verdict on the
    /// request, case by case: uncalibrated, calibrated on an encoder, on
    /// halls, faulted, enabled.
    #[test]
    fn the_sweep_rule_is_the_lifecycles() {
        let request = |s| match s {
            Sweep::Cogging => ConfigChange {
                calibrate_cogging: true,
                ..ConfigChange::default()
            },
            Sweep::Encoder => ConfigChange {
                calibrate_encoder: true,
                ..ConfigChange::default()
            },
        };
        let calibrated = |counts| {
            let (mut c, cfg) = cascade(counts);
            c.set_calibration(
                &Calibrated::supplied(cfg.current.angle, cfg.current.current).unwrap(),
            );
            step(&mut c);
            (c, cfg)
        };
        for sweep in [Sweep::Cogging, Sweep::Encoder] {
            let cases = [
                ("uncalibrated", cascade(4096), Err(Refusal::NotCalibrated)),
                ("encoder", calibrated(4096), Ok(())),
                ("halls", calibrated(48), Err(Refusal::Unsupported)),
                (
                    "faulted",
                    {
                        let (mut c, cfg) = calibrated(4096);
                        c.report_fault(Fault::CommandTimeout);
                        step(&mut c);
                        (c, cfg)
                    },
                    Err(Refusal::Faulted),
                ),
                (
                    "enabled",
                    {
                        let (mut c, cfg) = calibrated(4096);
                        c.command(crate::control::Command::Torque { iq_a: 0.5 })
                            .unwrap();
                        step(&mut c);
                        (c, cfg)
                    },
                    Err(Refusal::NotDisabled),
                ),
            ];
            for (what, (mut c, _), want) in cases {
                let angle = c.current.config().angle;
                assert_eq!(
                    c.status().check_sweep(sweep, &angle),
                    want,
                    "{sweep:?} {what}"
                );
                c.request(request(sweep));
                assert_eq!(step(&mut c), Some(want), "{sweep:?} {what}: the lifecycle");
            }
        }
    }
}
