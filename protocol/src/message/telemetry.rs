//! [`Telemetry`]: one sample of the drive, and the wire codes of its
//! fields (mode, active limit, temperatures, timeout reaction).

use super::*;
pub use foc_core::control::AngleInUse;

/// One telemetry sample. Equality compares the temperatures as they
/// travel (0.1 deg C, "none" equal to "none"), every other field exactly.
#[derive(Clone, Copy, Debug)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Telemetry {
    /// Current-loop period counter (wraps).
    pub period: u32,
    /// Measured d current \[A\].
    pub i_d_a: f32,
    /// Measured q current \[A\].
    pub i_q_a: f32,
    /// Commanded d voltage \[V\].
    pub v_d_v: f32,
    /// Commanded q voltage \[V\].
    pub v_q_v: f32,
    /// Mechanical velocity [rad/s]: the drive's (rotor frame) from
    /// [`Self::from_feedback`]; on the wire the output frame's (the
    /// device converts, see [`crate::joint`]).
    pub velocity_rad_s: f32,
    /// Multi-turn mechanical position \[rad\]: rotor frame from
    /// [`Self::from_feedback`], output frame on the wire.
    pub position_rad: f32,
    /// Active mode.
    pub mode: Mode,
    /// First latched fault code (0: none).
    pub fault_code: u8,
    /// Longest current-loop run [CPU cycles].
    pub max_loop_cycles: u32,
    /// Bus voltage \[V\].
    pub v_bus_v: f32,
    /// The power limit that cut the q-current window the most (design
    /// §18; `None` while nothing is cut).
    pub power_limit: ActiveLimit,
    /// Share of the current limit left at that end [%] (100: nothing
    /// cut; rounded down, so 99 means a cut of at most 1 %).
    pub limit_left_pct: u8,
    /// The brake chopper conducts.
    pub brake_on: bool,
    /// The brake chopper's guard has locked it out.
    pub brake_locked: bool,
    /// Estimated winding temperature [deg C] (NaN: no power limits; 0.1
    /// deg C on the wire).
    pub winding_c: f32,
    /// Measured power-stage temperature [deg C] (NaN: no sensor or no
    /// reading; 0.1 deg C on the wire).
    pub stage_c: f32,
    /// Where the current loop's angle came from (design §27: the sensor,
    /// sensorless, the observer beside the sensor above its speed, or
    /// limp-home); bits 2 and 3 of the flags byte on the wire.
    pub angle_in_use: AngleInUse,
}

impl PartialEq for Telemetry {
    fn eq(&self, o: &Self) -> bool {
        self.period == o.period
            && self.i_d_a == o.i_d_a
            && self.i_q_a == o.i_q_a
            && self.v_d_v == o.v_d_v
            && self.v_q_v == o.v_q_v
            && self.velocity_rad_s == o.velocity_rad_s
            && self.position_rad == o.position_rad
            && self.mode == o.mode
            && self.fault_code == o.fault_code
            && self.max_loop_cycles == o.max_loop_cycles
            && self.v_bus_v == o.v_bus_v
            && self.power_limit == o.power_limit
            && self.limit_left_pct == o.limit_left_pct
            && self.brake_on == o.brake_on
            && self.brake_locked == o.brake_locked
            && self.angle_in_use == o.angle_in_use
            && temperature_to_wire(self.winding_c) == temperature_to_wire(o.winding_c)
            && temperature_to_wire(self.stage_c) == temperature_to_wire(o.stage_c)
    }
}

impl Telemetry {
    /// A zero sample (disabled).
    pub const ZERO: Self = Self {
        period: 0,
        i_d_a: 0.0,
        i_q_a: 0.0,
        v_d_v: 0.0,
        v_q_v: 0.0,
        velocity_rad_s: 0.0,
        position_rad: 0.0,
        mode: Mode::Disabled,
        fault_code: 0,
        max_loop_cycles: 0,
        v_bus_v: 0.0,
        power_limit: ActiveLimit::None,
        limit_left_pct: 100,
        brake_on: false,
        brake_locked: false,
        winding_c: f32::NAN,
        stage_c: f32::NAN,
        angle_in_use: AngleInUse::Sensor,
    };

    /// The sample of a current-stage [`Feedback`].
    pub fn from_feedback(fb: &Feedback, max_loop_cycles: u32) -> Self {
        Self {
            period: fb.period,
            i_d_a: fb.i_dq_a.d,
            i_q_a: fb.i_dq_a.q,
            v_d_v: fb.v_dq_v.d,
            v_q_v: fb.v_dq_v.q,
            velocity_rad_s: fb.velocity_rad_s,
            position_rad: fb.position_rad,
            mode: fb.mode,
            fault_code: fb.first_fault.map_or(0, Fault::code),
            max_loop_cycles,
            v_bus_v: fb.v_bus_v,
            power_limit: fb.power.active,
            limit_left_pct: percent(fb.power.factor),
            brake_on: fb.power.brake_on,
            brake_locked: fb.power.brake_locked,
            winding_c: fb.power.winding_c,
            stage_c: fb.power.stage_c,
            angle_in_use: fb.angle_in_use,
        }
    }
}

/// `f` in `[0, 1]` as a whole percentage, rounded down (NaN: 0).
pub(super) fn percent(f: f32) -> u8 {
    let p = f * 100.0;
    if p >= 100.0 {
        100
    } else if p >= 0.0 {
        p as u8
    } else {
        0
    }
}

/// Wire code of "no temperature" ([`Telemetry::winding_c`], `stage_c`).
pub const NO_TEMPERATURE: i16 = i16::MIN;

/// A temperature [deg C] in 0.1 deg C (saturated; NaN: [`NO_TEMPERATURE`]).
pub fn temperature_to_wire(t_c: f32) -> i16 {
    let d = t_c * 10.0;
    if d.is_nan() {
        NO_TEMPERATURE
    } else if d >= 32767.0 {
        i16::MAX
    } else if d <= -32767.0 {
        -i16::MAX
    } else {
        // Round half away from zero without `round` (no_std).
        (if d >= 0.0 { d + 0.5 } else { d - 0.5 }) as i16
    }
}

/// A wire temperature back in deg C ([`NO_TEMPERATURE`]: NaN).
pub fn temperature_from_wire(w: i16) -> f32 {
    if w == NO_TEMPERATURE {
        f32::NAN
    } else {
        f32::from(w) / 10.0
    }
}

/// [`ActiveLimit`] from its wire code (its `u8` value).
pub const fn active_limit_from_code(c: u8) -> Option<ActiveLimit> {
    Some(match c {
        0 => ActiveLimit::None,
        1 => ActiveLimit::Regen,
        2 => ActiveLimit::BusCurrentMotoring,
        3 => ActiveLimit::BusCurrentRegen,
        4 => ActiveLimit::PowerMotoring,
        5 => ActiveLimit::PowerRegen,
        6 => ActiveLimit::WindingTemperature,
        7 => ActiveLimit::StageTemperature,
        8 => ActiveLimit::MissingSensor,
        9 => ActiveLimit::InvalidModel,
        _ => return None,
    })
}

/// Mode from its wire code ([`Mode`] as `u8`).
pub const fn mode_from_code(c: u8) -> Option<Mode> {
    match c {
        0 => Some(Mode::Disabled),
        1 => Some(Mode::Torque),
        2 => Some(Mode::Velocity),
        3 => Some(Mode::Position),
        4 => Some(Mode::OpenLoop),
        5 => Some(Mode::Impedance),
        _ => None,
    }
}

/// Timeout reaction wire code.
pub const fn reaction_code(r: TimeoutReaction) -> u8 {
    match r {
        TimeoutReaction::Disable => 0,
        TimeoutReaction::Stop => 1,
        TimeoutReaction::Hold => 2,
    }
}

/// Timeout reaction from its wire code.
pub const fn reaction_from_code(c: u8) -> Option<TimeoutReaction> {
    match c {
        0 => Some(TimeoutReaction::Disable),
        1 => Some(TimeoutReaction::Stop),
        2 => Some(TimeoutReaction::Hold),
        _ => None,
    }
}
