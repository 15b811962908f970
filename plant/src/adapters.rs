//! `foc-core` hardware traits implemented on a shared [`Plant`].
//!
//! The plant lives in a [`RefCell`]; each adapter borrows it for one call, so
//! a runner can hand `PwmDriver`, `CurrentSense`, `AngleSensor` and
//! `BusVoltage` implementations to code written for a board. The PWM adapter
//! only stores duties and the enable flag; [`BenchPwm::step`] advances the
//! plant by one period and latches the sample the sensor adapters then read.
//!
//! ```
//! use core::cell::RefCell;
//! use foc_plant::adapters::{BenchPwm, BenchSensors};
//! use foc_plant::plant::{BenchConfig, MotorParams, Plant};
//! use foc_core::hal::{PwmDriver, CurrentSense, BusVoltage};
//! let plant = RefCell::new(Plant::new(MotorParams::example(), BenchConfig::default()));
//! let sensors = BenchSensors::new(&plant);
//! let mut pwm = BenchPwm::new(&sensors, 4200);
//! pwm.enable().unwrap();
//! pwm.set_duties([0.5, 0.5, 0.5]).unwrap();
//! pwm.step(0.0);
//! let mut cs = sensors.current_sense();
//! assert!(cs.read_currents().is_ok());
//! let mut vb = sensors.bus_voltage();
//! assert!(vb.read_bus_voltage_v().unwrap() > 20.0);
//! ```

use crate::plant::{Measurements, Plant};
use core::cell::{Cell, RefCell};
use foc_core::angle::MechanicalAngle;
use foc_core::frames::Abc;
use foc_core::hal::{AngleSensor, BusVoltage, CurrentSense, PhaseCurrents, PwmDriver};

/// Error of a bench adapter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BenchError {
    /// No period has been simulated yet, so there is no sample.
    NoSample,
    /// A compare value above the period.
    CompareOutOfRange,
    /// The reading is not a finite number (injected NaN fault).
    NotFinite,
}

/// The latest sample, shared by the sensor adapters.
#[derive(Debug)]
pub struct BenchSensors<'a> {
    plant: &'a RefCell<Plant>,
    latest: Cell<Option<Measurements>>,
    offsets: Cell<Abc>,
}

impl<'a> BenchSensors<'a> {
    /// Sensors of `plant` (no sample until the first [`BenchPwm::step`]).
    pub fn new(plant: &'a RefCell<Plant>) -> Self {
        Self {
            plant,
            latest: Cell::new(None),
            offsets: Cell::new(Abc::default()),
        }
    }
    /// The latest raw sample.
    pub fn latest(&self) -> Option<Measurements> {
        self.latest.get()
    }
    /// The shared plant.
    pub fn plant(&self) -> &'a RefCell<Plant> {
        self.plant
    }
    /// A [`CurrentSense`] view.
    pub fn current_sense(&self) -> BenchCurrentSense<'_, 'a> {
        BenchCurrentSense { s: self }
    }
    /// An [`AngleSensor`] view.
    pub fn angle_sensor(&self) -> BenchAngleSensor<'_, 'a> {
        BenchAngleSensor { s: self }
    }
    /// A [`BusVoltage`] view.
    pub fn bus_voltage(&self) -> BenchBusVoltage<'_, 'a> {
        BenchBusVoltage { s: self }
    }
}

/// [`PwmDriver`] on the plant.
#[derive(Debug)]
pub struct BenchPwm<'s, 'a> {
    sensors: &'s BenchSensors<'a>,
    period_counts: u16,
    compare: [u16; 3],
    enabled: bool,
}

impl<'s, 'a> BenchPwm<'s, 'a> {
    /// PWM adapter with a timer period of `period_counts`.
    pub fn new(sensors: &'s BenchSensors<'a>, period_counts: u16) -> Self {
        Self {
            sensors,
            period_counts: period_counts.max(1),
            compare: [period_counts / 2; 3],
            enabled: false,
        }
    }
    /// Simulate one period with the present compare values and latch the sample.
    pub fn step(&mut self, load_torque_nm: f32) -> Measurements {
        let p = self.period_counts as f32;
        let duties = self.compare.map(|c| c as f32 / p);
        let m = self
            .sensors
            .plant
            .borrow_mut()
            .step_period(duties, self.enabled, load_torque_nm);
        self.sensors.latest.set(Some(m));
        m
    }
}

impl PwmDriver for BenchPwm<'_, '_> {
    type Error = BenchError;
    fn period_counts(&self) -> u16 {
        self.period_counts
    }
    fn set_compare(&mut self, compare: [u16; 3]) -> Result<(), BenchError> {
        if compare.iter().any(|c| *c > self.period_counts) {
            return Err(BenchError::CompareOutOfRange);
        }
        self.compare = compare;
        Ok(())
    }
    fn enable(&mut self) -> Result<(), BenchError> {
        self.enabled = true;
        Ok(())
    }
    fn disable(&mut self) {
        self.enabled = false;
    }
    fn is_enabled(&self) -> bool {
        self.enabled
    }
}

/// [`CurrentSense`] view of [`BenchSensors`] (subtracts the set offsets).
#[derive(Debug)]
pub struct BenchCurrentSense<'s, 'a> {
    s: &'s BenchSensors<'a>,
}

impl CurrentSense for BenchCurrentSense<'_, '_> {
    type Error = BenchError;
    fn read_currents(&mut self) -> Result<PhaseCurrents, BenchError> {
        let m = self.s.latest.get().ok_or(BenchError::NoSample)?;
        let o = self.s.offsets.get();
        let c = match m.currents {
            PhaseCurrents::TwoPhase { a_a, b_a } => PhaseCurrents::TwoPhase {
                a_a: a_a - o.a,
                b_a: b_a - o.b,
            },
            PhaseCurrents::ThreePhase(abc) => {
                PhaseCurrents::ThreePhase(Abc::new(abc.a - o.a, abc.b - o.b, abc.c - o.c))
            }
        };
        if c.to_abc().is_finite() {
            Ok(c)
        } else {
            Err(BenchError::NotFinite)
        }
    }
    fn offsets_a(&self) -> Abc {
        self.s.offsets.get()
    }
    fn set_offsets_a(&mut self, offsets: Abc) {
        self.s.offsets.set(offsets);
    }
}

/// [`AngleSensor`] view of [`BenchSensors`].
#[derive(Debug)]
pub struct BenchAngleSensor<'s, 'a> {
    s: &'s BenchSensors<'a>,
}

impl AngleSensor for BenchAngleSensor<'_, '_> {
    type Error = BenchError;
    fn read_angle(&mut self) -> Result<MechanicalAngle, BenchError> {
        self.s
            .latest
            .get()
            .map(|m| m.angle)
            .ok_or(BenchError::NoSample)
    }
}

/// [`BusVoltage`] view of [`BenchSensors`].
#[derive(Debug)]
pub struct BenchBusVoltage<'s, 'a> {
    s: &'s BenchSensors<'a>,
}

impl BusVoltage for BenchBusVoltage<'_, '_> {
    type Error = BenchError;
    fn read_bus_voltage_v(&mut self) -> Result<f32, BenchError> {
        self.s
            .latest
            .get()
            .map(|m| m.v_bus_v)
            .ok_or(BenchError::NoSample)
    }
    /// The power-stage temperature of the latest sample: `None` (no sensor)
    /// unless the plant has a stage thermal model
    /// ([`Plant::set_stage_thermal`]) and has been stepped.
    fn read_temperature_c(&mut self) -> Option<Result<f32, BenchError>> {
        self.s
            .latest
            .get()
            .and_then(|m| m.stage_temperature_c)
            .map(Ok)
    }
}
