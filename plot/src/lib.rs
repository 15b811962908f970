//! Stacked SVG line plots whose axes fit the data.
//!
//! One [`Figure`] is a title and a column of [`Panel`]s sharing one x axis;
//! each panel is one frame with one unit (say so in its `y_label`, e.g.
//! `"current [A]"` or `"position [rad] (rotor, mechanical)"`) and draws
//! any number of [`Series`]. The rules every plot follows:
//!
//! - x runs from the data's smallest to its largest x (for a time series:
//!   its first to its last sample), without margin;
//! - y runs from each panel's smallest to its largest value with a 5 %
//!   margin ([`fit_range`]); a constant series gets a small band around
//!   its value (5 % of it, or +-1 around 0); [`write_svg_min_spans`]
//!   gives a panel a least span ([`MinSpan`]), so that a nearly constant
//!   quantity is not autoscaled into a zig-zag;
//! - non-finite values (NaN, +-inf) are skipped: a line stops at them and
//!   starts again after them, it is not drawn across the gap;
//! - the legend is drawn beside each panel, not over the data.
//!
//! Bad input is an error, never a panic: a series whose `x` and `y` differ
//! in length, a figure without panels.
//!
//! ```no_run
//! use foc_plot::{write_svg, Figure, Panel, Series};
//! let t = [0.0, 1e-4, 2e-4, 3e-4];
//! let iq_ref = [1.0, 1.0, 1.0, 1.0];
//! let iq = [0.0, 0.6, 0.9, 1.0];
//! let fig = Figure {
//!     title: "q-current step",
//!     x_label: "time [s]",
//!     panels: vec![Panel {
//!         y_label: "q current [A]",
//!         series: vec![
//!             Series { name: "reference", x: &t, y: &iq_ref },
//!             Series { name: "measured", x: &t, y: &iq },
//!         ],
//!     }],
//!     x_marker: Some((1e-4, "step")),
//! };
//! write_svg(std::path::Path::new("out/step.svg"), &fig).unwrap();
//! ```
//!
//! # Where to start reading
//!
//! The example above, then [`Figure`] and [`fit_range`].
#![warn(missing_docs)]

use plotters::coord::Shift;
use plotters::prelude::*;
use std::io;
use std::path::Path;

/// One line: `y[k]` against `x[k]` (same lengths). Non-finite points are
/// gaps.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Series<'a> {
    /// Legend text.
    pub name: &'a str,
    /// Abscissae (e.g. time \[s\]).
    pub x: &'a [f64],
    /// Ordinates, in the panel's unit.
    pub y: &'a [f64],
}

/// One panel: series sharing one y axis, i.e. one quantity in one frame
/// and one unit.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Panel<'a> {
    /// What the axis shows, with its unit and frame, e.g. `"current [A]"`
    /// or `"position [rad] (rotor, mechanical)"`. Drawn above the panel.
    pub y_label: &'a str,
    /// The lines.
    pub series: Vec<Series<'a>>,
}

/// Stacked panels sharing the x axis, under a title.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Figure<'a> {
    /// Title at the top.
    pub title: &'a str,
    /// What the shared x axis shows, with its unit, e.g. `"time [s]"`;
    /// written under the bottom panel.
    pub x_label: &'a str,
    /// The panels, top to bottom.
    pub panels: Vec<Panel<'a>>,
    /// Optional vertical line across every panel at this x, with a label
    /// (e.g. a scope's trigger instant or a step's start); `None` for
    /// none. Not drawn when outside the data's x range.
    pub x_marker: Option<(f64, &'a str)>,
}

/// Smallest and largest finite value, `None` when there is none.
fn finite_min_max(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    values
        .into_iter()
        .filter(|v| v.is_finite())
        .fold(None, |acc, v| match acc {
            None => Some((v, v)),
            Some((lo, hi)) => Some((v.min(lo), v.max(hi))),
        })
}

/// Largest axis limit [same unit as the data]: beyond it an axis' span
/// could overflow (and plotters' tick search would not end).
const LIMIT: f64 = 1e300;

/// `(lo, hi)` clamped to `-LIMIT..=LIMIT`, `lo < hi` kept.
fn finite_band(lo: f64, hi: f64) -> (f64, f64) {
    let lo = lo.clamp(-LIMIT, LIMIT);
    let hi = hi.clamp(-LIMIT, LIMIT);
    if lo < hi {
        (lo, hi)
    } else {
        // Only reachable at the limits: a band inside them.
        let mid = 0.5 * lo + 0.5 * hi;
        (mid - 0.05 * mid.abs() - 1.0, mid + 0.05 * mid.abs() + 1.0)
    }
}

/// A band around the finite `lo..=hi` (`lo <= hi`): 5 % of the span on
/// each side; a constant (the span below 1e-12 of the magnitude) gets 5 %
/// of its magnitude on each side, or +-1 around 0.
fn pad(lo: f64, hi: f64) -> (f64, f64) {
    let scale = lo.abs().max(hi.abs());
    let span = hi - lo;
    if span > 1e-12 * scale {
        let m = 0.05 * span;
        finite_band(lo - m, hi + m)
    } else {
        let mid = 0.5 * lo + 0.5 * hi;
        let half = if mid == 0.0 { 1.0 } else { 0.05 * mid.abs() };
        finite_band(mid - half, mid + half)
    }
}

/// Fitted range `(lo, hi)` of the finite values, with margin: 5 % of the
/// span on each side; a constant gets 5 % of its magnitude on each side
/// (+-1 around 0). `None` without any finite value. Always `lo < hi`, both
/// within +-1e300 (larger values are drawn at the axis' edge).
///
/// ```
/// assert_eq!(foc_plot::fit_range([0.0, 10.0]), Some((-0.5, 10.5)));
/// assert_eq!(foc_plot::fit_range([f64::NAN]), None);
/// ```
pub fn fit_range(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    finite_min_max(values).map(|(lo, hi)| pad(lo, hi))
}

/// The least span a y axis may have, before its margin: `relative` times
/// the largest magnitude of the panel's data plus `absolute` (in the
/// panel's unit). A panel whose data spread less is widened around their
/// middle, so that a nearly constant quantity shows flat instead of its
/// noise autoscaled across the whole panel. [`MinSpan::NONE`] (the
/// default) keeps [`fit_range`]'s fit.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MinSpan {
    /// Fraction of the data's largest magnitude (e.g. 0.01 for 1 %).
    pub relative: f64,
    /// Floor in the panel's unit.
    pub absolute: f64,
}

impl MinSpan {
    /// No minimum: the axis fits the data ([`fit_range`]).
    pub const NONE: Self = Self {
        relative: 0.0,
        absolute: 0.0,
    };

    /// The least span for data reaching magnitude `scale` (0 for a
    /// non-finite or negative result).
    fn span(&self, scale: f64) -> f64 {
        let s = self.relative * scale + self.absolute;
        if s.is_finite() && s > 0.0 {
            s
        } else {
            0.0
        }
    }
}

/// As [`fit_range`], the data's span first widened to at least `min`'s
/// (around the middle of the data), then the margin added.
///
/// ```
/// use foc_plot::{fit_range_min, MinSpan};
/// // 0.03 rpm of ripple on 137 rpm: at least 1 % of 137 plus 1 rpm.
/// let min = MinSpan { relative: 0.01, absolute: 1.0 };
/// let (lo, hi) = fit_range_min([137.00, 137.03], min).unwrap();
/// assert!(hi - lo > 2.37 && lo < 137.0 && hi > 137.03);
/// // Data wider than the minimum keep the plain fit.
/// assert_eq!(fit_range_min([0.0, 10.0], min), foc_plot::fit_range([0.0, 10.0]));
/// ```
pub fn fit_range_min(values: impl IntoIterator<Item = f64>, min: MinSpan) -> Option<(f64, f64)> {
    finite_min_max(values).map(|(lo, hi)| {
        let need = min.span(lo.abs().max(hi.abs()));
        if hi - lo < need {
            let mid = 0.5 * lo + 0.5 * hi;
            pad(mid - 0.5 * need, mid + 0.5 * need)
        } else {
            pad(lo, hi)
        }
    })
}

/// The x range: smallest to largest finite x of the points whose y is
/// finite too, without margin (a single x gets [`fit_range`]'s band).
fn x_range(fig: &Figure<'_>) -> Option<(f64, f64)> {
    let xs = fig.panels.iter().flat_map(|p| {
        p.series.iter().flat_map(|s| {
            s.x.iter()
                .zip(s.y)
                .filter(|(_, y)| y.is_finite())
                .map(|(x, _)| *x)
        })
    });
    finite_min_max(xs).map(|(lo, hi)| {
        if lo < hi {
            finite_band(lo, hi)
        } else {
            pad(lo, hi)
        }
    })
}

fn invalid(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, msg)
}

fn other(e: impl std::fmt::Display) -> io::Error {
    io::Error::other(e.to_string())
}

/// Checks what would otherwise panic or mislead.
fn validate(fig: &Figure<'_>) -> io::Result<()> {
    if fig.panels.is_empty() {
        return Err(invalid(format!("figure `{}` has no panels", fig.title)));
    }
    for p in &fig.panels {
        for s in &p.series {
            if s.x.len() != s.y.len() {
                return Err(invalid(format!(
                    "series `{}` of panel `{}`: {} x values, {} y values",
                    s.name,
                    p.y_label,
                    s.x.len(),
                    s.y.len()
                )));
            }
        }
    }
    Ok(())
}

/// Line colours, distinguishable on white (the first is for references).
const COLORS: [RGBColor; 8] = [
    RGBColor(0x1f, 0x77, 0xb4),
    RGBColor(0xd6, 0x27, 0x28),
    RGBColor(0x2c, 0xa0, 0x2c),
    RGBColor(0xff, 0x7f, 0x0e),
    RGBColor(0x94, 0x67, 0xbd),
    RGBColor(0x8c, 0x56, 0x4b),
    RGBColor(0x17, 0xbe, 0xcf),
    RGBColor(0x7f, 0x7f, 0x7f),
];

/// Tick-label text for an axis spanning `lo..hi`: as many decimals as the
/// ticks' spacing needs, trailing zeros dropped; exponent notation for
/// very large or very small magnitudes.
fn tick_text(v: f64, lo: f64, hi: f64) -> String {
    let scale = lo.abs().max(hi.abs());
    let span = hi - lo;
    if v == 0.0 || v.abs() < 1e-9 * span {
        return "0".into();
    }
    if !(1e-4..1e6).contains(&scale) || !span.is_finite() {
        return format!("{v:.3e}");
    }
    // Ticks are about span/10 apart; one more decimal than that needs.
    let step = span / 10.0;
    let decimals = (-step.log10()).ceil().clamp(0.0, 12.0) as usize + 1;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// Runs of consecutive finite points of `s`.
fn finite_runs<'s>(s: &'s Series<'_>) -> impl Iterator<Item = Vec<(f64, f64)>> + 's {
    let mut run = Vec::new();
    let mut points = s.x.iter().zip(s.y).map(|(x, y)| (*x, *y));
    std::iter::from_fn(move || {
        for (x, y) in points.by_ref() {
            if x.is_finite() && y.is_finite() {
                run.push((x, y));
            } else if !run.is_empty() {
                return Some(std::mem::take(&mut run));
            }
        }
        (!run.is_empty()).then(|| std::mem::take(&mut run))
    })
}

/// Sizes [px].
const WIDTH: u32 = 1100;
const TITLE_H: u32 = 40;
const PANEL_H: u32 = 230;
const LEGEND_W: u32 = 230;
const FONT: &str = "sans-serif";

fn draw_panel(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    panel: &Panel<'_>,
    (x0, x1): (f64, f64),
    x_label: Option<&str>,
    marker: Option<(f64, &str)>,
    min_span: MinSpan,
) -> io::Result<()> {
    let (w, _) = area.dim_in_pixel();
    let (head, body) = area.split_vertically(24);
    head.draw_text(
        panel.y_label,
        &TextStyle::from((FONT, 19).into_font()).color(&BLACK),
        (78, 4),
    )
    .map_err(other)?;
    let (plot, legend) = body.split_horizontally(w.saturating_sub(LEGEND_W));
    let fitted = fit_range_min(
        panel
            .series
            .iter()
            .flat_map(|s| s.x.iter().zip(s.y).filter(|(x, _)| x.is_finite()))
            .map(|(_, y)| *y),
        min_span,
    );
    let (y0, y1) = fitted.unwrap_or((0.0, 1.0));
    let mut chart = ChartBuilder::on(&plot)
        .margin_right(12)
        .margin_top(4)
        .x_label_area_size(if x_label.is_some() { 44 } else { 26 })
        .y_label_area_size(78)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(other)?;
    let x_fmt = |v: &f64| tick_text(*v, x0, x1);
    let y_fmt = |v: &f64| tick_text(*v, y0, y1);
    let mut mesh = chart.configure_mesh();
    mesh.x_labels(10)
        .y_labels(6)
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .label_style((FONT, 15))
        .light_line_style(TRANSPARENT);
    if let Some(d) = x_label {
        mesh.x_desc(d).axis_desc_style((FONT, 18));
    }
    mesh.draw().map_err(other)?;
    if fitted.is_none() {
        chart
            .draw_series(std::iter::once(Text::new(
                "no data",
                (0.5 * x0 + 0.5 * x1, 0.5 * y0 + 0.5 * y1),
                (FONT, 16).into_font().color(&BLACK.mix(0.6)),
            )))
            .map_err(other)?;
    }
    let marker = marker.filter(|(xm, _)| (x0..=x1).contains(xm));
    if let Some((xm, _)) = marker {
        chart
            .draw_series(DashedLineSeries::new(
                [(xm, y0), (xm, y1)],
                6,
                4,
                BLACK.mix(0.7).stroke_width(1),
            ))
            .map_err(other)?;
    }
    for (k, s) in panel.series.iter().enumerate() {
        let color = COLORS[k % COLORS.len()];
        for mut run in finite_runs(s) {
            // Inside the axes already, but for values beyond `LIMIT`:
            // plotters' pixel mapping would overflow on them.
            for p in &mut run {
                *p = (p.0.clamp(x0, x1), p.1.clamp(y0, y1));
            }
            if run.len() == 1 {
                chart
                    .draw_series(run.iter().map(|p| Circle::new(*p, 2, color.filled())))
                    .map_err(other)?;
            } else {
                chart
                    .draw_series(LineSeries::new(run, color.stroke_width(1)))
                    .map_err(other)?;
            }
        }
    }
    draw_legend(&legend, panel, marker.map(|(_, l)| l))
}

/// The legend beside a panel's plot: a line sample and the name of each
/// series ("(no data)" when it has none), and the marker's label.
fn draw_legend(
    legend: &DrawingArea<SVGBackend<'_>, Shift>,
    panel: &Panel<'_>,
    marker: Option<&str>,
) -> io::Result<()> {
    // Legend beside the plot: a line sample and the name per series.
    let text = TextStyle::from((FONT, 17).into_font()).color(&BLACK);
    let mut y = 12;
    for (k, s) in panel.series.iter().enumerate() {
        let color = COLORS[k % COLORS.len()];
        legend
            .draw(&PathElement::new(
                [(6, y + 7), (30, y + 7)],
                color.stroke_width(2),
            ))
            .map_err(other)?;
        let empty =
            !s.x.iter()
                .zip(s.y)
                .any(|(x, y)| x.is_finite() && y.is_finite());
        let name = if empty {
            format!("{} (no data)", s.name)
        } else {
            s.name.to_string()
        };
        legend.draw_text(&name, &text, (36, y)).map_err(other)?;
        y += 22;
    }
    if let Some(label) = marker {
        legend
            .draw(&PathElement::new(
                [(18, y), (18, y + 14)],
                BLACK.mix(0.7).stroke_width(1),
            ))
            .map_err(other)?;
        legend
            .draw_text(&format!("{label} (dashed)"), &text, (36, y))
            .map_err(other)?;
    }
    Ok(())
}

/// The title as lines that fit the figure's width at [`TITLE_SIZE`]
/// (about 0.5 em a character): split at spaces, one line per chunk.
fn title_lines(title: &str) -> Vec<String> {
    let max_chars = (f64::from(WIDTH - 24) / (0.5 * TITLE_SIZE)) as usize;
    let mut lines: Vec<String> = Vec::new();
    for word in title.split(' ') {
        match lines.last_mut() {
            Some(line) if line.chars().count() + 1 + word.chars().count() <= max_chars => {
                line.push(' ');
                line.push_str(word);
            }
            _ => lines.push(word.to_string()),
        }
    }
    lines
}

/// Title font size and line height [px].
const TITLE_SIZE: f64 = 24.0;
const TITLE_LINE_H: u32 = 26;

/// The figure as SVG text (see [`write_svg`]).
pub fn render_svg(fig: &Figure<'_>) -> io::Result<String> {
    render_svg_min_spans(fig, &[])
}

/// As [`render_svg`], panel `k`'s y axis spanning at least `y_min[k]`
/// ([`fit_range_min`]; panels beyond the slice get [`MinSpan::NONE`]).
pub fn render_svg_min_spans(fig: &Figure<'_>, y_min: &[MinSpan]) -> io::Result<String> {
    validate(fig)?;
    let (x0, x1) = x_range(fig).unwrap_or((0.0, 1.0));
    let n = fig.panels.len() as u32;
    let lines = title_lines(fig.title);
    let title_h = TITLE_H + TITLE_LINE_H * (lines.len().max(1) as u32 - 1);
    let height = title_h + PANEL_H * n + 20;
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, (WIDTH, height)).into_drawing_area();
        root.fill(&WHITE).map_err(other)?;
        let (title, body) = root.split_vertically(title_h);
        let style = TextStyle::from((FONT, TITLE_SIZE).into_font()).color(&BLACK);
        for (k, line) in lines.iter().enumerate() {
            title
                .draw_text(line, &style, (12, 10 + TITLE_LINE_H as i32 * k as i32))
                .map_err(other)?;
        }
        let (body, _) = body.split_vertically(PANEL_H * n);
        let areas = body.split_evenly((fig.panels.len(), 1));
        for (k, (area, panel)) in areas.iter().zip(&fig.panels).enumerate() {
            let last = k + 1 == fig.panels.len();
            draw_panel(
                area,
                panel,
                (x0, x1),
                last.then_some(fig.x_label),
                fig.x_marker,
                y_min.get(k).copied().unwrap_or(MinSpan::NONE),
            )?;
        }
        root.present().map_err(other)?;
    }
    Ok(buf)
}

/// Stacked panels sharing the x range; axes fitted to the data (see the
/// crate docs). Creates the parent directory. Errors: a series whose `x`
/// and `y` lengths differ, a figure without panels, the file system.
pub fn write_svg(path: &Path, fig: &Figure<'_>) -> io::Result<()> {
    write_svg_min_spans(path, fig, &[])
}

/// As [`write_svg`], with a least span per panel's y axis
/// ([`render_svg_min_spans`]).
pub fn write_svg_min_spans(path: &Path, fig: &Figure<'_>, y_min: &[MinSpan]) -> io::Result<()> {
    let svg = render_svg_min_spans(fig, y_min)?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(path, svg)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: (f64, f64), b: (f64, f64)) -> bool {
        (a.0 - b.0).abs() <= 1e-12 * (1.0 + b.0.abs())
            && (a.1 - b.1).abs() <= 1e-12 * (1.0 + b.1.abs())
    }

    #[test]
    fn fit_range_ordinary_data() {
        let r = fit_range([2.0, -1.0, 5.0, 0.0]).unwrap();
        assert!(close(r, (-1.3, 5.3)), "{r:?}");
        // Small spans are not widened to some absolute minimum: 0..6 ms
        // stays 0..6 ms (plus the margin).
        let r = fit_range([0.0, 0.006]).unwrap();
        assert!(close(r, (-0.0003, 0.0063)), "{r:?}");
        // Far from zero: the span, not the magnitude, sets the margin.
        let r = fit_range([24.0, 24.1]).unwrap();
        assert!(close(r, (23.995, 24.105)), "{r:?}");
    }

    #[test]
    fn fit_range_constant_data() {
        assert_eq!(fit_range([0.0; 5]), Some((-1.0, 1.0)));
        let r = fit_range([24.0, 24.0]).unwrap();
        assert!(close(r, (22.8, 25.2)), "{r:?}");
        let r = fit_range([-2.0]).unwrap();
        assert!(close(r, (-2.1, -1.9)), "{r:?}");
        let (lo, hi) = fit_range([1e-30]).unwrap();
        assert!(lo < 1e-30 && 1e-30 < hi);
    }

    #[test]
    fn fit_range_skips_non_finite_values() {
        let r = fit_range([f64::NAN, 1.0, f64::INFINITY, 3.0, f64::NEG_INFINITY]).unwrap();
        assert!(close(r, (0.9, 3.1)), "{r:?}");
        assert_eq!(fit_range([f64::NAN, f64::INFINITY]), None);
        // The extremes of f64 stay finite and ordered.
        for v in [
            [f64::MAX, f64::MAX],
            [f64::MIN, f64::MAX],
            [f64::MIN, f64::MIN],
        ] {
            let (lo, hi) = fit_range(v).unwrap();
            assert!(lo.is_finite() && hi.is_finite() && lo < hi, "{v:?}");
        }
    }

    #[test]
    fn fit_range_min_widens_small_spans_only() {
        let min = MinSpan {
            relative: 0.01,
            absolute: 1.0,
        };
        // 0.03 rpm on 137 rpm: widened to 2.37 rpm around the middle.
        let (lo, hi) = fit_range_min([137.0, 137.03], min).unwrap();
        let (mid, need) = (0.5 * 137.0 + 0.5 * 137.03, 0.01 * 137.03 + 1.0);
        let want = (mid - 0.55 * need, mid + 0.55 * need);
        assert!(close((lo, hi), want), "{lo} {hi}");
        // Wide data and no minimum: the plain fit.
        for v in [[0.0, 10.0], [24.0, 24.1], [-3.0, 3.0]] {
            assert_eq!(
                fit_range_min(
                    v,
                    MinSpan {
                        relative: 0.0,
                        absolute: 0.1
                    }
                ),
                fit_range(v)
            );
            assert_eq!(fit_range_min(v, MinSpan::NONE), fit_range(v));
        }
        assert_eq!(fit_range_min([f64::NAN], min), None);
        // Odd minimums are ignored, never a panic.
        for bad in [f64::NAN, f64::INFINITY, -1.0] {
            let m = MinSpan {
                relative: bad,
                absolute: bad,
            };
            assert_eq!(fit_range_min([1.0, 2.0], m), fit_range([1.0, 2.0]));
        }
    }

    #[test]
    fn fit_range_empty() {
        assert_eq!(fit_range(std::iter::empty()), None);
    }

    #[test]
    fn tick_text_uses_the_decimals_the_span_needs() {
        assert_eq!(tick_text(0.002, 0.0, 0.006), "0.002");
        assert_eq!(tick_text(0.0015, 0.0, 0.006), "0.0015");
        assert_eq!(tick_text(20.0, 0.0, 100.0), "20");
        assert_eq!(tick_text(24.05, 23.99, 24.11), "24.05");
        assert_eq!(tick_text(1e-18, -1.0, 1.0), "0");
    }

    #[test]
    fn long_titles_are_wrapped_at_spaces() {
        assert_eq!(title_lines("short title"), vec!["short title"]);
        let long = "word ".repeat(60);
        let lines = title_lines(long.trim());
        assert!(lines.len() >= 2);
        assert_eq!(lines.join(" "), long.trim());
        assert_eq!(title_lines(""), vec![""]);
    }

    #[test]
    fn finite_runs_split_at_gaps() {
        let x = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0];
        let y = [1.0, f64::NAN, 2.0, 3.0, f64::INFINITY, f64::NAN];
        let s = Series {
            name: "s",
            x: &x,
            y: &y,
        };
        let runs: Vec<_> = finite_runs(&s).collect();
        assert_eq!(runs, vec![vec![(0.0, 1.0)], vec![(2.0, 2.0), (3.0, 3.0)]]);
    }

    fn figure<'a>(t: &'a [f64], a: &'a [f64], b: &'a [f64]) -> Figure<'a> {
        Figure {
            title: "a test figure",
            x_label: "time [s]",
            panels: vec![
                Panel {
                    y_label: "current [A]",
                    series: vec![
                        Series {
                            name: "reference",
                            x: t,
                            y: a,
                        },
                        Series {
                            name: "measured",
                            x: t,
                            y: b,
                        },
                    ],
                },
                Panel {
                    y_label: "position [rad] (rotor, mechanical)",
                    series: vec![Series {
                        name: "true",
                        x: t,
                        y: b,
                    }],
                },
            ],
            x_marker: Some((t[1], "trigger")),
        }
    }

    #[test]
    fn write_svg_writes_the_labels() {
        let t: Vec<f64> = (0..100).map(|k| k as f64 * 6e-5).collect();
        let a = vec![1.0; 100];
        let b: Vec<f64> = t.iter().map(|t| 1.0 - (-t / 1e-3).exp()).collect();
        let dir = std::env::temp_dir().join(format!("foc-plot-{}", std::process::id()));
        let path = dir.join("sub").join("fig.svg");
        write_svg(&path, &figure(&t, &a, &b)).unwrap();
        let s = std::fs::read_to_string(&path).unwrap();
        std::fs::copy(&path, std::env::temp_dir().join("foc-plot-last.svg")).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        assert!(s.contains("<svg"));
        for label in [
            "a test figure",
            "time [s]",
            "current [A]",
            "position [rad] (rotor, mechanical)",
            "reference",
            "measured",
            "true",
            "trigger",
        ] {
            assert!(s.contains(label), "{label} missing");
        }
        // The time axis ends at the data's last sample (5.94 ms), not at
        // some padded round number: a tick label past it would show.
        let texts: Vec<&str> = s.lines().map(str::trim).collect();
        assert!(texts.contains(&"0.005"), "no 5 ms tick");
        assert!(!texts.contains(&"0.006") && !texts.contains(&"-0.05"));
    }

    #[test]
    fn mismatched_lengths_are_an_error() {
        let t = [0.0, 1.0, 2.0];
        let fig = Figure {
            title: "x",
            x_label: "t",
            panels: vec![Panel {
                y_label: "y",
                series: vec![Series {
                    name: "s",
                    x: &t,
                    y: &t[..2],
                }],
            }],
            x_marker: None,
        };
        let e = render_svg(&fig).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput);
        assert!(e.to_string().contains("3 x values, 2 y values"), "{e}");
        let none = Figure::default();
        assert!(render_svg(&none).is_err());
    }

    #[test]
    fn odd_input_does_not_panic() {
        let nan = [f64::NAN; 4];
        let x = [0.0, 1.0, 2.0, 3.0];
        let inf = [f64::INFINITY, f64::NEG_INFINITY, f64::NAN, 1.0];
        let huge = [f64::MAX, f64::MIN, 0.0, 1e300];
        let one = [5.0];
        let same_x = [2.0; 4];
        let cases: [(&[f64], &[f64]); 7] = [
            (&x, &nan),
            (&x, &inf),
            (&x, &huge),
            (&huge, &x),
            (&one, &one),
            (&same_x, &x),
            (&[], &[]),
        ];
        for (xs, ys) in cases {
            let fig = Figure {
                title: "odd",
                x_label: "x",
                panels: vec![
                    Panel {
                        y_label: "y",
                        series: vec![Series {
                            name: "s",
                            x: xs,
                            y: ys,
                        }],
                    },
                    Panel {
                        y_label: "empty",
                        series: vec![],
                    },
                ],
                x_marker: Some((f64::NAN, "nan marker")),
            };
            let svg = render_svg(&fig).unwrap();
            assert!(svg.contains("<svg"), "{xs:?} {ys:?}");
        }
    }
}
