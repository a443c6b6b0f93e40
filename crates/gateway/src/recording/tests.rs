//! The recorder against an in-process hub, on a paused clock: what goes in
//! the log, each way a recording stops, where the files go.

use std::pin::Pin;
use std::task::{Context, Poll};

use super::*;
use crate::can::candump::read_log;
use crate::can::{CanId, Frame, VirtualHub};

fn data(id: u32, bytes: &[u8]) -> Frame {
    Frame::new(CanId::standard(id).unwrap(), bytes).unwrap()
}

/// A directory of its own under the temporary directory, removed when
/// dropped.
struct Scratch(PathBuf);

impl Scratch {
    fn new(name: &str) -> Self {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let path = std::env::temp_dir().join(format!(
            "candeck-recording-test-{}-{name}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&path);
        Self(path)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn frames_of(path: &Path) -> Vec<(String, Frame)> {
    read_log(path)
        .unwrap()
        .into_iter()
        .map(|line| (line.iface, line.frame))
        .collect()
}

#[tokio::test(start_paused = true)]
async fn records_what_others_and_the_gateway_send_until_stopped() {
    let hub = VirtualHub::new("bench");
    let gateway = hub.attach();
    let other = hub.attach();
    let recorder = Recorder::new(&gateway, None);
    other.send(data(0x100, &[0])).await.unwrap(); // before: not recorded
    let status = recorder.start(Limits::default()).await.unwrap();
    assert_eq!(status.state, RecordingState::Recording);
    assert_eq!((status.frames, status.lost, status.bytes), (0, 0, 0));
    assert_eq!(status.limits, Some(Limits::default()));
    let file = status.file.clone().unwrap();
    assert!(
        file.starts_with("bench-") && file.ends_with("Z.log"),
        "{file}"
    );
    other.send(data(0x181, &[1, 2])).await.unwrap();
    gateway
        .send(data(0x601, &[0x40, 0, 0x10, 0]))
        .await
        .unwrap();
    other.send(data(0x581, &[0x43])).await.unwrap();
    let stopped = recorder.stop().await.unwrap();
    assert_eq!(stopped.state, RecordingState::Stopped);
    assert_eq!(stopped.stop_reason, Some(StopReason::Asked));
    assert_eq!((stopped.frames, stopped.lost), (3, 0));
    assert!(stopped.stopped.unwrap() >= stopped.started.unwrap());
    other.send(data(0x200, &[])).await.unwrap(); // after: not recorded

    let log = recorder.log().await.unwrap();
    assert_eq!(log.file_name, file);
    assert_eq!(log.len, stopped.bytes);
    assert_eq!(
        frames_of(&log.path),
        [
            ("bench".to_string(), data(0x181, &[1, 2])),
            ("bench".to_string(), data(0x601, &[0x40, 0, 0x10, 0])),
            ("bench".to_string(), data(0x581, &[0x43])),
        ]
    );
    assert_eq!(recorder.status(), stopped);
}

#[tokio::test(start_paused = true)]
async fn a_download_while_recording_has_everything_so_far() {
    let hub = VirtualHub::new("live");
    let gateway = hub.attach();
    let other = hub.attach();
    let recorder = Recorder::new(&gateway, None);
    recorder.start(Limits::default()).await.unwrap();
    for n in 0..5 {
        other.send(data(0x180 + n, &[n as u8])).await.unwrap();
    }
    // Well before the periodic flush.
    let log = recorder.log().await.unwrap();
    let status = recorder.status();
    assert_eq!(status.state, RecordingState::Recording);
    assert_eq!((status.frames, log.len), (5, status.bytes));
    assert_eq!(frames_of(&log.path).len(), 5);
    other.send(data(0x1FF, &[])).await.unwrap();
    assert_eq!(recorder.stop().await.unwrap().frames, 6);
}

#[tokio::test(start_paused = true)]
async fn the_buffer_is_flushed_every_second() {
    let hub = VirtualHub::new("tick");
    let gateway = hub.attach();
    let other = hub.attach();
    let recorder = Recorder::new(&gateway, None);
    recorder.start(Limits::default()).await.unwrap();
    other.send(data(0x123, &[1])).await.unwrap();
    tokio::time::sleep(Duration::from_millis(10)).await;
    let path = lock(&recorder.current).as_ref().unwrap().path.clone();
    assert_eq!(std::fs::metadata(&path).unwrap().len(), 0, "still buffered");
    tokio::time::sleep(FLUSH_EVERY).await;
    assert_eq!(
        std::fs::metadata(&path).unwrap().len(),
        recorder.status().bytes
    );
    assert_ne!(recorder.status().bytes, 0);
}

#[tokio::test(start_paused = true)]
async fn a_recording_stops_at_its_frame_limit() {
    let hub = VirtualHub::new("count");
    let gateway = hub.attach();
    let other = hub.attach();
    let recorder = Recorder::new(&gateway, None);
    let limits = Limits::new(Some(3), None).unwrap();
    recorder.start(limits).await.unwrap();
    for n in 0..5 {
        other.send(data(0x100 + n, &[])).await.unwrap();
    }
    tokio::time::sleep(Duration::from_millis(1)).await;
    let status = recorder.status();
    assert_eq!(status.state, RecordingState::Stopped);
    assert_eq!(status.stop_reason, Some(StopReason::MaxFrames));
    assert_eq!(status.frames, 3);
    let log = recorder.log().await.unwrap();
    let ids: Vec<u32> = frames_of(&log.path)
        .iter()
        .map(|(_, f)| f.id().raw())
        .collect();
    assert_eq!(ids, [0x100, 0x101, 0x102]);
    assert!(matches!(
        recorder.stop().await,
        Err(RecordingError::NotRunning { .. })
    ));
}

/// A download (which flushes the log) that comes while the frames that
/// reach the limit are queued still stops the recording at the limit: the
/// frame after it is not recorded.
#[tokio::test(start_paused = true)]
async fn a_download_at_the_frame_limit_records_no_frame_beyond_it() {
    let hub = VirtualHub::new("count");
    let gateway = hub.attach();
    let other = hub.attach();
    let recorder = Recorder::new(&gateway, None);
    let limits = Limits::new(Some(3), None).unwrap();
    recorder.start(limits).await.unwrap();
    for n in 0..3 {
        other.send(data(0x100 + n, &[])).await.unwrap();
    }
    // Queued for the recorder with the three above, which has not run yet.
    let log = recorder.log().await.unwrap();
    other.send(data(0x1FF, &[])).await.unwrap();
    tokio::time::sleep(Duration::from_millis(1)).await;
    let status = recorder.status();
    assert_eq!(status.state, RecordingState::Stopped);
    assert_eq!(status.stop_reason, Some(StopReason::MaxFrames));
    assert_eq!(status.frames, 3);
    let ids: Vec<u32> = frames_of(&log.path)
        .iter()
        .map(|(_, f)| f.id().raw())
        .collect();
    assert_eq!(ids, [0x100, 0x101, 0x102]);
}

#[tokio::test(start_paused = true)]
async fn a_recording_stops_at_its_time_limit() {
    let hub = VirtualHub::new("clock");
    let gateway = hub.attach();
    let other = hub.attach();
    let recorder = Recorder::new(&gateway, None);
    recorder
        .start(Limits::new(None, Some(2)).unwrap())
        .await
        .unwrap();
    other.send(data(0x700, &[5])).await.unwrap();
    tokio::time::sleep(Duration::from_millis(1999)).await;
    assert_eq!(recorder.status().state, RecordingState::Recording);
    other.send(data(0x701, &[5])).await.unwrap();
    tokio::time::sleep(Duration::from_millis(2)).await;
    let status = recorder.status();
    assert_eq!(status.stop_reason, Some(StopReason::MaxSeconds));
    assert_eq!(status.frames, 2);
    assert_eq!(
        recorder.log().await.unwrap().len,
        status.bytes,
        "flushed when it stopped"
    );
}

#[tokio::test(start_paused = true)]
async fn frames_the_recorder_missed_are_counted() {
    let hub = VirtualHub::with_queue("busy", 4);
    let gateway = hub.attach();
    let other = hub.attach();
    let recorder = Recorder::new(&gateway, None);
    recorder.start(Limits::default()).await.unwrap();
    // Ten frames before the recorder runs again: it can only keep four.
    for n in 0..10 {
        other.try_send(data(0x100 + n, &[])).unwrap();
    }
    let status = recorder.stop().await.unwrap();
    assert_eq!((status.frames, status.lost), (4, 6));
    let ids: Vec<u32> = frames_of(&recorder.log().await.unwrap().path)
        .iter()
        .map(|(_, f)| f.id().raw())
        .collect();
    assert_eq!(ids, [0x106, 0x107, 0x108, 0x109]);
}

#[tokio::test(start_paused = true)]
async fn one_recording_at_a_time() {
    let hub = VirtualHub::new("one");
    let gateway = hub.attach();
    let recorder = Recorder::new(&gateway, None);
    assert_eq!(recorder.status(), RecordingStatus::none());
    assert!(matches!(
        recorder.stop().await,
        Err(RecordingError::NoRecording(_))
    ));
    assert!(matches!(
        recorder.log().await,
        Err(RecordingError::NoRecording(_))
    ));
    recorder.start(Limits::default()).await.unwrap();
    let err = recorder.start(Limits::default()).await.unwrap_err();
    assert!(matches!(err, RecordingError::Running { .. }), "{err}");
    recorder.stop().await.unwrap();
    let err = recorder.stop().await.unwrap_err();
    assert_eq!(
        err.to_string(),
        "the recording of bus one has stopped already (asked)"
    );
}

#[tokio::test(start_paused = true)]
async fn temporary_recordings_replace_each_other_and_go_with_the_recorder() {
    let hub = VirtualHub::new("tmp");
    let gateway = hub.attach();
    let recorder = Recorder::new(&gateway, None);
    recorder.start(Limits::default()).await.unwrap();
    let first = recorder.log().await.unwrap().path;
    recorder.stop().await.unwrap();
    recorder.start(Limits::default()).await.unwrap();
    let second = recorder.log().await.unwrap().path;
    assert_ne!(first, second);
    assert!(!first.exists(), "the last recording is removed");
    assert!(second.exists());
    let dir = second.parent().unwrap().to_path_buf();
    assert!(dir.starts_with(std::env::temp_dir()));
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&dir).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o700);
    }
    drop(recorder);
    assert!(!dir.exists(), "the directory goes with the recorder");
}

#[tokio::test(start_paused = true)]
async fn recordings_in_a_data_dir_are_kept() {
    let scratch = Scratch::new("kept");
    let dir = scratch.0.join("recordings");
    let hub = VirtualHub::new("a very long bus name");
    let gateway = hub.attach();
    let other = hub.attach();
    let recorder = Recorder::new(&gateway, Some(dir.clone()));
    assert_eq!(recorder.iface(), "can0");
    recorder.start(Limits::default()).await.unwrap();
    other.send(data(0x80, &[])).await.unwrap();
    let first = recorder.stop().await.unwrap();
    recorder.start(Limits::default()).await.unwrap();
    let second = recorder.stop().await.unwrap();
    drop(recorder);
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|entry| entry.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    let mut expected = vec![first.file.unwrap(), second.file.unwrap()];
    expected.sort();
    assert_eq!(names, expected);
    // Two in one second get distinct names; spaces become `_`.
    assert!(
        names.iter().all(|n| n.starts_with("a_very_long_bus_name-")),
        "{names:?}"
    );
    let lines = frames_of(&dir.join(&names[0]));
    let lines = if lines.is_empty() {
        frames_of(&dir.join(&names[1]))
    } else {
        lines
    };
    assert_eq!(lines, [("can0".to_string(), data(0x80, &[]))]);
}

#[tokio::test(start_paused = true)]
async fn a_data_dir_that_cannot_be_made_is_an_io_error() {
    let scratch = Scratch::new("blocked");
    std::fs::write(&scratch.0, b"a file, not a directory").unwrap();
    let hub = VirtualHub::new("blocked");
    let recorder = Recorder::new(&hub.attach(), Some(scratch.0.join("recordings")));
    let err = recorder.start(Limits::default()).await.unwrap_err();
    assert!(matches!(err, RecordingError::Io { .. }), "{err}");
    assert_eq!(recorder.status().state, RecordingState::None);
    let _ = std::fs::remove_file(&scratch.0);
}

fn job(bus: &str) -> Job {
    Job {
        bus: bus.into(),
        iface: bus.into(),
        limits: Limits::default(),
        since: tokio::time::Instant::now(),
    }
}

/// Takes `room` bytes, then fails as a full disk does.
struct FullDisk {
    room: usize,
}

impl AsyncWrite for FullDisk {
    fn poll_write(
        mut self: Pin<&mut Self>,
        _: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        if self.room == 0 {
            return Poll::Ready(Err(io::Error::from_raw_os_error(28)));
        }
        let n = buf.len().min(self.room);
        self.room -= n;
        Poll::Ready(Ok(n))
    }

    fn poll_flush(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

#[tokio::test(start_paused = true)]
async fn a_write_error_stops_the_recording_with_its_reason() {
    let hub = VirtualHub::new("full");
    let gateway = hub.attach();
    let other = hub.attach();
    let progress = Arc::new(Progress::default());
    let (_commands, inbox) = mpsc::channel(1);
    let task = tokio::spawn(record(
        gateway.monitor(),
        FullDisk { room: 10 },
        job("full"),
        progress.clone(),
        inbox,
    ));
    other.send(data(0x181, &[1, 2, 3])).await.unwrap();
    // The first flush reaches the disk.
    tokio::time::sleep(FLUSH_EVERY * 2).await;
    task.await.unwrap();
    let end = lock(&progress.end);
    assert_eq!(end.reason, Some(StopReason::DiskError));
    assert!(
        end.error.as_deref().unwrap().contains("No space left"),
        "{:?}",
        end.error
    );
    assert!(end.stopped.is_some());
}

#[tokio::test(start_paused = true)]
async fn a_closed_bus_ends_the_recording() {
    let hub = VirtualHub::new("gone");
    let gateway = hub.attach();
    let other = hub.attach();
    let progress = Arc::new(Progress::default());
    let (_commands, inbox) = mpsc::channel(1);
    let mut out = Vec::new();
    let frames = gateway.monitor();
    other.send(data(0x181, &[1])).await.unwrap();
    drop(gateway);
    record(frames, &mut out, job("gone"), progress.clone(), inbox).await;
    assert_eq!(lock(&progress.end).reason, Some(StopReason::BusClosed));
    assert_eq!(progress.frames.load(Ordering::Relaxed), 1);
    let text = String::from_utf8(out).unwrap();
    assert!(text.ends_with(" gone 181#01\n"), "{text}");
}

#[test]
fn limits_are_checked() {
    assert_eq!(Limits::new(None, None).unwrap(), Limits::default());
    assert_eq!(
        Limits::new(Some(1), Some(MAX_SECONDS)).unwrap(),
        Limits {
            max_frames: 1,
            max_seconds: MAX_SECONDS
        }
    );
    let err = Limits::new(Some(0), None).unwrap_err();
    assert_eq!(
        err.to_string(),
        "max_frames 0: a recording takes 1 to 1000000"
    );
    let err = Limits::new(None, Some(MAX_SECONDS + 1)).unwrap_err();
    assert_eq!(
        err.to_string(),
        "max_seconds 3601: a recording takes 1 to 3600"
    );
}

#[test]
fn interface_names_are_the_bus_name_when_linux_would_take_it() {
    assert_eq!(iface_name("demo"), "demo");
    assert_eq!(iface_name("bench-2_a.b"), "bench-2_a.b");
    assert_eq!(iface_name("fifteen-chars-x"), "fifteen-chars-x");
    for bad in ["", "sixteen-chars-xx", "has space", "a/b", "..", "é"] {
        assert_eq!(iface_name(bad), "can0", "{bad}");
    }
}

#[test]
fn stamps_are_utc_calendar_times() {
    assert_eq!(utc_stamp(Timestamp::from_micros(0)), "19700101T000000Z");
    // 2024-02-29 23:59:59.5 UTC, a leap day.
    assert_eq!(
        utc_stamp(Timestamp::from_micros(1_709_251_199_500_000)),
        "20240229T235959Z"
    );
    assert_eq!(
        utc_stamp(Timestamp::from_micros(4_102_444_800_000_000)),
        "21000101T000000Z"
    );
}

/// What a recording costs and keeps up with: one sender as fast as it can
/// (yielding every 32 frames), the recorder writing 8-byte frames to a
/// file in the temporary directory. Run with
/// `cargo test --release --lib gateway::recording -- --ignored --nocapture`.
#[tokio::test]
#[ignore = "a measurement"]
async fn frames_per_second() {
    const FRAMES: u32 = 500_000;
    let hub = VirtualHub::new("bench");
    let gateway = hub.attach();
    let other = hub.attach();
    let recorder = Recorder::new(&gateway, None);
    recorder.start(Limits::default()).await.unwrap();
    let frame = data(0x181, &[1, 2, 3, 4, 5, 6, 7, 8]);
    let start = std::time::Instant::now();
    for n in 0..FRAMES {
        other.try_send(frame).unwrap();
        if n % 32 == 0 {
            tokio::task::yield_now().await;
        }
    }
    let status = recorder.stop().await.unwrap();
    let elapsed = start.elapsed().as_secs_f64();
    println!(
        "{} frames written, {} lost, {} bytes in {elapsed:.2} s: {:.0} frames/s ({:.0} ns/frame)",
        status.frames,
        status.lost,
        status.bytes,
        f64::from(FRAMES) / elapsed,
        elapsed * 1e9 / f64::from(FRAMES)
    );
    assert_eq!(status.frames + status.lost, u64::from(FRAMES));
}

/// Logs of `bytes` bytes in `dir`, named `n.log`, each modified a minute
/// after the one before (`0.log` the oldest).
fn logs_of(dir: &Path, sizes: &[usize]) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    let start = std::time::SystemTime::UNIX_EPOCH + Duration::from_secs(1_790_000_000);
    sizes
        .iter()
        .enumerate()
        .map(|(n, size)| {
            let path = dir.join(format!("{n}.log"));
            std::fs::write(&path, vec![b'x'; *size]).unwrap();
            let file = std::fs::File::options().write(true).open(&path).unwrap();
            file.set_modified(start + Duration::from_secs(60 * n as u64))
                .unwrap();
            path
        })
        .collect()
}

fn names_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|entry| entry.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn pruning_removes_the_oldest_logs_beyond_the_quota_but_never_a_kept_one() {
    let scratch = Scratch::new("prune");
    let logs = logs_of(&scratch.0, &[100, 100, 100, 100]);
    std::fs::write(scratch.0.join("notes.txt"), vec![b'x'; 1000]).unwrap();
    let quota = RecordingsQuota {
        dir: scratch.0.clone(),
        bytes: 250,
    };
    // The oldest is a bus's last recording: kept, the next two go.
    let pruned = prune(&quota, &logs[..1]).unwrap();
    let names: Vec<&str> = pruned.iter().map(|p| p.file_name.as_str()).collect();
    assert_eq!(names, ["1.log", "2.log"]);
    assert!(pruned.iter().all(|p| p.bytes == 100));
    assert_eq!(names_in(&scratch.0), ["0.log", "3.log", "notes.txt"]);
    // Within the quota: nothing more.
    assert_eq!(prune(&quota, &[]).unwrap(), []);
    // No directory yet: nothing to do.
    let missing = RecordingsQuota {
        dir: scratch.0.join("none"),
        bytes: 0,
    };
    assert_eq!(prune(&missing, &[]).unwrap(), []);
}

#[tokio::test]
async fn the_gateway_audits_each_pruned_recording_as_its_own() {
    use crate::Gateway;
    use crate::history::{EventKind, Query};
    let scratch = Scratch::new("prune-audit");
    logs_of(&scratch.0, &[300, 300, 300]);
    let gateway = Gateway::new([]).with_recordings_quota(RecordingsQuota {
        dir: scratch.0.clone(),
        bytes: 400,
    });
    let pruned = gateway.prune_recordings().await;
    assert_eq!(pruned.len(), 2, "{pruned:?}");
    assert_eq!(names_in(&scratch.0), ["2.log"]);
    let audit = gateway
        .history
        .query(Query {
            kind: Some(EventKind::Audit),
            since_us: None,
            until_us: None,
            channel: None,
            limit: 10,
        })
        .await
        .unwrap();
    let mut items: Vec<String> = audit
        .iter()
        .map(|event| {
            assert_eq!(event.fields["who"], "gateway", "{:?}", event.fields);
            // The gateway's own row: its channel, no HTTP words.
            assert_eq!(event.fields["channel"], "system", "{:?}", event.fields);
            assert_eq!(event.fields["outcome"], "ok", "{:?}", event.fields);
            assert!(
                !event.fields.contains_key("method") && !event.fields.contains_key("path"),
                "{:?}",
                event.fields
            );
            assert_eq!(
                event.fields["operation"], "prune recording (over quota)",
                "{:?}",
                event.fields
            );
            event.fields["item"].as_str().unwrap().to_string()
        })
        .collect();
    items.sort();
    assert_eq!(items, ["0.log", "1.log"]);
    // Without a quota (no --data-dir, or 0), nothing is pruned.
    assert_eq!(Gateway::new([]).prune_recordings().await, []);
}
