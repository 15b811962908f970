//! Report writers produce files whose content can be read back.

use foc_bench::report::{self, DynoHeader, DynoRow, Panel, Trace};
use std::path::PathBuf;

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("foc-bench-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn trace_csv_round_trip_and_svg() {
    let dir = temp_dir("trace");
    let mut t = Trace::new(&["iq_ref_a", "iq_a", "speed_rad_s"]);
    for k in 0..200 {
        let x = k as f64 * 1e-4;
        t.push(x, &[1.0, 1.0 - (-x / 2e-3).exp(), 10.0 * x]);
    }
    let csv = dir.join("trace.csv");
    t.write_csv(&csv).unwrap();
    let back = Trace::from_csv(&std::fs::read_to_string(&csv).unwrap()).unwrap();
    assert_eq!(back.names(), t.names());
    assert_eq!(back.len(), 200);
    for name in ["iq_ref_a", "iq_a", "speed_rad_s"] {
        let (a, b) = (t.column(name).unwrap(), back.column(name).unwrap());
        assert!(a.iter().zip(b).all(|(x, y)| x == y), "{name}");
    }
    let svg = dir.join("trace.svg");
    report::plot_svg(
        &svg,
        "step",
        &t,
        &[
            Panel::new("q current", "A", &["iq_ref_a", "iq_a"]),
            Panel::new("speed", "rad/s", &["speed_rad_s"]),
        ],
    )
    .unwrap();
    let s = std::fs::read_to_string(&svg).unwrap();
    assert!(s.starts_with("<svg") || s.contains("<svg"));
    for name in ["iq_ref_a", "iq_a", "speed_rad_s", "q current"] {
        assert!(s.contains(name), "{name} missing in SVG");
    }
    assert!(
        s.matches("<polyline").count() >= 3,
        "expected one polyline per series"
    );
    assert!(report::plot_svg(
        dir.join("x.svg"),
        "x",
        &t,
        &[Panel::new("p", "u", &["nope"])]
    )
    .is_err());
}

#[test]
fn dyno_report_files() {
    let dir = temp_dir("dyno");
    let header = DynoHeader {
        project_no: "P-001".into(),
        report_no: "R-042".into(),
        motor_model: "M153".into(),
        test_motor_no: "3".into(),
        report_date: "2024-05-01".into(),
        tested_by: "bench".into(),
        approved_by: "reviewer".into(),
    };
    // The source's table shape: ten equal steps down from 26 V / 42 A / 930 W / 260 rpm.
    let rows: Vec<DynoRow> = (1..=10)
        .rev()
        .map(|k| {
            let f = k as f64 / 10.0;
            DynoRow::new(26.0 * f, 42.0 * f, 930.0 * f, 260.0 * f, 25.0 * f)
        })
        .collect();
    let [csv, md, svg] = report::write_dyno_report(&dir, "m153", &header, &rows).unwrap();

    let csv = std::fs::read_to_string(csv).unwrap();
    assert!(csv.contains("# Motor Model: M153") && csv.contains("# Approved By: reviewer"));
    let table: Vec<Vec<f64>> = csv
        .lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
        .collect();
    assert_eq!(table.len(), 10);
    for (r, row) in table.iter().zip(&rows) {
        assert_eq!(r.len(), 7);
        assert!((r[0] - row.supply_voltage_v).abs() < 1e-3);
        // Mechanical power = T w; efficiency = P_mech / P_in.
        let p_mech = r[4] * r[3] * std::f64::consts::TAU / 60.0;
        assert!((r[5] - p_mech).abs() < 1e-2);
        assert!((r[6] - 100.0 * p_mech / r[2]).abs() < 1e-2);
    }
    assert!((table[0][5] - 680.678).abs() < 0.01, "25 N m at 260 rpm");

    let md = std::fs::read_to_string(md).unwrap();
    assert!(md.contains("| Report No. | R-042 |"));
    let data_rows: Vec<&str> = md
        .lines()
        .filter(|l| l.starts_with("| ") && l.split('|').count() == 9 && !l.contains("Supply"))
        .collect();
    assert_eq!(data_rows.len(), 10);
    assert!(
        data_rows[0].starts_with("| 26.0 | 42.00 | 930.0 | 260 |"),
        "{}",
        data_rows[0]
    );

    let svg = std::fs::read_to_string(svg).unwrap();
    // Torque is either a plotted series or, for a load sweep, the x axis.
    assert!(svg.contains("torque [N m]"), "torque missing");
    // Legends in words with units (issue 36).
    for name in [
        "speed [rpm]",
        "supply current [A]",
        "input power [W]",
        "mechanical power [W]",
        "efficiency [%]",
        "M153",
    ] {
        assert!(svg.contains(name), "{name}");
    }
}
