//! The HTTP server of `candeck serve` (issue 19, point 4): HTTP/1.1 over
//! hyper, one task per connection, with what keeps a few clients from
//! taking the gateway away from everyone else.
//!
//! - **Header timeout** (`header_timeout_ms`): from a request's first byte
//!   its head must be complete within this time, or the connection is
//!   closed (a half-sent request, "slowloris").
//! - **Idle timeout** (`idle_timeout_ms`): a connection on which nothing is
//!   in flight and nothing arrives (a fresh one, or one kept alive after an
//!   answer) is closed after this time. An answer still being written (a
//!   download) counts as activity while bytes go out. So is one whose
//!   handler waits for a request body of which nothing arrives (a stalled
//!   upload, issue 30): the request is dropped with its connection. A
//!   request without the credentials its route needs is answered 401 or
//!   403 without its body being read ([`super::auth::refused_for_credentials`]).
//! - **Connection limit** (`max_connections`): at most this many
//!   connections at once, so that the gateway never runs out of file
//!   descriptors. The last [`RESERVED_CONNECTIONS`] of them are a reserve
//!   that answers `GET /api/v1/health` and `POST /api/v1/stop-all` only
//!   (anything else: 503 `too_many_connections`), one request per
//!   connection. When the reserve is full too, a new connection takes the
//!   place of the oldest reserve connection that has not sent a request:
//!   idle clients sitting on the socket cannot keep STOP ALL out.
//!
//! A WebSocket keeps its place in the limit until it closes; the timeouts
//! end with the upgrade (the stream has its own keep-alive).
//!
//! What the limit turns away ([`ConnectionRefusals`]: answered 503, closed
//! at once, pushed out of the reserve) is counted for `/metrics`
//! (`candeck_http_connections_refused_total`) and logged as a warning at
//! most once per [`REFUSAL_LOG_EVERY`], with the counts since the last
//! line: a flood of connections must not flood the log. They are not in
//! the audit log: nothing was asked of the gateway, and a flood would
//! fill it.

use std::collections::VecDeque;
use std::convert::Infallible;
use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::Router;
use axum::extract::ConnectInfo;
use axum::http::{Method, Request};
use axum::response::{IntoResponse, Response};
use hyper::body::Incoming;
use hyper_util::rt::TokioIo;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Notify, oneshot, watch};
use tokio::time::Instant;
use tower_service::Service;

use super::AppError;

/// How long a request's head may take from its first byte, by default.
pub const DEFAULT_HEADER_TIMEOUT: Duration = Duration::from_secs(10);
/// How long a connection may sit with nothing in flight, by default.
pub const DEFAULT_IDLE_TIMEOUT: Duration = Duration::from_secs(30);
/// Connections at once, by default: with the reserve, well under the 1,024
/// file descriptors a process gets by default.
pub const DEFAULT_MAX_CONNECTIONS: usize = 512;
/// The connections of [`Limits::max_connections`] kept for `/health` and
/// `stop-all`.
pub const RESERVED_CONNECTIONS: usize = 16;

/// Refused connections are logged at most once per this interval.
pub const REFUSAL_LOG_EVERY: Duration = Duration::from_secs(60);

/// The connections the limit turned away, by how.
#[derive(Debug, Default)]
pub struct ConnectionRefusals {
    /// Reserve connections that asked for something other than `/health`
    /// or `stop-all`: answered 503 `too_many_connections`.
    pub answered_503: AtomicU64,
    /// Closed as soon as accepted: every place, the reserve's too, had a
    /// request in flight.
    pub closed: AtomicU64,
    /// Reserve connections pushed out by a newer one before they sent a
    /// request.
    pub evicted: AtomicU64,
    /// When a refusal was last logged, and the refusals since.
    log: Mutex<(Option<Instant>, u64)>,
}

impl ConnectionRefusals {
    /// Counts one refusal in `counter` and logs it if no refusal was logged
    /// for [`REFUSAL_LOG_EVERY`].
    fn note(&self, counter: &AtomicU64, peer: SocketAddr, how: &str) {
        counter.fetch_add(1, Ordering::Relaxed);
        if let Some(since) = self.log_due(Instant::now()) {
            tracing::warn!(
                "http: {peer} {how}: every connection is in use (max_connections); \
                 {since} connections refused since the last such line \
                 (503: {}, closed: {}, pushed out of the reserve: {} in all)",
                self.answered_503.load(Ordering::Relaxed),
                self.closed.load(Ordering::Relaxed),
                self.evicted.load(Ordering::Relaxed),
            );
        }
    }

    /// One more refusal at `now`: `Some(refusals since the last line)`
    /// when a line is due, the first one and then once per
    /// [`REFUSAL_LOG_EVERY`].
    pub fn log_due(&self, now: Instant) -> Option<u64> {
        let mut log = self.log.lock().unwrap_or_else(|poison| poison.into_inner());
        let (last, unlogged) = &mut *log;
        *unlogged += 1;
        if last.is_some_and(|last| now.saturating_duration_since(last) < REFUSAL_LOG_EVERY) {
            return None;
        }
        *last = Some(now);
        Some(std::mem::take(unlogged))
    }
}

/// The server's limits (config keys `header_timeout_ms`,
/// `idle_timeout_ms`, `max_connections`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    pub header_timeout: Duration,
    pub idle_timeout: Duration,
    pub max_connections: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            header_timeout: DEFAULT_HEADER_TIMEOUT,
            idle_timeout: DEFAULT_IDLE_TIMEOUT,
            max_connections: DEFAULT_MAX_CONNECTIONS,
        }
    }
}

impl Limits {
    /// The limits, checked: timeouts above 0, room for more than the
    /// reserve.
    pub fn new(
        header_timeout: Duration,
        idle_timeout: Duration,
        max_connections: usize,
    ) -> Result<Self, String> {
        if header_timeout.is_zero() || idle_timeout.is_zero() {
            return Err(
                "header_timeout_ms and idle_timeout_ms: a timeout is at least 1 ms".to_string(),
            );
        }
        if max_connections <= RESERVED_CONNECTIONS {
            return Err(format!(
                "max_connections {max_connections}: at least {} ({RESERVED_CONNECTIONS} of them are kept for /health and stop-all)",
                RESERVED_CONNECTIONS + 1
            ));
        }
        Ok(Self {
            header_timeout,
            idle_timeout,
            max_connections,
        })
    }
}

/// Serves `app` on `listener` until `shutdown` resolves; then stops
/// accepting, closes idle connections, lets the requests in flight finish
/// and returns when every connection has closed (a half-sent request within
/// the header timeout). The peer's address is in each request's
/// extensions as `ConnectInfo<SocketAddr>`.
pub async fn serve(
    listener: TcpListener,
    app: Router,
    limits: Limits,
    refusals: Arc<ConnectionRefusals>,
    shutdown: impl Future<Output = ()>,
) {
    let general = Arc::new(AtomicUsize::new(0));
    let reserve = Arc::new(Mutex::new(Reserve::default()));
    let (stop, stopping) = watch::channel(false);
    let mut tasks = tokio::task::JoinSet::new();
    tokio::pin!(shutdown);
    loop {
        let (stream, peer) = tokio::select! {
            () = &mut shutdown => break,
            accepted = listener.accept() => match accepted {
                Ok(accepted) => accepted,
                Err(err) => {
                    // Out of file descriptors and the like: wait, then go on.
                    tracing::warn!("http: accept failed: {err}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
        };
        while tasks.try_join_next().is_some() {}
        let _ = stream.set_nodelay(true);
        let class =
            if general.load(Ordering::Acquire) < limits.max_connections - RESERVED_CONNECTIONS {
                general.fetch_add(1, Ordering::AcqRel);
                Class::General(Counted(general.clone()))
            } else {
                match Reserve::enter(&reserve) {
                    Some(place) => Class::Reserve(place),
                    None => {
                        refusals.note(&refusals.closed, peer, "closed at once");
                        continue;
                    }
                }
            };
        tasks.spawn(connection(
            stream,
            peer,
            app.clone(),
            limits,
            class,
            refusals.clone(),
            stopping.clone(),
        ));
    }
    drop(listener);
    let _ = stop.send(true);
    while tasks.join_next().await.is_some() {}
}

/// What kind of place a connection has.
enum Class {
    General(Counted),
    Reserve(Place),
}

/// One general connection in the count; out of it when dropped (with the
/// socket, after a WebSocket upgrade too).
struct Counted(Arc<AtomicUsize>);

impl Drop for Counted {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// The reserve's connections, oldest first.
#[derive(Default)]
struct Reserve {
    next_id: u64,
    places: VecDeque<(u64, Arc<AtomicBool>, Option<oneshot::Sender<()>>)>,
}

/// A connection's place in the reserve: whether it sent a request, the
/// signal that it was pushed out, and its removal when it ends.
struct Place {
    id: u64,
    started: Arc<AtomicBool>,
    evicted: Option<oneshot::Receiver<()>>,
    reserve: Arc<Mutex<Reserve>>,
}

impl Reserve {
    /// A place for a new connection: a free one, else the oldest one whose
    /// connection sent no request yet (pushed out); `None` when every
    /// place has a request in flight.
    fn enter(reserve: &Arc<Mutex<Reserve>>) -> Option<Place> {
        let mut this = reserve.lock().unwrap_or_else(|poison| poison.into_inner());
        if this.places.len() >= RESERVED_CONNECTIONS {
            let idle = this
                .places
                .iter()
                .position(|(_, started, _)| !started.load(Ordering::Acquire))?;
            if let Some((_, _, Some(evict))) = this.places.remove(idle) {
                let _ = evict.send(());
            }
        }
        let id = this.next_id;
        this.next_id += 1;
        let started = Arc::new(AtomicBool::new(false));
        let (evict, evicted) = oneshot::channel();
        this.places.push_back((id, started.clone(), Some(evict)));
        Some(Place {
            id,
            started,
            evicted: Some(evicted),
            reserve: reserve.clone(),
        })
    }
}

impl Drop for Place {
    fn drop(&mut self) {
        let mut reserve = self
            .reserve
            .lock()
            .unwrap_or_else(|poison| poison.into_inner());
        reserve.places.retain(|(id, _, _)| *id != self.id);
    }
}

/// Whether a reserve connection may ask this.
fn reserved_route(method: &Method, path: &str) -> bool {
    matches!(
        (method, path),
        (&Method::GET | &Method::HEAD, "/api/v1/health") | (&Method::POST, "/api/v1/stop-all")
    )
}

/// Where a connection is between requests, for its timeouts.
#[derive(Debug, Clone, Copy)]
enum Phase {
    /// Nothing in flight, nothing read since this instant (or written:
    /// an answer's body going out).
    Waiting(Instant),
    /// A request's first bytes came at this instant; its head is not
    /// complete.
    Reading(Instant),
    /// Requests in flight (their handlers run).
    Busy(usize),
}

/// A connection's phase, shared by its socket (bytes in and out), its
/// service (requests begun and answered) and its task (the deadlines).
struct Activity {
    phase: Mutex<Phase>,
    /// While a handler waits for request body bytes that do not come: since
    /// when (the last bytes, or the wait's start).
    body_stalled: Mutex<Option<Instant>>,
    changed: Notify,
}

impl Activity {
    /// Applies `change`; the task is woken only when the phase changes
    /// kind (a later instant within one phase is seen when its deadline
    /// comes and is checked again).
    fn update(&self, change: impl FnOnce(Phase) -> Phase) {
        let mut phase = self
            .phase
            .lock()
            .unwrap_or_else(|poison| poison.into_inner());
        let before = std::mem::discriminant(&*phase);
        *phase = change(*phase);
        let changed = before != std::mem::discriminant(&*phase);
        drop(phase);
        if changed {
            self.changed.notify_one();
        }
    }

    /// A handler waits for body bytes since `since`, or (`None`) no longer.
    fn body_waiting(&self, since: Option<Instant>) {
        let mut stalled = self
            .body_stalled
            .lock()
            .unwrap_or_else(|poison| poison.into_inner());
        let began = stalled.is_none() && since.is_some();
        *stalled = since;
        drop(stalled);
        if began {
            self.changed.notify_one();
        }
    }

    /// When the connection's current wait expires: `None` while a handler
    /// works (it has its body, or needs none).
    fn deadline(&self, limits: &Limits) -> Option<Instant> {
        let phase = *self
            .phase
            .lock()
            .unwrap_or_else(|poison| poison.into_inner());
        match phase {
            Phase::Waiting(since) => Some(since + limits.idle_timeout),
            Phase::Reading(since) => Some(since + limits.header_timeout),
            Phase::Busy(_) => self
                .body_stalled
                .lock()
                .unwrap_or_else(|poison| poison.into_inner())
                .map(|since| since + limits.idle_timeout),
        }
    }

    fn read(&self) {
        self.update(|phase| match phase {
            Phase::Waiting(_) => Phase::Reading(Instant::now()),
            other => other,
        });
    }

    fn wrote(&self) {
        self.update(|phase| match phase {
            Phase::Waiting(_) => Phase::Waiting(Instant::now()),
            other => other,
        });
    }

    fn begin(&self) {
        self.update(|phase| match phase {
            Phase::Busy(n) => Phase::Busy(n + 1),
            _ => Phase::Busy(1),
        });
    }

    fn end(&self) {
        self.update(|phase| match phase {
            Phase::Busy(n) if n > 1 => Phase::Busy(n - 1),
            _ => Phase::Waiting(Instant::now()),
        });
    }
}

/// The socket, telling the connection's [`Activity`] of bytes in and out,
/// and holding the connection's place in the limit.
struct Watched {
    stream: TcpStream,
    activity: Arc<Activity>,
    _counted: Option<Counted>,
}

impl AsyncRead for Watched {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let polled = Pin::new(&mut self.stream).poll_read(cx, buf);
        if buf.filled().len() > before {
            self.activity.read();
        }
        polled
    }
}

impl AsyncWrite for Watched {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let polled = Pin::new(&mut self.stream).poll_write(cx, buf);
        if matches!(polled, Poll::Ready(Ok(n)) if n > 0) {
            self.activity.wrote();
        }
        polled
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        let polled = Pin::new(&mut self.stream).poll_write_vectored(cx, bufs);
        if matches!(polled, Poll::Ready(Ok(n)) if n > 0) {
            self.activity.wrote();
        }
        polled
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

/// A request's body, telling the connection's [`Activity`] while its
/// handler waits for bytes that have not come.
struct WatchedBody {
    inner: Incoming,
    activity: Arc<Activity>,
    waiting: bool,
}

impl WatchedBody {
    fn waiting(&mut self, waiting: bool) {
        if self.waiting != waiting {
            self.waiting = waiting;
            self.activity.body_waiting(waiting.then(Instant::now));
        }
    }
}

impl hyper::body::Body for WatchedBody {
    type Data = axum::body::Bytes;
    type Error = hyper::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<hyper::body::Frame<Self::Data>, Self::Error>>> {
        let polled = Pin::new(&mut self.inner).poll_frame(cx);
        // Each frame restarts the wait: the timeout is for a body of which
        // nothing arrives, not for a slow upload.
        self.waiting(polled.is_pending());
        polled
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> hyper::body::SizeHint {
        self.inner.size_hint()
    }
}

impl Drop for WatchedBody {
    fn drop(&mut self) {
        self.waiting(false);
    }
}

/// One connection, until it closes, times out, is pushed out of the
/// reserve, or the server stops.
async fn connection(
    stream: TcpStream,
    peer: SocketAddr,
    app: Router,
    limits: Limits,
    class: Class,
    refusals: Arc<ConnectionRefusals>,
    mut stopping: watch::Receiver<bool>,
) {
    let activity = Arc::new(Activity {
        phase: Mutex::new(Phase::Waiting(Instant::now())),
        body_stalled: Mutex::new(None),
        changed: Notify::new(),
    });
    let (counted, place) = match class {
        Class::General(counted) => (Some(counted), None),
        Class::Reserve(place) => (None, Some(place)),
    };
    let mut place = place;
    let reserve = place.is_some();
    let started = place.as_ref().map(|place| place.started.clone());
    let mut evicted = place.as_mut().and_then(|place| place.evicted.take());
    let io = Watched {
        stream,
        activity: activity.clone(),
        _counted: counted,
    };
    let service_activity = activity.clone();
    let service_refusals = refusals.clone();
    let service = hyper::service::service_fn(move |request: Request<Incoming>| {
        let mut app = app.clone();
        let activity = service_activity.clone();
        let mut request = request.map(|inner| WatchedBody {
            inner,
            activity: activity.clone(),
            waiting: false,
        });
        let refusals = service_refusals.clone();
        if let Some(started) = &started {
            started.store(true, Ordering::Release);
        }
        activity.begin();
        async move {
            request.extensions_mut().insert(ConnectInfo(peer));
            let response = if reserve && !reserved_route(request.method(), request.uri().path()) {
                refusals.note(&refusals.answered_503, peer, "answered 503");
                AppError::TooManyConnections(
                    "every connection of the gateway is in use; this one answers GET /api/v1/health and POST /api/v1/stop-all only (max_connections)"
                        .to_string(),
                )
                .into_response()
            } else {
                match app.call(request).await {
                    Ok(response) => response,
                    Err(never) => match never {},
                }
            };
            activity.end();
            Ok::<Response, Infallible>(response)
        }
    });
    let mut builder = hyper::server::conn::http1::Builder::new();
    // A reserve place is for one request.
    builder.keep_alive(!reserve);
    let conn = builder
        .serve_connection(TokioIo::new(io), service)
        .with_upgrades();
    tokio::pin!(conn);
    let mut closing = false;
    loop {
        let deadline = activity.deadline(&limits);
        let timeout = async {
            match deadline {
                Some(deadline) => tokio::time::sleep_until(deadline).await,
                None => std::future::pending().await,
            }
        };
        let evict = async {
            match &mut evicted {
                Some(evicted) => {
                    let _ = evicted.await;
                }
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            result = conn.as_mut() => {
                if let Err(err) = result {
                    tracing::debug!("http: {peer}: {err}");
                }
                return;
            }
            () = activity.changed.notified() => {}
            () = timeout => {
                // Checked again: bytes may have come meanwhile.
                let now = *activity.phase.lock().unwrap_or_else(|poison| poison.into_inner());
                let expired = activity
                    .deadline(&limits)
                    .is_some_and(|deadline| deadline <= Instant::now());
                if expired {
                    tracing::debug!("http: {peer}: closed, {}", match now {
                        Phase::Reading(_) => "no complete request head within header_timeout_ms",
                        Phase::Busy(_) => "no request body bytes for idle_timeout_ms",
                        Phase::Waiting(_) => "idle for idle_timeout_ms",
                    });
                    return;
                }
            }
            () = evict => {
                refusals.note(&refusals.evicted, peer, "pushed out of the reserve by a newer connection");
                return;
            }
            changed = stopping.changed(), if !closing => {
                if changed.is_err() || *stopping.borrow() {
                    let idle = matches!(
                        *activity.phase.lock().unwrap_or_else(|poison| poison.into_inner()),
                        Phase::Waiting(_)
                    );
                    if idle {
                        return;
                    }
                    closing = true;
                    conn.as_mut().graceful_shutdown();
                }
            }
        }
    }
}

#[cfg(test)]
mod tests;
