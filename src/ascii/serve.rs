//! The I/O of CiA 309-3 (§4, the ASCII transport): a connection (a TCP
//! client of `--ascii-listen`, or stdin/stdout of `candeck ascii`) reads
//! command lines, answers each one in turn through [`Session`], and gets
//! the gateway's events as unsolicited lines between the replies.
//!
//! Commands of one connection run one after another, as in CANopenNode's
//! gateway (a reply is written before the next line is read); connections
//! run side by side, their SDO transfers queued per node with REST's.

use std::collections::VecDeque;
use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::Poll;
use std::time::Duration;

use tokio::io::{
    AsyncBufRead, AsyncBufReadExt, AsyncRead, AsyncWrite, AsyncWriteExt, BufReader, ReadBuf,
};
use tokio::net::TcpListener;
use tokio::sync::{broadcast, mpsc, oneshot};
use tokio::time::Instant;

use crate::canopen::nmt::NmtState;
use crate::cia309::command::{self, Command, Context, HelpTopic, Line};
use crate::cia309::reply::{self, ErrorCode, Event, Reply};
use crate::cia309::{Cia309Gateway, Failure, Identity, Origin, TransferOptions};
use crate::gateway::GatewayError;
use crate::gateway::{NodeEvent, OfflineReason};

/// The longest command line read; a longer one is a syntax error.
pub const MAX_LINE: usize = 64 * 1024;

/// Lines waiting to be written to a slow client; events past that are
/// dropped (replies wait).
const QUEUE: usize = 256;

/// One connection's state: its defaults (`set network`, `set node`), SDO
/// settings (`set sdo_timeout`, `set sdo_block`), the last sequence number
/// (what a line without a readable one is answered with, as CANopenNode
/// does), and who it is.
pub struct Session {
    gateway: Cia309Gateway,
    identity: Identity,
    /// Who it is without a token: what a failed `auth` returns it to.
    anonymous: Identity,
    default_net: u16,
    default_node: Option<u8>,
    options: TransferOptions,
    last_sequence: u32,
    /// Whether a line other than an empty one came.
    last_sequence_seen: bool,
}

/// The longest part of a refused line the audit log keeps (a line may be
/// [`MAX_LINE`] long).
const MAX_AUDITED_LINE: usize = 256;

/// `[seq] auth TOKEN`: not part of CiA 309-3, candeck's way to give a
/// connection a token when the gateway has tokens (`docs/cia309.md`,
/// "Tokens"); the sequence number and the token, `None` for a line with
/// no token or with more after it (a syntax error).
fn auth_line(line: &str) -> Option<(u32, Option<&str>)> {
    let mut words = line.split_whitespace();
    let first = words.next()?;
    let sequence = first
        .strip_prefix('[')
        .and_then(|rest| rest.strip_suffix(']'))
        .and_then(|number| number.parse().ok());
    let command = match sequence {
        Some(_) => words.next()?,
        None => first,
    };
    if !command.eq_ignore_ascii_case("auth") {
        return None;
    }
    let token = match (words.next(), words.next()) {
        (Some(token), None) => Some(token),
        _ => None,
    };
    Some((sequence.unwrap_or(0), token))
}

impl Session {
    /// `auth TOKEN`: the connection takes the token's name and role. A
    /// failed `auth` (an unknown token, none, or words after it) leaves
    /// the connection with no token at all, whatever it had before: a
    /// client that meant to change who it is does not carry on as the
    /// earlier one.
    fn authenticate(&mut self, sequence: u32, token: Option<&str>) -> Reply {
        self.last_sequence = sequence;
        let found = token.and_then(|token| self.gateway.tokens().authenticate(token));
        match found {
            Some((name, role)) => {
                self.identity.who = name;
                self.identity.role = role.name().to_string();
                self.identity.access = Some(role);
                Reply::Ok(sequence)
            }
            None => {
                self.identity = self.anonymous.clone();
                tracing::warn!(
                    "ascii: {} sent an unknown token, or a malformed auth line",
                    self.identity.peer.as_deref().unwrap_or("a client")
                );
                let code = if token.is_some() {
                    ErrorCode::InternalState
                } else {
                    ErrorCode::Syntax
                };
                Reply::Error(sequence, code)
            }
        }
    }

    /// Whether the connection has shown it is a client of the gateway: it
    /// gave a valid token, or (on a gateway without tokens) it sent a
    /// command. Until then it has the short idle timeout and its place may
    /// go to a newer connection ([`listen`]).
    pub fn established(&self) -> bool {
        self.identity.access.is_some()
            || !self.gateway.tokens().required() && self.last_sequence_seen
    }

    pub fn new(gateway: Cia309Gateway, identity: Identity) -> Self {
        Self {
            gateway,
            anonymous: identity.clone(),
            identity,
            default_net: 1,
            default_node: None,
            options: TransferOptions::default(),
            last_sequence: 0,
            last_sequence_seen: false,
        }
    }

    /// The reply to one line.
    pub async fn handle(&mut self, line: &str) -> Reply {
        if !line.trim().is_empty() {
            self.last_sequence_seen = true;
        }
        if let Some((sequence, token)) = auth_line(line) {
            return self.authenticate(sequence, token);
        }
        let context = Context {
            default_net: self.default_net,
            default_node: self.default_node,
            networks: self.gateway.networks(),
        };
        let request = match command::parse(line, &context) {
            Ok(Line::Empty) => return Reply::Empty,
            Ok(Line::Request(request)) => request,
            Err(error) => {
                let sequence = error.sequence.unwrap_or(self.last_sequence);
                self.last_sequence = sequence;
                // A write or NMT command refused for its form is still an
                // attempt to change a device: logged as REST logs its 400s.
                if let Some(change) = command::attempted_change(line) {
                    let path = audited_line(line);
                    let origin = Origin {
                        identity: &self.identity,
                        method: "ASCII",
                        path: &path,
                    };
                    let refused = GatewayError::InvalidRequest(format!(
                        "ERROR:{} {}",
                        error.code.number(),
                        error.code.description()
                    ));
                    self.gateway
                        .audit_rejected(origin, 0, None, change.what(), &refused)
                        .await;
                }
                return Reply::Error(sequence, error.code);
            }
        };
        let sequence = request.sequence;
        self.last_sequence = sequence;
        let net = request.net;
        // The role and the write rate (the token's bucket, shared with its
        // REST and CiA 309-5 writes) are the gateway's to apply: refused,
        // 102 (CiA 309-3 has no "forbidden" or "too many requests": the
        // request is not processed for the gateway's state, docs/cia309.md).
        let node = request.node.unwrap_or(0);
        let path = line.trim_end_matches(['\r', '\n']);
        let origin = Origin {
            identity: &self.identity,
            method: "ASCII",
            path,
        };
        let result = match request.command {
            Command::Read {
                index,
                sub,
                datatype,
            } => {
                return match self
                    .gateway
                    .read(origin, net, node, index, sub, self.options)
                    .await
                {
                    Ok(bytes) => {
                        let text = match datatype {
                            Some(datatype) => datatype.format(&bytes),
                            None => crate::cia309::datatype::hex_text(&bytes),
                        };
                        Reply::Value(sequence, text)
                    }
                    Err(error) => failure_reply(sequence, Failure::of(&error)),
                };
            }
            Command::Write {
                index,
                sub,
                datatype,
                data,
                text,
            } => {
                let summary = format!("{} {text}", datatype.mnemonic());
                self.gateway
                    .write(origin, net, node, index, sub, data, summary, self.options)
                    .await
            }
            Command::Nmt(nmt) => self.gateway.nmt(origin, net, node, nmt).await,
            Command::SetNetwork(net) => {
                self.default_net = net;
                Ok(())
            }
            Command::SetNode(node) => {
                self.default_node = Some(node);
                Ok(())
            }
            Command::SetSdoTimeout(ms) => {
                self.options.timeout = Some(Duration::from_millis(ms.into()));
                Ok(())
            }
            Command::SetSdoBlock(block) => {
                self.options.block = block;
                Ok(())
            }
            Command::Help(HelpTopic::Commands) => return Reply::Help(reply::HELP),
            Command::Help(HelpTopic::Datatypes) => return Reply::Help(reply::HELP_DATATYPES),
        };
        match result {
            Ok(()) => Reply::Ok(sequence),
            Err(error) => failure_reply(sequence, Failure::of(&error)),
        }
    }
}

/// A line as the audit log keeps a refused one: without its end, at most
/// [`MAX_AUDITED_LINE`] bytes.
fn audited_line(line: &str) -> String {
    let line = line.trim_end_matches(['\r', '\n']);
    if line.len() <= MAX_AUDITED_LINE {
        return line.to_string();
    }
    let mut cut = MAX_AUDITED_LINE;
    while !line.is_char_boundary(cut) {
        cut -= 1;
    }
    format!("{}…", &line[..cut])
}

fn failure_reply(sequence: u32, failure: Failure) -> Reply {
    match failure {
        Failure::Abort(code) => Reply::Abort(sequence, code),
        Failure::Error(code) => Reply::Error(sequence, code),
    }
}

/// The event line of a registry event on net `net`, if it has one.
pub fn event_of(net: u16, event: &NodeEvent) -> Option<Event> {
    let node = event.node().get();
    match event {
        NodeEvent::NmtChanged {
            to: NmtState::BootUp,
            ..
        } => Some(Event::BootUp { net, node }),
        NodeEvent::Emcy { emcy, .. } => Some(Event::Emcy {
            net,
            node,
            code: emcy.code,
            register: emcy.register,
            manufacturer: emcy.manufacturer,
        }),
        NodeEvent::Online { .. } => Some(Event::HeartbeatStarted { net, node }),
        NodeEvent::Offline {
            reason: OfflineReason::HeartbeatLost,
            ..
        } => Some(Event::HeartbeatLost { net, node }),
        _ => None,
    }
}

/// Serves one connection until its input ends: a line in, a reply out,
/// events in between.
pub async fn serve_connection<R, W>(gateway: Cia309Gateway, identity: Identity, input: R, output: W)
where
    R: AsyncRead + Unpin,
    W: AsyncWrite + Unpin + Send + 'static,
{
    serve_session(gateway, identity, input, output, &AtomicBool::new(false)).await;
}

/// [`serve_connection`], telling `established` when the session is
/// ([`Session::established`]).
async fn serve_session<R, W>(
    gateway: Cia309Gateway,
    identity: Identity,
    input: R,
    mut output: W,
    established: &AtomicBool,
) where
    R: AsyncRead + Unpin,
    W: AsyncWrite + Unpin + Send + 'static,
{
    let (lines, mut queue) = mpsc::channel::<String>(QUEUE);
    // The events of every bus from now on.
    let mut forwarders = Vec::new();
    for (at, bus) in gateway.buses().iter().enumerate() {
        let net = (at + 1) as u16;
        let mut events = bus.node_events();
        let lines = lines.clone();
        forwarders.push(tokio::spawn(async move {
            loop {
                match events.recv().await {
                    Ok(event) => {
                        if let Some(event) = event_of(net, &event)
                            && let Err(mpsc::error::TrySendError::Closed(_)) =
                                lines.try_send(event.to_wire())
                        {
                            return;
                        }
                    }
                    Err(broadcast::error::RecvError::Lagged(_)) => {}
                    Err(broadcast::error::RecvError::Closed) => return,
                }
            }
        }));
    }
    let writer = tokio::spawn(async move {
        while let Some(line) = queue.recv().await {
            if output.write_all(line.as_bytes()).await.is_err() || output.flush().await.is_err() {
                return;
            }
        }
    });
    let mut session = Session::new(gateway, identity);
    let mut input = BufReader::new(input);
    while let Some(line) = read_line(&mut input).await {
        let reply = match line {
            Ok(line) => session.handle(&line).await,
            Err(TooLong) => Reply::Error(session.last_sequence, ErrorCode::Syntax),
        };
        established.store(session.established(), Ordering::Release);
        if lines.send(reply.to_wire()).await.is_err() {
            break;
        }
    }
    for forwarder in forwarders {
        forwarder.abort();
    }
    drop(lines);
    // What was answered is written before the connection closes.
    let _ = writer.await;
}

/// A line longer than [`MAX_LINE`].
struct TooLong;

/// The next line (without checking its content); `None` at the end of the
/// input. Bytes that are not UTF-8 are replaced (they can only be in a
/// value, which is then refused).
async fn read_line<R: AsyncBufRead + Unpin>(input: &mut R) -> Option<Result<String, TooLong>> {
    let mut buf = Vec::new();
    let mut too_long = false;
    loop {
        let available = match input.fill_buf().await {
            Ok(available) => available,
            Err(_) => return None,
        };
        if available.is_empty() {
            // The end of the input: a last line without its end counts.
            if buf.is_empty() && !too_long {
                return None;
            }
            break;
        }
        let (taken, ended) = match available.iter().position(|&b| b == b'\n') {
            Some(at) => (at + 1, true),
            None => (available.len(), false),
        };
        if !too_long {
            buf.extend_from_slice(&available[..taken]);
            if buf.len() > MAX_LINE {
                too_long = true;
                buf = Vec::new();
            }
        }
        input.consume(taken);
        if ended {
            break;
        }
    }
    if too_long {
        return Some(Err(TooLong));
    }
    Some(Ok(String::from_utf8_lossy(&buf).into_owned()))
}

/// The limits of the TCP listener (config keys `ascii_idle_timeout_ms`,
/// `ascii_max_connections`, `ascii_unauthenticated_timeout_ms`): a client
/// that sends no line for `idle_timeout` is closed (the events it would get
/// do not keep it open), and so is one not yet established
/// ([`Session::established`]: no valid token yet, or on a gateway without
/// tokens no command yet) after `unauthenticated_timeout`. When all
/// `max_connections` places are taken, a new connection takes the place of
/// the oldest one not established (issue 30: idle clients without a token
/// cannot lock out those with one); when every place is established, it is
/// closed at once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    pub idle_timeout: Duration,
    pub max_connections: usize,
    pub unauthenticated_timeout: Duration,
}

/// How long a CiA 309-3 client may send nothing, by default.
pub const DEFAULT_IDLE_TIMEOUT: Duration = Duration::from_secs(300);
/// CiA 309-3 connections at once, by default.
pub const DEFAULT_MAX_CONNECTIONS: usize = 32;
/// How long a CiA 309-3 client may go without a valid token (or, on a
/// gateway without tokens, without a command), by default.
pub const DEFAULT_UNAUTHENTICATED_TIMEOUT: Duration = Duration::from_secs(10);

impl Default for Limits {
    fn default() -> Self {
        Self {
            idle_timeout: DEFAULT_IDLE_TIMEOUT,
            max_connections: DEFAULT_MAX_CONNECTIONS,
            unauthenticated_timeout: DEFAULT_UNAUTHENTICATED_TIMEOUT,
        }
    }
}

impl Limits {
    /// The limits, checked: timeouts above 0, at least one connection.
    pub fn new(
        idle_timeout: Duration,
        max_connections: usize,
        unauthenticated_timeout: Duration,
    ) -> Result<Self, String> {
        if idle_timeout.is_zero() || unauthenticated_timeout.is_zero() {
            return Err(
                "ascii_idle_timeout_ms, ascii_unauthenticated_timeout_ms: a timeout is at least 1 ms"
                    .to_string(),
            );
        }
        if max_connections == 0 {
            return Err("ascii_max_connections: at least 1".to_string());
        }
        Ok(Self {
            idle_timeout,
            max_connections,
            unauthenticated_timeout,
        })
    }
}

/// Reads what comes from `input` until it has sent nothing for the idle
/// timeout: `limits.idle_timeout` once the session is established, else
/// the shorter `limits.unauthenticated_timeout`.
struct IdleLimited<R> {
    input: R,
    limits: Limits,
    established: Arc<AtomicBool>,
    /// Fires when a newer connection took this one's place: the input
    /// ends there.
    evicted: Option<oneshot::Receiver<()>>,
    last: Instant,
    deadline: Pin<Box<tokio::time::Sleep>>,
}

impl<R> IdleLimited<R> {
    fn new(
        input: R,
        limits: Limits,
        established: Arc<AtomicBool>,
        evicted: oneshot::Receiver<()>,
    ) -> Self {
        let last = Instant::now();
        let mut this = Self {
            input,
            limits,
            established,
            evicted: Some(evicted),
            last,
            deadline: Box::pin(tokio::time::sleep_until(last)),
        };
        let first = this.expiry();
        this.deadline.as_mut().reset(first);
        this
    }

    /// When the client, silent since `last`, is closed.
    fn expiry(&self) -> Instant {
        let idle = if self.established.load(Ordering::Acquire) {
            self.limits.idle_timeout
        } else {
            self.limits
                .unauthenticated_timeout
                .min(self.limits.idle_timeout)
        };
        self.last + idle
    }
}

impl<R: AsyncRead + Unpin> AsyncRead for IdleLimited<R> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        if let Some(evicted) = &mut self.evicted
            && let Poll::Ready(sent) = Pin::new(evicted).poll(cx)
        {
            self.evicted = None;
            if sent.is_ok() {
                // The end of the input, as if the client had closed.
                return Poll::Ready(Ok(()));
            }
        }
        match Pin::new(&mut self.input).poll_read(cx, buf) {
            Poll::Ready(result) => {
                if buf.filled().len() > before {
                    self.last = Instant::now();
                    let next = self.expiry();
                    self.deadline.as_mut().reset(next);
                }
                Poll::Ready(result)
            }
            Poll::Pending => loop {
                match self.deadline.as_mut().poll(cx) {
                    Poll::Ready(()) => {
                        // The session may have become established since
                        // the deadline was set (its `auth` line).
                        let expiry = self.expiry();
                        if expiry > Instant::now() {
                            self.deadline.as_mut().reset(expiry);
                            continue;
                        }
                        // The end of the input, as if the client had closed.
                        return Poll::Ready(Ok(()));
                    }
                    Poll::Pending => return Poll::Pending,
                }
            },
        }
    }
}

/// The listener's connections, oldest first: whether each is established,
/// and the signal that pushes it out.
#[derive(Default)]
struct Places {
    next_id: u64,
    taken: VecDeque<(u64, Arc<AtomicBool>, Option<oneshot::Sender<()>>)>,
}

/// A connection's place; given back when dropped.
struct Place {
    id: u64,
    places: Arc<Mutex<Places>>,
}

impl Drop for Place {
    fn drop(&mut self) {
        let mut places = self.places.lock().unwrap_or_else(|p| p.into_inner());
        places.taken.retain(|(id, _, _)| *id != self.id);
    }
}

impl Places {
    /// A place for a new connection: a free one, else the one of the oldest
    /// connection not established (pushed out); `None` when every
    /// connection is established.
    fn enter(
        places: &Arc<Mutex<Places>>,
        max: usize,
    ) -> Option<(Place, Arc<AtomicBool>, oneshot::Receiver<()>)> {
        let mut this = places.lock().unwrap_or_else(|p| p.into_inner());
        if this.taken.len() >= max {
            let oldest = this
                .taken
                .iter()
                .position(|(_, established, _)| !established.load(Ordering::Acquire))?;
            if let Some((_, _, Some(evict))) = this.taken.remove(oldest) {
                tracing::debug!(
                    "ascii: a connection without a token gave its place to a newer one (ascii_max_connections)"
                );
                let _ = evict.send(());
            }
        }
        let id = this.next_id;
        this.next_id += 1;
        let established = Arc::new(AtomicBool::new(false));
        let (evict, evicted) = oneshot::channel();
        this.taken.push_back((id, established.clone(), Some(evict)));
        let place = Place {
            id,
            places: places.clone(),
        };
        Some((place, established, evicted))
    }
}

/// Accepts CiA 309-3 clients on `listener` until the task is dropped, each
/// served by [`serve_connection`] within `limits`.
pub async fn listen(listener: TcpListener, gateway: Cia309Gateway, limits: Limits) {
    let places = Arc::new(Mutex::new(Places::default()));
    loop {
        let (stream, peer) = match listener.accept().await {
            Ok(accepted) => accepted,
            Err(err) => {
                // Out of file descriptors and the like: wait, then go on.
                tracing::warn!("ascii: accept failed: {err}");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let Some((place, established, evicted)) = Places::enter(&places, limits.max_connections)
        else {
            tracing::warn!(
                "ascii: {peer} refused: {} connections already, each with a token or in use (ascii_max_connections)",
                limits.max_connections
            );
            continue;
        };
        let _ = stream.set_nodelay(true);
        let identity = Identity::anonymous("ascii", Some(peer.to_string()));
        let gateway = gateway.clone();
        tokio::spawn(async move {
            tracing::debug!("ascii: {peer} connected");
            let (input, output) = stream.into_split();
            // Pushed out, the input ends: the session closes as if the
            // client had.
            let input = IdleLimited::new(input, limits, established.clone(), evicted);
            serve_session(gateway, identity, input, output, &established).await;
            drop(place);
            tracing::debug!("ascii: {peer} disconnected");
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::NodeId;
    use crate::gateway::EmcyRecord;

    async fn lines(input: &[u8]) -> Vec<Result<String, ()>> {
        let mut reader = BufReader::with_capacity(8, input);
        let mut out = Vec::new();
        while let Some(line) = read_line(&mut reader).await {
            out.push(line.map_err(|TooLong| ()));
        }
        out
    }

    #[tokio::test(start_paused = true)]
    async fn lines_are_split_across_reads_and_a_last_line_needs_no_end() {
        assert_eq!(
            lines(b"[1] 1 r 0x1000 0\r\n\n[2] start").await,
            vec![
                Ok("[1] 1 r 0x1000 0\r\n".to_string()),
                Ok("\n".to_string()),
                Ok("[2] start".to_string())
            ]
        );
        assert_eq!(lines(b"").await, Vec::<Result<String, ()>>::new());
    }

    #[tokio::test(start_paused = true)]
    async fn a_line_too_long_is_refused_and_the_next_one_read() {
        let mut input = vec![b'x'; MAX_LINE + 10];
        input.extend_from_slice(b"\n[3] help\n");
        assert_eq!(
            lines(&input).await,
            vec![Err(()), Ok("[3] help\n".to_string())]
        );
    }

    #[test]
    fn registry_events_become_309_3_event_lines() {
        let node = NodeId::new(4).unwrap();
        let boot = NodeEvent::NmtChanged {
            node,
            from: Some(NmtState::Operational),
            to: NmtState::BootUp,
        };
        assert_eq!(event_of(2, &boot), Some(Event::BootUp { net: 2, node: 4 }));
        let other = NodeEvent::NmtChanged {
            node,
            from: Some(NmtState::BootUp),
            to: NmtState::PreOperational,
        };
        assert_eq!(event_of(2, &other), None);
        let lost = NodeEvent::Offline {
            node,
            reason: OfflineReason::HeartbeatLost,
        };
        assert_eq!(
            event_of(1, &lost),
            Some(Event::HeartbeatLost { net: 1, node: 4 })
        );
        let down = NodeEvent::Offline {
            node,
            reason: OfflineReason::BusDown,
        };
        assert_eq!(event_of(1, &down), None);
        assert_eq!(
            event_of(1, &NodeEvent::Online { node }),
            Some(Event::HeartbeatStarted { net: 1, node: 4 })
        );
        let emcy = EmcyRecord {
            code: 0x4210,
            text: String::new(),
            register: 0x09,
            manufacturer: [1, 2, 3, 4, 5],
            timestamp: crate::can::Timestamp(0),
            axis: None,
        };
        assert_eq!(
            event_of(1, &NodeEvent::Emcy { node, emcy }).map(|e| e.to_wire()),
            Some("1 4 EMCY 0x4210 0x09 01 02 03 04 05\r\n".to_string())
        );
    }
}
