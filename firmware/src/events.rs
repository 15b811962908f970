//! The drive's lifecycle events in the log (defmt), nothing else: what
//! happens is decided in `foc_core::drive`.

use foc_core::calibration::identification::IdentificationResult;
use foc_core::drive::Event;

/// Log `e` (`period`: current-loop periods since reset); returns the
/// result of a successful identification (the current loop publishes it
/// for the command channel).
pub fn log(e: &Event, period: u32) -> Option<IdentificationResult> {
    match *e {
        Event::OffsetsDone(o) => defmt::info!("current offsets [A]: {}", o),
        Event::OffsetsFailed(err) => defmt::error!("offset calibration failed: {}", err),
        Event::CurrentSenseFailed => defmt::error!("current sensor did not answer"),
        Event::SensorCheckFailed => defmt::error!("angle sensor check failed"),
        Event::StartUpDone => {
            defmt::info!("start-up done: disabled, waiting for a command")
        }
        Event::CalibrationRestored => {
            defmt::info!(
                "start-up done: calibrated from the store at period {=u32}, disabled, waiting for a command",
                period
            )
        }
        Event::IdentificationStarted => defmt::info!("identifying the motor"),
        Event::Identified(r) => {
            defmt::info!(
                "identified: R {=f32} ohm, Ld {=f32} H, Lq {=f32} H, psi {=f32} Wb, {}",
                r.r_ohm,
                r.ld_h,
                r.lq_h,
                r.flux_linkage_wb,
                r.angle
            );
            if let Some(m) = r.mechanics {
                defmt::info!(
                    "identified mechanics: J {=f32} kg m^2, B {=f32} N m s/rad, Fc {=f32} N m",
                    m.inertia_kg_m2,
                    m.viscous_friction_nm_s_per_rad,
                    m.coulomb_friction_nm
                );
            }
            return Some(r);
        }
        Event::IdentificationFailed(err, st) => {
            defmt::error!("identification failed in {}: {}", st, err)
        }
        Event::IdentificationAborted(f, st) => {
            defmt::error!("identification aborted in {}: fault {}", st, f)
        }
        Event::IndexFound { travel_rad } => {
            defmt::info!("encoder index found after {=f32} rad", travel_rad)
        }
        Event::EncoderLinearised { peak_rad, periods } => {
            defmt::info!(
                "angle sensor linearised: peak {=f32} rad in {=u32} periods",
                peak_rad,
                periods
            )
        }
        Event::CoggingMeasured { peak_a, periods } => {
            defmt::info!(
                "anticogging map measured: peak {=f32} A in {=u32} periods",
                peak_a,
                periods
            )
        }
    }
    None
}
