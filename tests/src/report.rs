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
use std::path::Path;

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
    foc_plot::write_svg(path.as_ref(), &fig)
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

/// One operating point of a dynamometer run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DynoRow {
    /// Supply voltage \[V\].
    pub supply_voltage_v: f64,
    /// Supply current \[A\].
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
    /// Mean current at the source's terminals \[A\] (negative: returned to
    /// it). `None`: not measured (the column is left out of the report
    /// when no row has it).
    pub bus_current_a: Option<f64>,
    /// Energy returned to the source over the measurement window \[J\]
    /// (`None`: not measured, as above).
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
            bus_current_a: None,
            regen_energy_j: None,
        }
    }

    /// With the bus figures: the mean source current \[A\] and the energy
    /// returned to the source \[J\].
    pub fn with_bus(self, bus_current_a: f64, regen_energy_j: f64) -> Self {
        Self {
            bus_current_a: Some(bus_current_a),
            regen_energy_j: Some(regen_energy_j),
            ..self
        }
    }

    fn values(&self) -> [f64; 7] {
        [
            self.supply_voltage_v,
            self.supply_current_a,
            self.input_power_w,
            self.speed_rpm,
            self.torque_nm,
            self.mechanical_power_w,
            self.efficiency_percent,
        ]
    }
}

/// Column headings of the dynamometer table.
pub const DYNO_COLUMNS: [&str; 7] = [
    "Supply voltage [V]",
    "Supply current [A]",
    "Input power [W]",
    "Speed [rpm]",
    "Torque [N m]",
    "Mechanical power [W]",
    "Efficiency [%]",
];

/// Column headings of the bus figures, after [`DYNO_COLUMNS`] when any row
/// has them ([`DynoRow::with_bus`]).
pub const DYNO_BUS_COLUMNS: [&str; 2] = ["Bus current [A]", "Regenerated energy [J]"];

/// Whether any row carries the bus figures.
fn has_bus(rows: &[DynoRow]) -> bool {
    rows.iter()
        .any(|r| r.bus_current_a.is_some() || r.regen_energy_j.is_some())
}

/// The bus figures of a row (NaN where not measured).
fn bus_values(r: &DynoRow) -> [f64; 2] {
    [
        r.bus_current_a.unwrap_or(f64::NAN),
        r.regen_energy_j.unwrap_or(f64::NAN),
    ]
}

/// CSV: `# key: value` header lines, then the table (with the bus columns
/// when any row has them).
pub fn dyno_csv(header: &DynoHeader, rows: &[DynoRow]) -> String {
    let bus = has_bus(rows);
    let mut s = String::new();
    for (k, v) in header.fields() {
        let _ = writeln!(s, "# {k}: {v}");
    }
    s.push_str(&DYNO_COLUMNS.join(","));
    if bus {
        s.push(',');
        s.push_str(&DYNO_BUS_COLUMNS.join(","));
    }
    s.push('\n');
    for r in rows {
        let mut v: Vec<String> = r.values().iter().map(|x| format!("{x:.3}")).collect();
        if bus {
            v.extend(bus_values(r).iter().map(|x| format!("{x:.3}")));
        }
        s.push_str(&v.join(","));
        s.push('\n');
    }
    s
}

/// Markdown: title, header table, data table (with the bus columns when
/// any row has them).
pub fn dyno_markdown(header: &DynoHeader, rows: &[DynoRow]) -> String {
    let bus = has_bus(rows);
    let mut s = String::from("# Performance Curve Report\n\n| Field | Value |\n|---|---|\n");
    for (k, v) in header.fields() {
        let _ = writeln!(s, "| {k} | {v} |");
    }
    let n = DYNO_COLUMNS.len() + if bus { DYNO_BUS_COLUMNS.len() } else { 0 };
    s.push_str("\n| ");
    s.push_str(&DYNO_COLUMNS.join(" | "));
    if bus {
        s.push_str(" | ");
        s.push_str(&DYNO_BUS_COLUMNS.join(" | "));
    }
    s.push_str(" |\n|");
    s.push_str(&"---:|".repeat(n));
    s.push('\n');
    for r in rows {
        let v = r.values();
        let _ = write!(
            s,
            "| {:.1} | {:.2} | {:.1} | {:.0} | {:.3} | {:.1} | {:.1} |",
            v[0], v[1], v[2], v[3], v[4], v[5], v[6]
        );
        if bus {
            let b = bus_values(r);
            let _ = write!(s, " {:.2} | {:.3} |", b[0], b[1]);
        }
        s.push('\n');
    }
    s
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

/// SVG performance curves: speed, supply current, input/mechanical power and
/// efficiency against the swept quantity (torque for a load sweep, supply
/// voltage for a voltage sweep: whichever varies more across the rows).
pub fn dyno_svg(path: impl AsRef<Path>, header: &DynoHeader, rows: &[DynoRow]) -> io::Result<()> {
    let torque_sweep =
        spread(rows.iter().map(|r| r.values()[4])) >= spread(rows.iter().map(|r| r.values()[0]));
    let (x_col, x_desc, what) = if torque_sweep {
        (4, "torque [N m]", "load sweep")
    } else {
        (0, "supply voltage [V]", "supply-voltage sweep")
    };
    let bus = has_bus(rows);
    let mut names = vec![
        "speed_rpm",
        "torque_nm",
        "supply_current_a",
        "input_power_w",
        "mechanical_power_w",
        "efficiency_percent",
    ];
    if bus {
        names.extend(["bus_current_a", "regen_energy_j"]);
    }
    let mut t = Trace::new(&names);
    let mut sorted: Vec<DynoRow> = rows.to_vec();
    sorted.sort_by(|a, b| a.values()[x_col].total_cmp(&b.values()[x_col]));
    for r in &sorted {
        let v = r.values();
        let mut row = vec![v[3], v[4], v[1], v[2], v[5], v[6]];
        if bus {
            row.extend(bus_values(r));
        }
        t.push(v[x_col], &row);
    }
    let title = format!("Performance Curve Report: {} ({what})", header.motor_model);
    let mut panels = vec![Panel::new("Speed", "rpm", &["speed_rpm"])];
    if !torque_sweep {
        panels.push(Panel::new("Torque", "N m", &["torque_nm"]));
    }
    if bus {
        panels.push(Panel::new(
            "Supply and bus current",
            "A",
            &["supply_current_a", "bus_current_a"],
        ));
    } else {
        panels.push(Panel::new("Supply current", "A", &["supply_current_a"]));
    }
    panels.extend([
        Panel::new("Power", "W", &["input_power_w", "mechanical_power_w"]),
        Panel::new("Efficiency", "%", &["efficiency_percent"]),
    ]);
    if bus {
        panels.push(Panel::new("Regenerated energy", "J", &["regen_energy_j"]));
    }
    plot_svg_against(path, &title, &t, &panels, x_desc)
}

/// Write `<stem>.csv`, `<stem>.md` and `<stem>.svg` into `dir`.
pub fn write_dyno_report(
    dir: impl AsRef<Path>,
    stem: &str,
    header: &DynoHeader,
    rows: &[DynoRow],
) -> io::Result<[std::path::PathBuf; 3]> {
    let dir = dir.as_ref();
    let csv = dir.join(format!("{stem}.csv"));
    let md = dir.join(format!("{stem}.md"));
    let svg = dir.join(format!("{stem}.svg"));
    write_file(&csv, &dyno_csv(header, rows))?;
    write_file(&md, &dyno_markdown(header, rows))?;
    dyno_svg(&svg, header, rows)?;
    Ok([csv, md, svg])
}
