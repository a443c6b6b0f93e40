//! The virtual bus: an in-process hub with any number of attachments.
//!
//! A frame sent by one attachment reaches every other attachment, in one
//! order that all of them see (the order a real bus's arbitration would give),
//! and never the sender. The hub never blocks a sender: a reader that falls
//! more than [`DEFAULT_RX_QUEUE`] frames behind loses the oldest, as a CAN
//! controller does on receive overrun.
//!
//! Its state can be forced (down, bus-off, ...) to test what sits above it.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use tokio::sync::{broadcast, watch};

use super::bus::{
    Bus, BusCounters, BusKind, BusParts, BusState, BusStatus, DEFAULT_RX_QUEUE, Envelope,
    LazyChannel, Origin, TxPath, WIRE,
};
use super::frame::{Frame, Timestamp};

/// The queues of one attachment (see [`crate::can::bus`]).
struct Attachment {
    origin: Origin,
    rx_frames: broadcast::Sender<Envelope>,
    monitor_frames: LazyChannel,
    /// The attachment's counters: the hub counts what it receives.
    counters: Arc<BusCounters>,
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
}

impl HubLink {
    pub fn publish(&self, frame: Frame) {
        self.hub.publish(self.origin, frame);
    }
}

impl Drop for HubLink {
    fn drop(&mut self) {
        self.hub
            .attachments()
            .retain(|attachment| attachment.origin != self.origin);
    }
}

impl HubInner {
    fn attachments(&self) -> MutexGuard<'_, Vec<Attachment>> {
        // A panic elsewhere while holding the lock leaves the list intact.
        self.attachments
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    fn publish(&self, origin: Origin, frame: Frame) {
        self.frames_total.fetch_add(1, Ordering::Relaxed);
        self.bits_total
            .fetch_add(u64::from(frame.wire_bits()), Ordering::Relaxed);
        let envelope = Envelope {
            origin,
            frame,
            timestamp: Timestamp::now(),
        };
        // A queue nobody reads refuses the frame and stores nothing, so an
        // attachment without readers costs next to nothing.
        for attachment in self.attachments().iter() {
            if attachment.origin != origin {
                attachment.counters.count_rx(&frame);
                let _ = attachment.rx_frames.send(envelope);
            }
            attachment.monitor_frames.send(envelope);
        }
    }
}

impl VirtualHub {
    pub fn new(name: impl Into<String>) -> Self {
        Self::with_queue(name, DEFAULT_RX_QUEUE)
    }

    /// A hub whose readers may fall `queue` frames behind before losing any.
    pub fn with_queue(name: impl Into<String>, queue: usize) -> Self {
        let (status, _) = watch::channel(BusStatus::up());
        Self {
            inner: Arc::new(HubInner {
                name: name.into(),
                queue: queue.max(1),
                attachments: Mutex::new(Vec::new()),
                status,
                next_origin: AtomicU32::new(WIRE + 1),
                frames_total: AtomicU64::new(0),
                bits_total: AtomicU64::new(0),
            }),
        }
    }

    pub fn name(&self) -> &str {
        &self.inner.name
    }

    /// A new attachment to this bus.
    pub fn attach(&self) -> Bus {
        let origin = self.inner.next_origin.fetch_add(1, Ordering::Relaxed);
        let (rx_frames, _) = broadcast::channel(self.inner.queue);
        let monitor_frames = LazyChannel::new(self.inner.queue);
        let counters = Arc::new(BusCounters::default());
        self.inner.attachments().push(Attachment {
            origin,
            rx_frames: rx_frames.clone(),
            monitor_frames: monitor_frames.clone(),
            counters: counters.clone(),
        });
        Bus::from_parts(BusParts {
            name: self.inner.name.clone(),
            spec: format!("virtual:{}", self.inner.name),
            kind: BusKind::Virtual,
            me: origin,
            tx: TxPath::Hub(HubLink {
                hub: self.inner.clone(),
                origin,
            }),
            rx_frames,
            monitor_frames,
            status: self.inner.status.subscribe(),
            counters,
            driver: None,
        })
    }

    /// Forces the bus state seen by every attachment (fault injection).
    pub fn set_status(&self, status: BusStatus) {
        self.inner.status.send_replace(status);
    }

    pub fn state(&self) -> BusState {
        self.inner.status.borrow().state
    }

    /// Frames carried since the hub was made.
    pub fn frames_total(&self) -> u64 {
        self.inner.frames_total.load(Ordering::Relaxed)
    }

    /// Wire bits carried since the hub was made (for a load estimate).
    pub fn bits_total(&self) -> u64 {
        self.inner.bits_total.load(Ordering::Relaxed)
    }

    /// Readers currently listening, over all attachments.
    pub fn receivers(&self) -> usize {
        self.inner
            .attachments()
            .iter()
            .map(|a| a.rx_frames.receiver_count() + a.monitor_frames.receiver_count())
            .sum()
    }

    /// Attachments currently on the bus.
    pub fn attachments(&self) -> usize {
        self.inner.attachments().len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::bus::{BusError, RecvError};
    use crate::can::frame::{CanId, Direction};

    fn frame(id: u32, data: &[u8]) -> Frame {
        Frame::new(CanId::standard(id).unwrap(), data).unwrap()
    }

    #[tokio::test]
    async fn frames_reach_every_other_attachment_in_order_never_the_sender() {
        let hub = VirtualHub::new("test");
        let a = hub.attach();
        let b = hub.attach();
        let c = hub.attach();
        let mut rx_a = a.subscribe();
        let mut rx_b = b.subscribe();
        let mut rx_c = c.subscribe();

        for i in 0..100u32 {
            a.send(frame(0x100 + i, &[i as u8])).await.unwrap();
        }
        b.send(frame(0x7FF, &[])).await.unwrap();

        for rx in [&mut rx_b, &mut rx_c] {
            for i in 0..100u32 {
                let got = rx.recv().await.unwrap();
                assert_eq!(got.frame, frame(0x100 + i, &[i as u8]));
                assert_eq!(got.direction, Direction::Rx);
            }
        }
        // b does not hear itself; c and a hear b.
        assert_eq!(rx_b.try_recv().unwrap(), None);
        assert_eq!(rx_c.recv().await.unwrap().frame, frame(0x7FF, &[]));
        assert_eq!(rx_a.recv().await.unwrap().frame, frame(0x7FF, &[]));
        assert_eq!(rx_a.try_recv().unwrap(), None);
        assert_eq!(hub.frames_total(), 101);
        assert_eq!(a.counters().tx_frames, 100);
        // Each attachment counts what it heard, the sender's own frames not.
        assert_eq!(
            [
                a.counters().rx_frames,
                b.counters().rx_frames,
                c.counters().rx_frames
            ],
            [1, 100, 101]
        );
        assert_eq!(c.counters().rx_bits, hub.bits_total());
    }

    #[tokio::test]
    async fn a_monitor_sees_its_own_frames_as_tx() {
        let hub = VirtualHub::new("test");
        let a = hub.attach();
        let b = hub.attach();
        let mut monitor = a.monitor();
        a.send(frame(1, &[1])).await.unwrap();
        b.send(frame(2, &[2])).await.unwrap();
        let first = monitor.recv().await.unwrap();
        let second = monitor.recv().await.unwrap();
        assert_eq!(
            (first.frame, first.direction),
            (frame(1, &[1]), Direction::Tx)
        );
        assert_eq!(
            (second.frame, second.direction),
            (frame(2, &[2]), Direction::Rx)
        );
    }

    #[tokio::test]
    async fn a_slow_reader_loses_oldest_frames_and_is_told_without_slowing_others() {
        let hub = VirtualHub::with_queue("test", 16);
        let sender = hub.attach();
        let slow = hub.attach();
        let fast = hub.attach();
        let mut slow_rx = slow.subscribe();
        let mut fast_rx = fast.subscribe();
        for i in 0..40u32 {
            sender.send(frame(i, &[])).await.unwrap();
            // The fast reader keeps up and sees every frame.
            assert_eq!(fast_rx.recv().await.unwrap().frame, frame(i, &[]));
        }
        assert_eq!(slow_rx.recv().await, Err(RecvError::Lagged(24)));
        assert_eq!(slow_rx.recv().await.unwrap().frame, frame(24, &[]));
        assert_eq!(slow.counters().rx_overruns, 24);
    }

    #[tokio::test]
    async fn a_forced_down_bus_refuses_to_send_with_the_reason() {
        let hub = VirtualHub::new("line");
        let a = hub.attach();
        hub.set_status(BusStatus::new(BusState::BusOff, "injected"));
        let err = a.send(frame(1, &[])).await.unwrap_err();
        assert_eq!(
            err,
            BusError::NotUp {
                bus: "line".into(),
                state: BusState::BusOff,
                reason: Some("injected".into())
            }
        );
        assert_eq!(err.to_string(), "bus line is bus_off: injected");
        assert_eq!(a.counters().tx_errors, 1);
        hub.set_status(BusStatus::up());
        a.send(frame(1, &[])).await.unwrap();
    }

    #[tokio::test]
    async fn receivers_see_closed_when_their_attachment_is_gone() {
        let hub = VirtualHub::new("gone");
        let mut rx = {
            let bus = hub.attach();
            bus.subscribe()
        };
        assert_eq!(hub.attachments(), 0);
        assert_eq!(rx.recv().await, Err(RecvError::Closed));
    }

    #[tokio::test]
    async fn a_busy_sender_keeps_its_whole_receive_window_for_others() {
        let hub = VirtualHub::with_queue("test", 16);
        let chatty = hub.attach();
        let other = hub.attach();
        let mut chatty_rx = chatty.subscribe();
        other.send(frame(0x581, &[1])).await.unwrap();
        // Far more of its own frames than its queue holds.
        for i in 0..100u32 {
            chatty.send(frame(0x601, &[i as u8])).await.unwrap();
        }
        assert_eq!(chatty_rx.recv().await.unwrap().frame, frame(0x581, &[1]));
        assert_eq!(chatty_rx.try_recv().unwrap(), None);
    }
}
