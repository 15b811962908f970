//! The configuration store of this board (design §17): the board's facts
//! for the link's rules, what boot does with the store, and the flash
//! operations behind the command channel's `Store` requests. The record
//! format, its checks and the power-fail-safe log are `foc_store`'s, the
//! rules for applying a record `foc_service`'s (both host-tested there);
//! the region and the flash driver are the board's (`board::STORE_RANGE`,
//! `board::StoreFlash`).

use crate::{config, watchdog};
use board_support::board;
use core::sync::atomic::{AtomicBool, Ordering};
use foc_service::{Board, BootOutcome, RecordStore, Service};
use foc_store::{CanRecord, DriveRecord, Store, StoreError};

/// The store over this board's flash region.
pub type BoardStore = Store<board::StoreFlash>;

/// The board's PWM frequency, which a record's gains must have been made for.
const PWM_HZ: u32 = board::PWM_FREQUENCY_HZ;

// The link must move the largest record the store writes.
const _: () = assert!(foc_store::MAX_RECORD_BYTES <= foc_protocol::config::MAX_RECORD);

/// This board's facts for the link's rules: the build-time configuration
/// (`config::cascade`, uncalibrated), its current limit (`config::MOTOR`),
/// its sensor kind, the UART's telemetry rate, the scope's size.
pub fn board_facts() -> Board {
    let mut b = Board::new(config::cascade(PWM_HZ as f32), PWM_HZ, config::MOTOR.1);
    b.zero_survives_reset = board::angle_kind().zero_survives_reset();
    b.firmware_version = crate::comms::FIRMWARE_VERSION;
    b.max_stream_hz = Some(foc_protocol::device::max_stream_hz(board::SERIAL_BAUD));
    b.scope_values = config::SCOPE_VALUES as u32;
    #[cfg(feature = "can")]
    {
        b.can_identity = crate::comms::CAN_IDENTITY;
    }
    b
}

/// What boot found.
pub struct Boot {
    /// The service with the settings to start with.
    pub service: Service,
    /// The store (`None`: the region is unusable).
    pub store: Option<BoardStore>,
}

/// Open the store and take its record, or the build-time settings. Runs in
/// `init`, before the independent watchdog starts (a repair after an
/// interrupted write may erase a sector). Never fails: any problem is
/// logged and the drive boots from the build-time settings, uncalibrated.
pub fn boot(flash: board::StoreFlash) -> Boot {
    #[cfg(feature = "qemu")]
    if board::args().store_path().is_none() {
        defmt::info!("store: none (emulated board without `store=`): build-time defaults");
        return Boot {
            service: Service::new(board_facts()),
            store: None,
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
    let (service, outcome) = Service::boot(board_facts(), store.as_mut());
    log_boot(&service, &outcome);
    Boot { service, store }
}

fn log_boot(service: &Service, outcome: &BootOutcome) {
    match outcome {
        BootOutcome::NoStore => {}
        BootOutcome::Empty => defmt::info!("store: empty: build-time defaults, uncalibrated"),
        BootOutcome::Loaded { calibrated } => {
            defmt::info!(
                "store: loaded \"{=str}\" ({=str})",
                service.label().as_str(),
                if *calibrated {
                    "with calibration"
                } else {
                    "no calibration"
                }
            );
            if service
                .boot_link_setting()
                .is_some_and(|l| l.timeout_periods == 0)
            {
                defmt::warn!("store: the link watchdog is off (stored setting): a silent host leaves the motor running");
            }
        }
        BootOutcome::Refused(e) => defmt::error!(
            "store: record refused ({}): build-time defaults, uncalibrated",
            e
        ),
        BootOutcome::Unreadable(e) => defmt::error!(
            "store: unreadable ({}): build-time defaults, uncalibrated",
            e
        ),
    }
}

/// The store once the drive runs: every flash operation with the watchdog
/// stretched ([`guarded`]). The link's rules allow them only while the
/// bridge is off and stays off (`foc_service::Link::quiet`).
pub struct GuardedStore(pub BoardStore);

impl RecordStore for GuardedStore {
    fn load(&mut self) -> Result<Option<DriveRecord>, StoreError> {
        guarded(|| self.0.load())
    }
    fn save(&mut self, rec: &DriveRecord) -> Result<(), StoreError> {
        guarded(|| self.0.save(rec))
    }
    fn erase(&mut self) -> Result<(), StoreError> {
        guarded(|| self.0.erase())
    }
    fn load_can(&mut self) -> Result<Option<CanRecord>, StoreError> {
        guarded(|| self.0.load_can())
    }
    fn save_can(&mut self, rec: &CanRecord) -> Result<(), StoreError> {
        guarded(|| self.0.save_can(rec))
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
/// caller has made sure the bridge is off and stays off.
pub fn guarded<T>(f: impl FnOnce() -> T) -> T {
    FLASH_BUSY.store(true, Ordering::Relaxed);
    let out = watchdog::stretched(config::WATCHDOG_TIMEOUT_MS, f);
    FLASH_BUSY.store(false, Ordering::Relaxed);
    out
}
