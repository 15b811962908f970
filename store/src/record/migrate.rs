//! Older schema versions, frozen, and their migration to the current one.

use super::*;

/// Upgrade the payload of an older schema version to a record of this one.
///
/// Each older version is read with its own frozen struct and converted
/// one step at a time: version 1 (before the power limits,
/// [`v1::DriveRecordV1`]) gets `power: None` (the build's defaults),
/// version 2 (before the mechanics, [`v2::DriveRecordV2`]) gets
/// `mechanics: None`, version 3 (before the joint, [`v3::DriveRecordV3`])
/// gets `joint: None`, version 4 (before the sensorless setting,
/// [`v4::DriveRecordV4`]) gets `sensorless: None` (the angle sensor),
/// version 5 (before the observer's role beside the sensor,
/// [`v5::DriveRecordV5`]) gets `beside_sensor: None` (a `[sensorless]`
/// table replaces the sensor, as it did), version 6 (before calibrations
/// made without a sensor, [`v6::DriveRecordV6`]) gets
/// `sensorless_only: false` in its calibration (every earlier one was
/// made with the sensor), version 7 (before the d-current reference,
/// [`v7::DriveRecordV7`]) gets `field: None` (the motor's defaults,
/// foc-core's `FieldConfig::for_motor`, applied with the record), version
/// 8 (before the tables, [`v8::DriveRecordV8`]) gets `cogging: None` and
/// `angle_correction: None` (none measured); a version-1 record goes
/// `1 -> 2 -> ... -> 9`. A
/// migrated record is validated by the caller like any other; version 0
/// and unknown versions are refused.
pub(super) fn migrate(found: u16, payload: &[u8]) -> Result<DriveRecord, RecordError> {
    match found {
        1 => match postcard::take_from_bytes::<v1::DriveRecordV1>(payload) {
            Ok((r, [])) => Ok(r
                .into_v2()
                .into_v3()
                .into_v4()
                .into_v5()
                .into_v6()
                .into_v7()
                .into_v8()
                .into_v9()),
            _ => Err(RecordError::Malformed),
        },
        2 => match postcard::take_from_bytes::<v2::DriveRecordV2>(payload) {
            Ok((r, [])) => Ok(r
                .into_v3()
                .into_v4()
                .into_v5()
                .into_v6()
                .into_v7()
                .into_v8()
                .into_v9()),
            _ => Err(RecordError::Malformed),
        },
        3 => match postcard::take_from_bytes::<v3::DriveRecordV3>(payload) {
            Ok((r, [])) => Ok(r
                .into_v4()
                .into_v5()
                .into_v6()
                .into_v7()
                .into_v8()
                .into_v9()),
            _ => Err(RecordError::Malformed),
        },
        4 => match postcard::take_from_bytes::<v4::DriveRecordV4>(payload) {
            Ok((r, [])) => Ok(r.into_v5().into_v6().into_v7().into_v8().into_v9()),
            _ => Err(RecordError::Malformed),
        },
        5 => match postcard::take_from_bytes::<v5::DriveRecordV5>(payload) {
            Ok((r, [])) => Ok(r.into_v6().into_v7().into_v8().into_v9()),
            _ => Err(RecordError::Malformed),
        },
        6 => match postcard::take_from_bytes::<v6::DriveRecordV6>(payload) {
            Ok((r, [])) => Ok(r.into_v7().into_v8().into_v9()),
            _ => Err(RecordError::Malformed),
        },
        7 => match postcard::take_from_bytes::<v7::DriveRecordV7>(payload) {
            Ok((r, [])) => Ok(r.into_v8().into_v9()),
            _ => Err(RecordError::Malformed),
        },
        8 => match postcard::take_from_bytes::<v8::DriveRecordV8>(payload) {
            Ok((r, [])) => Ok(r.into_v9()),
            _ => Err(RecordError::Malformed),
        },
        _ => Err(RecordError::UnsupportedVersion {
            found,
            supported: SCHEMA_VERSION,
        }),
    }
}

/// The angle calibration of versions 1 to 6 (without
/// [`AngleRecord::sensorless_only`]). Frozen: never change it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AngleRecordV6 {
    /// See [`AngleRecord::zero_offset_e_rad`].
    pub zero_offset_e_rad: f32,
    /// See [`AngleRecord::reversed`].
    pub reversed: bool,
    /// See [`AngleRecord::pole_pairs`].
    pub pole_pairs: u8,
    /// See [`AngleRecord::sensor_counts_per_rev`].
    pub sensor_counts_per_rev: u32,
}

impl AngleRecordV6 {
    /// Version 7: made with the sensor.
    pub fn into_v7(self) -> AngleRecord {
        AngleRecord {
            zero_offset_e_rad: self.zero_offset_e_rad,
            reversed: self.reversed,
            pole_pairs: self.pole_pairs,
            sensor_counts_per_rev: self.sensor_counts_per_rev,
            sensorless_only: false,
        }
    }
}

/// Schema version 1: [`DriveRecord`] without `power`.
pub mod v1 {
    use super::*;

    /// The version-1 layout (field for field [`DriveRecord`] up to
    /// `watchdog`). Frozen: never change it.
    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct DriveRecordV1 {
        /// See [`DriveRecord::label`].
        pub label: Label,
        /// See [`DriveRecord::pwm_frequency_hz`].
        pub pwm_frequency_hz: u32,
        /// See [`DriveRecord::motor`].
        pub motor: MotorRecord,
        /// See [`DriveRecord::current_gains`].
        pub current_gains: CurrentGainsRecord,
        /// See [`DriveRecord::calibration`].
        pub calibration: Option<super::AngleRecordV6>,
        /// See [`DriveRecord::limits`].
        pub limits: LimitsRecord,
        /// See [`DriveRecord::speed`].
        pub speed: SpeedRecord,
        /// See [`DriveRecord::position`].
        pub position: PositionRecord,
        /// See [`DriveRecord::dividers`].
        pub dividers: DividersRecord,
        /// See [`DriveRecord::watchdog`].
        pub watchdog: WatchdogRecord,
    }

    impl DriveRecordV1 {
        /// Version 2: the same values, the power limits at the build's
        /// defaults.
        pub fn into_v2(self) -> super::v2::DriveRecordV2 {
            super::v2::DriveRecordV2 {
                label: self.label,
                pwm_frequency_hz: self.pwm_frequency_hz,
                motor: self.motor,
                current_gains: self.current_gains,
                calibration: self.calibration,
                limits: self.limits,
                speed: self.speed,
                position: self.position,
                dividers: self.dividers,
                watchdog: self.watchdog,
                power: None,
            }
        }
    }
}

/// Schema version 2: [`DriveRecord`] without `mechanics`.
pub mod v2 {
    use super::*;

    /// The version-2 layout (field for field [`DriveRecord`] up to
    /// `power`). Frozen: never change it.
    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct DriveRecordV2 {
        /// See [`DriveRecord::label`].
        pub label: Label,
        /// See [`DriveRecord::pwm_frequency_hz`].
        pub pwm_frequency_hz: u32,
        /// See [`DriveRecord::motor`].
        pub motor: MotorRecord,
        /// See [`DriveRecord::current_gains`].
        pub current_gains: CurrentGainsRecord,
        /// See [`DriveRecord::calibration`].
        pub calibration: Option<super::AngleRecordV6>,
        /// See [`DriveRecord::limits`].
        pub limits: LimitsRecord,
        /// See [`DriveRecord::speed`].
        pub speed: SpeedRecord,
        /// See [`DriveRecord::position`].
        pub position: PositionRecord,
        /// See [`DriveRecord::dividers`].
        pub dividers: DividersRecord,
        /// See [`DriveRecord::watchdog`].
        pub watchdog: WatchdogRecord,
        /// See [`DriveRecord::power`].
        pub power: Option<PowerRecord>,
    }

    impl DriveRecordV2 {
        /// Version 3: the same values, the mechanics not identified (the
        /// build's).
        pub fn into_v3(self) -> super::v3::DriveRecordV3 {
            super::v3::DriveRecordV3 {
                label: self.label,
                pwm_frequency_hz: self.pwm_frequency_hz,
                motor: self.motor,
                current_gains: self.current_gains,
                calibration: self.calibration,
                limits: self.limits,
                speed: self.speed,
                position: self.position,
                dividers: self.dividers,
                watchdog: self.watchdog,
                power: self.power,
                mechanics: None,
            }
        }
    }
}

/// Schema version 3: [`DriveRecord`] without `joint`.
pub mod v3 {
    use super::*;

    /// The version-3 layout (field for field [`DriveRecord`] up to
    /// `mechanics`). Frozen: never change it.
    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct DriveRecordV3 {
        /// See [`DriveRecord::label`].
        pub label: Label,
        /// See [`DriveRecord::pwm_frequency_hz`].
        pub pwm_frequency_hz: u32,
        /// See [`DriveRecord::motor`].
        pub motor: MotorRecord,
        /// See [`DriveRecord::current_gains`].
        pub current_gains: CurrentGainsRecord,
        /// See [`DriveRecord::calibration`].
        pub calibration: Option<super::AngleRecordV6>,
        /// See [`DriveRecord::limits`].
        pub limits: LimitsRecord,
        /// See [`DriveRecord::speed`].
        pub speed: SpeedRecord,
        /// See [`DriveRecord::position`].
        pub position: PositionRecord,
        /// See [`DriveRecord::dividers`].
        pub dividers: DividersRecord,
        /// See [`DriveRecord::watchdog`].
        pub watchdog: WatchdogRecord,
        /// See [`DriveRecord::power`].
        pub power: Option<PowerRecord>,
        /// See [`DriveRecord::mechanics`].
        pub mechanics: Option<MechanicsRecord>,
    }

    impl DriveRecordV3 {
        /// Version 4: the same values, the joint the build's.
        pub fn into_v4(self) -> super::v4::DriveRecordV4 {
            super::v4::DriveRecordV4 {
                label: self.label,
                pwm_frequency_hz: self.pwm_frequency_hz,
                motor: self.motor,
                current_gains: self.current_gains,
                calibration: self.calibration,
                limits: self.limits,
                speed: self.speed,
                position: self.position,
                dividers: self.dividers,
                watchdog: self.watchdog,
                power: self.power,
                mechanics: self.mechanics,
                joint: None,
            }
        }
    }
}

/// Schema version 4: [`DriveRecord`] without `sensorless`.
pub mod v4 {
    use super::*;

    /// The version-4 layout (field for field [`DriveRecord`] up to
    /// `joint`). Frozen: never change it.
    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct DriveRecordV4 {
        /// See [`DriveRecord::label`].
        pub label: Label,
        /// See [`DriveRecord::pwm_frequency_hz`].
        pub pwm_frequency_hz: u32,
        /// See [`DriveRecord::motor`].
        pub motor: MotorRecord,
        /// See [`DriveRecord::current_gains`].
        pub current_gains: CurrentGainsRecord,
        /// See [`DriveRecord::calibration`].
        pub calibration: Option<super::AngleRecordV6>,
        /// See [`DriveRecord::limits`].
        pub limits: LimitsRecord,
        /// See [`DriveRecord::speed`].
        pub speed: SpeedRecord,
        /// See [`DriveRecord::position`].
        pub position: PositionRecord,
        /// See [`DriveRecord::dividers`].
        pub dividers: DividersRecord,
        /// See [`DriveRecord::watchdog`].
        pub watchdog: WatchdogRecord,
        /// See [`DriveRecord::power`].
        pub power: Option<PowerRecord>,
        /// See [`DriveRecord::mechanics`].
        pub mechanics: Option<MechanicsRecord>,
        /// See [`DriveRecord::joint`].
        pub joint: Option<JointRecord>,
    }

    impl DriveRecordV4 {
        /// Version 5: the same values, on the angle sensor.
        pub fn into_v5(self) -> super::v5::DriveRecordV5 {
            super::v5::DriveRecordV5 {
                label: self.label,
                pwm_frequency_hz: self.pwm_frequency_hz,
                motor: self.motor,
                current_gains: self.current_gains,
                calibration: self.calibration,
                limits: self.limits,
                speed: self.speed,
                position: self.position,
                dividers: self.dividers,
                watchdog: self.watchdog,
                power: self.power,
                mechanics: self.mechanics,
                joint: self.joint,
                sensorless: None,
            }
        }
    }
}

/// Schema version 5: [`DriveRecord`] with the sensorless table before the
/// observer's role beside the sensor.
pub mod v5 {
    use super::*;

    /// The version-5 sensorless table (`start_current_a`, `bus_voltage_v`
    /// of [`SensorlessRecord`]). Frozen: never change it.
    #[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct SensorlessRecordV5 {
        /// See [`SensorlessRecord::start_current_a`].
        pub start_current_a: f32,
        /// See [`SensorlessRecord::bus_voltage_v`].
        pub bus_voltage_v: f32,
    }

    /// The version-5 layout. Frozen: never change it.
    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct DriveRecordV5 {
        /// See [`DriveRecord::label`].
        pub label: Label,
        /// See [`DriveRecord::pwm_frequency_hz`].
        pub pwm_frequency_hz: u32,
        /// See [`DriveRecord::motor`].
        pub motor: MotorRecord,
        /// See [`DriveRecord::current_gains`].
        pub current_gains: CurrentGainsRecord,
        /// See [`DriveRecord::calibration`].
        pub calibration: Option<super::AngleRecordV6>,
        /// See [`DriveRecord::limits`].
        pub limits: LimitsRecord,
        /// See [`DriveRecord::speed`].
        pub speed: SpeedRecord,
        /// See [`DriveRecord::position`].
        pub position: PositionRecord,
        /// See [`DriveRecord::dividers`].
        pub dividers: DividersRecord,
        /// See [`DriveRecord::watchdog`].
        pub watchdog: WatchdogRecord,
        /// See [`DriveRecord::power`].
        pub power: Option<PowerRecord>,
        /// See [`DriveRecord::mechanics`].
        pub mechanics: Option<MechanicsRecord>,
        /// See [`DriveRecord::joint`].
        pub joint: Option<JointRecord>,
        /// See [`DriveRecord::sensorless`].
        pub sensorless: Option<SensorlessRecordV5>,
    }

    impl DriveRecordV5 {
        /// Version 6: the same values; a sensorless table replaces the
        /// sensor, as it did.
        pub fn into_v6(self) -> super::v6::DriveRecordV6 {
            super::v6::DriveRecordV6 {
                label: self.label,
                pwm_frequency_hz: self.pwm_frequency_hz,
                motor: self.motor,
                current_gains: self.current_gains,
                calibration: self.calibration,
                limits: self.limits,
                speed: self.speed,
                position: self.position,
                dividers: self.dividers,
                watchdog: self.watchdog,
                power: self.power,
                mechanics: self.mechanics,
                joint: self.joint,
                sensorless: self.sensorless.map(|sl| SensorlessRecord {
                    start_current_a: sl.start_current_a,
                    bus_voltage_v: sl.bus_voltage_v,
                    beside_sensor: None,
                    observer_above_rad_s: None,
                }),
            }
        }
    }
}

/// Schema version 6: [`DriveRecord`] before calibrations made without a
/// sensor.
pub mod v6 {
    use super::*;

    /// The version-6 layout. Frozen: never change it.
    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct DriveRecordV6 {
        /// See [`DriveRecord::label`].
        pub label: Label,
        /// See [`DriveRecord::pwm_frequency_hz`].
        pub pwm_frequency_hz: u32,
        /// See [`DriveRecord::motor`].
        pub motor: MotorRecord,
        /// See [`DriveRecord::current_gains`].
        pub current_gains: CurrentGainsRecord,
        /// See [`DriveRecord::calibration`].
        pub calibration: Option<super::AngleRecordV6>,
        /// See [`DriveRecord::limits`].
        pub limits: LimitsRecord,
        /// See [`DriveRecord::speed`].
        pub speed: SpeedRecord,
        /// See [`DriveRecord::position`].
        pub position: PositionRecord,
        /// See [`DriveRecord::dividers`].
        pub dividers: DividersRecord,
        /// See [`DriveRecord::watchdog`].
        pub watchdog: WatchdogRecord,
        /// See [`DriveRecord::power`].
        pub power: Option<PowerRecord>,
        /// See [`DriveRecord::mechanics`].
        pub mechanics: Option<MechanicsRecord>,
        /// See [`DriveRecord::joint`].
        pub joint: Option<JointRecord>,
        /// See [`DriveRecord::sensorless`].
        pub sensorless: Option<SensorlessRecord>,
    }

    impl DriveRecordV6 {
        /// Version 7: the same values; the calibration was made with the
        /// sensor.
        pub fn into_v7(self) -> super::v7::DriveRecordV7 {
            super::v7::DriveRecordV7 {
                label: self.label,
                pwm_frequency_hz: self.pwm_frequency_hz,
                motor: self.motor,
                current_gains: self.current_gains,
                calibration: self.calibration.map(super::AngleRecordV6::into_v7),
                limits: self.limits,
                speed: self.speed,
                position: self.position,
                dividers: self.dividers,
                watchdog: self.watchdog,
                power: self.power,
                mechanics: self.mechanics,
                joint: self.joint,
                sensorless: self.sensorless,
            }
        }
    }
}

/// Schema version 7: [`DriveRecord`] before the d-current reference
/// (design §30).
pub mod v7 {
    use super::*;

    /// The version-7 layout. Frozen: never change it.
    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct DriveRecordV7 {
        /// See [`DriveRecord::label`].
        pub label: Label,
        /// See [`DriveRecord::pwm_frequency_hz`].
        pub pwm_frequency_hz: u32,
        /// See [`DriveRecord::motor`].
        pub motor: MotorRecord,
        /// See [`DriveRecord::current_gains`].
        pub current_gains: CurrentGainsRecord,
        /// See [`DriveRecord::calibration`].
        pub calibration: Option<AngleRecord>,
        /// See [`DriveRecord::limits`].
        pub limits: LimitsRecord,
        /// See [`DriveRecord::speed`].
        pub speed: SpeedRecord,
        /// See [`DriveRecord::position`].
        pub position: PositionRecord,
        /// See [`DriveRecord::dividers`].
        pub dividers: DividersRecord,
        /// See [`DriveRecord::watchdog`].
        pub watchdog: WatchdogRecord,
        /// See [`DriveRecord::power`].
        pub power: Option<PowerRecord>,
        /// See [`DriveRecord::mechanics`].
        pub mechanics: Option<MechanicsRecord>,
        /// See [`DriveRecord::joint`].
        pub joint: Option<JointRecord>,
        /// See [`DriveRecord::sensorless`].
        pub sensorless: Option<SensorlessRecord>,
    }

    impl DriveRecordV7 {
        /// Version 8: the same values; the d-current reference the motor's
        /// defaults (`field: None`, see [`DriveRecord::field`]).
        pub fn into_v8(self) -> super::v8::DriveRecordV8 {
            super::v8::DriveRecordV8 {
                label: self.label,
                pwm_frequency_hz: self.pwm_frequency_hz,
                motor: self.motor,
                current_gains: self.current_gains,
                calibration: self.calibration,
                limits: self.limits,
                speed: self.speed,
                position: self.position,
                dividers: self.dividers,
                watchdog: self.watchdog,
                power: self.power,
                mechanics: self.mechanics,
                joint: self.joint,
                sensorless: self.sensorless,
                field: None,
            }
        }
    }
}

/// Schema version 8: [`DriveRecord`] before the tables (the anticogging
/// map, design §32; the angle sensor's correction, design §33).
pub mod v8 {
    use super::*;

    /// The version-8 layout. Frozen: never change it.
    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct DriveRecordV8 {
        /// See [`DriveRecord::label`].
        pub label: Label,
        /// See [`DriveRecord::pwm_frequency_hz`].
        pub pwm_frequency_hz: u32,
        /// See [`DriveRecord::motor`].
        pub motor: MotorRecord,
        /// See [`DriveRecord::current_gains`].
        pub current_gains: CurrentGainsRecord,
        /// See [`DriveRecord::calibration`].
        pub calibration: Option<AngleRecord>,
        /// See [`DriveRecord::limits`].
        pub limits: LimitsRecord,
        /// See [`DriveRecord::speed`].
        pub speed: SpeedRecord,
        /// See [`DriveRecord::position`].
        pub position: PositionRecord,
        /// See [`DriveRecord::dividers`].
        pub dividers: DividersRecord,
        /// See [`DriveRecord::watchdog`].
        pub watchdog: WatchdogRecord,
        /// See [`DriveRecord::power`].
        pub power: Option<PowerRecord>,
        /// See [`DriveRecord::mechanics`].
        pub mechanics: Option<MechanicsRecord>,
        /// See [`DriveRecord::joint`].
        pub joint: Option<JointRecord>,
        /// See [`DriveRecord::sensorless`].
        pub sensorless: Option<SensorlessRecord>,
        /// See [`DriveRecord::field`].
        pub field: Option<FieldRecord>,
    }

    impl DriveRecordV8 {
        /// Version 9: the same values; no tables measured
        /// (`cogging: None`, `angle_correction: None`).
        pub fn into_v9(self) -> DriveRecord {
            DriveRecord {
                label: self.label,
                pwm_frequency_hz: self.pwm_frequency_hz,
                motor: self.motor,
                current_gains: self.current_gains,
                calibration: self.calibration,
                limits: self.limits,
                speed: self.speed,
                position: self.position,
                dividers: self.dividers,
                watchdog: self.watchdog,
                power: self.power,
                mechanics: self.mechanics,
                joint: self.joint,
                sensorless: self.sensorless,
                field: self.field,
                cogging: None,
                angle_correction: None,
            }
        }
    }
}
