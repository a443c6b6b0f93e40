//! The SDO frame formats (CiA 301 §7.2.4.3): what each of the eight data
//! bytes of a request or a response means, decoded into [`Request`],
//! [`Response`] and [`BlockSegment`] and encoded back, byte for byte.
//!
//! The first byte carries the command specifier in bits 7–5 (`ccs` from the
//! client, `scs` from the server) and the protocol's flags below it; bytes
//! 1–3 are the multiplexer (index little-endian, sub-index) where a frame has
//! one. The segments inside a block carry no command specifier at all, so
//! only the state of a transfer tells a [`BlockSegment`] from a command: the
//! machines decode them apart.
//!
//! Decoding ignores reserved bits, as CiA 301 asks of receivers; encoding
//! writes them as 0.

use std::fmt;

use super::AbortCode;

/// Data bytes of every SDO frame.
pub const FRAME_LEN: usize = 8;
/// Data bytes of one segment (segmented and block transfers).
pub const SEGMENT_LEN: usize = 7;
/// Largest block size (segments per block) and sequence number.
pub const MAX_BLOCK_SIZE: u8 = 127;

/// Bit 0x80 of a block segment: no more segments follow (`c`).
const LAST_SEGMENT: u8 = 0x80;
/// Bit 0x10 of a segment command: the toggle bit (`t`).
const TOGGLE: u8 = 0x10;

/// The client command specifier (`ccs`): bits 7–5 of a request's first byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ClientCommand {
    /// 0: download segment.
    DownloadSegment,
    /// 1: initiate download.
    InitiateDownload,
    /// 2: initiate upload.
    InitiateUpload,
    /// 3: upload segment.
    UploadSegment,
    /// 4: abort transfer.
    Abort,
    /// 5: block upload (initiate, start, block acknowledge, end: bits 1–0).
    BlockUpload,
    /// 6: block download (initiate, end: bit 0).
    BlockDownload,
    /// Any other value (7): CiA 301 defines none.
    Unknown(u8),
}

impl ClientCommand {
    /// Reads the 3-bit specifier (0–7).
    pub fn from_raw(raw: u8) -> Self {
        match raw {
            0 => Self::DownloadSegment,
            1 => Self::InitiateDownload,
            2 => Self::InitiateUpload,
            3 => Self::UploadSegment,
            4 => Self::Abort,
            5 => Self::BlockUpload,
            6 => Self::BlockDownload,
            other => Self::Unknown(other),
        }
    }

    /// The 3-bit specifier.
    pub fn raw(self) -> u8 {
        match self {
            Self::DownloadSegment => 0,
            Self::InitiateDownload => 1,
            Self::InitiateUpload => 2,
            Self::UploadSegment => 3,
            Self::Abort => 4,
            Self::BlockUpload => 5,
            Self::BlockDownload => 6,
            Self::Unknown(raw) => raw,
        }
    }

    /// The specifier in a request's first byte.
    pub fn of(first_byte: u8) -> Self {
        Self::from_raw(first_byte >> 5)
    }
}

/// The server command specifier (`scs`): bits 7–5 of a response's first byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ServerCommand {
    /// 0: upload segment.
    UploadSegment,
    /// 1: download segment.
    DownloadSegment,
    /// 2: initiate upload.
    InitiateUpload,
    /// 3: initiate download.
    InitiateDownload,
    /// 4: abort transfer.
    Abort,
    /// 5: block download (initiate, end, block acknowledge: bits 1–0).
    BlockDownload,
    /// 6: block upload (initiate, end: bit 0).
    BlockUpload,
    /// Any other value (7): CiA 301 defines none.
    Unknown(u8),
}

impl ServerCommand {
    /// Reads the 3-bit specifier (0–7).
    pub fn from_raw(raw: u8) -> Self {
        match raw {
            0 => Self::UploadSegment,
            1 => Self::DownloadSegment,
            2 => Self::InitiateUpload,
            3 => Self::InitiateDownload,
            4 => Self::Abort,
            5 => Self::BlockDownload,
            6 => Self::BlockUpload,
            other => Self::Unknown(other),
        }
    }

    /// The 3-bit specifier.
    pub fn raw(self) -> u8 {
        match self {
            Self::UploadSegment => 0,
            Self::DownloadSegment => 1,
            Self::InitiateUpload => 2,
            Self::InitiateDownload => 3,
            Self::Abort => 4,
            Self::BlockDownload => 5,
            Self::BlockUpload => 6,
            Self::Unknown(raw) => raw,
        }
    }

    /// The specifier in a response's first byte.
    pub fn of(first_byte: u8) -> Self {
        Self::from_raw(first_byte >> 5)
    }
}

/// Why eight bytes are not a valid SDO frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    #[error("an SDO frame has 8 data bytes, this one has {0}")]
    Length(usize),
    #[error("command byte 0x{0:02X} is no SDO command")]
    Command(u8),
}

/// Up to 7 data bytes of one segment.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Chunk {
    bytes: [u8; SEGMENT_LEN],
    len: u8,
}

impl Chunk {
    /// The first 7 bytes of `data` (all of it if shorter).
    pub fn new(data: &[u8]) -> Self {
        let len = data.len().min(SEGMENT_LEN);
        let mut bytes = [0; SEGMENT_LEN];
        bytes[..len].copy_from_slice(&data[..len]);
        Self {
            bytes,
            len: len as u8,
        }
    }

    pub fn as_slice(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len)]
    }

    pub fn len(&self) -> usize {
        usize::from(self.len)
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// `n` of a segment command: the bytes that carry no data.
    fn unused(&self) -> u8 {
        SEGMENT_LEN as u8 - self.len
    }
}

impl fmt::Debug for Chunk {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Chunk({:02X?})", self.as_slice())
    }
}

/// What the initiate frame of a download (request) or an upload (response)
/// carries: the value itself, or the announcement of segments.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Initiate {
    /// `e` = 1: the value is in bytes 4–7. `len` is 1–4 when the size is
    /// indicated (`s` = 1, `n` = 4 − len), `None` when it is not: then the
    /// receiver decides how many of the four bytes count.
    Expedited { data: [u8; 4], len: Option<u8> },
    /// `e` = 0: segments follow; `size` (bytes 4–7) when `s` = 1.
    Segmented { size: Option<u32> },
}

impl Initiate {
    /// An expedited transfer of `value`, size indicated. Only 1–4 bytes fit:
    /// more are cut, and an empty value reads as one zero byte, since `n`
    /// cannot say "none" (empty values go segmented).
    pub fn expedited(value: &[u8]) -> Self {
        let len = value.len().clamp(1, 4);
        let mut data = [0; 4];
        data[..value.len().min(4)].copy_from_slice(&value[..value.len().min(4)]);
        Self::Expedited {
            data,
            len: Some(len as u8),
        }
    }

    /// The flag bits 3–0 (`n`, `e`, `s`) and bytes 4–7.
    fn encode(self) -> (u8, [u8; 4]) {
        match self {
            Self::Expedited {
                data,
                len: Some(len),
            } => ((4 - len.clamp(1, 4)) << 2 | 0b11, data),
            Self::Expedited { data, len: None } => (0b10, data),
            Self::Segmented { size: Some(size) } => (0b01, size.to_le_bytes()),
            Self::Segmented { size: None } => (0b00, [0; 4]),
        }
    }

    fn decode(command: u8, data: [u8; 4]) -> Self {
        let expedited = command & 0b10 != 0;
        let size_indicated = command & 0b01 != 0;
        match (expedited, size_indicated) {
            (true, true) => Self::Expedited {
                data,
                len: Some(4 - (command >> 2 & 0b11)),
            },
            (true, false) => Self::Expedited { data, len: None },
            (false, true) => Self::Segmented {
                size: Some(u32::from_le_bytes(data)),
            },
            (false, false) => Self::Segmented { size: None },
        }
    }
}

/// A frame from client to server, outside the segments of a block.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Request {
    /// ccs 1: write `index`:`sub`, expedited or announcing segments.
    InitiateDownload { index: u16, sub: u8, data: Initiate },
    /// ccs 0: one segment of a segmented download; `last` is `c`.
    DownloadSegment {
        toggle: bool,
        chunk: Chunk,
        last: bool,
    },
    /// ccs 2: read `index`:`sub`.
    InitiateUpload { index: u16, sub: u8 },
    /// ccs 3: ask for the next segment of a segmented upload.
    UploadSegment { toggle: bool },
    /// ccs 4: the client ends the transfer.
    Abort {
        index: u16,
        sub: u8,
        code: AbortCode,
    },
    /// ccs 6, cs 0: write `index`:`sub` by block download; `crc` is `cc`.
    InitiateBlockDownload {
        index: u16,
        sub: u8,
        crc: bool,
        size: Option<u32>,
    },
    /// ccs 6, cs 1: `unused` (`n`) bytes of the last segment carried no data;
    /// `crc` of all the data, meaningful when both sides support it.
    EndBlockDownload { unused: u8, crc: u16 },
    /// ccs 5, cs 0: read `index`:`sub` by block upload, `block_size`
    /// segments per block; the server may answer with a plain upload if the
    /// value has at most `switch_threshold` bytes (`pst`, 0: it may not).
    InitiateBlockUpload {
        index: u16,
        sub: u8,
        crc: bool,
        block_size: u8,
        switch_threshold: u8,
    },
    /// ccs 5, cs 3: start sending the first block.
    StartBlockUpload,
    /// ccs 5, cs 2: segments 1–`ackseq` of the block arrived; next blocks
    /// have `block_size` segments.
    BlockUploadAck { ackseq: u8, block_size: u8 },
    /// ccs 5, cs 1: the client has the end frame; the transfer is over.
    EndBlockUpload,
}

/// A frame from server to client, outside the segments of a block.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Response {
    /// scs 2: the value of `index`:`sub`, expedited or announcing segments.
    InitiateUpload { index: u16, sub: u8, data: Initiate },
    /// scs 0: one segment of a segmented upload; `last` is `c`.
    UploadSegment {
        toggle: bool,
        chunk: Chunk,
        last: bool,
    },
    /// scs 3: the download of `index`:`sub` is accepted (or, expedited, done).
    InitiateDownload { index: u16, sub: u8 },
    /// scs 1: the download segment arrived.
    DownloadSegment { toggle: bool },
    /// scs 4: the server ends the transfer.
    Abort {
        index: u16,
        sub: u8,
        code: AbortCode,
    },
    /// scs 5, ss 0: the block download may start, `block_size` segments per
    /// block; `crc` is `sc`.
    InitiateBlockDownload {
        index: u16,
        sub: u8,
        crc: bool,
        block_size: u8,
    },
    /// scs 5, ss 2: segments 1–`ackseq` arrived; next blocks have
    /// `block_size` segments.
    BlockDownloadAck { ackseq: u8, block_size: u8 },
    /// scs 5, ss 1: the block download is done.
    EndBlockDownload,
    /// scs 6, ss 0: the block upload may start; `crc` is `sc`.
    InitiateBlockUpload {
        index: u16,
        sub: u8,
        crc: bool,
        size: Option<u32>,
    },
    /// scs 6, ss 1: `unused` (`n`) bytes of the last segment carried no data;
    /// `crc` of all the data.
    EndBlockUpload { unused: u8, crc: u16 },
}

/// One segment inside a block: bit 7 `c` (last), bits 6–0 the sequence number
/// (1–127), then 7 data bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct BlockSegment {
    pub seqno: u8,
    pub last: bool,
    pub data: [u8; SEGMENT_LEN],
}

fn multiplexer(data: &[u8; FRAME_LEN]) -> (u16, u8) {
    (u16::from_le_bytes([data[1], data[2]]), data[3])
}

fn with_multiplexer(command: u8, index: u16, sub: u8, tail: [u8; 4]) -> [u8; FRAME_LEN] {
    let [lo, hi] = index.to_le_bytes();
    [command, lo, hi, sub, tail[0], tail[1], tail[2], tail[3]]
}

fn tail(data: &[u8; FRAME_LEN]) -> [u8; 4] {
    [data[4], data[5], data[6], data[7]]
}

fn segment_frame(command: u8, chunk: &Chunk) -> [u8; FRAME_LEN] {
    let mut frame = [command, 0, 0, 0, 0, 0, 0, 0];
    frame[1..].copy_from_slice(&chunk.bytes);
    frame
}

fn segment_chunk(data: &[u8; FRAME_LEN], command: u8) -> Chunk {
    let unused = usize::from(command >> 1 & 0b111);
    Chunk::new(&data[1..FRAME_LEN - unused])
}

fn toggle_bit(toggle: bool) -> u8 {
    if toggle { TOGGLE } else { 0 }
}

fn exactly_eight(data: &[u8]) -> Result<&[u8; FRAME_LEN], DecodeError> {
    data.try_into().map_err(|_| DecodeError::Length(data.len()))
}

fn abort_frame(index: u16, sub: u8, code: AbortCode) -> [u8; FRAME_LEN] {
    with_multiplexer(0x80, index, sub, code.raw().to_le_bytes())
}

impl Request {
    pub fn decode(data: &[u8]) -> Result<Self, DecodeError> {
        let data = exactly_eight(data)?;
        let command = data[0];
        let (index, sub) = multiplexer(data);
        let toggle = command & TOGGLE != 0;
        Ok(match ClientCommand::of(command) {
            ClientCommand::DownloadSegment => Self::DownloadSegment {
                toggle,
                chunk: segment_chunk(data, command),
                last: command & 1 != 0,
            },
            ClientCommand::InitiateDownload => Self::InitiateDownload {
                index,
                sub,
                data: Initiate::decode(command, tail(data)),
            },
            ClientCommand::InitiateUpload => Self::InitiateUpload { index, sub },
            ClientCommand::UploadSegment => Self::UploadSegment { toggle },
            ClientCommand::Abort => Self::Abort {
                index,
                sub,
                code: AbortCode::from_raw(u32::from_le_bytes(tail(data))),
            },
            ClientCommand::BlockDownload if command & 1 == 0 => Self::InitiateBlockDownload {
                index,
                sub,
                crc: command & 0b100 != 0,
                size: (command & 0b10 != 0).then(|| u32::from_le_bytes(tail(data))),
            },
            ClientCommand::BlockDownload => Self::EndBlockDownload {
                unused: command >> 2 & 0b111,
                crc: u16::from_le_bytes([data[1], data[2]]),
            },
            ClientCommand::BlockUpload => match command & 0b11 {
                0 => Self::InitiateBlockUpload {
                    index,
                    sub,
                    crc: command & 0b100 != 0,
                    block_size: data[4],
                    switch_threshold: data[5],
                },
                1 => Self::EndBlockUpload,
                2 => Self::BlockUploadAck {
                    ackseq: data[1],
                    block_size: data[2],
                },
                _ => Self::StartBlockUpload,
            },
            ClientCommand::Unknown(_) => return Err(DecodeError::Command(command)),
        })
    }

    pub fn encode(&self) -> [u8; FRAME_LEN] {
        match *self {
            Self::InitiateDownload { index, sub, data } => {
                let (flags, tail) = data.encode();
                with_multiplexer(0x20 | flags, index, sub, tail)
            }
            Self::DownloadSegment {
                toggle,
                chunk,
                last,
            } => segment_frame(
                toggle_bit(toggle) | chunk.unused() << 1 | u8::from(last),
                &chunk,
            ),
            Self::InitiateUpload { index, sub } => with_multiplexer(0x40, index, sub, [0; 4]),
            Self::UploadSegment { toggle } => [0x60 | toggle_bit(toggle), 0, 0, 0, 0, 0, 0, 0],
            Self::Abort { index, sub, code } => abort_frame(index, sub, code),
            Self::InitiateBlockDownload {
                index,
                sub,
                crc,
                size,
            } => {
                let command = 0xC0 | u8::from(crc) << 2 | u8::from(size.is_some()) << 1;
                with_multiplexer(command, index, sub, size.unwrap_or(0).to_le_bytes())
            }
            Self::EndBlockDownload { unused, crc } => {
                let [lo, hi] = crc.to_le_bytes();
                [0xC1 | (unused & 0b111) << 2, lo, hi, 0, 0, 0, 0, 0]
            }
            Self::InitiateBlockUpload {
                index,
                sub,
                crc,
                block_size,
                switch_threshold,
            } => with_multiplexer(
                0xA0 | u8::from(crc) << 2,
                index,
                sub,
                [block_size, switch_threshold, 0, 0],
            ),
            Self::StartBlockUpload => [0xA3, 0, 0, 0, 0, 0, 0, 0],
            Self::BlockUploadAck { ackseq, block_size } => {
                [0xA2, ackseq, block_size, 0, 0, 0, 0, 0]
            }
            Self::EndBlockUpload => [0xA1, 0, 0, 0, 0, 0, 0, 0],
        }
    }
}

impl Request {
    /// What the frame is, for messages: "an initiate upload request".
    pub fn describe(&self) -> &'static str {
        match self {
            Self::InitiateDownload { .. } => "an initiate download request",
            Self::DownloadSegment { .. } => "a download segment",
            Self::InitiateUpload { .. } => "an initiate upload request",
            Self::UploadSegment { .. } => "an upload segment request",
            Self::Abort { .. } => "an abort",
            Self::InitiateBlockDownload { .. } => "an initiate block download request",
            Self::EndBlockDownload { .. } => "an end block download request",
            Self::InitiateBlockUpload { .. } => "an initiate block upload request",
            Self::StartBlockUpload => "a start block upload request",
            Self::BlockUploadAck { .. } => "a block acknowledgement",
            Self::EndBlockUpload => "an end block upload response",
        }
    }
}

impl Response {
    /// What the frame is, for messages: "an upload segment".
    pub fn describe(&self) -> &'static str {
        match self {
            Self::InitiateUpload { .. } => "an initiate upload response",
            Self::UploadSegment { .. } => "an upload segment",
            Self::InitiateDownload { .. } => "an initiate download response",
            Self::DownloadSegment { .. } => "a download segment response",
            Self::Abort { .. } => "an abort",
            Self::InitiateBlockDownload { .. } => "an initiate block download response",
            Self::BlockDownloadAck { .. } => "a block acknowledgement",
            Self::EndBlockDownload => "an end block download response",
            Self::InitiateBlockUpload { .. } => "an initiate block upload response",
            Self::EndBlockUpload { .. } => "an end block upload frame",
        }
    }
}

impl Response {
    pub fn decode(data: &[u8]) -> Result<Self, DecodeError> {
        let data = exactly_eight(data)?;
        let command = data[0];
        let (index, sub) = multiplexer(data);
        let toggle = command & TOGGLE != 0;
        Ok(match ServerCommand::of(command) {
            ServerCommand::UploadSegment => Self::UploadSegment {
                toggle,
                chunk: segment_chunk(data, command),
                last: command & 1 != 0,
            },
            ServerCommand::DownloadSegment => Self::DownloadSegment { toggle },
            ServerCommand::InitiateUpload => Self::InitiateUpload {
                index,
                sub,
                data: Initiate::decode(command, tail(data)),
            },
            ServerCommand::InitiateDownload => Self::InitiateDownload { index, sub },
            ServerCommand::Abort => Self::Abort {
                index,
                sub,
                code: AbortCode::from_raw(u32::from_le_bytes(tail(data))),
            },
            ServerCommand::BlockDownload => match command & 0b11 {
                0 => Self::InitiateBlockDownload {
                    index,
                    sub,
                    crc: command & 0b100 != 0,
                    block_size: data[4],
                },
                1 => Self::EndBlockDownload,
                2 => Self::BlockDownloadAck {
                    ackseq: data[1],
                    block_size: data[2],
                },
                _ => return Err(DecodeError::Command(command)),
            },
            ServerCommand::BlockUpload if command & 1 == 0 => Self::InitiateBlockUpload {
                index,
                sub,
                crc: command & 0b100 != 0,
                size: (command & 0b10 != 0).then(|| u32::from_le_bytes(tail(data))),
            },
            ServerCommand::BlockUpload => Self::EndBlockUpload {
                unused: command >> 2 & 0b111,
                crc: u16::from_le_bytes([data[1], data[2]]),
            },
            ServerCommand::Unknown(_) => return Err(DecodeError::Command(command)),
        })
    }

    pub fn encode(&self) -> [u8; FRAME_LEN] {
        match *self {
            Self::InitiateUpload { index, sub, data } => {
                let (flags, tail) = data.encode();
                with_multiplexer(0x40 | flags, index, sub, tail)
            }
            Self::UploadSegment {
                toggle,
                chunk,
                last,
            } => segment_frame(
                toggle_bit(toggle) | chunk.unused() << 1 | u8::from(last),
                &chunk,
            ),
            Self::InitiateDownload { index, sub } => with_multiplexer(0x60, index, sub, [0; 4]),
            Self::DownloadSegment { toggle } => [0x20 | toggle_bit(toggle), 0, 0, 0, 0, 0, 0, 0],
            Self::Abort { index, sub, code } => abort_frame(index, sub, code),
            Self::InitiateBlockDownload {
                index,
                sub,
                crc,
                block_size,
            } => with_multiplexer(0xA0 | u8::from(crc) << 2, index, sub, [block_size, 0, 0, 0]),
            Self::BlockDownloadAck { ackseq, block_size } => {
                [0xA2, ackseq, block_size, 0, 0, 0, 0, 0]
            }
            Self::EndBlockDownload => [0xA1, 0, 0, 0, 0, 0, 0, 0],
            Self::InitiateBlockUpload {
                index,
                sub,
                crc,
                size,
            } => {
                let command = 0xC0 | u8::from(crc) << 2 | u8::from(size.is_some()) << 1;
                with_multiplexer(command, index, sub, size.unwrap_or(0).to_le_bytes())
            }
            Self::EndBlockUpload { unused, crc } => {
                let [lo, hi] = crc.to_le_bytes();
                [0xC1 | (unused & 0b111) << 2, lo, hi, 0, 0, 0, 0, 0]
            }
        }
    }
}

impl BlockSegment {
    /// Segment `seqno` of a block holding `data` (up to 7 bytes, zero-padded).
    pub fn new(seqno: u8, last: bool, data: &[u8]) -> Self {
        Self {
            seqno,
            last,
            data: Chunk::new(data).bytes,
        }
    }

    /// Any eight bytes are a segment; whether its sequence number fits is the
    /// receiving machine's question.
    pub fn decode(data: &[u8]) -> Result<Self, DecodeError> {
        let data = exactly_eight(data)?;
        let mut bytes = [0; SEGMENT_LEN];
        bytes.copy_from_slice(&data[1..]);
        Ok(Self {
            seqno: data[0] & 0x7F,
            last: data[0] & LAST_SEGMENT != 0,
            data: bytes,
        })
    }

    pub fn encode(&self) -> [u8; FRAME_LEN] {
        let mut frame = [0; FRAME_LEN];
        frame[0] = self.seqno & 0x7F | if self.last { LAST_SEGMENT } else { 0 };
        frame[1..].copy_from_slice(&self.data);
        frame
    }
}

/// Whether a frame is an abort transfer request or response (cs 4), the one
/// frame a peer may send in any state. Between the segments of a block the
/// first byte is a sequence number, and there only `0x80` (sequence number 0,
/// which no segment has) is an abort. A short abort still ends the transfer:
/// answering an abort with an abort would help no one.
pub fn is_abort(data: &[u8], inside_block: bool) -> bool {
    match data.first() {
        Some(&first) if inside_block => first == 0x80,
        Some(&first) => first >> 5 == 4,
        None => false,
    }
}

/// The abort code of an abort frame; bytes missing from a short one read as 0.
pub fn abort_code_of(data: &[u8]) -> AbortCode {
    let mut raw = [0; 4];
    for (i, byte) in data.iter().skip(4).take(4).enumerate() {
        raw[i] = *byte;
    }
    AbortCode::from_raw(u32::from_le_bytes(raw))
}

/// The CRC of block transfers (CiA 301 §7.2.4.3.16): CRC-16-CCITT, polynomial
/// x^16 + x^12 + x^5 + 1 (0x1021), initial value 0, no reflection and no final
/// XOR (the "XMODEM" variant; python-canopen uses `binascii.crc_hqx`).
pub fn crc16(data: &[u8]) -> u16 {
    crc16_update(0, data)
}

/// Continues a [`crc16`] over more data.
pub fn crc16_update(mut crc: u16, data: &[u8]) -> u16 {
    for &byte in data {
        crc ^= u16::from(byte) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                crc << 1 ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// Segments needed for `len` bytes: at least one, since even an empty value
/// travels in a segment saying that none of its bytes count.
pub fn segment_count(len: usize) -> usize {
    len.div_ceil(SEGMENT_LEN).max(1)
}

#[cfg(test)]
mod tests;
