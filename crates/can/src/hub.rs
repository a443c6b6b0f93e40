//! The virtual bus: an in-process hub with any number of attachments.
//!
//! A frame sent by one attachment reaches every other attachment, in one
//! order that all of them see, and never the sender. A reader that falls
//! more than [`DEFAULT_RX_QUEUE`] frames behind loses the oldest, as a CAN
//! controller does on receive overrun.
//!
//! A hub has a bit rate ([`Bitrate`]). At a number of bit/s the frames take
//! time on the wire ([`super::timing`]): each attachment has a transmit
//! queue of [`DEFAULT_TX_QUEUE`] frames (a sender waits when it is full, and
//! `try_send` fails), the frames wait while the bus is busy, the lowest
//! identifier wins arbitration, and receivers get a frame when its last bit
//! has crossed the bus, a lone frame on an idle bus too. A task of the
//! hub's drives the wire on tokio's clock: it sleeps on tokio's timers (one
//! millisecond's resolution) to the millisecond before a frame's end and
//! waits out the rest on a blocking thread, so a frame is never early.
//! Under a paused clock (tests) a frame arrives at the timer tick at or
//! after its end. The wire itself keeps exact time, so the frames a second
//! and the load are exact. Unlimited, a frame reaches the others the moment
//! it is sent and the hub never blocks a sender.
//!
//! Its state can be forced (down, bus-off, ...) to test what sits above it.
//!
//! Each attachment has a CAN controller's fault confinement
//! ([`super::fault`]): its error counters rise with the errors it sees and
//! fall with the frames that cross, and its state (error active, error
//! passive, bus-off) is the attachment's [`BusStatus`]. [`Bus::controller_fault`]
//! injects bit errors into an attachment's frames, takes it bus-off, and
//! asks it to recover (128 × 11 recessive bits later at the hub's bit
//! rate, as if the bus were idle; at once when unlimited). A frame that
//! meets a bit error reaches the others as a SocketCAN error frame
//! (`CAN_ERR_PROT | CAN_ERR_BUSERROR`, a stuff error: what receivers see of
//! an error flag) and is sent again; a bus-off attachment neither sends nor
//! receives.

use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, Weak};

use tokio::sync::{Notify, Semaphore, broadcast, watch};

use super::bus::{
    Bus, BusCounters, BusKind, BusParts, BusState, BusStatus, DEFAULT_RX_QUEUE, DEFAULT_TX_QUEUE,
    Envelope, IdChannels, LazyChannel, Origin, TxPath, WIRE,
};
use super::fault::{ErrorState, FaultConfinement, Transition};
use super::frame::{ERROR_FRAME_LEN, Frame, Timestamp};
use super::timing::{Bitrate, Wire, frame_bits};

/// The queues of one attachment (see [`crate::bus`]).
struct Attachment {
    origin: Origin,
    rx_frames: broadcast::Sender<Envelope>,
    id_frames: IdChannels,
    monitor_frames: LazyChannel,
    /// The attachment's counters: the hub counts what it receives.
    counters: Arc<BusCounters>,
    /// Room in its transmit queue (a timed hub only).
    tx_room: Arc<Semaphore>,
    /// Its own status: the hub's forced one, or its controller's state.
    status: watch::Sender<BusStatus>,
    /// Its controller's error counters and state.
    confinement: FaultConfinement,
    /// Injected: each of its frames meets one bit error.
    bit_errors: bool,
    /// Set while its controller needs a look at each frame it sends (bit
    /// errors, a TEC above 0, bus-off), so that a healthy attachment's
    /// frames skip the lock.
    tx_watched: Arc<AtomicBool>,
}

/// Error class of what receivers see of an error flag: `CAN_ERR_PROT |
/// CAN_ERR_BUSERROR` (`linux/can/error.h`).
pub const BIT_ERROR_CLASS: u32 = 0x08 | 0x80;
/// Its details: data\[2\] `CAN_ERR_PROT_STUFF` (six dominant bits break the
/// stuffing rule), location unspecified.
pub const BIT_ERROR_DATA: [u8; ERROR_FRAME_LEN] = [0, 0, 0x04, 0, 0, 0, 0, 0];

/// The error frame a bit error puts on the bus.
pub fn bit_error_frame() -> Frame {
    Frame::error(BIT_ERROR_CLASS, BIT_ERROR_DATA).expect("a valid error class")
}

/// A fault of one attachment's CAN controller (virtual buses only).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControllerFault {
    /// From now on each frame it sends meets one bit error (TEC + 8) and
    /// crosses on its retransmission (TEC − 1): error passive after 19
    /// frames, bus-off at the 37th.
    BitErrors,
    /// No more bit errors.
    NoBitErrors,
    /// Off the bus at once.
    BusOff,
    /// Asks a bus-off controller to recover.
    Recover,
}

impl Attachment {
    /// Its status from the hub's and its controller's.
    fn status(&self, hub: &BusStatus) -> BusStatus {
        if hub.state != BusState::Up {
            return hub.clone();
        }
        match self.confinement.state() {
            ErrorState::ErrorActive => BusStatus::up(),
            ErrorState::ErrorPassive => {
                BusStatus::new(BusState::ErrorPassive, "controller is error passive")
            }
            ErrorState::BusOff => BusStatus::new(
                BusState::BusOff,
                "controller is bus-off (too many transmit errors)",
            ),
        }
    }

    /// After its counters moved: they are published, and its status if the
    /// state changed.
    fn follow(&self, transition: Option<Transition>, hub: &watch::Sender<BusStatus>) {
        let tec = u64::from(self.confinement.tec());
        let rec = u64::from(self.confinement.rec());
        if self.counters.tec.load(Ordering::Relaxed) != tec {
            self.counters.tec.store(tec, Ordering::Relaxed);
        }
        if self.counters.rec.load(Ordering::Relaxed) != rec {
            self.counters.rec.store(rec, Ordering::Relaxed);
        }
        if transition.is_some() {
            let hub = hub.borrow().clone();
            self.status.send_replace(self.status(&hub));
        }
        self.tx_watched.store(
            self.bit_errors || self.confinement.tec() > 0 || !self.confinement.can_transmit(),
            Ordering::Relaxed,
        );
    }
}

struct HubInner {
    name: String,
    queue: usize,
    /// Publishing holds this lock while it fills every queue, so that all
    /// attachments see one order.
    attachments: Mutex<Vec<Attachment>>,
    status: watch::Sender<BusStatus>,
    next_origin: AtomicU32,
    frames_total: AtomicU64,
    bits_total: AtomicU64,
    /// The wire of a timed hub; `None` when the bit rate is unlimited.
    wire: Option<Mutex<Wire<Origin>>>,
    /// Wakes the wire's task: a frame was queued, or the hub is gone.
    wake: Arc<Notify>,
    /// Frames refused because their sender's transmit queue was full.
    tx_overflows: AtomicU64,
    /// An overflow was logged and the wire has not been idle since: one
    /// log line per burst.
    overflowing: AtomicBool,
}

impl Drop for HubInner {
    fn drop(&mut self) {
        // The wire's task sees the hub gone and ends.
        self.wake.notify_one();
    }
}

/// An in-process CAN bus. Cheap to clone; clones are the same bus.
#[derive(Clone)]
pub struct VirtualHub {
    inner: Arc<HubInner>,
}

impl std::fmt::Debug for VirtualHub {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VirtualHub")
            .field("name", &self.inner.name)
            .finish()
    }
}

/// An attachment's way into the hub; dropping it detaches.
pub(crate) struct HubLink {
    hub: Arc<HubInner>,
    origin: Origin,
    tx_room: Arc<Semaphore>,
    tx_watched: Arc<AtomicBool>,
}

/// The attachment's transmit queue is full.
#[derive(Debug)]
pub(crate) struct TxQueueFull;

impl HubLink {
    /// Puts `frame` on the bus, waiting for room in the transmit queue of a
    /// timed hub.
    pub(crate) async fn send(&self, frame: Frame) {
        if self.hub.wire.is_some() {
            // The semaphore is never closed.
            if let Ok(permit) = self.tx_room.acquire().await {
                permit.forget();
            }
        }
        self.hub
            .transmit(self.origin, frame, self.tx_watched.load(Ordering::Relaxed));
    }

    /// [`HubLink::send`] without waiting.
    pub(crate) fn try_send(&self, frame: Frame) -> Result<(), TxQueueFull> {
        if self.hub.wire.is_some() {
            let Ok(permit) = self.tx_room.try_acquire() else {
                self.hub.overflowed();
                return Err(TxQueueFull);
            };
            permit.forget();
        }
        self.hub
            .transmit(self.origin, frame, self.tx_watched.load(Ordering::Relaxed));
        Ok(())
    }
}

impl HubLink {
    /// Frames any sender's full transmit queue refused on this bus.
    pub(crate) fn tx_queue_overflows(&self) -> u64 {
        self.hub.tx_overflows.load(Ordering::Relaxed)
    }

    /// Puts `frame` in the place of a frame with its identifier that this
    /// attachment still has waiting; `false` when there is none (or the
    /// bus is unlimited: nothing waits).
    pub(crate) fn replace_queued(&self, frame: Frame) -> bool {
        let Some(wire) = &self.hub.wire else {
            return false;
        };
        lock(wire).replace_queued(self.origin, frame)
    }
}

impl Drop for HubLink {
    fn drop(&mut self) {
        // Frames it queued still go out: a socketcand client that sends and
        // hangs up at once has handed them to the bus.
        self.hub
            .attachments()
            .retain(|attachment| attachment.origin != self.origin);
    }
}

fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl HubInner {
    /// A sender's transmit queue refused a frame: counted, and logged once
    /// per burst (until the wire is idle again).
    fn overflowed(&self) {
        let total = self.tx_overflows.fetch_add(1, Ordering::Relaxed) + 1;
        if !self.overflowing.swap(true, Ordering::Relaxed) {
            tracing::warn!(
                "bus {}: a sender's transmit queue ({DEFAULT_TX_QUEUE} frames) is full: frames dropped ({total} so far, tx_queue_overflows)",
                self.name
            );
        }
    }

    fn attachments(&self) -> MutexGuard<'_, Vec<Attachment>> {
        // A panic elsewhere while holding the lock leaves the list intact.
        self.attachments
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// A frame sent: on the wire's queue, or to everyone at once. A frame
    /// of an attachment with bit errors first fails once (an error frame
    /// for the others); one that takes it bus-off is lost.
    fn transmit(&self, origin: Origin, frame: Frame, watched: bool) {
        let mut failed = false;
        let mut lost = false;
        if watched {
            let hub = &self.status;
            let mut attachments = self.attachments();
            if let Some(sender) = attachments.iter_mut().find(|a| a.origin == origin) {
                if !sender.confinement.can_transmit() {
                    lost = true;
                } else if sender.bit_errors && !frame.is_error() {
                    failed = true;
                    let transition = sender.confinement.transmit_error();
                    lost = !sender.confinement.can_transmit();
                    if !lost {
                        let ok = sender.confinement.transmit_ok();
                        sender.follow(transition.or(ok), hub);
                    } else {
                        sender.follow(transition, hub);
                    }
                } else if sender.confinement.tec() > 0 && !frame.is_error() {
                    let transition = sender.confinement.transmit_ok();
                    sender.follow(transition, hub);
                }
            }
        }
        if failed {
            self.publish(origin, bit_error_frame(), true);
        }
        if lost {
            return;
        }
        match &self.wire {
            Some(wire) => {
                let now = tokio::time::Instant::now().into_std();
                lock(wire).queue(origin, frame, now);
                self.wake.notify_one();
            }
            None => self.publish(origin, frame, true),
        }
    }

    /// A frame that crossed the bus reaches every other attachment; the
    /// sender's transmit queue has room for one more (`released`).
    fn publish(&self, origin: Origin, frame: Frame, released: bool) {
        self.frames_total.fetch_add(1, Ordering::Relaxed);
        self.bits_total
            .fetch_add(u64::from(frame_bits(&frame)), Ordering::Relaxed);
        let envelope = Envelope {
            origin,
            frame,
            timestamp: Timestamp::now(),
        };
        let hub = &self.status;
        // A queue nobody reads refuses the frame and stores nothing, so an
        // attachment without readers costs next to nothing.
        for attachment in self.attachments().iter_mut() {
            if attachment.origin != origin {
                if !attachment.confinement.can_transmit() {
                    // Bus-off: off the bus, it hears nothing.
                    continue;
                }
                if frame.is_error() {
                    let transition = attachment.confinement.receive_error();
                    attachment.follow(transition, hub);
                } else if attachment.confinement.rec() > 0 {
                    let transition = attachment.confinement.receive_ok();
                    attachment.follow(transition, hub);
                }
                attachment.counters.count_rx(&frame);
                let _ = attachment.rx_frames.send(envelope);
                attachment.id_frames.send(envelope);
            } else if !released {
                attachment.tx_room.add_permits(1);
            }
            attachment.monitor_frames.send(envelope);
        }
    }
}

/// tokio's timers have a resolution of one millisecond (they fire at the
/// tick at or after their deadline). The wire's task sleeps on them until
/// the tick before a frame's last bit crosses, and waits out the rest of
/// the millisecond on a blocking thread, whose sleep has the operating
/// system's microsecond resolution, so that a frame reaches the receivers
/// when it has crossed: never before, and not a tick after.
const TIMER_RESOLUTION: std::time::Duration = std::time::Duration::from_millis(1);

/// Waits until `deadline` (tokio's clock) more finely than tokio's timers.
/// `false` if the clock did not move meanwhile: it is paused (a test's),
/// whose time only moves by tokio's timers.
async fn wait_finely(deadline: tokio::time::Instant) -> bool {
    let before = tokio::time::Instant::now();
    let Some(left) = deadline.checked_duration_since(before) else {
        return true;
    };
    // A paused current-thread runtime holds its clock while a blocking
    // task runs, so the check below tells a paused clock from a real one.
    let slept = tokio::task::spawn_blocking(move || std::thread::sleep(left)).await;
    slept.is_ok() && tokio::time::Instant::now() > before
}

/// The task of a timed hub: runs its wire on tokio's clock and delivers
/// each frame when its last bit has crossed, until the hub is gone.
async fn drive_wire(hub: Weak<HubInner>, wake: Arc<Notify>) {
    // Under a paused clock a frame arrives at the timer tick at or after
    // its end: simulated time, so nothing is gained by finer waits.
    let mut paused_clock = false;
    loop {
        let deadline = {
            let Some(hub) = hub.upgrade() else {
                return;
            };
            let Some(wire) = &hub.wire else {
                return;
            };
            let now = tokio::time::Instant::now().into_std();
            let crossed = lock(wire).poll(now);
            for frame in crossed {
                hub.publish(frame.sender, frame.frame, false);
            }
            lock(wire).deadline()
        };
        let Some(deadline) = deadline.map(tokio::time::Instant::from_std) else {
            // Idle: a burst of overflows, if any, is over.
            if let Some(hub) = hub.upgrade() {
                hub.overflowing.store(false, Ordering::Relaxed);
            }
            wake.notified().await;
            continue;
        };
        let now = tokio::time::Instant::now();
        if deadline <= now {
            continue;
        }
        if paused_clock || deadline - now > TIMER_RESOLUTION {
            let wake_at = if paused_clock {
                deadline
            } else {
                deadline - TIMER_RESOLUTION
            };
            tokio::select! {
                _ = tokio::time::sleep_until(wake_at) => {}
                _ = wake.notified() => {}
            }
        } else {
            tokio::select! {
                moved = wait_finely(deadline) => paused_clock = !moved,
                _ = wake.notified() => {}
            }
        }
    }
}

impl HubInner {
    /// A fault of the controller of attachment `origin`.
    fn controller_fault(self: &Arc<Self>, origin: Origin, fault: ControllerFault) {
        let hub = &self.status;
        let recovery_bits = {
            let mut attachments = self.attachments();
            let Some(attachment) = attachments.iter_mut().find(|a| a.origin == origin) else {
                return;
            };
            match fault {
                ControllerFault::BitErrors => {
                    attachment.bit_errors = true;
                    attachment.follow(None, hub);
                }
                ControllerFault::NoBitErrors => {
                    attachment.bit_errors = false;
                    attachment.follow(None, hub);
                }
                ControllerFault::BusOff => {
                    let transition = attachment.confinement.force_bus_off();
                    attachment.follow(transition, hub);
                }
                ControllerFault::Recover => attachment.confinement.request_recovery(),
            }
            attachment.confinement.recovery_bits_left()
        };
        if fault == ControllerFault::Recover
            && let Some(bits) = recovery_bits
        {
            let duration = self
                .wire
                .as_ref()
                .map_or(Bitrate::Unlimited, |wire| lock(wire).bitrate())
                .duration_of(u32::try_from(bits).unwrap_or(u32::MAX));
            if duration.is_zero() {
                self.recessive_bits(origin, bits);
            } else {
                let hub = Arc::downgrade(self);
                tokio::spawn(async move {
                    tokio::time::sleep(duration).await;
                    if let Some(hub) = hub.upgrade() {
                        hub.recessive_bits(origin, bits);
                    }
                });
            }
        }
    }

    /// `bits` recessive bit times went by for a recovering attachment.
    fn recessive_bits(&self, origin: Origin, bits: u64) {
        let hub = &self.status;
        let mut attachments = self.attachments();
        if let Some(attachment) = attachments.iter_mut().find(|a| a.origin == origin) {
            let transition = attachment.confinement.recessive_bits(bits);
            attachment.follow(transition, hub);
        }
    }
}

impl HubLink {
    /// A fault of this attachment's controller.
    pub(crate) fn controller_fault(&self, fault: ControllerFault) {
        self.hub.controller_fault(self.origin, fault);
    }
}

impl VirtualHub {
    /// A hub of unlimited bit rate: every frame crosses at once.
    pub fn new(name: impl Into<String>) -> Self {
        Self::with_queue(name, DEFAULT_RX_QUEUE)
    }

    /// A hub whose readers may fall `queue` frames behind before losing any
    /// (unlimited bit rate).
    pub fn with_queue(name: impl Into<String>, queue: usize) -> Self {
        Self::build(name.into(), queue, Bitrate::Unlimited)
    }

    /// A hub whose frames take the time `bitrate` gives them on the wire
    /// (see the module documentation). A timed hub needs a tokio runtime:
    /// its wire runs on a task.
    pub fn with_bitrate(name: impl Into<String>, bitrate: Bitrate) -> Self {
        Self::build(name.into(), DEFAULT_RX_QUEUE, bitrate)
    }

    fn build(name: String, queue: usize, bitrate: Bitrate) -> Self {
        let (status, _) = watch::channel(BusStatus::up());
        let wake = Arc::new(Notify::new());
        let inner = Arc::new(HubInner {
            name,
            queue: queue.max(1),
            attachments: Mutex::new(Vec::new()),
            status,
            next_origin: AtomicU32::new(WIRE + 1),
            frames_total: AtomicU64::new(0),
            bits_total: AtomicU64::new(0),
            wire: bitrate.get().map(|_| Mutex::new(Wire::new(bitrate))),
            wake: wake.clone(),
            tx_overflows: AtomicU64::new(0),
            overflowing: AtomicBool::new(false),
        });
        if inner.wire.is_some() {
            tokio::spawn(drive_wire(Arc::downgrade(&inner), wake));
        }
        Self { inner }
    }

    pub fn name(&self) -> &str {
        &self.inner.name
    }

    /// The bus's bit rate.
    pub fn bitrate(&self) -> Bitrate {
        self.inner
            .wire
            .as_ref()
            .map_or(Bitrate::Unlimited, |wire| lock(wire).bitrate())
    }

    /// Bit times the wire of a timed hub has been busy (0 when unlimited).
    pub fn busy_bits(&self) -> u64 {
        self.inner
            .wire
            .as_ref()
            .map_or(0, |wire| lock(wire).busy_bits())
    }

    /// A new attachment to this bus.
    pub fn attach(&self) -> Bus {
        let origin = self.inner.next_origin.fetch_add(1, Ordering::Relaxed);
        let (rx_frames, _) = broadcast::channel(self.inner.queue);
        let monitor_frames = LazyChannel::new(self.inner.queue);
        let id_frames = IdChannels::default();
        let counters = Arc::new(BusCounters::default());
        let tx_room = Arc::new(Semaphore::new(DEFAULT_TX_QUEUE));
        let tx_watched = Arc::new(AtomicBool::new(false));
        let (status, status_rx) = watch::channel(self.inner.status.borrow().clone());
        self.inner.attachments().push(Attachment {
            origin,
            rx_frames: rx_frames.clone(),
            id_frames: id_frames.clone(),
            monitor_frames: monitor_frames.clone(),
            counters: counters.clone(),
            tx_room: tx_room.clone(),
            status,
            confinement: FaultConfinement::new(),
            bit_errors: false,
            tx_watched: tx_watched.clone(),
        });
        Bus::from_parts(BusParts {
            name: self.inner.name.clone(),
            spec: format!("virtual:{}", self.inner.name),
            kind: BusKind::Virtual,
            me: origin,
            tx: TxPath::Hub(HubLink {
                hub: self.inner.clone(),
                origin,
                tx_room,
                tx_watched,
            }),
            rx_frames,
            id_frames,
            monitor_frames,
            status: status_rx,
            counters,
            driver: None,
        })
    }

    /// Forces the bus state seen by every attachment (fault injection);
    /// back up, each attachment shows its controller's state again.
    pub fn set_status(&self, status: BusStatus) {
        self.inner.status.send_replace(status.clone());
        for attachment in self.inner.attachments().iter() {
            attachment.status.send_replace(attachment.status(&status));
        }
    }

    pub fn state(&self) -> BusState {
        self.inner.status.borrow().state
    }

    /// Frames carried since the hub was made.
    pub fn frames_total(&self) -> u64 {
        self.inner.frames_total.load(Ordering::Relaxed)
    }

    /// Bits carried since the hub was made, stuff bits counted as the
    /// worst case ([`frame_bits`]).
    pub fn bits_total(&self) -> u64 {
        self.inner.bits_total.load(Ordering::Relaxed)
    }

    /// Readers currently listening, over all attachments.
    pub fn receivers(&self) -> usize {
        self.inner
            .attachments()
            .iter()
            .map(|a| {
                a.rx_frames.receiver_count()
                    + a.id_frames.receiver_count()
                    + a.monitor_frames.receiver_count()
            })
            .sum()
    }

    /// Attachments currently on the bus.
    pub fn attachments(&self) -> usize {
        self.inner.attachments().len()
    }
}

#[cfg(test)]
mod tests;
