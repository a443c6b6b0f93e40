//! Telemetry topics: the state the gateway follows (TPDO values, axis
//! status, LED previews) published for whoever streams it
//! (`docs/websocket.md`).
//!
//! A [`ValueTopic`] holds the newest [`Sample`] of one topic and nothing
//! else: values are state, so a reader that looks late sees the newest one,
//! never a backlog, and a producer never waits for a reader. Each
//! [`TopicReceiver`] says how often its reader wants updates, so that a
//! producer that has to ask the device (SDO polling) polls only as fast as
//! its fastest reader, and not at all when nobody reads
//! ([`ValueTopic::wanted_rate_hz`]).
//!
//! [`StreamCounters`] are the stream's own numbers (clients, coalesced
//! values, lagged events) for `/metrics`. [`StreamTurns`] bound the work of
//! fanning the streams out to their clients, so that the bus and the
//! requests of others keep their place (issue 30).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{SystemTime, UNIX_EPOCH};

use tokio::sync::{Notify, OwnedSemaphorePermit, Semaphore, watch};

/// One published state of a topic.
#[derive(Debug)]
pub struct Sample {
    /// 1 for the first sample of the topic, then one more per sample: a
    /// reader that skips from 3 to 7 had 3 samples coalesced away.
    pub seq: u64,
    /// When it was published, in milliseconds since the Unix epoch.
    pub ts_ms: u64,
    pub data: serde_json::Value,
    /// `data` as JSON text, made once for every reader that sends it.
    text: OnceLock<Arc<str>>,
}

impl Sample {
    /// `data` as JSON text.
    pub fn data_text(&self) -> Arc<str> {
        self.text
            .get_or_init(|| Arc::from(self.data.to_string()))
            .clone()
    }
}

/// Milliseconds since the Unix epoch, as the stream's `ts` gives them.
pub fn unix_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |elapsed| elapsed.as_millis() as u64)
}

/// The newest value of one topic; cheap to clone (clones share it).
#[derive(Clone)]
pub struct ValueTopic {
    shared: Arc<TopicShared>,
}

struct TopicShared {
    latest: watch::Sender<Option<Arc<Sample>>>,
    seq: AtomicU64,
    /// The rate each live receiver asked for, by receiver.
    rates: Mutex<BTreeMap<u64, f64>>,
    next_receiver: AtomicU64,
    /// Woken when a receiver comes or goes.
    readers_changed: Notify,
}

impl Default for ValueTopic {
    fn default() -> Self {
        Self::new()
    }
}

impl ValueTopic {
    pub fn new() -> Self {
        Self {
            shared: Arc::new(TopicShared {
                latest: watch::Sender::new(None),
                seq: AtomicU64::new(0),
                rates: Mutex::new(BTreeMap::new()),
                next_receiver: AtomicU64::new(0),
                readers_changed: Notify::new(),
            }),
        }
    }

    /// Makes `data` the topic's newest value; never waits.
    pub fn publish(&self, data: serde_json::Value) {
        let seq = self.shared.seq.fetch_add(1, Ordering::Relaxed) + 1;
        self.shared.latest.send_replace(Some(Arc::new(Sample {
            seq,
            ts_ms: unix_ms(),
            data,
            text: OnceLock::new(),
        })));
    }

    /// The newest sample, if any was published.
    pub fn latest(&self) -> Option<Arc<Sample>> {
        self.shared.latest.borrow().clone()
    }

    /// A reader that wants at most `rate_hz` updates per second (a rate
    /// that is not a positive number counts as 1 Hz).
    pub fn subscribe(&self, rate_hz: f64) -> TopicReceiver {
        let rate_hz = if rate_hz.is_finite() && rate_hz > 0.0 {
            rate_hz
        } else {
            1.0
        };
        let id = self.shared.next_receiver.fetch_add(1, Ordering::Relaxed);
        self.shared.lock_rates().insert(id, rate_hz);
        self.shared.readers_changed.notify_waiters();
        TopicReceiver {
            latest: self.shared.latest.subscribe(),
            id,
            rate_hz,
            topic: self.shared.clone(),
        }
    }

    /// The fastest rate a live receiver asked for; `None` when nobody
    /// reads.
    pub fn wanted_rate_hz(&self) -> Option<f64> {
        self.shared.lock_rates().values().copied().reduce(f64::max)
    }

    /// Live receivers.
    pub fn receivers(&self) -> usize {
        self.shared.lock_rates().len()
    }

    /// Waits until a receiver comes or goes (or a wanted rate changes).
    pub async fn readers_changed(&self) {
        self.shared.readers_changed.notified().await;
    }

    /// Waits until the topic has at least one receiver.
    pub async fn wait_for_readers(&self) {
        loop {
            let changed = self.shared.readers_changed.notified();
            if self.receivers() > 0 {
                return;
            }
            changed.await;
        }
    }
}

impl TopicShared {
    fn lock_rates(&self) -> std::sync::MutexGuard<'_, BTreeMap<u64, f64>> {
        // A map of plain numbers is never left half-written.
        self.rates
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// One reader of a `ValueTopic`; dropping it withdraws its rate.
pub struct TopicReceiver {
    latest: watch::Receiver<Option<Arc<Sample>>>,
    id: u64,
    rate_hz: f64,
    topic: Arc<TopicShared>,
}

impl TopicReceiver {
    /// The rate this reader asked for.
    pub fn rate_hz(&self) -> f64 {
        self.rate_hz
    }

    /// Waits for a sample newer than the last one taken and takes it
    /// (`None` only if the topic is gone).
    pub async fn changed(&mut self) -> Option<Arc<Sample>> {
        loop {
            self.latest.changed().await.ok()?;
            if let Some(sample) = self.latest.borrow_and_update().clone() {
                return Some(sample);
            }
        }
    }

    /// The newest sample without waiting, marking it taken.
    pub fn take(&mut self) -> Option<Arc<Sample>> {
        self.latest.borrow_and_update().clone()
    }
}

impl Drop for TopicReceiver {
    fn drop(&mut self) {
        self.topic.lock_rates().remove(&self.id);
        self.topic.readers_changed.notify_waiters();
    }
}

/// The stream's numbers since the gateway started, for `/metrics`.
#[derive(Debug, Default)]
pub struct StreamCounters {
    /// WebSocket clients connected now.
    pub clients: AtomicU64,
    /// Messages sent to clients.
    pub messages: AtomicU64,
    /// Values a client never saw because a newer one replaced them first.
    pub coalesced: AtomicU64,
    /// Events (and frames) a client lost because it fell behind; each was
    /// reported to it as `lagged`.
    pub lagged: AtomicU64,
}

impl StreamCounters {
    pub fn add(counter: &AtomicU64, n: u64) {
        counter.fetch_add(n, Ordering::Relaxed);
    }
}

/// Stream sessions that render and write their pending messages at one
/// time, by default: one. The runtime runs its tasks in turn, so a session
/// that waits for its turn is not among them; with hundreds of sessions
/// each woken by the same frames, the bus reader, the SDO client and a
/// REST request would otherwise wait behind all of them at every step
/// (issue 30: one client's streams made REST's p99 13 times worse, and
/// with 200 streams the gateway fell so far behind its bus that SDO
/// answers were lost). With one turn, every other task runs between two
/// sessions' writes; the sessions still write as fast as the machine
/// allows, and one that falls behind loses its oldest frames (`lagged`).
pub const STREAM_TURNS: usize = 1;

/// Turns at fanning the streams out to their clients, shared by every
/// session of every door: a session takes one before it renders and
/// writes, and gives it back when done, or as soon as a write has to wait
/// for its client (a slow client never holds up the others). First come,
/// first served. Cheap to clone; clones share the turns.
#[derive(Debug, Clone)]
pub struct StreamTurns {
    turns: Arc<Semaphore>,
}

impl Default for StreamTurns {
    fn default() -> Self {
        Self::new(STREAM_TURNS)
    }
}

/// One session's turn; given back when dropped.
#[derive(Debug)]
pub struct StreamTurn {
    _permit: OwnedSemaphorePermit,
}

impl StreamTurns {
    /// `at_once` turns (at least one).
    pub fn new(at_once: usize) -> Self {
        Self {
            turns: Arc::new(Semaphore::new(at_once.max(1))),
        }
    }

    /// Waits for a turn; sessions get theirs in the order they asked.
    /// Every socket that became ready before the turn came runs first.
    pub async fn take(&self) -> StreamTurn {
        // The semaphore is never closed.
        let permit = self
            .turns
            .clone()
            .acquire_owned()
            .await
            .expect("the stream turns are never closed");
        // Handed from session to session, the turns keep the runtime's
        // queue full for a whole burst of batches, and the runtime looks
        // for socket events only every few dozen tasks (61 by default) or
        // when its queue is empty: a REST request or an SDO answer would
        // wait behind every session's write. A yielded task runs again
        // only after the runtime has polled its sockets, so their tasks go
        // first (issue 30: the REST p99 under 32 frames-topic sessions fell
        // from 4.3-4.9 to 1.3-2.5 times idle).
        tokio::task::yield_now().await;
        StreamTurn { _permit: permit }
    }

    /// Turns free now.
    pub fn free(&self) -> usize {
        self.turns.available_permits()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn stream_turns_are_taken_in_order_and_given_back_when_dropped() {
        let turns = StreamTurns::default();
        let first = turns.take().await;
        assert_eq!(turns.free(), 0);
        let order = Arc::new(Mutex::new(Vec::new()));
        let waiters: Vec<_> = (0..3)
            .map(|n| {
                let turns = turns.clone();
                let order = order.clone();
                tokio::spawn(async move {
                    let _turn = turns.take().await;
                    order.lock().unwrap().push(n);
                })
            })
            .collect();
        tokio::task::yield_now().await;
        assert!(
            order.lock().unwrap().is_empty(),
            "nobody runs while a turn is held"
        );
        drop(first);
        for waiter in waiters {
            waiter.await.unwrap();
        }
        assert_eq!(*order.lock().unwrap(), vec![0, 1, 2]);
        assert_eq!(turns.free(), STREAM_TURNS);
    }

    /// Sessions passing the turn from one to the next never leave the
    /// runtime's queue empty; a socket that became ready while a turn was
    /// held must still have its task run before the next session's turn.
    #[tokio::test]
    async fn a_socket_that_became_ready_runs_before_the_next_turn() {
        let turns = StreamTurns::default();
        let order = Arc::new(Mutex::new(Vec::new()));
        let receiver = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let sender = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        sender.connect(receiver.local_addr().unwrap()).unwrap();
        let socket = tokio::spawn({
            let order = order.clone();
            async move {
                let mut datagram = [0; 8];
                receiver.recv(&mut datagram).await.unwrap();
                order.lock().unwrap().push("socket");
            }
        });
        let first = turns.take().await;
        let sessions: Vec<_> = (0..32)
            .map(|_| {
                let turns = turns.clone();
                let order = order.clone();
                tokio::spawn(async move {
                    let _turn = turns.take().await;
                    order.lock().unwrap().push("session");
                })
            })
            .collect();
        // Every session waits for the turn, and the socket's task for its
        // datagram.
        tokio::task::yield_now().await;
        assert!(order.lock().unwrap().is_empty());
        sender.send(b"ready").unwrap();
        drop(first);
        for session in sessions {
            session.await.unwrap();
        }
        socket.await.unwrap();
        let order = order.lock().unwrap();
        let socket_at = order.iter().position(|task| *task == "socket").unwrap();
        assert_eq!(
            socket_at, 0,
            "the socket's task ran after {socket_at} sessions' turns"
        );
    }

    #[tokio::test]
    async fn a_late_reader_gets_the_newest_sample_and_can_count_what_it_missed() {
        let topic = ValueTopic::new();
        let mut reader = topic.subscribe(10.0);
        for n in 1..=5 {
            topic.publish(serde_json::json!(n));
        }
        let sample = reader.changed().await.unwrap();
        assert_eq!(sample.seq, 5);
        assert_eq!(sample.data, serde_json::json!(5));
        assert_eq!(&*sample.data_text(), "5");
        topic.publish(serde_json::json!(6));
        assert_eq!(reader.take().unwrap().seq, 6);
    }

    #[test]
    fn the_wanted_rate_is_the_fastest_live_readers() {
        let topic = ValueTopic::new();
        assert_eq!(topic.wanted_rate_hz(), None);
        let slow = topic.subscribe(2.0);
        let fast = topic.subscribe(50.0);
        let odd = topic.subscribe(f64::NAN);
        assert_eq!(odd.rate_hz(), 1.0);
        assert_eq!(topic.wanted_rate_hz(), Some(50.0));
        drop(fast);
        assert_eq!(topic.wanted_rate_hz(), Some(2.0));
        drop(slow);
        drop(odd);
        assert_eq!(topic.wanted_rate_hz(), None);
        assert_eq!(topic.receivers(), 0);
    }

    #[tokio::test(start_paused = true)]
    async fn a_producer_waits_for_its_first_reader() {
        let topic = ValueTopic::new();
        let waiting = tokio::spawn({
            let topic = topic.clone();
            async move { topic.wait_for_readers().await }
        });
        tokio::time::sleep(std::time::Duration::from_secs(1)).await;
        assert!(!waiting.is_finished());
        let _reader = topic.subscribe(1.0);
        waiting.await.unwrap();
    }
}
