//! The sampler on the paused clock, through a fake backend that counts
//! its SDO uploads.

use std::sync::Mutex;

use opcua::types::Variant;

use super::*;
use crate::gateway::Channel;

/// How long a fake upload takes.
const UPLOAD: Duration = Duration::from_millis(2);

#[derive(Default)]
struct Fake {
    /// Each upload: the object and when it started.
    uploads: Mutex<Vec<(Entry, Instant)>>,
    /// The objects a TPDO carries, and their newest value.
    carried: Mutex<BTreeMap<Entry, Option<Carried>>>,
    frames: Mutex<Option<watch::Sender<u64>>>,
    published: Mutex<Vec<(Entry, DataValue)>>,
}

impl Fake {
    fn uploads(&self) -> Vec<(Entry, Instant)> {
        self.uploads.lock().unwrap().clone()
    }

    fn published(&self, entry: Entry) -> Vec<DataValue> {
        let published = self.published.lock().unwrap();
        published
            .iter()
            .filter(|(of, _)| *of == entry)
            .map(|(_, value)| value.clone())
            .collect()
    }

    /// A TPDO frame brings `value` for `entry`.
    fn frame(&self, entry: Entry, value: i32, count: u64) {
        self.carried.lock().unwrap().insert(
            entry,
            Some(Carried {
                seen: (Instant::now(), count),
                value: DataValue::new_now(Variant::Int32(value)),
            }),
        );
        if let Some(frames) = self.frames.lock().unwrap().as_ref() {
            frames.send_modify(|count| *count += 1);
        }
    }
}

#[async_trait]
impl Backend for Arc<Fake> {
    fn carried(&self, _: &NodePath, entry: Entry) -> Option<Option<Carried>> {
        self.carried.lock().unwrap().get(&entry).cloned()
    }

    async fn read(&self, _: &NodePath, entry: Entry, _: &Caller) -> DataValue {
        self.uploads.lock().unwrap().push((entry, Instant::now()));
        tokio::time::sleep(UPLOAD).await;
        DataValue::new_now(Variant::UInt16(entry.0))
    }

    fn frames(&self, _: &NodePath) -> Option<watch::Receiver<u64>> {
        let mut frames = self.frames.lock().unwrap();
        Some(
            frames
                .get_or_insert_with(|| watch::Sender::new(0))
                .subscribe(),
        )
    }

    fn publish(&self, _: &NodePath, entry: Entry, value: DataValue) {
        self.published.lock().unwrap().push((entry, value));
    }
}

fn node() -> NodePath {
    NodePath {
        bus: "demo".into(),
        node: 3,
    }
}

fn handle(id: u32) -> MonitoredItemHandle {
    MonitoredItemHandle {
        subscription_id: 1,
        monitored_item_id: id,
    }
}

fn caller() -> Caller {
    Caller::new(Channel::Opcua, "anonymous", None)
}

fn sampling(bound: u32) -> (DictionarySampling, Arc<Fake>) {
    let fake = Arc::new(Fake::default());
    let sampling = DictionarySampling::new(bound);
    sampling.start(Arc::new(fake.clone()));
    (sampling, fake)
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
async fn many_items_on_one_node_take_no_more_uploads_a_second_than_the_bound() {
    const BOUND: u32 = 20;
    let (sampling, fake) = sampling(BOUND);
    // Twelve objects, two items each, every one asking 1 ms.
    for n in 0..24u32 {
        let entry = (0x2000 + (n % 12) as u16, 0);
        sampling.monitor(handle(n), node(), entry, 1.0, caller());
    }
    let start = Instant::now();
    tokio::time::sleep(Duration::from_secs(10)).await;
    let uploads = fake.uploads();
    // Per second, at most the bound: every window of one second.
    for (at, (_, started)) in uploads.iter().enumerate() {
        let within = uploads[at..]
            .iter()
            .take_while(|(_, other)| *other < *started + Duration::from_secs(1))
            .count();
        assert!(within <= BOUND as usize, "{within} uploads in one second");
    }
    // And the bound is used: each object gets its share, 20/12 a second.
    assert!(
        uploads.len() >= (BOUND as usize) * 10 - 1,
        "{}",
        uploads.len()
    );
    for n in 0..12u16 {
        let of = uploads
            .iter()
            .filter(|(entry, _)| entry.0 == 0x2000 + n)
            .count();
        assert!((15..=18).contains(&of), "object {n}: {of} uploads in 10 s");
    }
    // Sampled slower than asked: the values say so.
    let values = fake.published((0x2000, 0));
    assert!(!values.is_empty());
    assert!(
        values
            .iter()
            .all(|value| value.status() == StatusCode::GoodOverload)
    );
    assert!(Instant::now() - start >= Duration::from_secs(10));
}

#[tokio::test(start_paused = true)]
async fn an_item_within_the_bound_is_sampled_at_its_interval_with_good_values() {
    let (sampling, fake) = sampling(20);
    sampling.monitor(handle(1), node(), (0x1017, 0), 500.0, caller());
    tokio::time::sleep(Duration::from_millis(2_100)).await;
    let uploads = fake.uploads();
    assert_eq!(uploads.len(), 5, "{uploads:?}");
    let values = fake.published((0x1017, 0));
    assert!(
        values
            .iter()
            .all(|value| value.status() == StatusCode::Good)
    );
}

#[tokio::test(start_paused = true)]
async fn an_object_a_tpdo_carries_takes_no_sdo_and_sends_each_frames_value() {
    let (sampling, fake) = sampling(20);
    let position = (0x6064, 0);
    fake.carried.lock().unwrap().insert(position, None);
    sampling.monitor(handle(1), node(), position, 1.0, caller());
    tokio::time::sleep(Duration::from_millis(50)).await;
    fake.frame(position, -1200, 1);
    tokio::time::sleep(Duration::from_millis(50)).await;
    fake.frame(position, -1100, 2);
    tokio::time::sleep(Duration::from_secs(5)).await;
    assert!(fake.uploads().is_empty(), "{:?}", fake.uploads());
    let values: Vec<_> = fake
        .published(position)
        .into_iter()
        .map(|value| value.value)
        .collect();
    assert_eq!(
        values,
        vec![Some(Variant::Int32(-1200)), Some(Variant::Int32(-1100))]
    );
    // Its first value is the TPDO's too.
    assert_eq!(
        sampling
            .initial(&node(), position)
            .and_then(|value| value.value),
        Some(Variant::Int32(-1100))
    );
}

#[tokio::test(start_paused = true)]
async fn sampling_stops_when_the_last_item_goes() {
    let (sampling, fake) = sampling(20);
    sampling.monitor(handle(1), node(), (0x1017, 0), 100.0, caller());
    sampling.monitor(handle(2), node(), (0x1017, 0), 100.0, caller());
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert!(!fake.uploads().is_empty());
    sampling.unmonitor(handle(1));
    tokio::time::sleep(Duration::from_secs(1)).await;
    let while_one = fake.uploads().len();
    assert!(while_one > 10, "{while_one}");
    assert_eq!(sampling.sampled_nodes(), vec![node()]);
    sampling.unmonitor(handle(2));
    tokio::time::sleep(Duration::from_secs(5)).await;
    // At most the upload under way when it went.
    assert!(fake.uploads().len() <= while_one + 1);
    assert!(sampling.sampled_nodes().is_empty());
}

#[tokio::test(start_paused = true)]
async fn nothing_is_sampled_before_the_server_starts_it_nor_unmonitored() {
    let fake = Arc::new(Fake::default());
    let sampling = DictionarySampling::new(20);
    sampling.monitor(handle(1), node(), (0x1017, 0), 100.0, caller());
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert!(fake.uploads().is_empty());
    sampling.start(Arc::new(fake.clone()));
    tokio::time::sleep(Duration::from_millis(150)).await;
    assert_eq!(fake.uploads().len(), 2);
    // A slower interval asked by ModifyMonitoredItems.
    sampling.modify(handle(1), 1000.0);
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert!(fake.uploads().len() <= 6, "{}", fake.uploads().len());
}
