//! The summary as Markdown (`summary.md`).

use super::*;

impl MissionSummary {
    /// The summary as Markdown.
    pub fn to_markdown(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "# Simulation: {}\n", self.motor);
        let _ = writeln!(
            s,
            "PWM {:.0} Hz; speed loop every {} periods, position loop every {}; {} periods ({:.3} s simulated) in {:.2} s wall time.\n",
            self.pwm_hz, self.dividers.0, self.dividers.1, self.periods, self.sim_time_s, self.wall_time_s
        );
        s.push_str("| figure | value |\n|---|---:|\n");
        let mut t = Table(s);
        self.identification_rows(&mut t);
        self.loop_rows(&mut t);
        self.motion_rows(&mut t);
        self.braking_rows(&mut t);
        self.field_weakening_rows(&mut t);
        self.smoothness_rows(&mut t);
        t.row(
            "model check: largest healthy residual / bound, disturbance / envelope",
            format!(
                "{:.2}, {:.2}",
                self.model_margin, self.model_disturbance_margin
            ),
        );
        t.row(
            "faults",
            if self.faults.is_empty() {
                "none".into()
            } else {
                self.faults.join(", ")
            },
        );
        let mut s = t.0;
        let fails = self.failures();
        let _ = writeln!(
            s,
            "\nResult: {}",
            if fails.is_empty() {
                "PASS".to_string()
            } else {
                format!("FAIL ({})", fails.join("; "))
            }
        );
        s
    }

    /// The calibration's rows: identified or restored, and the electrical zero.
    pub(super) fn identification_rows(&self, t: &mut Table) {
        if self.restored {
            t.row(
                "calibration",
                "restored from the stored configuration (no identification)".into(),
            );
        }
        match &self.identification {
            Some(id) => {
                t.row(
                    "identification time (offsets + identification)",
                    format!(
                        "{:.3} s + {:.2} s simulated ({:.2} s wall)",
                        id.offset_time_s, id.time_s, id.wall_time_s
                    ),
                );
                t.row(
                    "identified R / error",
                    format!("{:.4} ohm / {:+.2} %", id.r_ohm.0, id.r_ohm.1),
                );
                t.row(
                    "identified Ld / error",
                    format!("{:.2} uH / {:+.2} %", id.ld_h.0 * 1e6, id.ld_h.1),
                );
                t.row(
                    "identified Lq / error",
                    format!("{:.2} uH / {:+.2} %", id.lq_h.0 * 1e6, id.lq_h.1),
                );
                t.row(
                    "identified flux linkage / error",
                    id.flux_linkage_wb.map_or("not measured".into(), |(v, e)| {
                        format!("{:.3} mWb / {e:+.2} %", v * 1e3)
                    }),
                );
                if let Some(mf) = &id.mechanics {
                    t.row(
                        "identified inertia / error",
                        format!(
                            "{:.4e} kg m^2 / {:+.2} %",
                            mf.inertia_kg_m2.0, mf.inertia_kg_m2.1
                        ),
                    );
                    t.row(
                        "identified friction (plant)",
                        format!(
                            "B {:.3e} N m s/rad, Fc {:.4} N m ({:.3e}, {:.4}); at {:.1} rad/s {:+.2} %, at {:.1} rad/s {:+.2} %",
                            mf.friction.0,
                            mf.friction.1,
                            mf.plant_friction.0,
                            mf.plant_friction.1,
                            mf.torque_at[0].0,
                            mf.torque_at[0].2,
                            mf.torque_at[1].0,
                            mf.torque_at[1].2
                        ),
                    );
                }
                t.row(
                    "pole pairs found (plant)",
                    format!("{} ({})", id.pole_pairs.0, id.pole_pairs.1),
                );
                let dir = |r: bool| if r { "reversed" } else { "forward" };
                t.row(
                    "sensor direction found (plant)",
                    format!("{} ({})", dir(id.reversed.0), dir(id.reversed.1)),
                );
            }
            None if self.restored => {}
            None => t.row(
                "identification",
                format!(
                    "FAILED: {} (mission run on the supplied calibration)",
                    self.identification_failure.as_deref().unwrap_or("?")
                ),
            ),
        }
        t.row(
            if self.restored {
                "stored electrical zero / error"
            } else {
                "identified electrical zero / error"
            },
            format!(
                "{:.2} deg / {:+.2} deg",
                self.align_found_deg, self.align_error_deg
            ),
        );
    }

    /// The loops' rows: current step, speed step, load step, speed and
    /// acceleration figures.
    pub(super) fn loop_rows(&self, t: &mut Table) {
        let opt_ms =
            |x: Option<f64>| x.map_or("did not settle".to_string(), |v| format!("{v:.1} ms"));
        t.row(
            "q-current step",
            format!(
                "{:.2} A{}",
                self.current_step_a,
                if self.current_step_magnitude {
                    " (figures of the true current's magnitude: hall-class sensor)"
                } else {
                    ""
                }
            ),
        );
        t.row(
            "q-current overshoot",
            format!("{:.2} %", self.current_overshoot_percent),
        );
        t.row(
            "q-current 2 % settling",
            self.current_settling_periods
                .map_or("did not settle".into(), |n| format!("{n} PWM periods")),
        );
        t.row(
            "d-current peak during the q step",
            format!("{:.3} A", self.current_id_peak_a),
        );
        t.row("speed step", format!("{:.1} rad/s", self.speed_step_rad_s));
        t.row(
            "speed overshoot",
            format!("{:.2} %", self.speed_overshoot_percent),
        );
        t.row("speed 2 % settling", opt_ms(self.speed_settling_ms));
        t.row(
            "speed after ramp",
            format!("{:.1} rad/s", self.speed_high_rad_s),
        );
        t.row("load step", format!("{:.4} N m", self.load_step_nm));
        t.row(
            "speed dip after load step",
            format!("{:.3} rad/s", self.load_dip_rad_s),
        );
        t.row(
            "steady speed error with load",
            format!("{:+.4} rad/s", self.load_steady_error_rad_s),
        );
        t.row("recovery into +-2 %", opt_ms(self.load_recovery_ms));
        let sp = &self.speed;
        t.row(
            "speed rise after load release",
            format!("{:.3} rad/s", sp.release_rise_rad_s),
        );
        t.row(
            "recovery into +-2 % after release",
            opt_ms(sp.release_recovery_ms),
        );
        t.row(
            "speed-estimate error while the step accelerates",
            format!(
                "{:.3} rad/s ({:.2} % of the step; peak acceleration {:.0} rad/s^2)",
                sp.estimate_error.0, sp.estimate_error.1, sp.step_peak_acceleration_rad_s2
            ),
        );
        t.row(
            "current-limited speed step",
            format!(
                "{:.1} rad/s, current limit {:.2} A (q current on it for {:.1} ms, peak acceleration {:.0} rad/s^2)",
                sp.sat_step_rad_s, sp.sat_limit_a, sp.sat_limited_ms, sp.sat_peak_acceleration_rad_s2
            ),
        );
        t.row(
            "current-limited step overshoot",
            format!("{:.2} %", sp.sat_overshoot_percent),
        );
        t.row(
            "current-limited step 2 % settling",
            opt_ms(sp.sat_settling_ms),
        );
        t.row(
            "speed-estimate error while it accelerates",
            format!(
                "{:.3} rad/s ({:.2} % of the step)",
                sp.sat_estimate_error.0, sp.sat_estimate_error.1
            ),
        );
        let (e, a) = sp.fastest_estimate_error();
        t.row(
            "speed-estimate error at the mission's fastest acceleration",
            format!("{e:.2} % of its step ({a:.0} rad/s^2)"),
        );
    }

    /// The position move and impedance rows.
    pub(super) fn motion_rows(&self, t: &mut Table) {
        let opt_ms =
            |x: Option<f64>| x.map_or("did not settle".to_string(), |v| format!("{v:.1} ms"));
        t.row("position move", format!("{:.4} rad", self.move_rad));
        t.row("position 2 % settling", opt_ms(self.position_settling_ms));
        t.row(
            "position final error",
            format!(
                "{:+.5} rad ({:.2} encoder counts)",
                self.position_final_error_rad,
                self.position_final_error_rad / self.encoder_count_rad
            ),
        );
        if let Some(z) = &self.impedance {
            t.row("impedance (design §21)", z.describe());
        }
    }

    /// The braking segment's rows.
    pub(super) fn braking_rows(&self, t: &mut Table) {
        if let Some(b) = &self.braking {
            t.row(
                "braking: DC link",
                format!(
                    "{:.1} uF ({}), {:.1} V supply that cannot sink current; over-voltage threshold {:.2} V, regen ramp {:.2} -> {:.2} V",
                    b.c_f * 1e6,
                    b.link,
                    b.v_source_v,
                    b.over_voltage_v,
                    b.regen_v.0,
                    b.regen_v.1
                ),
            );
            let how = |st: &StopFigures| {
                if st.ramp_s > 0.0 {
                    format!("ramp to 0 in {:.0} ms", st.ramp_s * 1e3)
                } else {
                    "hard stop".to_string()
                }
            };
            for (name, stop) in [
                (
                    format!("braking into the capacitor ({})", how(&b.capacitor)),
                    &b.capacitor,
                ),
                (
                    format!(
                        "braking with a {:.3} ohm brake resistor ({})",
                        b.resistor_ohm,
                        how(&b.resistor)
                    ),
                    &b.resistor,
                ),
            ] {
                t.row(
                    &name,
                    format!(
                        "from {:.1} rad/s: peak bus {:.2} V, stop {}; kinetic {:.3} J -> capacitor {:.3} J, resistor {:.3} J, copper {:.3} J, friction {:.3} J (supply {:+.3} J); regen limit active {:.1} ms, chopper on {:.1} ms",
                        stop.from_rad_s,
                        stop.peak_bus_v,
                        stop.stop_s.map_or(
                            format!(
                                "{:.1} rad/s after {:.0} ms (not stopped)",
                                stop.end_rad_s,
                                BRAKE_STOP_S * 1e3
                            ),
                            |t| format!("{:.1} ms", t * 1e3)
                        ),
                        stop.kinetic_j,
                        stop.capacitor_j,
                        stop.resistor_j,
                        stop.copper_j,
                        stop.friction_j,
                        stop.source_j,
                        stop.regen_limited_periods as f64 / self.pwm_hz as f64 * 1e3,
                        stop.brake_periods as f64 / self.pwm_hz as f64 * 1e3,
                    ),
                );
            }
        }
    }
}

impl MissionSummary {
    /// The field-weakening segment's rows (design §30).
    pub(super) fn field_weakening_rows(&self, t: &mut Table) {
        const NAME: &str = "field weakening (design §30)";
        let w = match &self.field_weakening {
            None => return,
            Some(FieldWeakeningSegment::Skipped(why)) => {
                t.row(NAME, format!("skipped: {why}"));
                return;
            }
            Some(FieldWeakeningSegment::Ran(w)) => w,
        };
        t.row(
            NAME,
            format!(
                "turned on, from rest to the top speed, held, a load step there, back to rest, turned off: {:.3} s simulated ({:.2} s wall)",
                w.time_s, w.wall_time_s
            ),
        );
        t.row(
            "field weakening: base speed (drive's model, no load)",
            format!("{:.1} rad/s", w.base_rad_s),
        );
        let model = if w.model_top_rad_s.is_finite() {
            format!("{:.1} rad/s", w.model_top_rad_s)
        } else {
            "unbounded (the d-current bound reaches psi / Ld)".into()
        };
        t.row(
            "field weakening: top speed commanded / reached",
            format!(
                "{:.1} / {:.1} rad/s = {:.2} x base{} (the model's top speed {model})",
                w.commanded_rad_s,
                w.reached_rad_s,
                w.ratio(),
                w.ratio_goal
                    .map_or(String::new(), |g| format!(", goal {g:.1} x")),
            ),
        );
        t.row(
            "field weakening: load step at the top speed",
            format!(
                "{:.3} N m: {:.1} rad/s at its end; back at rest {:.2} rad/s",
                w.load_nm, w.loaded_rad_s, w.end_rad_s
            ),
        );
        t.row(
            "field weakening: most negative d current",
            format!("{:.2} A (bound {:.2} A)", w.min_id_a, -w.max_id_a),
        );
        t.row(
            "field weakening: peak phase current / limit",
            format!("{:.2} A / {:.2} A", w.peak_phase_a, w.limit_a),
        );
        t.row(
            "field weakening: peak bus voltage",
            format!("{:.2} V", w.peak_bus_v),
        );
        t.row(
            "field weakening: faults",
            if w.faults.is_empty() {
                "none".into()
            } else {
                w.faults.join(", ")
            },
        );
    }
}

/// The summary's table of figures (Markdown), row by row.
pub(super) struct Table(String);

impl Table {
    pub(super) fn row(&mut self, k: &str, v: String) {
        let _ = writeln!(self.0, "| {k} | {v} |");
    }
}
