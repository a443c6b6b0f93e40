//! The samplers on the paused clock, through fake reads that count their
//! SDO uploads.

use super::*;
use crate::Channel as CallerChannel;

/// How long a fake upload takes.
const UPLOAD: Duration = Duration::from_millis(2);

#[derive(Default)]
struct Fake {
    /// Each upload: the object, when it started and whose rights it took.
    uploads: Mutex<Vec<(Object, Instant, CallerChannel)>>,
    /// What the device holds, by object; the index's bytes where not set.
    device: Mutex<HashMap<Object, Vec<u8>>>,
    /// The objects whose uploads time out.
    failing: Mutex<Vec<Object>>,
    /// The objects a TPDO carries, and their newest bytes.
    carried: Mutex<BTreeMap<Object, Option<Carried>>>,
    frames: Mutex<Option<watch::Sender<u64>>>,
}

impl Fake {
    fn uploads(&self) -> Vec<(Object, Instant)> {
        let uploads = self.uploads.lock().unwrap();
        uploads
            .iter()
            .map(|(object, at, _)| (*object, *at))
            .collect()
    }

    fn uploads_of(&self, object: Object) -> usize {
        self.uploads()
            .iter()
            .filter(|(of, _)| *of == object)
            .count()
    }

    /// A TPDO frame brings `value` (an INTEGER32) for `object`.
    fn frame(&self, object: Object, value: i32, count: u64) {
        self.carried.lock().unwrap().insert(
            object,
            Some(Carried {
                seen: (Instant::now(), count),
                data: value.to_le_bytes().to_vec(),
            }),
        );
        if let Some(frames) = self.frames.lock().unwrap().as_ref() {
            frames.send_modify(|count| *count += 1);
        }
    }
}

impl NodeReads for Fake {
    fn carried(&self, _: &NodeKey, object: Object) -> Option<Option<Carried>> {
        self.carried.lock().unwrap().get(&object).cloned()
    }

    fn read<'a>(&'a self, _: &'a NodeKey, object: Object, caller: &'a Caller) -> ReadFuture<'a> {
        Box::pin(async move {
            self.uploads
                .lock()
                .unwrap()
                .push((object, Instant::now(), caller.channel));
            tokio::time::sleep(UPLOAD).await;
            if self.failing.lock().unwrap().contains(&object) {
                return Err(GatewayError::SdoTimeout { node: 3 });
            }
            let held = self.device.lock().unwrap().get(&object).cloned();
            Ok(held.unwrap_or_else(|| object.0.to_le_bytes().to_vec()))
        })
    }

    fn frames(&self, _: &NodeKey) -> Option<watch::Receiver<u64>> {
        let mut frames = self.frames.lock().unwrap();
        Some(
            frames
                .get_or_insert_with(|| watch::Sender::new(0))
                .subscribe(),
        )
    }
}

fn node() -> NodeKey {
    ("demo".to_string(), 3)
}

fn caller(channel: CallerChannel) -> Caller {
    Caller::new(channel, "anonymous", None)
}

type Received = Arc<Mutex<Vec<ObjectSample>>>;

struct Rig {
    samplers: Arc<Samplers>,
    fake: Arc<Fake>,
}

impl Rig {
    fn new(bound: u32) -> Self {
        Self {
            samplers: Arc::new(Samplers::new(bound)),
            fake: Arc::new(Fake::default()),
        }
    }

    /// A request of `channel` on `objects` every `interval_ms`, and what
    /// it receives.
    fn ask(
        &self,
        objects: &[Object],
        interval_ms: u64,
        channel: CallerChannel,
    ) -> (ObjectSampling, Received) {
        let received = Received::default();
        let sink: SampleSink = {
            let received = received.clone();
            Arc::new(move |sample| received.lock().unwrap().push(sample))
        };
        let request = Request {
            caller: caller(channel),
            objects: objects.to_vec(),
            interval: Duration::from_millis(interval_ms),
            sink,
        };
        let handle = self.samplers.request(self.fake.clone(), node(), request);
        (handle, received)
    }
}

fn of(received: &Received, object: Object) -> Vec<ObjectSample> {
    let received = received.lock().unwrap();
    received
        .iter()
        .filter(|sample| sample.object == object)
        .cloned()
        .collect()
}

/// At most `bound` uploads start within any one second.
fn assert_within_bound(uploads: &[(Object, Instant)], bound: u32) {
    for (at, (_, started)) in uploads.iter().enumerate() {
        let within = uploads[at..]
            .iter()
            .take_while(|(_, other)| *other < *started + Duration::from_secs(1))
            .count();
        assert!(within <= bound as usize, "{within} uploads in one second");
    }
}

#[test]
fn the_bound_is_shared_max_min_fairly() {
    let ms = Duration::from_millis;
    // 5 + 5 a second of 20: each gets what it asks.
    assert_eq!(fair_interval(&[ms(200), ms(200)], 20), None);
    // Four at 100/s of 20: 5 a second each.
    assert_eq!(fair_interval(&[ms(10); 4], 20), Some(ms(200)));
    // One asks 2/s: it keeps it, the other two share the 18 left.
    let share = fair_interval(&[ms(500), ms(10), ms(10)], 20).unwrap();
    assert_eq!(share.as_millis(), 111);
    assert_eq!(fair_interval(&[], 20), None);
}

#[test]
fn the_schedule_spaces_uploads_by_the_bound_and_marks_the_slowed() {
    let start = Instant::now();
    let mut schedule = NodeSchedule::new(10);
    let asked = BTreeMap::from([((0x1017, 0), Duration::from_millis(1))]);
    schedule.plan(asked, start);
    assert_eq!(schedule.next(), Some(((0x1017, 0), start)));
    schedule.sampled((0x1017, 0), start);
    // One object at 1000/s of 10: every 100 ms, and said so.
    assert_eq!(
        schedule.next(),
        Some(((0x1017, 0), start + Duration::from_millis(100)))
    );
    assert!(schedule.overloaded((0x1017, 0)));
    let relaxed = BTreeMap::from([((0x1017, 0), Duration::from_secs(1))]);
    schedule.plan(relaxed, start);
    assert!(!schedule.overloaded((0x1017, 0)));
}

#[tokio::test(start_paused = true)]
async fn many_requests_on_one_node_take_no_more_uploads_a_second_than_the_bound() {
    const BOUND: u32 = 20;
    let rig = Rig::new(BOUND);
    // Twelve objects, two requests each, every one asking 1 ms.
    let requests: Vec<_> = (0..24u16)
        .map(|n| rig.ask(&[(0x2000 + n % 12, 0)], 1, CallerChannel::Opcua))
        .collect();
    tokio::time::sleep(Duration::from_secs(10)).await;
    let uploads = rig.fake.uploads();
    assert_within_bound(&uploads, BOUND);
    // And the bound is used: each object gets its share, 20/12 a second.
    assert!(
        uploads.len() >= (BOUND as usize) * 10 - 1,
        "{}",
        uploads.len()
    );
    for n in 0..12u16 {
        let count = rig.fake.uploads_of((0x2000 + n, 0));
        assert!((15..=18).contains(&count), "object {n}: {count} uploads");
    }
    // Sampled slower than asked: the samples say so, to both requests on
    // the object.
    for (_, received) in [&requests[0], &requests[12]] {
        let samples = of(received, (0x2000, 0));
        assert!(!samples.is_empty());
        assert!(
            samples
                .iter()
                .all(|sample| sample.slowed && !sample.carried),
            "{samples:?}"
        );
    }
}

#[tokio::test(start_paused = true)]
async fn every_callers_requests_share_the_nodes_one_bound() {
    const BOUND: u32 = 10;
    let rig = Rig::new(BOUND);
    // Three doors, two objects each, all asking 10 ms.
    let channels = [
        CallerChannel::Opcua,
        CallerChannel::Rest,
        CallerChannel::Sparkplug,
    ];
    let requests: Vec<_> = (0..6u16)
        .map(|n| rig.ask(&[(0x2100 + n, 0)], 10, channels[usize::from(n) % 3]))
        .collect();
    tokio::time::sleep(Duration::from_secs(10)).await;
    let uploads = rig.fake.uploads();
    assert_within_bound(&uploads, BOUND);
    // Six objects share 10 a second: 10/6 each, whoever asked.
    for n in 0..6u16 {
        let count = rig.fake.uploads_of((0x2100 + n, 0));
        assert!((15..=18).contains(&count), "object {n}: {count} uploads");
    }
    // Each read with the rights of the caller who asked it.
    let by_channel = rig.fake.uploads.lock().unwrap().clone();
    for (object, _, channel) in by_channel {
        assert_eq!(channel, channels[usize::from(object.0 - 0x2100) % 3]);
    }
    assert_eq!(requests.len(), 6);
}

#[tokio::test(start_paused = true)]
async fn an_object_is_read_at_its_fastest_request_with_that_callers_rights() {
    let rig = Rig::new(20);
    let (_slow, slow_received) = rig.ask(&[(0x1017, 0)], 1000, CallerChannel::Rest);
    let (fast, fast_received) = rig.ask(&[(0x1017, 0)], 200, CallerChannel::Opcua);
    tokio::time::sleep(Duration::from_millis(1_100)).await;
    // Every 200 ms, 0 to 1 s, as the OPC UA caller; both get every sample.
    assert_eq!(rig.fake.uploads_of((0x1017, 0)), 6);
    let channels: Vec<CallerChannel> = rig
        .fake
        .uploads
        .lock()
        .unwrap()
        .iter()
        .map(|(_, _, channel)| *channel)
        .collect();
    assert!(
        channels
            .iter()
            .all(|channel| *channel == CallerChannel::Opcua)
    );
    assert_eq!(of(&slow_received, (0x1017, 0)).len(), 6);
    assert_eq!(of(&fast_received, (0x1017, 0)).len(), 6);
    // The fast request ends: the slow one's interval and rights.
    fast.end();
    tokio::time::sleep(Duration::from_millis(3_050)).await;
    let uploads = rig.fake.uploads.lock().unwrap().clone();
    assert!(uploads.len() <= 6 + 4, "{}", uploads.len());
    assert_eq!(
        uploads.last().map(|(_, _, channel)| *channel),
        Some(CallerChannel::Rest)
    );
}

#[tokio::test(start_paused = true)]
async fn a_request_within_the_bound_gets_every_sample_at_its_interval_not_slowed() {
    let rig = Rig::new(20);
    let (_request, received) = rig.ask(&[(0x1017, 0)], 500, CallerChannel::Opcua);
    tokio::time::sleep(Duration::from_millis(2_100)).await;
    assert_eq!(rig.fake.uploads().len(), 5);
    let samples = of(&received, (0x1017, 0));
    assert_eq!(samples.len(), 5);
    assert!(
        samples
            .iter()
            .all(|sample| !sample.slowed && sample.data == Ok(vec![0x17, 0x10]))
    );
}

#[tokio::test(start_paused = true)]
async fn an_object_a_tpdo_carries_takes_no_sdo_and_each_frame_is_a_sample() {
    let rig = Rig::new(20);
    let position = (0x6064, 0);
    rig.fake.carried.lock().unwrap().insert(position, None);
    let (request, received) = rig.ask(&[position], 1, CallerChannel::Opcua);
    tokio::time::sleep(Duration::from_millis(50)).await;
    rig.fake.frame(position, -1200, 1);
    tokio::time::sleep(Duration::from_millis(50)).await;
    rig.fake.frame(position, -1100, 2);
    tokio::time::sleep(Duration::from_secs(5)).await;
    assert!(rig.fake.uploads().is_empty(), "{:?}", rig.fake.uploads());
    let samples = of(&received, position);
    let data: Vec<_> = samples.iter().map(|sample| sample.data.clone()).collect();
    assert_eq!(
        data,
        vec![
            Ok((-1200i32).to_le_bytes().to_vec()),
            Ok((-1100i32).to_le_bytes().to_vec())
        ]
    );
    assert!(
        samples
            .iter()
            .all(|sample| sample.carried && !sample.slowed)
    );
    // A request that joins starts with the newest.
    let (joined, _) = rig.ask(&[position], 100, CallerChannel::Rest);
    let latest = joined.latest();
    assert_eq!(latest.len(), 1);
    assert_eq!(latest[0].data, Ok((-1100i32).to_le_bytes().to_vec()));
    drop(request);
}

#[tokio::test(start_paused = true)]
async fn a_failed_read_is_a_sample_with_its_error_and_sampling_goes_on() {
    let rig = Rig::new(20);
    let object = (0x6125, 0);
    rig.fake.failing.lock().unwrap().push(object);
    let (_request, received) = rig.ask(&[object], 200, CallerChannel::Opcua);
    tokio::time::sleep(Duration::from_millis(500)).await;
    let samples = of(&received, object);
    assert_eq!(samples.len(), 3, "{samples:?}");
    assert!(
        samples
            .iter()
            .all(|sample| sample.data == Err(GatewayError::SdoTimeout { node: 3 }))
    );
    rig.fake.failing.lock().unwrap().clear();
    rig.fake.device.lock().unwrap().insert(object, vec![42]);
    tokio::time::sleep(Duration::from_millis(300)).await;
    let samples = of(&received, object);
    assert_eq!(
        samples.last().map(|sample| sample.data.clone()),
        Some(Ok(vec![42]))
    );
}

#[tokio::test(start_paused = true)]
async fn sampling_stops_when_the_last_request_goes() {
    let rig = Rig::new(20);
    let (first, _) = rig.ask(&[(0x1017, 0)], 100, CallerChannel::Opcua);
    let (second, _) = rig.ask(&[(0x1017, 0), (0x6411, 1)], 100, CallerChannel::Rest);
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert!(!rig.fake.uploads().is_empty());
    drop(first);
    tokio::time::sleep(Duration::from_secs(1)).await;
    let while_one = rig.fake.uploads().len();
    assert!(while_one > 10, "{while_one}");
    assert_eq!(rig.samplers.nodes(), vec![node()]);
    // A slower interval from now.
    second.set_interval(Duration::from_secs(1));
    tokio::time::sleep(Duration::from_secs(3)).await;
    let slowed_down = rig.fake.uploads().len();
    assert!(slowed_down <= while_one + 2 * 4, "{slowed_down}");
    second.end();
    tokio::time::sleep(Duration::from_secs(5)).await;
    // At most the upload under way when it went.
    assert!(rig.fake.uploads().len() <= slowed_down + 1);
    assert!(rig.samplers.nodes().is_empty());
}

#[tokio::test]
async fn a_request_names_a_bus_a_node_id_and_objects() {
    let gateway = Gateway::new([]).with_sdo_samples_per_s(5);
    assert_eq!(gateway.sdo_samples_per_s(), 5);
    let sink: SampleSink = Arc::new(|_| {});
    let anyone = caller(CallerChannel::Rest);
    let asked = |bus: &str, node: u8, objects: Vec<(u16, u8)>| {
        gateway
            .sample_objects(
                &anyone,
                bus,
                node,
                objects,
                Duration::from_secs(1),
                sink.clone(),
            )
            .unwrap_err()
    };
    assert!(matches!(
        asked("nope", 3, vec![(0x1017, 0)]),
        GatewayError::UnknownBus(_)
    ));
    assert!(matches!(
        asked("nope", 0, vec![(0x1017, 0)]),
        GatewayError::InvalidRequest(_)
    ));
    assert!(matches!(
        asked("nope", 128, vec![(0x1017, 0)]),
        GatewayError::InvalidRequest(_)
    ));
    assert!(matches!(
        asked("nope", 3, vec![]),
        GatewayError::InvalidRequest(_)
    ));
    assert!(gateway.sampled_nodes().is_empty());
}
