//! The main scenario's sensorless part (design §27): the emulated board's
//! firmware switched to its flux observer by a configuration record, as a
//! user does it (`foc-ctl config import` of a `[sensorless]` table), and
//! the observer beside the encoder taking over when the encoder jumps
//! (limp-home).

use foc_core::control::{AngleInUse, Command as DriveCommand, Fault};
use foc_ctl::ClientError;
use foc_protocol::config::{ConfigSource, StoreOp};
use foc_protocol::message::{ErrorCode, ParamId};
use foc_store::record::{BesideRole, MechanicsRecord, SensorlessRecord};
use foc_store::DriveRecord;

use super::{motor, near, Rig};
use crate::e2e::{check, client_err};
use crate::util::{Error, Result};

/// The commanded speed [rad/s, mechanical]: well above the hand-over speed
/// (about 28 rad/s for the emulated motor at a 5 A start).
const SPEED_RAD_S: f32 = 100.0;

/// From rest: the live record with a `[sensorless]` table applied (the
/// plant's mechanics when the record has none); the drive reports it
/// (`angle-source` 1) and refuses a torque command (`NeedsAngleSensor`);
/// the encoder is made to jump by a quarter turn and the drive, which
/// ignores it, starts from standstill and reaches +100 rad/s, then
/// reverses to -100 rad/s, each within 2 rad/s (the plant's true speed),
/// with no fault. Then stopped, the encoder restored and the record
/// without the table applied: back on the encoder (`angle-source` 0), it
/// runs at 50 rad/s again.
pub(super) fn sensorless_run(r: &mut Rig) -> Result {
    to_rest(r)?;
    let (rec, sensor) = with_sensorless_table(r, None)?;
    apply(r, &rec)?;
    angle_source(r, 1.0)?;
    let refused = r.s.client.set_command(DriveCommand::Torque { iq_a: 0.5 });
    check(
        matches!(refused, Err(ClientError::Nack(ErrorCode::NeedsAngleSensor))),
        format!("sensorless: a torque command is refused ({refused:?})"),
    )?;
    r.inst.act("jump 1024")?;
    for target in [SPEED_RAD_S, -SPEED_RAD_S] {
        // The command again every 0.3 s, as an operator's tool keeps it
        // alive (the link watchdog's timeout is shorter than the run).
        let mut t = None;
        for _ in 0..3 {
            r.command(DriveCommand::Velocity { rad_s: target })?;
            t = Some(r.s.let_pass(0.3)?);
        }
        let t = t.ok_or_else(|| Error("no telemetry".into()))?;
        let tr = r.inst.truth()?;
        check(
            t.fault_code == 0 && near(tr.omega_rad_s, target, 2.0),
            format!(
                "sensorless, encoder off by a quarter turn: {target} rad/s within 2 rad/s ({:.2}; drive: {:.2} rad/s, {:?}, fault {:?})",
                tr.omega_rad_s,
                t.velocity_rad_s,
                t.mode,
                Fault::from_code(t.fault_code)
            ),
        )?;
    }
    to_rest(r)?;
    r.inst.act("clear")?;
    apply(r, &sensor)?;
    angle_source(r, 0.0)?;
    r.command(DriveCommand::Velocity { rad_s: 50.0 })?;
    r.s.let_pass(0.4)?;
    let tr = r.inst.truth()?;
    check(
        r.first_fault()?.is_none() && near(tr.omega_rad_s, 50.0, 2.0),
        format!(
            "back on the encoder: 50 rad/s within 2 rad/s ({:.2})",
            tr.omega_rad_s
        ),
    )
}

/// Limp-home (design §27): the live record with a `[sensorless]` table
/// whose `beside_sensor` is `"limp-home"` applied; the drive runs at
/// +100 rad/s on its encoder (`angle-source` 0), the encoder jumps by a
/// quarter turn, and the observer beside it takes over: no fault, the
/// speed within 2 rad/s (the plant's true one), the telemetry's angle in
/// use `LimpHome` and `angle-source` 3. Then stopped, the encoder restored
/// and the record without the table applied (`angle-source` 0).
pub(super) fn limp_home_run(r: &mut Rig) -> Result {
    to_rest(r)?;
    let (rec, sensor) = with_sensorless_table(r, Some(BesideRole::LimpHome))?;
    apply(r, &rec)?;
    angle_source(r, 0.0)?;
    for _ in 0..2 {
        r.command(DriveCommand::Velocity { rad_s: SPEED_RAD_S })?;
        r.s.let_pass(0.3)?;
    }
    r.inst.act("jump 1024")?;
    let mut t = None;
    for _ in 0..2 {
        r.command(DriveCommand::Velocity { rad_s: SPEED_RAD_S })?;
        t = Some(r.s.let_pass(0.3)?);
    }
    let t = t.ok_or_else(|| Error("no telemetry".into()))?;
    let tr = r.inst.truth()?;
    check(
        t.fault_code == 0
            && t.angle_in_use == AngleInUse::LimpHome
            && near(tr.omega_rad_s, SPEED_RAD_S, 2.0),
        format!(
            "limp-home: the encoder jumped at {SPEED_RAD_S} rad/s, the observer took over ({:?}), {:.2} rad/s true (fault {:?})",
            t.angle_in_use,
            tr.omega_rad_s,
            Fault::from_code(t.fault_code)
        ),
    )?;
    angle_source(r, 3.0)?;
    to_rest(r)?;
    r.inst.act("clear")?;
    apply(r, &sensor)?;
    angle_source(r, 0.0)
}

/// The live record with a `[sensorless]` table in the role `beside`
/// (`None`: without the sensor) and the plant's mechanics when it has
/// none, and the live record as it was.
fn with_sensorless_table(
    r: &mut Rig,
    beside: Option<BesideRole>,
) -> Result<(DriveRecord, DriveRecord)> {
    let live =
        r.s.client
            .read_config(ConfigSource::Live)
            .map_err(client_err("read the live configuration"))?;
    let mut rec = DriveRecord::decode(&live).map_err(|e| Error(format!("live record: {e}")))?;
    let sensor = rec.clone();
    let m = motor();
    rec.mechanics = rec.mechanics.or(Some(MechanicsRecord {
        inertia_kg_m2: m.inertia_kg_m2 as f32,
        viscous_friction_nm_s_per_rad: m.viscous_friction_nm_s_per_rad as f32,
        coulomb_friction_nm: m.coulomb_friction_nm as f32,
    }));
    rec.sensorless = Some(SensorlessRecord {
        start_current_a: (0.5 * rec.limits.max_current_a).min(5.0),
        bus_voltage_v: 24.0,
        beside_sensor: beside,
        observer_above_rad_s: None,
    });
    Ok((rec, sensor))
}

/// Velocity 0 for 0.5 s, then disabled.
fn to_rest(r: &mut Rig) -> Result {
    r.command(DriveCommand::Velocity { rad_s: 0.0 })?;
    r.s.let_pass(0.5)?;
    r.command(DriveCommand::Disable)?;
    r.s.let_pass(0.02)?;
    Ok(())
}

/// Stage `rec` and apply it (not saved).
fn apply(r: &mut Rig, rec: &DriveRecord) -> Result {
    let mut buf = [0u8; foc_store::MAX_RECORD_BYTES];
    let n = rec
        .encode(&mut buf)
        .map_err(|e| Error(format!("encode the record: {e}")))?;
    let c = &mut r.s.client;
    c.write_config(buf.get(..n).unwrap_or(&[]))
        .map_err(client_err("stage the record"))?;
    c.store(StoreOp::Apply)
        .map_err(client_err("apply the record"))?;
    // The drive takes the change at a period boundary.
    r.s.let_pass(0.01)?;
    Ok(())
}

/// The drive reports `want` as its angle source.
fn angle_source(r: &mut Rig, want: f32) -> Result {
    let got =
        r.s.client
            .param(ParamId::AngleSource)
            .map_err(client_err("read angle-source"))?;
    check(
        got == want,
        format!("angle-source reads {got} (expect {want})"),
    )
}
