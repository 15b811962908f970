//! The configuration store of this board (design §17): what boot does with
//! it, and the flash operations behind the command channel's `Store`
//! requests. The record format, its checks and the power-fail-safe log are
//! `foc_store`'s (host-tested there); the region and the flash driver are
//! the board's (`board::STORE_RANGE`, `board::StoreFlash`).

use crate::{config, watchdog};
use board_support::board;
use core::sync::atomic::{AtomicBool, Ordering};
use foc_core::drive::cascade::CascadeConfig;
use foc_protocol::WatchdogConfig;
use foc_store::record::WatchdogRecord;
use foc_store::settings::{reaction_record, timeout_reaction};
use foc_store::{DriveRecord, Invalid, Label, Settings, Store};

/// The store over this board's flash region.
pub type BoardStore = Store<board::StoreFlash>;

/// The board's PWM frequency, which a record's gains must have been made for.
const PWM_HZ: u32 = board::PWM_FREQUENCY_HZ;

// The link must move the largest record the store writes.
const _: () = assert!(foc_store::MAX_RECORD_BYTES <= foc_protocol::config::MAX_RECORD);

/// The build-time settings (`config::cascade`), uncalibrated.
pub fn build_time_settings() -> Settings {
    Settings::from_cascade(&config::cascade(PWM_HZ as f32))
}

/// What boot found.
pub struct Boot {
    /// The settings to start with.
    pub settings: Settings,
    /// The drive's label.
    pub label: Label,
    /// The store (`None`: the region is unusable).
    pub store: Option<BoardStore>,
    /// The link-watchdog setting of the loaded record.
    pub link: Option<WatchdogConfig>,
}

/// Open the store and take its record, or the build-time settings. Runs in
/// `init`, before the independent watchdog starts (a repair after an
/// interrupted write may erase a sector). Never fails: any problem is
/// logged and the drive boots from the build-time settings, uncalibrated.
pub fn boot(flash: board::StoreFlash) -> Boot {
    let base = build_time_settings();
    #[cfg(feature = "qemu")]
    if board::args().store_path().is_none() {
        defmt::info!("store: none (emulated board without `store=`): build-time defaults");
        return Boot {
            settings: base,
            label: Label::new(),
            store: None,
            link: None,
        };
    }
    let mut store = match Store::new(flash, board::STORE_RANGE) {
        Ok(s) => Some(s),
        Err(e) => {
            defmt::error!(
                "store: unusable region ({}): build-time defaults, uncalibrated",
                e
            );
            None
        }
    };
    let mut boot = Boot {
        settings: base,
        label: Label::new(),
        store: None,
        link: None,
    };
    match store.as_mut().map(|s| s.load()) {
        None => {}
        Some(Ok(None)) => defmt::info!("store: empty: build-time defaults, uncalibrated"),
        Some(Ok(Some(rec))) => match admit(&rec) {
            Ok(s) => {
                defmt::info!(
                    "store: loaded \"{=str}\" ({=str})",
                    rec.label.as_str(),
                    if s.calibrated {
                        "with calibration"
                    } else {
                        "no calibration"
                    }
                );
                boot.settings = s;
                boot.link = Some(link_setting(&rec));
                boot.label = rec.label;
                if rec.watchdog.timeout_periods == 0 {
                    defmt::warn!("store: the link watchdog is off (stored setting): a silent host leaves the motor running");
                }
            }
            Err(e) => defmt::error!(
                "store: record refused ({}): build-time defaults, uncalibrated",
                e
            ),
        },
        Some(Err(e)) => defmt::error!(
            "store: unreadable ({}): build-time defaults, uncalibrated",
            e
        ),
    }
    boot.store = store;
    boot
}

/// `rec` applied onto the build-time settings: whole, or refused. On top
/// of the record's own checks, this board's: its current limit
/// (`config::MOTOR`), its over-voltage threshold (the regen limit's end
/// and the brake's switch-on voltage below it), its motor's pole pairs (the identification and the
/// hall decoder are built for them) and its sensor's counts per turn (a
/// calibration from another sensor is meaningless here). Where the
/// sensor's zero does not survive a reset (an incremental encoder), the
/// record's motor model and gains apply but not its calibration: the
/// settings stay uncalibrated until an identification.
pub fn admit(rec: &DriveRecord) -> Result<Settings, Invalid> {
    let base = build_time_settings();
    let invalid = |field| Err(Invalid { field });
    if rec.motor.pole_pairs != base.current.motor.pole_pairs {
        return invalid("motor.pole_pairs");
    }
    if rec
        .calibration
        .as_ref()
        .is_some_and(|c| c.sensor_counts_per_rev != base.angle.sensor_counts_per_rev)
    {
        return invalid("calibration.sensor_counts_per_rev");
    }
    let mut s = rec.apply(&base, PWM_HZ)?;
    if s.limits.max_current_a > config::MOTOR.1 {
        return invalid("limits.max_current_a");
    }
    // The regen limit and the brake must act below this board's
    // over-voltage fault, or the fault lets the motor coast and its
    // back-EMF charges the bus through the body diodes.
    let over_voltage_v = config::cascade(PWM_HZ as f32)
        .current
        .supervisor
        .bus_over_voltage_v;
    if let Some(p) = &rec.power {
        if p.regen_end_v >= over_voltage_v {
            return invalid("power.regen_end_v");
        }
        if p.brake_on_v < f32::INFINITY && p.brake_on_v >= over_voltage_v {
            return invalid("power.brake_on_v");
        }
    }
    if s.calibrated && !board::angle_kind().zero_survives_reset() {
        defmt::warn!(
            "store: the stored electrical zero does not apply to an incremental encoder (its zero is where the rotor was at reset): motor model and gains kept, identification needed"
        );
        s.calibrated = false;
        s.angle = base.angle;
    }
    Ok(s)
}

/// The cascade configuration of `s` (the build-time one with `s` applied).
pub fn cascade(s: &Settings) -> CascadeConfig {
    s.apply_to(&config::cascade(PWM_HZ as f32))
}

/// The record of the live settings, with the link watchdog in force.
pub fn live_record(label: &Label, s: &Settings, link: WatchdogConfig) -> DriveRecord {
    let mut s = *s;
    s.watchdog = WatchdogRecord {
        timeout_periods: link.timeout_periods,
        reaction: reaction_record(link.reaction),
    };
    DriveRecord::from_settings(label, PWM_HZ, &s)
}

/// The link-watchdog setting a record carries.
pub fn link_setting(rec: &DriveRecord) -> WatchdogConfig {
    WatchdogConfig {
        timeout_periods: rec.watchdog.timeout_periods,
        reaction: timeout_reaction(rec.watchdog.reaction),
    }
}

/// A flash operation is running (set by [`guarded`]): the current loop
/// does not count a run stretched by a flash stall as an overrun.
static FLASH_BUSY: AtomicBool = AtomicBool::new(false);

/// True while a flash operation runs.
pub fn flash_busy() -> bool {
    FLASH_BUSY.load(Ordering::Relaxed)
}

/// Run a flash operation with the watchdog stretched: a sector erase
/// stalls the processor for seconds (see `watchdog::stretched`). The
/// caller has made sure the bridge is off and stays off
/// (`comms::Link::quiet`).
pub fn guarded<T>(f: impl FnOnce() -> T) -> T {
    FLASH_BUSY.store(true, Ordering::Relaxed);
    let out = watchdog::stretched(config::WATCHDOG_TIMEOUT_MS, f);
    FLASH_BUSY.store(false, Ordering::Relaxed);
    out
}
