//! The socketcand line protocol, without I/O (linux-can/socketcand
//! `doc/protocol.md`, modes NO_BUS, BCM and RAW; byte formats as
//! `src/state_raw.c` writes them).
//!
//! Every message is an ASCII text between `<` and `>`; there is no line
//! separator. [`Framer`] cuts a byte stream into messages and reports what is
//! not one. The rest parses and writes the two directions:
//!
//! | direction | messages |
//! |---|---|
//! | client → server | `open CH`, `rawmode`, `bcmmode`, `echo`, `send ID DLC B0..`, `sendrtr ID DLC`, `fdsend ID FLAGS LEN B0..` |
//! | server → client | `hi`, `ok`, `echo`, `frame ID SECS.USECS HEX`, `fdframe ID FLAGS SECS.USECS HEX`, `frame ID SECS.USECS  rtr DLC` (a remote frame: python-can reads a frame without data), `error CLASS SECS.USECS` (error frame), `error TEXT`; `rtr ID SECS.USECS DLC` is read too |
//!
//! Identifiers are written with three hex digits (standard) or eight
//! (extended); the width, not the value, says which (python-can and
//! socketcand both decide by width).

use std::fmt;

use crate::frame::{CanId, FD_MAX_LEN, FdFlags, Frame, FrameError, FrameKind, Timestamp};

/// Longest message accepted, in bytes between `<` and `>`. An `fdsend` of 64
/// bytes needs about 230.
pub const DEFAULT_MAX_MESSAGE: usize = 512;

/// A piece of the byte stream.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Token {
    /// The text between `<` and `>`, trimmed.
    Message(String),
    /// Bytes outside any `< >` that are not white space.
    Garbage { bytes: usize },
    /// A message longer than the limit; it was skipped up to its `>`.
    Oversized { bytes: usize },
    /// A message cut short by a new `<`; what it had so far.
    Truncated(String),
    /// A message with bytes that are not printable ASCII; it was skipped.
    NotAscii,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FramerState {
    /// Between messages.
    Idle,
    /// After `<`.
    InMessage,
    /// Inside a message that is too long or not ASCII, up to its `>`.
    Skipping { oversized: bool },
}

/// Cuts a byte stream into [`Token`]s. Memory is bounded by the message
/// limit whatever the input.
#[derive(Debug)]
pub struct Framer {
    state: FramerState,
    message: Vec<u8>,
    garbage: usize,
    skipped: usize,
    max_message: usize,
}

impl Default for Framer {
    fn default() -> Self {
        Self::new(DEFAULT_MAX_MESSAGE)
    }
}

impl Framer {
    pub fn new(max_message: usize) -> Self {
        Self {
            state: FramerState::Idle,
            message: Vec::with_capacity(64),
            garbage: 0,
            skipped: 0,
            max_message,
        }
    }

    /// Feeds bytes; complete tokens are appended to `out`. Garbage is
    /// reported once per run, at the next `<` or at the end of `bytes`, so a
    /// client typing junk gets an answer without sending anything more.
    pub fn push(&mut self, bytes: &[u8], out: &mut Vec<Token>) {
        for &byte in bytes {
            match self.state {
                FramerState::Idle => match byte {
                    b'<' => {
                        self.flush_garbage(out);
                        self.start_message();
                    }
                    _ if self.garbage == 0 && byte.is_ascii_whitespace() => {}
                    _ => self.garbage += 1,
                },
                FramerState::InMessage => match byte {
                    b'>' => {
                        let text = self.take_message();
                        out.push(Token::Message(text));
                        self.state = FramerState::Idle;
                    }
                    b'<' => {
                        let text = self.take_message();
                        out.push(Token::Truncated(text));
                        self.start_message();
                    }
                    _ if !(byte.is_ascii_graphic() || byte == b' ' || byte == b'\t') => {
                        self.skip(false);
                    }
                    _ if self.message.len() >= self.max_message => self.skip(true),
                    _ => self.message.push(byte),
                },
                FramerState::Skipping { oversized } => {
                    self.skipped += 1;
                    if byte == b'>' {
                        out.push(if oversized {
                            Token::Oversized {
                                bytes: self.skipped,
                            }
                        } else {
                            Token::NotAscii
                        });
                        self.state = FramerState::Idle;
                    }
                }
            }
        }
        self.flush_garbage(out);
    }

    fn start_message(&mut self) {
        self.message.clear();
        self.state = FramerState::InMessage;
    }

    fn take_message(&mut self) -> String {
        let text = String::from_utf8_lossy(&self.message).trim().to_string();
        self.message.clear();
        text
    }

    fn skip(&mut self, oversized: bool) {
        self.skipped = self.message.len() + 2;
        self.message.clear();
        self.state = FramerState::Skipping { oversized };
    }

    fn flush_garbage(&mut self, out: &mut Vec<Token>) {
        if self.garbage > 0 {
            out.push(Token::Garbage {
                bytes: self.garbage,
            });
            self.garbage = 0;
        }
    }

    /// Bytes held for an unfinished message.
    pub fn pending(&self) -> usize {
        self.message.len()
    }
}

/// What is wrong with a message.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    #[error("empty message")]
    Empty,
    #[error("unknown command '{0}'")]
    UnknownCommand(String),
    #[error("{command}: {problem}")]
    Syntax {
        command: &'static str,
        problem: String,
    },
    #[error("{0}")]
    Frame(#[from] FrameError),
}

fn syntax(command: &'static str, problem: impl Into<String>) -> ParseError {
    ParseError::Syntax {
        command,
        problem: problem.into(),
    }
}

/// A request from a client to the server.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    /// `< open CHANNEL >`: select a bus (NO_BUS mode only).
    Open(String),
    /// `< rawmode >`: receive every frame.
    RawMode,
    /// `< bcmmode >`: leave raw mode.
    BcmMode,
    /// `< echo >`: answered with `< echo >`.
    Echo,
    /// `< send >`, `< sendrtr >` or `< fdsend >`: put a frame on the bus.
    Send(Frame),
    /// A command of socketcand's other modes (BCM jobs, control, ISO-TP)
    /// that this server does not offer.
    Unsupported(String),
}

const UNSUPPORTED: &[&str] = &[
    "add",
    "update",
    "delete",
    "filter",
    "muxfilter",
    "subscribe",
    "unsubscribe",
    "controlmode",
    "statistics",
    "isotpmode",
    "isotpconf",
    "sendpdu",
];

/// Parses the text of a client message (as [`Token::Message`] gives it).
pub fn parse_command(text: &str) -> Result<Command, ParseError> {
    let mut words = text.split_ascii_whitespace();
    let verb = words.next().ok_or(ParseError::Empty)?;
    let args: Vec<&str> = words.collect();
    match verb {
        "open" => match args.as_slice() {
            [channel] if channel.len() <= 16 => Ok(Command::Open(channel.to_string())),
            [_] => Err(syntax("open", "channel names have at most 16 characters")),
            _ => Err(syntax("open", "expected '< open CHANNEL >'")),
        },
        "rawmode" | "bcmmode" | "echo" if !args.is_empty() => Err(ParseError::Syntax {
            command: "mode",
            problem: format!("'{verb}' takes no arguments"),
        }),
        "rawmode" => Ok(Command::RawMode),
        "bcmmode" => Ok(Command::BcmMode),
        "echo" => Ok(Command::Echo),
        "send" => parse_send(&args).map(Command::Send),
        "sendrtr" => parse_sendrtr(&args).map(Command::Send),
        "fdsend" => parse_fdsend(&args).map(Command::Send),
        _ if UNSUPPORTED.contains(&verb) => Ok(Command::Unsupported(verb.to_string())),
        _ => Err(ParseError::UnknownCommand(truncate(verb, 32))),
    }
}

fn truncate(text: &str, max: usize) -> String {
    text.chars().take(max).collect()
}

/// An identifier field: eight hex digits mean extended, fewer standard.
fn parse_id(command: &'static str, word: &str) -> Result<CanId, ParseError> {
    if word.is_empty() || word.len() > 8 {
        return Err(syntax(
            command,
            format!(
                "identifier '{}' is not 1 to 8 hex digits",
                truncate(word, 12)
            ),
        ));
    }
    let raw = u32::from_str_radix(word, 16)
        .map_err(|_| syntax(command, format!("identifier '{word}' is not hex")))?;
    if word.len() == 8 {
        Ok(CanId::extended(raw)?)
    } else {
        Ok(CanId::standard(raw)?)
    }
}

fn parse_len(command: &'static str, word: &str, max: usize) -> Result<usize, ParseError> {
    word.parse::<usize>()
        .ok()
        .filter(|&len| len <= max)
        .ok_or_else(|| {
            syntax(
                command,
                format!("length '{}' is not 0 to {max}", truncate(word, 12)),
            )
        })
}

fn parse_byte(command: &'static str, word: &str) -> Result<u8, ParseError> {
    if word.is_empty() || word.len() > 2 {
        return Err(syntax(
            command,
            format!(
                "data byte '{}' is not 1 or 2 hex digits",
                truncate(word, 12)
            ),
        ));
    }
    u8::from_str_radix(word, 16)
        .map_err(|_| syntax(command, format!("data byte '{word}' is not hex")))
}

fn parse_bytes(command: &'static str, words: &[&str], len: usize) -> Result<Vec<u8>, ParseError> {
    if words.len() != len {
        return Err(syntax(
            command,
            format!("length says {len} data bytes but {} follow", words.len()),
        ));
    }
    words.iter().map(|w| parse_byte(command, w)).collect()
}

fn parse_send(args: &[&str]) -> Result<Frame, ParseError> {
    let [id, len, data @ ..] = args else {
        return Err(syntax("send", "expected '< send ID LEN B0 B1 ... >'"));
    };
    let id = parse_id("send", id)?;
    let len = parse_len("send", len, 8)?;
    let data = parse_bytes("send", data, len)?;
    Ok(Frame::new(id, &data)?)
}

fn parse_sendrtr(args: &[&str]) -> Result<Frame, ParseError> {
    let [id, len] = args else {
        return Err(syntax("sendrtr", "expected '< sendrtr ID DLC >'"));
    };
    let id = parse_id("sendrtr", id)?;
    let len = parse_len("sendrtr", len, 8)?;
    Ok(Frame::remote(id, len as u8)?)
}

fn parse_fdsend(args: &[&str]) -> Result<Frame, ParseError> {
    let [id, flags, len, data @ ..] = args else {
        return Err(syntax(
            "fdsend",
            "expected '< fdsend ID FLAGS LEN B0 B1 ... >'",
        ));
    };
    let id = parse_id("fdsend", id)?;
    let flags = parse_byte("fdsend", flags)?;
    let len = parse_len("fdsend", len, FD_MAX_LEN)?;
    let data = parse_bytes("fdsend", data, len)?;
    Ok(Frame::fd(id, &data, FdFlags::from_raw(flags))?)
}

/// A message from the server to a client.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ServerMessage {
    Hi,
    Ok,
    Echo,
    /// A frame on the bus with the server's timestamp (an error frame too).
    Frame(Frame, Timestamp),
    /// `< error TEXT >`: the server refused a command.
    Error(String),
    /// Something else (`stat`, BCM replies): not used in raw mode.
    Other(String),
}

/// Parses the text of a server message.
pub fn parse_server_message(text: &str) -> Result<ServerMessage, ParseError> {
    let mut words = text.split_ascii_whitespace();
    let verb = words.next().ok_or(ParseError::Empty)?;
    let args: Vec<&str> = words.collect();
    match verb {
        "hi" => Ok(ServerMessage::Hi),
        "ok" => Ok(ServerMessage::Ok),
        "echo" => Ok(ServerMessage::Echo),
        "frame" => parse_frame_line(&args),
        "fdframe" => parse_fdframe_line(&args),
        "rtr" => parse_rtr_line(&args),
        "error" => Ok(parse_error_line(text, &args)),
        _ => Ok(ServerMessage::Other(text.to_string())),
    }
}

/// Reading is lenient about the width: socketcand writes 3 or 8 digits, but
/// a standard value written wider is still standard.
fn parse_received_id(command: &'static str, word: &str) -> Result<CanId, ParseError> {
    let raw = u32::from_str_radix(word, 16)
        .ok()
        .filter(|_| !word.is_empty() && word.len() <= 8)
        .ok_or_else(|| {
            syntax(
                command,
                format!("identifier '{}' is not hex", truncate(word, 12)),
            )
        })?;
    if word.len() == 8 || raw > 0x7FF {
        Ok(CanId::extended(raw)?)
    } else {
        Ok(CanId::standard(raw)?)
    }
}

fn parse_timestamp(command: &'static str, word: &str) -> Result<Timestamp, ParseError> {
    let bad = || {
        syntax(
            command,
            format!("timestamp '{}' is not SECS.USECS", truncate(word, 24)),
        )
    };
    let (secs, micros) = word.split_once('.').ok_or_else(bad)?;
    if secs.is_empty() || micros.is_empty() || micros.len() > 6 {
        return Err(bad());
    }
    let secs: u64 = secs.parse().map_err(|_| bad())?;
    let digits: u64 = micros.parse().map_err(|_| bad())?;
    let micros = digits * 10u64.pow(6 - micros.len() as u32);
    secs.checked_mul(1_000_000)
        .and_then(|s| s.checked_add(micros))
        .map(Timestamp)
        .ok_or_else(bad)
}

/// Data is written as one hex run (socketcand) or as spaced bytes (the
/// protocol document's example); both are read.
fn parse_hex_data(
    command: &'static str,
    words: &[&str],
    max: usize,
) -> Result<Vec<u8>, ParseError> {
    let mut data = Vec::with_capacity(8);
    for word in words {
        if word.len() % 2 != 0 {
            return Err(syntax(
                command,
                format!(
                    "data '{}' has an odd number of hex digits",
                    truncate(word, 24)
                ),
            ));
        }
        for pair in word.as_bytes().chunks(2) {
            let text = std::str::from_utf8(pair).map_err(|_| syntax(command, "data is not hex"))?;
            let byte = u8::from_str_radix(text, 16).map_err(|_| {
                syntax(command, format!("data '{}' is not hex", truncate(word, 24)))
            })?;
            data.push(byte);
        }
        if data.len() > max {
            return Err(syntax(command, format!("more than {max} data bytes")));
        }
    }
    Ok(data)
}

fn parse_frame_line(args: &[&str]) -> Result<ServerMessage, ParseError> {
    let [id, ts, data @ ..] = args else {
        return Err(syntax("frame", "expected '< frame ID SECS.USECS DATA >'"));
    };
    let id = parse_received_id("frame", id)?;
    let ts = parse_timestamp("frame", ts)?;
    if let ["rtr", dlc] = data {
        let dlc = parse_len("frame", dlc, 8)?;
        return Ok(ServerMessage::Frame(Frame::remote(id, dlc as u8)?, ts));
    }
    let data = parse_hex_data("frame", data, 8)?;
    Ok(ServerMessage::Frame(Frame::new(id, &data)?, ts))
}

fn parse_fdframe_line(args: &[&str]) -> Result<ServerMessage, ParseError> {
    let [id, flags, ts, data @ ..] = args else {
        return Err(syntax(
            "fdframe",
            "expected '< fdframe ID FLAGS SECS.USECS DATA >'",
        ));
    };
    let id = parse_received_id("fdframe", id)?;
    let flags = parse_byte("fdframe", flags)?;
    let ts = parse_timestamp("fdframe", ts)?;
    let data = parse_hex_data("fdframe", data, FD_MAX_LEN)?;
    Ok(ServerMessage::Frame(
        Frame::fd(id, &data, FdFlags::from_raw(flags))?,
        ts,
    ))
}

fn parse_rtr_line(args: &[&str]) -> Result<ServerMessage, ParseError> {
    let [id, ts, dlc] = args else {
        return Err(syntax("rtr", "expected '< rtr ID SECS.USECS DLC >'"));
    };
    let id = parse_received_id("rtr", id)?;
    let ts = parse_timestamp("rtr", ts)?;
    let dlc = parse_len("rtr", dlc, 8)?;
    Ok(ServerMessage::Frame(Frame::remote(id, dlc as u8)?, ts))
}

/// `< error CLASS SECS.USECS >` is an error frame; any other `< error ... >`
/// is the server refusing something.
fn parse_error_line(text: &str, args: &[&str]) -> ServerMessage {
    if let [class, ts] = args
        && let Ok(class) = u32::from_str_radix(class, 16)
        && let Ok(ts) = parse_timestamp("error", ts)
        && let Ok(frame) = Frame::error(class & 0x1FFF_FFFF, [0; 8])
    {
        return ServerMessage::Frame(frame, ts);
    }
    let detail = text.strip_prefix("error").unwrap_or(text).trim();
    ServerMessage::Error(detail.to_string())
}

const HEX: &[u8; 16] = b"0123456789ABCDEF";

fn push_hex_byte(out: &mut Vec<u8>, byte: u8) {
    out.push(HEX[usize::from(byte >> 4)]);
    out.push(HEX[usize::from(byte & 0xF)]);
}

fn push_id(out: &mut Vec<u8>, id: CanId) {
    let (raw, digits) = match id {
        CanId::Standard(raw) => (u32::from(raw), 3),
        CanId::Extended(raw) => (raw, 8),
    };
    for shift in (0..digits).rev() {
        out.push(HEX[((raw >> (shift * 4)) & 0xF) as usize]);
    }
}

fn push_decimal(out: &mut Vec<u8>, value: u64) {
    out.extend_from_slice(value.to_string().as_bytes());
}

fn push_timestamp(out: &mut Vec<u8>, ts: Timestamp) {
    push_decimal(out, ts.secs());
    out.push(b'.');
    let micros = ts.subsec_micros();
    for divisor in [100_000, 10_000, 1_000, 100, 10, 1] {
        out.push(b'0' + ((micros / divisor) % 10) as u8);
    }
}

/// Appends the server's message for a frame on the bus, byte for byte as
/// socketcand writes it: `< frame 123 1700000000.123456 1122 >` (data as one
/// hex run, two spaces when empty), `< fdframe ID FLAGS TS DATA >`,
/// `< frame ID TS  rtr DLC >` (a remote frame), `< error CLASS TS >`.
pub fn write_frame(out: &mut Vec<u8>, frame: &Frame, ts: Timestamp) {
    match frame.kind() {
        FrameKind::Data | FrameKind::Fd(_) => {
            if let FrameKind::Fd(flags) = frame.kind() {
                out.extend_from_slice(b"< fdframe ");
                push_id(out, frame.id());
                out.push(b' ');
                push_hex_byte(out, flags.raw());
            } else {
                out.extend_from_slice(b"< frame ");
                push_id(out, frame.id());
            }
            out.push(b' ');
            push_timestamp(out, ts);
            out.push(b' ');
            for &byte in frame.data() {
                push_hex_byte(out, byte);
            }
            out.extend_from_slice(b" >");
        }
        // socketcand has no form for a remote frame (it forwards none).
        // This one is a `frame` line with no data, which python-can reads
        // as such without a warning (it splits at most three fields and
        // ignores the rest), followed by `rtr DLC`, which candeck reads.
        FrameKind::Remote => {
            out.extend_from_slice(b"< frame ");
            push_id(out, frame.id());
            out.push(b' ');
            push_timestamp(out, ts);
            out.extend_from_slice(b"  rtr ");
            push_decimal(out, u64::from(frame.dlc()));
            out.extend_from_slice(b" >");
        }
        FrameKind::Error => {
            out.extend_from_slice(b"< error ");
            let class = frame.id().raw();
            let text = format!("{class:03X}");
            out.extend_from_slice(text.as_bytes());
            out.push(b' ');
            push_timestamp(out, ts);
            out.extend_from_slice(b" >");
        }
    }
}

/// Why a frame cannot be sent through socketcand.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("socketcand cannot send error frames")]
pub struct CannotSendErrorFrame;

/// Appends the client's command that sends `frame`: `< send ID LEN B0 .. >`
/// (bytes as two hex digits, length in decimal as socketcand reads it),
/// `< sendrtr ID DLC >` or `< fdsend ID FLAGS LEN B0 .. >`.
pub fn write_send(out: &mut Vec<u8>, frame: &Frame) -> Result<(), CannotSendErrorFrame> {
    match frame.kind() {
        FrameKind::Error => return Err(CannotSendErrorFrame),
        FrameKind::Remote => {
            out.extend_from_slice(b"< sendrtr ");
            push_id(out, frame.id());
            out.push(b' ');
            push_decimal(out, u64::from(frame.dlc()));
        }
        FrameKind::Data | FrameKind::Fd(_) => {
            if let FrameKind::Fd(flags) = frame.kind() {
                out.extend_from_slice(b"< fdsend ");
                push_id(out, frame.id());
                out.push(b' ');
                push_hex_byte(out, flags.raw());
            } else {
                out.extend_from_slice(b"< send ");
                push_id(out, frame.id());
            }
            out.push(b' ');
            push_decimal(out, frame.data().len() as u64);
            for &byte in frame.data() {
                out.push(b' ');
                push_hex_byte(out, byte);
            }
        }
    }
    out.extend_from_slice(b" >");
    Ok(())
}

/// A reply of the server that is not a frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reply {
    Hi,
    Ok,
    Echo,
    Error(String),
}

impl fmt::Display for Reply {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Hi => f.write_str("< hi >"),
            Self::Ok => f.write_str("< ok >"),
            Self::Echo => f.write_str("< echo >"),
            // The text must not end the message early or open another one.
            Self::Error(text) => {
                let clean: String = text
                    .chars()
                    .map(|c| match c {
                        '<' | '>' => '\'',
                        c if c.is_ascii_graphic() || c == ' ' => c,
                        _ => '?',
                    })
                    .collect();
                write!(f, "< error {clean} >")
            }
        }
    }
}

/// Appends a client command that has no frame (`open`, `rawmode`, `echo`).
pub fn write_command(out: &mut Vec<u8>, command: &Command) {
    match command {
        Command::Open(channel) => {
            out.extend_from_slice(b"< open ");
            out.extend_from_slice(channel.as_bytes());
            out.extend_from_slice(b" >");
        }
        Command::RawMode => out.extend_from_slice(b"< rawmode >"),
        Command::BcmMode => out.extend_from_slice(b"< bcmmode >"),
        Command::Echo => out.extend_from_slice(b"< echo >"),
        Command::Send(frame) => {
            // An error frame has no send command; the caller checks first.
            let _ = write_send(out, frame);
        }
        Command::Unsupported(verb) => {
            out.extend_from_slice(b"< ");
            out.extend_from_slice(verb.as_bytes());
            out.extend_from_slice(b" >");
        }
    }
}

#[cfg(test)]
mod tests;
