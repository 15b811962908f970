//! What the sensors read at the sampling instant (offsets, noise,
//! quantisation, the angle sensor's error, faults).

use super::*;

impl Plant {
    /// What the ADCs and the encoder read now.
    pub(super) fn sample(&mut self) -> Measurements {
        let s = self.cfg.sensors;
        let i_abc = self.phase_currents_a();
        let drives = self.drives(0.0, 1.0, i_abc);
        let i_short = self.short_current(&drives, self.v_bus);
        let mut legs = i_abc;
        if let Some(sh) = self.faults.phase_short {
            legs[sh.a.index()] += i_short;
            legs[sh.b.index()] -= i_short;
        }
        let levels = (1u64 << s.adc_bits.min(31)) as Real;
        let lsb_i = 2.0 * s.current_full_scale_a / levels;
        let mut read = [0.0f32; 3];
        for k in 0..3 {
            let raw = legs[k] + s.current_offset_a[k] + self.faults.current_offset_error_a[k];
            let sign = if self.faults.current_reversed.map(Phase::index) == Some(k) {
                -1.0
            } else {
                1.0
            };
            let noise = s.current_noise_lsb_rms * self.rng.gaussian() as Real;
            let counts = real::floor(sign * raw / lsb_i + levels / 2.0 + noise + 0.5)
                .clamp(0.0, levels - 1.0);
            read[k] = ((counts - levels / 2.0) * lsb_i) as f32;
        }
        if let Some(p) = self.faults.nan_current {
            read[p.index()] = f32::NAN;
        }
        let currents = match s.shunts {
            Shunts::Two => PhaseCurrents::TwoPhase {
                a_a: read[0],
                b_a: read[1],
            },
            Shunts::Three => PhaseCurrents::ThreePhase(Abc::new(read[0], read[1], read[2])),
        };

        // Encoder.
        let cpr = s.encoder_counts_per_rev.max(1);
        let dir = if self.faults.encoder_reversed {
            -1.0
        } else {
            1.0
        };
        let read_m_rad = match self.sensor_error {
            // The disc's error, before quantisation.
            Some(_) => self.theta_m + self.angle_sensor_error_rad(),
            None => self.theta_m,
        };
        let turns = (dir * (read_m_rad - self.sensor_zero_m_rad) - s.encoder_offset_rad) / TAU;
        let frac = turns - real::floor(turns);
        let mut counts = (real::floor(frac * cpr as Real) as i64).rem_euclid(cpr as i64);
        match self.faults.encoder {
            EncoderFault::None => {}
            EncoderFault::Stuck => counts = self.last_encoder_counts as i64,
            EncoderFault::Jump(j) => counts = (counts + j as i64).rem_euclid(cpr as i64),
        }
        self.last_encoder_counts = counts as u32;
        let bits = ((counts as u128) << 32) / cpr as u128;
        let angle = MechanicalAngle::from_bits(bits as u32);
        let index = self.index_crossed();

        // Bus voltage.
        let lsb_v = s.bus_full_scale_v / levels;
        let noise = s.bus_noise_lsb_rms * self.rng.gaussian() as Real;
        let vc = real::floor(self.v_bus / lsb_v + noise + 0.5).clamp(0.0, levels - 1.0);

        Measurements {
            currents,
            angle,
            index,
            v_bus_v: (vc * lsb_v) as f32,
            stage_temperature_c: self.stage_thermal.map(|_| self.t_stage_c as f32),
            time_s: self.time_s,
            period: self.period,
        }
    }

    /// The encoder's index mark at `theta_m_rad` (mechanical, the rotor's
    /// angle at which it pulses; `None`: no index).
    pub fn set_encoder_index(&mut self, theta_m_rad: Option<Real>) {
        self.encoder_index_m_rad = theta_m_rad;
        self.index_last_pos_rad = self.position_rad();
    }

    /// The reading the encoder latches at its index pulse, when the rotor
    /// crossed the mark since the last sample (either way): the count at
    /// the mark, through the same direction, offset and sensor error as
    /// the reading.
    fn index_crossed(&mut self) -> Option<MechanicalAngle> {
        let mark = self.encoder_index_m_rad?;
        let (from, to) = (self.index_last_pos_rad, self.position_rad());
        self.index_last_pos_rad = to;
        let k_from = real::floor((from - mark) / TAU);
        let k_to = real::floor((to - mark) / TAU);
        if k_from == k_to {
            return None;
        }
        let s = self.cfg.sensors;
        let cpr = s.encoder_counts_per_rev.max(1);
        let dir = if self.faults.encoder_reversed {
            -1.0
        } else {
            1.0
        };
        let error = match (self.sensor_error, self.angle_sensor) {
            (None, _) => 0.0,
            (Some(e), AngleSensorKind::Absolute { .. }) => e.error_rad(mark),
            (Some(e), AngleSensorKind::Incremental) => {
                e.error_rad(mark) - e.error_rad(self.sensor_zero_m_rad)
            }
        };
        let turns = (dir * (mark + error - self.sensor_zero_m_rad) - s.encoder_offset_rad) / TAU;
        let frac = turns - real::floor(turns);
        let counts = (real::floor(frac * cpr as Real) as i64).rem_euclid(cpr as i64);
        let bits = ((counts as u128) << 32) / cpr as u128;
        Some(MechanicalAngle::from_bits(bits as u32))
    }
}
