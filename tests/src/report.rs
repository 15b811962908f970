//! Report writers: CSV traces, stacked SVG plots, dynamometer reports.
//!
//! ```no_run
//! use foc_bench::report::{Trace, Panel, plot_svg};
//! let mut t = Trace::new(&["iq_ref_a", "iq_a"]);
//! t.push(0.0, &[1.0, 0.0]);
//! t.push(1e-4, &[1.0, 0.6]);
//! t.write_csv("out/trace.csv").unwrap();
//! plot_svg("out/trace.svg", "current step", &t, &[Panel::new("q current", "A", &["iq_ref_a", "iq_a"])]).unwrap();
//! ```

use std::fmt::Write as _;
use std::io;
use std::path::{Path, PathBuf};

fn other(e: impl std::fmt::Display) -> io::Error {
    io::Error::other(e.to_string())
}

/// Time series: a time column \[s\] and named signal columns.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trace {
    names: Vec<String>,
    time_s: Vec<f64>,
    columns: Vec<Vec<f64>>,
}

impl Trace {
    /// Empty trace with these column names (units in the names: `iq_a`, `speed_rad_s`).
    pub fn new(names: &[&str]) -> Self {
        Self {
            names: names.iter().map(|s| s.to_string()).collect(),
            time_s: Vec::new(),
            columns: vec![Vec::new(); names.len()],
        }
    }
    /// Append one row; missing values are NaN, extra ones ignored.
    pub fn push(&mut self, time_s: f64, values: &[f64]) {
        self.time_s.push(time_s);
        for (k, c) in self.columns.iter_mut().enumerate() {
            c.push(values.get(k).copied().unwrap_or(f64::NAN));
        }
    }
    /// Column names.
    pub fn names(&self) -> &[String] {
        &self.names
    }
    /// Time column \[s\].
    pub fn time_s(&self) -> &[f64] {
        &self.time_s
    }
    /// A column by name.
    pub fn column(&self, name: &str) -> Option<&[f64]> {
        let i = self.names.iter().position(|n| n == name)?;
        self.columns.get(i).map(|c| c.as_slice())
    }
    /// This trace with one more column (`values` cut or padded with NaN to
    /// the number of rows), e.g. a signal converted into another frame for
    /// a plot.
    pub fn with_column(mut self, name: &str, mut values: Vec<f64>) -> Self {
        values.resize(self.time_s.len(), f64::NAN);
        self.names.push(name.to_string());
        self.columns.push(values);
        self
    }
    /// Number of rows.
    pub fn len(&self) -> usize {
        self.time_s.len()
    }
    /// True without rows.
    pub fn is_empty(&self) -> bool {
        self.time_s.is_empty()
    }

    /// CSV text: header `time_s,<names>`, one row per sample.
    pub fn to_csv(&self) -> String {
        let mut s = String::from("time_s");
        for n in &self.names {
            s.push(',');
            s.push_str(n);
        }
        s.push('\n');
        for (r, t) in self.time_s.iter().enumerate() {
            let _ = write!(s, "{t}");
            for c in &self.columns {
                let _ = write!(s, ",{}", c[r]);
            }
            s.push('\n');
        }
        s
    }
    /// Write the CSV (creating parent directories).
    pub fn write_csv(&self, path: impl AsRef<Path>) -> io::Result<()> {
        write_file(path.as_ref(), &self.to_csv())
    }
    /// Parse CSV written by [`Trace::to_csv`].
    pub fn from_csv(text: &str) -> io::Result<Self> {
        let mut lines = text.lines();
        let header = lines.next().ok_or_else(|| other("empty CSV"))?;
        let mut cols = header.split(',');
        if cols.next() != Some("time_s") {
            return Err(other("first column must be time_s"));
        }
        let names: Vec<&str> = cols.collect();
        let mut t = Trace::new(&names);
        for (i, line) in lines.enumerate() {
            let vals: Result<Vec<f64>, _> = line.split(',').map(str::parse::<f64>).collect();
            let vals = vals.map_err(|e| other(format!("row {}: {e}", i + 1)))?;
            if vals.len() != names.len() + 1 {
                return Err(other(format!("row {}: {} fields", i + 1, vals.len())));
            }
            t.push(vals[0], &vals[1..]);
        }
        Ok(t)
    }
}

fn write_file(path: &Path, text: &str) -> io::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(path, text)
}

/// One panel of a stacked plot: signals (trace column names) sharing a y axis.
#[derive(Clone, Debug, PartialEq)]
pub struct Panel {
    /// Panel title.
    pub title: String,
    /// Unit of the y axis.
    pub unit: String,
    /// Column names drawn in this panel (e.g. a reference and a measurement).
    pub signals: Vec<String>,
}

impl Panel {
    /// New panel.
    pub fn new(title: &str, unit: &str, signals: &[&str]) -> Self {
        Self {
            title: title.into(),
            unit: unit.into(),
            signals: signals.iter().map(|s| s.to_string()).collect(),
        }
    }
}

impl Panel {
    /// The axis label: the title with the unit in brackets after its first
    /// word group, a frame in parentheses kept after it:
    /// `("position (rotor, mechanical)", "rad")` gives
    /// `position [rad] (rotor, mechanical)`.
    pub fn y_label(&self) -> String {
        match self.title.find(" (") {
            Some(i) => format!("{} [{}]{}", &self.title[..i], self.unit, &self.title[i..]),
            None => format!("{} [{}]", self.title, self.unit),
        }
    }
}

/// SVG with one panel per [`Panel`], stacked, all against time \[s\], drawn
/// by [`foc_plot`] (axes fitted to the data: time from the first to the
/// last row, each panel's y from its minimum to its maximum with a small
/// margin, NaN rows left as gaps). Unknown signal names are an error.
pub fn plot_svg(
    path: impl AsRef<Path>,
    title: &str,
    trace: &Trace,
    panels: &[Panel],
) -> io::Result<()> {
    plot_svg_marked(path, title, trace, panels, "time [s]", None)
}

/// As [`plot_svg`], with the trace's first column (its "time" column)
/// standing for another quantity, described by `x_desc` (e.g. `torque [N m]`).
pub fn plot_svg_against(
    path: impl AsRef<Path>,
    title: &str,
    trace: &Trace,
    panels: &[Panel],
    x_desc: &str,
) -> io::Result<()> {
    plot_svg_marked(path, title, trace, panels, x_desc, None)
}

/// As [`plot_svg_against`], with an optional dashed vertical line at
/// `marker.0` (same unit as the x axis) labelled `marker.1` (e.g. the
/// instant a step is commanded).
pub fn plot_svg_marked(
    path: impl AsRef<Path>,
    title: &str,
    trace: &Trace,
    panels: &[Panel],
    x_desc: &str,
    marker: Option<(f64, &str)>,
) -> io::Result<()> {
    plot_min_spans(path, title, trace, panels, x_desc, marker, &[])
}

/// As [`plot_svg_marked`], panel `k`'s y axis spanning at least
/// `y_min[k]` ([`foc_plot::MinSpan`]; none for panels beyond the slice).
fn plot_min_spans(
    path: impl AsRef<Path>,
    title: &str,
    trace: &Trace,
    panels: &[Panel],
    x_desc: &str,
    marker: Option<(f64, &str)>,
    y_min: &[foc_plot::MinSpan],
) -> io::Result<()> {
    for p in panels {
        for s in &p.signals {
            if trace.column(s).is_none() {
                return Err(other(format!("unknown signal `{s}`")));
            }
        }
    }
    let labels: Vec<String> = panels.iter().map(Panel::y_label).collect();
    let fig = foc_plot::Figure {
        title,
        x_label: x_desc,
        panels: panels
            .iter()
            .zip(&labels)
            .map(|(p, label)| foc_plot::Panel {
                y_label: label,
                series: p
                    .signals
                    .iter()
                    .map(|s| foc_plot::Series {
                        name: s,
                        x: trace.time_s(),
                        y: trace.column(s).unwrap_or(&[]),
                    })
                    .collect(),
            })
            .collect(),
        x_marker: marker,
    };
    foc_plot::write_svg_min_spans(path.as_ref(), &fig, y_min)
}

/// Header of a dynamometer "Performance Curve Report" (design §12).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DynoHeader {
    /// Project number.
    pub project_no: String,
    /// Report number.
    pub report_no: String,
    /// Motor model (e.g. "M153").
    pub motor_model: String,
    /// Test motor number.
    pub test_motor_no: String,
    /// Report date (ISO 8601).
    pub report_date: String,
    /// Tested by.
    pub tested_by: String,
    /// Approved by.
    pub approved_by: String,
}

impl DynoHeader {
    fn fields(&self) -> [(&'static str, &str); 7] {
        [
            ("Project No.", &self.project_no),
            ("Report No.", &self.report_no),
            ("Motor Model", &self.motor_model),
            ("Test Motor No.", &self.test_motor_no),
            ("Report Date", &self.report_date),
            ("Tested By", &self.tested_by),
            ("Approved By", &self.approved_by),
        ]
    }
}

/// What a dynamometer run swept (design §12): it names the report (the
/// titles of its files) and sets the plots' x axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DynoSweep {
    /// Load-torque steps at a fixed speed command (x axis: torque).
    Load,
    /// Supply-voltage steps with a speed command proportional to the
    /// voltage (x axis: supply voltage).
    Voltage,
    /// Overhauling-load steps at a fixed speed command: the drive brakes
    /// and regenerates (x axis: torque, negative).
    Regen,
}

impl DynoSweep {
    /// `load`, `voltage` or `regen` (the files' stem: `dyno-<name>`).
    pub fn name(self) -> &'static str {
        match self {
            DynoSweep::Load => "load",
            DynoSweep::Voltage => "voltage",
            DynoSweep::Regen => "regen",
        }
    }

    /// The words of the reports' titles: `load sweep`, `supply-voltage
    /// sweep`, `regen sweep`.
    pub fn title(self) -> &'static str {
        match self {
            DynoSweep::Load => "load sweep",
            DynoSweep::Voltage => "supply-voltage sweep",
            DynoSweep::Regen => "regen sweep",
        }
    }

    /// What the sweep steps, one sentence (the Markdown's "Sweep" row).
    pub fn describe(self) -> &'static str {
        match self {
            DynoSweep::Load => "load torque stepped from 0 to the rated torque at a fixed speed command",
            DynoSweep::Voltage => {
                "supply voltage stepped from nominal down to a tenth of it, the speed command proportional to it, 30 % of the rated torque as load"
            }
            DynoSweep::Regen => {
                "an overhauling load (it drives the shaft forwards) stepped from 0 to the rated torque at a fixed speed command: the drive brakes and returns energy (generator points, negative powers)"
            }
        }
    }

    /// The plots' x axis: its description and a row's value.
    fn x_axis(self) -> (&'static str, fn(&DynoRow) -> f64) {
        match self {
            DynoSweep::Load | DynoSweep::Regen => ("torque [N m]", |r| r.torque_nm),
            DynoSweep::Voltage => ("supply voltage [V]", |r| r.supply_voltage_v),
        }
    }
}

/// One operating point of a dynamometer run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DynoRow {
    /// Supply voltage \[V\].
    pub supply_voltage_v: f64,
    /// Supply current \[A\] (the inverter's DC input).
    pub supply_current_a: f64,
    /// Input power \[W\].
    pub input_power_w: f64,
    /// Speed \[rpm\].
    pub speed_rpm: f64,
    /// Shaft torque [N m].
    pub torque_nm: f64,
    /// Mechanical output power \[W\].
    pub mechanical_power_w: f64,
    /// Efficiency [%]: mechanical / input while motoring; electrical out /
    /// mechanical in while generating (both powers negative).
    pub efficiency_percent: f64,
    /// The speed command \[rpm\] (`None`: not known; the column is left
    /// out of the report when no row has it, as for every `Option` here).
    pub speed_command_rpm: Option<f64>,
    /// Phase current \[A\], **peak**: the amplitude of the phase currents,
    /// `|i_dq|` with the amplitude-invariant Clarke transform (the motor
    /// file's convention; rms is peak / sqrt 2), averaged over the window.
    pub phase_current_a: Option<f64>,
    /// Modulation index `sqrt(3) |v| / v_bus` = `|v_dq| / (v_bus /
    /// sqrt(3))` (foc-core's `SvpwmOutput::modulation_index`): 1 on the
    /// circle inscribed in the hexagon (the end of the linear range),
    /// `2 / sqrt(3)` = 1.155 at its corners.
    pub modulation_index: Option<f64>,
    /// Mean current at the source's terminals \[A\] (negative: returned to
    /// it). Differs from the supply current only with a DC link (the
    /// source's side of the capacitor); without one it is left `None`.
    pub bus_current_a: Option<f64>,
    /// Energy returned to the source over the measurement window \[J\].
    pub regen_energy_j: Option<f64>,
}

impl DynoRow {
    /// Row from measured values; mechanical power and efficiency are derived
    /// (`P = T w`, efficiency 0 when no power goes in).
    pub fn new(
        supply_voltage_v: f64,
        supply_current_a: f64,
        input_power_w: f64,
        speed_rpm: f64,
        torque_nm: f64,
    ) -> Self {
        let mech = torque_nm * speed_rpm * std::f64::consts::TAU / 60.0;
        let eff = if input_power_w > 0.0 {
            100.0 * mech / input_power_w
        } else if input_power_w < 0.0 && mech < 0.0 {
            // Generating: the electrical power out over the mechanical in.
            100.0 * input_power_w / mech
        } else {
            0.0
        };
        Self {
            supply_voltage_v,
            supply_current_a,
            input_power_w,
            speed_rpm,
            torque_nm,
            mechanical_power_w: mech,
            efficiency_percent: eff,
            speed_command_rpm: None,
            phase_current_a: None,
            modulation_index: None,
            bus_current_a: None,
            regen_energy_j: None,
        }
    }

    /// With the speed command \[rpm\].
    pub fn with_speed_command(self, speed_command_rpm: f64) -> Self {
        Self {
            speed_command_rpm: Some(speed_command_rpm),
            ..self
        }
    }

    /// With the drive's figures: the phase current \[A, peak\] and the
    /// modulation index (see the fields).
    pub fn with_drive(self, phase_current_peak_a: f64, modulation_index: f64) -> Self {
        Self {
            phase_current_a: Some(phase_current_peak_a),
            modulation_index: Some(modulation_index),
            ..self
        }
    }

    /// With the energy returned to the source \[J\] (no DC link: the bus
    /// current is the supply current, not repeated).
    pub fn with_regen(self, regen_energy_j: f64) -> Self {
        Self {
            regen_energy_j: Some(regen_energy_j),
            ..self
        }
    }

    /// With the bus figures of a DC link: the mean source current \[A\]
    /// and the energy returned to the source \[J\].
    pub fn with_bus(self, bus_current_a: f64, regen_energy_j: f64) -> Self {
        Self {
            bus_current_a: Some(bus_current_a),
            ..self.with_regen(regen_energy_j)
        }
    }
}

/// One column of the dynamometer table, in the CSV, the Markdown and the
/// plots alike.
struct DynoColumn {
    /// Table heading (CSV and Markdown).
    heading: &'static str,
    /// The plots' legend: words and unit.
    legend: &'static str,
    /// Decimals in the Markdown.
    decimals: usize,
    /// Always shown (the source's columns), or only when a row has it.
    optional: bool,
    /// The row's value.
    value: fn(&DynoRow) -> Option<f64>,
}

/// The table's columns, in order: the source report's (design §12), the
/// speed command beside the speed, the drive's figures, the bus figures.
const COLUMNS: [DynoColumn; 12] = [
    DynoColumn {
        heading: "Supply voltage [V]",
        legend: "supply voltage [V]",
        decimals: 1,
        optional: false,
        value: |r| Some(r.supply_voltage_v),
    },
    DynoColumn {
        heading: "Supply current [A]",
        legend: "supply current [A]",
        decimals: 2,
        optional: false,
        value: |r| Some(r.supply_current_a),
    },
    DynoColumn {
        heading: "Input power [W]",
        legend: "input power [W]",
        decimals: 1,
        optional: false,
        value: |r| Some(r.input_power_w),
    },
    DynoColumn {
        heading: "Speed [rpm]",
        legend: "speed [rpm]",
        decimals: 0,
        optional: false,
        value: |r| Some(r.speed_rpm),
    },
    DynoColumn {
        heading: "Speed command [rpm]",
        legend: "speed command [rpm]",
        decimals: 0,
        optional: true,
        value: |r| r.speed_command_rpm,
    },
    DynoColumn {
        heading: "Torque [N m]",
        legend: "torque [N m]",
        decimals: 3,
        optional: false,
        value: |r| Some(r.torque_nm),
    },
    DynoColumn {
        heading: "Mechanical power [W]",
        legend: "mechanical power [W]",
        decimals: 1,
        optional: false,
        value: |r| Some(r.mechanical_power_w),
    },
    DynoColumn {
        heading: "Efficiency [%]",
        legend: "efficiency [%]",
        decimals: 1,
        optional: false,
        value: |r| Some(r.efficiency_percent),
    },
    DynoColumn {
        heading: "Phase current [A peak]",
        legend: "phase current [A peak]",
        decimals: 2,
        optional: true,
        value: |r| r.phase_current_a,
    },
    DynoColumn {
        heading: "Modulation index",
        legend: "modulation index",
        decimals: 3,
        optional: true,
        value: |r| r.modulation_index,
    },
    DynoColumn {
        heading: "Bus current [A]",
        legend: "bus current [A]",
        decimals: 2,
        optional: true,
        value: |r| r.bus_current_a,
    },
    DynoColumn {
        heading: "Regenerated energy [J]",
        legend: "regenerated energy [J]",
        decimals: 3,
        optional: true,
        value: |r| r.regen_energy_j,
    },
];

/// What the Markdown says under the table about a column, when shown.
fn column_note(heading: &str) -> Option<&'static str> {
    match heading {
        "Speed command [rpm]" => Some(
            "Speed command: what the speed loop was asked for; where the speed falls short of it the drive ran out of voltage or current.",
        ),
        "Phase current [A peak]" => Some(
            "Phase current: the amplitude (peak) of the phase currents, `|i_dq|` (amplitude-invariant Clarke, as the motor file's currents), averaged over the window; rms is peak / sqrt 2.",
        ),
        "Modulation index" => Some(
            "Modulation index: `sqrt(3) |v| / v_bus` = `|v_dq| / (v_bus / sqrt(3))` of the duties the bridge applied (foc-core's `SvpwmOutput::modulation_index`), averaged over the window: 1 on the circle inscribed in the hexagon (the end of the linear range), 1.155 at its corners.",
        ),
        "Bus current [A]" => Some(
            "Bus current: the mean current at the source's terminals, the source's side of the DC link (the supply current is the inverter's side).",
        ),
        "Regenerated energy [J]" => Some(
            "Regenerated energy: what went back into the source over the window (0 at motoring points).",
        ),
        _ => None,
    }
}

/// A dynamometer report: the header, the sweep (`None`: not known; the
/// titles then name none and the plots' x axis is whichever of torque
/// and supply voltage varies more) and the rows. A column is written once:
/// the optional ones (speed command, phase current, modulation index, bus
/// figures) only when a row has them, so the bus current appears only
/// where it differs from the supply current (with a DC link).
#[derive(Clone, Copy, Debug)]
pub struct DynoReport<'a> {
    /// The seven header fields.
    pub header: &'a DynoHeader,
    /// What was swept.
    pub sweep: Option<DynoSweep>,
    /// One row per operating point.
    pub rows: &'a [DynoRow],
}

impl DynoReport<'_> {
    /// The columns shown.
    fn columns(&self) -> impl Iterator<Item = &'static DynoColumn> + '_ {
        COLUMNS
            .iter()
            .filter(|c| !c.optional || self.rows.iter().any(|r| (c.value)(r).is_some()))
    }

    /// The table's headings, in order.
    pub fn headings(&self) -> Vec<&'static str> {
        self.columns().map(|c| c.heading).collect()
    }

    /// `Performance Curve Report`, with the sweep's title when known.
    fn title(&self) -> String {
        match self.sweep {
            Some(s) => format!("Performance Curve Report ({})", s.title()),
            None => "Performance Curve Report".into(),
        }
    }

    /// CSV: `# key: value` header lines (and `# Sweep:`), then the table.
    pub fn csv(&self) -> String {
        let mut s = String::new();
        for (k, v) in self.header.fields() {
            let _ = writeln!(s, "# {k}: {v}");
        }
        if let Some(sw) = self.sweep {
            let _ = writeln!(s, "# Sweep: {}", sw.title());
        }
        s.push_str(&self.headings().join(","));
        s.push('\n');
        for r in self.rows {
            let v: Vec<String> = self
                .columns()
                .map(|c| format!("{:.3}", (c.value)(r).unwrap_or(f64::NAN)))
                .collect();
            s.push_str(&v.join(","));
            s.push('\n');
        }
        s
    }

    /// Markdown: title, header table, data table, a note per column the
    /// source's report does not have.
    pub fn markdown(&self) -> String {
        let mut s = format!("# {}\n\n| Field | Value |\n|---|---|\n", self.title());
        for (k, v) in self.header.fields() {
            let _ = writeln!(s, "| {k} | {v} |");
        }
        if let Some(sw) = self.sweep {
            let _ = writeln!(s, "| Sweep | {}: {} |", sw.title(), sw.describe());
        }
        let headings = self.headings();
        let _ = write!(
            s,
            "\n| {} |\n|{}\n",
            headings.join(" | "),
            "---:|".repeat(headings.len())
        );
        for r in self.rows {
            s.push('|');
            for c in self.columns() {
                match (c.value)(r) {
                    Some(v) => {
                        let _ = write!(s, " {v:.*} |", c.decimals);
                    }
                    None => s.push_str(" - |"),
                }
            }
            s.push('\n');
        }
        let notes: Vec<&str> = headings.iter().filter_map(|h| column_note(h)).collect();
        if !notes.is_empty() {
            s.push('\n');
            for n in notes {
                let _ = writeln!(s, "- {n}");
            }
        }
        s
    }

    /// The plots' x axis: the sweep's, or whichever of torque and supply
    /// voltage varies more across the rows.
    fn x_axis(&self) -> (&'static str, fn(&DynoRow) -> f64) {
        match self.sweep {
            Some(s) => s.x_axis(),
            None => {
                let torque = spread(self.rows.iter().map(|r| r.torque_nm));
                let volts = spread(self.rows.iter().map(|r| r.supply_voltage_v));
                if torque >= volts {
                    DynoSweep::Load.x_axis()
                } else {
                    DynoSweep::Voltage.x_axis()
                }
            }
        }
    }

    /// SVG performance curves against the swept quantity (torque for the
    /// load and regen sweeps, supply voltage for the voltage sweep): the
    /// panels of [`DYNO_PANELS`] with a column shown, less the torque's
    /// when torque is the x axis and the regenerated energy's when none
    /// was. Each quantity drawn once, legends in words with units, every y
    /// axis at least [`dyno_min_span`] wide (so a flat speed shows flat).
    pub fn write_svg(&self, path: impl AsRef<Path>) -> io::Result<()> {
        let (x_desc, x_of) = self.x_axis();
        let columns: Vec<&DynoColumn> = self.columns().collect();
        let legends: Vec<&str> = columns.iter().map(|c| c.legend).collect();
        let mut t = Trace::new(&legends);
        let mut sorted: Vec<&DynoRow> = self.rows.iter().collect();
        sorted.sort_by(|a, b| x_of(a).total_cmp(&x_of(b)));
        for r in sorted {
            let v: Vec<f64> = columns
                .iter()
                .map(|c| (c.value)(r).unwrap_or(f64::NAN))
                .collect();
            t.push(x_of(r), &v);
        }
        let regen = self
            .rows
            .iter()
            .any(|r| r.regen_energy_j.is_some_and(|e| e > 0.0));
        let skip = |title: &str| match title {
            "torque" => x_desc == DynoSweep::Load.x_axis().0,
            "regenerated energy" => !regen,
            _ => false,
        };
        let mut panels = Vec::new();
        let mut spans = Vec::new();
        for (title, unit, signals) in DYNO_PANELS {
            let shown: Vec<&str> = signals
                .iter()
                .copied()
                .filter(|s| legends.contains(s))
                .collect();
            if !shown.is_empty() && !skip(title) {
                panels.push(Panel::new(title, unit, &shown));
                spans.push(dyno_min_span(unit));
            }
        }
        let title = match self.sweep {
            Some(s) => format!(
                "Performance Curve Report: {} ({})",
                self.header.motor_model,
                s.title()
            ),
            None => format!("Performance Curve Report: {}", self.header.motor_model),
        };
        plot_min_spans(path, &title, &t, &panels, x_desc, None, &spans)
    }

    /// Write `<stem>.csv`, `<stem>.md` and `<stem>.svg` into `dir`.
    pub fn write(&self, dir: impl AsRef<Path>, stem: &str) -> io::Result<[PathBuf; 3]> {
        let dir = dir.as_ref();
        let csv = dir.join(format!("{stem}.csv"));
        let md = dir.join(format!("{stem}.md"));
        let svg = dir.join(format!("{stem}.svg"));
        write_file(&csv, &self.csv())?;
        write_file(&md, &self.markdown())?;
        self.write_svg(&svg)?;
        Ok([csv, md, svg])
    }
}

/// The dynamometer plots' panels, top to bottom: title, unit and the
/// columns drawn (by legend; the reference first, as the plots' first
/// colour is the reference's).
pub const DYNO_PANELS: [(&str, &str, &[&str]); 7] = [
    ("speed", "rpm", &["speed command [rpm]", "speed [rpm]"]),
    ("torque", "N m", &["torque [N m]"]),
    (
        "current",
        "A",
        &[
            "supply current [A]",
            "bus current [A]",
            "phase current [A peak]",
        ],
    ),
    ("power", "W", &["input power [W]", "mechanical power [W]"]),
    ("efficiency", "%", &["efficiency [%]"]),
    (
        "modulation index (sqrt3 |v| / v_bus)",
        "1",
        &["modulation index"],
    ),
    ("regenerated energy", "J", &["regenerated energy [J]"]),
];

/// The least span of a dynamometer plot's y axis: 1 % of the largest
/// magnitude plus a floor per unit (1 rpm, 1 W, 1 %, 0.01 A, N m and
/// modulation index, 1 mJ, 0.1 V), so that a quantity the sweep holds
/// (the speed of a load sweep) shows flat rather than its ripple
/// autoscaled over the panel.
pub fn dyno_min_span(unit: &str) -> foc_plot::MinSpan {
    let absolute = match unit {
        "rpm" | "W" | "%" => 1.0,
        "J" => 1e-3,
        "V" => 0.1,
        _ => 0.01,
    };
    foc_plot::MinSpan {
        relative: 0.01,
        absolute,
    }
}

/// Relative spread `(max - min) / max|x|` of a set of values (0 when flat).
fn spread(values: impl Iterator<Item = f64> + Clone) -> f64 {
    let (lo, hi) = values
        .clone()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        });
    let mag = lo.abs().max(hi.abs());
    if mag > 0.0 && mag.is_finite() {
        (hi - lo) / mag
    } else {
        0.0
    }
}

/// [`DynoReport::csv`] of a run whose sweep is not known.
pub fn dyno_csv(header: &DynoHeader, rows: &[DynoRow]) -> String {
    DynoReport {
        header,
        sweep: None,
        rows,
    }
    .csv()
}

/// [`DynoReport::markdown`] of a run whose sweep is not known.
pub fn dyno_markdown(header: &DynoHeader, rows: &[DynoRow]) -> String {
    DynoReport {
        header,
        sweep: None,
        rows,
    }
    .markdown()
}

/// [`DynoReport::write_svg`] of a run whose sweep is not known.
pub fn dyno_svg(path: impl AsRef<Path>, header: &DynoHeader, rows: &[DynoRow]) -> io::Result<()> {
    DynoReport {
        header,
        sweep: None,
        rows,
    }
    .write_svg(path)
}

/// [`DynoReport::write`] of a run whose sweep is not known.
pub fn write_dyno_report(
    dir: impl AsRef<Path>,
    stem: &str,
    header: &DynoHeader,
    rows: &[DynoRow],
) -> io::Result<[PathBuf; 3]> {
    DynoReport {
        header,
        sweep: None,
        rows,
    }
    .write(dir, stem)
}
