//! `config`: read, save, load, erase, export and import the drive's
//! configuration record.

use super::*;

/// What a `config` Nack means for the operation `what`, with a hint.
pub(super) fn config_error(what: &str, e: ClientError) -> Box<dyn std::error::Error> {
    let ClientError::Nack(code) = e else {
        return format!("{what}: {e}").into();
    };
    let hint = match code {
        ErrorCode::NotDisabled => "disable the drive first (`foc-ctl mode disable`)",
        ErrorCode::Busy => "the drive is starting up or calibrating; try again when it is done",
        ErrorCode::NothingStored => {
            "the flash store is empty; `foc-ctl config save` writes the configuration in force"
        }
        ErrorCode::BadRecord if what == "config save" => {
            "a value in force is out of range for a record (see `config show`); nothing was written"
        }
        ErrorCode::BadRecord if what.starts_with("reading") => {
            "the stored record is corrupt, from another version or out of range; \
             `config erase` clears it, `config import FILE` sends a good one"
        }
        ErrorCode::BadRecord => {
            "the configuration in force is unchanged; `config erase` clears a bad stored record, \
             `config import FILE` sends a good one"
        }
        ErrorCode::StoreFailed => {
            "the configuration in force is unchanged; the stored record may be the old one, \
             check it with `config show --stored`"
        }
        ErrorCode::Unsupported => "this device has no configuration store",
        _ => "nothing was changed",
    };
    format!(
        "{what}: refused by the device: {} ({hint})",
        describe_error(code)
    )
    .into()
}

pub(super) fn source_name(source: ConfigSource) -> &'static str {
    match source {
        ConfigSource::Live => "live",
        ConfigSource::Stored => "stored",
    }
}

/// The live or stored record from the device, decoded; a record that
/// fails its CRC or version check is an error that says so, an
/// out-of-range one a warning.
pub(super) fn read_record(
    c: &mut Client,
    source: ConfigSource,
) -> Result<DriveRecord, Box<dyn std::error::Error>> {
    let name = source_name(source);
    let bytes = c
        .read_config(source)
        .map_err(|e| config_error(&format!("reading the {name} record"), e))?;
    let r = DriveRecord::decode(&bytes).map_err(|e| {
        format!(
            "the {name} record from the device ({} bytes) is not readable: {e}",
            bytes.len()
        )
    })?;
    if let Err(e) = r.validate() {
        say_err!(
            "warning: the {name} record has a value out of range ({e}); it would be refused on import"
        );
    }
    Ok(r)
}

/// `config ...`.
pub(super) fn config(c: &mut Client, op: ConfigCmd) -> CliResult {
    let source = |stored: bool| {
        if stored {
            ConfigSource::Stored
        } else {
            ConfigSource::Live
        }
    };
    match op {
        ConfigCmd::Show { stored } => {
            let r = read_record(c, source(stored))?;
            say_raw!("{}", to_toml(&r));
        }
        ConfigCmd::Export { file, stored } => {
            let r = read_record(c, source(stored))?;
            std::fs::write(&file, to_toml(&r))
                .map_err(|e| format!("cannot write {}: {e}", file.display()))?;
            say!("wrote {}", file.display());
        }
        ConfigCmd::Save => {
            c.store(StoreOp::Save)
                .map_err(|e| config_error("config save", e))?;
            say!("saved the configuration in force");
        }
        ConfigCmd::Load => {
            c.store(StoreOp::Load)
                .map_err(|e| config_error("config load", e))?;
            say!("loaded and applied the stored record");
        }
        ConfigCmd::Erase => {
            c.store(StoreOp::Erase)
                .map_err(|e| config_error("config erase", e))?;
            say!(
                "erased the store (the configuration in force is kept; the next boot starts from the defaults)"
            );
        }
        ConfigCmd::Import { file, no_save } => import(c, &file, no_save)?,
    }
    Ok(())
}

/// `config import FILE [--no-save]`: parse and validate on the host (nothing
/// is sent for a bad file), check the PWM frequency, then send, apply and
/// (unless `no_save`) save.
pub(super) fn import(c: &mut Client, file: &Path, no_save: bool) -> CliResult {
    let text = std::fs::read_to_string(file)
        .map_err(|e| format!("cannot read {}: {e}", file.display()))?;
    let r = from_toml(&text)
        .map_err(|e| format!("{}: {e} (nothing was sent to the device)", file.display()))?;
    let mut buf = [0u8; MAX_RECORD_BYTES];
    let n = r
        .encode(&mut buf)
        .map_err(|e| format!("{}: cannot encode the record: {e:?}", file.display()))?;
    match c.param(ParamId::PwmFrequencyHz) {
        Ok(pwm) if pwm != r.pwm_frequency_hz as f32 => {
            return Err(format!(
                "{}: made for a PWM frequency of {} Hz, the drive runs at {pwm} Hz                  (the gains and watchdog periods would be wrong; nothing was sent)",
                file.display(),
                r.pwm_frequency_hz
            )
            .into())
        }
        Ok(_) | Err(ClientError::Nack(ErrorCode::Unsupported)) => {}
        Err(e) => return Err(e.into()),
    }
    c.write_config(&buf[..n])
        .map_err(|e| config_error("config import (sending the record)", e))?;
    let op = if no_save {
        StoreOp::Apply
    } else {
        StoreOp::ApplyAndSave
    };
    c.store(op).map_err(|e| {
        // A rule the host cannot check (the drive's angle sensor) named.
        let hint = match e {
            ClientError::Nack(ErrorCode::BadRecord) => refusal::record_refusal_hint(&r),
            _ => None,
        };
        let base = config_error("config import", e);
        match hint {
            Some(h) => format!("{base}; {h}").into(),
            None => base,
        }
    })?;
    if no_save {
        say!(
            "applied {} (not saved: `foc-ctl config save` keeps it)",
            file.display()
        );
    } else {
        say!("applied and saved {}", file.display());
    }
    Ok(())
}
