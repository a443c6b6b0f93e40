//! `GET /api/v1/stream`: live telemetry over WebSocket (`docs/websocket.md`).
//!
//! Client → server, one JSON text message each:
//! `{"op":"subscribe","topics":[...],"max_rate_hz"?:n}` and
//! `{"op":"unsubscribe","topics":[...]}`, and `{"op":"renew","leases":[id]}`
//! for motion leases ([`super::leases`]: answered with
//! `{"op":"renewed","leases":[{"id","expires_in_ms"}]}`, an unknown one with
//! an error naming it in `lease`; a lease renewed here lapses as soon as
//! the session ends; only the lease's holder renews it — another token is
//! answered `lease_conflict`, a viewer `forbidden`; renewals are audited,
//! the first of each lease then one a minute, refusals one a minute per
//! session with the count of those left out). Server → client:
//! `{"topic","ts","data"}` for an update, `{"topic","lagged":N}` when the
//! client fell behind and lost N events (or frames) of a topic, and, for the
//! requests themselves, `{"op":"subscribed","topics":[...],"max_rate_hz"}`,
//! `{"op":"unsubscribed","topics":[...]}` and
//! `{"op":"error","topic"?,"error":{"code","message"}}` with the codes of the
//! REST API (`unknown_bus`, `unknown_node`, `not_a_drive`, ...) and
//! `invalid_request`. A subscribe with some bad topics subscribes the good
//! ones and names each bad one. `max_rate_hz` is a number from
//! [`MIN_RATE_HZ`] (0.01: one update every 100 s) to [`MAX_RATE_HZ`]
//! (1000); any other (0, negative, 1e-300, 1e9) is answered
//! `value_out_of_range` and subscribes nothing, and the session goes on.
//!
//! Topics: `nodes` (appeared, identified, NMT state changed, offline,
//! online), `emcy`, `buses/{bus}/frames[?ids=0x181,0x701]` (frames in
//! batches, at most [`MAX_PUBLISH_HZ`] a second: `data` is a list),
//! `buses/{bus}/nodes/{id}/values`,
//! `buses/{bus}/nodes/{id}/axes/{axis}`, `buses/{bus}/nodes/{id}/segments`,
//! `buses/{bus}/nodes/{id}/program` (the progress of a program download)
//! and `loggers/{id}` (a data logger's new rows, ten times a second).
//!
//! How a slow client is kept from hurting anyone: nothing the gateway does
//! waits for a client. Each session has a mailbox that producers'
//! forwarding tasks fill and the session drains into the socket:
//! - values are state: one pending sample per topic, a newer one replaces
//!   it (counted as coalesced), and each topic is forwarded at most
//!   `max_rate_hz` times per second;
//! - events and frames queue up to a bound ([`EVENT_QUEUE`],
//!   [`FRAME_QUEUE`]); past it the oldest go, and the client is told how
//!   many with `lagged` before the next message of that topic.
//!
//! So a client's memory is bounded by its topics, and a client that stops
//! reading only stalls its own session, which is closed when one message
//! cannot be written in [`SEND_TIMEOUT`]. The session is generic over its
//! message stream and sink ([`run_session`]), so it is tested with channels.
//!
//! How many clients are kept from hurting the rest (issue 30): a bus's
//! frames are batched and rendered once for all its sessions
//! (`frame_feed`), a frames topic sends at most [`MAX_PUBLISH_HZ`]
//! batches a second, a session renders and writes only in its turn
//! ([`crate::gateway::StreamTurns`]: one session at a time, every other
//! task runs in between), and its client's socket is read only when it has
//! something (`WokenStream`).

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::fmt::Write as _;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{Context, Poll, Waker};
use std::time::Duration;

use axum::Extension;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{ConnectInfo, State};
use axum::response::Response;
use futures_util::{Sink, SinkExt, Stream, StreamExt};
use serde::Deserialize;
use serde_json::{Value as Json, json};
use tokio::sync::Notify;
use tokio::task::JoinHandle;
use tokio::time::Instant;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::auth::Identity;
use super::doc::ErrorBody;
use super::nodes::known_node;
use super::{AppError, AppState};
use crate::gateway::NodeEvent;
use crate::gateway::{self, MAX_PUBLISH_HZ, StreamTurn, period_at_most};
use crate::gateway::{Caller, Channel};
use crate::gateway::{GatewayError, ServedBus};
use crate::gateway::{Sample, StreamCounters, TopicReceiver, unix_ms};

mod frame_feed;

pub use frame_feed::FrameFeeds;
#[cfg(test)]
use frame_feed::RenderedFrame;
use frame_feed::{FeedError, FeedReceiver, FrameBatch};

/// Updates per second of a value topic when the client asks no rate.
pub const DEFAULT_RATE_HZ: f64 = 10.0;
/// The fastest rate a client may ask for.
pub const MAX_RATE_HZ: f64 = gateway::MAX_RATE_HZ;
/// The slowest rate a client may ask for: one update every 100 s.
pub const MIN_RATE_HZ: f64 = gateway::MIN_RATE_HZ;
/// Topics one client may hold.
pub const MAX_TOPICS: usize = 256;
/// Events (`nodes`, `emcy`) queued for one client before the oldest go.
pub const EVENT_QUEUE: usize = 1024;
/// Frames queued per frames topic of one client before the oldest go.
pub const FRAME_QUEUE: usize = 4096;
/// A client that takes longer than this to accept one message is closed.
pub const SEND_TIMEOUT: Duration = Duration::from_secs(10);
/// The largest message a client may send.
pub const MAX_CLIENT_MESSAGE: usize = 64 * 1024;
/// Frames queued for one client across all its frames topics before the
/// oldest go (issue 30, finding 7: 20 clients that did not read took
/// 750 MB with [`FRAME_QUEUE`] per topic and 256 topics each).
pub const CLIENT_FRAME_QUEUE: usize = 8192;
/// WebSocket streams one token may hold at once, by default.
pub const DEFAULT_MAX_STREAMS_PER_TOKEN: usize = 32;
/// WebSocket streams one peer address may hold at once, by default.
pub const DEFAULT_MAX_STREAMS_PER_PEER: usize = 64;

/// How many WebSocket streams one token and one peer address may hold at
/// once (config keys `stream_max_per_token`, `stream_max_per_peer`): one
/// more is answered 429 `too_many_streams` before the upgrade.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamLimits {
    pub per_token: usize,
    pub per_peer: usize,
}

impl Default for StreamLimits {
    fn default() -> Self {
        Self {
            per_token: DEFAULT_MAX_STREAMS_PER_TOKEN,
            per_peer: DEFAULT_MAX_STREAMS_PER_PEER,
        }
    }
}

impl StreamLimits {
    /// The limits, checked: at least one stream each.
    pub fn new(per_token: usize, per_peer: usize) -> Result<Self, String> {
        if per_token == 0 || per_peer == 0 {
            return Err("stream_max_per_token, stream_max_per_peer: at least 1".to_string());
        }
        Ok(Self {
            per_token,
            per_peer,
        })
    }
}

/// The streams open now, by token name and by peer address.
#[derive(Debug, Default)]
pub struct OpenStreams {
    limits: StreamLimits,
    open: Mutex<(BTreeMap<String, usize>, BTreeMap<std::net::IpAddr, usize>)>,
}

/// One stream's place in [`OpenStreams`]; given back when dropped (the
/// session's end).
#[derive(Debug)]
pub struct StreamPlace {
    streams: Arc<OpenStreams>,
    token: Option<String>,
    peer: Option<std::net::IpAddr>,
}

impl OpenStreams {
    pub fn new(limits: StreamLimits) -> Self {
        Self {
            limits,
            open: Mutex::default(),
        }
    }

    /// A place for one more stream of `token` (a valid token's name; none
    /// on a gateway without tokens) from `peer`, or why not.
    pub fn admit(
        self: &Arc<Self>,
        token: Option<&str>,
        peer: Option<std::net::IpAddr>,
    ) -> Result<StreamPlace, String> {
        let mut open = self.open.lock().unwrap_or_else(|p| p.into_inner());
        let (by_token, by_peer) = &mut *open;
        if let Some(token) = token
            && by_token.get(token).copied().unwrap_or(0) >= self.limits.per_token
        {
            return Err(format!(
                "token {token} holds {} streams already, as many as one token may (stream_max_per_token): close one first",
                self.limits.per_token
            ));
        }
        if let Some(peer) = peer
            && by_peer.get(&peer).copied().unwrap_or(0) >= self.limits.per_peer
        {
            return Err(format!(
                "{peer} holds {} streams already, as many as one address may (stream_max_per_peer): close one first",
                self.limits.per_peer
            ));
        }
        if let Some(token) = token {
            *by_token.entry(token.to_string()).or_default() += 1;
        }
        if let Some(peer) = peer {
            *by_peer.entry(peer).or_default() += 1;
        }
        Ok(StreamPlace {
            streams: self.clone(),
            token: token.map(str::to_string),
            peer,
        })
    }
}

impl Drop for StreamPlace {
    fn drop(&mut self) {
        let mut open = self.streams.open.lock().unwrap_or_else(|p| p.into_inner());
        let (by_token, by_peer) = &mut *open;
        if let Some(token) = &self.token
            && let Some(n) = by_token.get_mut(token)
        {
            *n -= 1;
            if *n == 0 {
                by_token.remove(token);
            }
        }
        if let Some(peer) = &self.peer
            && let Some(n) = by_peer.get_mut(peer)
        {
            *n -= 1;
            if *n == 0 {
                by_peer.remove(peer);
            }
        }
    }
}

pub fn router() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(stream))
}

/// The live telemetry stream (WebSocket).
///
/// Upgrade to a WebSocket, then send
/// `{"op":"subscribe","topics":["nodes","emcy","buses/demo/nodes/1/axes/1"],"max_rate_hz":20}`.
/// Updates come as `{"topic","ts","data"}` (`ts` in ms since the Unix
/// epoch); values are coalesced to the newest at `max_rate_hz` (default
/// 10, from 0.01 to 1000; another rate is answered
/// `{"op":"error","error":{"code":"value_out_of_range",...}}` and the
/// session goes on); a client that falls behind on events or frames gets
/// `{"topic","lagged":N}`. See `docs/websocket.md` for every topic
/// and message.
#[utoipa::path(get, path = "/stream", tag = "stream",
    responses(
        (status = 101, description = "Switching to the WebSocket protocol"),
        (status = 429, description = "`too_many_streams`: the token or the address holds as many streams as it may (stream_max_per_token, stream_max_per_peer)", body = ErrorBody),
        (status = 426, description = "`upgrade_required`: a plain HTTP request; this endpoint speaks WebSocket only", body = ErrorBody),
    ))]
async fn stream(
    State(state): State<AppState>,
    identity: Option<Extension<Identity>>,
    peer: Option<Extension<ConnectInfo<SocketAddr>>>,
    upgrade: Result<WebSocketUpgrade, axum::extract::ws::rejection::WebSocketUpgradeRejection>,
) -> Result<Response, AppError> {
    let peer_address = peer.map(|Extension(ConnectInfo(addr))| addr);
    let client = Client {
        identity: identity.map_or_else(Identity::anonymous, |Extension(id)| id),
        peer: peer_address.map(|addr| addr.to_string()),
    };
    let upgrade = upgrade.map_err(|rejection| AppError::UpgradeRequired(rejection.body_text()))?;
    // Per token and per peer, before the upgrade (issue 30, finding 7).
    let token = client
        .identity
        .role
        .is_some()
        .then_some(client.identity.name.as_str());
    let peer_ip = peer_address.map(|addr| addr.ip());
    let place = state
        .open_streams
        .admit(token, peer_ip)
        .map_err(AppError::TooManyStreams)?;
    // A browser sends its token as a second subprotocol (`bearer.TOKEN`,
    // checked by the access layer); the answer names ours only.
    Ok(upgrade
        .protocols([super::auth::STREAM_PROTOCOL])
        .max_message_size(MAX_CLIENT_MESSAGE)
        .on_upgrade(move |socket| async move {
            serve_socket(state, client, socket).await;
            drop(place);
        }))
}

/// Who a session serves, as the access layer found it: leases are renewed
/// for this identity, and its renewals are audited under its name.
#[derive(Debug, Clone)]
pub struct Client {
    pub identity: Identity,
    pub peer: Option<String>,
}

impl Client {
    /// A client without a token (a gateway without tokens), address unknown.
    pub fn anonymous() -> Self {
        Self {
            identity: Identity::anonymous(),
            peer: None,
        }
    }
}

/// What a client sent, as the session sees it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Inbound {
    Text(String),
    /// A binary message (the protocol has none): answered with an error.
    Binary,
}

async fn serve_socket(state: AppState, client: Client, socket: WebSocket) {
    let (sink, stream) = socket.split();
    let sink = sink.with(|text: String| async move { Ok::<_, axum::Error>(Message::text(text)) });
    // Pings are answered by the WebSocket layer itself; a close or an error
    // ends the stream, and with it the session.
    let inbound = stream
        .take_while(|message| {
            std::future::ready(matches!(message, Ok(m) if !matches!(m, Message::Close(_))))
        })
        .filter_map(|message| async move {
            match message {
                Ok(Message::Text(text)) => Some(Inbound::Text(text.as_str().to_string())),
                Ok(Message::Binary(_)) => Some(Inbound::Binary),
                _ => None,
            }
        });
    let mut sink = Box::pin(sink);
    run_session_as(state, client, Box::pin(inbound), &mut sink).await;
    // The close handshake: the WebSocket layer queued its answer to the
    // client's Close frame (or ours, when the session ended first); closing
    // the sink sends it, so the client sees a clean 1000 rather than a
    // dropped connection.
    let _ = tokio::time::timeout(SEND_TIMEOUT, sink.close()).await;
}

/// [`run_session_as`] for a client without a token.
pub async fn run_session<I, O>(state: AppState, inbound: I, outbound: O)
where
    I: Stream<Item = Inbound> + Unpin,
    O: Sink<String> + Unpin,
{
    run_session_as(state, Client::anonymous(), inbound, outbound).await;
}

/// One client's session: reads its requests from `inbound` and writes the
/// stream to `outbound` until either ends (or a write times out).
pub async fn run_session_as<I, O>(state: AppState, client: Client, inbound: I, mut outbound: O)
where
    I: Stream<Item = Inbound> + Unpin,
    O: Sink<String> + Unpin,
{
    let counters = state.stream_counters.clone();
    let _client = ClientGuard::new(counters.clone());
    let lease_session = state.gateway.lease_session();
    let mut caller = Caller::new(
        Channel::Websocket,
        client.identity.name.clone(),
        client.identity.role,
    );
    caller.peer = client.peer;
    let mut session = Session {
        lease_session,
        caller,
        state,
        mailbox: Arc::new(Mailbox::default()),
        topics: BTreeMap::new(),
        default_rate_hz: DEFAULT_RATE_HZ,
        delivered: BTreeMap::new(),
        counters,
    };
    let mut inbound = WokenStream::new(inbound);
    let turns = session.state.gateway.stream_turns().clone();
    loop {
        let (replies, turn) = tokio::select! {
            biased;
            request = inbound.next() => match request {
                Some(request) => (session.handle(request), None),
                None => break,
            },
            () = session.mailbox.ready() => {
                // Rendered in the session's turn: the bus reader, SDO and
                // others' requests run between two sessions' turns.
                let turn = turns.take().await;
                (session.drain(), Some(turn))
            }
        };
        if !send_replies(&mut outbound, replies, turn, &session.counters).await {
            return;
        }
    }
}

/// Writes `replies` in order; false when the client is gone, or accepted
/// one of them in no less than [`SEND_TIMEOUT`]. The turn is kept while the
/// client takes each message at once, and given back as soon as a write
/// has to wait for it: a slow client holds up no other session.
async fn send_replies<O>(
    outbound: &mut O,
    replies: Vec<String>,
    mut turn: Option<StreamTurn>,
    counters: &StreamCounters,
) -> bool
where
    O: Sink<String> + Unpin,
{
    for reply in replies {
        let mut send = outbound.send(reply);
        let at_once = std::future::poll_fn(|cx| Poll::Ready(Pin::new(&mut send).poll(cx))).await;
        let sent = match at_once {
            Poll::Ready(result) => Ok(result),
            Poll::Pending => {
                turn = None;
                tokio::time::timeout(SEND_TIMEOUT, send).await
            }
        };
        match sent {
            Ok(Ok(())) => StreamCounters::add(&counters.messages, 1),
            Ok(Err(_)) => return false,
            Err(_) => {
                tracing::info!("stream client closed: it accepted no message in {SEND_TIMEOUT:?}");
                return false;
            }
        }
    }
    drop(turn);
    true
}

/// A client's messages, read from its socket only when the socket has
/// woken the session for them (and once at the start). A session's loop
/// asks for the next message each time round, and the WebSocket layer
/// prepares a read buffer of 128 KiB (zeroed) at each ask, data or none:
/// with a session waking for every batch of frames that was a fifth of the
/// gateway's time under 32 streams (issue 30, perf).
struct WokenStream<S> {
    inner: S,
    wake: Arc<WakeFlag>,
}

#[derive(Default)]
struct WakeFlag {
    woken: AtomicBool,
    waker: futures_util::task::AtomicWaker,
}

impl std::task::Wake for WakeFlag {
    fn wake(self: Arc<Self>) {
        self.wake_by_ref();
    }

    fn wake_by_ref(self: &Arc<Self>) {
        self.woken.store(true, Ordering::Release);
        self.waker.wake();
    }
}

impl<S> WokenStream<S> {
    fn new(inner: S) -> Self {
        Self {
            inner,
            wake: Arc::new(WakeFlag {
                woken: AtomicBool::new(true),
                waker: futures_util::task::AtomicWaker::new(),
            }),
        }
    }
}

impl<S: Stream + Unpin> Stream for WokenStream<S> {
    type Item = S::Item;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<S::Item>> {
        let this = &mut *self;
        this.wake.waker.register(cx.waker());
        if !this.wake.woken.swap(false, Ordering::AcqRel) {
            return Poll::Pending;
        }
        let waker = Waker::from(this.wake.clone());
        let polled = Pin::new(&mut this.inner).poll_next(&mut Context::from_waker(&waker));
        if polled.is_ready() {
            // There may be more already read: ask again next time.
            this.wake.woken.store(true, Ordering::Release);
        }
        polled
    }
}

/// Counts the client while its session runs.
struct ClientGuard(Arc<StreamCounters>);

impl ClientGuard {
    fn new(counters: Arc<StreamCounters>) -> Self {
        counters.clients.fetch_add(1, Ordering::Relaxed);
        Self(counters)
    }
}

impl Drop for ClientGuard {
    fn drop(&mut self) {
        self.0.clients.fetch_sub(1, Ordering::Relaxed);
    }
}

/// A request of the client.
#[derive(Debug, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case", deny_unknown_fields)]
enum Request {
    Renew {
        leases: Vec<String>,
    },
    Subscribe {
        topics: Vec<String>,
        max_rate_hz: Option<f64>,
    },
    Unsubscribe {
        topics: Vec<String>,
    },
}

/// A topic, parsed.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Topic {
    Nodes,
    Emcy,
    Machine,
    /// The alarms (issue 31): what is open, then every change.
    Alarms,
    Frames {
        bus: String,
        /// Only these identifiers (raw, without the extended flag); all
        /// without.
        ids: Option<BTreeSet<u32>>,
    },
    Values {
        bus: String,
        node: String,
    },
    Axis {
        bus: String,
        node: String,
        axis: String,
    },
    Segments {
        bus: String,
        node: String,
    },
    Logger {
        id: String,
    },
    Program {
        bus: String,
        node: String,
    },
}

impl Topic {
    fn parse(text: &str) -> Result<Self, AppError> {
        let (path, query) = match text.split_once('?') {
            Some((path, query)) => (path, Some(query)),
            None => (text, None),
        };
        let parts: Vec<&str> = path.split('/').collect();
        let topic = match parts.as_slice() {
            ["nodes"] => Self::Nodes,
            ["emcy"] => Self::Emcy,
            ["machine"] => Self::Machine,
            ["alarms"] => Self::Alarms,
            ["buses", bus, "frames"] => Self::Frames {
                bus: bus.to_string(),
                ids: query.map(parse_ids).transpose()?,
            },
            ["buses", bus, "nodes", node, "values"] => Self::Values {
                bus: bus.to_string(),
                node: node.to_string(),
            },
            ["buses", bus, "nodes", node, "axes", axis] => Self::Axis {
                bus: bus.to_string(),
                node: node.to_string(),
                axis: axis.to_string(),
            },
            ["buses", bus, "nodes", node, "segments"] => Self::Segments {
                bus: bus.to_string(),
                node: node.to_string(),
            },
            ["buses", bus, "nodes", node, "program"] => Self::Program {
                bus: bus.to_string(),
                node: node.to_string(),
            },
            ["loggers", id] => Self::Logger { id: id.to_string() },
            _ => {
                return Err(AppError::InvalidRequest(format!(
                    "'{text}' is no topic: nodes, emcy, machine, alarms, buses/{{bus}}/frames, \
                     buses/{{bus}}/nodes/{{id}}/values, .../axes/{{axis}}, .../segments, .../program or loggers/{{id}}"
                )));
            }
        };
        if query.is_some() && !matches!(topic, Self::Frames { .. }) {
            return Err(AppError::InvalidRequest(format!(
                "topic '{text}' takes no query (only frames take ?ids=...)"
            )));
        }
        Ok(topic)
    }
}

/// `ids=0x181,0x701` (hex with `0x`, or decimal).
fn parse_ids(query: &str) -> Result<BTreeSet<u32>, AppError> {
    let list = query.strip_prefix("ids=").ok_or_else(|| {
        AppError::InvalidRequest(format!(
            "frames topic query '{query}': only ids=ID,ID,... is known"
        ))
    })?;
    list.split(',')
        .map(|id| {
            let id = id.trim();
            let parsed = match id.strip_prefix("0x").or_else(|| id.strip_prefix("0X")) {
                Some(hex) => u32::from_str_radix(hex, 16),
                None => id.parse(),
            };
            match parsed {
                Ok(raw) if raw <= 0x1FFF_FFFF => Ok(raw),
                _ => Err(AppError::InvalidRequest(format!(
                    "frames topic: '{id}' is no CAN identifier (0x000 to 0x1FFFFFFF)"
                ))),
            }
        })
        .collect()
}

/// What a session holds for one topic.
struct Subscription {
    /// The tasks that feed the mailbox; aborted when the topic is dropped.
    tasks: Vec<JoinHandle<()>>,
}

impl Drop for Subscription {
    fn drop(&mut self) {
        for task in &self.tasks {
            task.abort();
        }
    }
}

struct Session {
    state: AppState,
    /// Who the session serves, as the gateway's operations take it.
    caller: Caller,
    /// The leases the client renews lapse when it ends (the client is
    /// gone, or its network).
    lease_session: crate::gateway::LeaseSession,
    mailbox: Arc<Mailbox>,
    /// By the topic string as the client wrote it (the messages carry it
    /// back the same way).
    topics: BTreeMap<String, Subscription>,
    default_rate_hz: f64,
    /// The last sample sent per value topic, to count what was coalesced.
    delivered: BTreeMap<String, u64>,
    counters: Arc<StreamCounters>,
}

impl Session {
    fn handle(&mut self, inbound: Inbound) -> Vec<String> {
        let text = match inbound {
            Inbound::Text(text) => text,
            Inbound::Binary => {
                return vec![error_message(
                    None,
                    &AppError::InvalidRequest(
                        "binary messages are not part of the protocol: send JSON text".into(),
                    ),
                )];
            }
        };
        let request: Request = match serde_json::from_str(&text) {
            Ok(request) => request,
            Err(err) => {
                return vec![error_message(
                    None,
                    &AppError::InvalidRequest(format!(
                        "not a request ({err}): send {{\"op\":\"subscribe\",\"topics\":[...]}} \
                         or {{\"op\":\"unsubscribe\",\"topics\":[...]}} \
                         or {{\"op\":\"renew\",\"leases\":[...]}}"
                    )),
                )];
            }
        };
        match request {
            Request::Subscribe {
                topics,
                max_rate_hz,
            } => self.subscribe(topics, max_rate_hz),
            Request::Unsubscribe { topics } => self.unsubscribe(topics),
            Request::Renew { leases } => self.renew(leases),
        }
    }

    /// Renewals are the gateway's ([`crate::gateway::Gateway::renew_in_session`]:
    /// the role, the holder, the audit rows); the stream answers them.
    fn renew(&mut self, ids: Vec<String>) -> Vec<String> {
        let mut renewed = Vec::new();
        let mut replies = Vec::new();
        for id in ids {
            let renewal =
                self.state
                    .gateway
                    .renew_in_session(&self.caller, &mut self.lease_session, &id);
            match renewal {
                Ok(lease) => {
                    let left = lease.remaining(tokio::time::Instant::now()).as_millis();
                    renewed.push(json!({"id": id, "expires_in_ms": left as u64}));
                }
                Err(error) => {
                    let error = AppError::from(error);
                    let mut message = json!({"op": "error", "error": error.to_json()});
                    message["lease"] = Json::from(id);
                    replies.push(message.to_string());
                }
            }
        }
        replies.insert(0, json!({"op": "renewed", "leases": renewed}).to_string());
        replies
    }

    fn subscribe(&mut self, topics: Vec<String>, max_rate_hz: Option<f64>) -> Vec<String> {
        let rate_hz = match max_rate_hz {
            None => self.default_rate_hz,
            // Every number the stream takes is checked here, at its edge:
            // a rate of 1e-300 Hz is a period no clock can wait.
            Some(rate) if (MIN_RATE_HZ..=MAX_RATE_HZ).contains(&rate) => rate,
            Some(rate) => {
                return vec![error_message(
                    None,
                    &GatewayError::ValueOutOfRange(format!(
                        "max_rate_hz {rate} is out of range: from {MIN_RATE_HZ} \
                         (one update every 100 s) to {MAX_RATE_HZ} updates per second"
                    ))
                    .into(),
                )];
            }
        };
        self.default_rate_hz = rate_hz;
        let mut replies = Vec::new();
        let mut subscribed = Vec::new();
        for text in topics {
            if !self.topics.contains_key(&text) && self.topics.len() >= MAX_TOPICS {
                replies.push(error_message(
                    Some(&text),
                    &AppError::InvalidRequest(format!(
                        "a client may hold at most {MAX_TOPICS} topics"
                    )),
                ));
                continue;
            }
            match self.open(&text, rate_hz) {
                Ok(subscription) => {
                    // Subscribing again replaces the old one (a new rate).
                    self.forget(&text);
                    self.topics.insert(text.clone(), subscription);
                    subscribed.push(text);
                }
                Err(err) => replies.push(error_message(Some(&text), &err)),
            }
        }
        if !subscribed.is_empty() {
            replies.insert(
                0,
                json!({"op": "subscribed", "topics": subscribed, "max_rate_hz": rate_hz})
                    .to_string(),
            );
        }
        replies
    }

    fn unsubscribe(&mut self, topics: Vec<String>) -> Vec<String> {
        let mut done = Vec::new();
        let mut replies = Vec::new();
        for text in topics {
            if self.topics.contains_key(&text) {
                self.forget(&text);
                done.push(text);
            } else {
                replies.push(error_message(
                    Some(&text),
                    &AppError::InvalidRequest(format!("not subscribed to '{text}'")),
                ));
            }
        }
        replies.insert(0, json!({"op": "unsubscribed", "topics": done}).to_string());
        replies
    }

    /// Drops a topic: its tasks stop and what it had pending goes.
    fn forget(&mut self, text: &str) {
        self.topics.remove(text);
        self.delivered.remove(text);
        self.mailbox.forget(text);
    }

    /// Starts the tasks that feed `text` into the mailbox.
    fn open(&self, text: &str, rate_hz: f64) -> Result<Subscription, AppError> {
        let topic = Topic::parse(text)?;
        let key: Arc<str> = Arc::from(text);
        let mailbox = self.mailbox.clone();
        let tasks = match topic {
            Topic::Nodes | Topic::Emcy => {
                let mut tasks: Vec<JoinHandle<()>> = self
                    .state
                    .gateway
                    .buses()
                    .map(|served| {
                        let events = served.node_events();
                        let bus: Arc<str> = Arc::from(served.name());
                        tokio::spawn(forward_events(
                            events,
                            bus,
                            topic == Topic::Emcy,
                            key.clone(),
                            mailbox.clone(),
                        ))
                    })
                    .collect();
                if topic == Topic::Nodes {
                    tasks.extend(self.state.gateway.buses().map(|served| {
                        tokio::spawn(forward_bus_states(
                            served.clone(),
                            key.clone(),
                            mailbox.clone(),
                        ))
                    }));
                }
                tasks
            }
            Topic::Machine => self
                .state
                .gateway
                .buses()
                .filter_map(|served| {
                    // The machine with its alarms (issue 31).
                    let machine = self.state.gateway.watch_machine(served.name())?;
                    let bus: Arc<str> = Arc::from(served.name());
                    Some(tokio::spawn(forward_machine(
                        machine,
                        bus,
                        key.clone(),
                        mailbox.clone(),
                    )))
                })
                .collect(),
            Topic::Alarms => {
                let alarms = self.state.gateway.alarm_book().clone();
                vec![tokio::spawn(forward_alarms(alarms, key, mailbox))]
            }
            Topic::Frames { bus, ids } => {
                let served = self.state.bus(&bus)?;
                let feed = self.state.frame_feeds.subscribe(&served);
                vec![tokio::spawn(forward_frames(
                    feed, ids, rate_hz, key, mailbox,
                ))]
            }
            Topic::Values { bus, node } => {
                let (served, info) = known_node(&self.state, &bus, &node)?;
                let receiver = served.values().subscribe(info.id, rate_hz);
                vec![tokio::spawn(forward_values(receiver, key, mailbox))]
            }
            Topic::Axis { bus, node, axis } => {
                let (served, info) = known_node(&self.state, &bus, &node)?;
                let axis: u8 = axis.parse().map_err(|_| {
                    GatewayError::UnknownAxis(format!("'{axis}' is no axis number (1, 2, ...)"))
                })?;
                let receiver = served.axes().subscribe(info.id, axis, rate_hz)?;
                vec![tokio::spawn(forward_values(receiver, key, mailbox))]
            }
            Topic::Segments { bus, node } => {
                let (served, info) = known_node(&self.state, &bus, &node)?;
                let receiver = served.previews().subscribe(info.id, rate_hz)?;
                vec![tokio::spawn(forward_values(receiver, key, mailbox))]
            }
            Topic::Program { bus, node } => {
                let (served, info) = known_node(&self.state, &bus, &node)?;
                let receiver = served.programs().topic(info.id).subscribe(rate_hz);
                vec![tokio::spawn(forward_values(receiver, key, mailbox))]
            }
            Topic::Logger { id } => {
                let receiver = self.state.gateway.loggers().subscribe(&id, rate_hz)?;
                vec![tokio::spawn(forward_values(receiver, key, mailbox))]
            }
        };
        Ok(Subscription { tasks })
    }

    /// Everything pending, as messages: per topic, a `lagged` notice
    /// first, then its events in order; then values; then frame batches.
    fn drain(&mut self) -> Vec<String> {
        let pending = self.mailbox.take();
        let mut out = Vec::new();
        for (topic, lost) in &pending.lagged {
            if self.topics.contains_key(&**topic) {
                StreamCounters::add(&self.counters.lagged, *lost);
                out.push(json!({"topic": &**topic, "lagged": lost}).to_string());
            }
        }
        for (topic, message) in pending.events {
            if self.topics.contains_key(&*topic) {
                out.push(message);
            }
        }
        for (topic, sample) in pending.values {
            if !self.topics.contains_key(&*topic) {
                continue;
            }
            let last = self.delivered.insert(topic.to_string(), sample.seq);
            if let Some(last) = last {
                let skipped = sample.seq.saturating_sub(last + 1);
                StreamCounters::add(&self.counters.coalesced, skipped);
            }
            out.push(update_message(&topic, sample.ts_ms, &sample.data_text()));
        }
        for (topic, frames) in pending.frames {
            if !self.topics.contains_key(&*topic) || frames.len == 0 {
                continue;
            }
            out.push(update_message(&topic, unix_ms(), &frames.json()));
        }
        out
    }
}

/// `{"topic":..,"ts":..,"data":..}` around data already in JSON.
fn update_message(topic: &str, ts_ms: u64, data: &str) -> String {
    let mut message = String::with_capacity(data.len() + topic.len() + 40);
    message.push_str("{\"topic\":");
    message.push_str(&Json::from(topic).to_string());
    let _ = write!(message, ",\"ts\":{ts_ms},\"data\":");
    message.push_str(data);
    message.push('}');
    message
}

fn error_message(topic: Option<&str>, error: &AppError) -> String {
    let mut message = json!({
        "op": "error",
        "error": error.to_json(),
    });
    if let Some(topic) = topic {
        message["topic"] = Json::from(topic);
    }
    message.to_string()
}

/// What a session has to send, filled by its forwarding tasks.
#[derive(Default)]
struct Mailbox {
    pending: Mutex<Pending>,
    /// A permit is stored when nobody waits, so no wake-up is lost.
    ready: Notify,
}

#[derive(Default)]
struct Pending {
    /// Events in arrival order, whole messages, with their topic.
    events: VecDeque<(Arc<str>, String)>,
    /// Per topic, events or frames lost since the client was last told.
    lagged: BTreeMap<Arc<str>, u64>,
    values: BTreeMap<Arc<str>, Arc<Sample>>,
    frames: BTreeMap<Arc<str>, FrameQueue>,
    /// The frames of every topic together.
    frame_count: usize,
}

/// The frames of one topic waiting to be sent, rendered by the feed and
/// shared with every other session, oldest first.
#[derive(Default)]
struct FrameQueue {
    runs: VecDeque<FrameRun>,
    len: usize,
}

/// Frames of one topic, in order.
enum FrameRun {
    /// A batch's frames from `from` to the last (a topic without
    /// `?ids=`).
    Batch { batch: Arc<FrameBatch>, from: usize },
    /// Frames picked out of batches (a topic's `?ids=`): their text
    /// alone, so a client that does not read never holds whole batches
    /// for a few frames of them.
    Picked(VecDeque<Arc<str>>),
}

impl FrameRun {
    fn len(&self) -> usize {
        match self {
            Self::Batch { batch, from } => batch.len().saturating_sub(*from),
            Self::Picked(picked) => picked.len(),
        }
    }

    /// Drops the `n` oldest frames (at most all of them).
    fn drop_oldest(&mut self, n: usize) {
        match self {
            Self::Batch { batch, from } => *from = (*from + n).min(batch.len()),
            Self::Picked(picked) => {
                picked.drain(..n.min(picked.len()));
            }
        }
    }

    fn write_json(&self, out: &mut String) {
        let mut write = |json: &str| {
            if out.len() > 1 {
                out.push(',');
            }
            out.push_str(json);
        };
        match self {
            Self::Batch { batch, from } => {
                for frame in batch.frames().iter().skip(*from) {
                    write(&frame.json);
                }
            }
            Self::Picked(picked) => picked.iter().for_each(|json| write(json)),
        }
    }
}

impl FrameQueue {
    fn push(&mut self, run: FrameRun) {
        self.len += run.len();
        // Picked frames join the picked frames before them.
        if let (FrameRun::Picked(more), Some(FrameRun::Picked(last))) = (&run, self.runs.back_mut())
        {
            last.extend(more.iter().cloned());
            return;
        }
        self.runs.push_back(run);
    }

    /// Drops the `n` oldest frames; how many went.
    fn drop_oldest(&mut self, mut n: usize) -> usize {
        let mut dropped = 0;
        while n > 0
            && let Some(run) = self.runs.front_mut()
        {
            let len = run.len();
            if len <= n {
                self.runs.pop_front();
                n -= len;
                dropped += len;
            } else {
                run.drop_oldest(n);
                dropped += n;
                n = 0;
            }
        }
        self.len -= dropped;
        dropped
    }

    /// The frames as a JSON list.
    fn json(&self) -> String {
        let mut out = String::from("[");
        for run in &self.runs {
            run.write_json(&mut out);
        }
        out.push(']');
        out
    }
}

impl Mailbox {
    fn lock(&self) -> MutexGuard<'_, Pending> {
        // Queues of whole messages: never left half-written.
        self.pending
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    async fn ready(&self) {
        self.ready.notified().await;
    }

    fn take(&self) -> Pending {
        std::mem::take(&mut *self.lock())
    }

    fn forget(&self, topic: &str) {
        let mut pending = self.lock();
        pending.events.retain(|(t, _)| &**t != topic);
        pending.lagged.remove(topic);
        pending.values.remove(topic);
        if let Some(queue) = pending.frames.remove(topic) {
            pending.frame_count -= queue.len;
        }
    }

    fn push_event(&self, topic: &Arc<str>, message: String) {
        {
            let mut pending = self.lock();
            if pending.events.len() >= EVENT_QUEUE
                && let Some((oldest, _)) = pending.events.pop_front()
            {
                *pending.lagged.entry(oldest).or_default() += 1;
            }
            pending.events.push_back((topic.clone(), message));
        }
        self.ready.notify_one();
    }

    fn lost(&self, topic: &Arc<str>, n: u64) {
        *self.lock().lagged.entry(topic.clone()).or_default() += n;
        self.ready.notify_one();
    }

    fn put_value(&self, topic: &Arc<str>, sample: Arc<Sample>) {
        self.lock().values.insert(topic.clone(), sample);
        self.ready.notify_one();
    }

    /// Queues frames of a batch, as if one at a time: when the topic's
    /// queue ([`FRAME_QUEUE`]) or the client's ([`CLIENT_FRAME_QUEUE`]) is
    /// full, the oldest frame of the topic goes (of the longest queue, when
    /// this topic has none), counted as lagged for its topic.
    fn push_frames(&self, topic: &Arc<str>, run: FrameRun) {
        let count = run.len();
        if count == 0 {
            return;
        }
        let mut guard = self.lock();
        let pending = &mut *guard;
        let own = pending.frames.get(topic).map_or(0, |queue| queue.len);
        let over_topic = (own + count).saturating_sub(FRAME_QUEUE);
        let over_client = (pending.frame_count + count).saturating_sub(CLIENT_FRAME_QUEUE);
        let mut over = over_topic.max(over_client);
        if own == 0 && over_client > over_topic {
            // The first frame's room comes from the longest queue.
            let victim = pending
                .frames
                .iter()
                .max_by_key(|(_, queue)| queue.len)
                .map(|(topic, _)| topic.clone());
            if let Some(victim) = victim
                && let Some(queue) = pending.frames.get_mut(&victim)
                && queue.drop_oldest(1) == 1
            {
                pending.frame_count -= 1;
                *pending.lagged.entry(victim).or_default() += 1;
                over -= 1;
            }
        }
        let queue = pending.frames.entry(topic.clone()).or_default();
        queue.push(run);
        let dropped = queue.drop_oldest(over);
        pending.frame_count += count;
        pending.frame_count -= dropped;
        if dropped > 0 {
            *pending.lagged.entry(topic.clone()).or_default() += dropped as u64;
        }
    }

    fn wake(&self) {
        self.ready.notify_one();
    }
}

/// Forwards a value topic at most at its receiver's rate, on a steady
/// cadence: each due time is one period after the last (not after the last
/// delivery), and at a due time the newest sample goes, or the next one as
/// soon as it is published. Sleeping a period after each delivery instead
/// would beat against a producer publishing at the same rate and deliver
/// each sample up to a whole period late.
async fn forward_values(mut receiver: TopicReceiver, topic: Arc<str>, mailbox: Arc<Mailbox>) {
    let period = period_at_most(receiver.rate_hz(), MAX_RATE_HZ);
    let mut due = Instant::now();
    if let Some(sample) = receiver.take() {
        mailbox.put_value(&topic, sample);
        due += period;
    }
    loop {
        tokio::time::sleep_until(due).await;
        let Some(sample) = receiver.changed().await else {
            return;
        };
        mailbox.put_value(&topic, sample);
        // After a long wait for a sample the cadence starts again from now,
        // rather than catching up with a burst.
        due = (due + period).max(Instant::now());
    }
}

/// Forwards one bus's registry events of one kind (`nodes`, or `emcy`).
async fn forward_events(
    mut events: tokio::sync::broadcast::Receiver<NodeEvent>,
    bus: Arc<str>,
    emcy: bool,
    topic: Arc<str>,
    mailbox: Arc<Mailbox>,
) {
    use tokio::sync::broadcast::error::RecvError as EventError;
    loop {
        match events.recv().await {
            Ok(event) => {
                if matches!(event, NodeEvent::Emcy { .. }) != emcy {
                    continue;
                }
                let data = event_json(&bus, &event);
                mailbox.push_event(&topic, update_message(&topic, unix_ms(), &data.to_string()));
            }
            // The registry's channel lost events before this task read them:
            // they are this topic's as far as anyone can tell.
            Err(EventError::Lagged(n)) => mailbox.lost(&topic, n),
            Err(EventError::Closed) => return,
        }
    }
}

/// The changes of a bus's state, as `bus_state` events of the `nodes`
/// topic: up or down, and the CAN controller's error state and counters
/// (`error_active`, `error_passive`, `bus_off`), as a real interface
/// reports them.
async fn forward_bus_states(served: Arc<ServedBus>, topic: Arc<str>, mailbox: Arc<Mailbox>) {
    let name: Arc<str> = Arc::from(served.name());
    let mut status = served.watch_status();
    status.mark_unchanged();
    while status.changed().await.is_ok() {
        let current = status.borrow_and_update().clone();
        let counters = served.counters();
        let data = json!({
            "bus": &*name,
            "event": "bus_state",
            "state": if current.state.can_send() { "up" } else { "down" },
            "error_state": current.state.error_state().map(|state| state.as_str()),
            "reason": current.reason,
            "tx_error_counter": counters.tec,
            "rx_error_counter": counters.rec,
        });
        mailbox.push_event(&topic, update_message(&topic, unix_ms(), &data.to_string()));
    }
}

/// Forwards one bus's machine (its network manager's status): as it is
/// when subscribed, then every change.
async fn forward_machine(
    mut machine: tokio::sync::watch::Receiver<crate::gateway::MachineView>,
    bus: Arc<str>,
    topic: Arc<str>,
    mailbox: Arc<Mailbox>,
) {
    loop {
        let data = {
            let status = machine.borrow_and_update();
            let mut data = serde_json::to_value(&*status).unwrap_or(Json::Null);
            data["bus"] = json!(&*bus);
            data
        };
        mailbox.push_event(&topic, update_message(&topic, unix_ms(), &data.to_string()));
        if machine.changed().await.is_err() {
            return;
        }
    }
}

/// Forwards the alarms (issue 31): the open ones as they are when
/// subscribed, then every change; after a lag, the open ones again.
async fn forward_alarms(alarms: gateway::Alarms, topic: Arc<str>, mailbox: Arc<Mailbox>) {
    use tokio::sync::broadcast::error::RecvError as ChangeError;
    let mut changes = alarms.subscribe();
    let snapshot = |mailbox: &Mailbox| {
        let data = super::alarms::stream_open(&alarms);
        mailbox.push_event(&topic, update_message(&topic, unix_ms(), &data.to_string()));
    };
    snapshot(&mailbox);
    loop {
        match changes.recv().await {
            Ok(change) => {
                let data = super::alarms::stream_change(&alarms, &change);
                mailbox.push_event(&topic, update_message(&topic, unix_ms(), &data.to_string()));
            }
            Err(ChangeError::Lagged(n)) => {
                mailbox.lost(&topic, n);
                snapshot(&mailbox);
            }
            Err(ChangeError::Closed) => return,
        }
    }
}

/// One registry event as the `nodes` or `emcy` topic sends it.
fn event_json(bus: &str, event: &NodeEvent) -> Json {
    let node = event.node().get();
    match event {
        NodeEvent::Appeared { .. } => json!({"bus": bus, "node": node, "event": "appeared"}),
        NodeEvent::Identified { profile, eds, .. } => json!({
            "bus": bus, "node": node, "event": "identified", "profile": profile, "eds": eds,
        }),
        NodeEvent::IdentificationFailed { error, .. } => json!({
            "bus": bus, "node": node, "event": "identification_failed", "error": error,
        }),
        NodeEvent::NmtChanged { from, to, .. } => json!({
            "bus": bus, "node": node, "event": "nmt_changed",
            "from": from.map_or("unknown", |state| state.name()), "nmt": to.name(),
        }),
        NodeEvent::Offline { reason, .. } => json!({
            "bus": bus, "node": node, "event": "offline", "reason": reason,
        }),
        NodeEvent::Online { .. } => json!({"bus": bus, "node": node, "event": "online"}),
        NodeEvent::HeartbeatWritten { heartbeat_ms, .. } => json!({
            "bus": bus, "node": node, "event": "heartbeat_written", "heartbeat_ms": heartbeat_ms,
        }),
        NodeEvent::WatchdogOff { warning, .. } => json!({
            "bus": bus, "node": node, "event": "watchdog_off", "warning": warning,
        }),
        // issue 30 (motion authority): an axis stopped and its lease ended
        // by the gateway (a renumbering).
        NodeEvent::MotionEnded {
            axis,
            reason,
            detail,
            ..
        } => json!({
            "bus": bus, "node": node, "event": "motion_ended", "axis": axis,
            "reason": reason, "detail": detail,
        }),
        NodeEvent::Emcy { emcy, .. } => json!({
            "bus": bus,
            "node": node,
            "code": format!("0x{:04X}", emcy.code),
            "text": emcy.text,
            "register": emcy.register,
            "manufacturer": emcy.manufacturer_hex(),
            "timestamp_us": emcy.timestamp.as_micros(),
            "axis": emcy.axis,
        }),
    }
}

/// Forwards a bus's frames (those of `ids`, or all) from its feed, waking
/// the session at most `rate_hz` times per second, and at most
/// [`MAX_PUBLISH_HZ`] (the feed's batches).
async fn forward_frames(
    mut feed: FeedReceiver,
    ids: Option<BTreeSet<u32>>,
    rate_hz: f64,
    topic: Arc<str>,
    mailbox: Arc<Mailbox>,
) {
    let period = period_at_most(rate_hz, MAX_PUBLISH_HZ);
    let mut next_wake = Instant::now();
    let mut queued = false;
    // The feed's count of frames after the last batch seen: batches lost
    // before this task read them are frames lost.
    let mut seen: Option<u64> = None;
    loop {
        tokio::select! {
            received = feed.recv() => match received {
                Ok(batch) => {
                    let missed = seen.map_or(0, |seen| batch.before.saturating_sub(seen));
                    seen = Some(batch.through());
                    if missed + batch.lost > 0 {
                        mailbox.lost(&topic, missed + batch.lost);
                        queued = true;
                    }
                    let run = match &ids {
                        None => FrameRun::Batch { batch, from: 0 },
                        Some(ids) => FrameRun::Picked(
                            batch
                                .frames()
                                .iter()
                                .filter(|frame| ids.contains(&frame.id))
                                .map(|frame| frame.json.clone())
                                .collect(),
                        ),
                    };
                    if run.len() > 0 {
                        mailbox.push_frames(&topic, run);
                        queued = true;
                    }
                }
                // Counted from the next batch's `before`.
                Err(FeedError::Lagged) => {}
                Err(FeedError::Closed) => {
                    mailbox.wake();
                    return;
                }
            },
            () = tokio::time::sleep_until(next_wake), if queued => {}
        }
        let now = Instant::now();
        if queued && now >= next_wake {
            mailbox.wake();
            queued = false;
            next_wake = now + period;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::{CanId, Direction, Frame, TimedFrame, Timestamp};

    /// A batch of the feed holding one frame.
    fn batch() -> Arc<FrameBatch> {
        let mut batch = FrameBatch::default();
        batch.push(&TimedFrame {
            frame: Frame::new(CanId::standard(0x181).unwrap(), &[1, 2]).unwrap(),
            timestamp: Timestamp(0),
            direction: Direction::Rx,
        });
        Arc::new(batch)
    }

    /// Issue 30, finding 7: a client that does not read holds at most
    /// [`CLIENT_FRAME_QUEUE`] frames, however many frames topics it has;
    /// what goes is counted as lagged, per topic.
    #[test]
    fn a_client_that_does_not_read_holds_a_bounded_number_of_frames() {
        let mailbox = Mailbox::default();
        let topics: Vec<Arc<str>> = (0..MAX_TOPICS)
            .map(|n| Arc::from(format!("buses/demo/frames?ids={n:#x}")))
            .collect();
        let per_topic = 200;
        for _ in 0..per_topic {
            for topic in &topics {
                mailbox.push_frames(
                    topic,
                    FrameRun::Batch {
                        batch: batch(),
                        from: 0,
                    },
                );
            }
        }
        let pending = mailbox.take();
        let queued: usize = pending.frames.values().map(|queue| queue.len).sum();
        assert_eq!(queued, CLIENT_FRAME_QUEUE);
        assert_eq!(pending.frame_count, CLIENT_FRAME_QUEUE);
        let lagged: u64 = pending.lagged.values().sum();
        assert_eq!(lagged as usize, MAX_TOPICS * per_topic - CLIENT_FRAME_QUEUE);
        // One topic alone still keeps its own bound.
        for _ in 0..FRAME_QUEUE + 10 {
            mailbox.push_frames(
                &topics[0],
                FrameRun::Batch {
                    batch: batch(),
                    from: 0,
                },
            );
        }
        let pending = mailbox.take();
        assert_eq!(pending.frames[&topics[0]].len, FRAME_QUEUE);
        assert_eq!(pending.lagged[&topics[0]], 10);
    }

    /// A batch larger than the room left loses its own oldest frames, as
    /// frames pushed one at a time would, and the rest are sent in order.
    #[test]
    fn a_batch_beyond_the_topics_queue_keeps_its_newest_frames() {
        let mailbox = Mailbox::default();
        let topic: Arc<str> = Arc::from("buses/demo/frames");
        let mut big = FrameBatch::default();
        for n in 0..FRAME_QUEUE as u32 + 5 {
            big.push(&TimedFrame {
                frame: Frame::new(CanId::standard(0x181).unwrap(), &n.to_le_bytes()).unwrap(),
                timestamp: Timestamp(0),
                direction: Direction::Rx,
            });
        }
        let big = Arc::new(big);
        mailbox.push_frames(
            &topic,
            FrameRun::Batch {
                batch: big.clone(),
                from: 0,
            },
        );
        // Of picked frames, only those, in order, however they came.
        let listed: Arc<str> = Arc::from("buses/demo/frames?ids=0x181");
        let pick = |at: &[usize]| {
            let frames: &[RenderedFrame] = big.frames();
            FrameRun::Picked(at.iter().map(|&at| frames[at].json.clone()).collect())
        };
        mailbox.push_frames(&listed, pick(&[0, 2]));
        mailbox.push_frames(&listed, pick(&[4]));
        assert_eq!(mailbox.lock().frames[&listed].runs.len(), 1);
        let pending = mailbox.take();
        assert_eq!(pending.lagged[&topic], 5);
        let sent: Json = serde_json::from_str(&pending.frames[&topic].json()).unwrap();
        let sent = sent.as_array().unwrap();
        assert_eq!(sent.len(), FRAME_QUEUE);
        assert_eq!(sent[0]["data"], "05000000");
        let sent: Json = serde_json::from_str(&pending.frames[&listed].json()).unwrap();
        let data: Vec<&str> = sent
            .as_array()
            .unwrap()
            .iter()
            .map(|frame| frame["data"].as_str().unwrap())
            .collect();
        assert_eq!(data, ["00000000", "02000000", "04000000"]);
    }
}
