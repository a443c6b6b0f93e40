//! The frames topics' feed (issue 30): one task per bus, while anyone
//! streams its frames, reads the bus's monitor and publishes the frames in
//! batches, each frame rendered to JSON once, for every session.
//!
//! Before it, each session read the monitor itself, woke for each frame,
//! and serialised its own copy of every frame: 32 sessions on a bus of
//! 8,000 frames/s were 256,000 wake-ups and as many serialisations a
//! second, and the bus reader, SDO and REST waited behind them. Now a
//! session wakes once per batch, at most [`MAX_PUBLISH_HZ`] times a second
//! (a browser draws 60), and copies text.
//!
//! A batch is published as soon as a frame comes when the last one is at
//! least a period old (a quiet bus's frames are not held back), else at the
//! end of the period with everything that came meanwhile.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, Weak};

use tokio::sync::broadcast;
use tokio::task::AbortHandle;
use tokio::time::Instant;

use super::super::frames::BusFrame;
use crate::can::{CanId, FrameReceiver, RecvError, TimedFrame};
use crate::gateway::{MAX_PUBLISH_HZ, ServedBus, period_at_most};

/// Batches a session's forwarding task may fall behind the feed before it
/// loses the oldest (counted as lagged frames): 640 ms at the feed's rate.
const FEED_QUEUE: usize = 64;

/// The most frames in one batch; more waiting go in the next one at once.
/// A topic queues no more for a client anyway ([`super::FRAME_QUEUE`]).
const MAX_BATCH: usize = super::FRAME_QUEUE;

/// Frames of one bus, each rendered once as `GET .../frames` gives it.
#[derive(Debug, Default)]
pub(super) struct FrameBatch {
    frames: Vec<RenderedFrame>,
    /// Frames the feed lost (it fell behind the bus) since the last batch.
    pub(super) lost: u64,
    /// Frames the feed read or lost before this batch's `lost`: a reader
    /// that lost batches can tell how many frames they held.
    pub(super) before: u64,
}

/// One frame, rendered.
#[derive(Debug, Clone)]
pub(super) struct RenderedFrame {
    /// The raw identifier (without the extended flag), for `?ids=`.
    pub(super) id: u32,
    /// The frame's JSON object. A topic of some identifiers keeps its
    /// frames' text alone, not their batches: the memory a client that does
    /// not read holds stays that of the frames it is owed.
    pub(super) json: Arc<str>,
}

impl FrameBatch {
    pub(super) fn len(&self) -> usize {
        self.frames.len()
    }

    pub(super) fn frames(&self) -> &[RenderedFrame] {
        &self.frames
    }

    /// The frames read or lost up to the end of this batch.
    pub(super) fn through(&self) -> u64 {
        self.before + self.lost + self.len() as u64
    }

    pub(super) fn push(&mut self, frame: &TimedFrame) {
        let json = serde_json::to_string(&BusFrame::from(frame)).unwrap_or_else(|_| "{}".into());
        self.frames.push(RenderedFrame {
            id: match frame.frame.id() {
                CanId::Standard(raw) => u32::from(raw),
                CanId::Extended(raw) => raw,
            },
            json: Arc::from(json),
        });
    }
}

/// The feeds of the buses whose frames someone streams, by bus name.
#[derive(Debug, Default)]
pub struct FrameFeeds {
    feeds: Mutex<HashMap<String, Weak<Feed>>>,
}

/// One bus's feed; its task ends when the last receiver is dropped.
#[derive(Debug)]
struct Feed {
    batches: broadcast::WeakSender<Arc<FrameBatch>>,
    task: AbortHandle,
}

impl Drop for Feed {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// A session's share of a bus's feed.
pub(super) struct FeedReceiver {
    batches: broadcast::Receiver<Arc<FrameBatch>>,
    _feed: Arc<Feed>,
}

/// Why a [`FeedReceiver`] has no batch.
pub(super) enum FeedError {
    /// This many batches went before the receiver read them.
    Lagged,
    /// The bus is gone.
    Closed,
}

impl FeedReceiver {
    pub(super) async fn recv(&mut self) -> Result<Arc<FrameBatch>, FeedError> {
        match self.batches.recv().await {
            Ok(batch) => Ok(batch),
            Err(broadcast::error::RecvError::Lagged(_)) => Err(FeedError::Lagged),
            Err(broadcast::error::RecvError::Closed) => Err(FeedError::Closed),
        }
    }
}

impl FrameFeeds {
    /// The batches of `served`'s frames from now on: the bus's feed, started
    /// by its first reader.
    pub(super) fn subscribe(&self, served: &Arc<ServedBus>) -> FeedReceiver {
        let mut feeds = self.feeds.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(feed) = feeds.get(served.name()).and_then(Weak::upgrade)
            && let Some(sender) = feed.batches.upgrade()
        {
            return FeedReceiver {
                batches: sender.subscribe(),
                _feed: feed,
            };
        }
        feeds.retain(|_, feed| feed.strong_count() > 0);
        let (sender, batches) = broadcast::channel(FEED_QUEUE);
        let weak = sender.downgrade();
        // Subscribed before the task starts: nothing sent from now on is
        // missed.
        let monitor = served.monitor();
        let task = tokio::spawn(run(served.clone(), monitor, sender)).abort_handle();
        let feed = Arc::new(Feed {
            batches: weak,
            task,
        });
        feeds.insert(served.name().to_string(), Arc::downgrade(&feed));
        FeedReceiver {
            batches,
            _feed: feed,
        }
    }
}

/// Reads the monitor and publishes batches until the bus closes or the
/// feed is dropped.
async fn run(
    served: Arc<ServedBus>,
    mut monitor: FrameReceiver,
    sender: broadcast::Sender<Arc<FrameBatch>>,
) {
    // The attachment must outlive its receiver.
    let _served = served;
    let period = period_at_most(MAX_PUBLISH_HZ, MAX_PUBLISH_HZ);
    let mut next = Instant::now();
    let mut read: u64 = 0;
    loop {
        let mut batch = FrameBatch {
            before: read,
            ..FrameBatch::default()
        };
        let mut closed = false;
        // A quiet bus: the first frame goes out at once.
        match monitor.recv().await {
            Ok(frame) => batch.push(&frame),
            Err(RecvError::Lagged(n)) => batch.lost += n,
            Err(RecvError::Closed) => return,
        }
        if Instant::now() < next {
            tokio::time::sleep_until(next).await;
        }
        while batch.len() < MAX_BATCH {
            match monitor.try_recv() {
                Ok(Some(frame)) => batch.push(&frame),
                Ok(None) => break,
                Err(RecvError::Lagged(n)) => batch.lost += n,
                Err(RecvError::Closed) => {
                    closed = true;
                    break;
                }
            }
            // The frames of a backlog are rendered a budget at a time, so
            // the bus reader and the rest run in between.
            tokio::task::coop::consume_budget().await;
        }
        read = batch.through();
        // No receiver: the feed is being dropped.
        let _ = sender.send(Arc::new(batch));
        if closed {
            return;
        }
        next = Instant::now() + period;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::{Direction, Frame, Timestamp};

    fn frame(id: u32, data: &[u8]) -> TimedFrame {
        TimedFrame {
            frame: Frame::new(CanId::standard(id).unwrap(), data).unwrap(),
            timestamp: Timestamp(1_000),
            direction: Direction::Rx,
        }
    }

    /// The batch's frames, joined, are what serialising them as a list
    /// gives.
    #[test]
    fn a_batch_renders_each_frame_as_the_frames_list_does() {
        let frames = [frame(0x181, &[1, 2]), frame(0x701, &[5]), frame(0x7E5, &[])];
        let mut batch = FrameBatch::default();
        for frame in &frames {
            batch.push(frame);
        }
        let listed: Vec<BusFrame> = frames.iter().map(BusFrame::from).collect();
        let joined: Vec<&str> = batch.frames().iter().map(|frame| &*frame.json).collect();
        assert_eq!(
            format!("[{}]", joined.join(",")),
            serde_json::to_string(&listed).unwrap()
        );
        let ids: Vec<u32> = batch.frames().iter().map(|frame| frame.id).collect();
        assert_eq!(ids, [0x181, 0x701, 0x7E5]);
    }

    /// Issue 30: the sessions on one bus's frames share one feed, and each
    /// batch, rendered once, is the same for all of them; the feed goes
    /// with its last reader, and the next reader starts another.
    #[tokio::test(start_paused = true)]
    async fn the_readers_of_a_bus_share_each_rendered_batch() {
        let served = Arc::new(
            crate::api::tests::support::open("demo", "virtual:empty?bitrate=unlimited").await,
        );
        let feeds = FrameFeeds::default();
        let mut readers: Vec<FeedReceiver> = (0..5).map(|_| feeds.subscribe(&served)).collect();
        for n in 0..3u8 {
            let frame = crate::can::Frame::new(CanId::standard(0x555).unwrap(), &[n]).unwrap();
            served.send_frame(frame).await.unwrap();
        }
        let mut batches = Vec::new();
        for reader in &mut readers {
            let mut frames = 0;
            let mut got = Vec::new();
            while frames < 3 {
                let Ok(batch) = reader.recv().await else {
                    panic!("a batch");
                };
                frames += batch.len();
                got.push(batch);
            }
            batches.push(got);
        }
        for other in &batches[1..] {
            assert_eq!(other.len(), batches[0].len());
            for (mine, theirs) in batches[0].iter().zip(other) {
                assert!(Arc::ptr_eq(mine, theirs), "one rendering for every reader");
            }
        }
        let first = Arc::downgrade(&readers[0]._feed);
        drop(readers);
        drop(batches);
        assert!(
            first.upgrade().is_none(),
            "the feed goes with its last reader"
        );
        let mut again = feeds.subscribe(&served);
        let frame = crate::can::Frame::new(CanId::standard(0x555).unwrap(), &[9]).unwrap();
        served.send_frame(frame).await.unwrap();
        let Ok(batch) = again.recv().await else {
            panic!("a batch from the new feed");
        };
        assert!(batch.frames()[0].json.contains("\"data\":\"09\""));
    }
}
