//! The [`Bus`]: one attachment to a CAN bus, whatever carries it.
//!
//! A `Bus` is what a CAN controller is to a node: it sends frames, receives the
//! frames others send (never its own, as on a real bus), and reports the bus
//! state and its counters. Every backend (virtual hub, socketcand client,
//! SocketCAN, replay) hands out the same `Bus` type, so nothing above `crates/can`
//! knows which one it has.
//!
//! Received frames are fanned out to any number of [`FrameReceiver`]s. A
//! receiver that falls behind loses the oldest frames and is told how many
//! ([`RecvError::Lagged`]), exactly like a controller's receive overrun: a slow
//! reader never slows the bus or the other readers, and memory stays bounded.
//!
//! Each attachment has a queue of its own for what others send (its receive
//! buffer), and a second one, fed only while someone monitors it, that also
//! holds what it sent. So an attachment that sends a lot never pushes out of
//! its own receive window the frames others sent it.

use std::collections::HashMap;
use std::sync::atomic::AtomicBool;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock, RwLock};
use std::time::Duration;

use tokio::sync::{broadcast, mpsc, watch};
use tokio::task::JoinHandle;

use super::frame::{CanId, Direction, Frame, TimedFrame, Timestamp};
use super::hub::{ControllerFault, HubLink};
use super::timing::frame_bits;

/// How many frames a receiver may fall behind before it loses the oldest.
/// About one second of a saturated 1 Mbit/s bus.
pub const DEFAULT_RX_QUEUE: usize = 8192;
/// Frames waiting to be written by a driver task (socketcand, SocketCAN).
pub const DEFAULT_TX_QUEUE: usize = 1024;

/// Which backend carries a bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BusKind {
    Virtual,
    Socketcand,
    Socketcan,
    Replay,
}

impl BusKind {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Virtual => "virtual",
            Self::Socketcand => "socketcand",
            Self::Socketcan => "socketcan",
            Self::Replay => "replay",
        }
    }
}

/// The state of the bus as this attachment sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BusState {
    /// Connected and error active: frames flow.
    Up,
    /// The controller is error passive (transmit or receive error counter at
    /// 128 or more): frames still flow, but the bus is unhealthy.
    ErrorPassive,
    /// The controller left the bus after too many transmit errors.
    BusOff,
    /// Not connected (connection lost, interface down, replay finished).
    Down,
}

impl BusState {
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Up => "up",
            Self::ErrorPassive => "error_passive",
            Self::BusOff => "bus_off",
            Self::Down => "down",
        }
    }

    /// The CAN controller's error state this state names; `None` when the
    /// bus is down (there is no controller to speak of).
    pub fn error_state(self) -> Option<super::fault::ErrorState> {
        use super::fault::ErrorState;
        match self {
            Self::Up => Some(ErrorState::ErrorActive),
            Self::ErrorPassive => Some(ErrorState::ErrorPassive),
            Self::BusOff => Some(ErrorState::BusOff),
            Self::Down => None,
        }
    }

    /// Whether frames can be sent in this state.
    pub fn can_send(self) -> bool {
        matches!(self, Self::Up | Self::ErrorPassive)
    }
}

/// The bus state with the reason for the last change, for people to read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BusStatus {
    pub state: BusState,
    pub reason: Option<String>,
}

impl BusStatus {
    pub fn up() -> Self {
        Self {
            state: BusState::Up,
            reason: None,
        }
    }

    pub fn new(state: BusState, reason: impl Into<String>) -> Self {
        Self {
            state,
            reason: Some(reason.into()),
        }
    }
}

/// Why a frame could not be sent. What the bus did, never what a device said.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BusError {
    #[error("bus {bus} is {}{}", .state.as_str(), .reason.as_deref().map(|r| format!(": {r}")).unwrap_or_default())]
    NotUp {
        bus: String,
        state: BusState,
        reason: Option<String>,
    },
    #[error("bus {0} is closed")]
    Closed(String),
    #[error("bus {0} is a replay and cannot send")]
    ReadOnly(String),
    #[error("bus {0}: transmit queue full")]
    TxQueueFull(String),
    #[error("bus {bus} cannot send {what}")]
    Unsupported { bus: String, what: &'static str },
    #[error("bus {bus} did not come up within {timeout:?}{}", .reason.as_deref().map(|r| format!(": {r}")).unwrap_or_default())]
    Timeout {
        bus: String,
        timeout: Duration,
        reason: Option<String>,
    },
}

/// Counters of one attachment, updated lock-free.
#[derive(Debug, Default)]
pub struct BusCounters {
    pub rx_frames: AtomicU64,
    pub tx_frames: AtomicU64,
    pub rx_bits: AtomicU64,
    pub tx_bits: AtomicU64,
    /// Frames lost by receivers that fell behind.
    pub rx_overruns: AtomicU64,
    /// Frames that could not be sent (bus down, write failed).
    pub tx_errors: AtomicU64,
    /// Error frames seen.
    pub error_frames: AtomicU64,
    /// Times a lost connection was re-established.
    pub reconnects: AtomicU64,
    /// Malformed input from the transport (counted, never fatal).
    pub malformed: AtomicU64,
    /// The controller's transmit error counter (TEC) as last known: the
    /// virtual hub's fault confinement, or data\[6\] of SocketCAN's error
    /// frames. A level, not a count.
    pub tec: AtomicU64,
    /// The controller's receive error counter (REC), likewise (data\[7\]).
    pub rec: AtomicU64,
    /// Frames refused because the sender's transmit queue was full
    /// ([`DEFAULT_TX_QUEUE`]): this attachment's own, or on a virtual bus
    /// every sender's (see [`Bus::counters`]).
    pub tx_queue_overflows: AtomicU64,
}

impl BusCounters {
    pub(crate) fn count_rx(&self, frame: &Frame) {
        self.rx_frames.fetch_add(1, Ordering::Relaxed);
        self.rx_bits
            .fetch_add(u64::from(frame_bits(frame)), Ordering::Relaxed);
        if frame.is_error() {
            self.error_frames.fetch_add(1, Ordering::Relaxed);
        }
    }

    pub(crate) fn count_tx(&self, frame: &Frame) {
        self.tx_frames.fetch_add(1, Ordering::Relaxed);
        self.tx_bits
            .fetch_add(u64::from(frame_bits(frame)), Ordering::Relaxed);
    }

    pub(crate) fn bump(counter: &AtomicU64) {
        counter.fetch_add(1, Ordering::Relaxed);
    }

    pub fn snapshot(&self) -> CounterSnapshot {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        CounterSnapshot {
            rx_frames: get(&self.rx_frames),
            tx_frames: get(&self.tx_frames),
            rx_bits: get(&self.rx_bits),
            tx_bits: get(&self.tx_bits),
            rx_overruns: get(&self.rx_overruns),
            tx_errors: get(&self.tx_errors),
            error_frames: get(&self.error_frames),
            reconnects: get(&self.reconnects),
            malformed: get(&self.malformed),
            tec: get(&self.tec),
            rec: get(&self.rec),
            tx_queue_overflows: get(&self.tx_queue_overflows),
        }
    }
}

/// A copy of [`BusCounters`] at one moment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CounterSnapshot {
    pub rx_frames: u64,
    pub tx_frames: u64,
    pub rx_bits: u64,
    pub tx_bits: u64,
    pub rx_overruns: u64,
    pub tx_errors: u64,
    pub error_frames: u64,
    pub reconnects: u64,
    pub malformed: u64,
    /// Transmit error counter (see [`BusCounters::tec`]).
    pub tec: u64,
    /// Receive error counter (see [`BusCounters::rec`]).
    pub rec: u64,
    /// Frames refused by a full transmit queue (see
    /// [`BusCounters::tx_queue_overflows`]).
    pub tx_queue_overflows: u64,
}

/// Who put a frame on a fan-out channel: an attachment id, or [`WIRE`] for
/// frames that came from outside the process.
pub(crate) type Origin = u32;
pub(crate) const WIRE: Origin = 0;

/// What travels on a fan-out channel.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Envelope {
    pub origin: Origin,
    pub frame: Frame,
    pub timestamp: Timestamp,
}

/// A fan-out channel made on first use. tokio's broadcast channel allocates
/// its whole ring at once (about 1 MiB for [`DEFAULT_RX_QUEUE`]), and most
/// attachments are never monitored.
#[derive(Clone)]
pub(crate) struct LazyChannel {
    cell: Arc<OnceLock<broadcast::Sender<Envelope>>>,
    capacity: usize,
}

impl LazyChannel {
    pub(crate) fn new(capacity: usize) -> Self {
        Self {
            cell: Arc::new(OnceLock::new()),
            capacity,
        }
    }

    pub(crate) fn subscribe(&self) -> broadcast::Receiver<Envelope> {
        self.cell
            .get_or_init(|| broadcast::channel(self.capacity).0)
            .subscribe()
    }

    /// Sends if anyone ever subscribed; a channel never made costs nothing.
    pub(crate) fn send(&self, envelope: Envelope) {
        if let Some(channel) = self.cell.get() {
            let _ = channel.send(envelope);
        }
    }

    pub(crate) fn receiver_count(&self) -> usize {
        self.cell.get().map_or(0, |c| c.receiver_count())
    }

    pub(crate) fn len(&self) -> usize {
        self.cell.get().map_or(0, |c| c.len())
    }
}

/// How many frames of one identifier a reader of that identifier alone
/// ([`Bus::subscribe_id`]) may fall behind: more than an SDO block of 127
/// segments.
pub const ID_RX_QUEUE: usize = 512;

/// The fan-out channels of single identifiers, made on first use: a CAN
/// controller's acceptance filters. A reader of one identifier neither
/// wakes for the other frames of a busy bus nor has to skip them, and a
/// bus without such readers pays one atomic load per frame.
#[derive(Clone, Default)]
pub(crate) struct IdChannels {
    inner: Arc<IdChannelsInner>,
}

#[derive(Default)]
struct IdChannelsInner {
    /// Set once the first channel is made.
    any: AtomicBool,
    channels: RwLock<HashMap<CanId, broadcast::Sender<Envelope>>>,
}

impl IdChannels {
    pub(crate) fn subscribe(&self, id: CanId) -> broadcast::Receiver<Envelope> {
        let mut channels = self
            .inner
            .channels
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        // Channels whose readers are all gone go (a node's SDO channel is
        // made again after it boots).
        channels.retain(|_, channel| channel.receiver_count() > 0);
        let receiver = channels
            .entry(id)
            .or_insert_with(|| broadcast::channel(ID_RX_QUEUE).0)
            .subscribe();
        self.inner.any.store(true, Ordering::Relaxed);
        receiver
    }

    /// Hands `envelope` to the readers of its identifier, if any.
    pub(crate) fn send(&self, envelope: Envelope) {
        if !self.inner.any.load(Ordering::Relaxed) {
            return;
        }
        let channels = self
            .inner
            .channels
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(channel) = channels.get(&envelope.frame.id()) {
            let _ = channel.send(envelope);
        }
    }

    pub(crate) fn receiver_count(&self) -> usize {
        self.inner
            .channels
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .values()
            .map(broadcast::Sender::receiver_count)
            .sum()
    }
}

/// How an attachment's frames leave it.
pub(crate) enum TxPath {
    /// Straight into an in-process hub.
    Hub(HubLink),
    /// To a driver task that owns the transport.
    Driver(mpsc::Sender<Frame>),
    /// Nothing can be sent (replay).
    ReadOnly,
}

/// Stops a driver task when the last handle to its bus is dropped.
pub(crate) struct DriverGuard(pub JoinHandle<()>);

impl Drop for DriverGuard {
    fn drop(&mut self) {
        self.0.abort();
    }
}

struct BusInner {
    name: String,
    spec: String,
    kind: BusKind,
    me: Origin,
    tx: TxPath,
    rx_frames: broadcast::Sender<Envelope>,
    id_frames: IdChannels,
    monitor_frames: LazyChannel,
    status: watch::Receiver<BusStatus>,
    counters: Arc<BusCounters>,
    _driver: Option<DriverGuard>,
}

/// One attachment to a CAN bus. Cheap to clone; clones share the attachment.
#[derive(Clone)]
pub struct Bus {
    inner: Arc<BusInner>,
}

impl std::fmt::Debug for Bus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bus")
            .field("name", &self.inner.name)
            .field("spec", &self.inner.spec)
            .finish()
    }
}

/// The parts a backend assembles a [`Bus`] from.
pub(crate) struct BusParts {
    pub name: String,
    pub spec: String,
    pub kind: BusKind,
    pub me: Origin,
    pub tx: TxPath,
    /// What others send.
    pub rx_frames: broadcast::Sender<Envelope>,
    /// The same, by identifier, for the readers of one.
    pub id_frames: IdChannels,
    /// What others send and what this attachment sends, for monitors.
    pub monitor_frames: LazyChannel,
    pub status: watch::Receiver<BusStatus>,
    pub counters: Arc<BusCounters>,
    pub driver: Option<DriverGuard>,
}

impl Bus {
    pub(crate) fn from_parts(parts: BusParts) -> Self {
        Self {
            inner: Arc::new(BusInner {
                name: parts.name,
                spec: parts.spec,
                kind: parts.kind,
                me: parts.me,
                tx: parts.tx,
                rx_frames: parts.rx_frames,
                id_frames: parts.id_frames,
                monitor_frames: parts.monitor_frames,
                status: parts.status,
                counters: parts.counters,
                _driver: parts.driver,
            }),
        }
    }

    /// The bus's name (`demo`, `can0`, ...).
    pub fn name(&self) -> &str {
        &self.inner.name
    }

    /// The spec the bus was opened from (`socketcand:host:port/can0`, ...).
    pub fn spec(&self) -> &str {
        &self.inner.spec
    }

    pub fn kind(&self) -> BusKind {
        self.inner.kind
    }

    /// Sends a frame, waiting for room in the transmit queue if a driver's
    /// queue is full. Fails at once when the bus is not up: a frame held back
    /// while disconnected and sent later could act on a machine at the wrong
    /// moment.
    pub async fn send(&self, frame: Frame) -> Result<(), BusError> {
        self.check_up()?;
        match &self.inner.tx {
            TxPath::Hub(link) => {
                link.send(frame).await;
                self.inner.counters.count_tx(&frame);
                Ok(())
            }
            TxPath::Driver(queue) => queue
                .send(frame)
                .await
                .map_err(|_| BusError::Closed(self.inner.name.clone())),
            TxPath::ReadOnly => Err(BusError::ReadOnly(self.inner.name.clone())),
        }
    }

    /// Sends a frame without waiting: a full transmit queue is an error.
    pub fn try_send(&self, frame: Frame) -> Result<(), BusError> {
        self.check_up()?;
        match &self.inner.tx {
            TxPath::Hub(link) => {
                // The hub counts and logs the overflow, for the whole bus.
                link.try_send(frame)
                    .map_err(|_| BusError::TxQueueFull(self.inner.name.clone()))?;
                self.inner.counters.count_tx(&frame);
                Ok(())
            }
            TxPath::Driver(queue) => queue.try_send(frame).map_err(|err| match err {
                mpsc::error::TrySendError::Full(_) => {
                    let overflows = &self.inner.counters.tx_queue_overflows;
                    if overflows.fetch_add(1, Ordering::Relaxed) == 0 {
                        tracing::warn!(
                            "bus {}: transmit queue full, frame dropped (counted in tx_queue_overflows)",
                            self.inner.name
                        );
                    }
                    BusError::TxQueueFull(self.inner.name.clone())
                }
                mpsc::error::TrySendError::Closed(_) => BusError::Closed(self.inner.name.clone()),
            }),
            TxPath::ReadOnly => Err(BusError::ReadOnly(self.inner.name.clone())),
        }
    }

    /// Injects a fault into this attachment's CAN controller (see
    /// [`ControllerFault`]); only an attachment to a virtual hub has one to
    /// inject into.
    pub fn controller_fault(&self, fault: ControllerFault) -> Result<(), BusError> {
        match &self.inner.tx {
            TxPath::Hub(link) => {
                link.controller_fault(fault);
                Ok(())
            }
            _ => Err(BusError::Unsupported {
                bus: self.inner.name.clone(),
                what: "controller faults (a virtual bus only)",
            }),
        }
    }

    fn check_up(&self) -> Result<(), BusError> {
        let status = self.inner.status.borrow();
        if status.state.can_send() {
            return Ok(());
        }
        BusCounters::bump(&self.inner.counters.tx_errors);
        Err(BusError::NotUp {
            bus: self.inner.name.clone(),
            state: status.state,
            reason: status.reason.clone(),
        })
    }

    /// The frames other nodes send, from now on. The receiver belongs to
    /// this attachment: once the last handle to the attachment is dropped it
    /// reports [`RecvError::Closed`], so keep the [`Bus`] while reading.
    pub fn subscribe(&self) -> FrameReceiver {
        self.receiver(false)
    }

    /// The frames other nodes send with identifier `id` alone, from now on
    /// (an acceptance filter): for a reader of one kind of answer, such as
    /// an SDO client's, which on a bus busy with PDOs would otherwise wake
    /// for every frame, or find thousands queued before its own. Data and
    /// remote frames of `id` both come. Keep the [`Bus`] while reading, as
    /// with [`Bus::subscribe`].
    pub fn subscribe_id(&self, id: CanId) -> FrameReceiver {
        FrameReceiver {
            rx: self.inner.id_frames.subscribe(id),
            me: self.inner.me,
            counters: self.inner.counters.clone(),
        }
    }

    /// Everything on the bus from now on, including the frames sent through
    /// this attachment (as [`Direction::Tx`]): for traces and logs.
    pub fn monitor(&self) -> FrameReceiver {
        self.receiver(true)
    }

    fn receiver(&self, include_own: bool) -> FrameReceiver {
        let rx = if include_own {
            self.inner.monitor_frames.subscribe()
        } else {
            self.inner.rx_frames.subscribe()
        };
        FrameReceiver {
            rx,
            me: self.inner.me,
            counters: self.inner.counters.clone(),
        }
    }

    pub fn status(&self) -> BusStatus {
        self.inner.status.borrow().clone()
    }

    pub fn state(&self) -> BusState {
        self.inner.status.borrow().state
    }

    /// A watch on the bus status, to react to changes.
    pub fn watch_status(&self) -> watch::Receiver<BusStatus> {
        self.inner.status.clone()
    }

    /// Waits until frames can be sent, or fails with the last reason after
    /// `timeout`.
    pub async fn wait_up(&self, timeout: Duration) -> Result<(), BusError> {
        let mut status = self.inner.status.clone();
        let wait = status.wait_for(|s| s.state.can_send());
        match tokio::time::timeout(timeout, wait).await {
            Ok(Ok(_)) => Ok(()),
            Ok(Err(_)) => Err(BusError::Closed(self.inner.name.clone())),
            Err(_) => Err(BusError::Timeout {
                bus: self.inner.name.clone(),
                timeout,
                reason: self.inner.status.borrow().reason.clone(),
            }),
        }
    }

    /// This attachment's counters; on a virtual bus `tx_queue_overflows`
    /// is the bus's: frames any sender's full queue refused.
    pub fn counters(&self) -> CounterSnapshot {
        let mut snapshot = self.inner.counters.snapshot();
        if let TxPath::Hub(link) = &self.inner.tx {
            snapshot.tx_queue_overflows = link.tx_queue_overflows();
        }
        snapshot
    }

    /// Like [`Bus::try_send`] for a frame that only its latest value is
    /// worth sending (a heartbeat): on a virtual bus, if this attachment
    /// still has a frame with the same identifier waiting, the new one
    /// takes its place, as a CAN controller's transmit buffer rewritten
    /// before it went out, so that a starved sender does not send a
    /// backlog of stale values once the bus frees.
    pub fn try_send_latest(&self, frame: Frame) -> Result<(), BusError> {
        if let TxPath::Hub(link) = &self.inner.tx
            && link.replace_queued(frame)
        {
            return Ok(());
        }
        self.try_send(frame)
    }

    /// Lets go of this handle. When it is the last one, the frames still
    /// queued for sending are written before the backend stops (dropping the
    /// last handle instead stops it at once, and queued frames are lost).
    /// Waits at most `DRAIN_LIMIT` for a backend that cannot write.
    pub async fn close(self) {
        let Ok(inner) = Arc::try_unwrap(self.inner) else {
            return;
        };
        let BusInner { tx, _driver, .. } = inner;
        if let (TxPath::Driver(queue), Some(mut driver)) = (tx, _driver) {
            // Closing the queue tells the driver to finish: it writes what is
            // queued, then ends.
            drop(queue);
            let _ = tokio::time::timeout(DRAIN_LIMIT, &mut driver.0).await;
        }
    }
}

/// How long [`Bus::close`] waits for queued frames to be written.
pub const DRAIN_LIMIT: Duration = Duration::from_secs(2);

/// Why no frame was received.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum RecvError {
    /// The receiver fell behind and lost this many frames; the next call
    /// returns the oldest frame still queued.
    #[error("receiver fell behind and lost {0} frames")]
    Lagged(u64),
    /// The bus was closed and every queued frame has been read.
    #[error("bus closed")]
    Closed,
}

/// A stream of frames from one [`Bus`].
pub struct FrameReceiver {
    rx: broadcast::Receiver<Envelope>,
    me: Origin,
    counters: Arc<BusCounters>,
}

impl FrameReceiver {
    /// The next frame.
    pub async fn recv(&mut self) -> Result<TimedFrame, RecvError> {
        let result = self.rx.recv().await;
        self.accept(result)
    }

    /// The next frame if one is queued, without waiting.
    pub fn try_recv(&mut self) -> Result<Option<TimedFrame>, RecvError> {
        let result = match self.rx.try_recv() {
            Err(broadcast::error::TryRecvError::Empty) => return Ok(None),
            Err(broadcast::error::TryRecvError::Lagged(n)) => {
                Err(broadcast::error::RecvError::Lagged(n))
            }
            Err(broadcast::error::TryRecvError::Closed) => Err(broadcast::error::RecvError::Closed),
            Ok(envelope) => Ok(envelope),
        };
        self.accept(result).map(Some)
    }

    fn accept(
        &self,
        result: Result<Envelope, broadcast::error::RecvError>,
    ) -> Result<TimedFrame, RecvError> {
        match result {
            Ok(envelope) => Ok(TimedFrame {
                frame: envelope.frame,
                timestamp: envelope.timestamp,
                direction: if envelope.origin == self.me {
                    Direction::Tx
                } else {
                    Direction::Rx
                },
            }),
            Err(broadcast::error::RecvError::Lagged(n)) => {
                self.counters.rx_overruns.fetch_add(n, Ordering::Relaxed);
                Err(RecvError::Lagged(n))
            }
            Err(broadcast::error::RecvError::Closed) => Err(RecvError::Closed),
        }
    }
}

/// Channels a driver task uses to feed its [`Bus`].
pub(crate) struct DriverSide {
    pub rx_frames: broadcast::Sender<Envelope>,
    pub id_frames: IdChannels,
    pub monitor_frames: LazyChannel,
    pub status: watch::Sender<BusStatus>,
    pub counters: Arc<BusCounters>,
    pub tx: mpsc::Receiver<Frame>,
}

/// The attachment id a driver-backed bus uses for its own frames.
pub(crate) const DRIVER_SELF: Origin = 1;

impl DriverSide {
    /// Publishes a frame that came from the wire.
    pub(crate) fn received(&self, frame: Frame, timestamp: Timestamp) {
        self.counters.count_rx(&frame);
        let envelope = Envelope {
            origin: WIRE,
            frame,
            timestamp,
        };
        // A channel nobody listens to refuses the frame: nothing is stored.
        let _ = self.rx_frames.send(envelope);
        self.id_frames.send(envelope);
        self.monitor_frames.send(envelope);
    }

    /// Publishes a frame this attachment has written, for monitors.
    pub(crate) fn sent(&self, frame: Frame) {
        self.counters.count_tx(&frame);
        self.monitor_frames.send(Envelope {
            origin: DRIVER_SELF,
            frame,
            timestamp: Timestamp::now(),
        });
    }

    /// Receivers of this bus, of both kinds.
    pub(crate) fn receivers(&self) -> usize {
        self.rx_frames.receiver_count()
            + self.id_frames.receiver_count()
            + self.monitor_frames.receiver_count()
    }

    /// Frames the slowest receiver has yet to read.
    pub(crate) fn backlog(&self) -> usize {
        self.rx_frames.len().max(self.monitor_frames.len())
    }

    pub(crate) fn set_status(&self, status: BusStatus) {
        self.status.send_if_modified(|current| {
            if *current == status {
                false
            } else {
                *current = status;
                true
            }
        });
    }

    pub(crate) fn state(&self) -> BusState {
        self.status.borrow().state
    }
}

/// Builds the channels of a driver-backed bus: the [`Bus`] handle for users
/// and the [`DriverSide`] for the task that owns the transport. The caller
/// spawns the task and hands its handle to [`attach_driver`].
pub(crate) fn driver_channels(
    name: &str,
    spec: &str,
    kind: BusKind,
    initial: BusStatus,
    tx_path_read_only: bool,
) -> (BusParts, DriverSide) {
    let (rx_frames, _) = broadcast::channel(DEFAULT_RX_QUEUE);
    let monitor_frames = LazyChannel::new(DEFAULT_RX_QUEUE);
    let id_frames = IdChannels::default();
    let (status_tx, status_rx) = watch::channel(initial);
    let (tx_queue, tx_rx) = mpsc::channel(DEFAULT_TX_QUEUE);
    let counters = Arc::new(BusCounters::default());
    let parts = BusParts {
        name: name.to_string(),
        spec: spec.to_string(),
        kind,
        me: DRIVER_SELF,
        tx: if tx_path_read_only {
            TxPath::ReadOnly
        } else {
            TxPath::Driver(tx_queue)
        },
        rx_frames: rx_frames.clone(),
        id_frames: id_frames.clone(),
        monitor_frames: monitor_frames.clone(),
        status: status_rx,
        counters: counters.clone(),
        driver: None,
    };
    let driver = DriverSide {
        rx_frames,
        id_frames,
        monitor_frames,
        status: status_tx,
        counters,
        tx: tx_rx,
    };
    (parts, driver)
}

/// Finishes a driver-backed bus once its task is spawned.
pub(crate) fn attach_driver(mut parts: BusParts, task: JoinHandle<()>) -> Bus {
    parts.driver = Some(DriverGuard(task));
    Bus::from_parts(parts)
}

#[cfg(test)]
mod tests;
