//! SDO transfers to one node over a [`Bus`]: the sans-I/O client of
//! [`crate::canopen::sdo`] driven by frames and tokio's clock.
//!
//! CiA 301 allows one SDO transaction at a time between a client and a
//! server, so a [`SdoChannel`] runs them one after another; callers queue on
//! a fair (first come, first served) lock. Procedures of several transfers
//! that must not interleave with another such procedure on the same node (a
//! PDO re-mapping, a DCF restore, a drive's state walk) hold
//! [`SdoChannel::procedure`] as well.
//!
//! Every channel counts its transfers by outcome and times them in a
//! latency histogram ([`SdoStats`], read as an [`SdoStatsSnapshot`] for
//! `/metrics`): a few relaxed atomic additions per transfer, taken while
//! the transfer holds the node's queue anyway, so they add no lock and no
//! contention to the hot path.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use tokio::sync::{Mutex, OwnedMutexGuard};

use crate::can::{Bus, BusError, FrameReceiver, RecvError};
use crate::canopen::NodeId;
use crate::canopen::sdo::{AbortCode, ClientConfig, SdoClient, SdoError, Step, Transfer};

/// Why an SDO transfer failed: what the device said, what the protocol
/// timer said, or what the bus did.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SdoRequestError {
    /// The node refused or broke the protocol, or did not answer in time.
    #[error("node {node}: {error}")]
    Sdo { node: NodeId, error: SdoError },
    /// The frames could not be sent or the bus went away.
    #[error("node {node}: {error}")]
    Bus { node: NodeId, error: BusError },
}

impl SdoRequestError {
    /// The abort code the device sent, if it was a device abort.
    pub fn device_abort(&self) -> Option<AbortCode> {
        match self {
            Self::Sdo {
                error: SdoError::ServerAborted(code),
                ..
            } => Some(*code),
            _ => None,
        }
    }
}

struct Session {
    client: SdoClient,
    responses: FrameReceiver,
}

/// The upper bounds of the latency histogram's buckets: 0.25 ms (a
/// request and its answer on an idle bus at 1 Mbit/s take about 0.2 ms) to
/// 2.5 s (past the default SDO timeout of 1 s), in 1-2.5-5 steps.
pub const LATENCY_BUCKETS: [Duration; 13] = [
    Duration::from_micros(250),
    Duration::from_micros(500),
    Duration::from_millis(1),
    Duration::from_micros(2500),
    Duration::from_millis(5),
    Duration::from_millis(10),
    Duration::from_millis(25),
    Duration::from_millis(50),
    Duration::from_millis(100),
    Duration::from_millis(250),
    Duration::from_millis(500),
    Duration::from_secs(1),
    Duration::from_millis(2500),
];

/// How a transfer ended, as [`SdoStats`] counts it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Outcome {
    Done,
    /// The device sent an abort.
    Aborted,
    /// The device did not answer in time.
    TimedOut,
    /// The device broke the protocol, or the client could not start.
    Protocol,
    /// The bus failed.
    Bus,
}

impl Outcome {
    fn of<T>(result: &Result<T, SdoRequestError>) -> Self {
        match result {
            Ok(_) => Self::Done,
            Err(SdoRequestError::Sdo { error, .. }) => match error {
                SdoError::ServerAborted(_) => Self::Aborted,
                SdoError::Timeout => Self::TimedOut,
                SdoError::Protocol { .. } | SdoError::Busy | SdoError::TooLarge(_) => {
                    Self::Protocol
                }
            },
            Err(SdoRequestError::Bus { .. }) => Self::Bus,
        }
    }
}

/// The transfers of one node's channel since it was made, counted by
/// outcome, with their latency (from the node's turn in the queue to the
/// end of the transfer: the time on the bus and in the device, not the
/// wait behind other callers). Lock-free.
#[derive(Debug, Default)]
pub struct SdoStats {
    aborts: AtomicU64,
    timeouts: AtomicU64,
    protocol_errors: AtomicU64,
    bus_errors: AtomicU64,
    abandoned: AtomicU64,
    /// Finished transfers per bucket (not cumulative); the last is past
    /// the last bound.
    buckets: [AtomicU64; LATENCY_BUCKETS.len() + 1],
    /// The latencies added up, in nanoseconds (u64 lasts 584 years).
    sum_nanos: AtomicU64,
}

impl SdoStats {
    fn record(&self, outcome: Outcome, latency: Duration) {
        let counter = match outcome {
            Outcome::Done => None,
            Outcome::Aborted => Some(&self.aborts),
            Outcome::TimedOut => Some(&self.timeouts),
            Outcome::Protocol => Some(&self.protocol_errors),
            Outcome::Bus => Some(&self.bus_errors),
        };
        if let Some(counter) = counter {
            counter.fetch_add(1, Ordering::Relaxed);
        }
        let bucket = LATENCY_BUCKETS
            .iter()
            .position(|bound| latency <= *bound)
            .unwrap_or(LATENCY_BUCKETS.len());
        self.buckets[bucket].fetch_add(1, Ordering::Relaxed);
        let nanos = u64::try_from(latency.as_nanos()).unwrap_or(u64::MAX);
        self.sum_nanos.fetch_add(nanos, Ordering::Relaxed);
    }

    /// The counts now. Each is read on its own while transfers go on, so
    /// two counts may be one transfer apart; the histogram's total is the
    /// sum of its buckets, so it always agrees with them.
    pub fn snapshot(&self) -> SdoStatsSnapshot {
        let get = |counter: &AtomicU64| counter.load(Ordering::Relaxed);
        let mut cumulative = [0u64; LATENCY_BUCKETS.len() + 1];
        let mut total = 0u64;
        for (out, bucket) in cumulative.iter_mut().zip(&self.buckets) {
            total += get(bucket);
            *out = total;
        }
        let abandoned = get(&self.abandoned);
        SdoStatsSnapshot {
            transactions: total + abandoned,
            aborts: get(&self.aborts),
            timeouts: get(&self.timeouts),
            protocol_errors: get(&self.protocol_errors),
            bus_errors: get(&self.bus_errors),
            abandoned,
            latency: LatencySnapshot {
                cumulative,
                sum: Duration::from_nanos(get(&self.sum_nanos)),
            },
        }
    }
}

/// [`SdoStats`] at one moment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SdoStatsSnapshot {
    /// Transfers that ended, whatever the outcome (abandoned ones included).
    pub transactions: u64,
    /// Refused by the device (SDO abort from the server).
    pub aborts: u64,
    /// Not answered in time.
    pub timeouts: u64,
    /// The device broke the protocol (the client aborted), or the transfer
    /// could not start.
    pub protocol_errors: u64,
    /// The bus could not carry the transfer (down, closed).
    pub bus_errors: u64,
    /// Given up by their caller halfway (its future dropped); aborted on
    /// the bus before the next transfer, and not in the histogram.
    pub abandoned: u64,
    /// The latency of every transfer that ended by itself.
    pub latency: LatencySnapshot,
}

/// A latency histogram at one moment, in the shape Prometheus wants.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LatencySnapshot {
    /// Transfers at or under each bound of [`LATENCY_BUCKETS`], then all of
    /// them (the `+Inf` bucket).
    pub cumulative: [u64; LATENCY_BUCKETS.len() + 1],
    /// The latencies added up.
    pub sum: Duration,
}

impl LatencySnapshot {
    /// Transfers observed.
    pub fn count(&self) -> u64 {
        self.cumulative[LATENCY_BUCKETS.len()]
    }
}

/// Counts a transfer as abandoned if its future is dropped before
/// [`Pending::finish`].
struct Pending<'a> {
    stats: &'a SdoStats,
    finished: bool,
}

impl Pending<'_> {
    fn finish(mut self, outcome: Outcome, latency: Duration) {
        self.finished = true;
        self.stats.record(outcome, latency);
    }
}

impl Drop for Pending<'_> {
    fn drop(&mut self) {
        if !self.finished {
            self.stats.abandoned.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// The SDO client side of one node on one bus.
#[derive(Clone)]
pub struct SdoChannel {
    bus: Bus,
    node: NodeId,
    /// What transfers use unless their caller gives its own
    /// ([`SdoChannel::upload_with`]).
    config: ClientConfig,
    session: Arc<Mutex<Session>>,
    procedure: Arc<Mutex<()>>,
    stats: Arc<SdoStats>,
}

impl SdoChannel {
    pub fn new(bus: Bus, node: NodeId, config: ClientConfig) -> Self {
        let responses = bus.subscribe();
        Self {
            session: Arc::new(Mutex::new(Session {
                client: SdoClient::new(node, config.clone()),
                responses,
            })),
            procedure: Arc::new(Mutex::new(())),
            stats: Arc::new(SdoStats::default()),
            bus,
            node,
            config,
        }
    }

    /// The configuration transfers use unless their caller gives its own.
    pub fn config(&self) -> &ClientConfig {
        &self.config
    }

    pub fn node(&self) -> NodeId {
        self.node
    }

    /// The channel's transfers so far, by outcome, with their latency.
    pub fn stats(&self) -> SdoStatsSnapshot {
        self.stats.snapshot()
    }

    /// Waits until no other procedure runs on this node, and holds off the
    /// next one until the guard is dropped (first come, first served).
    /// Single transfers of other callers still go between the steps: the
    /// node serves them one at a time anyway, and they do not change what
    /// a procedure configures.
    pub async fn procedure(&self) -> OwnedMutexGuard<()> {
        self.procedure.clone().lock_owned().await
    }

    /// Reads an object's value bytes.
    pub async fn upload(&self, index: u16, sub: u8) -> Result<Vec<u8>, SdoRequestError> {
        self.upload_with(index, sub, None).await
    }

    /// Writes an object's value bytes.
    pub async fn download(&self, index: u16, sub: u8, data: &[u8]) -> Result<(), SdoRequestError> {
        self.download_with(index, sub, data, None).await
    }

    /// [`SdoChannel::upload`] with the caller's own timeout and block mode
    /// (a CiA 309-3 connection's `set sdo_timeout`, `set sdo_block`) for
    /// this one transfer; `None`: the channel's. It queues like any other.
    pub async fn upload_with(
        &self,
        index: u16,
        sub: u8,
        config: Option<&ClientConfig>,
    ) -> Result<Vec<u8>, SdoRequestError> {
        match self
            .transfer(Request::Upload { index, sub }, config)
            .await?
        {
            Transfer::Uploaded(data) => Ok(data),
            Transfer::Downloaded => Ok(Vec::new()),
        }
    }

    /// [`SdoChannel::download`] with the caller's own configuration for
    /// this one transfer (see [`SdoChannel::upload_with`]).
    pub async fn download_with(
        &self,
        index: u16,
        sub: u8,
        data: &[u8],
        config: Option<&ClientConfig>,
    ) -> Result<(), SdoRequestError> {
        self.transfer(Request::Download { index, sub, data }, config)
            .await
            .map(|_| ())
    }

    async fn transfer(
        &self,
        request: Request<'_>,
        config: Option<&ClientConfig>,
    ) -> Result<Transfer, SdoRequestError> {
        let mut session = self.session.lock().await;
        // Each transfer runs with its caller's configuration, or the
        // channel's: one caller's timeout never leaks into the next one's.
        let config = config.unwrap_or(&self.config);
        if session.client.config() != config {
            session.client.set_config(config.clone());
        }
        let started = tokio::time::Instant::now();
        let pending = Pending {
            stats: &self.stats,
            finished: false,
        };
        let result = self.exchange(&mut session, request, started).await;
        pending.finish(Outcome::of(&result), started.elapsed());
        result
    }

    /// One transfer, the node's queue held.
    async fn exchange(
        &self,
        session: &mut Session,
        request: Request<'_>,
        started: tokio::time::Instant,
    ) -> Result<Transfer, SdoRequestError> {
        let Session { client, responses } = session;
        let mut now = started;
        // A caller that gave up half way (its future dropped: an HTTP client
        // that went away, a timeout around the call) left its transfer
        // running: abort it, so that the server knows, and start afresh
        // rather than refuse every later transfer as busy.
        for frame in client.abort(AbortCode::GeneralError) {
            if let Err(error) = self.bus.send(frame).await {
                tracing::debug!(
                    "node {}: abort of a dropped transfer not sent: {error}",
                    self.node
                );
            }
            // Sending may have waited: the timeout starts from here. (Read
            // the clock only then; it costs as much as the counting.)
            now = tokio::time::Instant::now();
        }
        // Answers to an earlier transfer that gave up must not be taken for
        // answers to this one.
        while let Ok(Some(_)) | Err(RecvError::Lagged(_)) = responses.try_recv() {}
        let now = now.into_std();
        let first = match request {
            Request::Upload { index, sub } => client.upload(index, sub, now),
            Request::Download { index, sub, data } => client.download(index, sub, data, now),
        }
        .map_err(|error| self.sdo_error(error))?;
        let mut step = Step {
            send: first,
            done: None,
        };
        loop {
            for frame in step.send.drain(..) {
                if let Err(error) = self.bus.send(frame).await {
                    // Leave the client ready for the next transfer.
                    let _ = client.abort(AbortCode::GeneralError);
                    return Err(SdoRequestError::Bus {
                        node: self.node,
                        error,
                    });
                }
            }
            if let Some(done) = step.done.take() {
                return done.map_err(|error| self.sdo_error(error));
            }
            let deadline = client
                .deadline()
                .map(tokio::time::Instant::from_std)
                .unwrap_or_else(|| tokio::time::Instant::now() + Duration::from_secs(1));
            step = tokio::select! {
                received = responses.recv() => match received {
                    Ok(frame) => client.handle_frame(&frame.frame, tokio::time::Instant::now().into_std()),
                    // Lost frames show up as a protocol error or a timeout.
                    Err(RecvError::Lagged(_)) => Step { send: Vec::new(), done: None },
                    Err(RecvError::Closed) => {
                        let _ = client.abort(AbortCode::GeneralError);
                        return Err(SdoRequestError::Bus {
                            node: self.node,
                            error: BusError::Closed(self.bus.name().to_string()),
                        });
                    }
                },
                _ = tokio::time::sleep_until(deadline) => {
                    client.handle_timeout(tokio::time::Instant::now().into_std())
                }
            };
        }
    }

    fn sdo_error(&self, error: SdoError) -> SdoRequestError {
        SdoRequestError::Sdo {
            node: self.node,
            error,
        }
    }
}

enum Request<'a> {
    Upload { index: u16, sub: u8 },
    Download { index: u16, sub: u8, data: &'a [u8] },
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex as StdMutex;

    use super::*;
    use crate::can::{BusState, BusStatus, CanId, VirtualHub};
    use crate::canopen::od::{AccessType, DataType, Object, ObjectDictionary, SubObject};
    use crate::sim::device::{DeviceCore, run_device};

    fn node() -> NodeId {
        NodeId::new(5).unwrap()
    }

    fn config() -> ClientConfig {
        ClientConfig {
            timeout: Duration::from_millis(500),
            ..ClientConfig::default()
        }
    }

    #[tokio::test(start_paused = true)]
    async fn a_silent_node_times_out_at_the_configured_time_and_is_told_so() {
        let hub = VirtualHub::new("test");
        let channel = SdoChannel::new(hub.attach(), node(), config());
        let observer = hub.attach();
        let mut watch = observer.monitor();
        let start = tokio::time::Instant::now();
        let error = channel.upload(0x1000, 0).await.unwrap_err();
        assert_eq!(
            error,
            SdoRequestError::Sdo {
                node: node(),
                error: SdoError::Timeout
            }
        );
        // The paused clock moved exactly by the timeout, no real waiting.
        assert_eq!(start.elapsed(), Duration::from_millis(500));
        // The request, then the client's abort 0x05040000 on 0x605.
        let request = watch.recv().await.unwrap().frame;
        assert_eq!(request.id(), CanId::Standard(0x605));
        let abort = watch.recv().await.unwrap().frame;
        assert_eq!(
            abort.data(),
            &[0x80, 0x00, 0x10, 0x00, 0x00, 0x00, 0x04, 0x05]
        );
        assert_eq!(
            error.to_string(),
            "node 5: the device did not answer the SDO request in time, so the transfer was aborted"
        );
    }

    /// A device at node 5 with one UNSIGNED32 at 0x2000 of `access`,
    /// running on `hub`.
    fn spawn_device(hub: &VirtualHub, access: AccessType) -> tokio::task::JoinHandle<()> {
        let mut dictionary = ObjectDictionary::new();
        dictionary.insert(Object::var(
            0x2000,
            SubObject::new(0, "Word", DataType::Unsigned32, access),
        ));
        let device = Arc::new(StdMutex::new(DeviceCore::new(dictionary, node()).unwrap()));
        tokio::spawn(run_device(hub.attach(), device))
    }

    #[tokio::test(start_paused = true)]
    async fn a_device_abort_a_timeout_and_a_bus_failure_are_different_errors() {
        let hub = VirtualHub::new("test");
        let server = spawn_device(&hub, AccessType::Ro);
        let channel = SdoChannel::new(hub.attach(), node(), config());

        assert_eq!(channel.upload(0x2000, 0).await, Ok(vec![0, 0, 0, 0]));
        let refused = channel
            .download(0x2000, 0, &[1, 0, 0, 0])
            .await
            .unwrap_err();
        assert_eq!(refused.device_abort(), Some(AbortCode::ReadOnlyObject));

        hub.set_status(BusStatus::new(BusState::Down, "cable pulled"));
        let down = channel.upload(0x2000, 0).await.unwrap_err();
        assert!(matches!(down, SdoRequestError::Bus { .. }), "{down:?}");
        assert_eq!(down.device_abort(), None);
        hub.set_status(BusStatus::up());

        // After every failure the channel is ready for the next transfer.
        assert_eq!(channel.upload(0x2000, 0).await, Ok(vec![0, 0, 0, 0]));
        server.abort();

        // Counted apart as well.
        let stats = channel.stats();
        assert_eq!(stats.transactions, 4, "{stats:?}");
        assert_eq!(
            (stats.aborts, stats.timeouts, stats.bus_errors),
            (1, 0, 1),
            "{stats:?}"
        );
        assert_eq!((stats.protocol_errors, stats.abandoned), (0, 0));
        assert_eq!(stats.latency.count(), 4);
    }

    #[tokio::test(start_paused = true)]
    async fn a_timeout_is_counted_with_its_latency_in_the_histogram() {
        let hub = VirtualHub::new("test");
        let channel = SdoChannel::new(hub.attach(), node(), config());
        assert_eq!(channel.stats(), SdoStatsSnapshot::default());
        channel.upload(0x1000, 0).await.unwrap_err();
        // A clone shares the counts (the registry hands out clones).
        let stats = channel.clone().stats();
        assert_eq!(
            (stats.transactions, stats.timeouts, stats.aborts),
            (1, 1, 0),
            "{stats:?}"
        );
        assert_eq!(stats.latency.count(), 1);
        assert_eq!(stats.latency.sum, Duration::from_millis(500));
        // 500 ms is in the 0.5 s bucket and every one above, not below.
        let bucket = |bound: Duration| {
            let at = LATENCY_BUCKETS.iter().position(|b| *b == bound).unwrap();
            stats.latency.cumulative[at]
        };
        assert_eq!(bucket(Duration::from_millis(250)), 0);
        assert_eq!(bucket(Duration::from_millis(500)), 1);
        assert_eq!(bucket(Duration::from_millis(2500)), 1);
        assert!(stats.latency.cumulative.windows(2).all(|w| w[0] <= w[1]));
    }

    #[tokio::test(start_paused = true)]
    async fn an_answer_within_a_millisecond_lands_in_the_first_buckets() {
        let hub = VirtualHub::new("test");
        let server = spawn_device(&hub, AccessType::Rw);
        let channel = SdoChannel::new(hub.attach(), node(), config());
        for _ in 0..3 {
            channel.upload(0x2000, 0).await.unwrap();
        }
        let stats = channel.stats();
        assert_eq!((stats.transactions, stats.latency.count()), (3, 3));
        // The paused clock does not move while the device answers.
        assert_eq!(stats.latency.cumulative[0], 3);
        assert_eq!(stats.latency.sum, Duration::ZERO);
        server.abort();
    }

    #[tokio::test(start_paused = true)]
    async fn a_transfer_dropped_half_way_is_aborted_and_the_next_one_runs() {
        let hub = VirtualHub::new("test");
        let observer = hub.attach();
        let mut frames = observer.subscribe();
        let channel = SdoChannel::new(hub.attach(), node(), config());
        // No device answers; the caller gives up before the SDO timeout.
        let given_up =
            tokio::time::timeout(Duration::from_millis(10), channel.upload(0x2000, 0)).await;
        assert!(given_up.is_err());
        let server = spawn_device(&hub, AccessType::Rw);
        assert_eq!(channel.upload(0x2000, 0).await, Ok(vec![0, 0, 0, 0]));
        // On the bus: the abandoned request, its abort (0x08000000), the
        // new request.
        let mut requests = Vec::new();
        while let Ok(Some(frame)) = frames.try_recv() {
            if frame.frame.id() == CanId::Standard(0x605) {
                requests.push(frame.frame.data().to_vec());
            }
        }
        assert_eq!(
            requests,
            vec![
                vec![0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0],
                vec![0x80, 0x00, 0x20, 0x00, 0, 0, 0, 0x08],
                vec![0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0],
            ]
        );
        server.abort();
        let stats = channel.stats();
        assert_eq!((stats.transactions, stats.abandoned), (2, 1), "{stats:?}");
        assert_eq!(stats.latency.count(), 1);
    }

    #[tokio::test(start_paused = true)]
    async fn callers_queue_for_the_node_one_transfer_at_a_time() {
        let hub = VirtualHub::new("test");
        let server = spawn_device(&hub, AccessType::Rw);
        let channel = SdoChannel::new(hub.attach(), node(), config());
        let tasks: Vec<_> = (0..8u32)
            .map(|i| {
                let channel = channel.clone();
                tokio::spawn(async move {
                    channel.download(0x2000, 0, &i.to_le_bytes()).await.unwrap();
                    channel.upload(0x2000, 0).await.unwrap()
                })
            })
            .collect();
        for task in tasks {
            assert_eq!(task.await.unwrap().len(), 4);
        }
        // Nobody was refused as busy (the unwraps): each waited for its turn.
        server.abort();
    }

    /// Two procedures on one node do not interleave: each one's write and
    /// read-back see its own value, though both run at once.
    #[tokio::test(start_paused = true)]
    async fn procedures_on_a_node_run_one_after_another() {
        let hub = VirtualHub::new("test");
        let server = spawn_device(&hub, AccessType::Rw);
        let channel = SdoChannel::new(hub.attach(), node(), config());
        let tasks: Vec<_> = (0..4u32)
            .map(|i| {
                let channel = channel.clone();
                tokio::spawn(async move {
                    let _procedure = channel.procedure().await;
                    channel.download(0x2000, 0, &i.to_le_bytes()).await.unwrap();
                    // Another procedure would write between these steps.
                    tokio::time::sleep(Duration::from_millis(5)).await;
                    (i, channel.upload(0x2000, 0).await.unwrap())
                })
            })
            .collect();
        for task in tasks {
            let (i, read) = task.await.unwrap();
            assert_eq!(read, i.to_le_bytes());
        }
        server.abort();
    }
}
