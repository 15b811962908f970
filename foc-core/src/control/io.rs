//! Glue between the hardware traits and the stages: read a [`Sample`] from
//! the sensors, apply a [`BridgeCommand`] to the PWM. Used by the firmware,
//! the emulated board and the bench alike.

use super::stage::Sample;
use super::supervisor::Fault;
use super::BridgeCommand;
use crate::hal::{AngleSensor, BusVoltage, CurrentSense, PwmDriver};

/// Read one sample; a failed read becomes `None` (the current stage turns
/// it into the matching fault).
#[inline]
pub fn read_sample<C, A, B>(currents: &mut C, angle: &mut A, bus: &mut B) -> Sample
where
    C: CurrentSense,
    A: AngleSensor,
    B: BusVoltage,
{
    Sample {
        currents: currents.read_currents().ok(),
        angle: angle.read_angle().ok(),
        v_bus_v: bus.read_bus_voltage_v().ok(),
        temperature_c: bus.read_temperature_c().and_then(|r| r.ok()),
    }
}

/// Apply the stage's decision. Duties are written *before* the bridge is
/// enabled. A PWM error puts the bridge in the safe state and is returned
/// as [`Fault::PwmError`] for the caller to report.
#[inline]
pub fn apply<P: PwmDriver>(pwm: &mut P, cmd: BridgeCommand) -> Result<(), Fault> {
    match cmd {
        BridgeCommand::SafeState => {
            pwm.disable();
            Ok(())
        }
        BridgeCommand::ShortCircuit => pwm.short_circuit().map_err(|_| {
            pwm.disable();
            Fault::PwmError
        }),
        BridgeCommand::Duties(d) => {
            let r = pwm.set_duties(d).and_then(|()| {
                if pwm.is_enabled() {
                    Ok(())
                } else {
                    pwm.enable()
                }
            });
            r.map_err(|_| {
                pwm.disable();
                Fault::PwmError
            })
        }
    }
}
