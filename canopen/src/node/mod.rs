//! The CANopen node (CiA 301 slave): NMT, heartbeat, SDO server, PDOs,
//! SYNC and EMCY around the object dictionary, driving a [`Profile`]
//! (the CiA 402 drive, [`Cia402`]) on a [`CanDevice`].
//!
//! Sans-I/O: the owner hands the node every received frame
//! ([`Node::on_frame`]), the bus state ([`Node::on_bus_state`]) and the
//! time ([`Node::tick`], at 1 kHz or more), and sends every frame the node
//! gives to `out`.
//!
//! ```text
//! let mut node = Node::new(CommSettings::new(5, 1000, 100, Some((1, 300))).unwrap());
//! node.boot(now_us, &mut ctx, &mut |f| can.send(f));
//! // CAN task: node.on_frame(&rx, now_us, &mut ctx, &mut |f| can.send(f));
//! // 1 kHz:    node.tick(now_us, &mut ctx, &mut |f| can.send(f));
//! ```

mod objects;

use foc_protocol::device::{DeviceContext, WatchdogConfig};
use foc_protocol::message::ErrorCode;

use crate::cia402::Cia402;
use crate::emcy;
use crate::nmt::{ConsumerEvent, HeartbeatConsumer, HeartbeatProducer, NmtCommand, NmtState};
use crate::od::{self, Data};
use crate::pdo::{self, PdoConfig, COUNT};
use crate::profile::Profile;
use crate::sdo::{ObjectAccess, SdoServer};
use crate::{Abort, CanFrame};

use objects::{Action, Dict};
pub use objects::{LOAD, SAVE};

/// The identity object (0x1018) and the device strings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Identity {
    /// Vendor-ID (assigned by CiA).
    pub vendor_id: u32,
    /// Product code.
    pub product_code: u32,
    /// Revision number (major << 16 | minor).
    pub revision: u32,
    /// Serial number.
    pub serial: u32,
    /// 0x1008 manufacturer device name (at most 32 bytes are sent).
    pub device_name: &'static str,
    /// 0x1009 manufacturer hardware version.
    pub hardware_version: &'static str,
}

/// The CAN controller's error state (the hardware layer's).
pub use foc_core::hal::BusState;

/// Why [`CommSettings::new`] refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SettingsError {
    /// Node id not in 1..=127.
    NodeId,
    /// Bit rate not one of [`CommSettings::BIT_RATES`].
    BitRate,
    /// Consumer: master id not in 1..=127, equal to the node's, or time 0.
    Consumer,
}

/// The node's stored communication settings (what [`CanDevice::save_comm`]
/// keeps): node id, bit rate, heartbeat producer time and the consumed
/// heartbeat (the master's node id and time).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CommSettings {
    node_id: u8,
    bitrate_kbit: u16,
    heartbeat_ms: u16,
    consumer: Option<(u8, u16)>,
}

impl CommSettings {
    /// Supported bit rates [kbit/s].
    pub const BIT_RATES: [u16; 4] = [125, 250, 500, 1000];

    /// Node 1, 1 Mbit/s (the default bit rate), heartbeat every 100 ms, no consumer.
    pub const DEFAULT: Self = Self {
        node_id: 1,
        bitrate_kbit: 1000,
        heartbeat_ms: 100,
        consumer: None,
    };

    /// Checked settings.
    pub fn new(
        node_id: u8,
        bitrate_kbit: u16,
        heartbeat_ms: u16,
        consumer: Option<(u8, u16)>,
    ) -> Result<Self, SettingsError> {
        if !(1..=127).contains(&node_id) {
            return Err(SettingsError::NodeId);
        }
        if !Self::BIT_RATES.contains(&bitrate_kbit) {
            return Err(SettingsError::BitRate);
        }
        if let Some((m, ms)) = consumer {
            if !(1..=127).contains(&m) || m == node_id || ms == 0 {
                return Err(SettingsError::Consumer);
            }
        }
        Ok(Self {
            node_id,
            bitrate_kbit,
            heartbeat_ms,
            consumer,
        })
    }
    /// From the stored record (`foc_store::CanRecord`, validated again
    /// here: the two rule sets agree, see the tests).
    pub fn from_record(r: &foc_store::CanRecord) -> Result<Self, SettingsError> {
        let consumer = (r.consumer_node != 0).then_some((r.consumer_node, r.consumer_ms));
        Self::new(r.node_id, r.bitrate_kbit, r.heartbeat_ms, consumer)
    }

    /// As the stored record.
    pub const fn to_record(&self) -> foc_store::CanRecord {
        let (consumer_node, consumer_ms) = match self.consumer {
            Some((n, ms)) => (n, ms),
            None => (0, 0),
        };
        foc_store::CanRecord {
            node_id: self.node_id,
            bitrate_kbit: self.bitrate_kbit,
            heartbeat_ms: self.heartbeat_ms,
            consumer_node,
            consumer_ms,
        }
    }

    /// Node id, 1..=127.
    pub const fn node_id(&self) -> u8 {
        self.node_id
    }
    /// Bit rate [kbit/s].
    pub const fn bitrate_kbit(&self) -> u16 {
        self.bitrate_kbit
    }
    /// Heartbeat producer time \[ms\] (0: off).
    pub const fn heartbeat_ms(&self) -> u16 {
        self.heartbeat_ms
    }
    /// Consumed heartbeat: the master's node id and time \[ms\].
    pub const fn consumer(&self) -> Option<(u8, u16)> {
        self.consumer
    }
}

impl Default for CommSettings {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The drive as the CANopen node sees it: the protocol's
/// [`DeviceContext`] and what CANopen adds.
pub trait CanDevice: DeviceContext {
    /// The identity object and device strings.
    fn identity(&self) -> Identity;
    /// The link-watchdog setting in force, handed to
    /// [`DeviceContext::store`] (saved with the configuration).
    fn link_setting(&self) -> WatchdogConfig;
    /// Keep the communication settings for the next boot (0x1010 "save",
    /// after the drive's configuration was saved).
    fn save_comm(&mut self, s: &CommSettings) -> Result<(), ErrorCode>;
}

/// Run-time state of a TPDO.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
struct TpdoRun {
    /// Data last sent.
    last: Option<([u8; 8], u8)>,
    /// When it was last sent \[µs\].
    sent_us: Option<u64>,
    /// SYNCs counted (types 1..=240).
    syncs: u8,
}

/// A CANopen node (see the module docs).
#[derive(Clone, Debug)]
pub struct Node<P: Profile = Cia402> {
    settings: CommSettings,
    nmt: NmtState,
    sdo: SdoServer,
    dict: Dict<P>,
    producer: HeartbeatProducer,
    consumer: HeartbeatConsumer,
    tpdo_run: [TpdoRun; COUNT],
    /// Synchronous RPDOs received since the last SYNC.
    rpdo_pending: [Option<CanFrame>; COUNT],
    bus_off: bool,
    reset_request: bool,
}

impl Node<Cia402> {
    /// A node with the CiA 402 profile at its defaults; call
    /// [`Node::boot`] next.
    pub fn new(settings: CommSettings) -> Self {
        Self::with_profile(settings, Cia402::new())
    }
}

/// The SDO server's view of the dictionary.
struct Access<'a, P, C> {
    dict: &'a mut Dict<P>,
    ctx: &'a mut C,
    now_us: u64,
}

impl<P: Profile, C: CanDevice> ObjectAccess for Access<'_, P, C> {
    fn read(&mut self, index: u16, sub: u8) -> Result<Data, Abort> {
        self.dict.read(index, sub, self.ctx)
    }
    fn check_write(&mut self, index: u16, sub: u8) -> Result<usize, Abort> {
        let def = od::lookup(index, sub)?;
        if !def.access.writable() {
            return Err(Abort::ReadOnly);
        }
        Ok(def.data_type.size())
    }
    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), Abort> {
        self.dict.write(index, sub, data, self.now_us, self.ctx)
    }
}

impl<P: Profile> Node<P> {
    /// A node driving `profile`; call [`Node::boot`] next.
    pub fn with_profile(settings: CommSettings, profile: P) -> Self {
        Self {
            settings,
            nmt: NmtState::Initialising,
            sdo: SdoServer::new(),
            dict: Dict::new(&settings, profile),
            producer: HeartbeatProducer::new(),
            consumer: HeartbeatConsumer::new(),
            tpdo_run: [TpdoRun::default(); COUNT],
            rpdo_pending: [None; COUNT],
            bus_off: false,
            reset_request: false,
        }
    }

    /// The node id in force.
    pub fn node_id(&self) -> u8 {
        self.settings.node_id()
    }

    /// The NMT state.
    pub fn nmt_state(&self) -> NmtState {
        self.nmt
    }

    /// The profile.
    pub fn cia402(&self) -> &P {
        &self.dict.profile
    }

    /// Replace the profile (tests and simulators that drive a fake
    /// profile from outside).
    #[doc(hidden)]
    pub fn replace_profile_for_test(&mut self, p: P) {
        self.dict.profile = p;
    }

    /// The settings in force.
    pub fn settings(&self) -> &CommSettings {
        &self.settings
    }

    /// The settings 0x2100 / 0x2101 / 0x1016 / 0x1017 hold now (what
    /// 0x1010 would save).
    pub fn pending_settings(&self) -> CommSettings {
        self.dict.settings_to_save()
    }

    /// True once after an NMT "reset node": the owner may restart the
    /// port (to take a saved bit rate; the node itself takes the saved
    /// node id and heartbeat times at once, and has already put the
    /// profile back to its power-on values).
    pub fn take_reset_request(&mut self) -> bool {
        core::mem::replace(&mut self.reset_request, false)
    }

    /// The error register (0x1001).
    pub fn error_register(&self) -> u8 {
        self.dict.emcy.register()
    }

    /// Read an object as an SDO upload would (for tools and tests).
    pub fn read_object<C: CanDevice>(&self, index: u16, sub: u8, ctx: &C) -> Result<Data, Abort> {
        self.dict.read(index, sub, ctx)
    }

    /// Write an object as an SDO download would (validated whole first).
    pub fn write_object<C: CanDevice>(
        &mut self,
        index: u16,
        sub: u8,
        data: &[u8],
        now_us: u64,
        ctx: &mut C,
    ) -> Result<(), Abort> {
        self.dict.write(index, sub, data, now_us, ctx)
    }

    /// Initialisation: communication objects to their defaults, boot-up
    /// frame `0x700 + id: [0x00]`, pre-operational.
    pub fn boot<C: CanDevice>(&mut self, now_us: u64, ctx: &mut C, out: &mut dyn FnMut(CanFrame)) {
        let _ = ctx;
        self.dict.reset_comm(&self.settings);
        self.sdo.reset();
        self.tpdo_run = [TpdoRun::default(); COUNT];
        self.rpdo_pending = [None; COUNT];
        self.consumer = HeartbeatConsumer::new();
        self.consumer.configure(self.dict.consumer_entry);
        if let Some(f) = CanFrame::new(0x700 + u16::from(self.node_id()), &[0x00]) {
            out(f);
        }
        self.producer.restart(self.dict.heartbeat_ms, now_us);
        self.nmt = NmtState::PreOperational;
    }

    /// Reset communication: the communication settings a 0x1010 save
    /// stored (else those in force), then boot-up.
    fn reset_communication<C: CanDevice>(
        &mut self,
        now_us: u64,
        ctx: &mut C,
        out: &mut dyn FnMut(CanFrame),
    ) {
        if let Some(saved) = self.dict.saved {
            self.settings = saved;
        }
        self.boot(now_us, ctx, out);
    }

    /// Reset application: the profile back to its power-on values
    /// (disable voltage: the bridge off unless in Fault, which stays until
    /// a fault reset; parameters at their defaults, targets zero).
    fn reset_application<C: CanDevice>(&mut self, now_us: u64, ctx: &mut C) {
        self.dict.profile.write_controlword(0, now_us, ctx);
        self.dict.profile.set_params(crate::cia402::Params::DEFAULT);
        *self.dict.profile.targets_mut() = crate::cia402::Targets::ZERO;
    }

    fn set_state(&mut self, s: NmtState) {
        if s != NmtState::Operational {
            self.tpdo_run = [TpdoRun::default(); COUNT];
            self.rpdo_pending = [None; COUNT];
        }
        self.nmt = s;
    }

    /// A received frame; then the event-driven TPDOs whose data it
    /// changed (e.g. the statusword after a controlword) go out at once,
    /// not at the next tick (inhibit times respected).
    pub fn on_frame<C: CanDevice>(
        &mut self,
        f: &CanFrame,
        now_us: u64,
        ctx: &mut C,
        out: &mut dyn FnMut(CanFrame),
    ) {
        self.handle_frame(f, now_us, ctx, out);
        if self.nmt.pdo() {
            self.event_tpdos(now_us, ctx, out);
        }
    }

    fn handle_frame<C: CanDevice>(
        &mut self,
        f: &CanFrame,
        now_us: u64,
        ctx: &mut C,
        out: &mut dyn FnMut(CanFrame),
    ) {
        if self.nmt == NmtState::Initialising {
            return;
        }
        let id = self.node_id();
        if f.id == 0 {
            if f.rtr {
                return;
            }
            if let Some(cmd) = NmtCommand::parse(f.data(), id) {
                match cmd {
                    NmtCommand::ResetNode => {
                        self.reset_request = true;
                        self.dict.profile.connection_lost(now_us, ctx);
                        self.reset_application(now_us, ctx);
                        self.reset_communication(now_us, ctx, out);
                    }
                    NmtCommand::ResetCommunication => {
                        self.dict.profile.connection_lost(now_us, ctx);
                        self.reset_communication(now_us, ctx, out);
                    }
                    c => {
                        let next = c.next(self.nmt);
                        if next == NmtState::Stopped && self.nmt != NmtState::Stopped {
                            // Entering Stopped is a connection loss (0x6007).
                            self.dict.profile.connection_lost(now_us, ctx);
                        }
                        self.set_state(next);
                    }
                }
            }
            return;
        }
        if f.rtr {
            return;
        }
        if let Some((master, _)) = HeartbeatConsumer::decode(self.dict.consumer_entry) {
            if f.id == 0x700 + u16::from(master) {
                if self.consumer.on_heartbeat(master, now_us) == Some(ConsumerEvent::Recovered) {
                    self.dict.emcy.clear_comm();
                }
                return;
            }
        }
        if self.nmt == NmtState::Stopped {
            return;
        }
        if self.dict.sync_cob_id & pdo::INVALID == 0
            && f.id == (self.dict.sync_cob_id & 0x7FF) as u16
        {
            self.on_sync(now_us, ctx, out);
            return;
        }
        if f.id == 0x600 + u16::from(id) {
            let mut acc = Access {
                dict: &mut self.dict,
                ctx,
                now_us,
            };
            if let Some(r) = self.sdo.on_request(f.data(), now_us, &mut acc) {
                if let Some(fr) = CanFrame::new(0x580 + u16::from(id), &r) {
                    out(fr);
                }
            }
            return;
        }
        if self.nmt.pdo() {
            self.on_rpdo(f, now_us, ctx, out);
        }
    }

    fn on_sync<C: CanDevice>(&mut self, now_us: u64, ctx: &mut C, out: &mut dyn FnMut(CanFrame)) {
        if !self.nmt.pdo() {
            return;
        }
        for n in 0..COUNT {
            let pending = self.rpdo_pending.get_mut(n).and_then(Option::take);
            if let Some(f) = pending {
                self.apply_rpdo(n, f.data(), now_us, ctx);
            }
        }
        self.dict.profile.update(now_us, ctx);
        for n in 0..COUNT {
            let Some(cfg) = self.dict.tpdo.get(n).copied() else {
                continue;
            };
            if !cfg.valid() || !cfg.synchronous() {
                continue;
            }
            let Some((data, len)) = self.pack(&cfg, ctx) else {
                continue;
            };
            let Some(run) = self.tpdo_run.get_mut(n) else {
                continue;
            };
            let send = if cfg.transmission == 0 {
                run.last != Some((data, len))
            } else {
                run.syncs = run.syncs.saturating_add(1);
                if run.syncs >= cfg.transmission {
                    run.syncs = 0;
                    true
                } else {
                    false
                }
            };
            if send {
                run.last = Some((data, len));
                run.sent_us = Some(now_us);
                if let Some(fr) =
                    CanFrame::new(cfg.id(), data.get(..usize::from(len)).unwrap_or(&[]))
                {
                    out(fr);
                }
            }
        }
    }

    /// The TPDO's data sampled now.
    fn pack<C: CanDevice>(&self, cfg: &PdoConfig, ctx: &C) -> Option<([u8; 8], u8)> {
        let mut buf = [0u8; 8];
        let mut len = 0usize;
        for &e in cfg.map.entries() {
            let def = pdo::check_entry(e, false).ok()?;
            let v = self.dict.value(def, ctx).ok()?;
            let bytes = od::encode(def.data_type, v);
            for &b in bytes.bytes() {
                *buf.get_mut(len)? = b;
                len += 1;
            }
        }
        Some((buf, len as u8))
    }

    fn on_rpdo<C: CanDevice>(
        &mut self,
        f: &CanFrame,
        now_us: u64,
        ctx: &mut C,
        out: &mut dyn FnMut(CanFrame),
    ) {
        let Some(n) = self
            .dict
            .rpdo
            .iter()
            .position(|c| c.valid() && c.id() == f.id)
        else {
            return;
        };
        let Some(cfg) = self.dict.rpdo.get(n).copied() else {
            return;
        };
        let want = cfg.map.bytes();
        let got = f.data().len();
        if got != want {
            let code = if got < want {
                emcy::PDO_LENGTH
            } else {
                emcy::PDO_LENGTH_EXCEEDED
            };
            let cob = self.dict.emcy_id();
            self.dict.emcy.comm_error(cob, code, false, out);
            return;
        }
        if cfg.synchronous() {
            if let Some(slot) = self.rpdo_pending.get_mut(n) {
                *slot = Some(*f);
            }
        } else {
            self.apply_rpdo(n, f.data(), now_us, ctx);
        }
    }

    /// Apply an RPDO's data as one data set: every mapped value is
    /// validated as an SDO write would be (one refused value drops the
    /// whole PDO); then the targets and parameters, the other objects in
    /// mapping order, and the controlword last, so a controlword acts on
    /// the target and mode sent with it (pp's new set-point with 0x607A,
    /// enable with 0x6060).
    fn apply_rpdo<C: CanDevice>(&mut self, n: usize, data: &[u8], now_us: u64, ctx: &mut C) {
        let Some(cfg) = self.dict.rpdo.get(n).copied() else {
            return;
        };
        let mut actions: [Option<Action>; 8] = [None; 8];
        let mut targets = *self.dict.profile.targets();
        let mut params = *self.dict.profile.params();
        let (mut staged_t, mut staged_p) = (false, false);
        let mut controlword = None;
        let mut pos = 0usize;
        for (slot, &e) in actions.iter_mut().zip(cfg.map.entries()) {
            let Ok(def) = pdo::check_entry(e, true) else {
                return;
            };
            let size = def.data_type.size();
            let Some(bytes) = data.get(pos..pos + size) else {
                return;
            };
            pos += size;
            let Ok(v) = od::parse(def, bytes) else {
                return;
            };
            match self.dict.prepare_staged(def, v, ctx, targets, params) {
                Ok(Action::Targets(t)) => (targets, staged_t) = (t, true),
                Ok(Action::Params(p)) => (params, staged_p) = (p, true),
                Ok(Action::Controlword(cw)) => controlword = Some(cw),
                Ok(a) => *slot = Some(a),
                Err(_) => return,
            }
        }
        if staged_t {
            let _ = self.dict.apply(Action::Targets(targets), now_us, ctx);
        }
        if staged_p {
            let _ = self.dict.apply(Action::Params(params), now_us, ctx);
        }
        for a in actions.into_iter().flatten() {
            let _ = self.dict.apply(a, now_us, ctx);
        }
        if let Some(cw) = controlword {
            let _ = self.dict.apply(Action::Controlword(cw), now_us, ctx);
        }
    }

    /// Call at 1 kHz or more: SDO timeout, profile update, heartbeat
    /// producer and consumer, EMCY on fault edges, event-driven TPDOs.
    pub fn tick<C: CanDevice>(&mut self, now_us: u64, ctx: &mut C, out: &mut dyn FnMut(CanFrame)) {
        if self.nmt == NmtState::Initialising {
            return;
        }
        let id = self.node_id();
        if let Some(r) = self.sdo.poll(now_us) {
            if let Some(fr) = CanFrame::new(0x580 + u16::from(id), &r) {
                out(fr);
            }
        }
        self.dict.profile.update(now_us, ctx);
        self.producer.configure(self.dict.heartbeat_ms, now_us);
        if self.producer.poll(now_us) {
            if let Some(fr) = CanFrame::new(0x700 + u16::from(id), &[self.nmt.heartbeat_byte()]) {
                out(fr);
            }
        }
        self.consumer.configure(self.dict.consumer_entry);
        let cob = self.dict.emcy_id();
        if self.consumer.poll(now_us) == Some(ConsumerEvent::Lost) {
            self.dict.profile.connection_lost(now_us, ctx);
            if self.nmt != NmtState::Stopped {
                self.dict.emcy.comm_error(cob, emcy::HEARTBEAT, true, out);
            }
        }
        if self.nmt != NmtState::Stopped {
            let faults = ctx.faults().0;
            let pf = self.dict.profile.profile_fault();
            self.dict.emcy.update(cob, faults, pf, out);
        }
        if self.nmt.pdo() {
            self.event_tpdos(now_us, ctx, out);
        }
    }

    fn event_tpdos<C: CanDevice>(
        &mut self,
        now_us: u64,
        ctx: &mut C,
        out: &mut dyn FnMut(CanFrame),
    ) {
        for n in 0..COUNT {
            let Some(cfg) = self.dict.tpdo.get(n).copied() else {
                continue;
            };
            if !cfg.valid() || cfg.synchronous() {
                continue;
            }
            let Some((data, len)) = self.pack(&cfg, ctx) else {
                continue;
            };
            let Some(run) = self.tpdo_run.get_mut(n) else {
                continue;
            };
            let changed = run.last != Some((data, len));
            let since = run.sent_us.map(|t| now_us.saturating_sub(t));
            let timer_due =
                cfg.event_ms != 0 && since.is_some_and(|s| s >= u64::from(cfg.event_ms) * 1000);
            let inhibit_ok = since.is_none_or(|s| s >= u64::from(cfg.inhibit_100us) * 100);
            if (changed || timer_due) && inhibit_ok {
                run.last = Some((data, len));
                run.sent_us = Some(now_us);
                if let Some(fr) =
                    CanFrame::new(cfg.id(), data.get(..usize::from(len)).unwrap_or(&[]))
                {
                    out(fr);
                }
            }
        }
    }

    /// The CAN controller's state changed: bus-off is a lost connection
    /// (the profile reacts per 0x6007); back on the bus, EMCY 0x8140.
    pub fn on_bus_state<C: CanDevice>(
        &mut self,
        s: BusState,
        now_us: u64,
        ctx: &mut C,
        out: &mut dyn FnMut(CanFrame),
    ) {
        match s {
            BusState::BusOff => {
                if !self.bus_off {
                    self.bus_off = true;
                    self.dict.profile.connection_lost(now_us, ctx);
                }
            }
            BusState::ErrorActive | BusState::ErrorPassive => {
                if self.bus_off {
                    self.bus_off = false;
                    if self.nmt != NmtState::Initialising && self.nmt != NmtState::Stopped {
                        let cob = self.dict.emcy_id();
                        self.dict
                            .emcy
                            .comm_error(cob, emcy::BUS_OFF_RECOVERED, false, out);
                    }
                }
            }
        }
    }
}
