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

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::sync::Notify;

use crate::can::{Bitrate, Bus, Frame, FrameReceiver, RecvError, VirtualHub};
use crate::canopen::NodeId;

use super::behaviour::{Fault, FaultError, TICK_MS};
use super::device::DeviceCore;
use super::persist::{read_saved, saved_path, write_saved};
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

#[derive(Default)]
struct Inner {
    slots: BTreeMap<NodeId, Slot>,
    /// The bus's bit rate (a bus-off recovery takes 128 × 11 bit times).
    bitrate: Bitrate,
    /// Frames the controls produced (boot-up of an added device), for the
    /// runner to send.
    outbox: Vec<(NodeId, Frame)>,
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
        lock(&self.inner)
            .slots
            .values()
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
            if let Some(slot) = lock(&self.inner).slots.get(&spec.node) {
                return Err(RackError::NodeTaken(spec.node, product_name(slot)));
            }
            built.push((spec.product, self.build(spec.product, spec.node)?));
        }
        for (product, (core, persist)) in built {
            self.insert(Some(product), core, persist)?;
        }
        Ok(())
    }

    /// Adds a device of `product` at `node`; it boots at once.
    pub fn add(&self, product: Product, node: NodeId) -> Result<(), RackError> {
        let (core, persist) = self.build(product, node)?;
        self.insert(Some(product), core, persist)
    }

    /// Adds a device built elsewhere (a test node with its own dictionary).
    pub fn add_device(&self, core: DeviceCore) -> Result<(), RackError> {
        self.insert(None, core, None)
    }

    fn build(
        &self,
        product: Product,
        node: NodeId,
    ) -> Result<(DeviceCore, Option<PathBuf>), RackError> {
        let mut core = product.device(node).map_err(RackError::Device)?;
        let path = self
            .data_dir
            .as_deref()
            .map(|dir| saved_path(dir, product.name(), node));
        if let Some(path) = &path {
            core.load_saved(read_saved(path).map_err(|err| RackError::Device(err.to_string()))?);
        }
        Ok((core, path))
    }

    fn insert(
        &self,
        product: Option<Product>,
        mut core: DeviceCore,
        persist: Option<PathBuf>,
    ) -> Result<(), RackError> {
        let node = core.node();
        let mut inner = lock(&self.inner);
        if let Some(slot) = inner.slots.get(&node) {
            return Err(RackError::NodeTaken(node, product_name(slot)));
        }
        let now = now();
        core.set_bitrate(inner.bitrate);
        let boot = core.boot(now);
        core.tick_to(now);
        let version = core.saved_version();
        inner
            .outbox
            .extend(boot.into_iter().map(|frame| (node, frame)));
        inner.slots.insert(
            node,
            Slot {
                product,
                core,
                plugged: true,
                persist: persist.map(|path| (path, version)),
            },
        );
        drop(inner);
        self.wake.notify_one();
        Ok(())
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
    let mut out: Vec<(NodeId, Frame)> = Vec::new();
    let mut saves: Vec<(PathBuf, super::device::SavedValues)> = Vec::new();
    loop {
        let woke = tokio::select! {
            received = frames.recv() => match received {
                Ok(frame) => Wake::Frame(frame.frame),
                // Requests lost in an overrun end as timeouts, as on a real bus.
                Err(RecvError::Lagged(_)) => continue,
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
                    for (node, slot) in inner.slots.iter_mut() {
                        slot.core.tick_to(due);
                        let frames = slot.core.poll(due);
                        if slot.plugged {
                            out.extend(frames.into_iter().map(|frame| (*node, frame)));
                        }
                    }
                }
                Wake::Controls => {}
            }
            let controls = std::mem::take(&mut inner.outbox);
            out.extend(controls);
            relay_between_devices(&mut inner, now, &mut out);
            collect_saves(&mut inner, &mut saves);
        }
        stats
            .max_busy_us
            .fetch_max(busy_from.elapsed().as_micros() as u64, Ordering::Relaxed);
        for (path, saved) in saves.drain(..) {
            // A device whose flash fails still runs; the log says so.
            if let Err(err) = write_saved(&path, &saved) {
                tracing::warn!("virtual device: {err}");
            }
        }
        for (_, frame) in out.drain(..) {
            match bus.try_send(frame) {
                Ok(()) => {
                    stats.frames_sent.fetch_add(1, Ordering::Relaxed);
                }
                Err(err) => tracing::debug!("virtual device: frame not sent: {err}"),
            }
        }
    }
}

/// A frame on the wire reaches every device plugged in but its sender.
fn deliver(
    inner: &mut Inner,
    sender: Option<NodeId>,
    frame: &Frame,
    now: Instant,
    out: &mut Vec<(NodeId, Frame)>,
) {
    for (node, slot) in inner.slots.iter_mut() {
        if !slot.plugged || Some(*node) == sender {
            continue;
        }
        let replies = slot.core.handle_frame(frame, now);
        out.extend(replies.into_iter().map(|reply| (*node, reply)));
    }
}

/// The devices hear each other's frames (a TPDO of one may be an RPDO of
/// another), and whatever they answer in turn, a bounded number of rounds.
/// Each frame first passes its sender's CAN controller
/// ([`DeviceCore::on_the_wire`]): a bus-off device sends nothing, one with
/// bit errors an error frame before its frame.
fn relay_between_devices(inner: &mut Inner, now: Instant, out: &mut Vec<(NodeId, Frame)>) {
    let mut start = 0;
    for _ in 0..MAX_LOCAL_ROUNDS {
        on_the_wire(inner, now, out, start);
        let end = out.len();
        if start == end || inner.slots.len() < 2 {
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
fn on_the_wire(inner: &mut Inner, now: Instant, out: &mut Vec<(NodeId, Frame)>, start: usize) {
    if start == out.len() {
        return;
    }
    let sent: Vec<(NodeId, Frame)> = out.drain(start..).collect();
    for (node, frame) in sent {
        let Some(slot) = inner.slots.get_mut(&node) else {
            continue;
        };
        for frame in slot.core.on_the_wire(frame, now).into_iter().flatten() {
            out.push((node, frame));
        }
    }
}

/// The saved values of devices that saved since they were last written.
fn collect_saves(inner: &mut Inner, saves: &mut Vec<(PathBuf, super::device::SavedValues)>) {
    for slot in inner.slots.values_mut() {
        if let Some((path, version)) = &mut slot.persist
            && slot.core.saved_version() != *version
        {
            *version = slot.core.saved_version();
            saves.push((path.clone(), slot.core.saved().clone()));
        }
    }
}

#[cfg(test)]
mod tests;
