//! The SDO server (CiA 301 §7.2.4): answers the requests of one client on an
//! object dictionary it reaches through [`ObjectAccess`], by expedited,
//! segmented and block transfer in both directions.
//!
//! Every request the protocol does not allow at that point gets an abort with
//! the code CiA 301 names for it, and ends the transfer; a client's abort ends
//! it silently. A transfer that stalls is aborted with 0x05040000 once
//! [`ServerConfig::timeout`] has passed.

use std::time::{Duration, Instant};

use crate::NodeId;
use crate::can::{CanId, Frame, FrameKind};
use crate::cob::Function;

use super::AbortCode;
use super::block::{self, BlockReceiver};
use super::wire::{
    self, BlockSegment, Chunk, FRAME_LEN, Initiate, MAX_BLOCK_SIZE, Request, Response, SEGMENT_LEN,
    crc16, segment_count,
};

/// The object dictionary as the SDO server sees it: value bytes in, value
/// bytes out, and an abort code for every refusal.
pub trait ObjectAccess {
    /// The value bytes of `index`:`sub`, or why not (0x06020000 no such
    /// object, 0x06090011 no such sub-index, 0x06010001 write-only, ...).
    fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode>;

    /// Checks a download before its data arrives (existence, access, and the
    /// size when the client indicated one), so that the abort comes with the
    /// initiate response, as real devices do. [`ObjectAccess::write`] is
    /// called afterwards all the same.
    fn check_write(&mut self, index: u16, sub: u8, size: Option<usize>) -> Result<(), AbortCode> {
        let _ = (index, sub, size);
        Ok(())
    }

    /// Stores the value bytes of `index`:`sub`, or says why not (0x06010002
    /// read-only, 0x06070010 wrong length, 0x06090031 value too high, ...).
    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode>;

    /// The size of the value of `index`:`sub` when its type fixes one. It cuts
    /// an expedited download that does not indicate its size (the client
    /// sends four bytes, of which a UNSIGNED8 object takes one); without it
    /// all four bytes are written.
    fn fixed_size(&mut self, index: u16, sub: u8) -> Option<usize> {
        let _ = (index, sub);
        None
    }
}

/// How a server transfers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServerConfig {
    /// How long a started transfer may wait for the client's next request;
    /// then the server aborts with 0x05040000.
    pub timeout: Duration,
    /// Segments per block the server takes in a block download, 1–127
    /// (other values are clamped).
    pub block_size: u8,
    /// Offer the CRC in block transfers.
    pub crc: bool,
    /// The largest value a download may bring: beyond it the server aborts
    /// with 0x05040005 (out of memory) rather than buffer without end.
    pub max_size: usize,
}

impl Default for ServerConfig {
    fn default() -> Self {
        Self {
            timeout: Duration::from_secs(1),
            block_size: MAX_BLOCK_SIZE,
            crc: true,
            max_size: 1 << 20,
        }
    }
}

/// The SDO server of one node. See the module documentation.
#[derive(Debug, Clone)]
pub struct SdoServer {
    request: CanId,
    response: CanId,
    config: ServerConfig,
    state: State,
    deadline: Option<Instant>,
}

/// The transfer in progress and what the server waits for.
#[derive(Debug, Clone, Default)]
enum State {
    #[default]
    Idle,
    /// The next download segment.
    SegmentedDownload {
        index: u16,
        sub: u8,
        size: Option<usize>,
        toggle: bool,
        data: Vec<u8>,
    },
    /// The next upload segment request; `pos` is the first byte not sent.
    SegmentedUpload {
        index: u16,
        sub: u8,
        data: Vec<u8>,
        pos: usize,
        toggle: bool,
    },
    /// The segments of a block download.
    BlockDownload {
        index: u16,
        sub: u8,
        size: Option<usize>,
        crc: bool,
        data: Vec<u8>,
        receiver: BlockReceiver,
    },
    /// The end block download request.
    EndBlockDownload {
        index: u16,
        sub: u8,
        size: Option<usize>,
        crc: bool,
        data: Vec<u8>,
    },
    /// The start block upload request.
    StartBlockUpload {
        index: u16,
        sub: u8,
        data: Vec<u8>,
        block_size: u8,
    },
    /// The acknowledgement of the block of `count` segments that started with
    /// segment `first` (0-based over the value).
    BlockUpload {
        index: u16,
        sub: u8,
        data: Vec<u8>,
        first: usize,
        count: u8,
    },
    /// The end block upload response.
    EndBlockUpload { index: u16, sub: u8 },
}

impl State {
    /// A block download whose segments are all in: waiting for the end.
    fn into_end(self) -> Self {
        match self {
            Self::BlockDownload {
                index,
                sub,
                size,
                crc,
                data,
                ..
            } => Self::EndBlockDownload {
                index,
                sub,
                size,
                crc,
                data,
            },
            other => other,
        }
    }

    fn multiplexer(&self) -> Option<(u16, u8)> {
        match *self {
            Self::Idle => None,
            Self::SegmentedDownload { index, sub, .. }
            | Self::SegmentedUpload { index, sub, .. }
            | Self::BlockDownload { index, sub, .. }
            | Self::EndBlockDownload { index, sub, .. }
            | Self::StartBlockUpload { index, sub, .. }
            | Self::BlockUpload { index, sub, .. }
            | Self::EndBlockUpload { index, sub } => Some((index, sub)),
        }
    }
}

/// python-canopen downloads an empty value by block with no segment at all:
/// the end request follows the initiate directly. CiA 301 has one empty
/// segment sent instead, but when the client announced 0 bytes and nothing
/// has arrived, a frame shaped like an end request cannot be a first segment
/// (that would be numbered 1), so it is taken for the end.
fn empty_block_download_end(state: &State, data: &[u8]) -> Option<Request> {
    let State::BlockDownload {
        size: Some(0),
        data: received,
        ..
    } = state
    else {
        return None;
    };
    let end = Request::decode(data).ok()?;
    (received.is_empty() && matches!(end, Request::EndBlockDownload { .. })).then_some(end)
}

/// Why the server ends a transfer: the abort it sends.
struct Refusal {
    index: u16,
    sub: u8,
    code: AbortCode,
}

/// The frames to answer with (encoded, since block segments are no
/// [`Response`]), or the abort.
type Reply = Result<Vec<[u8; FRAME_LEN]>, Refusal>;

fn answer(response: Response) -> Reply {
    Ok(vec![response.encode()])
}

fn refuse(index: u16, sub: u8) -> impl Fn(AbortCode) -> Refusal {
    move |code| Refusal { index, sub, code }
}

impl SdoServer {
    /// The server of `node` on the predefined connection set: requests on
    /// 0x600 + node, responses on 0x580 + node.
    pub fn new(node: NodeId, config: ServerConfig) -> Self {
        Self::with_cob_ids(
            Function::SdoRx.can_id(node),
            Function::SdoTx.can_id(node),
            config,
        )
    }

    /// A server on other COB-IDs (an additional server channel, 0x1201 ff.).
    pub fn with_cob_ids(request: CanId, response: CanId, mut config: ServerConfig) -> Self {
        config.block_size = config.block_size.clamp(1, MAX_BLOCK_SIZE);
        Self {
            request,
            response,
            config,
            state: State::Idle,
            deadline: None,
        }
    }

    /// Where the server listens for requests.
    pub fn request_id(&self) -> CanId {
        self.request
    }

    /// Where the server answers.
    pub fn response_id(&self) -> CanId {
        self.response
    }

    pub fn config(&self) -> &ServerConfig {
        &self.config
    }

    /// No transfer is in progress.
    pub fn is_idle(&self) -> bool {
        matches!(self.state, State::Idle)
    }

    /// When [`SdoServer::handle_timeout`] is due; `None` while idle.
    pub fn deadline(&self) -> Option<Instant> {
        self.deadline
    }

    /// Takes a frame from the bus and gives the frames to answer with.
    /// Frames on other identifiers, and remote, FD and error frames, are
    /// ignored.
    pub fn handle_frame(
        &mut self,
        frame: &Frame,
        now: Instant,
        objects: &mut dyn ObjectAccess,
    ) -> Vec<Frame> {
        if frame.id() != self.request || frame.kind() != FrameKind::Data {
            return Vec::new();
        }
        let data = frame.data();
        let inside_block = matches!(self.state, State::BlockDownload { .. });
        if wire::is_abort(data, inside_block) {
            self.finish();
            return Vec::new();
        }
        let state = std::mem::take(&mut self.state);
        let reply = if data.len() != FRAME_LEN {
            // CiA 301 defines every SDO frame with all eight data bytes, the
            // unused ones reserved, and no shorter form. CANopenNode drops
            // shorter frames without a word; an abort tells the client at
            // once instead of letting it wait for its timeout.
            let (index, sub) = state.multiplexer().unwrap_or((0, 0));
            Err(Refusal {
                index,
                sub,
                code: AbortCode::InvalidCommandSpecifier,
            })
        } else if let State::BlockDownload { .. } = state {
            if let Some(end) = empty_block_download_end(&state, data) {
                self.on_request(state.into_end(), end, objects)
            } else {
                let segment = BlockSegment::decode(data).expect("8 bytes are a segment");
                self.on_segment(state, &segment)
            }
        } else {
            match Request::decode(data) {
                Ok(request) => self.on_request(state, request, objects),
                Err(_) => {
                    let (index, sub) = state.multiplexer().unwrap_or((0, 0));
                    Err(Refusal {
                        index,
                        sub,
                        code: AbortCode::InvalidCommandSpecifier,
                    })
                }
            }
        };
        match reply {
            Ok(responses) => {
                self.deadline = match &self.state {
                    State::Idle => None,
                    // The sub-block timeout: half the time, so that its
                    // acknowledgement reaches the client before the client's
                    // own timeout.
                    State::BlockDownload { receiver, .. } if receiver.wants_rescue() => {
                        Some(now + self.config.timeout / 2)
                    }
                    _ => Some(now + self.config.timeout),
                };
                responses.into_iter().map(|data| self.frame(data)).collect()
            }
            Err(refusal) => {
                self.finish();
                vec![self.abort_frame(refusal)]
            }
        }
    }

    /// Call once `now` has reached [`SdoServer::deadline`]: the client has
    /// been silent too long, and the server aborts with 0x05040000. In the
    /// middle of a block download it first acknowledges the segments it has,
    /// once, in case only the block's last segment was lost. Before the
    /// deadline it does nothing.
    pub fn handle_timeout(&mut self, now: Instant) -> Vec<Frame> {
        match self.deadline {
            Some(deadline) if now >= deadline => {}
            _ => return Vec::new(),
        }
        if let State::BlockDownload { receiver, .. } = &mut self.state
            && let Some(ackseq) = receiver.rescue()
        {
            let ack = Response::BlockDownloadAck {
                ackseq,
                block_size: receiver.block_size(),
            };
            self.deadline = Some(now + self.config.timeout);
            return vec![self.frame(ack.encode())];
        }
        let (index, sub) = self.state.multiplexer().unwrap_or((0, 0));
        self.finish();
        vec![self.abort_frame(Refusal {
            index,
            sub,
            code: AbortCode::TimedOut,
        })]
    }

    fn finish(&mut self) {
        self.state = State::Idle;
        self.deadline = None;
    }

    fn on_request(
        &mut self,
        state: State,
        request: Request,
        objects: &mut dyn ObjectAccess,
    ) -> Reply {
        match (state, request) {
            (State::Idle, Request::InitiateUpload { index, sub }) => {
                let data = objects.read(index, sub).map_err(refuse(index, sub))?;
                self.start_upload(index, sub, data)
            }
            (
                State::SegmentedUpload {
                    index,
                    sub,
                    data,
                    pos,
                    toggle,
                },
                Request::UploadSegment { toggle: theirs },
            ) => {
                if theirs != toggle {
                    return Err(refuse(index, sub)(AbortCode::ToggleBitNotAlternated));
                }
                let end = (pos + SEGMENT_LEN).min(data.len());
                let last = end == data.len();
                let segment = Response::UploadSegment {
                    toggle,
                    chunk: Chunk::new(&data[pos..end]),
                    last,
                };
                if !last {
                    self.state = State::SegmentedUpload {
                        index,
                        sub,
                        data,
                        pos: end,
                        toggle: !toggle,
                    };
                }
                answer(segment)
            }
            (
                State::Idle,
                Request::InitiateDownload {
                    index,
                    sub,
                    data: Initiate::Expedited { data, len },
                },
            ) => {
                let refuse = refuse(index, sub);
                let fixed = objects
                    .fixed_size(index, sub)
                    .filter(|size| (1..=4).contains(size));
                let size = len.map(usize::from).or(fixed);
                objects.check_write(index, sub, size).map_err(&refuse)?;
                objects
                    .write(index, sub, &data[..size.unwrap_or(4)])
                    .map_err(&refuse)?;
                answer(Response::InitiateDownload { index, sub })
            }
            (
                State::Idle,
                Request::InitiateDownload {
                    index,
                    sub,
                    data: Initiate::Segmented { size },
                },
            ) => {
                let size = size.map(|size| size as usize);
                self.check_download(index, sub, size, objects)?;
                self.state = State::SegmentedDownload {
                    index,
                    sub,
                    size,
                    toggle: false,
                    data: Vec::with_capacity(size.unwrap_or(0)),
                };
                answer(Response::InitiateDownload { index, sub })
            }
            (
                State::SegmentedDownload {
                    index,
                    sub,
                    size,
                    toggle,
                    mut data,
                },
                Request::DownloadSegment {
                    toggle: theirs,
                    chunk,
                    last,
                },
            ) => {
                let refuse = refuse(index, sub);
                if theirs != toggle {
                    return Err(refuse(AbortCode::ToggleBitNotAlternated));
                }
                data.extend_from_slice(chunk.as_slice());
                self.check_length(&data, size, last).map_err(&refuse)?;
                if last {
                    objects.write(index, sub, &data).map_err(&refuse)?;
                } else {
                    self.state = State::SegmentedDownload {
                        index,
                        sub,
                        size,
                        toggle: !toggle,
                        data,
                    };
                }
                answer(Response::DownloadSegment { toggle })
            }
            (
                State::Idle,
                Request::InitiateBlockDownload {
                    index,
                    sub,
                    crc,
                    size,
                },
            ) => {
                let size = size.map(|size| size as usize);
                self.check_download(index, sub, size, objects)?;
                let crc = self.config.crc && crc;
                let block_size = self.config.block_size;
                self.state = State::BlockDownload {
                    index,
                    sub,
                    size,
                    crc,
                    data: Vec::with_capacity(size.unwrap_or(0)),
                    receiver: BlockReceiver::new(block_size),
                };
                answer(Response::InitiateBlockDownload {
                    index,
                    sub,
                    crc,
                    block_size,
                })
            }
            (
                State::EndBlockDownload {
                    index,
                    sub,
                    size,
                    crc,
                    mut data,
                },
                Request::EndBlockDownload {
                    unused,
                    crc: theirs,
                },
            ) => {
                let refuse = refuse(index, sub);
                // At least one segment (7 bytes) arrived before the end, but
                // for python-canopen's empty download (see
                // `empty_block_download_end`).
                data.truncate(data.len().saturating_sub(usize::from(unused)));
                self.check_length(&data, size, true).map_err(&refuse)?;
                if crc && crc16(&data) != theirs {
                    return Err(refuse(AbortCode::CrcError));
                }
                objects.write(index, sub, &data).map_err(&refuse)?;
                answer(Response::EndBlockDownload)
            }
            (
                State::Idle,
                Request::InitiateBlockUpload {
                    index,
                    sub,
                    crc,
                    block_size,
                    switch_threshold,
                },
            ) => {
                let refuse = refuse(index, sub);
                if !block::valid_block_size(block_size) {
                    return Err(refuse(AbortCode::InvalidBlockSize));
                }
                let data = objects.read(index, sub).map_err(&refuse)?;
                if switch_threshold > 0 && data.len() <= usize::from(switch_threshold) {
                    // The protocol switch: a short value costs fewer frames
                    // by plain upload, and the client said it takes one.
                    return self.start_upload(index, sub, data);
                }
                let size = u32::try_from(data.len()).map_err(|_| refuse(AbortCode::OutOfMemory))?;
                self.state = State::StartBlockUpload {
                    index,
                    sub,
                    data,
                    block_size,
                };
                // The CRC flag answers the client's: python-canopen's client
                // checks the CRC whenever the server's flag is set, even if it
                // did not ask for one.
                answer(Response::InitiateBlockUpload {
                    index,
                    sub,
                    crc: self.config.crc && crc,
                    size: Some(size),
                })
            }
            (
                State::StartBlockUpload {
                    index,
                    sub,
                    data,
                    block_size,
                },
                Request::StartBlockUpload,
            ) => self.send_block(index, sub, data, 0, block_size),
            (
                State::BlockUpload {
                    index,
                    sub,
                    data,
                    first,
                    count,
                },
                Request::BlockUploadAck { ackseq, block_size },
            ) => {
                let refuse = refuse(index, sub);
                if ackseq > count {
                    return Err(refuse(AbortCode::InvalidSequenceNumber));
                }
                if !block::valid_block_size(block_size) {
                    return Err(refuse(AbortCode::InvalidBlockSize));
                }
                // Segments after `ackseq` did not arrive: the next block
                // starts with the first of them.
                let next = first + usize::from(ackseq);
                if next < segment_count(data.len()) {
                    return self.send_block(index, sub, data, next, block_size);
                }
                self.state = State::EndBlockUpload { index, sub };
                // The CRC goes out whether or not the client asked for it, for
                // clients that check it regardless.
                answer(Response::EndBlockUpload {
                    unused: block::unused_in_last(data.len()),
                    crc: crc16(&data),
                })
            }
            (State::EndBlockUpload { .. }, Request::EndBlockUpload) => Ok(Vec::new()),
            // Anything else is out of place: a segment with no transfer, a new
            // initiate in the middle of one (CANopenNode aborts it too), a
            // block command in a segmented transfer.
            (state, request) => {
                let (index, sub) = state.multiplexer().unwrap_or(match request {
                    Request::InitiateDownload { index, sub, .. }
                    | Request::InitiateUpload { index, sub }
                    | Request::InitiateBlockDownload { index, sub, .. }
                    | Request::InitiateBlockUpload { index, sub, .. } => (index, sub),
                    _ => (0, 0),
                });
                Err(Refusal {
                    index,
                    sub,
                    code: AbortCode::InvalidCommandSpecifier,
                })
            }
        }
    }

    fn on_segment(&mut self, state: State, segment: &BlockSegment) -> Reply {
        let State::BlockDownload {
            index,
            sub,
            size,
            crc,
            mut data,
            mut receiver,
        } = state
        else {
            unreachable!("segments are decoded only during a block download");
        };
        let refuse = refuse(index, sub);
        let received = receiver
            .receive(segment)
            .map_err(|()| refuse(AbortCode::InvalidSequenceNumber))?;
        if let Some(bytes) = received.accepted {
            data.extend_from_slice(&bytes);
            if data.len() > self.config.max_size + SEGMENT_LEN {
                return Err(refuse(AbortCode::OutOfMemory));
            }
            if let Some(size) = size
                && data.len() > segment_count(size) * SEGMENT_LEN
            {
                return Err(refuse(AbortCode::LengthTooHigh));
            }
        }
        let block_size = receiver.block_size();
        self.state = if received.complete {
            State::EndBlockDownload {
                index,
                sub,
                size,
                crc,
                data,
            }
        } else {
            State::BlockDownload {
                index,
                sub,
                size,
                crc,
                data,
                receiver,
            }
        };
        Ok(received
            .ack
            .map(|ackseq| Response::BlockDownloadAck { ackseq, block_size }.encode())
            .into_iter()
            .collect())
    }

    /// Answers an upload: expedited for 1–4 bytes, segmented otherwise (an
    /// empty value too, as one empty segment: an expedited frame cannot say
    /// "0 bytes").
    fn start_upload(&mut self, index: u16, sub: u8, data: Vec<u8>) -> Reply {
        if (1..=4).contains(&data.len()) {
            return answer(Response::InitiateUpload {
                index,
                sub,
                data: Initiate::expedited(&data),
            });
        }
        let size =
            u32::try_from(data.len()).map_err(|_| refuse(index, sub)(AbortCode::OutOfMemory))?;
        self.state = State::SegmentedUpload {
            index,
            sub,
            data,
            pos: 0,
            toggle: false,
        };
        answer(Response::InitiateUpload {
            index,
            sub,
            data: Initiate::Segmented { size: Some(size) },
        })
    }

    /// Whether a segmented or block download of `size` bytes may start.
    fn check_download(
        &self,
        index: u16,
        sub: u8,
        size: Option<usize>,
        objects: &mut dyn ObjectAccess,
    ) -> Result<(), Refusal> {
        let refuse = refuse(index, sub);
        if size.is_some_and(|size| size > self.config.max_size) {
            return Err(refuse(AbortCode::OutOfMemory));
        }
        objects.check_write(index, sub, size).map_err(refuse)
    }

    /// Against the size the client indicated: too much at any time, too
    /// little at the end; and against the server's memory.
    fn check_length(&self, data: &[u8], size: Option<usize>, ended: bool) -> Result<(), AbortCode> {
        if data.len() > self.config.max_size {
            return Err(AbortCode::OutOfMemory);
        }
        match size {
            Some(size) if data.len() > size => Err(AbortCode::LengthTooHigh),
            Some(size) if ended && data.len() < size => Err(AbortCode::LengthTooLow),
            _ => Ok(()),
        }
    }

    /// Sends the block that starts with segment `first` (0-based).
    fn send_block(
        &mut self,
        index: u16,
        sub: u8,
        data: Vec<u8>,
        first: usize,
        block_size: u8,
    ) -> Reply {
        let segments = block::segments(&data, first, block_size);
        self.state = State::BlockUpload {
            index,
            sub,
            data,
            first,
            count: segments.len() as u8,
        };
        Ok(segments.iter().map(BlockSegment::encode).collect())
    }

    fn abort_frame(&self, refusal: Refusal) -> Frame {
        self.frame(
            Response::Abort {
                index: refusal.index,
                sub: refusal.sub,
                code: refusal.code,
            }
            .encode(),
        )
    }

    fn frame(&self, data: [u8; FRAME_LEN]) -> Frame {
        Frame::new(self.response, &data).expect("8 bytes fit a classic frame")
    }
}
