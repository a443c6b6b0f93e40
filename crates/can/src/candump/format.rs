//! The log format: a line parsed (with an error that names the file, the
//! line and what is wrong with it) and a frame written as a line.

use std::fmt;
use std::io::{self, BufRead, Read};
use std::path::{Path, PathBuf};

use socketcan_rs::dump::{CanDumpRecord, ParseError, Reader};
use socketcan_rs::id::CAN_ERR_FLAG;
use socketcan_rs::{CanAnyFrame, CanDataFrame};
use tokio::io::{AsyncWrite, AsyncWriteExt};

use crate::frame::{EXTENDED_ID_MAX, FD_MAX_LEN, Frame, STANDARD_ID_MAX, TimedFrame, Timestamp};
use crate::socketcan::{from_socketcan, to_socketcan};

/// Longest line read, the `socketcan` crate's own limit. A 64-byte FD frame
/// takes about 170 bytes.
pub const MAX_LINE: usize = 64 * 1024;

/// One line of a candump log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LoggedFrame {
    pub timestamp: Timestamp,
    /// The interface the frame was logged on (`can0`, ...).
    pub iface: String,
    pub frame: Frame,
}

impl LoggedFrame {
    fn record(&self) -> CanDumpRecord {
        CanDumpRecord {
            t_us: self.timestamp.as_micros(),
            device: self.iface.clone(),
            frame: to_socketcan(&self.frame),
            direction: None,
        }
    }
}

impl fmt::Display for LoggedFrame {
    /// The log line, without its newline.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.record().fmt(f)
    }
}

/// Why a log could not be read.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    #[error("cannot read {}: {source}", .path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: io::Error,
    },
    /// `line` counts from 1.
    #[error("{}:{line}: {problem}", .path.display())]
    Line {
        path: PathBuf,
        line: usize,
        problem: String,
    },
}

/// Reads a whole candump `-L` log. Blank lines are skipped; anything else
/// that is not a frame is an error naming the line.
pub fn read_log(path: impl AsRef<Path>) -> Result<Vec<LoggedFrame>, LogError> {
    let path = path.as_ref();
    let file = std::fs::File::open(path).map_err(|source| LogError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    read_log_from(io::BufReader::new(file), path)
}

/// Reads a candump `-L` log from `input`; `path` names it in errors.
pub fn read_log_from(mut input: impl BufRead, path: &Path) -> Result<Vec<LoggedFrame>, LogError> {
    let mut frames = Vec::new();
    let mut buf = Vec::new();
    let mut line = 0;
    loop {
        buf.clear();
        // One byte over the limit tells a line of exactly the limit from a
        // longer one, without ever holding more than that in memory.
        let read = (&mut input)
            .take(MAX_LINE as u64 + 1)
            .read_until(b'\n', &mut buf)
            .map_err(|source| LogError::Read {
                path: path.to_path_buf(),
                source,
            })?;
        if read == 0 {
            return Ok(frames);
        }
        line += 1;
        let fail = |problem: String| LogError::Line {
            path: path.to_path_buf(),
            line,
            problem,
        };
        let content = buf.strip_suffix(b"\n").unwrap_or(&buf);
        if content.len() > MAX_LINE {
            return Err(fail(format!("line is longer than {} KiB", MAX_LINE / 1024)));
        }
        let text = std::str::from_utf8(content)
            .map_err(|_| fail("line is not UTF-8 text".to_string()))?
            .trim();
        if text.is_empty() {
            continue;
        }
        frames.push(parse_line(text).map_err(fail)?);
    }
}

/// One non-blank line, trimmed.
pub(super) fn parse_line(text: &str) -> Result<LoggedFrame, String> {
    let record = match Reader::from_reader(text.as_bytes()).next_record() {
        Ok(Some(record)) => record,
        Ok(None) => return Err("line is empty".to_string()),
        Err(err) => return Err(explain(text, err)),
    };
    let frame = from_socketcan(&record.frame)
        .map_err(|err| format!("frame `{}`: {err}", excerpt(field(text, 2))))?;
    Ok(LoggedFrame {
        timestamp: Timestamp::from_micros(record.t_us),
        iface: record.device,
        frame,
    })
}

/// The `index`th space-separated field, as the `socketcan` parser splits.
pub(super) fn field(text: &str, index: usize) -> &str {
    text.split(' ').nth(index).unwrap_or("")
}

/// At most 40 characters of `text`, for error messages.
pub(super) fn excerpt(text: &str) -> String {
    const LIMIT: usize = 40;
    if text.chars().count() <= LIMIT {
        text.to_string()
    } else {
        format!("{}...", text.chars().take(LIMIT).collect::<String>())
    }
}

/// What the `socketcan` parser's terse error means for this line.
pub(super) fn explain(text: &str, err: ParseError) -> String {
    match err {
        ParseError::UnexpectedEndOfLine => format!(
            "line ends early: expected `(SECONDS.MICROSECONDS) INTERFACE FRAME`, found `{}`",
            excerpt(text)
        ),
        ParseError::InvalidTimestamp => format!(
            "timestamp `{}` is not `(SECONDS.MICROSECONDS)` with six digits after the point",
            excerpt(field(text, 0))
        ),
        ParseError::InvalidDeviceName => {
            format!("interface name `{}` is not valid", excerpt(field(text, 1)))
        }
        ParseError::InvalidCanFrame => explain_frame(field(text, 2)),
        ParseError::InvalidFrameDirection => format!(
            "`{}` after the frame is not a direction (`R` or `T`)",
            excerpt(field(text, 3))
        ),
        ParseError::ConstructionError(err) => {
            format!("frame `{}` cannot be built: {err}", excerpt(field(text, 2)))
        }
        ParseError::Io(err) => err.to_string(),
    }
}

/// Says what is wrong with a frame field the parser rejected.
pub(super) fn explain_frame(frame: &str) -> String {
    frame_problem(frame).unwrap_or_else(|| format!("frame `{}` is not valid", excerpt(frame)))
}

pub(super) fn frame_problem(frame: &str) -> Option<String> {
    let Some((id, body)) = frame.split_once('#') else {
        return Some(format!(
            "frame `{}` has no `#` between identifier and data",
            excerpt(frame)
        ));
    };
    if id.is_empty() || !id.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Some(format!("identifier `{}` is not hexadecimal", excerpt(id)));
    }
    if id.len() != 3 && id.len() != 8 {
        return Some(format!(
            "identifier `{id}` has {} hex digits; candump writes 3 (standard) or 8 (extended)",
            id.len()
        ));
    }
    let raw = u32::from_str_radix(id, 16).ok()?;
    let is_error = raw & CAN_ERR_FLAG != 0;
    if !is_error && id.len() == 3 && raw > u32::from(STANDARD_ID_MAX) {
        return Some(format!(
            "standard identifier 0x{raw:03X} is above 0x7FF (write it with 8 digits if it is extended)"
        ));
    }
    if !is_error && raw > EXTENDED_ID_MAX {
        return Some(format!(
            "extended identifier 0x{raw:08X} is above 0x1FFFFFFF"
        ));
    }
    if let Some(fd) = body.strip_prefix('#') {
        if is_error {
            return Some("an error frame cannot be a CAN FD frame".to_string());
        }
        let mut chars = fd.chars();
        if !chars.next().is_some_and(|c| c.is_ascii_hexdigit()) {
            return Some(format!(
                "CAN FD frame `{}` lacks the flags digit after `##`",
                excerpt(frame)
            ));
        }
        return data_problem(chars.as_str(), FD_MAX_LEN, "a CAN FD frame");
    }
    if !is_error && let Some(dlc) = body.strip_prefix('R') {
        return Some(match u8::from_str_radix(dlc, 16) {
            Ok(dlc) if dlc > 8 => format!("a remote frame requests at most 8 bytes, not {dlc}"),
            _ => format!(
                "remote frame length `{}` is not one hex digit",
                excerpt(dlc)
            ),
        });
    }
    if body.contains('_') {
        return Some("the `_DLC` suffix (a raw DLC above 8) is not supported".to_string());
    }
    let what = if is_error {
        "an error frame"
    } else {
        "a classic CAN frame"
    };
    data_problem(body, 8, what)
}

pub(super) fn data_problem(hex: &str, max: usize, what: &str) -> Option<String> {
    if !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Some(format!("data `{}` is not hexadecimal", excerpt(hex)));
    }
    if !hex.len().is_multiple_of(2) {
        return Some(format!(
            "data `{}` has an odd number of hex digits",
            excerpt(hex)
        ));
    }
    let len = hex.len() / 2;
    (len > max).then(|| format!("{what} carries at most {max} data bytes, not {len}"))
}

/// Writes frames as candump `-L` lines. Unbuffered: wrap `out` in a
/// [`BufWriter`](tokio::io::BufWriter) and [`flush`](Self::flush) when a batch is written.
pub struct LogWriter<W> {
    out: W,
    /// Reused for every line, so writing allocates nothing per frame.
    record: CanDumpRecord,
    line: String,
}

impl<W: AsyncWrite + Unpin> LogWriter<W> {
    /// Lines name `iface` as the interface. White space in it would make
    /// the lines unreadable, so it is written as `_`.
    pub fn new(out: W, iface: &str) -> Self {
        let mut device: String = iface
            .chars()
            .map(|c| if c.is_whitespace() { '_' } else { c })
            .collect();
        if device.is_empty() {
            device = "can".to_string();
        }
        Self {
            out,
            record: CanDumpRecord {
                t_us: 0,
                device,
                // Replaced before every line.
                frame: CanAnyFrame::Normal(CanDataFrame::default()),
                direction: None,
            },
            line: String::new(),
        }
    }

    /// Writes one line; returns its length in bytes (newline included).
    pub async fn write(&mut self, frame: &TimedFrame) -> io::Result<usize> {
        use fmt::Write as _;
        self.record.t_us = frame.timestamp.as_micros();
        self.record.frame = to_socketcan(&frame.frame);
        self.line.clear();
        // Writing to a String cannot fail.
        let _ = writeln!(self.line, "{}", self.record);
        self.out.write_all(self.line.as_bytes()).await?;
        Ok(self.line.len())
    }

    pub async fn flush(&mut self) -> io::Result<()> {
        self.out.flush().await
    }

    pub fn into_inner(self) -> W {
        self.out
    }
}
