//! The producers' pacing and the life of their tasks.

use super::*;

#[test]
fn the_period_is_capped_and_odd_rates_count_as_one_hertz() {
    assert_eq!(period(20.0), Duration::from_millis(50));
    assert_eq!(period(1e9), Duration::from_millis(10));
    assert_eq!(period(0.0), Duration::from_secs(1));
    assert_eq!(period(f64::NAN), Duration::from_secs(1));
    assert_eq!(period_at_most(500.0, 1000.0), Duration::from_millis(2));
}

/// Issue 19, point 8: `max_rate_hz: 1e-300` reached `period`, and
/// `Duration::from_secs_f64(1e300)` panicked in the producer task.
#[test]
fn the_period_is_a_sleepable_duration_for_every_rate() {
    assert_eq!(1.0 / MIN_RATE_HZ, LONGEST_PERIOD.as_secs_f64());
    assert_eq!(period_at_most(f64::MAX, f64::MAX), Duration::from_millis(1));
    let rates = [
        1e-300,
        f64::MIN_POSITIVE,
        5e-324, // the smallest subnormal: 1 / it is infinite
        1e-3,
        MIN_RATE_HZ,
        0.0,
        -0.0,
        -1.0,
        -1e300,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NAN,
        f64::MAX,
        1e300,
    ];
    for rate in rates {
        for max in [
            MAX_PUBLISH_HZ,
            1000.0,
            0.0,
            -1.0,
            f64::NAN,
            f64::INFINITY,
            1e-300,
        ] {
            let every = period_at_most(rate, max);
            assert!(every > Duration::ZERO, "{rate} Hz at most {max}: {every:?}");
            assert!(
                every <= LONGEST_PERIOD,
                "{rate} Hz at most {max}: {every:?}"
            );
            // The producers add it to now, and take it from now.
            let now = tokio::time::Instant::now();
            assert!(now + every > now);
        }
        assert!(period(rate) >= Duration::from_millis(10), "{rate}");
    }
    assert_eq!(period(1e-300), LONGEST_PERIOD);
    assert_eq!(period(5e-324), LONGEST_PERIOD);
    assert_eq!(period(f64::INFINITY), Duration::from_secs(1));
    assert_eq!(period(f64::MAX), Duration::from_millis(10));
}

/// A producer that publishes a count every 10 ms while it has readers.
async fn count(topic: ValueTopic, lease: Lease<u8>) {
    let mut n = 0;
    while lease.keep_going() {
        n += 1;
        topic.publish(serde_json::json!(n));
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

#[tokio::test(start_paused = true)]
async fn a_producer_runs_while_someone_reads_and_starts_again_for_the_next_reader() {
    let set = TopicSet::new();
    let mut first = set.subscribe(1u8, 10.0, count);
    let second = set.subscribe(1u8, 10.0, count);
    assert_eq!(first.changed().await.unwrap().data, serde_json::json!(1));
    assert!(set.is_running(&1));
    drop(second);
    tokio::time::sleep(Duration::from_millis(25)).await;
    assert!(set.is_running(&1), "one reader is left");
    drop(first);
    tokio::time::sleep(Duration::from_millis(25)).await;
    assert!(!set.is_running(&1));
    let published = set.topic(&1).unwrap().latest().unwrap().seq;
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(set.topic(&1).unwrap().latest().unwrap().seq, published);

    let mut again = set.subscribe(1u8, 10.0, count);
    assert!(set.is_running(&1));
    assert_eq!(again.changed().await.unwrap().data, serde_json::json!(1));
}

#[tokio::test(start_paused = true)]
async fn dropping_the_set_ends_its_producers() {
    let set = TopicSet::new();
    let reader = set.subscribe(7u8, 10.0, count);
    let topic = set.topic(&7).unwrap();
    tokio::time::sleep(Duration::from_millis(15)).await;
    drop(set);
    tokio::time::sleep(Duration::from_millis(5)).await;
    let seq = topic.latest().unwrap().seq;
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(topic.latest().unwrap().seq, seq, "the task still publishes");
    drop(reader);
}

/// The suspects of the soak's stalled topics (issue 19, point 11) on this
/// side: a reader that comes just as its producer decides to end, a task
/// that ends while its topic has readers. Readers come and go in a seeded
/// random order, at 0 to 15 ms apart around a producer of 10 ms rounds
/// (0: in the same instant, only a yield between): whenever someone
/// reads, a producer runs and publishes.
#[tokio::test(start_paused = true)]
async fn no_reader_is_left_without_a_producer_however_readers_come_and_go() {
    let set = TopicSet::new();
    let mut rng = 0x2545_F491_4F6C_DD1Du64;
    let mut next = move |n: u64| {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng % n
    };
    let mut readers: Vec<TopicReceiver> = Vec::new();
    let mut read_since: Option<tokio::time::Instant> = None;
    let mut seen = (0, tokio::time::Instant::now());
    let mut restarts = 0;
    for step in 0..3000 {
        // Leaving a little likelier than coming: the topic is often left
        // without readers, long enough for its producer to end.
        match next(6) {
            0 | 1 => {
                if !set.is_running(&1) {
                    restarts += 1;
                }
                readers.push(set.subscribe(1u8, 100.0, count));
            }
            2..=4 if !readers.is_empty() => {
                let gone = next(readers.len() as u64) as usize;
                readers.swap_remove(gone);
            }
            _ => {}
        }
        match next(16) {
            0 => tokio::task::yield_now().await,
            ms => tokio::time::sleep(Duration::from_millis(ms)).await,
        }
        let now = tokio::time::Instant::now();
        let seq = set
            .topic(&1)
            .and_then(|topic| topic.latest())
            .map_or(0, |s| s.seq);
        if seq != seen.0 {
            seen = (seq, now);
        }
        if readers.is_empty() {
            read_since = None;
            continue;
        }
        assert!(set.is_running(&1), "step {step}: readers, no producer");
        let since = *read_since.get_or_insert(now);
        // Someone has read for 25 ms: something was published within them.
        if now - since >= Duration::from_millis(25) {
            assert!(
                now - seen.1 <= Duration::from_millis(25),
                "step {step}: nothing published for {:?} with {} readers",
                now - seen.1,
                readers.len()
            );
        }
    }
    assert!(
        restarts > 100,
        "the producer ended and started again {restarts} times"
    );
}
