//! The SDO client (CiA 301 §7.2.4): reads and writes the object dictionary of
//! one server, one transfer at a time, by expedited, segmented or block
//! transfer.
//!
//! The client picks the transfer kind from its [`ClientConfig`] and the
//! value's size; the server's answers decide the rest (an expedited or a
//! segmented upload, a switch from block to plain upload for short values).

use std::time::{Duration, Instant};

use crate::NodeId;
use crate::can::{CanId, Frame, FrameKind};
use crate::cob::Function;

use super::block::{self, BlockReceiver};
use super::wire::{
    self, BlockSegment, Chunk, FRAME_LEN, Initiate, MAX_BLOCK_SIZE, Request, Response, SEGMENT_LEN,
    crc16, segment_count,
};
use super::{AbortCode, SdoError};

/// How a client transfers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClientConfig {
    /// How long to wait for each answer of the server; then the client
    /// aborts with 0x05040000 and reports [`SdoError::Timeout`].
    pub timeout: Duration,
    /// Segments per block the client takes in a block upload, 1–127 (other
    /// values are clamped).
    pub block_size: u8,
    /// Download values of at least this many bytes by block download;
    /// `None`: never. Smaller values go expedited (1–4 bytes) or segmented.
    pub use_block_download_from: Option<usize>,
    /// Upload by block upload. Not every server supports it.
    pub use_block_upload: bool,
    /// The protocol switch threshold of a block upload (`pst`): the server
    /// may answer with a plain upload when the value has at most this many
    /// bytes; 0 forbids the switch.
    pub switch_threshold: u8,
    /// Ask for the CRC over the data of block transfers.
    pub crc: bool,
}

impl Default for ClientConfig {
    fn default() -> Self {
        Self {
            timeout: Duration::from_secs(1),
            block_size: MAX_BLOCK_SIZE,
            use_block_download_from: None,
            use_block_upload: false,
            // Up to three segments a segmented upload takes fewer frames than
            // a block upload (8 against 9 for 21 bytes); CANopenNode's
            // default too.
            switch_threshold: 21,
            crc: true,
        }
    }
}

/// What the client has to do after a frame or a timeout: send these frames,
/// in order, and, once `done` is set, take the transfer's outcome (the client
/// is then idle).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Step {
    pub send: Vec<Frame>,
    pub done: Option<Result<Transfer, SdoError>>,
}

/// A transfer that succeeded.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Transfer {
    /// The value read.
    Uploaded(Vec<u8>),
    /// The value was written.
    Downloaded,
}

/// The SDO client of one server. See the module documentation.
#[derive(Debug, Clone)]
pub struct SdoClient {
    request: CanId,
    response: CanId,
    config: ClientConfig,
    active: Option<Active>,
}

/// The transfer in progress.
#[derive(Debug, Clone)]
struct Active {
    index: u16,
    sub: u8,
    /// The value being downloaded, or what has been uploaded so far.
    data: Vec<u8>,
    /// The upload size the server announced.
    size: Option<usize>,
    phase: Phase,
    deadline: Instant,
}

/// What the client waits for.
#[derive(Debug, Clone)]
enum Phase {
    /// The initiate download response; the transfer ends there if expedited.
    InitiateDownload {
        expedited: bool,
    },
    /// The confirmation of the download segment that ended at byte `end`.
    DownloadSegment {
        toggle: bool,
        end: usize,
    },
    InitiateUpload,
    UploadSegment {
        toggle: bool,
    },
    InitiateBlockDownload,
    /// The acknowledgement of the block of `count` segments that started with
    /// segment `first` (0-based over the value).
    BlockDownload {
        crc: bool,
        first: usize,
        count: u8,
    },
    EndBlockDownload,
    /// The initiate block upload response, or a plain initiate upload
    /// response if the server switched protocol.
    InitiateBlockUpload,
    BlockUpload {
        crc: bool,
        receiver: BlockReceiver,
    },
    EndBlockUpload {
        crc: bool,
    },
}

impl Phase {
    /// What the client waits for, for error details.
    fn expecting(&self) -> &'static str {
        match self {
            Self::InitiateDownload { .. } => "an initiate download response",
            Self::DownloadSegment { .. } => "a download segment response",
            Self::InitiateUpload => "an initiate upload response",
            Self::UploadSegment { .. } => "an upload segment",
            Self::InitiateBlockDownload => "an initiate block download response",
            Self::BlockDownload { .. } => "a block acknowledgement",
            Self::EndBlockDownload => "an end block download response",
            Self::InitiateBlockUpload => "an initiate block upload response",
            Self::BlockUpload { .. } => "a block segment",
            Self::EndBlockUpload { .. } => "an end block upload frame",
        }
    }
}

/// The result of one frame for the transfer in progress.
enum Outcome {
    /// Send these frames and wait for the next answer.
    Continue(Vec<Frame>),
    /// The transfer succeeded; send these frames first.
    Finished(Vec<Frame>, Transfer),
    /// The server broke the protocol: abort with this code.
    Violation(AbortCode, String),
}

impl SdoClient {
    /// A client of `server` on the predefined connection set: requests on
    /// 0x600 + node, responses on 0x580 + node.
    pub fn new(server: NodeId, config: ClientConfig) -> Self {
        Self::with_cob_ids(
            Function::SdoRx.can_id(server),
            Function::SdoTx.can_id(server),
            config,
        )
    }

    /// A client on other COB-IDs (an SDO channel configured in 0x1280 ff.).
    pub fn with_cob_ids(request: CanId, response: CanId, mut config: ClientConfig) -> Self {
        config.block_size = config.block_size.clamp(1, MAX_BLOCK_SIZE);
        Self {
            request,
            response,
            config,
            active: None,
        }
    }

    /// Where the client sends its requests.
    pub fn request_id(&self) -> CanId {
        self.request
    }

    /// Where the client listens for the server.
    pub fn response_id(&self) -> CanId {
        self.response
    }

    pub fn config(&self) -> &ClientConfig {
        &self.config
    }

    /// Changes the configuration for the transfers that start from now on
    /// (a gateway client that sets its own timeout or block mode per
    /// request); a running transfer keeps the deadlines it has.
    pub fn set_config(&mut self, mut config: ClientConfig) {
        config.block_size = config.block_size.clamp(1, MAX_BLOCK_SIZE);
        self.config = config;
    }

    /// No transfer is running.
    pub fn is_idle(&self) -> bool {
        self.active.is_none()
    }

    /// Whether [`SdoClient::handle_frame`] reads `frame` at all (a data
    /// frame on the server's response COB-ID): a caller fed every frame of
    /// a busy bus skips the others without handling them.
    pub fn is_response(&self, frame: &Frame) -> bool {
        frame.id() == self.response && frame.kind() == FrameKind::Data
    }

    /// When [`SdoClient::handle_timeout`] is due; `None` while idle.
    pub fn deadline(&self) -> Option<Instant> {
        self.active.as_ref().map(|active| active.deadline)
    }

    /// How far the running download has come: the bytes of the value the
    /// server has confirmed, and the value's size; `None` while idle or
    /// uploading. A progress report for long (block) downloads: it moves
    /// with each block acknowledgement (each segment confirmation in a
    /// segmented one), and is the whole value once the last block is
    /// acknowledged, before the end of the transfer is confirmed.
    pub fn download_progress(&self) -> Option<(usize, usize)> {
        let active = self.active.as_ref()?;
        let total = active.data.len();
        let confirmed = match active.phase {
            Phase::InitiateDownload { .. } | Phase::InitiateBlockDownload => 0,
            // Segments start every SEGMENT_LEN bytes: the one that ends at
            // `end` started at the multiple below it.
            Phase::DownloadSegment { end, .. } => end.saturating_sub(1) / SEGMENT_LEN * SEGMENT_LEN,
            Phase::BlockDownload { first, .. } => (first * SEGMENT_LEN).min(total),
            Phase::EndBlockDownload => total,
            Phase::InitiateUpload
            | Phase::UploadSegment { .. }
            | Phase::InitiateBlockUpload
            | Phase::BlockUpload { .. }
            | Phase::EndBlockUpload { .. } => return None,
        };
        Some((confirmed, total))
    }

    /// Starts reading `index`:`sub`; gives the frames to send.
    pub fn upload(&mut self, index: u16, sub: u8, now: Instant) -> Result<Vec<Frame>, SdoError> {
        if self.active.is_some() {
            return Err(SdoError::Busy);
        }
        let (request, phase) = if self.config.use_block_upload {
            let request = Request::InitiateBlockUpload {
                index,
                sub,
                crc: self.config.crc,
                block_size: self.config.block_size,
                switch_threshold: self.config.switch_threshold,
            };
            (request, Phase::InitiateBlockUpload)
        } else {
            (
                Request::InitiateUpload { index, sub },
                Phase::InitiateUpload,
            )
        };
        self.start(index, sub, Vec::new(), phase, now);
        Ok(vec![self.frame(request)])
    }

    /// Starts writing `data` to `index`:`sub`; gives the frames to send.
    pub fn download(
        &mut self,
        index: u16,
        sub: u8,
        data: &[u8],
        now: Instant,
    ) -> Result<Vec<Frame>, SdoError> {
        if self.active.is_some() {
            return Err(SdoError::Busy);
        }
        let size = u32::try_from(data.len()).map_err(|_| SdoError::TooLarge(data.len()))?;
        let block = self
            .config
            .use_block_download_from
            .is_some_and(|from| data.len() >= from);
        let (request, phase) = if block {
            let request = Request::InitiateBlockDownload {
                index,
                sub,
                crc: self.config.crc,
                size: Some(size),
            };
            (request, Phase::InitiateBlockDownload)
        } else {
            let expedited = (1..=4).contains(&data.len());
            let payload = if expedited {
                Initiate::expedited(data)
            } else {
                Initiate::Segmented { size: Some(size) }
            };
            let request = Request::InitiateDownload {
                index,
                sub,
                data: payload,
            };
            (request, Phase::InitiateDownload { expedited })
        };
        self.start(index, sub, data.to_vec(), phase, now);
        Ok(vec![self.frame(request)])
    }

    /// Takes a frame from the bus. Frames on other identifiers, and any
    /// frame while idle, are none of this client's business: an empty step.
    pub fn handle_frame(&mut self, frame: &Frame, now: Instant) -> Step {
        if !self.is_response(frame) {
            return Step::default();
        }
        let Some(mut active) = self.active.take() else {
            return Step::default();
        };
        let data = frame.data();
        let inside_block = matches!(active.phase, Phase::BlockUpload { .. });
        if wire::is_abort(data, inside_block) {
            return Step {
                send: Vec::new(),
                done: Some(Err(SdoError::ServerAborted(wire::abort_code_of(data)))),
            };
        }
        let outcome = if data.len() != FRAME_LEN {
            // CiA 301 defines every SDO frame with all eight data bytes, the
            // unused ones reserved; a shorter frame is no SDO frame at all.
            Outcome::Violation(
                AbortCode::InvalidCommandSpecifier,
                format!(
                    "it sent a frame of {} data bytes where SDO frames have 8",
                    data.len()
                ),
            )
        } else if inside_block {
            let segment = BlockSegment::decode(data).expect("8 bytes are a segment");
            self.on_segment(&mut active, &segment)
        } else {
            match Response::decode(data) {
                Ok(response) => self.on_response(&mut active, response),
                Err(_) => Outcome::Violation(
                    AbortCode::InvalidCommandSpecifier,
                    format!(
                        "it sent command byte 0x{:02X}, which is no SDO response, while the \
                         client waited for {}",
                        data[0],
                        active.phase.expecting()
                    ),
                ),
            }
        };
        self.conclude(active, outcome, now)
    }

    /// Call once `now` has reached [`SdoClient::deadline`]: the server has
    /// been silent too long, and the client aborts with 0x05040000. In the
    /// middle of a block upload it first acknowledges the segments it has,
    /// once, in case only the block's last segment was lost. Before the
    /// deadline it does nothing.
    pub fn handle_timeout(&mut self, now: Instant) -> Step {
        let timeout = self.config.timeout;
        let Some(active) = self.active.as_mut() else {
            return Step::default();
        };
        if now < active.deadline {
            return Step::default();
        }
        let rescue = match &mut active.phase {
            Phase::BlockUpload { receiver, .. } => receiver
                .rescue()
                .map(|ackseq| (ackseq, receiver.block_size())),
            _ => None,
        };
        if let Some((ackseq, block_size)) = rescue {
            active.deadline = now + timeout;
            return Step {
                send: vec![self.frame(Request::BlockUploadAck { ackseq, block_size })],
                done: None,
            };
        }
        Step {
            send: self.abort(AbortCode::TimedOut),
            done: Some(Err(SdoError::Timeout)),
        }
    }

    /// Cancels the running transfer: gives the abort frame to send (nothing
    /// when idle). The transfer reports no outcome; the caller knows why it
    /// ended.
    pub fn abort(&mut self, code: AbortCode) -> Vec<Frame> {
        match self.active.take() {
            Some(active) => vec![self.frame(Request::Abort {
                index: active.index,
                sub: active.sub,
                code,
            })],
            None => Vec::new(),
        }
    }

    fn start(&mut self, index: u16, sub: u8, data: Vec<u8>, phase: Phase, now: Instant) {
        self.active = Some(Active {
            index,
            sub,
            data,
            size: None,
            phase,
            deadline: now + self.config.timeout,
        });
    }

    fn conclude(&mut self, mut active: Active, outcome: Outcome, now: Instant) -> Step {
        match outcome {
            Outcome::Continue(send) => {
                active.deadline = match &active.phase {
                    // The sub-block timeout: half the time, so that its
                    // acknowledgement reaches the server before the server's
                    // own timeout.
                    Phase::BlockUpload { receiver, .. } if receiver.wants_rescue() => {
                        now + self.config.timeout / 2
                    }
                    _ => now + self.config.timeout,
                };
                self.active = Some(active);
                Step { send, done: None }
            }
            Outcome::Finished(send, transfer) => Step {
                send,
                done: Some(Ok(transfer)),
            },
            Outcome::Violation(code, detail) => Step {
                send: vec![self.frame(Request::Abort {
                    index: active.index,
                    sub: active.sub,
                    code,
                })],
                done: Some(Err(SdoError::Protocol { code, detail })),
            },
        }
    }

    fn on_response(&self, active: &mut Active, response: Response) -> Outcome {
        match (&active.phase, response) {
            (&Phase::InitiateDownload { expedited }, Response::InitiateDownload { index, sub }) => {
                if let Some(violation) = check_multiplexer(active, index, sub) {
                    return violation;
                }
                if expedited {
                    Outcome::Finished(Vec::new(), Transfer::Downloaded)
                } else {
                    Outcome::Continue(vec![self.download_segment(active, 0, false)])
                }
            }
            (
                &Phase::DownloadSegment { toggle, end },
                Response::DownloadSegment { toggle: echoed },
            ) => {
                if echoed != toggle {
                    return toggle_violation(toggle);
                }
                if end == active.data.len() {
                    Outcome::Finished(Vec::new(), Transfer::Downloaded)
                } else {
                    Outcome::Continue(vec![self.download_segment(active, end, !toggle)])
                }
            }
            (
                Phase::InitiateUpload | Phase::InitiateBlockUpload,
                Response::InitiateUpload { index, sub, data },
            ) => {
                // A block upload may end here: CiA 301 lets the server switch
                // to a plain upload when the value is no longer than the
                // threshold, and python-canopen's server switches for every
                // value (it has no block upload), so the switch is taken
                // whatever the threshold.
                if let Some(violation) = check_multiplexer(active, index, sub) {
                    return violation;
                }
                match data {
                    Initiate::Expedited { data, len } => {
                        let len = usize::from(len.unwrap_or(4));
                        Outcome::Finished(Vec::new(), Transfer::Uploaded(data[..len].to_vec()))
                    }
                    Initiate::Segmented { size } => {
                        active.size = size.map(|size| size as usize);
                        active.phase = Phase::UploadSegment { toggle: false };
                        Outcome::Continue(vec![
                            self.frame(Request::UploadSegment { toggle: false }),
                        ])
                    }
                }
            }
            (
                &Phase::UploadSegment { toggle },
                Response::UploadSegment {
                    toggle: echoed,
                    chunk,
                    last,
                },
            ) => {
                if echoed != toggle {
                    return toggle_violation(toggle);
                }
                active.data.extend_from_slice(chunk.as_slice());
                if let Some(violation) = check_length(active, last) {
                    return violation;
                }
                if last {
                    Outcome::Finished(
                        Vec::new(),
                        Transfer::Uploaded(std::mem::take(&mut active.data)),
                    )
                } else {
                    active.phase = Phase::UploadSegment { toggle: !toggle };
                    Outcome::Continue(vec![self.frame(Request::UploadSegment { toggle: !toggle })])
                }
            }
            (
                Phase::InitiateBlockDownload,
                Response::InitiateBlockDownload {
                    index,
                    sub,
                    crc,
                    block_size,
                },
            ) => {
                if let Some(violation) = check_multiplexer(active, index, sub) {
                    return violation;
                }
                if !block::valid_block_size(block_size) {
                    return block_size_violation(block_size);
                }
                let crc = self.config.crc && crc;
                Outcome::Continue(self.send_block(active, crc, 0, block_size))
            }
            (
                &Phase::BlockDownload { crc, first, count },
                Response::BlockDownloadAck { ackseq, block_size },
            ) => {
                if ackseq > count {
                    return Outcome::Violation(
                        AbortCode::InvalidSequenceNumber,
                        format!("it acknowledged segment {ackseq} of a block of {count}"),
                    );
                }
                if !block::valid_block_size(block_size) {
                    return block_size_violation(block_size);
                }
                // Segments after `ackseq` did not arrive: the next block
                // starts with the first of them.
                let next = first + usize::from(ackseq);
                if next < segment_count(active.data.len()) {
                    return Outcome::Continue(self.send_block(active, crc, next, block_size));
                }
                active.phase = Phase::EndBlockDownload;
                // The CRC goes out whether or not the server asked for it: a
                // server that checks it regardless (python-canopen reads the
                // server's flag only) still finds the right one.
                Outcome::Continue(vec![self.frame(Request::EndBlockDownload {
                    unused: block::unused_in_last(active.data.len()),
                    crc: crc16(&active.data),
                })])
            }
            (Phase::EndBlockDownload, Response::EndBlockDownload) => {
                Outcome::Finished(Vec::new(), Transfer::Downloaded)
            }
            (
                Phase::InitiateBlockUpload,
                Response::InitiateBlockUpload {
                    index,
                    sub,
                    crc,
                    size,
                },
            ) => {
                if let Some(violation) = check_multiplexer(active, index, sub) {
                    return violation;
                }
                active.size = size.map(|size| size as usize);
                active.phase = Phase::BlockUpload {
                    crc: self.config.crc && crc,
                    receiver: BlockReceiver::new(self.config.block_size),
                };
                Outcome::Continue(vec![self.frame(Request::StartBlockUpload)])
            }
            (
                &Phase::EndBlockUpload { crc },
                Response::EndBlockUpload {
                    unused,
                    crc: theirs,
                },
            ) => {
                // At least one segment (7 bytes) arrived before the end frame.
                let len = active.data.len() - usize::from(unused);
                active.data.truncate(len);
                if let Some(violation) = check_length(active, true) {
                    return violation;
                }
                let ours = crc16(&active.data);
                if crc && ours != theirs {
                    return Outcome::Violation(
                        AbortCode::CrcError,
                        format!(
                            "the CRC it sent, 0x{theirs:04X}, is not that of the data received, \
                             0x{ours:04X}"
                        ),
                    );
                }
                Outcome::Finished(
                    vec![self.frame(Request::EndBlockUpload)],
                    Transfer::Uploaded(std::mem::take(&mut active.data)),
                )
            }
            (phase, response) => Outcome::Violation(
                AbortCode::InvalidCommandSpecifier,
                format!(
                    "it sent {} while the client waited for {}",
                    response.describe(),
                    phase.expecting()
                ),
            ),
        }
    }

    fn on_segment(&self, active: &mut Active, segment: &BlockSegment) -> Outcome {
        let Phase::BlockUpload { crc, receiver } = &mut active.phase else {
            unreachable!("segments are decoded only during a block upload");
        };
        let crc = *crc;
        let Ok(received) = receiver.receive(segment) else {
            return Outcome::Violation(
                AbortCode::InvalidSequenceNumber,
                format!(
                    "it sent segment number {} in blocks of {}",
                    segment.seqno,
                    receiver.block_size()
                ),
            );
        };
        let block_size = receiver.block_size();
        if let Some(data) = received.accepted {
            active.data.extend_from_slice(&data);
            if let Some(size) = active.size
                && active.data.len() > segment_count(size) * SEGMENT_LEN
            {
                return Outcome::Violation(
                    AbortCode::LengthTooHigh,
                    format!("it sent more segments than the {size} bytes it announced need"),
                );
            }
        }
        if received.complete {
            active.phase = Phase::EndBlockUpload { crc };
        }
        let send = received
            .ack
            .map(|ackseq| self.frame(Request::BlockUploadAck { ackseq, block_size }))
            .into_iter()
            .collect();
        Outcome::Continue(send)
    }

    /// The download segment starting at byte `start`; an empty value takes
    /// one empty segment.
    fn download_segment(&self, active: &mut Active, start: usize, toggle: bool) -> Frame {
        let end = (start + SEGMENT_LEN).min(active.data.len());
        active.phase = Phase::DownloadSegment { toggle, end };
        self.frame(Request::DownloadSegment {
            toggle,
            chunk: Chunk::new(&active.data[start..end]),
            last: end == active.data.len(),
        })
    }

    fn send_block(
        &self,
        active: &mut Active,
        crc: bool,
        first: usize,
        block_size: u8,
    ) -> Vec<Frame> {
        let segments = block::segments(&active.data, first, block_size);
        active.phase = Phase::BlockDownload {
            crc,
            first,
            count: segments.len() as u8,
        };
        segments
            .iter()
            .map(|s| self.raw_frame(s.encode()))
            .collect()
    }

    fn frame(&self, request: Request) -> Frame {
        self.raw_frame(request.encode())
    }

    fn raw_frame(&self, data: [u8; FRAME_LEN]) -> Frame {
        Frame::new(self.request, &data).expect("8 bytes fit a classic frame")
    }
}

/// The server answered for another object: perhaps another client shares the
/// channel. CANopenNode aborts with the same code.
fn check_multiplexer(active: &Active, index: u16, sub: u8) -> Option<Outcome> {
    (index != active.index || sub != active.sub).then(|| {
        Outcome::Violation(
            AbortCode::ParameterIncompatible,
            format!(
                "it answered for object 0x{index:04X}:{sub:02X} instead of 0x{:04X}:{:02X}",
                active.index, active.sub
            ),
        )
    })
}

/// Against the size the server announced: too much at any time, too little at
/// the end.
fn check_length(active: &Active, ended: bool) -> Option<Outcome> {
    let size = active.size?;
    let got = active.data.len();
    if got > size {
        Some(Outcome::Violation(
            AbortCode::LengthTooHigh,
            format!("it sent at least {got} bytes after announcing {size}"),
        ))
    } else if ended && got < size {
        Some(Outcome::Violation(
            AbortCode::LengthTooLow,
            format!("it sent {got} bytes after announcing {size}"),
        ))
    } else {
        None
    }
}

fn toggle_violation(expected: bool) -> Outcome {
    Outcome::Violation(
        AbortCode::ToggleBitNotAlternated,
        format!(
            "its toggle bit was {} where {} was due",
            u8::from(!expected),
            u8::from(expected)
        ),
    )
}

fn block_size_violation(block_size: u8) -> Outcome {
    Outcome::Violation(
        AbortCode::InvalidBlockSize,
        format!("it asked for blocks of {block_size} segments, outside 1 to 127"),
    )
}
