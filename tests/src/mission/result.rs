//! [`MissionResult`]: the trace, its segments and the files written from
//! them (CSV, SVG, summary).

use super::*;

/// A named stretch of the mission (trace rows `start..end`).
#[derive(Clone, Debug, PartialEq)]
pub struct Segment {
    /// Name.
    pub name: &'static str,
    /// First row.
    pub start: usize,
    /// One past the last row.
    pub end: usize,
}

/// A finished mission.
#[derive(Clone, Debug)]
pub struct MissionResult {
    /// The full-rate trace (one row per PWM period).
    pub trace: Trace,
    /// Its segments.
    pub segments: Vec<Segment>,
    /// The measured figures.
    pub summary: MissionSummary,
    /// The configuration the mission ended with (identified or restored),
    /// as the drive would save it.
    pub record: foc_store::DriveRecord,
    /// The low-speed smoothness segment's waveforms, before and after,
    /// against the share of their turn (None: it did not run, or a
    /// calibration failed).
    pub smoothness_trace: Option<Trace>,
}

impl MissionResult {
    /// The segment called `name`.
    pub fn segment(&self, name: &str) -> Option<&Segment> {
        self.segments.iter().find(|s| s.name == name)
    }

    /// Rows `seg` of the trace as a new trace (time from the segment start).
    pub fn slice(&self, seg: &Segment) -> Trace {
        let names: Vec<&str> = self.trace.names().iter().map(String::as_str).collect();
        let mut t = Trace::new(&names);
        let cols: Vec<&[f64]> = names.iter().filter_map(|n| self.trace.column(n)).collect();
        let t0 = self.trace.time_s().get(seg.start).copied().unwrap_or(0.0);
        for r in seg.start..seg.end.min(self.trace.len()) {
            let row: Vec<f64> = cols.iter().map(|c| c[r]).collect();
            t.push(self.trace.time_s()[r] - t0, &row);
        }
        t
    }

    /// Every `k`-th row, at most `max_rows` rows (for plots of long runs).
    pub fn decimated(&self, max_rows: usize) -> Trace {
        decimate(&self.trace, max_rows)
    }

    /// Rows `start..end` of the trace, times unchanged (simulation time).
    pub fn rows(&self, start: usize, end: usize) -> Trace {
        let names: Vec<&str> = self.trace.names().iter().map(String::as_str).collect();
        let mut t = Trace::new(&names);
        let cols: Vec<&[f64]> = names.iter().filter_map(|n| self.trace.column(n)).collect();
        for r in start..end.min(self.trace.len()) {
            let row: Vec<f64> = cols.iter().map(|c| c[r]).collect();
            t.push(self.trace.time_s()[r], &row);
        }
        t
    }

    /// Write into `dir`: `identification.csv` and `identification.svg`
    /// (the identify segment, decimated to at most 20 000 and 4000 rows:
    /// it is most of the simulated time), `mission.csv` (every PWM period
    /// from the end of the identification on, simulation time),
    /// `mission.svg` (the same, decimated), `current_step.csv`,
    /// `current_step.svg`, `speed.svg`, `position.svg`, `braking.svg`,
    /// `field_weakening.svg` and `smoothness.svg` (where those segments
    /// ran) and `summary.md`.
    /// Returns the paths.
    pub fn write(&self, dir: &Path) -> std::io::Result<Vec<std::path::PathBuf>> {
        std::fs::create_dir_all(dir)?;
        let mut out = Vec::new();
        self.write_identification(dir, &mut out)?;
        self.write_mission(dir, &mut out)?;
        self.write_current_step(dir, &mut out)?;
        self.write_speed_and_position(dir, &mut out)?;
        self.write_braking(dir, &mut out)?;
        self.write_field_weakening(dir, &mut out)?;
        self.write_smoothness(dir, &mut out)?;
        let p = dir.join("summary.md");
        std::fs::write(&p, self.summary.to_markdown())?;
        out.push(p);
        Ok(out)
    }

    /// `identification.csv` and `identification.svg`.
    pub(super) fn write_identification(
        &self,
        dir: &Path,
        out: &mut Vec<std::path::PathBuf>,
    ) -> std::io::Result<()> {
        if let Some(seg) = self.segment("identify") {
            let t = self.rows(seg.start, seg.end);
            let p = dir.join("identification.csv");
            decimate(&t, 20_000).write_csv(&p)?;
            out.push(p);
            let k = t.len().div_ceil(4000).max(1);
            let p = dir.join("identification.svg");
            crate::report::plot_svg(
                &p,
                &format!(
                    "Identification: {} (offsets, R, L, alignment sweeps, flux; every {k}-th period)",
                    self.summary.motor
                ),
                &decimate(&t, 4000),
                &[
                    Panel::new("d current", "A", &["id_ref_a", "id_a"]),
                    Panel::new("q current", "A", &["iq_ref_a", "iq_a"]),
                    Panel::new("dq voltages", "V", &["vd_v", "vq_v"]),
                    Panel::new(
                        "speed",
                        "rad/s",
                        &["speed_ref_rad_s", "speed_rad_s", "speed_est_rad_s"],
                    ),
                    Panel::new(
                        "position (rotor, mechanical, true, bench's encoder frame)",
                        "rad",
                        &["position_rad"],
                    ),
                    mode_panel(),
                    Panel::new("bridge on (0 off, 1 on)", "flag", &["bridge_on"]),
                ],
            )?;
            out.push(p);
        }
        Ok(())
    }

    /// `mission.csv` and `mission.svg`: from the end of the identification on.
    pub(super) fn write_mission(
        &self,
        dir: &Path,
        out: &mut Vec<std::path::PathBuf>,
    ) -> std::io::Result<()> {
        let id_end = self.segment("identify").map_or(0, |s| s.end);
        let closed = self.rows(id_end, self.trace.len());
        let p = dir.join("mission.csv");
        closed.write_csv(&p)?;
        out.push(p);
        let (closed_plot, true_in_drive) =
            with_true_position_in_drive_frame(decimate(&closed, 4000));
        let mission_panels = [
            Panel::new("q current", "A", &["iq_ref_a", "iq_a"]),
            Panel::new("d current", "A", &["id_ref_a", "id_a"]),
            Panel::new("dq voltages", "V", &["vd_v", "vq_v"]),
            Panel::new(
                "speed",
                "rad/s",
                &["speed_ref_rad_s", "speed_rad_s", "speed_est_rad_s"],
            ),
            Panel::new(POSITION_PANEL, "rad", &["position_ref_rad", &true_in_drive]),
            Panel::new("PWM duty", "1", &["duty_a", "duty_b", "duty_c"]),
            Panel::new("bus voltage", "V", &["v_bus_v"]),
            Panel::new("load torque", "N m", &["load_nm"]),
            mode_panel(),
        ];
        let p = dir.join("mission.svg");
        crate::report::plot_svg(
            &p,
            &format!(
                "Mission after the identification: {} (every {}-th period)",
                self.summary.motor,
                closed.len().div_ceil(4000).max(1)
            ),
            &closed_plot,
            &mission_panels,
        )?;
        out.push(p);
        Ok(())
    }

    /// `current_step.csv` and `current_step.svg`: the step, zoomed.
    pub(super) fn write_current_step(
        &self,
        dir: &Path,
        out: &mut Vec<std::path::PathBuf>,
    ) -> std::io::Result<()> {
        if let Some(seg) = self.segment("current step") {
            let zoom = Segment {
                name: "zoom",
                start: seg.start.saturating_sub(5),
                end: (seg.start + 80).min(seg.end),
            };
            let t = self.slice(&zoom);
            let p = dir.join("current_step.csv");
            t.write_csv(&p)?;
            out.push(p);
            let p = dir.join("current_step.svg");
            // The first row with the new reference.
            let step_at = t.time_s().get(seg.start - zoom.start).copied();
            crate::report::plot_svg_marked(
                &p,
                &format!(
                    "q-current step, rotor locked: {} ({:.2} % overshoot)",
                    self.summary.motor, self.summary.current_overshoot_percent
                ),
                &t,
                &[
                    Panel::new("q current", "A", &["iq_ref_a", "iq_a", "iq_true_a"]),
                    Panel::new("d current", "A", &["id_ref_a", "id_a"]),
                    Panel::new("dq voltages", "V", &["vd_v", "vq_v"]),
                ],
                "time [s]",
                step_at.map(|t| (t, "step")),
            )?;
            out.push(p);
        }
        Ok(())
    }

    /// `speed.svg` (step, ramp and load step) and `position.svg`.
    pub(super) fn write_speed_and_position(
        &self,
        dir: &Path,
        out: &mut Vec<std::path::PathBuf>,
    ) -> std::io::Result<()> {
        for (name, file, panels) in [
            (
                "speed step",
                "speed",
                vec![
                    Panel::new(
                        "speed",
                        "rad/s",
                        &["speed_ref_rad_s", "speed_rad_s", "speed_est_rad_s"],
                    ),
                    Panel::new("q current", "A", &["iq_ref_a", "iq_a"]),
                    Panel::new("load torque", "N m", &["load_nm"]),
                ],
            ),
            (
                "position move",
                "position",
                vec![
                    Panel::new(
                        POSITION_PANEL,
                        "rad",
                        &["position_ref_rad", "position_est_rad", TRUE_IN_DRIVE],
                    ),
                    Panel::new("speed", "rad/s", &["speed_ref_rad_s", "speed_rad_s"]),
                    Panel::new("q current", "A", &["iq_ref_a", "iq_a"]),
                ],
            ),
        ] {
            if let Some(seg) = self.segment(name) {
                // The speed plot covers step, ramp and load step.
                let end = if name == "speed step" {
                    self.segment("load step").map_or(seg.end, |s| s.end)
                } else {
                    seg.end
                };
                let whole = Segment {
                    name,
                    start: seg.start,
                    end,
                };
                let (dec, true_in_drive) =
                    with_true_position_in_drive_frame(decimate(&self.slice(&whole), 4000));
                let panels: Vec<Panel> = panels
                    .into_iter()
                    .map(|mut p| {
                        for s in &mut p.signals {
                            if s == TRUE_IN_DRIVE {
                                s.clone_from(&true_in_drive);
                            }
                        }
                        p
                    })
                    .collect();
                let p = dir.join(format!("{file}.svg"));
                crate::report::plot_svg(
                    &p,
                    &format!("{name}: {}", self.summary.motor),
                    &dec,
                    &panels,
                )?;
                out.push(p);
            }
        }
        Ok(())
    }

    /// `braking.svg`: both braking segments.
    pub(super) fn write_braking(
        &self,
        dir: &Path,
        out: &mut Vec<std::path::PathBuf>,
    ) -> std::io::Result<()> {
        if let (Some(a), Some(b)) = (self.segment("braking"), self.segment("braking, resistor")) {
            let whole = Segment {
                name: "braking",
                start: a.start,
                end: b.end,
            };
            let p = dir.join("braking.svg");
            crate::report::plot_svg(
                &p,
                &format!(
                    "Braking into a supply that cannot sink current (capacitor alone, then a brake resistor): {}",
                    self.summary.motor
                ),
                &decimate(&self.slice(&whole), 4000),
                &[
                    Panel::new("speed", "rad/s", &["speed_ref_rad_s", "speed_rad_s"]),
                    Panel::new("bus voltage", "V", &["v_bus_v"]),
                    Panel::new("q current", "A", &["iq_ref_a", "iq_a"]),
                ],
            )?;
            out.push(p);
        }
        Ok(())
    }
}

impl MissionResult {
    /// `field_weakening.svg`: the field-weakening segment (design §30).
    pub(super) fn write_field_weakening(
        &self,
        dir: &Path,
        out: &mut Vec<std::path::PathBuf>,
    ) -> std::io::Result<()> {
        let (Some(seg), Some(FieldWeakeningSegment::Ran(w))) = (
            self.segment("field weakening"),
            self.summary.field_weakening.as_ref(),
        ) else {
            return Ok(());
        };
        let p = dir.join("field_weakening.svg");
        crate::report::plot_svg(
            &p,
            &format!(
                "Field weakening: {} (top speed {:.1} rad/s = {:.2} x base, a {:.3} N m load step there)",
                self.summary.motor,
                w.commanded_rad_s,
                w.ratio(),
                w.load_nm
            ),
            &decimate(&self.slice(seg), 4000),
            &[
                Panel::new("speed", "rad/s", &["speed_ref_rad_s", "speed_rad_s"]),
                Panel::new("d current", "A", &["id_ref_a", "id_a"]),
                Panel::new("q current", "A", &["iq_ref_a", "iq_a"]),
                Panel::new("dq voltages", "V", &["vd_v", "vq_v"]),
                Panel::new("load torque", "N m", &["load_nm"]),
            ],
        )?;
        out.push(p);
        Ok(())
    }
}

/// Title of the position panels: the reference, the drive's estimate and
/// the plant's true position, all in the drive's frame.
pub(super) const POSITION_PANEL: &str = "position (rotor, mechanical, drive's frame)";

/// Stands for the true position's column in the drive's frame in a panel
/// list (replaced by [`with_true_position_in_drive_frame`]'s name).
pub(super) const TRUE_IN_DRIVE: &str = "<true position in the drive's frame>";

/// The drive's mode code as its own panel, the codes spelled out.
pub(super) fn mode_panel() -> Panel {
    let codes: Vec<String> = [
        (Mode::Disabled, "disabled"),
        (Mode::Torque, "torque"),
        (Mode::Velocity, "velocity"),
        (Mode::Position, "position"),
        (Mode::OpenLoop, "open loop"),
        (Mode::Impedance, "impedance"),
    ]
    .iter()
    .map(|(m, name)| format!("{} {name}", *m as u8))
    .collect();
    Panel::new(
        &format!("drive mode ({})", codes.join(", ")),
        "code",
        &["mode"],
    )
}

/// Whole turns `k` with `position_est_rad = position_rad + k 2 pi` over most
/// rows of `trace` (0 without rows that have both).
///
/// The two columns are in different frames: `position_rad` is the plant's
/// true position in the encoder's frame, unwrapped since the simulation
/// started ([`Sim::true_position_rad`]); the drive's position (its
/// estimate `position_est_rad`, its reference `position_ref_rad`) counts
/// turns from the encoder's single-turn reading (0..2 pi) where its angle
/// tracker last restarted (reset, start-up, calibration). So they differ
/// by whole turns, fixed between restarts: after the default mission's
/// identification by -1 turn (6.28 rad).
pub fn drive_frame_turns(trace: &Trace) -> i64 {
    let mut counts: Vec<(i64, usize)> = Vec::new();
    for (t, e) in col(trace, "position_rad")
        .iter()
        .zip(col(trace, "position_est_rad"))
    {
        let k = ((e - t) / std::f64::consts::TAU).round();
        if !k.is_finite() {
            continue;
        }
        let k = k as i64;
        match counts.iter_mut().find(|(kk, _)| *kk == k) {
            Some((_, n)) => *n += 1,
            None => counts.push((k, 1)),
        }
    }
    counts.iter().max_by_key(|(_, n)| *n).map_or(0, |(k, _)| *k)
}

/// `trace` with the true position shifted by [`drive_frame_turns`] whole
/// turns into the drive's frame, and the name of that column
/// (`position_rad` itself when no shift is needed, else e.g.
/// `position_rad - 1 turn`), so that a plot shows the reference, the
/// estimate and the true position in one frame.
pub fn with_true_position_in_drive_frame(trace: Trace) -> (Trace, String) {
    let k = drive_frame_turns(&trace);
    if k == 0 {
        return (trace, "position_rad".into());
    }
    let shift = k as f64 * std::f64::consts::TAU;
    let values: Vec<f64> = col(&trace, "position_rad")
        .iter()
        .map(|p| p + shift)
        .collect();
    let name = format!(
        "position_rad {} {} turn{}",
        if k < 0 { '-' } else { '+' },
        k.unsigned_abs(),
        if k.unsigned_abs() == 1 { "" } else { "s" }
    );
    (trace.with_column(&name, values), name)
}

/// Every `k`-th row of `trace`, at most `max_rows` rows.
pub fn decimate(trace: &Trace, max_rows: usize) -> Trace {
    let k = trace.len().div_ceil(max_rows.max(1)).max(1);
    let names: Vec<&str> = trace.names().iter().map(String::as_str).collect();
    let cols: Vec<&[f64]> = names.iter().filter_map(|n| trace.column(n)).collect();
    let mut t = Trace::new(&names);
    for r in (0..trace.len()).step_by(k) {
        let row: Vec<f64> = cols.iter().map(|c| c[r]).collect();
        t.push(trace.time_s()[r], &row);
    }
    t
}
