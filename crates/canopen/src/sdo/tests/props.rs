//! Properties: neither machine panics or loses track of its deadline on any
//! sequence of frames and timeouts, whether random or a real conversation
//! with frames lost, damaged and injected; and a wired client and server carry
//! any value intact by every method, with or without a lost frame.

use proptest::collection::vec;
use proptest::prelude::*;

use super::wired::{METHODS, Method, link};
use super::*;
use crate::sdo::{ClientConfig, ServerConfig, Step};

/// Something that happens to a machine: a frame on its COB-ID, or time.
#[derive(Debug, Clone)]
enum Event {
    Frame(Vec<u8>),
    Wait(u64),
}

/// Frames of 0–8 bytes, biased toward real command bytes and known objects so
/// that the machines get deep into transfers, not only refuse garbage.
fn frame_bytes() -> impl Strategy<Value = Vec<u8>> {
    let first = prop_oneof![
        any::<u8>(),
        prop::sample::select(vec![
            0x00u8, 0x01, 0x0F, 0x10, 0x1D, 0x20, 0x21, 0x22, 0x23, 0x2F, 0x30, 0x40, 0x41, 0x43,
            0x4F, 0x60, 0x70, 0x80, 0x81, 0x83, 0xA0, 0xA1, 0xA2, 0xA3, 0xA4, 0xC0, 0xC1, 0xC2,
            0xC5, 0xC6, 0xDD,
        ]),
        1u8..=8,
    ];
    let index = prop::sample::select(vec![
        0x1000u16, 0x1001, 0x1008, 0x2000, 0x2001, 0x2003, 0x2FFF,
    ]);
    (
        first,
        index,
        0u8..2,
        any::<[u8; 4]>(),
        0usize..=8,
        any::<bool>(),
    )
        .prop_map(|(first, index, sub, tail, len, small_tail)| {
            let [lo, hi] = index.to_le_bytes();
            let mut data = vec![first, lo, hi, sub];
            // Block acknowledgements and sizes want small numbers.
            data.extend(if small_tail {
                tail.map(|b| b % 8)
            } else {
                tail
            });
            data.truncate(len);
            data
        })
}

fn events() -> impl Strategy<Value = Vec<Event>> {
    vec(
        prop_oneof![
            8 => frame_bytes().prop_map(Event::Frame),
            1 => (0u64..1500).prop_map(Event::Wait),
        ],
        0..60,
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(crate::can::test_support::fuzz_cases(256)))]

    #[test]
    fn the_server_survives_any_frames_and_timeouts(events in events(), block_size in 1u8..=127, crc: bool) {
        let mut server = SdoServer::new(node(), ServerConfig {
            timeout: TIMEOUT,
            block_size,
            crc,
            max_size: 4096,
        });
        let mut objects = Objects::new();
        objects.entries.get_mut(&(0x2000, 0)).unwrap().value = counting(100);
        let mut now = Instant::now();
        for event in events {
            let sent = match event {
                Event::Frame(data) => {
                    let frame = Frame::new(CanId::Standard(0x605), &data).unwrap();
                    server.handle_frame(&frame, now, &mut objects)
                }
                Event::Wait(ms) => {
                    now += Duration::from_millis(ms);
                    server.handle_timeout(now)
                }
            };
            for frame in &sent {
                prop_assert_eq!(frame.id(), CanId::Standard(0x585));
                prop_assert_eq!(frame.data().len(), 8);
            }
            prop_assert_eq!(server.is_idle(), server.deadline().is_none());
        }
    }

    #[test]
    fn the_client_survives_any_frames_and_timeouts(
        events in events(),
        method in prop::sample::select(METHODS.to_vec()),
        block_size in 1u8..=127,
        crc: bool,
        lens in vec(0usize..40, 1..4),
    ) {
        let mut client = SdoClient::new(node(), ClientConfig {
            timeout: TIMEOUT,
            block_size,
            use_block_download_from: matches!(method, Method::Block { .. }).then_some(0),
            use_block_upload: matches!(method, Method::Block { .. }),
            switch_threshold: 21,
            crc,
        });
        let mut now = Instant::now();
        let mut started = 0usize;
        for event in events {
            if client.is_idle() {
                // Keep a transfer running: downloads and uploads in turn.
                let len = lens[started % lens.len()];
                let frames = if started.is_multiple_of(2) {
                    client.download(0x2000, 0, &counting(len), now)
                } else {
                    client.upload(0x2000, 0, now)
                };
                prop_assert_eq!(frames.map(|f| f.len()), Ok(1));
                started += 1;
            }
            let step = match event {
                Event::Frame(mut data) => {
                    // Half the frames answer for the right object.
                    if data.len() >= 4 && data[3] == 0 {
                        data[1] = 0x00;
                        data[2] = 0x20;
                    }
                    let frame = Frame::new(CanId::Standard(0x585), &data).unwrap();
                    client.handle_frame(&frame, now)
                }
                Event::Wait(ms) => {
                    now += Duration::from_millis(ms);
                    client.handle_timeout(now)
                }
            };
            for frame in &step.send {
                prop_assert_eq!(frame.id(), CanId::Standard(0x605));
                prop_assert_eq!(frame.data().len(), 8);
            }
            if step.done.is_some() {
                prop_assert!(client.is_idle());
            }
            prop_assert_eq!(client.is_idle(), client.deadline().is_none());
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(crate::can::test_support::fuzz_cases(48)))]

    #[test]
    fn any_value_travels_intact_by_every_method(
        value in vec(any::<u8>(), 0..2000),
        client_block in 1u8..=127,
        server_block in 1u8..=127,
        client_crc: bool,
        server_crc: bool,
    ) {
        for method in METHODS {
            let mut link = link(method, client_block, server_block, client_crc, server_crc);
            prop_assert_eq!(link.download(0x2000, 0, &value), Ok(Transfer::Downloaded));
            prop_assert_eq!(link.objects.value(0x2000, 0), &value[..]);
            // Upload by every method, whatever carried the download.
            for upload in METHODS {
                let mut other = super::wired::link(upload, client_block, server_block, client_crc, server_crc);
                other.objects = link.objects.clone();
                prop_assert_eq!(other.upload(0x2000, 0), Ok(Transfer::Uploaded(value.clone())));
            }
        }
    }

    #[test]
    fn a_lost_frame_never_corrupts_a_value(
        value in vec(any::<u8>(), 0..300),
        method in prop::sample::select(METHODS.to_vec()),
        upload: bool,
        client_block in 1u8..=16,
        server_block in 1u8..=16,
        lost in 0usize..120,
    ) {
        let mut link = link(method, client_block, server_block, true, true);
        link.objects.add(0x2100, 0, if upload { value.clone() } else { Vec::new() }, Access::ReadWrite, None);
        let first = if upload {
            link.client.upload(0x2100, 0, link.now).unwrap()
        } else {
            link.client.download(0x2100, 0, &value, link.now).unwrap()
        };
        match link.run(first, &mut |n, _| n == lost) {
            Ok(Transfer::Uploaded(got)) => prop_assert_eq!(got, value),
            Ok(Transfer::Downloaded) => prop_assert_eq!(link.objects.value(0x2100, 0), &value[..]),
            Err(SdoError::Timeout | SdoError::ServerAborted(AbortCode::TimedOut)) => {
                // Nothing half-written.
                let stored = link.objects.value(0x2100, 0);
                prop_assert!(stored.is_empty() || stored == &value[..]);
            }
            Err(other) => prop_assert!(false, "{other:?}"),
        }
        prop_assert!(link.settle());
    }
}

/// What the bus does to the conversation of a real client and server.
#[derive(Debug, Clone)]
enum Mishap {
    /// The next frame arrives.
    Deliver,
    /// The next frame arrives with this bit (0–63) flipped.
    Flip(u8),
    /// The next frame arrives cut to this many bytes.
    Truncate(usize),
    /// The next frame is lost.
    Lose,
    /// A stranger's frame arrives at the server or at the client.
    Inject { to_server: bool, data: Vec<u8> },
    /// Time passes.
    Wait(u64),
}

fn mishaps() -> impl Strategy<Value = Vec<Mishap>> {
    vec(
        prop_oneof![
            60 => Just(Mishap::Deliver),
            1 => (0u8..64).prop_map(Mishap::Flip),
            1 => (0usize..8).prop_map(Mishap::Truncate),
            1 => Just(Mishap::Lose),
            1 => (any::<bool>(), frame_bytes()).prop_map(|(to_server, data)| Mishap::Inject { to_server, data }),
            2 => (0u64..1500).prop_map(Mishap::Wait),
        ],
        0..400,
    )
}

/// One transfer the client runs: how, which way, how long a value.
fn transfers() -> impl Strategy<Value = Vec<(Method, bool, usize)>> {
    vec(
        (
            prop::sample::select(METHODS.to_vec()),
            any::<bool>(),
            0usize..120,
        ),
        1..6,
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(crate::can::test_support::fuzz_cases(192)))]

    #[test]
    fn both_machines_survive_a_conversation_gone_wrong(
        mishaps in mishaps(),
        transfers in transfers(),
        client_block in 1u8..=8,
        server_block in 1u8..=8,
        client_crc: bool,
        server_crc: bool,
    ) {
        let mut links: Vec<Link> = METHODS
            .iter()
            .map(|&m| link(m, client_block, server_block, client_crc, server_crc))
            .collect();
        // One server and one dictionary; a client per method, used in turn.
        let mut server = links[0].server.clone();
        let mut objects = Objects::new();
        objects.entries.get_mut(&(0x2000, 0)).unwrap().value = counting(77);
        let mut now = Instant::now();
        let mut bus: VecDeque<Frame> = VecDeque::new();
        let mut next = 0usize;
        let mut running: Option<Running> = None;
        for mishap in mishaps {
            if running.is_none() && bus.is_empty() {
                let (method, upload, len) = transfers[next % transfers.len()];
                next += 1;
                let which = METHODS.iter().position(|&m| m == method).unwrap();
                let value: Vec<u8> = (0..len).map(|i| (i + next) as u8).collect();
                let client = &mut links[which].client;
                let frames = if upload {
                    client.upload(0x2000, 0, now)
                } else {
                    client.download(0x2000, 0, &value, now)
                };
                bus.extend(frames.unwrap());
                running = Some(Running {
                    client: which,
                    downloaded: (!upload).then_some(value),
                    // A server still in an earlier transfer (whose abort was
                    // lost) refuses the new one.
                    tainted: !server.is_idle(),
                    disturbed: false,
                });
            }
            let mut arrived = None;
            match mishap {
                Mishap::Deliver => arrived = bus.pop_front(),
                Mishap::Flip(bit) => {
                    arrived = bus.pop_front().map(|frame| {
                        let mut data = frame.data().to_vec();
                        let byte = usize::from(bit / 8);
                        if byte < data.len() {
                            data[byte] ^= 1 << (bit % 8);
                        }
                        Frame::new(frame.id(), &data).unwrap()
                    });
                    if let Some(running) = &mut running { running.tainted = true; }
                }
                Mishap::Truncate(len) => {
                    arrived = bus.pop_front().map(|frame| {
                        Frame::new(frame.id(), &frame.data()[..len.min(frame.data().len())]).unwrap()
                    });
                    if let Some(running) = &mut running { running.tainted = true; }
                }
                Mishap::Lose => {
                    bus.pop_front();
                    if let Some(running) = &mut running { running.disturbed = true; }
                }
                Mishap::Inject { to_server, data } => {
                    let id = CanId::Standard(if to_server { 0x605 } else { 0x585 });
                    arrived = Some(Frame::new(id, &data).unwrap());
                    if let Some(running) = &mut running { running.tainted = true; }
                }
                Mishap::Wait(ms) => {
                    now += Duration::from_millis(ms);
                    bus.extend(server.handle_timeout(now));
                    if let Some(Running { client: which, .. }) = running {
                        running.as_mut().unwrap().disturbed = true;
                        let step = links[which].client.handle_timeout(now);
                        bus.extend(step.send.iter().copied());
                        check_done(&step, &mut running, &objects)?;
                    }
                }
            }
            if let Some(frame) = arrived {
                if frame.id() == CanId::Standard(0x605) {
                    bus.extend(server.handle_frame(&frame, now, &mut objects));
                } else if let Some(Running { client: which, .. }) = running {
                    let step = links[which].client.handle_frame(&frame, now);
                    bus.extend(step.send.iter().copied());
                    check_done(&step, &mut running, &objects)?;
                }
            }
            prop_assert_eq!(server.is_idle(), server.deadline().is_none());
            for link in &links {
                prop_assert_eq!(link.client.is_idle(), link.client.deadline().is_none());
            }
            if let Some(running) = &running {
                prop_assert!(!links[running.client].client.is_idle());
            }
            for frame in &bus {
                prop_assert_eq!(frame.data().len(), 8);
            }
        }
    }
}

/// The transfer a client is running in the conversation property.
#[derive(Debug, Clone)]
struct Running {
    /// Which of the clients (one per method).
    client: usize,
    /// The value, for a download.
    downloaded: Option<Vec<u8>>,
    /// Frames were damaged or injected, or the server was not idle at the
    /// start: anything may come of it, except a panic.
    tainted: bool,
    /// Frames were lost or late (time passed): it may fail, but only by a
    /// timeout or by the server refusing what it no longer expects.
    disturbed: bool,
}

/// When the step ends the running transfer: an untainted success must bring
/// the right value, an undisturbed transfer must succeed, and a disturbed one
/// may fail only for the time it lost.
fn check_done(
    step: &Step,
    running: &mut Option<Running>,
    objects: &Objects,
) -> Result<(), TestCaseError> {
    let Some(done) = &step.done else {
        return Ok(());
    };
    let transfer = running.take().expect("a transfer was running");
    if transfer.tainted {
        return Ok(());
    }
    match (done, transfer.downloaded) {
        (Ok(Transfer::Uploaded(got)), None) => prop_assert_eq!(&got[..], objects.value(0x2000, 0)),
        (Ok(Transfer::Downloaded), Some(value)) => {
            prop_assert_eq!(objects.value(0x2000, 0), &value[..])
        }
        (Ok(other), expected) => prop_assert!(false, "{other:?} for {expected:?}"),
        (Err(error), _) if !transfer.disturbed => {
            prop_assert!(false, "an undisturbed transfer failed: {error:?}")
        }
        // Either side may time out first; when the server's abort is lost,
        // the client's next request finds it idle and refused.
        (
            Err(
                SdoError::Timeout
                | SdoError::ServerAborted(AbortCode::TimedOut | AbortCode::InvalidCommandSpecifier),
            ),
            _,
        ) => {}
        (Err(other), _) => prop_assert!(false, "lost or late frames made it fail with {other:?}"),
    }
    Ok(())
}
