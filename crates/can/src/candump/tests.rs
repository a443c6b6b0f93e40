use super::format::*;
use super::record::*;
use super::replay::*;
use std::path::{Path, PathBuf};
use std::time::Duration;

use tokio::time::Instant;

use crate::bus::{Bus, BusKind, BusState, BusStatus, DEFAULT_RX_QUEUE};
use crate::frame::{Frame, TimedFrame, Timestamp};

use crate::bus::BusError;
use crate::frame::{CanId, Direction, FdFlags};
use crate::hub::VirtualHub;

fn std_id(raw: u32) -> CanId {
    CanId::standard(raw).unwrap()
}

fn data(id: u32, bytes: &[u8]) -> Frame {
    Frame::new(std_id(id), bytes).unwrap()
}

fn timed(frame: Frame, micros: u64) -> TimedFrame {
    TimedFrame {
        frame,
        timestamp: Timestamp::from_micros(micros),
        direction: Direction::Rx,
    }
}

/// A log file in the temporary directory, removed when dropped.
struct TempLog(PathBuf);

impl TempLog {
    fn new(name: &str, contents: &[u8]) -> Self {
        let dir = std::env::temp_dir().join(format!("candeck-candump-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(name);
        std::fs::write(&path, contents).unwrap();
        Self(path)
    }
}

impl Drop for TempLog {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

fn every_kind() -> Vec<Frame> {
    let fd_data: Vec<u8> = (0..64).collect();
    vec![
        data(0x123, &[0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88]),
        data(0x000, &[]),
        data(0x7FF, &[0xFF]),
        Frame::new(CanId::Extended(0x1FFF_FFFF), &[1, 2]).unwrap(),
        Frame::new(CanId::Extended(0x123), &[]).unwrap(),
        Frame::remote(std_id(0x701), 0).unwrap(),
        Frame::remote(CanId::Extended(0x1ABCDE), 8).unwrap(),
        Frame::fd(std_id(0x10), &[0xAA, 0xBB], FdFlags::default()).unwrap(),
        Frame::fd(
            CanId::Extended(0x1234),
            &fd_data,
            FdFlags {
                brs: true,
                esi: true,
            },
        )
        .unwrap(),
        Frame::fd(
            std_id(0x11),
            &[0x5A; 12],
            FdFlags {
                brs: true,
                esi: false,
            },
        )
        .unwrap(),
        Frame::error(0x004, [0, 0x0C, 0, 0, 0, 0, 0, 0]).unwrap(),
        Frame::error(0x040, [0; 8]).unwrap(),
    ]
}

async fn written(iface: &str, frames: &[TimedFrame]) -> String {
    let mut writer = LogWriter::new(Vec::new(), iface);
    for frame in frames {
        writer.write(frame).await.unwrap();
    }
    writer.flush().await.unwrap();
    String::from_utf8(writer.into_inner()).unwrap()
}

#[tokio::test]
async fn writes_frames_in_candump_spelling() {
    let frames: Vec<TimedFrame> = every_kind()
        .into_iter()
        .enumerate()
        .map(|(i, frame)| timed(frame, 1_436_509_052_249_713 + i as u64))
        .collect();
    let text = written("can0", &frames).await;
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(
        lines[..8],
        [
            "(1436509052.249713) can0 123#1122334455667788",
            "(1436509052.249714) can0 000#",
            "(1436509052.249715) can0 7FF#FF",
            "(1436509052.249716) can0 1FFFFFFF#0102",
            "(1436509052.249717) can0 00000123#",
            "(1436509052.249718) can0 701#R",
            "(1436509052.249719) can0 001ABCDE#R8",
            // candump shows CANFD_FDF (0x4) in the flags digit.
            "(1436509052.249720) can0 010##4AABB",
        ]
    );
    assert!(lines[8].starts_with("(1436509052.249721) can0 00001234##7000102"));
    assert_eq!(
        lines[9],
        format!("(1436509052.249722) can0 011##5{}", "5A".repeat(12))
    );
    assert_eq!(
        lines[10],
        "(1436509052.249723) can0 20000004#000C000000000000"
    );
    assert_eq!(
        lines[11],
        "(1436509052.249724) can0 20000040#0000000000000000"
    );
    assert!(text.ends_with('\n'));
    assert_eq!(lines.len(), 12);
}

#[tokio::test]
async fn interface_names_with_white_space_stay_readable() {
    let text = written("my bus", &[timed(data(1, &[]), 0)]).await;
    assert_eq!(text, "(0.000000) my_bus 001#\n");
    let text = written("", &[timed(data(1, &[]), 0)]).await;
    assert_eq!(text, "(0.000000) can 001#\n");
}

#[tokio::test]
async fn every_frame_kind_survives_a_write_and_read_round_trip() {
    let frames: Vec<TimedFrame> = every_kind()
        .into_iter()
        .enumerate()
        .map(|(i, frame)| timed(frame, 1_000_000 * i as u64 + 999_999))
        .collect();
    let text = written("vcan0", &frames).await;
    let read = read_log_from(text.as_bytes(), Path::new("round.log")).unwrap();
    assert_eq!(read.len(), frames.len());
    for (logged, original) in read.iter().zip(&frames) {
        assert_eq!(logged.frame, original.frame);
        assert_eq!(logged.timestamp, original.timestamp);
        assert_eq!(logged.iface, "vcan0");
    }
    // And a line prints back as it was read.
    let line = read[8].to_string();
    assert_eq!(
        format!("{line}\n"),
        text.lines().nth(8).unwrap().to_string() + "\n"
    );
}

#[test]
fn reads_candump_logs_skipping_blank_lines() {
    let text = "\n(1436509052.249713) can0 123#1122334455667788\r\n   \n\
                (1436509052.250000) can1 00000123#R4 T\n\
                (1436509053.000001) can0 701#7F";
    let read = read_log_from(text.as_bytes(), Path::new("x.log")).unwrap();
    assert_eq!(
        read,
        vec![
            LoggedFrame {
                timestamp: Timestamp::from_micros(1_436_509_052_249_713),
                iface: "can0".into(),
                frame: data(0x123, &[0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88]),
            },
            LoggedFrame {
                timestamp: Timestamp::from_micros(1_436_509_052_250_000),
                iface: "can1".into(),
                frame: Frame::remote(CanId::Extended(0x123), 4).unwrap(),
            },
            LoggedFrame {
                timestamp: Timestamp::from_micros(1_436_509_053_000_001),
                iface: "can0".into(),
                frame: data(0x701, &[0x7F]),
            },
        ]
    );
}

#[test]
fn empty_logs_read_as_no_frames() {
    for text in ["", "\n", "  \n\r\n\n"] {
        assert_eq!(
            read_log_from(text.as_bytes(), Path::new("e.log")).unwrap(),
            vec![]
        );
    }
    let file = TempLog::new("empty.log", b"");
    assert_eq!(read_log(&file.0).unwrap(), vec![]);
}

fn problem_with(line: &[u8]) -> String {
    let mut text = b"(1.000000) can0 123#00\n\n".to_vec();
    text.extend_from_slice(line);
    text.extend_from_slice(b"\n(2.000000) can0 123#00\n");
    let err = read_log_from(&text[..], Path::new("logs/bad.log")).unwrap_err();
    let message = err.to_string();
    let LogError::Line {
        line,
        path,
        problem,
    } = err
    else {
        panic!("expected a line error, got {message}");
    };
    assert_eq!((line, path.as_path()), (3, Path::new("logs/bad.log")));
    assert!(message.starts_with("logs/bad.log:3: "), "{message}");
    problem
}

#[test]
fn malformed_lines_name_the_file_the_line_and_the_problem() {
    let cases: &[(&[u8], &str)] = &[
        (
            b"(1436509052.24971) can0 123#00",
            "timestamp `(1436509052.24971)` is not `(SECONDS.MICROSECONDS)`",
        ),
        (b"(abc.000000) can0 123#00", "timestamp `(abc.000000)`"),
        (
            b"1436509052.249713 can0 123#00",
            "timestamp `1436509052.249713`",
        ),
        (
            b"(1.000000) can0 1234#00",
            "identifier `1234` has 4 hex digits; candump writes 3 (standard) or 8 (extended)",
        ),
        (b"(1.000000) can0 12#00", "identifier `12` has 2 hex digits"),
        (
            b"(1.000000) can0 800#00",
            "standard identifier 0x800 is above 0x7FF",
        ),
        (
            b"(1.000000) can0 20000004#000C00000000000000",
            "an error frame carries at most 8 data bytes, not 9",
        ),
        (
            b"(1.000000) can0 123#112233445566778899",
            "a classic CAN frame carries at most 8 data bytes, not 9",
        ),
        (
            b"(1.000000) can0 123#R9",
            "a remote frame requests at most 8 bytes, not 9",
        ),
        (
            b"(1.000000) can0 123#RX",
            "remote frame length `X` is not one hex digit",
        ),
        (
            b"(1.000000) can0 123#112",
            "data `112` has an odd number of hex digits",
        ),
        (b"(1.000000) can0 123#GG", "data `GG` is not hexadecimal"),
        (
            b"(1.000000) can0 XYZ#00",
            "identifier `XYZ` is not hexadecimal",
        ),
        (
            b"(1.000000) can0 12300",
            "frame `12300` has no `#` between identifier and data",
        ),
        (
            b"(1.000000) can0 123#1122334455667788_E",
            "the `_DLC` suffix",
        ),
        (
            b"(1.000000) can0 123##",
            "CAN FD frame `123##` lacks the flags digit after `##`",
        ),
        (b"(1.000000) can0", "line ends early"),
        (b"hello world", "timestamp `hello`"),
        (
            b"(1.000000) can0 123#00 X",
            "`X` after the frame is not a direction (`R` or `T`)",
        ),
        (b"(1.000000) can0 123#\xff\xfe", "line is not UTF-8 text"),
    ];
    for (line, expected) in cases {
        let problem = problem_with(line);
        assert!(
            problem.contains(expected),
            "{:?}: {problem:?} lacks {expected:?}",
            String::from_utf8_lossy(line)
        );
    }
    let fd_too_long = format!("(1.000000) can0 123##1{}", "00".repeat(65));
    assert_eq!(
        problem_with(fd_too_long.as_bytes()),
        "a CAN FD frame carries at most 64 data bytes, not 65"
    );
}

#[test]
fn overlong_lines_are_refused_without_reading_them_whole() {
    let long = vec![b'A'; MAX_LINE + 10];
    assert_eq!(problem_with(&long), "line is longer than 64 KiB");
    // Exactly at the limit is read, and found wanting on its own terms.
    let mut at_limit = b"(1.000000) can0 123#".to_vec();
    at_limit.resize(MAX_LINE, b'0');
    assert!(problem_with(&at_limit).contains("classic CAN frame carries at most 8"));
}

#[test]
fn garbage_never_panics() {
    let inputs: &[&[u8]] = &[
        b"(",
        b")",
        b"()",
        b"(.)",
        b"(1.)",
        b"(.000000)",
        b"(99999999999999999999.000000) a 1#",
        b"(1.000000) a #",
        b"(1.000000) a ##",
        b"(1.000000) a ###",
        b"(1.000000) a 123#R",
        b"(1.000000) a \xc3\xa9#00",
        b"\0\0\0",
        b"(1.000000)  can0 123#00",
        b"\t",
        b"(1.000000) a 20000000#",
        b"(1.000000) a 20000000#R",
        b"(1.000000) a 20000000##0",
    ];
    for input in inputs {
        let _ = read_log_from(*input, Path::new("g.log"));
    }
    // Every single byte value on its own line.
    let all: Vec<u8> = (0..=255u8).flat_map(|b| [b, b'\n']).collect();
    let _ = read_log_from(&all[..], Path::new("g.log"));
}

#[test]
fn a_missing_file_is_named() {
    let err = read_log("/nonexistent/candeck/missing.log").unwrap_err();
    assert!(matches!(err, LogError::Read { .. }));
    assert!(
        err.to_string()
            .starts_with("cannot read /nonexistent/candeck/missing.log: "),
        "{err}"
    );
}

async fn wait_for_receiver(hub: &VirtualHub) {
    while hub.receivers() == 0 {
        tokio::task::yield_now().await;
    }
}

#[tokio::test]
async fn record_bus_writes_what_the_monitor_sees_and_counts_losses() {
    let hub = VirtualHub::with_queue("line", 4);
    let recorded = hub.attach();
    let other = hub.attach();
    let (stop_tx, stop_rx) = tokio::sync::oneshot::channel::<()>();
    let task = tokio::spawn({
        let recorded = recorded.clone();
        async move {
            let mut out = Vec::new();
            let stop = async move {
                let _ = stop_rx.await;
            };
            let summary = record_bus(&recorded, "can0", &mut out, None, stop)
                .await
                .unwrap();
            (summary, String::from_utf8(out).unwrap())
        }
    });
    wait_for_receiver(&hub).await;
    // Ten frames before the recorder runs again: it can only keep four.
    for i in 0..10 {
        other.send(data(0x100 + i, &[i as u8])).await.unwrap();
    }
    recorded.send(data(0x7FF, &[])).await.unwrap();
    tokio::task::yield_now().await;
    stop_tx.send(()).unwrap();
    let (summary, text) = task.await.unwrap();
    assert_eq!(
        summary,
        RecordSummary {
            written: 4,
            lost: 7
        }
    );
    let bodies: Vec<&str> = text.lines().map(|l| field(l, 2)).collect();
    assert_eq!(bodies, ["107#07", "108#08", "109#09", "7FF#"]);
    assert!(text.lines().all(|l| field(l, 1) == "can0"));
    assert_eq!(recorded.counters().rx_overruns, 7);
}

#[tokio::test]
async fn record_bus_stops_after_max_frames() {
    let hub = VirtualHub::new("line");
    let recorded = hub.attach();
    let other = hub.attach();
    let task = tokio::spawn({
        let recorded = recorded.clone();
        async move {
            let mut out = Vec::new();
            let summary = record_bus(&recorded, "x", &mut out, Some(3), std::future::pending())
                .await
                .unwrap();
            (summary, out)
        }
    });
    wait_for_receiver(&hub).await;
    for i in 0..5 {
        other.send(data(i, &[])).await.unwrap();
    }
    let (summary, out) = task.await.unwrap();
    assert_eq!(
        summary,
        RecordSummary {
            written: 3,
            lost: 0
        }
    );
    assert_eq!(String::from_utf8(out).unwrap().lines().count(), 3);
}

#[test]
fn replay_query_reads_speed_loop_and_iface() {
    assert_eq!(ReplayOptions::parse_query(""), Ok(ReplayOptions::default()));
    assert_eq!(
        ReplayOptions::parse_query("speed=4&loop&iface=can0"),
        Ok(ReplayOptions {
            speed: 4.0,
            looping: true,
            iface: Some("can0".into())
        })
    );
    let max = ReplayOptions::parse_query("speed=max").unwrap();
    assert_eq!(max.speed, f64::INFINITY);
    assert_eq!(
        ReplayOptions::parse_query("speed=MAX").unwrap().speed,
        f64::INFINITY
    );
    assert_eq!(
        ReplayOptions::parse_query("speed=0.25").unwrap().speed,
        0.25
    );
    assert!(ReplayOptions::parse_query("loop=true").unwrap().looping);
    assert!(!ReplayOptions::parse_query("loop=false").unwrap().looping);
    // Stray separators are harmless.
    assert!(ReplayOptions::parse_query("&loop&").unwrap().looping);
}

#[test]
fn replay_query_refuses_what_it_does_not_understand() {
    let cases = [
        ("speed=0", "replay speed must be above 0, not 0"),
        ("speed=-2", "replay speed must be above 0, not -2"),
        ("speed=NaN", "replay speed must be above 0, not NaN"),
        ("speed=fast", "replay speed `fast` is not a number or `max`"),
        ("speed", "replay option `speed` needs a value: `speed=...`"),
        ("iface=", "replay option `iface` needs a value: `iface=...`"),
        ("loop=maybe", "`loop=maybe`: loop takes true or false"),
        ("speed=2&speed=3", "replay option `speed` is given twice"),
        (
            "rate=2",
            "unknown replay option `rate` (known: speed, loop, iface)",
        ),
    ];
    for (query, message) in cases {
        assert_eq!(
            ReplayOptions::parse_query(query),
            Err(message.to_string()),
            "{query}"
        );
    }
}

#[test]
fn replay_options_print_as_the_query_they_come_from() {
    for query in [
        "",
        "speed=4",
        "speed=0.5&loop",
        "speed=max&iface=can1",
        "loop&iface=vcan0",
    ] {
        let options = ReplayOptions::parse_query(query).unwrap();
        assert_eq!(options.to_string(), query);
    }
}

const TIMED_LOG: &str = "(1000.000000) can0 100#01\n\
                         (1000.100000) can1 200#02\n\
                         (1000.350000) can0 300#03\n";

/// Receives `count` frames, each with the paused-clock time it came at,
/// counted from `start`.
async fn receive(bus: &Bus, count: usize) -> Vec<(u64, TimedFrame)> {
    let start = Instant::now();
    let mut rx = bus.subscribe();
    let mut got = Vec::new();
    for _ in 0..count {
        let frame = rx.recv().await.unwrap();
        got.push((start.elapsed().as_micros() as u64, frame));
    }
    got
}

fn ids(got: &[(u64, TimedFrame)]) -> Vec<(u64, u32)> {
    got.iter()
        .map(|(at, f)| (*at, f.frame.id().raw()))
        .collect()
}

#[tokio::test(start_paused = true)]
async fn replay_plays_frames_at_their_recorded_times() {
    let log = TempLog::new("timed.log", TIMED_LOG.as_bytes());
    let bus = open_replay(&log.0, ReplayOptions::default()).await.unwrap();
    let got = receive(&bus, 3).await;
    assert_eq!(ids(&got), [(0, 0x100), (100_000, 0x200), (350_000, 0x300)]);
    // Stamped with play time, spaced as recorded.
    let stamps: Vec<u64> = got.iter().map(|(_, f)| f.timestamp.as_micros()).collect();
    assert_eq!(stamps[1] - stamps[0], 100_000);
    assert_eq!(stamps[2] - stamps[0], 350_000);
    assert!(got.iter().all(|(_, f)| f.direction == Direction::Rx));
}

#[tokio::test(start_paused = true)]
async fn replay_speed_scales_the_time_between_frames() {
    let log = TempLog::new("scaled.log", TIMED_LOG.as_bytes());
    let options = ReplayOptions::parse_query("speed=2").unwrap();
    let bus = open_replay(&log.0, options).await.unwrap();
    assert_eq!(
        ids(&receive(&bus, 3).await),
        [(0, 0x100), (50_000, 0x200), (175_000, 0x300)]
    );

    let options = ReplayOptions::parse_query("speed=0.5").unwrap();
    let bus = open_replay(&log.0, options).await.unwrap();
    assert_eq!(
        ids(&receive(&bus, 3).await),
        [(0, 0x100), (200_000, 0x200), (700_000, 0x300)]
    );
}

#[tokio::test(start_paused = true)]
async fn replay_at_max_speed_does_not_wait() {
    let log = TempLog::new("max.log", TIMED_LOG.as_bytes());
    let options = ReplayOptions {
        speed: ReplayOptions::MAX_SPEED,
        ..ReplayOptions::default()
    };
    let bus = open_replay(&log.0, options).await.unwrap();
    assert_eq!(
        ids(&receive(&bus, 3).await),
        [(0, 0x100), (0, 0x200), (0, 0x300)]
    );
}

#[tokio::test(start_paused = true)]
async fn a_max_speed_replay_waits_for_a_reader_that_keeps_reading() {
    let mut text = String::new();
    let total = DEFAULT_RX_QUEUE * 3;
    for i in 0..total {
        text.push_str(&format!(
            "(1.{:06}) can0 123#{:02X}\n",
            i % 1_000_000,
            i % 256
        ));
    }
    let log = TempLog::new("many.log", text.as_bytes());
    let bus = open_replay(&log.0, ReplayOptions::parse_query("speed=max").unwrap())
        .await
        .unwrap();
    let mut rx = bus.subscribe();
    for i in 0..total {
        let frame = rx.recv().await.unwrap();
        assert_eq!(frame.frame.data(), [(i % 256) as u8]);
        if i % 1000 == 0 {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    }
    assert_eq!(bus.counters().rx_overruns, 0);
}

#[tokio::test(start_paused = true)]
async fn a_looping_replay_starts_over_one_average_gap_after_the_end() {
    let log = TempLog::new("loop.log", TIMED_LOG.as_bytes());
    let bus = open_replay(&log.0, ReplayOptions::parse_query("loop").unwrap())
        .await
        .unwrap();
    let got = receive(&bus, 7).await;
    // 350 ms over two gaps: the next pass starts 175 ms after the last frame.
    assert_eq!(
        ids(&got),
        [
            (0, 0x100),
            (100_000, 0x200),
            (350_000, 0x300),
            (525_000, 0x100),
            (625_000, 0x200),
            (875_000, 0x300),
            (1_050_000, 0x100),
        ]
    );
    let stamps: Vec<u64> = got.iter().map(|(_, f)| f.timestamp.as_micros()).collect();
    assert_eq!(stamps[6] - stamps[0], 1_050_000);
    assert_eq!(bus.state(), BusState::Up);
}

#[tokio::test(start_paused = true)]
async fn a_looping_single_frame_log_does_not_spin() {
    let log = TempLog::new("single.log", b"(5.000000) can0 001#\n");
    let options = ReplayOptions::parse_query("loop").unwrap();
    let bus = open_replay(&log.0, options).await.unwrap();
    let got = receive(&bus, 3).await;
    assert_eq!(ids(&got), [(0, 1), (1_000, 1), (2_000, 1)]);
}

#[tokio::test(start_paused = true)]
async fn an_interface_filter_plays_only_that_interface() {
    let log = TempLog::new("filter.log", TIMED_LOG.as_bytes());
    let options = ReplayOptions::parse_query("iface=can1").unwrap();
    let bus = open_replay(&log.0, options).await.unwrap();
    // The log's time starts at the first frame played.
    assert_eq!(ids(&receive(&bus, 1).await), [(0, 0x200)]);
    let mut status = bus.watch_status();
    status
        .wait_for(|s| s.state == BusState::Down)
        .await
        .unwrap();

    let options = ReplayOptions::parse_query("iface=can0").unwrap();
    let bus = open_replay(&log.0, options).await.unwrap();
    assert_eq!(ids(&receive(&bus, 2).await), [(0, 0x100), (350_000, 0x300)]);
}

#[tokio::test(start_paused = true)]
async fn a_finished_replay_goes_down() {
    let log = TempLog::new("finish.log", TIMED_LOG.as_bytes());
    let bus = open_replay(&log.0, ReplayOptions::default()).await.unwrap();
    assert_eq!(bus.status(), BusStatus::up());
    let start = Instant::now();
    let mut rx = bus.subscribe();
    let mut status = bus.watch_status();
    status
        .wait_for(|s| s.state == BusState::Down)
        .await
        .unwrap();
    assert_eq!(start.elapsed(), Duration::from_millis(350));
    assert_eq!(
        bus.status(),
        BusStatus::new(BusState::Down, "replay finished")
    );
    // Every frame is still there to read.
    for id in [0x100, 0x200, 0x300] {
        assert_eq!(rx.recv().await.unwrap().frame.id().raw(), id);
    }
    assert_eq!(bus.counters().rx_frames, 3);
}

#[tokio::test(start_paused = true)]
async fn playback_waits_for_its_first_reader() {
    let log = TempLog::new("late.log", TIMED_LOG.as_bytes());
    let bus = open_replay(&log.0, ReplayOptions::default()).await.unwrap();
    tokio::time::sleep(Duration::from_secs(10)).await;
    assert_eq!(ids(&receive(&bus, 2).await), [(0, 0x100), (100_000, 0x200)]);
}

#[tokio::test(start_paused = true)]
async fn a_replay_is_read_only_and_named_after_its_file() {
    let log = TempLog::new("bench-run.log", TIMED_LOG.as_bytes());
    let options = ReplayOptions::parse_query("speed=4&loop").unwrap();
    let bus = open_replay(&log.0, options).await.unwrap();
    assert_eq!(bus.name(), "bench-run");
    assert_eq!(bus.kind(), BusKind::Replay);
    assert_eq!(
        bus.spec(),
        format!("replay:{}?speed=4&loop", log.0.display())
    );
    assert_eq!(
        bus.send(data(1, &[])).await,
        Err(BusError::ReadOnly("bench-run".into()))
    );
    assert_eq!(
        bus.try_send(data(1, &[])),
        Err(BusError::ReadOnly("bench-run".into()))
    );
    let plain = open_replay(&log.0, ReplayOptions::default()).await.unwrap();
    assert_eq!(plain.spec(), format!("replay:{}", log.0.display()));
}

#[tokio::test]
async fn opening_a_bad_replay_names_the_file_and_line() {
    let log = TempLog::new("broken.log", b"(1.000000) can0 123#00\n(1.5) can0 123#00\n");
    let err = open_replay(&log.0, ReplayOptions::default())
        .await
        .unwrap_err();
    assert!(matches!(
        err,
        ReplayError::Log(LogError::Line { line: 2, .. })
    ));
    assert!(
        err.to_string()
            .starts_with(&format!("{}:2: timestamp `(1.5)`", log.0.display())),
        "{err}"
    );

    let missing = open_replay("/nonexistent/x.log", ReplayOptions::default())
        .await
        .unwrap_err();
    assert!(
        missing
            .to_string()
            .starts_with("cannot read /nonexistent/x.log: "),
        "{missing}"
    );

    let empty = TempLog::new("nothing.log", b"\n\n");
    let err = open_replay(&empty.0, ReplayOptions::default())
        .await
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        format!("{}: the log has no frames to replay", empty.0.display())
    );

    let log = TempLog::new("ifaces.log", TIMED_LOG.as_bytes());
    let options = ReplayOptions::parse_query("iface=can7").unwrap();
    let err = open_replay(&log.0, options).await.unwrap_err();
    assert_eq!(
        err.to_string(),
        format!(
            "{}: no frames from interface can7; the log has can0, can1",
            log.0.display()
        )
    );

    for speed in [0.0, -1.0, f64::NAN, f64::NEG_INFINITY] {
        let options = ReplayOptions {
            speed,
            ..ReplayOptions::default()
        };
        let err = open_replay(&log.0, options).await.unwrap_err();
        assert!(matches!(err, ReplayError::Speed(_)), "{speed}");
    }
}

#[tokio::test(start_paused = true)]
async fn a_replayed_log_records_back_to_the_same_frames() {
    let log = TempLog::new("again.log", TIMED_LOG.as_bytes());
    let bus = open_replay(&log.0, ReplayOptions::default()).await.unwrap();
    let mut status = bus.watch_status();
    let stop = async move {
        let _ = status.wait_for(|s| s.state == BusState::Down).await;
    };
    let mut out = Vec::new();
    let summary = record_bus(&bus, "can0", &mut out, None, stop)
        .await
        .unwrap();
    assert_eq!(
        summary,
        RecordSummary {
            written: 3,
            lost: 0
        }
    );
    let read = read_log_from(&out[..], Path::new("out.log")).unwrap();
    let frames: Vec<Frame> = read.iter().map(|l| l.frame).collect();
    assert_eq!(
        frames,
        [data(0x100, &[1]), data(0x200, &[2]), data(0x300, &[3])]
    );
}
