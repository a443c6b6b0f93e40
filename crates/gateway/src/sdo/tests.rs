use std::sync::Mutex as StdMutex;

use super::*;
use crate::can::bus::DEFAULT_RX_QUEUE;
use crate::can::{BusState, BusStatus, CanId, Frame, VirtualHub};
use crate::canopen::od::{AccessType, DataType, Object, ObjectDictionary, SubObject};
use candeck_sim::device::{DeviceCore, run_device};

fn node() -> NodeId {
    NodeId::new(5).unwrap()
}

fn config() -> ClientConfig {
    ClientConfig {
        timeout: Duration::from_millis(500),
        ..ClientConfig::default()
    }
}

#[tokio::test(start_paused = true)]
async fn a_silent_node_times_out_at_the_configured_time_and_is_told_so() {
    let hub = VirtualHub::new("test");
    let channel = SdoChannel::new(hub.attach(), node(), config());
    let observer = hub.attach();
    let mut watch = observer.monitor();
    let start = tokio::time::Instant::now();
    let error = channel.upload(0x1000, 0).await.unwrap_err();
    assert_eq!(
        error,
        SdoRequestError::Sdo {
            node: node(),
            error: SdoError::Timeout
        }
    );
    // The paused clock moved exactly by the timeout, no real waiting.
    assert_eq!(start.elapsed(), Duration::from_millis(500));
    // The request, then the client's abort 0x05040000 on 0x605.
    let request = watch.recv().await.unwrap().frame;
    assert_eq!(request.id(), CanId::Standard(0x605));
    let abort = watch.recv().await.unwrap().frame;
    assert_eq!(
        abort.data(),
        &[0x80, 0x00, 0x10, 0x00, 0x00, 0x00, 0x04, 0x05]
    );
    assert_eq!(
        error.to_string(),
        "node 5: the device did not answer the SDO request in time, so the transfer was aborted"
    );
}

/// A device at node 5 with one UNSIGNED32 at 0x2000 of `access`,
/// running on `hub`.
fn spawn_device(hub: &VirtualHub, access: AccessType) -> tokio::task::JoinHandle<()> {
    let mut dictionary = ObjectDictionary::new();
    dictionary.insert(Object::var(
        0x2000,
        SubObject::new(0, "Word", DataType::Unsigned32, access),
    ));
    let device = Arc::new(StdMutex::new(DeviceCore::new(dictionary, node()).unwrap()));
    tokio::spawn(run_device(hub.attach(), device))
}

#[tokio::test(start_paused = true)]
async fn a_device_abort_a_timeout_and_a_bus_failure_are_different_errors() {
    let hub = VirtualHub::new("test");
    let server = spawn_device(&hub, AccessType::Ro);
    let channel = SdoChannel::new(hub.attach(), node(), config());

    assert_eq!(channel.upload(0x2000, 0).await, Ok(vec![0, 0, 0, 0]));
    let refused = channel
        .download(0x2000, 0, &[1, 0, 0, 0])
        .await
        .unwrap_err();
    assert_eq!(refused.device_abort(), Some(AbortCode::ReadOnlyObject));

    hub.set_status(BusStatus::new(BusState::Down, "cable pulled"));
    let down = channel.upload(0x2000, 0).await.unwrap_err();
    assert!(matches!(down, SdoRequestError::Bus { .. }), "{down:?}");
    assert_eq!(down.device_abort(), None);
    hub.set_status(BusStatus::up());

    // After every failure the channel is ready for the next transfer.
    assert_eq!(channel.upload(0x2000, 0).await, Ok(vec![0, 0, 0, 0]));
    server.abort();

    // Counted apart as well.
    let stats = channel.stats();
    assert_eq!(stats.transactions, 4, "{stats:?}");
    assert_eq!(
        (stats.aborts, stats.timeouts, stats.bus_errors),
        (1, 0, 1),
        "{stats:?}"
    );
    assert_eq!((stats.protocol_errors, stats.abandoned), (0, 0));
    assert_eq!(stats.latency.count(), 4);
}

#[tokio::test(start_paused = true)]
async fn a_timeout_is_counted_with_its_latency_in_the_histogram() {
    let hub = VirtualHub::new("test");
    let channel = SdoChannel::new(hub.attach(), node(), config());
    assert_eq!(channel.stats(), SdoStatsSnapshot::default());
    channel.upload(0x1000, 0).await.unwrap_err();
    // A clone shares the counts (the registry hands out clones).
    let stats = channel.clone().stats();
    assert_eq!(
        (stats.transactions, stats.timeouts, stats.aborts),
        (1, 1, 0),
        "{stats:?}"
    );
    assert_eq!(stats.latency.count(), 1);
    assert_eq!(stats.latency.sum, Duration::from_millis(500));
    // 500 ms is in the 0.5 s bucket and every one above, not below.
    let bucket = |bound: Duration| {
        let at = LATENCY_BUCKETS.iter().position(|b| *b == bound).unwrap();
        stats.latency.cumulative[at]
    };
    assert_eq!(bucket(Duration::from_millis(250)), 0);
    assert_eq!(bucket(Duration::from_millis(500)), 1);
    assert_eq!(bucket(Duration::from_millis(2500)), 1);
    assert!(stats.latency.cumulative.windows(2).all(|w| w[0] <= w[1]));
}

#[tokio::test(start_paused = true)]
async fn an_answer_within_a_millisecond_lands_in_the_first_buckets() {
    let hub = VirtualHub::new("test");
    let server = spawn_device(&hub, AccessType::Rw);
    let channel = SdoChannel::new(hub.attach(), node(), config());
    for _ in 0..3 {
        channel.upload(0x2000, 0).await.unwrap();
    }
    let stats = channel.stats();
    assert_eq!((stats.transactions, stats.latency.count()), (3, 3));
    // The paused clock does not move while the device answers.
    assert_eq!(stats.latency.cumulative[0], 3);
    assert_eq!(stats.latency.sum, Duration::ZERO);
    server.abort();
}

#[tokio::test(start_paused = true)]
async fn a_transfer_dropped_half_way_is_aborted_and_the_next_one_runs() {
    let hub = VirtualHub::new("test");
    let observer = hub.attach();
    let mut frames = observer.subscribe();
    let channel = SdoChannel::new(hub.attach(), node(), config());
    // No device answers; the caller gives up before the SDO timeout.
    let given_up = tokio::time::timeout(Duration::from_millis(10), channel.upload(0x2000, 0)).await;
    assert!(given_up.is_err());
    let server = spawn_device(&hub, AccessType::Rw);
    assert_eq!(channel.upload(0x2000, 0).await, Ok(vec![0, 0, 0, 0]));
    // On the bus: the abandoned request, its abort (0x08000000), the
    // new request.
    let mut requests = Vec::new();
    while let Ok(Some(frame)) = frames.try_recv() {
        if frame.frame.id() == CanId::Standard(0x605) {
            requests.push(frame.frame.data().to_vec());
        }
    }
    assert_eq!(
        requests,
        vec![
            vec![0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0],
            vec![0x80, 0x00, 0x20, 0x00, 0, 0, 0, 0x08],
            vec![0x40, 0x00, 0x20, 0x00, 0, 0, 0, 0],
        ]
    );
    server.abort();
    let stats = channel.stats();
    assert_eq!((stats.transactions, stats.abandoned), (2, 1), "{stats:?}");
    assert_eq!(stats.latency.count(), 1);
}

#[tokio::test(start_paused = true)]
async fn callers_queue_for_the_node_one_transfer_at_a_time() {
    let hub = VirtualHub::new("test");
    let server = spawn_device(&hub, AccessType::Rw);
    let channel = SdoChannel::new(hub.attach(), node(), config());
    let tasks: Vec<_> = (0..8u32)
        .map(|i| {
            let channel = channel.clone();
            tokio::spawn(async move {
                channel.download(0x2000, 0, &i.to_le_bytes()).await.unwrap();
                channel.upload(0x2000, 0).await.unwrap()
            })
        })
        .collect();
    for task in tasks {
        assert_eq!(task.await.unwrap().len(), 4);
    }
    // Nobody was refused as busy (the unwraps): each waited for its turn.
    server.abort();
}

/// Two procedures on one node do not interleave: each one's write and
/// read-back see its own value, though both run at once.
#[tokio::test(start_paused = true)]
async fn procedures_on_a_node_run_one_after_another() {
    let hub = VirtualHub::new("test");
    let server = spawn_device(&hub, AccessType::Rw);
    let channel = SdoChannel::new(hub.attach(), node(), config());
    let tasks: Vec<_> = (0..4u32)
        .map(|i| {
            let channel = channel.clone();
            tokio::spawn(async move {
                let _procedure = channel.procedure().await;
                channel.download(0x2000, 0, &i.to_le_bytes()).await.unwrap();
                // Another procedure would write between these steps.
                tokio::time::sleep(Duration::from_millis(5)).await;
                (i, channel.upload(0x2000, 0).await.unwrap())
            })
        })
        .collect();
    for task in tasks {
        let (i, read) = task.await.unwrap();
        assert_eq!(read, i.to_le_bytes());
    }
    server.abort();
}

#[tokio::test(start_paused = true)]
async fn a_channel_on_a_bus_busy_with_pdos_neither_reads_nor_loses_their_frames() {
    // An idle channel used to hold a reader of the whole bus: every PDO
    // queued for it, the oldest lost (counted as receive overruns), and the
    // next transfer read through thousands of them before its answer.
    let hub = VirtualHub::new("test");
    let _server = spawn_device(&hub, AccessType::Rw);
    let bus = hub.attach();
    let channel = SdoChannel::new(bus.clone(), node(), config());
    let producer = hub.attach();
    for round in 0..3u32 {
        for i in 0..DEFAULT_RX_QUEUE as u32 + 100 {
            producer
                .send(Frame::new(CanId::Standard(0x185), &i.to_le_bytes()).unwrap())
                .await
                .unwrap();
        }
        channel
            .download(0x2000, 0, &round.to_le_bytes())
            .await
            .unwrap();
        assert_eq!(
            channel.upload(0x2000, 0).await,
            Ok(round.to_le_bytes().to_vec())
        );
    }
    assert_eq!(bus.counters().rx_overruns, 0);
}

#[tokio::test(start_paused = true)]
async fn the_observer_hears_every_confirmed_download_and_nothing_else() {
    let hub = VirtualHub::new("test");
    let heard = Arc::new(StdMutex::new(Vec::new()));
    let observer: WriteObserver = {
        let heard = heard.clone();
        Arc::new(move |node, index, sub, data: &[u8]| {
            heard
                .lock()
                .unwrap()
                .push((node, index, sub, data.to_vec()));
        })
    };
    // Refused by the device: not written, not heard.
    let server = spawn_device(&hub, AccessType::Ro);
    let channel = SdoChannel::new(hub.attach(), node(), config()).with_observer(observer);
    assert!(channel.download(0x2000, 0, &[1, 0, 0, 0]).await.is_err());
    server.abort();
    // Not answered: not heard either.
    assert!(channel.download(0x2000, 0, &[2, 0, 0, 0]).await.is_err());
    let server = spawn_device(&hub, AccessType::Rw);
    channel.upload(0x2000, 0).await.unwrap();
    channel.download(0x2000, 0, &[3, 0, 0, 0]).await.unwrap();
    channel
        .download_reporting(0x2000, 0, &[4, 0, 0, 0], None, &|_, _| {})
        .await
        .unwrap();
    server.abort();
    assert_eq!(
        *heard.lock().unwrap(),
        vec![
            (node(), 0x2000, 0, vec![3, 0, 0, 0]),
            (node(), 0x2000, 0, vec![4, 0, 0, 0]),
        ]
    );
}
