//! The sampler on the paused clock, through a fake backend that counts
//! its SDO uploads.

use std::collections::HashMap;
use std::sync::Mutex;

use opcua::types::Variant;

use super::*;
use crate::gateway::Channel as CallerChannel;
use crate::profiles::cia401::Channel;

/// How long a fake upload takes.
const UPLOAD: Duration = Duration::from_millis(2);

#[derive(Default)]
struct Fake {
    /// Each upload: the object and when it started.
    uploads: Mutex<Vec<(Entry, Instant)>>,
    /// What the device holds, by object; the index's bytes where not set.
    device: Mutex<HashMap<Entry, Vec<u8>>>,
    /// The objects whose uploads time out.
    failing: Mutex<Vec<Entry>>,
    /// The objects a TPDO carries, and their newest bytes.
    carried: Mutex<BTreeMap<Entry, Option<Carried>>>,
    frames: Mutex<Option<watch::Sender<u64>>>,
    published: Mutex<Vec<(Watched, DataValue)>>,
}

impl Fake {
    fn uploads(&self) -> Vec<(Entry, Instant)> {
        self.uploads.lock().unwrap().clone()
    }

    fn uploads_of(&self, entry: Entry) -> usize {
        self.uploads().iter().filter(|(of, _)| *of == entry).count()
    }

    fn published(&self, watched: Watched) -> Vec<DataValue> {
        let published = self.published.lock().unwrap();
        published
            .iter()
            .filter(|(of, _)| *of == watched)
            .map(|(_, value)| value.clone())
            .collect()
    }

    fn values(&self, watched: Watched) -> Vec<Variant> {
        self.published(watched)
            .into_iter()
            .filter_map(|value| value.value)
            .collect()
    }

    fn hold(&self, entry: Entry, data: &[u8]) {
        self.device.lock().unwrap().insert(entry, data.to_vec());
    }

    /// A TPDO frame brings `data` for `entry`.
    fn frame_of(&self, entry: Entry, data: &[u8], count: u64) {
        self.carried.lock().unwrap().insert(
            entry,
            Some(Carried {
                seen: (Instant::now(), count),
                data: data.to_vec(),
            }),
        );
        if let Some(frames) = self.frames.lock().unwrap().as_ref() {
            frames.send_modify(|count| *count += 1);
        }
    }

    /// A TPDO frame brings `value` (an INTEGER32) for `entry`.
    fn frame(&self, entry: Entry, value: i32, count: u64) {
        self.frame_of(entry, &value.to_le_bytes(), count);
    }
}

#[async_trait]
impl Backend for Arc<Fake> {
    fn carried(&self, _: &NodePath, entry: Entry) -> Option<Option<Carried>> {
        self.carried.lock().unwrap().get(&entry).cloned()
    }

    async fn read(&self, _: &NodePath, entry: Entry, _: &Caller) -> Result<Vec<u8>, GatewayError> {
        self.uploads.lock().unwrap().push((entry, Instant::now()));
        tokio::time::sleep(UPLOAD).await;
        if self.failing.lock().unwrap().contains(&entry) {
            return Err(GatewayError::SdoTimeout { node: 3 });
        }
        let held = self.device.lock().unwrap().get(&entry).cloned();
        Ok(held.unwrap_or_else(|| entry.0.to_le_bytes().to_vec()))
    }

    /// By its length, as an EDS would type it.
    fn decode(&self, _: &NodePath, entry: Entry, data: &[u8]) -> Result<Variant, GatewayError> {
        match *data {
            [byte] => Ok(Variant::Byte(byte)),
            [low, high] => Ok(Variant::UInt16(u16::from_le_bytes([low, high]))),
            [a, b, c, d] => Ok(Variant::Int32(i32::from_le_bytes([a, b, c, d]))),
            _ => Err(GatewayError::InvalidValue(format!("{entry:?}: {data:?}"))),
        }
    }

    fn frames(&self, _: &NodePath) -> Option<watch::Receiver<u64>> {
        let mut frames = self.frames.lock().unwrap();
        Some(
            frames
                .get_or_insert_with(|| watch::Sender::new(0))
                .subscribe(),
        )
    }

    fn publish(&self, _: &NodePath, watched: Watched, value: DataValue) {
        self.published.lock().unwrap().push((watched, value));
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
    Caller::new(CallerChannel::Opcua, "anonymous", None)
}

fn sampling(bound: u32) -> (Sampling, Arc<Fake>) {
    let fake = Arc::new(Fake::default());
    let sampling = Sampling::new(bound);
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
        sampling.monitor(handle(n), node(), Watched::Entry(entry), 1.0, caller());
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
    let values = fake.published(Watched::Entry((0x2000, 0)));
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
    sampling.monitor(
        handle(1),
        node(),
        Watched::Entry((0x1017, 0)),
        500.0,
        caller(),
    );
    tokio::time::sleep(Duration::from_millis(2_100)).await;
    let uploads = fake.uploads();
    assert_eq!(uploads.len(), 5, "{uploads:?}");
    let values = fake.published(Watched::Entry((0x1017, 0)));
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
    sampling.monitor(handle(1), node(), Watched::Entry(position), 1.0, caller());
    tokio::time::sleep(Duration::from_millis(50)).await;
    fake.frame(position, -1200, 1);
    tokio::time::sleep(Duration::from_millis(50)).await;
    fake.frame(position, -1100, 2);
    tokio::time::sleep(Duration::from_secs(5)).await;
    assert!(fake.uploads().is_empty(), "{:?}", fake.uploads());
    assert_eq!(
        fake.values(Watched::Entry(position)),
        vec![Variant::Int32(-1200), Variant::Int32(-1100)]
    );
    // Its first value is the TPDO's too.
    assert_eq!(
        sampling
            .initial(&node(), Watched::Entry(position))
            .and_then(|value| value.value),
        Some(Variant::Int32(-1100))
    );
}

#[tokio::test(start_paused = true)]
async fn sampling_stops_when_the_last_item_goes() {
    let (sampling, fake) = sampling(20);
    sampling.monitor(
        handle(1),
        node(),
        Watched::Entry((0x1017, 0)),
        100.0,
        caller(),
    );
    sampling.monitor(
        handle(2),
        node(),
        Watched::Entry((0x1017, 0)),
        100.0,
        caller(),
    );
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
    let sampling = Sampling::new(20);
    sampling.monitor(
        handle(1),
        node(),
        Watched::Entry((0x1017, 0)),
        100.0,
        caller(),
    );
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

fn channel(name: &str) -> Watched {
    Watched::Channel(Channel::parse(name).unwrap())
}

fn led(segment: u8, field: LedField) -> Watched {
    Watched::Led { segment, field }
}

#[tokio::test(start_paused = true)]
async fn a_tpdo_carried_digital_input_sends_each_change_of_its_bit_and_nothing_for_the_others() {
    let (sampling, fake) = sampling(20);
    // di1 and di2: bits 0 and 1 of 0x6000 sub 1, which TPDO1 carries.
    let group = (0x6000, 1);
    fake.carried.lock().unwrap().insert(group, None);
    sampling.monitor(handle(1), node(), channel("di2"), 1.0, caller());
    sampling.monitor(handle(2), node(), channel("di1"), 1.0, caller());
    tokio::time::sleep(Duration::from_millis(50)).await;
    for (count, byte) in [
        0b0000_0000u8,
        0b0000_0001,
        0b0000_0011,
        0b0000_0011,
        0b1000_0001,
    ]
    .into_iter()
    .enumerate()
    {
        fake.frame_of(group, &[byte], count as u64 + 1);
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert!(fake.uploads().is_empty(), "{:?}", fake.uploads());
    // di2 changes at the third frame and the fifth: di1's change at the
    // second, the same byte again and bit 7 send nothing for it.
    assert_eq!(
        fake.values(channel("di2")),
        vec![
            Variant::Boolean(false),
            Variant::Boolean(true),
            Variant::Boolean(false)
        ]
    );
    assert_eq!(
        fake.values(channel("di1")),
        vec![Variant::Boolean(false), Variant::Boolean(true)]
    );
    // An item that joins starts with the newest.
    let first = sampling.initial(&node(), channel("di2"));
    assert_eq!(
        first.and_then(|value| value.value),
        Some(Variant::Boolean(false))
    );
}

#[tokio::test(start_paused = true)]
async fn an_output_and_led_fields_are_sampled_at_their_interval_and_sent_when_they_change() {
    let (sampling, fake) = sampling(20);
    let ao1 = (0x6411, 1);
    fake.hold(ao1, &(-1000i16).to_le_bytes());
    // Segment 2's Dimmer is 0x6125; segment 1's Color_01 is 0x6030 sub 1 to 4.
    fake.hold((0x6125, 0), &[128]);
    for (sub, level) in (1..=4).zip([0x12, 0x34, 0x56, 0x78]) {
        fake.hold((0x6030, sub), &[level]);
    }
    sampling.monitor(handle(1), node(), channel("ao1"), 500.0, caller());
    sampling.monitor(handle(2), node(), led(2, LedField::Dimmer), 500.0, caller());
    sampling.monitor(
        handle(3),
        node(),
        led(1, LedField::Color(1)),
        500.0,
        caller(),
    );
    // Six objects, 50 ms apart (the bound), every 500 ms: five rounds
    // from 0, 0.5, 1, 1.5 and 2 s, the next at 2.5 s.
    tokio::time::sleep(Duration::from_millis(2_400)).await;
    assert_eq!(fake.uploads_of(ao1), 5, "{:?}", fake.uploads());
    assert_eq!(fake.uploads_of((0x6125, 0)), 5);
    for sub in 1..=4 {
        assert_eq!(fake.uploads_of((0x6030, sub)), 5);
    }
    assert_eq!(fake.uploads().len(), 30);
    // Read as the profiles say, once: the same value again sends nothing,
    // and a colour goes out whole, never with some of its channels read.
    assert_eq!(fake.values(channel("ao1")), vec![Variant::Int16(-1000)]);
    assert_eq!(
        fake.values(led(2, LedField::Dimmer)),
        vec![Variant::Byte(128)]
    );
    assert_eq!(
        fake.values(led(1, LedField::Color(1))),
        vec![Variant::String("#12345678".into())]
    );
    assert!(
        fake.published(channel("ao1"))
            .iter()
            .all(|value| value.status() == StatusCode::Good)
    );
    // A new value is sent with the next sample.
    fake.hold(ao1, &2000i16.to_le_bytes());
    fake.hold((0x6030, 2), &[0xFF]);
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert_eq!(
        fake.values(channel("ao1")),
        vec![Variant::Int16(-1000), Variant::Int16(2000)]
    );
    assert_eq!(
        fake.values(led(1, LedField::Color(1))),
        vec![
            Variant::String("#12345678".into()),
            Variant::String("#12ff5678".into())
        ]
    );
    // An item that joins starts with the value last sent.
    let first = sampling.initial(&node(), channel("ao1"));
    assert_eq!(
        first.and_then(|value| value.value),
        Some(Variant::Int16(2000))
    );
}

#[tokio::test(start_paused = true)]
async fn io_led_and_dictionary_items_share_the_nodes_one_bound() {
    const BOUND: u32 = 10;
    let (sampling, fake) = sampling(BOUND);
    let watched = [
        channel("ao1"),
        channel("ao2"),
        channel("do3"),
        led(1, LedField::Dimmer),
        led(4, LedField::Value),
        Watched::Entry((0x1017, 0)),
    ];
    for (n, watched) in (0..).zip(watched) {
        sampling.monitor(handle(n), node(), watched, 1.0, caller());
    }
    tokio::time::sleep(Duration::from_secs(10)).await;
    let uploads = fake.uploads();
    for (at, (_, started)) in uploads.iter().enumerate() {
        let within = uploads[at..]
            .iter()
            .take_while(|(_, other)| *other < *started + Duration::from_secs(1))
            .count();
        assert!(within <= BOUND as usize, "{within} uploads in one second");
    }
    // Six objects share 10 a second: 10/6 each.
    for watched in watched {
        let entry = watched.objects()[0];
        let of = fake.uploads_of(entry);
        assert!((15..=18).contains(&of), "{watched:?}: {of} uploads in 10 s");
        let values = fake.published(watched);
        assert!(!values.is_empty(), "{watched:?}");
        assert!(
            values
                .iter()
                .all(|value| value.status() == StatusCode::GoodOverload),
            "{watched:?}: {values:?}"
        );
    }
}

#[tokio::test(start_paused = true)]
async fn a_failed_read_is_a_value_with_its_status_and_sampling_goes_on() {
    let (sampling, fake) = sampling(20);
    let dimmer = led(3, LedField::Dimmer);
    let object = dimmer.objects()[0];
    fake.failing.lock().unwrap().push(object);
    sampling.monitor(handle(1), node(), dimmer, 200.0, caller());
    tokio::time::sleep(Duration::from_millis(500)).await;
    let failed = fake.published(dimmer);
    assert_eq!(failed.len(), 1, "{failed:?}");
    assert_eq!(failed[0].status(), StatusCode::BadTimeout);
    fake.failing.lock().unwrap().clear();
    fake.hold(object, &[42]);
    tokio::time::sleep(Duration::from_millis(300)).await;
    let values = fake.published(dimmer);
    assert_eq!(values.len(), 2, "{values:?}");
    assert_eq!(values[1].value, Some(Variant::Byte(42)));
    assert_eq!(values[1].status(), StatusCode::Good);
}

#[tokio::test(start_paused = true)]
async fn deleting_the_last_io_or_led_item_stops_the_nodes_sampling() {
    let (sampling, fake) = sampling(20);
    sampling.monitor(handle(1), node(), channel("ao1"), 100.0, caller());
    sampling.monitor(handle(2), node(), led(1, LedField::Speed), 100.0, caller());
    tokio::time::sleep(Duration::from_secs(1)).await;
    sampling.unmonitor(handle(1));
    let (ao1, speed) = ((0x6411, 1), (0x6013, 0));
    let before = (fake.uploads_of(ao1), fake.uploads_of(speed));
    tokio::time::sleep(Duration::from_secs(1)).await;
    // ao1 is no longer sampled, Speed still is, every 100 ms.
    assert!(fake.uploads_of(ao1) <= before.0 + 1);
    assert!(fake.uploads_of(speed) >= before.1 + 9);
    assert_eq!(sampling.sampled_nodes(), vec![node()]);
    sampling.unmonitor(handle(2));
    let while_one = fake.uploads().len();
    tokio::time::sleep(Duration::from_secs(5)).await;
    assert!(fake.uploads().len() <= while_one + 1);
    assert!(sampling.sampled_nodes().is_empty());
}
