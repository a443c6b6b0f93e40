//! The LSS master (CiA 305 §6): one service at a time, each a request and
//! the answer awaited until a deadline, or a series of them (switch state
//! selective, identify remote slave, Fastscan).
//!
//! Fastscan (§6.7) finds the LSS address of one unconfigured slave in 133
//! requests: a confirm (`BitChecked` 0x80) that asks whether any slave is
//! unconfigured, then, for each of the four parts, 32 requests that each
//! fix one more bit (an answer means the bit is as sent, silence that it is
//! the other value), and one that confirms the part and moves the slaves to
//! the next. The slave found is left in the configuration state, so it no
//! longer takes part: [`LssService::FastscanAll`] runs Fastscan again until
//! no slave answers the confirm, then switches every slave back to waiting
//! (still unconfigured), and so finds every unconfigured slave on the bus.
//! Several slaves answering one request send the same frame at the same
//! time, which the bus carries as one.
//!
//! An answer that comes after its timeout reads as a bit set that is not
//! (and may be taken for the answer to the next request): the part then
//! fails its confirmation, and Fastscan starts over from the confirm, at
//! most [`FASTSCAN_RETRIES`] times per slave, before it reports the timeout.

use std::time::{Duration, Instant};

use crate::can::Frame;

use super::{
    AddressPart, CommandSpecifier, ConfigResult, FASTSCAN_CONFIRM, IdentifyPart, Inquiry,
    LssAddress, LssRequest, LssResponse, LssState,
};

/// How many slaves [`LssService::FastscanAll`] finds at most (one per
/// node-ID a bus can give).
pub const MAX_FOUND: usize = 127;
/// How many times Fastscan starts over for one slave whose part failed its
/// confirmation.
pub const FASTSCAN_RETRIES: u8 = 3;

/// A service of the master.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LssService {
    /// Every slave to waiting or configuration; no answer.
    SwitchGlobal(LssState),
    /// The slave with this address to configuration.
    SwitchSelective(LssAddress),
    /// 1–127, or 0xFF (unconfigured).
    ConfigureNodeId(u8),
    ConfigureBitTiming {
        table: u8,
        index: u8,
    },
    /// No answer.
    ActivateBitTiming {
        delay_ms: u16,
    },
    StoreConfiguration,
    Inquire(Inquiry),
    /// Whether a slave within these bounds is on the bus.
    IdentifyRemote {
        vendor_id: u32,
        product_code: u32,
        revision: (u32, u32),
        serial: (u32, u32),
    },
    /// Whether an unconfigured slave is on the bus.
    IdentifyNonConfigured,
    /// One unconfigured slave, left in the configuration state.
    Fastscan,
    /// Every unconfigured slave, all left waiting.
    FastscanAll,
}

/// What a service found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LssOutcome {
    /// Done (the services without an answer, and the configuration
    /// services the slave accepted).
    Done,
    /// A slave answered switch state selective.
    Selected,
    Inquired(u32),
    /// Whether any slave answered an identify service.
    Identified(bool),
    /// The slave Fastscan found; `None`: no unconfigured slave answered.
    Found(Option<LssAddress>),
    /// Every slave [`LssService::FastscanAll`] found, in the order found.
    FoundAll(Vec<LssAddress>),
}

/// Why a service failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LssError {
    #[error("another LSS service is running")]
    Busy,
    #[error("no LSS answer to command 0x{:02X} in time", .0.raw())]
    Timeout(CommandSpecifier),
    /// The slave answered with an error code (1: not supported or out of
    /// range, 2: storage media error, 0xFF: implementation specific).
    #[error("the LSS slave refused command 0x{:02X}: error {}, specific error {}", .command.raw(), .result.error, .result.specific)]
    Refused {
        command: CommandSpecifier,
        result: ConfigResult,
    },
}

/// What to do after an input: send these frames; `done` once the service
/// ended.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct LssStep {
    pub send: Vec<Frame>,
    pub done: Option<Result<LssOutcome, LssError>>,
}

impl LssStep {
    fn send(frames: Vec<Frame>) -> Self {
        Self {
            send: frames,
            done: None,
        }
    }

    fn done(result: Result<LssOutcome, LssError>) -> Self {
        Self {
            send: Vec::new(),
            done: Some(result),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Waiting for any slave to answer the confirm (0x80).
    Confirm,
    /// Waiting for the answer on one bit of the part `sub`.
    Bit(u8),
    /// Waiting for the answer confirming the whole part `sub`.
    Next,
}

#[derive(Debug, Clone)]
struct Scan {
    id: [u32; 4],
    sub: u8,
    phase: Phase,
    /// `Some` for [`LssService::FastscanAll`]: the slaves found so far.
    all: Option<Vec<LssAddress>>,
    /// Start-overs for the slave being scanned.
    retries: u8,
}

impl Scan {
    fn new(all: Option<Vec<LssAddress>>) -> Self {
        Self {
            id: [0; 4],
            sub: 0,
            phase: Phase::Confirm,
            all,
            retries: 0,
        }
    }

    /// From the confirm again, for the same slave.
    fn start_over(&mut self) {
        let retries = self.retries + 1;
        *self = Self::new(self.all.take());
        self.retries = retries;
    }

    fn request(&self) -> Frame {
        let (bit_checked, next) = match self.phase {
            Phase::Confirm => (FASTSCAN_CONFIRM, 0),
            Phase::Bit(bit) => (bit, self.sub),
            Phase::Next => (0, (self.sub + 1) & 3),
        };
        LssRequest::Fastscan {
            id_number: self.id[usize::from(self.sub)],
            bit_checked,
            sub: self.sub,
            next,
        }
        .encode()
    }

    /// The answer to the last request came (`answered`) or did not.
    fn advance(&mut self, answered: bool) -> Result<Option<LssAddress>, Option<LssError>> {
        match self.phase {
            Phase::Confirm if !answered => return Err(None),
            Phase::Confirm => {
                self.id = [0; 4];
                self.sub = 0;
                self.phase = Phase::Bit(31);
            }
            Phase::Bit(bit) => {
                if !answered {
                    // No slave has this bit as sent: it is set.
                    self.id[usize::from(self.sub)] |= 1 << bit;
                }
                self.phase = match bit {
                    0 => Phase::Next,
                    _ => Phase::Bit(bit - 1),
                };
            }
            Phase::Next if !answered => {
                return Err(Some(LssError::Timeout(CommandSpecifier::Fastscan)));
            }
            Phase::Next => {
                self.sub += 1;
                if self.sub == 4 {
                    return Ok(Some(LssAddress::from_parts(self.id)));
                }
                self.phase = Phase::Bit(31);
            }
        }
        Ok(None)
    }
}

#[derive(Debug, Clone)]
enum Running {
    /// One answer with this command specifier.
    Answer(CommandSpecifier),
    /// Any identify answer until the deadline.
    Identify,
    Fastscan(Scan),
}

/// See the module documentation.
#[derive(Debug, Clone)]
pub struct LssMaster {
    timeout: Duration,
    running: Option<Running>,
    deadline: Option<Instant>,
}

impl LssMaster {
    /// A master that waits `timeout` for each answer (CANopenNode's
    /// default is 10 ms on a real bus; a bus bridged over TCP needs more).
    pub fn new(timeout: Duration) -> Self {
        Self {
            timeout,
            running: None,
            deadline: None,
        }
    }

    pub fn timeout(&self) -> Duration {
        self.timeout
    }

    pub fn is_busy(&self) -> bool {
        self.running.is_some()
    }

    /// When [`LssMaster::handle_timeout`] is due.
    pub fn deadline(&self) -> Option<Instant> {
        self.deadline
    }

    /// Starts `service`: the frames to send, and the outcome at once for a
    /// service without an answer.
    pub fn start(&mut self, service: LssService, now: Instant) -> LssStep {
        if self.running.is_some() {
            return LssStep::done(Err(LssError::Busy));
        }
        let (frames, running) = match service {
            LssService::SwitchGlobal(state) => {
                let frame = LssRequest::SwitchStateGlobal(state).encode();
                return LssStep {
                    send: vec![frame],
                    done: Some(Ok(LssOutcome::Done)),
                };
            }
            LssService::ActivateBitTiming { delay_ms } => {
                let frame = LssRequest::ActivateBitTiming { delay_ms }.encode();
                return LssStep {
                    send: vec![frame],
                    done: Some(Ok(LssOutcome::Done)),
                };
            }
            LssService::SwitchSelective(address) => (
                AddressPart::ALL
                    .iter()
                    .map(|part| LssRequest::SwitchStateSelective(*part, part.of(address)).encode())
                    .collect(),
                Running::Answer(CommandSpecifier::SwitchSelectiveResponse),
            ),
            LssService::ConfigureNodeId(node) => (
                vec![LssRequest::ConfigureNodeId(node).encode()],
                Running::Answer(CommandSpecifier::ConfigureNodeId),
            ),
            LssService::ConfigureBitTiming { table, index } => (
                vec![LssRequest::ConfigureBitTiming { table, index }.encode()],
                Running::Answer(CommandSpecifier::ConfigureBitTiming),
            ),
            LssService::StoreConfiguration => (
                vec![LssRequest::StoreConfiguration.encode()],
                Running::Answer(CommandSpecifier::StoreConfiguration),
            ),
            LssService::Inquire(inquiry) => {
                let request = LssRequest::Inquire(inquiry);
                (vec![request.encode()], Running::Answer(request.command()))
            }
            LssService::IdentifyRemote {
                vendor_id,
                product_code,
                revision,
                serial,
            } => {
                let values = [
                    vendor_id,
                    product_code,
                    revision.0,
                    revision.1,
                    serial.0,
                    serial.1,
                ];
                (
                    IdentifyPart::ALL
                        .iter()
                        .zip(values)
                        .map(|(part, value)| LssRequest::IdentifyRemoteSlave(*part, value).encode())
                        .collect(),
                    Running::Identify,
                )
            }
            LssService::IdentifyNonConfigured => (
                vec![LssRequest::IdentifyNonConfigured.encode()],
                Running::Identify,
            ),
            LssService::Fastscan | LssService::FastscanAll => {
                let all = (service == LssService::FastscanAll).then(Vec::new);
                let scan = Scan::new(all);
                let mut frames = Vec::new();
                if service == LssService::FastscanAll {
                    // Nobody left in configuration from before: those
                    // would not answer.
                    frames.push(LssRequest::SwitchStateGlobal(LssState::Waiting).encode());
                }
                frames.push(scan.request());
                (frames, Running::Fastscan(scan))
            }
        };
        self.running = Some(running);
        self.deadline = Some(now + self.timeout);
        LssStep::send(frames)
    }

    /// Takes a frame from the bus; anything but an LSS answer is ignored.
    pub fn on_frame(&mut self, frame: &Frame, now: Instant) -> LssStep {
        let Ok(response) = LssResponse::decode(frame) else {
            return LssStep::default();
        };
        let Some(running) = &mut self.running else {
            return LssStep::default();
        };
        let outcome = match (running, response) {
            (Running::Answer(expected), response) if response.command() == *expected => {
                match response {
                    LssResponse::SwitchStateSelective => Ok(LssOutcome::Selected),
                    LssResponse::ConfigureNodeId(result)
                    | LssResponse::ConfigureBitTiming(result)
                    | LssResponse::StoreConfiguration(result) => {
                        if result.is_ok() {
                            Ok(LssOutcome::Done)
                        } else {
                            Err(LssError::Refused {
                                command: *expected,
                                result,
                            })
                        }
                    }
                    LssResponse::Inquired(_, value) => Ok(LssOutcome::Inquired(value)),
                    LssResponse::IdentifySlave | LssResponse::IdentifyNonConfiguredSlave => {
                        Ok(LssOutcome::Identified(true))
                    }
                }
            }
            (
                Running::Identify,
                LssResponse::IdentifySlave | LssResponse::IdentifyNonConfiguredSlave,
            ) => Ok(LssOutcome::Identified(true)),
            (Running::Fastscan(_), LssResponse::IdentifySlave) => {
                return self.fastscan_step(true, now);
            }
            _ => return LssStep::default(),
        };
        self.finish(outcome)
    }

    /// The deadline passed: the service ends or (Fastscan) goes on.
    pub fn handle_timeout(&mut self, now: Instant) -> LssStep {
        if self.deadline.is_none_or(|deadline| now < deadline) {
            return LssStep::default();
        }
        match &self.running {
            None => LssStep::default(),
            Some(Running::Answer(command)) => {
                let command = *command;
                self.finish(Err(LssError::Timeout(command)))
            }
            Some(Running::Identify) => self.finish(Ok(LssOutcome::Identified(false))),
            Some(Running::Fastscan(_)) => self.fastscan_step(false, now),
        }
    }

    fn finish(&mut self, outcome: Result<LssOutcome, LssError>) -> LssStep {
        self.running = None;
        self.deadline = None;
        LssStep::done(outcome)
    }

    fn fastscan_step(&mut self, answered: bool, now: Instant) -> LssStep {
        let Some(Running::Fastscan(scan)) = &mut self.running else {
            return LssStep::default();
        };
        match scan.advance(answered) {
            Ok(None) => {
                let frame = scan.request();
                self.deadline = Some(now + self.timeout);
                LssStep::send(vec![frame])
            }
            Ok(Some(found)) => match &mut scan.all {
                None => self.finish(Ok(LssOutcome::Found(Some(found)))),
                Some(all) => {
                    all.push(found);
                    if all.len() >= MAX_FOUND {
                        let all = std::mem::take(all);
                        return self.finish_all(all);
                    }
                    *scan = Scan::new(scan.all.take());
                    let frame = scan.request();
                    self.deadline = Some(now + self.timeout);
                    LssStep::send(vec![frame])
                }
            },
            Err(None) => match scan.all.take() {
                None => self.finish(Ok(LssOutcome::Found(None))),
                Some(all) => self.finish_all(all),
            },
            Err(Some(_)) if scan.retries < FASTSCAN_RETRIES => {
                scan.start_over();
                let frame = scan.request();
                self.deadline = Some(now + self.timeout);
                LssStep::send(vec![frame])
            }
            Err(Some(error)) => {
                let waiting = scan.all.is_some();
                let mut step = self.finish(Err(error));
                if waiting {
                    step.send
                        .push(LssRequest::SwitchStateGlobal(LssState::Waiting).encode());
                }
                step
            }
        }
    }

    /// The end of [`LssService::FastscanAll`]: every slave found back to
    /// waiting.
    fn finish_all(&mut self, all: Vec<LssAddress>) -> LssStep {
        let mut step = self.finish(Ok(LssOutcome::FoundAll(all)));
        step.send
            .push(LssRequest::SwitchStateGlobal(LssState::Waiting).encode());
        step
    }
}
