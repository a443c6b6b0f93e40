//! A [`Bus`] on a remote socketcand server (ours, or linux-can's socketcand
//! beside a real CAN interface), in raw mode.
//!
//! The connection is kept up by a driver task: it reconnects with exponential
//! backoff when the connection drops and reports the bus down meanwhile.
//! Frames sent while down fail at once instead of waiting, so nothing stale
//! reaches a machine after a reconnection. A connection that goes quiet is
//! probed with `< echo >`; one that answers nothing is treated as lost, so a
//! pulled cable is noticed without waiting for TCP to give up.

use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::time::Instant;

use super::protocol::{
    Command, Framer, ServerMessage, Token, parse_server_message, write_command, write_send,
};
use crate::bus::{
    Bus, BusCounters, BusKind, BusState, BusStatus, DriverSide, attach_driver, driver_channels,
};
use crate::frame::Timestamp;
use crate::socketcan::bus_state_after_error;

/// Where and how to connect.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClientConfig {
    pub host: String,
    pub port: u16,
    pub channel: String,
    /// Limit for connecting and the handshake.
    pub connect_timeout: Duration,
    /// First wait after a failure; doubled each time up to `max_backoff`.
    pub min_backoff: Duration,
    pub max_backoff: Duration,
    /// Quiet time after which an `< echo >` is sent.
    pub probe_after: Duration,
    /// Quiet time after which the connection counts as lost.
    pub dead_after: Duration,
}

impl ClientConfig {
    pub fn new(host: impl Into<String>, port: u16, channel: impl Into<String>) -> Self {
        Self {
            host: host.into(),
            port,
            channel: channel.into(),
            connect_timeout: Duration::from_secs(3),
            min_backoff: Duration::from_millis(100),
            max_backoff: Duration::from_secs(5),
            probe_after: Duration::from_secs(2),
            dead_after: Duration::from_secs(5),
        }
    }

    /// The spec this bus is opened from.
    pub fn spec(&self) -> String {
        format!("socketcand:{}:{}/{}", self.host, self.port, self.channel)
    }
}

/// Opens a bus on a socketcand server. Returns at once; the bus is down
/// until the first connection is made (see [`Bus::wait_up`]).
pub fn open_socketcand(name: &str, config: ClientConfig) -> Bus {
    let initial = BusStatus::new(
        BusState::Down,
        format!("connecting to {}:{}", config.host, config.port),
    );
    let (parts, driver) =
        driver_channels(name, &config.spec(), BusKind::Socketcand, initial, false);
    let task = tokio::spawn(drive(driver, config));
    attach_driver(parts, task)
}

async fn drive(mut driver: DriverSide, config: ClientConfig) {
    let mut backoff = config.min_backoff;
    let mut connected_before = false;
    loop {
        match connect(&config).await {
            Ok(connection) => {
                if connected_before {
                    BusCounters::bump(&driver.counters.reconnects);
                }
                connected_before = true;
                backoff = config.min_backoff;
                tracing::info!("socketcand: connected to {}", config.spec());
                driver.set_status(BusStatus::up());
                let Some(reason) = run_connection(&mut driver, &config, connection).await else {
                    return;
                };
                tracing::warn!("socketcand: {}: {reason}", config.spec());
                driver.set_status(BusStatus::new(BusState::Down, reason));
            }
            Err(reason) => {
                tracing::debug!("socketcand: {}: {reason}", config.spec());
                driver.set_status(BusStatus::new(BusState::Down, reason));
            }
        }
        // Frames queued before the bus went down are not sent later.
        discard_queued(&mut driver);
        let until = Instant::now() + backoff;
        loop {
            match tokio::time::timeout_at(until, driver.tx.recv()).await {
                Ok(Some(_)) => BusCounters::bump(&driver.counters.tx_errors),
                // Every handle to the bus is gone: nobody wants it any more.
                Ok(None) => return,
                Err(_) => break,
            }
        }
        backoff = (backoff * 2).min(config.max_backoff);
    }
}

fn discard_queued(driver: &mut DriverSide) {
    while driver.tx.try_recv().is_ok() {
        BusCounters::bump(&driver.counters.tx_errors);
    }
}

/// A connection in raw mode, with anything the server sent after the
/// handshake that is already read.
struct Connection {
    stream: TcpStream,
    framer: Framer,
    early: Vec<Token>,
}

/// Connects and walks the handshake: `< hi >`, open, `< ok >`, rawmode, `< ok >`.
async fn connect(config: &ClientConfig) -> Result<Connection, String> {
    let address = format!("{}:{}", config.host, config.port);
    let work = async {
        let stream = TcpStream::connect(&address)
            .await
            .map_err(|err| format!("cannot connect to socketcand at {address}: {err}"))?;
        let _ = stream.set_nodelay(true);
        let mut connection = Connection {
            stream,
            framer: Framer::default(),
            early: Vec::new(),
        };
        expect(&mut connection, ServerMessage::Hi, "greeting").await?;
        send_command(&mut connection, &Command::Open(config.channel.clone())).await?;
        expect(&mut connection, ServerMessage::Ok, "open")
            .await
            .map_err(|err| {
                format!(
                    "socketcand at {address} refused channel '{}': {err}",
                    config.channel
                )
            })?;
        send_command(&mut connection, &Command::RawMode).await?;
        expect(&mut connection, ServerMessage::Ok, "rawmode").await?;
        Ok(connection)
    };
    match tokio::time::timeout(config.connect_timeout, work).await {
        Ok(result) => result,
        Err(_) => Err(format!(
            "socketcand at {address} did not complete the handshake within {:?}",
            config.connect_timeout
        )),
    }
}

async fn send_command(connection: &mut Connection, command: &Command) -> Result<(), String> {
    let mut out = Vec::new();
    write_command(&mut out, command);
    connection
        .stream
        .write_all(&out)
        .await
        .map_err(|err| format!("write failed: {err}"))
}

/// Reads until the next message and checks it is `wanted`.
async fn expect(
    connection: &mut Connection,
    wanted: ServerMessage,
    step: &str,
) -> Result<(), String> {
    let mut buf = [0u8; 1024];
    loop {
        if !connection.early.is_empty() {
            let token = connection.early.remove(0);
            let Token::Message(text) = token else {
                return Err(format!("unexpected input during {step}: {token:?}"));
            };
            return match parse_server_message(&text) {
                Ok(message) if message == wanted => Ok(()),
                Ok(ServerMessage::Error(detail)) => Err(detail),
                _ => Err(format!(
                    "expected {wanted:?} during {step}, got '< {text} >'"
                )),
            };
        }
        let n = connection
            .stream
            .read(&mut buf)
            .await
            .map_err(|err| format!("read failed during {step}: {err}"))?;
        if n == 0 {
            return Err(format!("server closed the connection during {step}"));
        }
        connection.framer.push(&buf[..n], &mut connection.early);
    }
}

/// Moves frames both ways until the connection ends; returns why it ended,
/// or `None` when the bus itself was dropped.
async fn run_connection(
    driver: &mut DriverSide,
    config: &ClientConfig,
    connection: Connection,
) -> Option<String> {
    let Connection {
        stream,
        mut framer,
        early,
    } = connection;
    let (mut reader, mut writer) = stream.into_split();
    let mut tokens = early;
    let mut buf = vec![0u8; 16 * 1024];
    let mut out = Vec::with_capacity(4096);
    let mut last_heard = Instant::now();
    let mut probed = false;
    loop {
        // One unit of the task's budget per frame, as each reader spends
        // one per frame it takes: after a backlog built up in the socket
        // (the process was busy or descheduled while the bus ran on), the
        // frames of many reads would otherwise go into the readers' queues
        // in one poll of this task, before any reader ran, and overrun
        // them all (SDO answers and heartbeats lost with the rest).
        for token in tokens.drain(..) {
            handle_token(driver, token);
            tokio::task::coop::consume_budget().await;
        }
        let probe_at = last_heard
            + if probed {
                config.dead_after
            } else {
                config.probe_after
            };
        tokio::select! {
            read = reader.read(&mut buf) => match read {
                Ok(0) => return Some("server closed the connection".into()),
                Ok(n) => {
                    last_heard = Instant::now();
                    probed = false;
                    framer.push(&buf[..n], &mut tokens);
                }
                Err(err) => return Some(format!("read failed: {err}")),
            },
            frame = driver.tx.recv() => {
                // No frame: every handle to the bus is gone.
                let first = frame?;
                out.clear();
                let mut batch = vec![first];
                while batch.len() < 256 {
                    match driver.tx.try_recv() {
                        Ok(frame) => batch.push(frame),
                        Err(_) => break,
                    }
                }
                let mut written = Vec::with_capacity(batch.len());
                for frame in batch {
                    if write_send(&mut out, &frame).is_ok() {
                        written.push(frame);
                    } else {
                        BusCounters::bump(&driver.counters.tx_errors);
                    }
                }
                if let Err(err) = writer.write_all(&out).await {
                    return Some(format!("write failed: {err}"));
                }
                for frame in &written {
                    driver.sent(*frame);
                }
            },
            _ = tokio::time::sleep_until(probe_at) => {
                if probed {
                    return Some(format!("no answer from the server for {:?}", config.dead_after));
                }
                probed = true;
                out.clear();
                write_command(&mut out, &Command::Echo);
                if let Err(err) = writer.write_all(&out).await {
                    return Some(format!("write failed: {err}"));
                }
            },
        }
    }
}

fn handle_token(driver: &DriverSide, token: Token) {
    match token {
        Token::Message(text) => match parse_server_message(&text) {
            Ok(ServerMessage::Frame(frame, _server_time)) => {
                // Timestamps are taken here, on candeck's clock, so that frames
                // of different buses compare; the server's clock may be off.
                driver.received(frame, Timestamp::now());
                // socketcand forwards only the class of an error frame, so
                // bus-off and its recovery are what can be told from it.
                if let Some(status) = bus_state_after_error(&frame, driver.state()) {
                    driver.set_status(status);
                }
            }
            Ok(ServerMessage::Echo | ServerMessage::Ok | ServerMessage::Hi) => {}
            Ok(ServerMessage::Error(detail)) => {
                tracing::warn!("socketcand: server reported: {detail}");
                BusCounters::bump(&driver.counters.tx_errors);
            }
            Ok(ServerMessage::Other(text)) => tracing::debug!("socketcand: ignored '< {text} >'"),
            Err(err) => {
                BusCounters::bump(&driver.counters.malformed);
                tracing::warn!("socketcand: malformed message '< {text} >': {err}");
            }
        },
        other => {
            BusCounters::bump(&driver.counters.malformed);
            tracing::warn!("socketcand: malformed input from server: {other:?}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spec_names_host_port_and_channel() {
        assert_eq!(
            ClientConfig::new("10.0.0.2", 29536, "can1").spec(),
            "socketcand:10.0.0.2:29536/can1"
        );
    }
}
