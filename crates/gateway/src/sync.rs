//! The gateway's SYNC producer on one bus (CiA 301 §7.2.5): a task that
//! sends SYNC (COB-ID 0x080, no counter) at the period the API sets, with
//! the sans-I/O [`crate::canopen::sync::SyncProducer`] deciding when.
//!
//! SYNC drives every synchronous PDO on the bus (transmission types 0–240),
//! so it belongs to the bus, not to a node. A SYNC that cannot be sent
//! (bus down) is skipped, not queued: a late SYNC would sample the nodes at
//! the wrong instant.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use tokio::sync::watch;
use tokio::time::Instant;

use crate::can::{Bus, CanId};
use crate::canopen::sync::SyncProducer;

/// The longest period the API takes: 0x1006 is in µs in a u32.
pub const MAX_PERIOD_MS: u32 = u32::MAX / 1000;

/// A SYNC producer's setting and count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SyncStatus {
    /// Zero while off.
    pub period: Duration,
    pub cob_id: CanId,
    /// SYNC frames sent since the producer started.
    pub sent: u64,
}

/// The SYNC producer of one bus; dropping it stops the task.
pub struct SyncService {
    period: watch::Sender<Duration>,
    sent: Arc<AtomicU64>,
    cob_id: CanId,
    task: tokio::task::JoinHandle<()>,
}

impl Drop for SyncService {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl SyncService {
    /// Starts the producer on `bus`, off.
    pub fn spawn(bus: Bus) -> Self {
        let (period, mut changes) = watch::channel(Duration::ZERO);
        let sent = Arc::new(AtomicU64::new(0));
        let producer = SyncProducer::new();
        let cob_id = producer.cob_id();
        let counter = sent.clone();
        let task = tokio::spawn(async move {
            let mut producer = producer;
            loop {
                let deadline = producer.deadline().map(Instant::from_std);
                tokio::select! {
                    changed = changes.changed() => {
                        if changed.is_err() {
                            return;
                        }
                        let period = *changes.borrow_and_update();
                        producer.set_period(period, Instant::now().into_std());
                    }
                    _ = sleep_until(deadline) => {
                        let Some(frame) = producer.poll(Instant::now().into_std()) else {
                            continue;
                        };
                        match bus.try_send(frame) {
                            Ok(()) => {
                                counter.fetch_add(1, Ordering::Relaxed);
                            }
                            Err(err) => tracing::debug!("SYNC on {} skipped: {err}", bus.name()),
                        }
                    }
                }
            }
        });
        Self {
            period,
            sent,
            cob_id,
            task,
        }
    }

    /// Sets the period; zero turns SYNC off. The first SYNC goes one period
    /// from now.
    ///
    /// A door sets it by [`crate::Gateway::set_sync_period`].
    pub(crate) fn set_period(&self, period: Duration) {
        self.period.send_replace(period);
    }

    /// The period; zero while off.
    pub fn period(&self) -> Duration {
        *self.period.borrow()
    }

    pub fn cob_id(&self) -> CanId {
        self.cob_id
    }

    /// How many SYNC frames the producer has sent.
    pub fn sent(&self) -> u64 {
        self.sent.load(Ordering::Relaxed)
    }

    /// Its setting and count now.
    pub fn status(&self) -> SyncStatus {
        SyncStatus {
            period: self.period(),
            cob_id: self.cob_id,
            sent: self.sent(),
        }
    }
}

async fn sleep_until(deadline: Option<Instant>) {
    match deadline {
        Some(deadline) => tokio::time::sleep_until(deadline).await,
        None => std::future::pending().await,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::VirtualHub;

    async fn syncs_within(listener: &mut crate::can::FrameReceiver, window: Duration) -> usize {
        let end = Instant::now() + window;
        let mut count = 0;
        while let Ok(Ok(frame)) = tokio::time::timeout_at(end, listener.recv()).await {
            if frame.frame.id() == CanId::Standard(0x080) {
                assert!(frame.frame.data().is_empty());
                count += 1;
            }
        }
        count
    }

    #[tokio::test(start_paused = true)]
    async fn sends_sync_at_its_period_until_turned_off() {
        let hub = VirtualHub::new("t");
        let service = SyncService::spawn(hub.attach());
        let listening = hub.attach();
        let mut listener = listening.subscribe();
        assert_eq!(service.period(), Duration::ZERO);
        assert_eq!(
            syncs_within(&mut listener, Duration::from_millis(50)).await,
            0
        );
        service.set_period(Duration::from_millis(10));
        let count = syncs_within(&mut listener, Duration::from_millis(105)).await;
        assert_eq!(count, 10);
        assert_eq!(service.sent(), 10);
        service.set_period(Duration::from_millis(50));
        let count = syncs_within(&mut listener, Duration::from_millis(205)).await;
        assert_eq!(count, 4);
        service.set_period(Duration::ZERO);
        assert_eq!(
            syncs_within(&mut listener, Duration::from_millis(100)).await,
            0
        );
        assert_eq!(service.sent(), 14);
    }
}
