//! The virtual devices of one emulated bus, run together: one attachment to
//! the bus, one simulation clock, and the controls a test bench has (add a
//! device, pull its cable, put it back, inject a fault).
//!
//! One runner serves every device of the bus, so that a bus of 127 devices
//! costs one wake-up per frame and one per millisecond, not 127 of each.
//! Frames from the bus go to every device plugged in; a frame a device
//! sends goes to the bus and to the other devices, as on a wire. The clock
//! ticks every [`TICK_MS`] of tokio's time (so a paused clock in a test
//! drives the simulation deterministically); each tick runs every device's
//! application up to now and its timers.
//!
//! Devices are known by the node-ID they use. One without (an unconfigured
//! LSS slave, `PRODUCT@lss`) or whose node-ID another device has is
//! *loose*: it runs and hears the bus, but the controls cannot name it.
//! After every event a device that changed its node-ID (LSS, or 0x2040 and
//! a reset) is filed under the new one. Identical LSS answers of several
//! devices to one request leave as one frame, as they would on a wire
//! (the slaves send them at the same time; Fastscan relies on it).

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::sync::Notify;

use crate::can::{Bitrate, Bus, Frame, FrameReceiver, RecvError, VirtualHub};
use crate::canopen::NodeId;
use crate::canopen::lss::LssAddress;

use super::behaviour::{Fault, FaultError, TICK_MS};
use super::device::{DeviceCore, LssStored};
use super::persist::{
    lss_path, program_path, read_lss, read_program, read_saved, saved_path, saved_path_lss,
    write_lss, write_program, write_saved,
};
use super::products::{DeviceSpec, Product};

/// How many rounds of device-to-device frames one event may cause before
/// the rest wait for the next tick (a loop of devices answering each other
/// must not hold the runner).
const MAX_LOCAL_ROUNDS: usize = 16;

/// Why a control of the rack was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RackError {
    #[error("node {0} is not on this bus")]
    UnknownNode(NodeId),
    #[error("node {0} is taken by a {1}")]
    NodeTaken(NodeId, String),
    #[error("{0}")]
    Device(String),
    #[error(transparent)]
    Fault(#[from] FaultError),
}

/// One device in the rack.
struct Slot {
    product: Option<Product>,
    core: DeviceCore,
    /// Its cable: an unplugged device runs on but neither sends nor hears.
    plugged: bool,
    /// Where its saved parameters are kept, and the version last written.
    persist: Option<(PathBuf, u64)>,
}

/// One device's saved values (and what LSS stored) to write.
/// A device's saved values, what LSS stored and (when it has program
/// memory) its program image, to write under a path.
type Save = (
    PathBuf,
    super::device::SavedValues,
    Option<LssStored>,
    Option<Option<Vec<u8>>>,
);

/// Who sent a frame, within one wake-up of the runner.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Sender {
    Node(NodeId),
    /// A loose device, by its place in [`Inner::loose`].
    Loose(usize),
}

#[derive(Default)]
struct Inner {
    slots: BTreeMap<NodeId, Slot>,
    /// The bus's bit rate (a bus-off recovery takes 128 × 11 bit times).
    bitrate: Bitrate,
    /// The devices without a node-ID of their own (see the module
    /// documentation).
    loose: Vec<Slot>,
    /// Unconfigured devices added without a serial number so far.
    lss_added: u32,
    /// Frames the controls produced (boot-up of an added device), for the
    /// runner to send.
    outbox: Vec<(Sender, Frame)>,
}

/// The serial numbers the rack gives: a device at node N has serial
/// number N; the k-th `@lss` device without one has 0x100 + k.
pub const LSS_SERIAL_BASE: u32 = 0x100;

impl Inner {
    /// Files every device under the node-ID it now uses.
    fn settle(&mut self) {
        let moved: Vec<NodeId> = self
            .slots
            .iter()
            .filter(|(node, slot)| slot.core.active_node() != Some(**node))
            .map(|(node, _)| *node)
            .collect();
        for node in moved {
            if let Some(slot) = self.slots.remove(&node) {
                self.loose.push(slot);
            }
        }
        let mut i = 0;
        while i < self.loose.len() {
            match self.loose[i].core.active_node() {
                Some(node) if !self.slots.contains_key(&node) => {
                    let slot = self.loose.remove(i);
                    self.slots.insert(node, slot);
                }
                _ => i += 1,
            }
        }
    }

    /// Every device with the name it sends under in this wake-up.
    fn all_mut(&mut self) -> impl Iterator<Item = (Sender, &mut Slot)> {
        self.slots
            .iter_mut()
            .map(|(node, slot)| (Sender::Node(*node), slot))
            .chain(
                self.loose
                    .iter_mut()
                    .enumerate()
                    .map(|(i, slot)| (Sender::Loose(i), slot)),
            )
    }

    fn len(&self) -> usize {
        self.slots.len() + self.loose.len()
    }
}

/// How late a tick may run and still count as on time: tokio's timers
/// have a resolution of 1 ms, so a tick usually runs 1 to 2 ms after it
/// was due; the simulation itself does not lose that time: each tick runs
/// the devices up to the instant it was due.
pub const ON_TIME: Duration = Duration::from_millis(5);

/// How well the runner keeps real time.
#[derive(Debug, Default)]
pub struct RackStats {
    /// Clock ticks run.
    pub ticks: AtomicU64,
    /// Ticks that ran more than [`ON_TIME`] after they were due.
    pub late_ticks: AtomicU64,
    /// The latest any tick ran, in µs after it was due.
    pub max_lateness_us: AtomicU64,
    /// Frames sent by the devices.
    pub frames_sent: AtomicU64,
    /// The longest the runner took over one wake-up (a frame, a tick), in
    /// µs: what the devices cost at their busiest.
    pub max_busy_us: AtomicU64,
}

impl Rack {
    /// Simulated milliseconds the devices skipped because the host fell too
    /// far behind (0 while the simulation keeps real time).
    pub fn skipped_ticks(&self) -> u64 {
        let inner = lock(&self.inner);
        inner
            .slots
            .values()
            .chain(inner.loose.iter())
            .map(|slot| slot.core.skipped_ticks())
            .sum()
    }
}

/// The devices of one virtual bus. Cloning gives another handle to the same
/// rack; the runner stops when the last handle is dropped or the bus closes.
#[derive(Clone)]
pub struct Rack {
    inner: Arc<Mutex<Inner>>,
    wake: Arc<Notify>,
    stats: Arc<RackStats>,
    data_dir: Option<PathBuf>,
    /// Keeps the runner alive while a handle exists.
    _runner: Arc<RunnerGuard>,
}

struct RunnerGuard(tokio::task::AbortHandle);

impl Drop for RunnerGuard {
    fn drop(&mut self) {
        self.0.abort();
    }
}

fn now() -> Instant {
    tokio::time::Instant::now().into_std()
}

impl Rack {
    /// An empty rack on `hub`, running from now (needs a tokio runtime).
    pub fn new(hub: VirtualHub) -> Self {
        Self::with_data_dir(hub, None)
    }

    /// With `data_dir`, each device added starts with the parameters it
    /// saved there before and keeps what it saves (see [`super::persist`]).
    pub fn with_data_dir(hub: VirtualHub, data_dir: Option<PathBuf>) -> Self {
        let inner = Arc::new(Mutex::new(Inner {
            bitrate: hub.bitrate(),
            ..Inner::default()
        }));
        let wake = Arc::new(Notify::new());
        let stats = Arc::new(RackStats::default());
        let bus = hub.attach();
        let frames = bus.subscribe();
        let runner = tokio::spawn(run(
            bus,
            frames,
            Arc::downgrade(&inner),
            wake.clone(),
            stats.clone(),
        ));
        Self {
            inner,
            wake,
            stats,
            data_dir,
            _runner: Arc::new(RunnerGuard(runner.abort_handle())),
        }
    }

    /// Adds every device of a `--devices` list; all are built before any
    /// boots, so a bad one leaves the rack as it was.
    pub fn add_all(&self, devices: &[DeviceSpec]) -> Result<(), RackError> {
        let mut built = Vec::new();
        for spec in devices {
            if let Some(node) = spec.node
                && let Some(slot) = lock(&self.inner).slots.get(&node)
            {
                return Err(RackError::NodeTaken(node, product_name(slot)));
            }
            built.push((spec.product, self.build(spec)?));
        }
        for (product, (core, persist)) in built {
            self.insert(Some(product), core, persist)?;
        }
        Ok(())
    }

    /// Adds a device of `product` at `node`; it boots at once.
    pub fn add(&self, product: Product, node: NodeId) -> Result<(), RackError> {
        self.add_spec(&DeviceSpec::at(product, node))
    }

    /// Adds a device as a `--devices` list spells it: at a node, or an
    /// unconfigured LSS slave (`@lss`) waiting for a node-ID. Its serial
    /// number (0x1018 sub 4) is the spec's, else the node-ID, else
    /// [`LSS_SERIAL_BASE`] + the how-manieth `@lss` device it is.
    pub fn add_spec(&self, spec: &DeviceSpec) -> Result<(), RackError> {
        let (core, persist) = self.build(spec)?;
        self.insert(Some(spec.product), core, persist)
    }

    fn build(&self, spec: &DeviceSpec) -> Result<(DeviceCore, Option<PathBuf>), RackError> {
        let product = spec.product;
        let serial = match (spec.serial, spec.node) {
            (Some(serial), _) => serial,
            (None, Some(node)) => u32::from(node.get()),
            (None, None) => {
                let mut inner = lock(&self.inner);
                inner.lss_added += 1;
                LSS_SERIAL_BASE + inner.lss_added
            }
        };
        // An unconfigured device is built for any node-ID; it takes its own
        // from the LSS master.
        let mut core = product
            .device_with_load(
                spec.node
                    .unwrap_or(NodeId::new(NodeId::MAX).expect("127 is a node-ID")),
                spec.load,
            )
            .map_err(RackError::Device)?;
        core.set_serial(serial);
        if spec.node.is_none() {
            core.unconfigure();
        } else if !product.answers_lss() {
            core.without_lss();
        }
        let path = self.data_dir.as_deref().map(|dir| match spec.node {
            Some(node) => saved_path(dir, product.name(), node),
            None => saved_path_lss(dir, product.name(), serial),
        });
        if let Some(path) = &path {
            let device_error =
                |err: super::persist::PersistError| RackError::Device(err.to_string());
            core.load_saved(read_saved(path).map_err(device_error)?);
            core.load_lss_stored(read_lss(&lss_path(path)).map_err(device_error)?);
            if core.program().is_supported() {
                core.load_program(read_program(&program_path(path)).map_err(device_error)?);
            }
        }
        Ok((core, path))
    }

    /// Adds a device built elsewhere (a test node with its own dictionary).
    pub fn add_device(&self, core: DeviceCore) -> Result<(), RackError> {
        self.insert(None, core, None)
    }

    fn insert(
        &self,
        product: Option<Product>,
        mut core: DeviceCore,
        persist: Option<PathBuf>,
    ) -> Result<(), RackError> {
        let mut inner = lock(&self.inner);
        let now = now();
        // Booting decides the node-ID (a saved 0x2040, a stored LSS one).
        core.set_bitrate(inner.bitrate);
        let boot = core.boot(now);
        let node = core.active_node();
        if let Some(node) = node
            && let Some(slot) = inner.slots.get(&node)
        {
            return Err(RackError::NodeTaken(node, product_name(slot)));
        }
        core.tick_to(now);
        let version = core.saved_version();
        let slot = Slot {
            product,
            core,
            plugged: true,
            persist: persist.map(|path| (path, version)),
        };
        let sender = match node {
            Some(node) => {
                inner.slots.insert(node, slot);
                Sender::Node(node)
            }
            None => {
                inner.loose.push(slot);
                Sender::Loose(inner.loose.len() - 1)
            }
        };
        inner
            .outbox
            .extend(boot.into_iter().map(|frame| (sender, frame)));
        drop(inner);
        self.wake.notify_one();
        Ok(())
    }

    /// The devices that have no node-ID of their own (unconfigured LSS
    /// slaves, or one whose node-ID another device has): node-ID, product,
    /// LSS address.
    pub fn loose_devices(&self) -> Vec<(Option<NodeId>, Option<Product>, LssAddress)> {
        lock(&self.inner)
            .loose
            .iter()
            .map(|slot| {
                (
                    slot.core.active_node(),
                    slot.product,
                    slot.core.lss_address(),
                )
            })
            .collect()
    }

    /// Takes a device off the bus for good.
    pub fn remove(&self, node: NodeId) -> Result<(), RackError> {
        lock(&self.inner)
            .slots
            .remove(&node)
            .map(drop)
            .ok_or(RackError::UnknownNode(node))
    }

    /// Pulls the device's cable: it goes on running, but neither sends nor
    /// hears anything until [`Rack::plug`].
    pub fn unplug(&self, node: NodeId) -> Result<(), RackError> {
        self.set_plugged(node, false)
    }

    /// Puts the cable back: the device is heard again from its next frame
    /// (no boot-up: it never stopped).
    pub fn plug(&self, node: NodeId) -> Result<(), RackError> {
        self.set_plugged(node, true)
    }

    fn set_plugged(&self, node: NodeId, plugged: bool) -> Result<(), RackError> {
        let mut inner = lock(&self.inner);
        let slot = inner
            .slots
            .get_mut(&node)
            .ok_or(RackError::UnknownNode(node))?;
        slot.plugged = plugged;
        Ok(())
    }

    /// Whether the device's cable is in; `None` for no such device.
    pub fn is_plugged(&self, node: NodeId) -> Option<bool> {
        lock(&self.inner).slots.get(&node).map(|slot| slot.plugged)
    }

    /// Injects a fault into a device (see [`Fault`]).
    pub fn inject_fault(&self, node: NodeId, fault: Fault) -> Result<(), RackError> {
        self.with_device(node, |core| core.inject_fault(fault, now()))?
            .map_err(RackError::from)?;
        self.wake.notify_one();
        Ok(())
    }

    /// Ends an injected fault condition.
    pub fn clear_fault(&self, node: NodeId, fault: Fault) -> Result<(), RackError> {
        self.with_device(node, |core| core.clear_fault(fault, now()))?
            .map_err(RackError::from)?;
        self.wake.notify_one();
        Ok(())
    }

    /// Runs `f` on a device (to look at its values, or to change them as
    /// the device itself would).
    pub fn with_device<R>(
        &self,
        node: NodeId,
        f: impl FnOnce(&mut DeviceCore) -> R,
    ) -> Result<R, RackError> {
        let mut inner = lock(&self.inner);
        let slot = inner
            .slots
            .get_mut(&node)
            .ok_or(RackError::UnknownNode(node))?;
        Ok(f(&mut slot.core))
    }

    /// The devices: node, product (`None` for one added with
    /// [`Rack::add_device`]) and whether plugged in.
    pub fn devices(&self) -> Vec<(NodeId, Option<Product>, bool)> {
        lock(&self.inner)
            .slots
            .iter()
            .map(|(node, slot)| (*node, slot.product, slot.plugged))
            .collect()
    }

    /// How well the runner keeps real time.
    pub fn stats(&self) -> &RackStats {
        &self.stats
    }
}

fn product_name(slot: &Slot) -> String {
    slot.product.map_or_else(
        || "device".to_string(),
        |product| product.name().to_string(),
    )
}

fn lock(inner: &Mutex<Inner>) -> MutexGuard<'_, Inner> {
    inner
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// What woke the runner.
enum Wake {
    Frame(Frame),
    Tick(tokio::time::Instant),
    Controls,
    /// The devices' receive queue overflowed.
    Overrun,
}

async fn run(
    bus: Bus,
    mut frames: FrameReceiver,
    inner: std::sync::Weak<Mutex<Inner>>,
    wake: Arc<Notify>,
    stats: Arc<RackStats>,
) {
    let period = Duration::from_millis(TICK_MS);
    let mut clock = tokio::time::interval(period);
    // A late tick is not made up in a burst: the devices catch up the
    // simulated time they missed in one go.
    clock.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut out: Vec<(Sender, Frame)> = Vec::new();
    let mut saves: Vec<Save> = Vec::new();
    loop {
        let woke = tokio::select! {
            received = frames.recv() => match received {
                Ok(frame) => Wake::Frame(frame.frame),
                // Requests lost in an overrun end as timeouts, as on a
                // real bus; each device reports its CAN overrun.
                Err(RecvError::Lagged(_)) => Wake::Overrun,
                Err(RecvError::Closed) => return,
            },
            due = clock.tick() => Wake::Tick(due),
            _ = wake.notified() => Wake::Controls,
        };
        let Some(inner) = inner.upgrade() else {
            return;
        };
        let busy_from = std::time::Instant::now();
        {
            let mut inner = lock(&inner);
            let now = now();
            match woke {
                Wake::Frame(frame) => deliver(&mut inner, None, &frame, now, &mut out),
                Wake::Tick(due) => {
                    let lateness = tokio::time::Instant::now().saturating_duration_since(due);
                    stats.ticks.fetch_add(1, Ordering::Relaxed);
                    if lateness > ON_TIME {
                        stats.late_ticks.fetch_add(1, Ordering::Relaxed);
                    }
                    stats
                        .max_lateness_us
                        .fetch_max(lateness.as_micros() as u64, Ordering::Relaxed);
                    // The devices live on the tick's schedule, as a real
                    // device on its 1 ms cycle: timers and event-timer
                    // PDOs keep their periods however late the host wakes.
                    let due = due.into_std();
                    for (sender, slot) in inner.all_mut() {
                        slot.core.tick_to(due);
                        let frames = slot.core.poll(due);
                        if slot.plugged {
                            out.extend(frames.into_iter().map(|frame| (sender, frame)));
                        }
                    }
                }
                Wake::Controls => {}
                Wake::Overrun => {
                    for (_, slot) in inner.all_mut() {
                        if slot.plugged {
                            slot.core.receive_overrun(now);
                        }
                    }
                }
            }
            let controls = std::mem::take(&mut inner.outbox);
            out.extend(controls);
            relay_between_devices(&mut inner, now, &mut out);
            collect_saves(&mut inner, &mut saves);
            inner.settle();
        }
        stats
            .max_busy_us
            .fetch_max(busy_from.elapsed().as_micros() as u64, Ordering::Relaxed);
        for (path, saved, lss, program) in saves.drain(..) {
            // A device whose flash fails still runs; the log says so.
            if let Err(err) = write_saved(&path, &saved) {
                tracing::warn!("virtual device: {err}");
            }
            if let Some(lss) = lss
                && let Err(err) = write_lss(&lss_path(&path), &lss)
            {
                tracing::warn!("virtual device: {err}");
            }
            if let Some(image) = program
                && let Err(err) = write_program(&program_path(&path), image.as_deref())
            {
                tracing::warn!("virtual device: {err}");
            }
        }
        merge_lss_answers(&mut out);
        for (_, frame) in out.drain(..) {
            // A heartbeat producer sends its current state: one still
            // waiting for the bus is brought up to date, not followed by
            // a backlog (a starved device sends no burst of stale ones).
            let sent = if is_heartbeat(&frame) {
                bus.try_send_latest(frame)
            } else {
                bus.try_send(frame)
            };
            match sent {
                Ok(()) => {
                    stats.frames_sent.fetch_add(1, Ordering::Relaxed);
                }
                Err(err) => tracing::debug!("virtual device: frame not sent: {err}"),
            }
        }
    }
}

/// A heartbeat (0x701–0x77F, one byte, not the boot-up message).
fn is_heartbeat(frame: &Frame) -> bool {
    matches!(frame.id(), crate::can::CanId::Standard(0x701..=0x77F))
        && matches!(frame.data(), [state] if *state != 0)
        && frame.kind() == crate::can::FrameKind::Data
}

/// Identical LSS answers of several devices are one frame on the wire.
fn merge_lss_answers(out: &mut Vec<(Sender, Frame)>) {
    let answer = crate::can::CanId::Standard(crate::canopen::lss::LSS_SLAVE_COB_ID);
    let mut seen: Vec<Frame> = Vec::new();
    out.retain(|(_, frame)| {
        if frame.id() != answer {
            return true;
        }
        if seen.contains(frame) {
            return false;
        }
        seen.push(*frame);
        true
    });
}

/// A frame on the wire reaches every device plugged in but its sender.
fn deliver(
    inner: &mut Inner,
    sender: Option<Sender>,
    frame: &Frame,
    now: Instant,
    out: &mut Vec<(Sender, Frame)>,
) {
    for (name, slot) in inner.all_mut() {
        if !slot.plugged || Some(name) == sender {
            continue;
        }
        let replies = slot.core.handle_frame(frame, now);
        out.extend(replies.into_iter().map(|reply| (name, reply)));
    }
}

/// The devices hear each other's frames (a TPDO of one may be an RPDO of
/// another), and whatever they answer in turn, a bounded number of rounds.
/// Each frame first passes its sender's CAN controller
/// ([`DeviceCore::on_the_wire`]): a bus-off device sends nothing, one with
/// bit errors an error frame before its frame.
fn relay_between_devices(inner: &mut Inner, now: Instant, out: &mut Vec<(Sender, Frame)>) {
    let mut start = 0;
    for _ in 0..MAX_LOCAL_ROUNDS {
        on_the_wire(inner, now, out, start);
        let end = out.len();
        if start == end || inner.len() < 2 {
            return;
        }
        for i in start..end {
            let (sender, frame) = out[i];
            deliver(inner, Some(sender), &frame, now, out);
        }
        start = end;
    }
    on_the_wire(inner, now, out, start);
}

/// Passes `out[start..]` through their senders' CAN controllers.
fn on_the_wire(inner: &mut Inner, now: Instant, out: &mut Vec<(Sender, Frame)>, start: usize) {
    if start == out.len() {
        return;
    }
    let sent: Vec<(Sender, Frame)> = out.drain(start..).collect();
    for (sender, frame) in sent {
        let slot = match sender {
            Sender::Node(node) => inner.slots.get_mut(&node),
            Sender::Loose(i) => inner.loose.get_mut(i),
        };
        let Some(slot) = slot else {
            continue;
        };
        for frame in slot.core.on_the_wire(frame, now).into_iter().flatten() {
            out.push((sender, frame));
        }
    }
}

/// The saved values of devices that saved since they were last written.
fn collect_saves(inner: &mut Inner, saves: &mut Vec<Save>) {
    for (_, slot) in inner.all_mut() {
        if let Some((path, version)) = &mut slot.persist
            && slot.core.saved_version() != *version
        {
            *version = slot.core.saved_version();
            saves.push((
                path.clone(),
                slot.core.saved().clone(),
                slot.core.lss_stored(),
                slot.core
                    .program()
                    .is_supported()
                    .then(|| slot.core.program().image().map(<[u8]>::to_vec)),
            ));
        }
    }
}

#[cfg(test)]
mod tests;
