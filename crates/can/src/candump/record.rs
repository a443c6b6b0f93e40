//! A bus recorded to a log: the one record loop ([`LogRecorder`]), used by
//! `candeck dump` ([`record_bus`]) and by the gateway's recorder
//! (`crate::gateway::recording`).

use std::future::Future;
use std::io;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use tokio::io::{AsyncWrite, BufWriter};
use tokio::time::{Instant, Interval, MissedTickBehavior};

use super::format::LogWriter;
use crate::bus::{Bus, FrameReceiver, RecvError};
use crate::frame::TimedFrame;

/// When the log is flushed, besides when the recording ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlushPolicy {
    /// Whenever no more frames are waiting, so that a terminal or a pipe
    /// sees each burst at once.
    AfterBurst,
    /// Every period, if something was written since (a file on disk).
    Every(Duration),
}

/// What a recording reports as it runs.
pub trait RecordProgress {
    /// One frame was written, as a line of `bytes` bytes.
    fn written(&self, bytes: usize);
    /// `frames` frames were lost because the recording fell behind the bus.
    fn lost(&self, frames: u64);
}

/// Why a recording cannot go on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ended {
    /// The frame limit is reached.
    MaxFrames,
    /// The bus is closed.
    Closed,
}

/// Why [`LogRecorder::run`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecordEnd<C> {
    /// The control future completed (with this), and what was queued then
    /// is written; [`LogRecorder::ended`] says whether the recording can go
    /// on.
    Control(C),
    /// The recording cannot go on.
    Ended(Ended),
}

/// A recording of a bus's frames as candump `-L` lines: the loop that
/// takes frames from the bus's receiver, writes them, counts what was lost,
/// stops at a frame limit, and flushes by its [`FlushPolicy`].
pub struct LogRecorder<W> {
    log: LogWriter<BufWriter<W>>,
    max_frames: Option<u64>,
    written: u64,
    flush: Option<Interval>,
    dirty: bool,
    ended: Option<Ended>,
    bus: String,
}

impl<W: AsyncWrite + Unpin> LogRecorder<W> {
    /// A recording of the bus `bus` into `out`, its lines naming `iface`;
    /// periodic flushes count from `since`.
    pub fn new(
        out: BufWriter<W>,
        iface: &str,
        bus: &str,
        max_frames: Option<u64>,
        flush: FlushPolicy,
        since: Instant,
    ) -> Self {
        let flush = match flush {
            FlushPolicy::AfterBurst => None,
            FlushPolicy::Every(period) => {
                let mut ticks = tokio::time::interval_at(since + period, period);
                ticks.set_missed_tick_behavior(MissedTickBehavior::Delay);
                Some(ticks)
            }
        };
        Self {
            log: LogWriter::new(out, iface),
            max_frames,
            written: 0,
            flush,
            dirty: false,
            // A limit of 0 frames is reached at once.
            ended: (max_frames == Some(0)).then_some(Ended::MaxFrames),
            bus: bus.to_string(),
        }
    }

    /// Why the recording cannot go on, once it cannot.
    pub fn ended(&self) -> Option<Ended> {
        self.ended
    }

    /// Records frames from `frames` until `control` completes (then writes
    /// what is queued without waiting for more, and returns its output), the
    /// frame limit is reached, or the bus closes. `control` is polled first:
    /// a busy bus would otherwise never let it be seen. Call again to go on.
    pub async fn run<C>(
        &mut self,
        frames: &mut FrameReceiver,
        progress: &impl RecordProgress,
        control: impl Future<Output = C>,
    ) -> io::Result<RecordEnd<C>> {
        tokio::pin!(control);
        loop {
            if let Some(ended) = self.ended {
                return Ok(RecordEnd::Ended(ended));
            }
            let tick = async {
                match &mut self.flush {
                    Some(ticks) => {
                        ticks.tick().await;
                    }
                    None => std::future::pending().await,
                }
            };
            tokio::select! {
                biased;
                output = &mut control => {
                    self.drain(frames, progress).await?;
                    return Ok(RecordEnd::Control(output));
                }
                () = tick => self.flush().await?,
                next = frames.recv() => {
                    self.take(next, progress).await?;
                    if self.flush.is_none() {
                        self.drain(frames, progress).await?;
                        self.flush().await?;
                    }
                }
            }
        }
    }

    /// Handles one receive result.
    async fn take(
        &mut self,
        next: Result<TimedFrame, RecvError>,
        progress: &impl RecordProgress,
    ) -> io::Result<()> {
        match next {
            Ok(frame) => {
                let len = self.log.write(&frame).await?;
                self.dirty = true;
                self.written += 1;
                progress.written(len);
                if self.max_frames.is_some_and(|max| self.written >= max) {
                    self.ended = Some(Ended::MaxFrames);
                }
            }
            Err(RecvError::Lagged(lost)) => {
                progress.lost(lost);
                tracing::warn!(
                    bus = self.bus,
                    lost,
                    "recording fell behind the bus; frames lost"
                );
            }
            Err(RecvError::Closed) => self.ended = Some(Ended::Closed),
        }
        Ok(())
    }

    /// Writes what is queued, without waiting for more, until the recording
    /// cannot go on.
    async fn drain(
        &mut self,
        frames: &mut FrameReceiver,
        progress: &impl RecordProgress,
    ) -> io::Result<()> {
        while self.ended.is_none() {
            let next = match frames.try_recv() {
                Ok(Some(frame)) => Ok(frame),
                Ok(None) => break,
                Err(err) => Err(err),
            };
            self.take(next, progress).await?;
        }
        Ok(())
    }

    /// Flushes what was written since the last flush.
    pub async fn flush(&mut self) -> io::Result<()> {
        if self.dirty {
            self.log.flush().await?;
            self.dirty = false;
        }
        Ok(())
    }
}

/// What [`record_bus`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RecordSummary {
    /// Lines written.
    pub written: u64,
    /// Frames lost because the writer fell behind the bus.
    pub lost: u64,
}

/// [`RecordSummary`] counted as a recording runs.
#[derive(Default)]
struct Counted {
    written: AtomicU64,
    lost: AtomicU64,
}

impl RecordProgress for Counted {
    fn written(&self, _bytes: usize) {
        self.written.fetch_add(1, Ordering::Relaxed);
    }

    fn lost(&self, frames: u64) {
        self.lost.fetch_add(frames, Ordering::Relaxed);
    }
}

/// Writes everything on `bus` (its [`monitor`](Bus::monitor): frames sent
/// through it too) to `out` as candump `-L` lines naming `iface`, until
/// `max_frames` are written or `stop` completes (Ctrl-C, say); frames
/// already queued when `stop` completes are still written. Output is
/// flushed whenever no more frames are waiting, so a terminal or pipe sees
/// each burst at once.
///
/// Frames lost because the writer fell behind are not written, only counted
/// and logged.
///
/// To end a replay's dump when the replay is over, let `stop` wait for the
/// bus to go down:
/// `async move { let _ = status.wait_for(|s| s.state == BusState::Down).await; }`
/// with `status = bus.watch_status()`.
pub async fn record_bus<W, S>(
    bus: &Bus,
    iface: &str,
    out: W,
    max_frames: Option<u64>,
    stop: S,
) -> io::Result<RecordSummary>
where
    W: AsyncWrite + Unpin,
    S: Future<Output = ()>,
{
    let mut frames = bus.monitor();
    let mut recorder = LogRecorder::new(
        BufWriter::new(out),
        iface,
        bus.name(),
        max_frames,
        FlushPolicy::AfterBurst,
        Instant::now(),
    );
    let counted = Counted::default();
    recorder.run(&mut frames, &counted, stop).await?;
    recorder.flush().await?;
    Ok(RecordSummary {
        written: counted.written.into_inner(),
        lost: counted.lost.into_inner(),
    })
}
