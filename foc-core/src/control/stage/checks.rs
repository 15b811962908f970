//! Sensor plausibility: the motor-model check (design §24) and the slower
//! tracking back-up.

use super::*;
use crate::control::frozen::Readings;

impl CurrentStage {
    /// The model check for the present motor, period and angle sensor (its
    /// healthy margin kept).
    pub(super) fn rebuild_model(&mut self) {
        let peaks = self.model.peaks_sq();
        self.model = model_check(&self.config);
        self.model.keep_peaks(peaks);
    }

    /// The model-based sensor check (design §24): its last residual and
    /// the healthy margin.
    pub fn model_check(&self) -> &ModelCheck {
        &self.model
    }

    /// Forget the model check's healthy margin (start a new measurement).
    pub fn reset_model_margin(&mut self) {
        self.model.reset_peak();
    }

    /// Sensor plausibility from the motor model (closed loop, design
    /// §24): judges this period, then records what it drives. False when
    /// a fault tripped.
    #[inline(always)]
    pub(super) fn sensors_plausible(
        &mut self,
        out: Option<&CurrentLoopOutput>,
        sensed: &Sensed,
        i_ref: Dq,
        w_e_rad_s: f32,
    ) -> bool {
        let Some(o) = out.filter(|o| !o.invalid) else {
            self.model.reset();
            return true;
        };
        let p = Period {
            i_ab_a: sensed.i_ab,
            i_dq_a: o.i_dq_a,
            sin_cos: o.sin_cos,
            theta_e: sensed.theta_e,
            // The observer's speed against the tracker's (coarse sensors).
            omega_spread_rad_s: w_e_rad_s
                - self.tracker.velocity_rad_s() * self.config.angle.pole_pairs as f32,
            omega_e_rad_s: w_e_rad_s,
            unchanged_periods: self.state.unchanged_periods,
        };
        let verdict = self.model.check(&p);
        self.follow_emf();
        let frozen = self.model.frozen_channel(&Readings {
            channels_a: sensed.channels,
            i_dq_a: o.i_dq_a,
            i_ref_a: i_ref,
            sin_cos: o.sin_cos,
            voltage_limited: o.voltage_limited,
        });
        let fault = match verdict {
            // Sensorless, the angle is the observer's: the check cannot
            // tell a wrong angle from wrong readings (design §27).
            Verdict::CurrentSense if self.sensorless.is_some() => Some(Fault::ObserverLostLock),
            Verdict::CurrentSense if self.angle_frozen() => Some(Fault::AngleSensorStuck),
            Verdict::CurrentSense => Some(Fault::CurrentSenseError),
            // A reading that stood while the angle turned the current.
            Verdict::Quiet if frozen => Some(Fault::CurrentSenseError),
            // (A coarse sensor, halls, legitimately stands still through a
            // reversal inside one of its wide counts: `angle_frozen` asks
            // it for four counts' worth.)
            Verdict::Quiet if self.sensorless.is_none() && self.still_while_emf_moves() => {
                Some(Fault::AngleSensorStuck)
            }
            Verdict::Quiet => None,
        };
        match fault {
            // Limp-home: the observer beside the sensor takes over.
            Some(Fault::AngleSensorStuck) if self.fallback_ready() => {
                self.take_over();
                self.model.reset();
                true
            }
            Some(f) => {
                self.supervisor.trip(f);
                self.model.reset();
                false
            }
            None => {
                self.model.record(&p, o.duties, sensed.v_bus_v);
                true
            }
        }
    }

    /// The slower back-up of the model check: the loop's tracking error
    /// against the supervisor's band, excused on the voltage limit when
    /// `limit_excuses` (the reference out of reach: back-EMF, or `L di/dt`
    /// while a large inductance slews) and while the angle reading looks
    /// frozen (the stuck check's to name). False when it trips.
    #[inline(always)]
    pub(super) fn currents_track(
        &mut self,
        out: Option<&CurrentLoopOutput>,
        i_ref: Dq,
        w_e_rad_s: f32,
        limit_excuses: bool,
    ) -> bool {
        let Some(o) = out else {
            return true;
        };
        let (ed, eq) = (i_ref.d - o.i_dq_a.d, i_ref.q - o.i_dq_a.q);
        let cpr = self.config.angle.sensor_counts_per_rev;
        let count_rad = if cpr > 0 {
            core::f32::consts::TAU / cpr as f32
        } else {
            0.01
        };
        let commanded_rad_s = match self.state.active {
            Command::Velocity { rad_s } => rad_s.abs(),
            _ => 0.0,
        };
        let pp = self.config.angle.pole_pairs.max(1) as f32;
        let tracked_rad_s = (w_e_rad_s / pp).abs();
        let speed = if commanded_rad_s > tracked_rad_s {
            commanded_rad_s
        } else {
            tracked_rad_s
        };
        let moved_rad = speed * self.config.current.ts_s * self.state.unchanged_periods as f32;
        let excused = (limit_excuses && o.voltage_limited) || moved_rad > 2.0 * count_rad;
        self.supervisor
            .check_tracking(ed * ed + eq * eq, excused)
            .is_none()
    }
}

/// The model check of a stage configuration: the current loop's motor and
/// period, the supervisor's tolerances with the angle sensor's resolution
/// added (a whole count for a fine sensor, half of one where the stage
/// interpolates a coarse one), and the bridge's dead time: the
/// tolerances' own, or where they know none (0) the one the current loop
/// compensates.
///
/// The bridge takes up to `4/3 V_bus t_d / T` off the voltage the duties
/// ask for and the duties carry it back (the compensation, design §31,
/// outside its band; the PI's integral inside it): a check that did not
/// know the dead time counted it as a voltage the motor did not follow.
/// At speed or current its envelope covers that; at standstill with a
/// current near zero (a speed loop holding a braked rotor) the envelope
/// shrinks to its noise floor, below the dead time's voltage, and the
/// slow check tripped `CurrentSenseError` on a healthy drive
/// (tests/tests/brake_to_standstill.rs). A board that compensates its
/// dead time has told the stage what it is; one that neither compensates
/// it nor states it in the tolerances (`supervisor.model.dead_time_s`)
/// still trips the same way: the cause is the bridge's dead time, not the
/// compensation. Every board's configuration states it (the firmware's
/// `config::cascade` does); the defaults of `CascadeConfig::for_motor`
/// (an ideal bridge) do not.
pub(super) fn model_check(c: &CurrentStageConfig) -> ModelCheck {
    let a = &c.angle;
    let count_e_rad = match a.sensor_counts_per_rev {
        0 => 0.0,
        n => core::f32::consts::TAU * a.pole_pairs as f32 / n as f32,
    };
    let mut tol = c.supervisor.model;
    // (Only a dead time the compensation acts on: positive, at most its
    // share of the period; a NaN tolerance stays NaN, which `sanitized`
    // makes 0 as before.)
    if tol.dead_time_s == 0.0 && c.current.dead_time.gains(c.current.ts_s).is_on() {
        tol.dead_time_s = c.current.dead_time.dead_time_s;
    }
    // An interpolated coarse sensor (halls) is within its half-count
    // window; a fine one within a count.
    tol.angle_e_rad += match a.interpolation_half_count() {
        Some(_) => 0.5 * count_e_rad,
        None => count_e_rad,
    };
    let coarse = a.interpolation_half_count().is_some();
    ModelCheck::new(c.current.motor, c.current.ts_s, tol, coarse)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::dead_time::DeadTimeCompensation;
    use crate::control::MotorParams;
    use crate::drive::cascade::CascadeConfig;

    fn config(dead_time: DeadTimeCompensation, model_dead_time_s: f32) -> CurrentStageConfig {
        let motor = MotorParams {
            pole_pairs: 7,
            r_ohm: 0.2,
            ld_h: 60e-6,
            lq_h: 60e-6,
            flux_linkage_wb: 0.005,
        };
        let mut c = CascadeConfig::for_motor(motor, 20_000.0, 10.0).current;
        c.current.dead_time = dead_time;
        c.supervisor.model.dead_time_s = model_dead_time_s;
        c
    }

    /// The check takes the dead time the current loop compensates where
    /// its tolerances know none; its own is kept; a compensation that is
    /// off (or a dead time it refuses) gives none; a NaN tolerance stays
    /// the 0 it always became.
    #[test]
    fn the_model_check_knows_the_dead_time_the_loop_compensates() {
        let dt = |c: &CurrentStageConfig| model_check(c).tolerances().dead_time_s;
        let board = DeadTimeCompensation::for_current_limit(200e-9, 10.0);
        assert_eq!(dt(&config(board, 0.0)), 200e-9);
        assert_eq!(dt(&config(board, 300e-9)), 300e-9);
        assert_eq!(dt(&config(DeadTimeCompensation::OFF, 0.0)), 0.0);
        assert_eq!(dt(&config(DeadTimeCompensation::OFF, 200e-9)), 200e-9);
        // A band of 0 leaves the compensation off: nothing in the duties.
        let no_band = DeadTimeCompensation {
            band_a: 0.0,
            ..board
        };
        assert_eq!(dt(&config(no_band, 0.0)), 0.0);
        // Microseconds given as nanoseconds (the compensation refuses it).
        let slip = DeadTimeCompensation::for_current_limit(200e-6, 10.0);
        assert_eq!(dt(&config(slip, 0.0)), 0.0);
        assert_eq!(dt(&config(board, f32::NAN)), 0.0);
        // A stage whose permit brings the compensation rebuilds its check.
        let mut stage = CurrentStage::new(config(DeadTimeCompensation::OFF, 0.0));
        assert_eq!(stage.model_check().tolerances().dead_time_s, 0.0);
        let c = config(board, 0.0);
        stage.set_calibration(&Calibrated::supplied(c.angle, c.current).unwrap());
        assert_eq!(stage.model_check().tolerances().dead_time_s, 200e-9);
    }
}
