//! A socketcand server sharing virtual buses over TCP, so that python-can's
//! `socketcand` interface, python-canopen, linux-can tools and other candeck
//! instances join an emulated bus.
//!
//! Each client is an attachment to the hub of the channel it opens. Clients
//! cannot disturb each other:
//! - bad input gets `< error ... >` and a log line, and the session goes on;
//! - a client that reads slower than the bus loses the oldest frames once it
//!   is [`DEFAULT_RX_QUEUE`](crate::bus::DEFAULT_RX_QUEUE) frames behind and
//!   stays connected, as upstream socketcand's CAN socket loses what its
//!   receive queue cannot hold ([`ServerStats::frames_lost_to_slow_clients`]);
//!   dropping it instead would turn a moment of overload into a reconnection
//!   and a full boot-up of its nodes;
//! - a client that stops reading is dropped once a write has made no progress
//!   for [`ServerConfig::write_timeout`]; nothing is buffered for it beyond
//!   its queue, and the kernel's send buffer is capped;
//! - a client that disconnects at any point only ends its own session;
//! - at most [`ServerConfig::max_connections`] clients at once (config key
//!   `share_max_connections`): one more is told `< error ... >` and closed,
//!   counted in [`ServerStats::refused`], and logged once a minute at most.

use std::collections::BTreeMap;
use std::io;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::net::{TcpListener, TcpSocket, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore, mpsc};
use tokio::task::JoinHandle;
use tokio::time::Instant;

use super::protocol::{DEFAULT_MAX_MESSAGE, Framer, Reply, write_frame};
use super::session::{Action, Session};
use crate::bus::{Bus, FrameReceiver, RecvError};
use crate::hub::VirtualHub;

/// Clients of one share at once, by default (`share_max_connections`).
pub const DEFAULT_MAX_CONNECTIONS: usize = 32;
/// Refused connections are logged at most once per this interval.
const REFUSAL_LOG_EVERY: Duration = Duration::from_secs(60);

/// Tunables of the server.
#[derive(Debug, Clone)]
pub struct ServerConfig {
    /// Longest accepted message.
    pub max_message: usize,
    /// Pause between the `< ok >` that enters raw mode and the first frame.
    /// python-can reads each handshake reply with a single `recv()` and
    /// compares it whole, so a frame written right behind the `< ok >` could
    /// arrive in the same read and fail its handshake. Frames of that moment
    /// are queued, not lost.
    pub settle: Duration,
    /// A write to a client that makes no progress for this long drops it.
    pub write_timeout: Duration,
    /// Kernel send buffer per client, bounding what a stalled client holds.
    pub send_buffer: u32,
    /// Largest batch of frames written to a client at once.
    pub max_batch_bytes: usize,
    /// Clients at once; one more is refused (`< error ... >`, closed).
    pub max_connections: usize,
}

impl Default for ServerConfig {
    fn default() -> Self {
        Self {
            max_message: DEFAULT_MAX_MESSAGE,
            settle: Duration::from_millis(50),
            write_timeout: Duration::from_secs(5),
            send_buffer: 64 * 1024,
            max_batch_bytes: 64 * 1024,
            max_connections: DEFAULT_MAX_CONNECTIONS,
        }
    }
}

/// What the server has seen, for logs, metrics and tests.
#[derive(Debug, Default)]
pub struct ServerStats {
    pub accepted: AtomicU64,
    pub connected: AtomicU64,
    pub rejected_commands: AtomicU64,
    /// Clients dropped because a write to them made no progress.
    pub slow_clients_dropped: AtomicU64,
    /// Frames lost by clients that read slower than the bus (they stay
    /// connected).
    pub frames_lost_to_slow_clients: AtomicU64,
    /// Connections refused because `max_connections` clients were connected.
    pub refused: AtomicU64,
    pub frames_from_clients: AtomicU64,
    pub frames_to_clients: AtomicU64,
}

/// A bound socketcand server; [`SocketcandServer::spawn`] runs it.
pub struct SocketcandServer {
    listener: TcpListener,
    channels: Arc<BTreeMap<String, VirtualHub>>,
    config: ServerConfig,
    stats: Arc<ServerStats>,
}

/// A running server. Dropping it stops accepting and ends every session.
pub struct ServerHandle {
    local_addr: SocketAddr,
    stats: Arc<ServerStats>,
    task: JoinHandle<()>,
}

impl ServerHandle {
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    pub fn stats(&self) -> &ServerStats {
        &self.stats
    }

    /// Runs until the process ends (the server stops only when dropped).
    pub async fn join(mut self) {
        let _ = (&mut self.task).await;
    }
}

impl Drop for ServerHandle {
    fn drop(&mut self) {
        self.task.abort();
    }
}

impl SocketcandServer {
    /// Binds `addr` and offers `channels` (name → hub).
    pub async fn bind(
        addr: SocketAddr,
        channels: impl IntoIterator<Item = (String, VirtualHub)>,
        config: ServerConfig,
    ) -> io::Result<Self> {
        let socket = if addr.is_ipv4() {
            TcpSocket::new_v4()?
        } else {
            TcpSocket::new_v6()?
        };
        socket.set_reuseaddr(true)?;
        // Accepted connections inherit the listener's send buffer size.
        socket.set_send_buffer_size(config.send_buffer)?;
        socket.bind(addr)?;
        let listener = socket.listen(1024)?;
        Ok(Self {
            listener,
            channels: Arc::new(channels.into_iter().collect()),
            config,
            stats: Arc::new(ServerStats::default()),
        })
    }

    pub fn local_addr(&self) -> io::Result<SocketAddr> {
        self.listener.local_addr()
    }

    pub fn spawn(self) -> io::Result<ServerHandle> {
        let local_addr = self.listener.local_addr()?;
        let stats = self.stats.clone();
        let task = tokio::spawn(self.run());
        Ok(ServerHandle {
            local_addr,
            stats,
            task,
        })
    }

    async fn run(self) {
        let mut sessions = tokio::task::JoinSet::new();
        let places = Arc::new(Semaphore::new(self.config.max_connections));
        // When a refusal was last logged, and how many came since.
        let mut logged: Option<Instant> = None;
        let mut unlogged = 0u64;
        loop {
            tokio::select! {
                accepted = self.listener.accept() => match accepted {
                    Ok((stream, peer)) => {
                        self.stats.accepted.fetch_add(1, Ordering::Relaxed);
                        let Ok(place) = places.clone().try_acquire_owned() else {
                            self.stats.refused.fetch_add(1, Ordering::Relaxed);
                            unlogged += 1;
                            let now = Instant::now();
                            if logged.is_none_or(|at| now.duration_since(at) >= REFUSAL_LOG_EVERY) {
                                tracing::warn!(
                                    "socketcand: {peer} refused: {} clients already \
                                     (share_max_connections); {unlogged} refused since the last \
                                     such line",
                                    self.config.max_connections
                                );
                                logged = Some(now);
                                unlogged = 0;
                            }
                            sessions.spawn(refuse(stream));
                            continue;
                        };
                        let channels = self.channels.clone();
                        let config = self.config.clone();
                        let stats = self.stats.clone();
                        sessions.spawn(serve_client(stream, peer, channels, config, stats, place));
                    }
                    Err(err) => {
                        // Out of file descriptors and the like: wait, do not spin.
                        tracing::warn!("socketcand: accept failed: {err}");
                        tokio::time::sleep(Duration::from_millis(100)).await;
                    }
                },
                Some(_) = sessions.join_next(), if !sessions.is_empty() => {}
            }
        }
    }
}

/// Instructions from a session's reader to its writer, in order.
enum WriterCmd {
    Reply(Reply),
    StartForwarding(FrameReceiver),
    StopForwarding,
}

/// Tells a client beyond the limit why, briefly, and closes it.
async fn refuse(mut stream: TcpStream) {
    let _ = tokio::time::timeout(
        Duration::from_secs(1),
        stream.write_all(b"< error too many clients (share_max_connections) >"),
    )
    .await;
}

async fn serve_client(
    stream: TcpStream,
    peer: SocketAddr,
    channels: Arc<BTreeMap<String, VirtualHub>>,
    config: ServerConfig,
    stats: Arc<ServerStats>,
    _place: OwnedSemaphorePermit,
) {
    // Frames are small and latency matters (SDO round trips).
    let _ = stream.set_nodelay(true);
    stats.connected.fetch_add(1, Ordering::Relaxed);
    tracing::info!("socketcand: client {peer} connected");

    let (reader, writer) = stream.into_split();
    let (commands, command_rx) = mpsc::channel(64);
    let mut writer_task = tokio::spawn(write_loop(
        writer,
        command_rx,
        peer,
        config.clone(),
        stats.clone(),
    ));
    let end = tokio::select! {
        end = read_loop(reader, commands, peer, &channels, &config, &stats) => {
            // Let the writer send what the reader asked for (an error before
            // closing), within bounds.
            let _ = tokio::time::timeout(config.write_timeout, &mut writer_task).await;
            end
        }
        end = &mut writer_task => end.unwrap_or_else(|_| "writer stopped".into()),
    };
    writer_task.abort();
    stats.connected.fetch_sub(1, Ordering::Relaxed);
    tracing::info!("socketcand: client {peer} disconnected ({end})");
}

async fn read_loop(
    mut reader: OwnedReadHalf,
    commands: mpsc::Sender<WriterCmd>,
    peer: SocketAddr,
    channels: &BTreeMap<String, VirtualHub>,
    config: &ServerConfig,
    stats: &ServerStats,
) -> String {
    if commands
        .send(WriterCmd::Reply(Session::greeting()))
        .await
        .is_err()
    {
        return "writer stopped".into();
    }
    let mut session = Session::new(channels.keys().cloned().collect());
    let mut framer = Framer::new(config.max_message);
    let mut bus: Option<Bus> = None;
    let mut buf = vec![0u8; 16 * 1024];
    let mut tokens = Vec::new();
    let mut actions = Vec::new();
    let mut rejected = 0u64;
    loop {
        let n = match reader.read(&mut buf).await {
            Ok(0) => return "closed by client".into(),
            Ok(n) => n,
            Err(err) => return format!("read failed: {err}"),
        };
        tokens.clear();
        framer.push(&buf[..n], &mut tokens);
        for token in tokens.drain(..) {
            actions.clear();
            if let Some(rejection) = session.handle(token, &mut actions) {
                rejected += 1;
                stats.rejected_commands.fetch_add(1, Ordering::Relaxed);
                // A client spewing junk must not flood the log.
                if rejected <= 10 || rejected.is_power_of_two() {
                    tracing::warn!(
                        "socketcand: client {peer}: {} (rejected input #{rejected})",
                        rejection.reason
                    );
                }
            }
            for action in actions.drain(..) {
                let cmd = match action {
                    Action::Reply(reply) => WriterCmd::Reply(reply),
                    Action::Attach(channel) => {
                        bus = channels.get(&channel).map(VirtualHub::attach);
                        continue;
                    }
                    Action::Send(frame) => {
                        let Some(bus) = &bus else { continue };
                        // A full transmit queue holds the client back (its
                        // TCP window fills), as a blocking write to the CAN
                        // socket holds socketcand: nothing is lost. A bus
                        // that is down refuses at once; socketcand answers
                        // a failed write with nothing either.
                        match bus.send(frame).await {
                            Ok(()) => {
                                stats.frames_from_clients.fetch_add(1, Ordering::Relaxed);
                            }
                            Err(err) => {
                                rejected += 1;
                                stats.rejected_commands.fetch_add(1, Ordering::Relaxed);
                                if rejected <= 10 || rejected.is_power_of_two() {
                                    tracing::warn!(
                                        "socketcand: client {peer}: frame not sent: {err} (rejected input #{rejected})"
                                    );
                                }
                            }
                        }
                        continue;
                    }
                    Action::StartForwarding => match &bus {
                        Some(bus) => WriterCmd::StartForwarding(bus.subscribe()),
                        None => continue,
                    },
                    Action::StopForwarding => WriterCmd::StopForwarding,
                    Action::Close => return "refused".into(),
                };
                if commands.send(cmd).await.is_err() {
                    return "writer stopped".into();
                }
            }
        }
    }
}

/// Writes replies and, in raw mode, the bus's frames in batches. Returns why
/// it stopped.
async fn write_loop(
    mut writer: OwnedWriteHalf,
    mut commands: mpsc::Receiver<WriterCmd>,
    peer: SocketAddr,
    config: ServerConfig,
    stats: Arc<ServerStats>,
) -> String {
    let mut out: Vec<u8> = Vec::with_capacity(config.max_batch_bytes + 256);
    let mut frames: Option<FrameReceiver> = None;
    let mut hold_until: Option<Instant> = None;
    let mut overruns = 0u64;
    loop {
        let forwarding = frames.is_some() && hold_until.is_none();
        tokio::select! {
            biased;
            cmd = commands.recv() => match cmd {
                // The reader finished; every earlier reply is already written.
                None => return "session ended".into(),
                Some(WriterCmd::Reply(reply)) => out.extend_from_slice(reply.to_string().as_bytes()),
                Some(WriterCmd::StartForwarding(rx)) => {
                    frames = Some(rx);
                    hold_until = Some(Instant::now() + config.settle);
                }
                Some(WriterCmd::StopForwarding) => {
                    frames = None;
                    hold_until = None;
                }
            },
            _ = tokio::time::sleep_until(hold_until.unwrap_or_else(Instant::now)), if hold_until.is_some() => {
                hold_until = None;
            }
            received = recv_frame(&mut frames), if forwarding => {
                let rx = frames.as_mut().expect("forwarding implies a receiver");
                let mut next = received;
                let mut count = 0u64;
                loop {
                    match next {
                        Ok(Some(frame)) => {
                            write_frame(&mut out, &frame.frame, frame.timestamp);
                            count += 1;
                        }
                        Ok(None) => break,
                        Err(RecvError::Lagged(lost)) => {
                            stats
                                .frames_lost_to_slow_clients
                                .fetch_add(lost, Ordering::Relaxed);
                            overruns += 1;
                            // Once per overrun at first, then ever more
                            // rarely: a client that keeps lagging must not
                            // flood the log.
                            if overruns <= 10 || overruns.is_power_of_two() {
                                tracing::warn!(
                                    "socketcand: client {peer} reads slower than the bus: {lost} frames lost (overrun #{overruns})"
                                );
                            }
                            next = rx.try_recv();
                            continue;
                        }
                        Err(RecvError::Closed) => return "bus closed".into(),
                    }
                    if out.len() >= config.max_batch_bytes {
                        break;
                    }
                    next = rx.try_recv();
                }
                stats.frames_to_clients.fetch_add(count, Ordering::Relaxed);
            }
        }
        if !out.is_empty() {
            match tokio::time::timeout(config.write_timeout, writer.write_all(&out)).await {
                Ok(Ok(())) => out.clear(),
                Ok(Err(err)) => return format!("write failed: {err}"),
                Err(_) => {
                    stats.slow_clients_dropped.fetch_add(1, Ordering::Relaxed);
                    tracing::warn!(
                        "socketcand: client {peer} read nothing for {:?}; dropping it",
                        config.write_timeout
                    );
                    return "stalled".into();
                }
            }
        }
    }
}

async fn recv_frame(
    frames: &mut Option<FrameReceiver>,
) -> Result<Option<crate::frame::TimedFrame>, RecvError> {
    match frames {
        Some(rx) => rx.recv().await.map(Some),
        None => std::future::pending().await,
    }
}
