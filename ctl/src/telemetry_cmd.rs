//! `telemetry`: the stream printed, plotted in the terminal, written as
//! CSV and SVG.

use super::*;

pub(super) const SPARK: [char; 8] = ['▁', '▂', '▃', '▄', '▅', '▆', '▇', '█'];

pub(super) fn sparkline(v: &[f32]) -> String {
    let (lo, hi) = v
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    v.iter()
        .map(|&x| {
            let t = if hi > lo { (x - lo) / (hi - lo) } else { 0.5 };
            SPARK[((t * 7.0).round() as usize).min(7)]
        })
        .collect()
}

pub(super) fn write_csv(path: &Path, samples: &[StreamSample]) -> std::io::Result<()> {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(
        f,
        "host_time_s,seq,period,i_d_a,i_q_a,v_d_v,v_q_v,velocity_out_rad_s,position_out_rad,mode,fault_code,max_loop_cycles,v_bus_v,bus_power_w,bus_current_a,power_limit,limit_left_pct,brake_on,winding_c,stage_c"
    )?;
    for s in samples {
        let t = &s.sample;
        writeln!(
            f,
            "{:.6},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:?},{},{},{},{}",
            s.host_time.as_secs_f64(),
            s.seq,
            t.period,
            t.i_d_a,
            t.i_q_a,
            t.v_d_v,
            t.v_q_v,
            t.velocity_rad_s,
            t.position_rad,
            t.mode as u8,
            t.fault_code,
            t.max_loop_cycles,
            t.v_bus_v,
            bus_power_w(t),
            bus_power_w(t) / t.v_bus_v,
            t.power_limit,
            t.limit_left_pct,
            u8::from(t.brake_on),
            t.winding_c,
            t.stage_c
        )?;
    }
    f.flush()
}

pub(super) fn write_svg(
    path: &Path,
    samples: &[StreamSample],
) -> Result<(), Box<dyn std::error::Error>> {
    use foc_plot::{Figure, Panel, Series};
    // One frame per panel: on the wire the velocity and position are the
    // output's (after the joint's gear ratio and offset, mechanical), the
    // currents the rotor's dq frame.
    let t0 = samples.first().map_or(0.0, |s| s.host_time.as_secs_f64());
    let t: Vec<f64> = samples
        .iter()
        .map(|s| s.host_time.as_secs_f64() - t0)
        .collect();
    let col = |get: fn(&StreamSample) -> f32| -> Vec<f64> {
        samples.iter().map(|s| f64::from(get(s))).collect()
    };
    let velocity = col(|s| s.sample.velocity_rad_s);
    let position = col(|s| s.sample.position_rad);
    let i_d = col(|s| s.sample.i_d_a);
    let i_q = col(|s| s.sample.i_q_a);
    let fig = Figure {
        title: "foc-ctl telemetry",
        x_label: "host time [s] (from the first sample)",
        panels: vec![
            Panel {
                y_label: "velocity [rad/s] (output, mechanical)",
                series: vec![Series {
                    name: "velocity",
                    x: &t,
                    y: &velocity,
                }],
            },
            Panel {
                y_label: "position [rad] (output, mechanical, multi-turn)",
                series: vec![Series {
                    name: "position",
                    x: &t,
                    y: &position,
                }],
            },
            Panel {
                y_label: "current [A] (rotor dq frame, measured)",
                series: vec![
                    Series {
                        name: "i_q",
                        x: &t,
                        y: &i_q,
                    },
                    Series {
                        name: "i_d",
                        x: &t,
                        y: &i_d,
                    },
                ],
            },
        ],
        x_marker: None,
    };
    foc_plot::write_svg(path, &fig)?;
    Ok(())
}

/// `telemetry`: stream for `duration` seconds (given in ms on the command line), showing each sample (a line,
/// or sparklines with `plot`), then the optional CSV and SVG files.
pub(super) fn stream_telemetry(
    c: &mut Client,
    rate: TelemetryRate,
    duration: f64,
    csv: Option<PathBuf>,
    plot: bool,
    svg: Option<PathBuf>,
) -> CliResult {
    let mut samples: Vec<StreamSample> = Vec::new();
    let mut stderr = std::io::stderr();
    let pwm_hz = c.param(ParamId::PwmFrequencyHz)?;
    let req = Request::StartTelemetry(rate);
    let t0 = std::time::Instant::now();
    let d =
        Duration::try_from_secs_f64(duration.max(0.0)).map_err(|_| "--duration-ms: not a time")?;
    c.telemetry_with(rate, d, |s| {
        samples.push(*s);
        if plot && samples.len().is_multiple_of(5) {
            plot_tail(&mut stderr, &samples, s);
        } else if !plot && csv.is_none() {
            print_sample(s);
        }
    })
    .map_err(|e| foc_ctl::refusal::explain(c, &req, &e))?;
    let wall_s = t0.elapsed().as_secs_f64();
    if plot {
        say_err!();
    }
    let st = c.stats();
    say_err!(
        "{}",
        rate_text(rate, pwm_hz, &samples, wall_s, st.stream_lost)
    );
    if let Some(p) = csv {
        write_csv(&p, &samples)?;
        say_err!("wrote {}", p.display());
    }
    if let Some(p) = svg {
        write_svg(&p, &samples)?;
        say_err!("wrote {}", p.display());
    }
    Ok(())
}

/// The rate asked and the rate given (from the samples' period counter),
/// what arrived and what was lost.
fn rate_text(
    rate: TelemetryRate,
    pwm_hz: f32,
    samples: &[StreamSample],
    wall_s: f64,
    lost: u64,
) -> String {
    let asked = match rate {
        TelemetryRate::Hz(hz) => format!("asked {hz} Hz"),
        TelemetryRate::EveryPeriods(k) => format!("asked every {k} periods"),
    };
    let every = match (samples.first(), samples.last()) {
        (Some(a), Some(b)) if samples.len() > 1 => {
            let span = b.sample.period.wrapping_sub(a.sample.period) as f64;
            Some(span / (samples.len() as f64 - 1.0 + lost as f64))
        }
        _ => None,
    };
    let given = match every {
        Some(k) if k > 0.0 => format!(
            "given every {k:.0} periods = {:.1} Hz at {pwm_hz} Hz PWM",
            f64::from(pwm_hz) / k
        ),
        _ => "too few samples to tell the rate given".into(),
    };
    format!(
        "{asked}, {given}; {} samples in {wall_s:.2} s ({:.1}/s received), {lost} lost in the stream",
        samples.len(),
        samples.len() as f64 / wall_s.max(1e-9)
    )
}

/// One live line of velocity and iq sparklines over the last 60 samples.
pub(super) fn plot_tail(out: &mut impl Write, samples: &[StreamSample], s: &StreamSample) {
    let tail = &samples[samples.len().saturating_sub(60)..];
    let w: Vec<f32> = tail.iter().map(|s| s.sample.velocity_rad_s).collect();
    let i: Vec<f32> = tail.iter().map(|s| s.sample.i_q_a).collect();
    let _ = write!(
        out,
        "\rw {:>9.2} rad/s (output) {}  iq {:>7.3} A {}",
        s.sample.velocity_rad_s,
        sparkline(&w),
        s.sample.i_q_a,
        sparkline(&i)
    );
}

/// The bus power of a sample \[W\]: the dq power `1.5 (v_d i_d + v_q i_q)`
/// of the commanded voltages and measured currents (inverter losses not
/// included; > 0 motoring, < 0 regenerating).
pub(super) fn bus_power_w(t: &foc_protocol::message::Telemetry) -> f32 {
    1.5 * (t.v_d_v * t.i_d_a + t.v_q_v * t.i_q_a)
}

/// The power limit of a sample, when one cuts the current, e.g.
/// ` limit=Regen(37%)`; empty otherwise. ` brake` while the chopper conducts.
pub(super) fn power_text(t: &foc_protocol::message::Telemetry) -> String {
    let mut s = String::new();
    if t.power_limit != ActiveLimit::None {
        s += &format!(" limit={:?}({}%)", t.power_limit, t.limit_left_pct);
    }
    if t.brake_on {
        s += " brake";
    }
    if t.brake_locked {
        s += " brake-locked-out";
    }
    s + angle_text(t.angle_in_use)
}

/// Where the angle came from, when not from the sensor: ` angle=sensorless`,
/// ` angle=observer` (halls + sensorless above its speed) or
/// ` angle=limp-home` (the sensor failed); empty on the sensor.
pub(super) fn angle_text(a: foc_protocol::message::AngleInUse) -> &'static str {
    use foc_protocol::message::AngleInUse;
    match a {
        AngleInUse::Sensor => "",
        AngleInUse::Sensorless => " angle=sensorless",
        AngleInUse::Observer => " angle=observer",
        AngleInUse::LimpHome => " angle=limp-home",
    }
}

/// One sample as a line on stdout.
pub(super) fn print_sample(s: &StreamSample) {
    let t = &s.sample;
    say!(
        "{:>10} {:?} w_out={:.3} p_out={:.4} id={:.3} iq={:.3} vd={:.3} vq={:.3} vbus={:.2} pbus={:.1} twind={:.1} tstage={:.1} fault={} cyc={}{}",
        t.period, t.mode, t.velocity_rad_s, t.position_rad, t.i_d_a, t.i_q_a,
        t.v_d_v, t.v_q_v, t.v_bus_v, bus_power_w(t), t.winding_c, t.stage_c,
        t.fault_code, t.max_loop_cycles, power_text(t)
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use foc_protocol::message::{AngleInUse, Telemetry};

    #[test]
    fn the_angle_in_use_is_shown_unless_it_is_the_sensor() {
        let mut t = Telemetry::ZERO;
        assert_eq!(power_text(&t), "");
        t.angle_in_use = AngleInUse::LimpHome;
        t.brake_on = true;
        assert_eq!(power_text(&t), " brake angle=limp-home");
        t.angle_in_use = AngleInUse::Observer;
        assert!(power_text(&t).ends_with(" angle=observer"));
    }
}
