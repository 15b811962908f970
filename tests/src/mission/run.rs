//! Running the mission: identification (or a restored configuration),
//! then the segments in order, then the summary.

use super::*;

/// The crude alignment (the dyno still uses it; the mission identifies the
/// motor with [`crate::identify::run`] instead). Find the electrical zero: open-loop d-axis voltage (30 % of the rated
/// current through R) at `theta_e = 90 deg`, then at `0 deg`, each until the
/// encoder reading has been still for 0.1 s (at most 0.6 s). The reading
/// there, scaled by the pole pairs, is the calibration's `zero_offset`; it is
/// installed in the controller as a [`Calibrated`] permit (with the
/// configured current loop), which is then disabled. Returns the offset
/// found and its error against the plant's true encoder offset [deg, electrical].
pub fn align(sim: &mut Sim, setup: &Setup) -> (ElectricalAngle, f64) {
    let pp = setup.motor.pole_pairs;
    let i_align = (0.3 * setup.rated_current_a).min(0.5 * setup.max_current_a);
    let v_align = (setup.motor.r_ohm as f32 * i_align).max(0.05);
    for theta_deg in [90.0f32, 0.0] {
        // A new open-loop command with a different `theta_e` moves the
        // field there at once (no detour through the safe state).
        sim.cascade
            .command(Command::OpenLoop {
                v_d_v: v_align,
                v_q_v: 0.0,
                theta_e: ElectricalAngle::from_degrees(theta_deg),
                omega_e_rad_s: 0.0,
            })
            .ok();
        let mut last = sim.last_sample().angle;
        let mut still = 0usize;
        let (min_n, max_n, still_n) = (secs(setup, 0.05), secs(setup, 0.6), secs(setup, 0.1));
        for n in 0..max_n {
            sim.step();
            let a = sim.last_sample().angle;
            still = if a == last && n > min_n { still + 1 } else { 0 };
            last = a;
            if still >= still_n {
                break;
            }
        }
    }
    let found = sim.last_sample().angle.to_electrical(pp);
    let truth = setup.true_angle_calibration().zero_offset;
    let error_deg = found.diff_radians(truth).to_degrees() as f64;
    let angle = AngleCalibration {
        pole_pairs: pp,
        zero_offset: found,
        reversed: false,
        sensor_counts_per_rev: 0,
        sensorless_only: false,
    };
    // The alignment result plus the configured current loop: the permit
    // for the closed-loop segments.
    let permit = Calibrated::supplied(angle, sim.cascade.config().current.current)
        .expect("plausible calibration");
    sim.cascade.set_calibration(&permit);
    sim.cascade.command(Command::Disable).ok();
    sim.run(secs(setup, 0.02));
    (found, error_deg)
}

pub(super) fn identification_summary(
    setup: &Setup,
    sim: &Sim,
    o: &identify::Outcome,
    r: &IdentificationResult,
    wall_time_s: f64,
) -> IdentificationSummary {
    let m = &setup.motor;
    let with_err = |x: f32, truth: f64| (x as f64, 100.0 * (x as f64 / truth - 1.0));
    let ts = 1.0 / setup.bench.pwm_frequency_hz as f64;
    IdentificationSummary {
        r_ohm: with_err(r.r_ohm, m.r_ohm as f64),
        // The identification measures the incremental d inductance at its
        // bias current (design §10): on a saturating motor that is the truth
        // to compare with.
        ld_h: with_err(
            r.ld_h,
            m.ld_incremental_h(
                identify::config(setup, m.pole_pairs)
                    .inductance
                    .bias_current_a as _,
            ) as f64,
        ),
        lq_h: with_err(r.lq_h, m.lq_h as f64),
        flux_linkage_wb: identify::config(setup, m.pole_pairs)
            .measure_flux
            .then(|| with_err(r.flux_linkage_wb, m.flux_linkage_wb as f64)),
        mechanics: r.mechanics.map(|x| {
            let (b, fc) = (
                x.viscous_friction_nm_s_per_rad as f64,
                x.coulomb_friction_nm as f64,
            );
            let (bp, fcp) = (m.viscous_friction_nm_s_per_rad, m.coulomb_friction_nm);
            let at = |w: f32| {
                let w = w.abs() as f64;
                let id = fc + b * w;
                (w, id, 100.0 * (id / (fcp + bp * w) - 1.0))
            };
            MechanicsFigures {
                inertia_kg_m2: with_err(x.inertia_kg_m2, m.inertia_kg_m2),
                friction: (b, fc),
                plant_friction: (bp, fcp),
                torque_at: [at(x.speeds_rad_s[0]), at(x.speeds_rad_s[1])],
            }
        }),
        pole_pairs: (r.pole_pairs, m.pole_pairs),
        reversed: (r.angle.reversed, sim.plant.faults().encoder_reversed),
        offsets_a: [o.offsets.a as f64, o.offsets.b as f64, o.offsets.c as f64],
        offset_time_s: o.offset_periods as f64 * ts,
        time_s: o.periods as f64 * ts,
        wall_time_s,
    }
}

/// Run the mission on `setup` (the ideal bench: no low-speed smoothness
/// segment, see [`run_mission_with`]). `progress` is called with the
/// fraction done (0..=1).
pub fn run_mission(setup: &Setup, progress: &mut dyn FnMut(f64)) -> MissionResult {
    match run_mission_from(setup, None, progress) {
        Ok(r) => r,
        // Without a record there is nothing to refuse.
        Err(e) => unreachable!("{e}"),
    }
}

/// [`run_mission`], starting from a stored configuration when `stored` is
/// given (design §17): its settings on top of the setup's, and its
/// calibration installed by the drive's start-up (the bench's encoder
/// reads the same angle for the same rotor position after every start, as
/// an absolute sensor does) instead of an identification. The rest of the
/// mission is the same; its alignment figure then measures the stored
/// electrical zero against the plant's truth. `Err` when the record does
/// not apply to this setup (another PWM frequency, a value out of range,
/// no calibration) or the start-up does not install it.
pub fn run_mission_from(
    setup: &Setup,
    stored: Option<&foc_store::DriveRecord>,
    progress: &mut dyn FnMut(f64),
) -> Result<MissionResult, String> {
    run_mission_with(setup, stored, None, progress)
}

/// [`run_mission_from`], then, where `imperfections` are given (the
/// motor file's, [`MotorFile::imperfections`]: what `cargo xtask sim`
/// runs), the low-speed smoothness segment on them (the module
/// `smoothness.rs`: a separate simulation of the same setup, so every
/// earlier figure is the same as without it).
pub fn run_mission_with(
    setup: &Setup,
    stored: Option<&foc_store::DriveRecord>,
    imperfections: Option<&Imperfections>,
    progress: &mut dyn FnMut(f64),
) -> Result<MissionResult, String> {
    let wall = Instant::now();
    // Without a stored record the drive knows nothing of the rotor's
    // mechanics until its identification has measured them.
    let base = match stored {
        Some(_) => setup.cascade_config(),
        None => setup.unidentified_config(),
    };
    let settings = match stored {
        Some(r) => Some(
            r.apply(&foc_store::Settings::from_cascade(&base), pwm_hz_u32(setup))
                .map_err(|e| e.to_string())?,
        ),
        None => None,
    };
    let config = settings.map_or(base, |s| s.apply_to(&base));
    let sim = Sim::new(setup, config, true);
    let mut plan = MissionPlan::new(setup, &config);
    if imperfections.is_some() {
        plan.expected_s += smoothness_expected_s(setup);
    }
    let total = secs(setup, plan.expected_s).max(1);
    let mut m = Mission {
        setup,
        config,
        plan,
        sim,
        segments: Vec::new(),
        progress: Progress {
            report: progress,
            total,
        },
    };

    // The rotor starts somewhere arbitrary.
    m.sim.set_rotor_angle(0.7);

    let identified = match &settings {
        None => m.identify(),
        Some(s) => m.restore(s)?,
    };
    let i_step = m.current_step(&identified.config);
    m.speed_step();
    m.ramp();
    let load = m.load_step();
    m.load_release();
    m.stop();
    m.saturated_step();
    let p0_true = m.position_move();
    let impedance = m.impedance();
    let braking = m.braking();
    let field_weakening = m.field_weakening();
    let (smoothness, smoothness_trace) = match imperfections {
        Some(imp) => {
            let (s, t) = m.smoothness(imp);
            (Some(s), t)
        }
        None => (None, None),
    };
    (m.progress.report)(1.0);

    let trace = m.sim.take_trace().unwrap_or_default();
    let record = m.record(settings.map_or(auto_link(setup), |s| s.watchdog));
    let mut summary = m.summary(&trace, identified, i_step, load, p0_true, wall);
    summary.restored = stored.is_some();
    summary.braking = Some(braking);
    summary.impedance = Some(impedance);
    summary.field_weakening = Some(field_weakening);
    summary.smoothness = smoothness;
    Ok(MissionResult {
        trace,
        segments: m.segments,
        summary,
        record,
        smoothness_trace,
    })
}

/// The link-watchdog setting a record made by the bench carries: the
/// firmware's automatic one (1 s, stop).
pub(super) fn auto_link(setup: &Setup) -> foc_store::record::WatchdogRecord {
    foc_store::record::WatchdogRecord {
        timeout_periods: pwm_hz_u32(setup),
        reaction: foc_store::record::WatchdogReaction::Stop,
    }
}

/// The setup's PWM frequency as a record states it \[Hz\].
pub(super) fn pwm_hz_u32(setup: &Setup) -> u32 {
    setup.pwm_hz().round() as u32
}

/// The mission's speeds and durations, derived from the setup before it
/// starts.
pub(super) struct MissionPlan {
    /// Torque constant [N m / A].
    pub(super) kt: f32,
    /// Speed step target [rad/s].
    pub(super) w1: f32,
    /// Speed at the end of the ramp [rad/s].
    pub(super) w2: f32,
    /// Duration of the ramp (and of the stop) \[s\].
    pub(super) t_ramp: f64,
    /// Duration of the current-limited step \[s\].
    pub(super) t_sat: f64,
    /// Its current limit \[A\].
    pub(super) i_sat: f32,
    /// Position move \[rad\].
    pub(super) move_rad: f32,
    /// Duration of the position move \[s\].
    pub(super) t_move: f64,
    /// Speed-loop divider of the initial configuration.
    pub(super) speed_div: usize,
    /// The identification's configuration.
    pub(super) id_cfg: foc_core::calibration::identification::IdentificationConfig,
    /// Expected duration of the whole mission, for the progress bar \[s\].
    pub(super) expected_s: f64,
}

impl MissionPlan {
    pub(super) fn new(setup: &Setup, config: &CascadeConfig) -> Self {
        let kt = setup.kt();
        let j = setup.motor.inertia_kg_m2 as f32;
        let w_max = setup.max_speed_rad_s();
        let i_max = setup.max_current_a;
        let speed_div = config.rates.speed_divider.max(1) as usize;
        // Speeds: within the voltage and current limits, and at most one
        // electrical turn per 10 PWM periods (`Setup::max_mission_speed_rad_s`).
        let w_cap = (0.6 * w_max).min(setup.max_mission_speed_rad_s());
        let w1 = (0.4 * w_cap).min(0.4 * i_max * kt / (j * 2.0 * std::f32::consts::PI * 20.0));
        let w2 = w_cap.max(w1);
        let a_ramp = 0.3 * kt * i_max / j;
        let t_ramp = ((w2 - w1) / a_ramp).max(0.1) as f64;
        // The current-limited step: at most the limit's acceleration, then
        // time to settle.
        let i_sat = i_max.min(0.5 * config.speed.kp_a_per_rad_s * w2);
        let t_sat = (w2 * j / (kt * i_sat)) as f64 * 1.5 + 0.4;
        let move_rad = std::f32::consts::TAU;
        let v_traj = config.position.max_velocity_rad_s;
        let a_traj = config.position.max_acceleration_rad_s2;
        let t_move = (move_rad / v_traj + v_traj / a_traj) as f64 + 0.6;
        let id_cfg = identify::config(setup, setup.motor.pole_pairs);
        // The alignment's calibration carries the sensor's resolution, so the
        // current stage adds the half count of a counting sensor to every
        // reading: the zero found is the physical one and the angle the
        // controller uses is unbiased (this matters on the hall-class hub
        // motor: half a count is 30 deg(e) there).
        // Identification: offsets, R and L (about 1 s), both alignment sweeps
        // with their holds, the flux step (about 2 s).
        let a = &id_cfg.alignment;
        let t_align = 2.0
            * (f32::from(a.lead_in_turns_e + a.turns_e) * std::f32::consts::TAU / a.speed_e_rad_s
                + a.hold_s);
        let t_id = 0.1 + 1.0 + t_align as f64 + if id_cfg.measure_flux { 2.0 } else { 0.0 };
        let expected_s = t_id
            + 0.03
            + 0.5
            + t_ramp
            + 0.3
            + 0.6
            + t_ramp
            + 0.4
            + 0.4
            + t_sat
            + t_ramp
            + 0.3
            + t_move
            + 2.0 * (BRAKE_SPIN_S + BRAKE_STOP_S)
            + field_weakening_expected_s(setup);
        Self {
            kt,
            w1,
            w2,
            t_ramp,
            t_sat,
            i_sat,
            move_rad,
            t_move,
            speed_div,
            id_cfg,
            expected_s,
        }
    }
}

/// The braking segment's longest spin-up before each stop \[s\].
pub(super) const BRAKE_SPIN_S: f64 = 1.0;

/// The braking segment's time after each stop command \[s\].
pub(super) const BRAKE_STOP_S: f64 = 0.4;

/// The progress callback and the expected number of periods.
pub(super) struct Progress<'a> {
    pub(super) report: &'a mut dyn FnMut(f64),
    pub(super) total: usize,
}

impl Progress<'_> {
    /// Report the fraction done every 2048 rows.
    pub(super) fn tick(&mut self, sim: &Sim) {
        self.tick_at(sim.rows());
    }

    /// [`Self::tick`] for a simulation that does not record (`rows`
    /// periods done in all).
    pub(super) fn tick_at(&mut self, rows: usize) {
        if rows.is_multiple_of(2048) {
            (self.report)((rows as f64 / self.total as f64).min(1.0));
        }
    }
}

/// What the identification segment left for the rest of the mission.
pub(super) struct Identified {
    /// Its figures (None: it failed).
    pub(super) summary: Option<IdentificationSummary>,
    /// Why it failed.
    pub(super) failure: Option<String>,
    /// The electrical zero in use after it.
    pub(super) found: ElectricalAngle,
    /// Error of `found` against the plant's truth [deg, electrical].
    pub(super) align_error_deg: f64,
    /// The measured configuration, used from here on.
    pub(super) config: CascadeConfig,
}

/// A mission in progress: the simulation and the segments run so far.
pub(super) struct Mission<'a> {
    pub(super) setup: &'a Setup,
    /// The configuration before identification.
    pub(super) config: CascadeConfig,
    pub(super) plan: MissionPlan,
    pub(super) sim: Sim,
    pub(super) segments: Vec<Segment>,
    pub(super) progress: Progress<'a>,
}

impl Mission<'_> {
    /// Run `n` periods, reporting progress.
    pub(super) fn run_ticking(&mut self, n: usize) {
        for _ in 0..n {
            self.sim.step();
            self.progress.tick(&self.sim);
        }
    }

    /// Record the segment `name` from row `start` to now.
    pub(super) fn end_segment(&mut self, name: &'static str, start: usize) {
        self.segments.push(Segment {
            name,
            start,
            end: self.sim.rows(),
        });
    }

    /// Segment 1, identify: current offsets, R, L, gains, alignment, flux
    /// linkage. On failure the rest runs on the supplied calibration.
    pub(super) fn identify(&mut self) -> Identified {
        let setup = self.setup;
        let start = self.sim.rows();
        let id_wall = Instant::now();
        let progress = &mut self.progress;
        let outcome = identify::run(&mut self.sim, setup, self.plan.id_cfg, &mut |s| {
            progress.tick(s)
        });
        let id_wall_s = id_wall.elapsed().as_secs_f64();
        let (summary, failure) = match &outcome {
            Ok(o) => match o.identified() {
                Some(d) => (
                    Some(identification_summary(
                        setup, &self.sim, o, &d.result, id_wall_s,
                    )),
                    None,
                ),
                None => (None, Some(format!("{:?} in {:?}", o.step, o.stage))),
            },
            Err(e) => (None, Some(e.to_string())),
        };
        if summary.is_none() {
            // Run the rest on the bench's knowledge so that the report is
            // complete; `failures()` reports the identification failure.
            self.sim.cascade.command(Command::Disable).ok();
            self.sim.cascade.clear_faults();
            self.sim
                .cascade
                .set_calibration(&setup.supplied_calibration(&self.config));
        }
        self.sim.run(secs(setup, 0.02));
        self.end_segment("identify", start);
        let found = self.sim.cascade.current.config().angle.zero_offset;
        let align_error_deg = found
            .diff_radians(setup.true_angle_calibration().zero_offset)
            .to_degrees() as f64;
        Identified {
            summary,
            failure,
            found,
            align_error_deg,
            config: *self.sim.cascade.config(),
        }
    }

    /// Segment 1 from a stored configuration: the drive's start-up (offsets,
    /// sensor check) installs the stored permit, no identification.
    pub(super) fn restore(&mut self, s: &foc_store::Settings) -> Result<Identified, String> {
        let setup = self.setup;
        let permit = s.permit().ok_or(
            "the configuration has no calibration (save one with `cargo xtask sim --save-config FILE`)",
        )?;
        let start = self.sim.rows();
        let mut life = identify::lifecycle_config(&self.sim, setup, self.plan.id_cfg);
        life.identify_at_start_up = false;
        life.angle_kind = foc_core::drive::AngleKind::Absolute;
        life.stored = Some(permit);
        self.sim.cascade = Cascade::from_reset(self.config, life);
        let limit = secs(setup, 1.0);
        let mut restored = false;
        for _ in 0..limit {
            self.sim.step();
            match self.sim.cascade.last_output().and_then(|o| o.event) {
                Some(foc_core::drive::Event::CalibrationRestored) => {
                    restored = true;
                    break;
                }
                Some(e @ foc_core::drive::Event::StartUpDone)
                | Some(e @ foc_core::drive::Event::OffsetsFailed(_))
                | Some(e @ foc_core::drive::Event::CurrentSenseFailed)
                | Some(e @ foc_core::drive::Event::SensorCheckFailed) => {
                    return Err(format!("start-up did not restore the calibration: {e:?}"))
                }
                _ => {}
            }
        }
        if !restored {
            return Err("start-up did not end within 1 s simulated".into());
        }
        self.sim.run(secs(setup, 0.02));
        self.end_segment("identify", start);
        let found = self.sim.cascade.current.config().angle.zero_offset;
        let align_error_deg = found
            .diff_radians(setup.true_angle_calibration().zero_offset)
            .to_degrees() as f64;
        Ok(Identified {
            summary: None,
            failure: None,
            found,
            align_error_deg,
            config: *self.sim.cascade.config(),
        })
    }

    /// The configuration in force as a record (calibrated when the stage is).
    pub(super) fn record(&self, link: foc_store::record::WatchdogRecord) -> foc_store::DriveRecord {
        let c = self.sim.cascade.config();
        let mut s = foc_store::Settings::from_cascade(c);
        s.calibrated = self.sim.cascade.is_calibrated();
        s.watchdog = link;
        let mut label = foc_store::Label::new();
        for ch in self.setup.name.chars().filter(|c| (' '..='~').contains(c)) {
            if label.push(ch).is_err() {
                break;
            }
        }
        foc_store::DriveRecord::from_settings(&label, pwm_hz_u32(self.setup), &s)
    }

    /// The segment `name` (every segment is recorded once).
    pub(super) fn segment(&self, name: &str) -> Segment {
        self.segments
            .iter()
            .find(|s| s.name == name)
            .cloned()
            .unwrap()
    }

    /// The mission's figures from its `trace`.
    pub(super) fn summary(
        &self,
        trace: &Trace,
        identified: Identified,
        i_step: f32,
        load: f32,
        p0_true: f64,
        wall: Instant,
    ) -> MissionSummary {
        let setup = self.setup;
        let periods = trace.len();
        let ts = 1.0 / setup.bench.pwm_frequency_hz as f64;
        let cpr = setup.bench.sensors.encoder_counts_per_rev.max(1);
        let i_step = i_step as f64;
        let current = current_step_figures(setup, trace, &self.segment("current step"), i_step);
        let w1 = self.plan.w1 as f64;
        let speed = speed_step_figures(trace, &self.segment("speed step"), w1, ts);
        let w2d = self.plan.w2 as f64;
        let load_figures = load_step_figures(setup, trace, &self.segment("load step"), w2d, ts);
        let move_d = self.plan.move_rad as f64;
        let ps = self.segment("position move");
        let position = position_figures(setup, trace, &ps, p0_true, move_d, ts);
        let config = identified.config;
        MissionSummary {
            motor: setup.name.clone(),
            pwm_hz: setup.pwm_hz(),
            dividers: (config.rates.speed_divider, config.rates.position_divider),
            identification: identified.summary,
            restored: false,
            identification_failure: identified.failure,
            align_found_deg: identified.found.to_degrees() as f64,
            align_error_deg: identified.align_error_deg,
            current_step_a: i_step,
            current_step_magnitude: current.0,
            current_overshoot_percent: current.1,
            current_settling_periods: current.2,
            current_id_peak_a: current.3,
            speed_step_rad_s: w1,
            speed_overshoot_percent: speed.0,
            speed_settling_ms: speed.1,
            speed_high_rad_s: w2d,
            load_step_nm: load as f64,
            load_dip_rad_s: load_figures.0,
            load_steady_error_rad_s: load_figures.1,
            load_recovery_ms: load_figures.2,
            speed: self.speed_figures(trace, w1, w2d, ts),
            move_rad: move_d,
            position_settling_ms: position.0,
            position_final_error_rad: position.1,
            encoder_count_rad: std::f64::consts::TAU / cpr as f64,
            braking: None,
            impedance: None,
            field_weakening: None,
            smoothness: None,
            faults: mission_faults(trace),
            model_margin: self.sim.cascade.current.model_check().peak_ratio() as f64,
            model_disturbance_margin: self
                .sim
                .cascade
                .current
                .model_check()
                .peak_disturbance_ratio() as f64,
            periods,
            sim_time_s: periods as f64 * ts,
            wall_time_s: wall.elapsed().as_secs_f64(),
        }
    }
}

impl Mission<'_> {
    /// The speed loop's further figures from `trace`.
    pub(super) fn speed_figures(&self, trace: &Trace, w1: f64, w2: f64, ts: f64) -> SpeedFigures {
        let est_err = |seg: &Segment, step: f64| {
            let e = estimate_error_accelerating(trace, seg, step);
            (e, 100.0 * e / step.abs().max(1e-9))
        };
        let rel = self.segment("load release");
        let w = &col(trace, "speed_rad_s")[rel.start..rel.end];
        let release_rise_rad_s = w.iter().fold(0.0f64, |m, v| m.max(v - w2));
        let tol = 0.02 * w2.abs();
        let release_recovery_ms = match w.iter().rposition(|v| (v - w2).abs() > tol) {
            None => Some(0.0),
            Some(i) if i + 1 < w.len() => Some(ms(i + 1, ts)),
            Some(_) => None,
        };
        let sat = self.segment("current-limited step");
        let (sat_overshoot_percent, sat_settling_ms) = speed_step_figures(trace, &sat, w2, ts);
        // The limit is on the torque asked, `T / kt` (design §30): with
        // MTPA the q current that gives it is smaller, the d current adding
        // reluctance torque.
        let iq_ref = &col(trace, "iq_ref_a")[sat.start..sat.end];
        let id_ref = &col(trace, "id_ref_a")[sat.start..sat.end];
        let lim = self.plan.i_sat as f64;
        let field = self.sim.cascade.current.field();
        let on_limit = iq_ref
            .iter()
            .zip(id_ref)
            .filter(|(q, d)| {
                let asked = field.torque_iq_a(foc_core::frames::Dq::new(**d as f32, **q as f32));
                f64::from(asked.abs()) >= 0.98 * lim
            })
            .count();
        let peak_acc = |seg: &Segment| {
            let ws = &col(trace, "speed_rad_s")[seg.start..seg.end];
            // Over 1 ms (the speed's quantisation is smoothed out).
            let n = ((1e-3 / ts).round() as usize).max(1);
            ws.windows(n + 1)
                .map(|p| ((p[n] - p[0]) / (n as f64 * ts)).abs())
                .fold(0.0f64, f64::max)
        };
        let step = self.segment("speed step");
        SpeedFigures {
            estimate_error: est_err(&step, w1),
            release_rise_rad_s,
            release_recovery_ms,
            sat_step_rad_s: w2,
            sat_limit_a: lim,
            sat_overshoot_percent,
            sat_settling_ms,
            sat_limited_ms: ms(on_limit, ts),
            sat_estimate_error: est_err(&sat, w2),
            sat_peak_acceleration_rad_s2: peak_acc(&sat),
            step_peak_acceleration_rad_s2: peak_acc(&step),
        }
    }
}

/// Simulation speed: controller steps per second alone (on a fixed sample)
/// and plant + controller periods per second, each measured for about
/// `seconds` of wall time.
pub fn bench_speed(setup: &Setup, seconds: f64) -> (f64, f64) {
    let config = setup.cascade_config();
    // Controller alone, torque mode, on a real sample.
    let mut sim = Sim::new_calibrated(setup, config, false);
    sim.cascade
        .command(Command::Torque {
            iq_a: 0.1 * setup.rated_current_a,
        })
        .ok();
    sim.run(10);
    let sample = sample_of(sim.last_sample());
    let mut c = sim.cascade;
    let t = Instant::now();
    let mut n = 0u64;
    let mut acc = 0.0f32;
    while t.elapsed().as_secs_f64() < seconds {
        for _ in 0..10_000 {
            if let BridgeCommand::Duties(d) = c.step(std::hint::black_box(&sample)) {
                acc += d[0];
            }
        }
        n += 10_000;
    }
    std::hint::black_box(acc);
    let ctrl = n as f64 / t.elapsed().as_secs_f64();
    // Plant + controller, velocity mode.
    let mut sim = Sim::new_calibrated(setup, config, false);
    sim.cascade
        .command(Command::Velocity {
            rad_s: 0.2 * setup.max_speed_rad_s(),
        })
        .ok();
    let t = Instant::now();
    let mut n = 0u64;
    while t.elapsed().as_secs_f64() < seconds {
        sim.run(1000);
        n += 1000;
    }
    let both = n as f64 / t.elapsed().as_secs_f64();
    (ctrl, both)
}
