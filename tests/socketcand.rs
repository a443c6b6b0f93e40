//! The socketcand server and client over real TCP on loopback (port 0).

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use candeck::can::socketcand::{
    ClientConfig, ServerConfig, ServerHandle, SocketcandServer, open_socketcand,
};
use candeck::can::{Bus, BusState, CanId, Direction, Frame, VirtualHub};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

const WAIT: Duration = Duration::from_secs(10);

async fn serve(hub: &VirtualHub, config: ServerConfig) -> ServerHandle {
    let addr: SocketAddr = "127.0.0.1:0".parse().unwrap();
    SocketcandServer::bind(addr, [("can0".to_string(), hub.clone())], config)
        .await
        .unwrap()
        .spawn()
        .unwrap()
}

fn client(addr: SocketAddr) -> Bus {
    let mut config = ClientConfig::new("127.0.0.1", addr.port(), "can0");
    config.min_backoff = Duration::from_millis(20);
    config.max_backoff = Duration::from_millis(200);
    open_socketcand("can0", config)
}

fn frames() -> Vec<Frame> {
    let mut out = Vec::new();
    for len in 0..=8usize {
        let data: Vec<u8> = (0..len as u8).map(|b| b.wrapping_mul(37)).collect();
        out.push(Frame::new(CanId::Standard(0x100 + len as u16), &data).unwrap());
        out.push(Frame::new(CanId::Extended(0x1ABC_0000 + len as u32), &data).unwrap());
    }
    out.push(Frame::new(CanId::Standard(0x7FF), &[0xFF; 8]).unwrap());
    out.push(Frame::new(CanId::Extended(0x1FFF_FFFF), &[]).unwrap());
    out.push(Frame::remote(CanId::Standard(0x701), 1).unwrap());
    out
}

async fn recv(rx: &mut candeck::can::FrameReceiver) -> Frame {
    tokio::time::timeout(WAIT, rx.recv())
        .await
        .expect("a frame in time")
        .expect("no error")
        .frame
}

/// Reads from a raw socket until `needle` has been seen.
async fn read_until(stream: &mut TcpStream, needle: &str) -> String {
    let mut seen = Vec::new();
    let mut buf = [0u8; 4096];
    while !String::from_utf8_lossy(&seen).contains(needle) {
        let n = tokio::time::timeout(WAIT, stream.read(&mut buf))
            .await
            .expect("data in time")
            .expect("read");
        assert!(
            n > 0,
            "closed before '{needle}': {}",
            String::from_utf8_lossy(&seen)
        );
        seen.extend_from_slice(&buf[..n]);
    }
    String::from_utf8(seen).unwrap()
}

#[tokio::test]
async fn two_clients_and_the_hub_exchange_every_frame_in_order() {
    let hub = VirtualHub::new("can0");
    let server = serve(&hub, ServerConfig::default()).await;
    let a = client(server.local_addr());
    let b = client(server.local_addr());
    a.wait_up(WAIT).await.unwrap();
    b.wait_up(WAIT).await.unwrap();
    let local = hub.attach();
    let mut rx_a = a.monitor();
    let mut rx_b = b.subscribe();
    let mut rx_local = local.subscribe();
    // Let the server's settle pause after rawmode pass for both sessions.
    tokio::time::sleep(Duration::from_millis(200)).await;

    for frame in frames() {
        a.send(frame).await.unwrap();
    }
    for frame in frames() {
        assert_eq!(recv(&mut rx_b).await, frame);
        assert_eq!(recv(&mut rx_local).await, frame);
        // a's monitor sees its own frames as sent, not as received.
        let own = tokio::time::timeout(WAIT, rx_a.recv())
            .await
            .unwrap()
            .unwrap();
        assert_eq!((own.frame, own.direction), (frame, Direction::Tx));
    }
    // The other way: from the hub to both clients.
    let reply = Frame::new(CanId::Standard(0x581), &[0x43, 0, 0x10, 0, 0x92, 0, 0, 0]).unwrap();
    local.send(reply).await.unwrap();
    assert_eq!(recv(&mut rx_b).await, reply);
    let got = tokio::time::timeout(WAIT, rx_a.recv())
        .await
        .unwrap()
        .unwrap();
    assert_eq!((got.frame, got.direction), (reply, Direction::Rx));
    assert_eq!(a.counters().tx_frames, frames().len() as u64);
    assert_eq!(b.counters().rx_frames, frames().len() as u64 + 1);
    assert_eq!(
        server.stats().frames_from_clients.load(Ordering::Relaxed),
        frames().len() as u64
    );
}

#[tokio::test]
async fn fd_frames_cross_between_candeck_clients() {
    let hub = VirtualHub::new("can0");
    let server = serve(&hub, ServerConfig::default()).await;
    let a = client(server.local_addr());
    let local = hub.attach();
    let mut rx = local.subscribe();
    a.wait_up(WAIT).await.unwrap();
    let frame = Frame::fd(
        CanId::Extended(0x10),
        &[0x5A; 64],
        candeck::can::FdFlags::from_raw(1),
    )
    .unwrap();
    a.send(frame).await.unwrap();
    assert_eq!(recv(&mut rx).await, frame);
}

#[tokio::test]
async fn garbage_gets_an_error_reply_and_disturbs_no_one() {
    let hub = VirtualHub::new("can0");
    let server = serve(&hub, ServerConfig::default()).await;
    let a = client(server.local_addr());
    let b = client(server.local_addr());
    a.wait_up(WAIT).await.unwrap();
    b.wait_up(WAIT).await.unwrap();
    let mut rx_b = b.subscribe();

    let mut junk = TcpStream::connect(server.local_addr()).await.unwrap();
    read_until(&mut junk, "< hi >").await;
    junk.write_all(b"GET / HTTP/1.1\r\n\r\n").await.unwrap();
    let reply = read_until(&mut junk, ">").await;
    assert!(reply.starts_with("< error "), "{reply}");
    junk.write_all(b"< open can0 >< rawmode >< send 123 9 >< frobnicate ><send 12")
        .await
        .unwrap();
    let replies = read_until(&mut junk, "unknown command").await;
    // A malformed send is answered with nothing, as socketcand does.
    assert!(
        replies.contains("< ok >< ok >< error unknown command 'frobnicate' >"),
        "{replies}"
    );
    junk.write_all(&[0xFF; 3000]).await.unwrap();

    tokio::time::sleep(Duration::from_millis(100)).await;
    for frame in frames() {
        a.send(frame).await.unwrap();
    }
    for frame in frames() {
        assert_eq!(recv(&mut rx_b).await, frame);
    }
    assert!(server.stats().rejected_commands.load(Ordering::Relaxed) >= 3);
    // The junk client is still served: it gets the frames too.
    read_until(&mut junk, "< frame 7FF ").await;
}

#[tokio::test]
async fn a_client_reading_slower_than_the_bus_loses_the_oldest_frames_and_stays_connected() {
    let hub = VirtualHub::with_queue("can0", 512);
    let config = ServerConfig {
        send_buffer: 4096,
        // Longer than the pause below: this client is slow, not stalled.
        write_timeout: Duration::from_secs(60),
        ..ServerConfig::default()
    };
    let server = serve(&hub, config).await;
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(2048).unwrap();
    let mut slow = socket.connect(server.local_addr()).await.unwrap();
    read_until(&mut slow, "< hi >").await;
    slow.write_all(b"< open can0 >< rawmode >").await.unwrap();
    read_until(&mut slow, "< ok >< ok >").await;
    tokio::time::sleep(Duration::from_millis(100)).await;

    // Far more than its queue and the sockets' buffers hold, while it does
    // not read; then a last frame.
    let sender = hub.attach();
    for i in 0..5_000u32 {
        sender
            .send(Frame::new(CanId::Standard(0x181), &i.to_le_bytes()).unwrap())
            .await
            .unwrap();
    }
    sender
        .send(Frame::new(CanId::Standard(0x7FF), &[]).unwrap())
        .await
        .unwrap();

    // It reads on and gets the last frame: the session went on.
    read_until(&mut slow, "< frame 7FF ").await;
    let stats = server.stats();
    let lost = stats.frames_lost_to_slow_clients.load(Ordering::Relaxed);
    assert!(lost > 0 && lost < 5_000, "frames lost: {lost}");
    assert_eq!(stats.slow_clients_dropped.load(Ordering::Relaxed), 0);
    assert_eq!(stats.connected.load(Ordering::Relaxed), 1);
}

#[tokio::test]
async fn a_client_that_stops_reading_is_dropped_and_the_others_get_everything() {
    let hub = VirtualHub::with_queue("can0", 512);
    let config = ServerConfig {
        send_buffer: 4096,
        ..ServerConfig::default()
    };
    let server = serve(&hub, config).await;
    let b = client(server.local_addr());
    b.wait_up(WAIT).await.unwrap();
    let mut rx_b = b.subscribe();

    // A client with a tiny receive window that never reads again.
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(2048).unwrap();
    let mut stalled = socket.connect(server.local_addr()).await.unwrap();
    read_until(&mut stalled, "< hi >").await;
    stalled
        .write_all(b"< open can0 >< rawmode >")
        .await
        .unwrap();
    read_until(&mut stalled, "< ok >< ok >").await;
    tokio::time::sleep(Duration::from_millis(100)).await;

    let sender = hub.attach();
    let total = 20_000u32;
    let read = Arc::new(std::sync::atomic::AtomicU32::new(0));
    let reading = read.clone();
    let reader = tokio::spawn(async move {
        for i in 0..total {
            let frame = recv(&mut rx_b).await;
            assert_eq!(frame.data(), &i.to_le_bytes(), "frame {i}");
            reading.store(i + 1, Ordering::Relaxed);
        }
    });
    for i in 0..total {
        // Paced by the live reader, not by the clock: it is never more
        // than 256 frames behind (its server queue holds 512), however
        // loaded the machine, while the stalled one falls ever further.
        while i >= read.load(Ordering::Relaxed) + 256 {
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        sender
            .send(Frame::new(CanId::Standard(0x181), &i.to_le_bytes()).unwrap())
            .await
            .unwrap();
    }
    reader.await.unwrap();
    let dropped = tokio::time::timeout(WAIT, async {
        while server.stats().slow_clients_dropped.load(Ordering::Relaxed) == 0 {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await;
    assert!(dropped.is_ok(), "the stalled client was not dropped");
    assert_eq!(server.stats().connected.load(Ordering::Relaxed), 1);
}

#[tokio::test]
async fn an_unknown_channel_is_refused_with_the_reason() {
    let hub = VirtualHub::new("can0");
    let server = serve(&hub, ServerConfig::default()).await;
    let mut config = ClientConfig::new("127.0.0.1", server.local_addr().port(), "can7");
    config.connect_timeout = Duration::from_secs(2);
    let bus = open_socketcand("can7", config);
    let err = bus
        .wait_up(Duration::from_millis(500))
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("refused channel 'can7'"), "{err}");
    assert!(err.contains("this server offers can0"), "{err}");
    assert!(
        bus.send(Frame::new(CanId::Standard(1), &[]).unwrap())
            .await
            .is_err()
    );
}

#[tokio::test]
async fn the_client_reports_down_and_reconnects_when_the_server_comes_back() {
    let hub = VirtualHub::new("can0");
    let server = serve(&hub, ServerConfig::default()).await;
    let addr = server.local_addr();
    let bus = client(addr);
    bus.wait_up(WAIT).await.unwrap();
    drop(server);

    let mut status = bus.watch_status();
    tokio::time::timeout(WAIT, status.wait_for(|s| s.state == BusState::Down))
        .await
        .unwrap()
        .unwrap();
    let err = bus
        .send(Frame::new(CanId::Standard(1), &[]).unwrap())
        .await
        .unwrap_err();
    assert!(err.to_string().starts_with("bus can0 is down"), "{err}");

    // Same port again: the client finds it on its own.
    let _server = SocketcandServer::bind(
        addr,
        [("can0".to_string(), hub.clone())],
        ServerConfig::default(),
    )
    .await
    .unwrap()
    .spawn()
    .unwrap();
    bus.wait_up(WAIT).await.unwrap();
    assert_eq!(bus.counters().reconnects, 1);
    let local = hub.attach();
    let mut rx = local.subscribe();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let frame = Frame::new(CanId::Standard(0x77), &[7]).unwrap();
    bus.send(frame).await.unwrap();
    assert_eq!(recv(&mut rx).await, frame);
}

#[tokio::test]
async fn a_silent_server_is_probed_with_echo_and_given_up() {
    // A fake server that completes the handshake, answers the first echo,
    // then goes silent without closing.
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let fake = tokio::spawn(async move {
        let (mut s, _) = listener.accept().await.unwrap();
        s.write_all(b"< hi >").await.unwrap();
        read_until(&mut s, "< open can0 >").await;
        s.write_all(b"< ok >").await.unwrap();
        read_until(&mut s, "< rawmode >").await;
        s.write_all(b"< ok >").await.unwrap();
        read_until(&mut s, "< echo >").await;
        s.write_all(b"< echo >").await.unwrap();
        read_until(&mut s, "< echo >").await;
        // Silent now; keep the socket open.
        tokio::time::sleep(Duration::from_secs(60)).await;
        drop(s);
    });
    let mut config = ClientConfig::new("127.0.0.1", addr.port(), "can0");
    config.probe_after = Duration::from_millis(100);
    config.dead_after = Duration::from_millis(300);
    let bus = open_socketcand("can0", config);
    bus.wait_up(WAIT).await.unwrap();
    let mut status = bus.watch_status();
    let down = tokio::time::timeout(
        WAIT,
        status.wait_for(|s| {
            s.state == BusState::Down
                && s.reason.as_deref().is_some_and(|r| r.contains("no answer"))
        }),
    )
    .await;
    fake.abort();
    assert!(down.is_ok(), "status: {:?}", bus.status());
}

/// An expedited SDO download to `node` over `bus`, waiting for its answer.
async fn sdo_write(
    bus: &Bus,
    rx: &mut candeck::can::FrameReceiver,
    node: u8,
    index: u16,
    sub: u8,
    value: &[u8],
) {
    let command = match value.len() {
        1 => 0x2F,
        2 => 0x2B,
        _ => 0x23,
    };
    let [lo, hi] = index.to_le_bytes();
    let mut data = [command, lo, hi, sub, 0, 0, 0, 0];
    data[4..4 + value.len()].copy_from_slice(value);
    bus.send(Frame::new(CanId::Standard(0x600 + u16::from(node)), &data).unwrap())
        .await
        .unwrap();
    loop {
        let frame = recv(rx).await;
        if frame.id() == CanId::Standard(0x580 + u16::from(node)) {
            assert_eq!(
                frame.data()[0],
                0x60,
                "{frame} answers the write of {index:04X}"
            );
            return;
        }
    }
}

/// Node guarding end to end over socketcand: the gateway's side is a
/// socketcand client (what `--bus socketcand:HOST:PORT/can0` opens), the
/// device's side what `candeck vbus` runs (a hub at 500 kbit/s, a rack of
/// virtual devices, the socketcand server). The master's remote requests
/// cross as `< sendrtr 705 1 >` and reach the device as remote frames; its
/// replies come back with the toggle bit alternating.
///
/// python-can's socketcand interface could not play the master here: it
/// writes every frame as `< send ID LEN DATA >`, which has no remote
/// frames, and it drops the `< rtr >` lines it receives. Upstream socketcand
/// (linux-can/socketcand `state_raw.c`) has no syntax for them either (a
/// received remote frame is a "TODO"); `sendrtr` and `rtr` are candeck's,
/// on both ends.
#[tokio::test]
async fn node_guarding_crosses_socketcand_and_an_unplugged_node_is_lost_within_its_life_time() {
    use candeck::canopen::NodeId;
    use candeck::canopen::heartbeat::{HeartbeatEvent, NodeGuardMaster};
    use candeck::sim::products::Product;
    use candeck::sim::rack::Rack;

    let hub = VirtualHub::with_bitrate("can0", candeck::can::Bitrate::default());
    let rack = Rack::new(hub.clone());
    let id = NodeId::new(5).unwrap();
    rack.add(Product::Uio1led, id).unwrap();
    let server = serve(&hub, ServerConfig::default()).await;
    let bus = client(server.local_addr());
    bus.wait_up(WAIT).await.unwrap();
    let mut rx = bus.subscribe();
    // Guarding needs the heartbeat off (it takes precedence); guard time
    // 200 ms, life time factor 3: a node life time of 600 ms.
    sdo_write(&bus, &mut rx, 5, 0x1017, 0, &0u16.to_le_bytes()).await;
    sdo_write(&bus, &mut rx, 5, 0x100C, 0, &200u16.to_le_bytes()).await;
    sdo_write(&bus, &mut rx, 5, 0x100D, 0, &[3]).await;

    let mut guard = NodeGuardMaster::new(id, 200, 3);
    let life_time = guard.life_time().unwrap();
    guard.start(std::time::Instant::now());
    let mut replies = Vec::new();
    let mut unplugged = None;
    let lost_at = loop {
        let deadline = guard.deadline().expect("guarding runs");
        tokio::select! {
            _ = tokio::time::sleep_until(deadline.into()) => {
                // The master's own clock: the instant the poll was due.
                let poll = guard.poll(deadline);
                if let Some(request) = poll.request {
                    assert!(request.is_remote());
                    assert_eq!(request.to_string(), "705#R1");
                    bus.send(request).await.unwrap();
                }
                if let Some(event) = poll.event {
                    assert_eq!(event, HeartbeatEvent::Lost { node: id });
                    break deadline;
                }
            }
            frame = recv(&mut rx) => {
                if frame.id() != CanId::Standard(0x705) {
                    continue;
                }
                assert!(unplugged.is_none(), "a reply from an unplugged node: {frame}");
                replies.push(frame.data().to_vec());
                guard.on_frame(&frame, std::time::Instant::now()).unwrap();
                if replies.len() == 5 {
                    rack.unplug(id).unwrap();
                    unplugged = Some(std::time::Instant::now());
                }
            }
        }
    };
    // Pre-operational (0x7F), the toggle bit 7 alternating from 0.
    assert_eq!(
        replies,
        vec![vec![0x7F], vec![0xFF], vec![0x7F], vec![0xFF], vec![0x7F]]
    );
    let last_seen = guard.last_seen().unwrap();
    let unplugged = unplugged.unwrap();
    assert!(last_seen <= unplugged);
    // Reported lost at the end of the node life time after its last reply,
    // so within guard time × life time factor of the unplugging.
    assert_eq!(lost_at, last_seen + life_time);
    assert!(lost_at.saturating_duration_since(unplugged) <= life_time);
    assert!(guard.is_lost());
}

/// Reads until the server closes the connection; what it sent.
async fn read_to_close(stream: &mut TcpStream) -> String {
    let mut seen = Vec::new();
    tokio::time::timeout(WAIT, stream.read_to_end(&mut seen))
        .await
        .expect("closed in time")
        .expect("read");
    String::from_utf8(seen).unwrap()
}

#[tokio::test]
async fn clients_beyond_the_connection_limit_are_refused_and_counted() {
    let hub = VirtualHub::new("can0");
    let config = ServerConfig {
        max_connections: 2,
        ..ServerConfig::default()
    };
    let server = serve(&hub, config).await;
    let addr = server.local_addr();
    let mut first = TcpStream::connect(addr).await.unwrap();
    read_until(&mut first, "< hi >").await;
    let mut second = TcpStream::connect(addr).await.unwrap();
    read_until(&mut second, "< hi >").await;
    // The third: told why, and closed; never greeted.
    let mut third = TcpStream::connect(addr).await.unwrap();
    let said = read_to_close(&mut third).await;
    assert_eq!(
        said, "< error too many clients (share_max_connections) >",
        "{said}"
    );
    assert_eq!(server.stats().refused.load(Ordering::Relaxed), 1);
    // The two still work.
    second.write_all(b"< open can0 >").await.unwrap();
    read_until(&mut second, "< ok >").await;
    // One goes: its place is free again.
    drop(first);
    let mut fourth = loop {
        let mut stream = TcpStream::connect(addr).await.unwrap();
        let mut buf = [0u8; 64];
        let n = tokio::time::timeout(WAIT, stream.read(&mut buf))
            .await
            .expect("an answer in time")
            .unwrap();
        if String::from_utf8_lossy(&buf[..n]).contains("< hi >") {
            break stream;
        }
        // The first's session had not ended yet: refused, try again.
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    fourth.write_all(b"< open can0 >").await.unwrap();
    read_until(&mut fourth, "< ok >").await;
}

/// A socketcand server that has a backlog for the client (the gateway was
/// busy, or the machine loaded, while its bus ran on): what the client
/// reads in one go must not overrun the readers of the bus. Every frame of
/// a burst far larger than a reader's queue reaches a reader that keeps
/// reading, in order, with none lost. (The client used to push every frame
/// of up to 128 reads of 16 KiB, tens of thousands, into the readers'
/// queues before any of them ran: each lost thousands, SDO answers and
/// heartbeats among them.)
#[tokio::test]
async fn a_backlog_from_the_server_reaches_the_readers_without_an_overrun() {
    use std::io::{Read, Write};
    const FRAMES: u32 = 60_000;
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    // A plain thread: it writes while the client's runtime is busy.
    let fake = std::thread::spawn(move || {
        let (mut s, _) = listener.accept().unwrap();
        let mut seen = Vec::new();
        let mut expect = |s: &mut std::net::TcpStream, needle: &str| {
            let mut buf = [0u8; 256];
            while !String::from_utf8_lossy(&seen).contains(needle) {
                let n = s.read(&mut buf).unwrap();
                assert!(n > 0, "closed before '{needle}'");
                seen.extend_from_slice(&buf[..n]);
            }
            seen.clear();
        };
        s.write_all(b"< hi >").unwrap();
        expect(&mut s, "< open can0 >");
        s.write_all(b"< ok >").unwrap();
        expect(&mut s, "< rawmode >");
        s.write_all(b"< ok >").unwrap();
        let mut burst = Vec::new();
        for n in 0..FRAMES {
            burst.extend_from_slice(b"< frame 181 0.000000 ");
            for byte in n.to_le_bytes() {
                burst.extend_from_slice(format!("{byte:02X}").as_bytes());
            }
            burst.extend_from_slice(b" >");
        }
        // Closed once written: what is written is still delivered.
        s.write_all(&burst).unwrap();
    });
    let bus = client(addr);
    let mut rx = bus.subscribe();
    bus.wait_up(WAIT).await.unwrap();
    // The runtime is held while the server writes: a backlog piles up in
    // the socket, as behind a gateway that was busy.
    std::thread::sleep(Duration::from_millis(300));
    for n in 0..FRAMES {
        let frame = tokio::time::timeout(WAIT, rx.recv())
            .await
            .unwrap_or_else(|_| panic!("frame {n} in time"))
            .unwrap_or_else(|err| panic!("frame {n}: {err:?}"))
            .frame;
        assert_eq!(frame.data(), n.to_le_bytes(), "frame {n}");
    }
    assert_eq!(bus.counters().rx_overruns, 0);
    fake.join().unwrap();
}

/// A client that sends faster than the wire carries is held back (its
/// frames wait in the TCP stream), not dropped: 8,000 frames sent at once
/// at 500 kbit/s all cross, and nothing counts as refused.
#[tokio::test]
async fn a_client_sending_faster_than_the_wire_loses_nothing() {
    let hub = VirtualHub::with_bitrate("can0", "1M".parse().unwrap());
    let listener = hub.attach();
    let mut rx = listener.subscribe();
    let server = serve(&hub, ServerConfig::default()).await;
    let mut stream = TcpStream::connect(server.local_addr()).await.unwrap();
    read_until(&mut stream, "< hi >").await;
    stream.write_all(b"< open can0 >< rawmode >").await.unwrap();
    read_until(&mut stream, "< ok >< ok >").await;
    let total = 8_000u32;
    let writer = tokio::spawn(async move {
        let mut text = String::new();
        for i in 0..total {
            let [a, b, ..] = i.to_le_bytes();
            text.push_str(&format!("< send 181 2 {a:02X} {b:02X} >"));
        }
        stream.write_all(text.as_bytes()).await.unwrap();
        stream
    });
    for i in 0..total {
        let frame = tokio::time::timeout(Duration::from_secs(60), rx.recv())
            .await
            .expect("a frame in time")
            .expect("no overrun")
            .frame;
        let [a, b, ..] = i.to_le_bytes();
        assert_eq!(frame.data(), [a, b], "frame {i}");
    }
    let _stream = writer.await.unwrap();
    assert_eq!(listener.counters().tx_queue_overflows, 0);
    assert_eq!(server.stats().rejected_commands.load(Ordering::Relaxed), 0);
}
