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
pub(crate) struct SdoStats {
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
    pub(crate) fn snapshot(&self) -> SdoStatsSnapshot {
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

/// `SdoStats` at one moment.
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

/// Told of every value a channel wrote, once the device confirmed it:
/// the node, the index, the sub-index and the value bytes. Whoever
/// follows what the gateway writes (the registry, for a node's producer
/// heartbeat time) hears every path alike: REST, CiA 309, Sparkplug, the
/// network manager.
pub(crate) type WriteObserver = Arc<dyn Fn(NodeId, u16, u8, &[u8]) + Send + Sync>;

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
    written: Option<WriteObserver>,
}

impl SdoChannel {
    pub fn new(bus: Bus, node: NodeId, config: ClientConfig) -> Self {
        let client = SdoClient::new(node, config.clone());
        // Its node's answers only: a channel hears nothing else of the bus.
        let responses = bus.subscribe_id(client.response_id());
        Self {
            session: Arc::new(Mutex::new(Session { client, responses })),
            procedure: Arc::new(Mutex::new(())),
            stats: Arc::new(SdoStats::default()),
            written: None,
            bus,
            node,
            config,
        }
    }

    /// This channel with `observer` told of every download that succeeds.
    pub fn with_observer(mut self, observer: WriteObserver) -> Self {
        self.written = Some(observer);
        self
    }

    fn wrote(&self, index: u16, sub: u8, data: &[u8]) {
        if let Some(observer) = &self.written {
            observer(self.node, index, sub, data);
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
            .transfer(Request::Upload { index, sub }, config, None)
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
        self.transfer(Request::Download { index, sub, data }, config, None)
            .await?;
        self.wrote(index, sub, data);
        Ok(())
    }

    /// [`SdoChannel::download_with`] that calls `progress(confirmed,
    /// total)` each time the device has confirmed more of the value (at
    /// each block acknowledgement of a block download; see
    /// [`SdoClient::download_progress`]), for a long download's progress
    /// report.
    pub async fn download_reporting(
        &self,
        index: u16,
        sub: u8,
        data: &[u8],
        config: Option<&ClientConfig>,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<(), SdoRequestError> {
        self.transfer(
            Request::Download { index, sub, data },
            config,
            Some(progress),
        )
        .await?;
        self.wrote(index, sub, data);
        Ok(())
    }

    async fn transfer(
        &self,
        request: Request<'_>,
        config: Option<&ClientConfig>,
        progress: Option<&(dyn Fn(usize, usize) + Sync)>,
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
        let result = self
            .exchange(&mut session, request, started, progress)
            .await;
        pending.finish(Outcome::of(&result), started.elapsed());
        result
    }

    /// One transfer, the node's queue held.
    async fn exchange(
        &self,
        session: &mut Session,
        request: Request<'_>,
        started: tokio::time::Instant,
        progress: Option<&(dyn Fn(usize, usize) + Sync)>,
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
        // What `progress` was last told: every frame on the bus comes
        // through here, few of them move the download on.
        let mut reported = None;
        loop {
            if let Some(progress) = progress {
                let now = client.download_progress();
                if now.is_some() && now != reported {
                    reported = now;
                    if let Some((confirmed, total)) = now {
                        progress(confirmed, total);
                    }
                }
            }
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
            // The frames of the bus that are not this node's answers are
            // skipped here, one timer for the whole wait: a busy bus (127
            // drives' TPDOs on every SYNC) no longer costs every transfer
            // in flight a pass through the select and a new timer per frame.
            let answer = async {
                loop {
                    match responses.recv().await {
                        Ok(frame) if !client.is_response(&frame.frame) => {}
                        other => return other,
                    }
                }
            };
            step = tokio::select! {
                received = answer => match received {
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
mod tests;
