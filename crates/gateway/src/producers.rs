//! What the producers of the telemetry topics share (`docs/websocket.md`,
//! "Value topics": the `values`, `axes/{axis}` and `segments` topics of a
//! node): a set of [`ValueTopic`]s by key, each fed by at most one task,
//! started by the first reader and ended by the task itself when the last
//! reader is gone, and the pacing of a publish to the rate the readers want.
//!
//! A producer task asks its [`Lease`] whether to go on before each round of
//! work; the question and the start of a task by [`TopicSet::subscribe`] are
//! answered under one lock, so a reader that comes just as the task decides
//! to end gets a new task, never none. Dropping the [`TopicSet`] (the bus
//! it belongs to is gone) aborts every task.

use std::collections::HashMap;
use std::future::Future;
use std::hash::Hash;
use std::sync::{Arc, Mutex, MutexGuard, Weak};
use std::time::Duration;

use tokio::task::JoinHandle;

use super::registry::NodeInfo;
use super::telemetry::{TopicReceiver, ValueTopic};
use crate::canopen::nmt::NmtState;

/// The fastest a producer publishes, whatever a reader asks: a browser
/// redraws at 60 Hz, and faster would only cost the gateway.
pub const MAX_PUBLISH_HZ: f64 = 100.0;

/// How long a producer waiting for something that may never come (a TPDO
/// frame, a node that is gone) sleeps at most before it looks again whether
/// anyone still reads.
pub(crate) const IDLE_CHECK: Duration = Duration::from_secs(1);

/// The slowest rate anything is paced at: one update every
/// `LONGEST_PERIOD`. The stream refuses slower rates at its edge; here
/// it bounds every period, so that no rate makes a duration that cannot be
/// slept (or added to an instant).
pub const MIN_RATE_HZ: f64 = 0.01;

/// The period of [`MIN_RATE_HZ`].
pub(crate) const LONGEST_PERIOD: Duration = Duration::from_secs(100);

/// The fastest rate anything is paced at (the fastest a stream client may
/// ask its values forwarded): one update every millisecond.
pub const MAX_RATE_HZ: f64 = 1000.0;

/// The time between two publishes at `rate_hz`, at most
/// [`MAX_PUBLISH_HZ`]; see [`period_at_most`].
pub(crate) fn period(rate_hz: f64) -> Duration {
    period_at_most(rate_hz, MAX_PUBLISH_HZ)
}

/// The time between two updates at `rate_hz` capped at `max_hz`, for any
/// numbers: a rate that is no positive number counts as 1 Hz (as
/// `ValueTopic::subscribe` counts it), and the rate is held between
/// [`MIN_RATE_HZ`] and the lower of `max_hz` and [`MAX_RATE_HZ`]. So the
/// period is 1 ms to `LONGEST_PERIOD` whatever comes in: a rate of
/// 1e-300 Hz would be a period of 1e300 s, which no [`Duration`] holds.
pub fn period_at_most(rate_hz: f64, max_hz: f64) -> Duration {
    let rate = if rate_hz.is_finite() && rate_hz > 0.0 {
        rate_hz
    } else {
        1.0
    };
    // `min` takes the number when `max_hz` is NaN, so what is clamped is a
    // number, between bounds that are.
    let rate = rate.min(max_hz).clamp(MIN_RATE_HZ, MAX_RATE_HZ);
    Duration::from_secs_f64(1.0 / rate).min(LONGEST_PERIOD)
}

/// The settings of the telemetry producers of a bus.
#[derive(Debug, Clone, PartialEq)]
pub struct TelemetryConfig {
    /// The fastest an axis's status is polled over SDO when its drive sends
    /// no TPDO that carries it (`candeck serve --axis-poll-hz`).
    pub axis_poll_hz: f64,
    /// How often an LED controller's segment parameters are read over SDO
    /// while its preview is read; the pixels are drawn from them between
    /// reads.
    pub segments_read_period: Duration,
}

/// The default of `--axis-poll-hz`.
pub const DEFAULT_AXIS_POLL_HZ: f64 = 20.0;

impl Default for TelemetryConfig {
    fn default() -> Self {
        Self {
            axis_poll_hz: DEFAULT_AXIS_POLL_HZ,
            segments_read_period: Duration::from_secs(1),
        }
    }
}

/// Why a producer does not ask a node over SDO: it could not answer (the
/// registry knows it offline, or stopped, where CiA 301 allows no SDO).
pub(crate) fn unreachable(info: &NodeInfo) -> Option<String> {
    if !info.online {
        Some(format!("node {} is offline", info.id))
    } else if info.nmt == Some(NmtState::Stopped) {
        Some(format!(
            "node {} is stopped (NMT): it answers no SDO",
            info.id
        ))
    } else {
        None
    }
}

/// Waits `duration`, or less if a reader of `topic` comes or goes.
pub(crate) async fn idle(topic: &ValueTopic, duration: Duration) {
    tokio::select! {
        () = tokio::time::sleep(duration) => {}
        () = topic.readers_changed() => {}
    }
}

struct Entry {
    topic: ValueTopic,
    task: Option<JoinHandle<()>>,
}

type Entries<K> = Mutex<HashMap<K, Entry>>;

fn lock<K>(entries: &Entries<K>) -> MutexGuard<'_, HashMap<K, Entry>> {
    // Every statement leaves the map whole: a panic elsewhere leaves nothing
    // half-written to protect against.
    entries
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Topics by key, each with at most one producer task.
pub(crate) struct TopicSet<K> {
    entries: Arc<Entries<K>>,
}

impl<K> Default for TopicSet<K> {
    fn default() -> Self {
        Self {
            entries: Arc::new(Mutex::new(HashMap::new())),
        }
    }
}

impl<K: Hash + Eq + Clone + Send + 'static> TopicSet<K> {
    pub(crate) fn new() -> Self {
        Self::default()
    }

    /// A reader of topic `key` wanting `rate_hz`; the topic is made on its
    /// first reader, and `start(topic, lease)` is spawned as its producer
    /// unless one runs.
    pub(crate) fn subscribe<F, Fut>(&self, key: K, rate_hz: f64, start: F) -> TopicReceiver
    where
        F: FnOnce(ValueTopic, Lease<K>) -> Fut,
        Fut: Future<Output = ()> + Send + 'static,
    {
        let mut entries = lock(&self.entries);
        let entry = entries.entry(key.clone()).or_insert_with(|| Entry {
            topic: ValueTopic::new(),
            task: None,
        });
        let receiver = entry.topic.subscribe(rate_hz);
        if entry.task.as_ref().is_none_or(JoinHandle::is_finished) {
            let lease = Lease {
                entries: Arc::downgrade(&self.entries),
                key,
            };
            entry.task = Some(tokio::spawn(start(entry.topic.clone(), lease)));
        }
        receiver
    }

    /// The topic of `key`, if it was ever subscribed to.
    pub(crate) fn topic(&self, key: &K) -> Option<ValueTopic> {
        lock(&self.entries)
            .get(key)
            .map(|entry| entry.topic.clone())
    }

    /// Whether the producer of `key` runs.
    pub(crate) fn is_running(&self, key: &K) -> bool {
        lock(&self.entries)
            .get(key)
            .and_then(|entry| entry.task.as_ref())
            .is_some_and(|task| !task.is_finished())
    }
}

impl<K> Drop for TopicSet<K> {
    fn drop(&mut self) {
        for entry in lock(&self.entries).values() {
            if let Some(task) = &entry.task {
                task.abort();
            }
        }
    }
}

/// A producer task's hold on its topic.
pub(crate) struct Lease<K> {
    entries: Weak<Entries<K>>,
    key: K,
}

impl<K: Hash + Eq> Lease<K> {
    /// Whether the producer has readers to work for. When it has none (or
    /// its set is gone) the answer is no, the task is forgotten, and the
    /// next reader starts a new one: the caller returns at once.
    pub(crate) fn keep_going(&self) -> bool {
        let Some(entries) = self.entries.upgrade() else {
            return false;
        };
        let mut entries = lock(&entries);
        let Some(entry) = entries.get_mut(&self.key) else {
            return false;
        };
        if entry.topic.receivers() > 0 {
            return true;
        }
        entry.task = None;
        false
    }
}

#[cfg(test)]
mod tests;
