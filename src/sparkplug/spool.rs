//! Store and forward (Sparkplug 3.0 §5.18 "Historical data"): the data
//! messages made while the broker (or the primary host) is away, kept in a
//! bounded queue, and sent in order once the births of the next session
//! are out, each metric marked `is_historical`.
//!
//! The queue is in memory, and mirrored in a file of the data directory
//! when there is one, so that what a restart of the gateway would lose is
//! sent after it. When the queue is full the oldest message goes, and is
//! counted: nothing is lost silently.
//!
//! The file holds one record per message: the topic's length (u32,
//! little-endian), the topic, the payload's length (u32, little-endian)
//! and the payload as protobuf.

use std::collections::VecDeque;
use std::io::Write;
use std::path::{Path, PathBuf};

use prost::Message;

use super::edge::Outgoing;
use super::proto::Payload;
use super::topic::Topic;

/// The bounded store-and-forward queue.
#[derive(Debug)]
pub struct Spool {
    capacity: usize,
    queue: VecDeque<Outgoing>,
    /// Messages dropped (the oldest, when full) since the start.
    dropped: u64,
    file: Option<PathBuf>,
}

impl Spool {
    /// A queue of at most `capacity` messages, in memory only.
    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            queue: VecDeque::new(),
            dropped: 0,
            file: None,
        }
    }

    /// The same, mirrored in `file`; the messages a previous run left in it
    /// are queued first (a record cut short by a crash, and what follows
    /// it, is left out).
    pub fn with_file(capacity: usize, file: PathBuf) -> std::io::Result<Self> {
        let mut spool = Self::new(capacity);
        match std::fs::read(&file) {
            Ok(bytes) => {
                for message in read_records(&bytes) {
                    spool.push_memory(message);
                }
            }
            Err(err) if err.kind() == std::io::ErrorKind::NotFound => {}
            Err(err) => return Err(err),
        }
        spool.file = Some(file);
        spool.rewrite()?;
        Ok(spool)
    }

    /// Queues a message, the oldest dropped when full.
    pub fn push(&mut self, message: Outgoing) {
        let dropped = self.push_memory(message);
        let result = if dropped {
            self.rewrite()
        } else if let (Some(file), Some(last)) = (&self.file, self.queue.back()) {
            append(file, last)
        } else {
            Ok(())
        };
        if let Err(err) = result {
            tracing::warn!("sparkplug: store-and-forward file: {err}");
        }
    }

    fn push_memory(&mut self, message: Outgoing) -> bool {
        let full = self.queue.len() >= self.capacity;
        if full {
            self.queue.pop_front();
            self.dropped += 1;
        }
        self.queue.push_back(message);
        full
    }

    /// The queued messages in order, each metric marked historical and
    /// named (not aliased: the aliases of the session that made them may
    /// not be this one's); the queue (and its file) is then empty.
    pub fn drain(&mut self) -> Vec<Outgoing> {
        self.drain_where(|_| true)
    }

    /// [`Spool::drain`] of the messages whose topic `ready` takes (those
    /// of the edge node and of the devices born again: a host must have the
    /// birth that names a message's metrics before it); the others stay
    /// queued, in order.
    pub fn drain_where(&mut self, ready: impl Fn(&Topic) -> bool) -> Vec<Outgoing> {
        let (taken, kept): (VecDeque<Outgoing>, VecDeque<Outgoing>) = self
            .queue
            .drain(..)
            .partition(|message| ready(&message.topic));
        self.queue = kept;
        let messages: Vec<Outgoing> = taken
            .into_iter()
            .map(|mut message| {
                for metric in &mut message.payload.metrics {
                    metric.is_historical = Some(true);
                    if metric.name.is_some() {
                        metric.alias = None;
                    }
                }
                message
            })
            .collect();
        if let Err(err) = self.rewrite() {
            tracing::warn!("sparkplug: store-and-forward file: {err}");
        }
        messages
    }

    pub fn len(&self) -> usize {
        self.queue.len()
    }

    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    /// Messages dropped because the queue was full.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    fn rewrite(&self) -> std::io::Result<()> {
        let Some(file) = &self.file else {
            return Ok(());
        };
        let mut bytes = Vec::new();
        for message in &self.queue {
            write_record(&mut bytes, message);
        }
        write_private(file, &bytes, false)
    }
}

fn append(file: &Path, message: &Outgoing) -> std::io::Result<()> {
    let mut bytes = Vec::new();
    write_record(&mut bytes, message);
    write_private(file, &bytes, true)
}

/// Writes (or appends to) a file only its owner may read, as the data
/// directory's other files.
fn write_private(file: &Path, bytes: &[u8], append: bool) -> std::io::Result<()> {
    let mut options = std::fs::OpenOptions::new();
    options.create(true);
    if append {
        options.append(true);
    } else {
        options.write(true).truncate(true);
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(0o600);
    }
    options.open(file)?.write_all(bytes)
}

fn write_record(out: &mut Vec<u8>, message: &Outgoing) {
    let topic = message.topic.to_string();
    let payload = message.payload.encode_to_vec();
    out.extend_from_slice(&(topic.len() as u32).to_le_bytes());
    out.extend_from_slice(topic.as_bytes());
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(&payload);
}

/// The records of a spool file, up to the first one that is cut short or
/// malformed.
pub fn read_records(mut bytes: &[u8]) -> Vec<Outgoing> {
    fn take<'a>(bytes: &mut &'a [u8]) -> Option<&'a [u8]> {
        let len = u32::from_le_bytes(bytes.get(..4)?.try_into().ok()?) as usize;
        let field = bytes.get(4..4 + len)?;
        *bytes = &bytes[4 + len..];
        Some(field)
    }
    let mut messages = Vec::new();
    while !bytes.is_empty() {
        let Some(topic) = take(&mut bytes) else { break };
        let Some(payload) = take(&mut bytes) else {
            break;
        };
        let topic = std::str::from_utf8(topic).ok().and_then(Topic::parse);
        let payload = Payload::decode(payload).ok();
        let (Some(topic), Some(payload)) = (topic, payload) else {
            break;
        };
        messages.push(Outgoing { topic, payload });
    }
    messages
}
