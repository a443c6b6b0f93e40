use super::*;

const SYNC: CanId = CanId::Standard(SYNC_COB_ID);

fn us(us: u64) -> Duration {
    Duration::from_micros(us)
}

fn sync(data: &[u8]) -> Frame {
    Frame::new(SYNC, data).unwrap()
}

#[test]
fn sync_frames_encode_byte_exact() {
    assert_eq!(SyncMessage::new(None).encode(SYNC).to_string(), "080#");
    assert_eq!(SyncMessage::new(Some(1)).encode(SYNC).to_string(), "080#01");
    assert_eq!(
        SyncMessage::new(Some(240)).encode(SYNC).to_string(),
        "080#F0"
    );
    assert_eq!(
        SyncMessage::new(None)
            .encode(CanId::Extended(0x1000_0080))
            .to_string(),
        "10000080#"
    );
}

#[test]
fn sync_frames_decode_and_reject_malformed_ones() {
    assert_eq!(SyncMessage::decode(&sync(&[])), Ok(SyncMessage::new(None)));
    assert_eq!(
        SyncMessage::decode(&sync(&[0x01])),
        Ok(SyncMessage::new(Some(1)))
    );
    assert_eq!(
        SyncMessage::decode(&sync(&[0xF0])),
        Ok(SyncMessage::new(Some(240)))
    );
    assert_eq!(
        SyncMessage::decode(&sync(&[0x00])),
        Err(SyncError::Counter(0))
    );
    assert_eq!(
        SyncMessage::decode(&sync(&[0xF1])),
        Err(SyncError::Counter(241))
    );
    assert_eq!(
        SyncMessage::decode(&sync(&[1, 2])),
        Err(SyncError::Length(2))
    );
    assert_eq!(
        SyncMessage::decode(&sync(&[0; 8])),
        Err(SyncError::Length(8))
    );
    assert_eq!(
        SyncMessage::decode(&Frame::remote(SYNC, 0).unwrap()),
        Err(SyncError::Remote)
    );
    assert_eq!(SyncError::Length(2).emcy_code(), Some(0x8240));
    assert_eq!(SyncError::Counter(0).emcy_code(), None);
}

#[test]
fn the_producer_sends_every_period_without_counter() {
    let t0 = Instant::now();
    let mut producer = SyncProducer::new();
    assert_eq!(producer.poll(t0 + us(1_000_000)), None);
    producer.set_period_us(10_000, t0);
    assert_eq!(producer.period(), Some(us(10_000)));
    assert_eq!(producer.deadline(), Some(t0 + us(10_000)));
    assert_eq!(producer.poll(t0 + us(9_999)), None);
    assert_eq!(producer.poll(t0 + us(10_000)).unwrap().to_string(), "080#");
    assert_eq!(producer.deadline(), Some(t0 + us(20_000)));
    // Late by less than a period: no drift.
    assert!(producer.poll(t0 + us(21_000)).is_some());
    assert_eq!(producer.deadline(), Some(t0 + us(30_000)));
    // Late by several periods: one SYNC, not a burst.
    assert!(producer.poll(t0 + us(95_000)).is_some());
    assert_eq!(producer.poll(t0 + us(95_000)), None);
    assert_eq!(producer.deadline(), Some(t0 + us(105_000)));
    producer.set_period_us(0, t0 + us(100_000));
    assert_eq!(producer.deadline(), None);
    assert_eq!(producer.poll(t0 + us(1_000_000)), None);
}

#[test]
fn the_counter_runs_from_1_to_the_overflow_value() {
    let t0 = Instant::now();
    let mut producer = SyncProducer::new();
    producer.set_counter_overflow(3).unwrap();
    assert_eq!(producer.counter_overflow(), 3);
    producer.set_period_us(1_000, t0);
    let sent: Vec<String> = (1..=7)
        .map(|n| producer.poll(t0 + us(1_000 * n)).unwrap().to_string())
        .collect();
    assert_eq!(
        sent,
        [
            "080#01", "080#02", "080#03", "080#01", "080#02", "080#03", "080#01"
        ]
    );
    producer.reset_counter();
    assert_eq!(producer.poll(t0 + us(8_000)).unwrap().to_string(), "080#01");
}

#[test]
fn the_overflow_value_is_checked_and_fixed_while_running() {
    let t0 = Instant::now();
    let mut producer = SyncProducer::new();
    assert_eq!(
        producer.set_counter_overflow(1),
        Err(SyncError::Overflow(1))
    );
    assert_eq!(
        producer.set_counter_overflow(241),
        Err(SyncError::Overflow(241))
    );
    assert_eq!(SyncError::Overflow(1).abort_code(), Some(0x0609_0030));
    assert_eq!(producer.set_counter_overflow(240), Ok(()));
    assert_eq!(producer.set_counter_overflow(0), Ok(()));
    producer.set_period(us(500), t0);
    assert_eq!(
        producer.set_counter_overflow(10),
        Err(SyncError::WhileRunning)
    );
    assert_eq!(SyncError::WhileRunning.abort_code(), Some(0x0800_0022));
    producer.set_period(Duration::ZERO, t0);
    assert_eq!(producer.set_counter_overflow(10), Ok(()));
    // Restarting starts the counter at 1 again.
    producer.set_period(us(500), t0);
    let _ = producer.poll(t0 + us(500));
    let _ = producer.poll(t0 + us(1000));
    producer.set_period(Duration::ZERO, t0 + us(1000));
    producer.set_period(us(500), t0 + us(1000));
    assert_eq!(producer.poll(t0 + us(1500)).unwrap().to_string(), "080#01");
}

#[test]
fn a_producer_on_another_cob_id() {
    let t0 = Instant::now();
    let mut producer = SyncProducer::with_cob_id(CanId::Standard(0x081));
    assert_eq!(producer.cob_id(), CanId::Standard(0x081));
    producer.set_period(us(100), t0);
    assert_eq!(producer.poll(t0 + us(100)).unwrap().to_string(), "081#");
}

#[test]
fn the_consumer_extracts_the_counter() {
    let mut consumer = SyncConsumer::new();
    assert_eq!(
        consumer.on_frame(&sync(&[])),
        Ok(Some(SyncMessage::new(None)))
    );
    consumer.set_counter_overflow(10).unwrap();
    assert_eq!(
        consumer.on_frame(&sync(&[7])),
        Ok(Some(SyncMessage::new(Some(7))))
    );
    let other = Frame::new(CanId::Standard(0x081), &[1, 2, 3]).unwrap();
    assert_eq!(consumer.on_frame(&other), Ok(None));
    assert_eq!(
        consumer.set_counter_overflow(1),
        Err(SyncError::Overflow(1))
    );
}

#[test]
fn the_consumer_reports_a_sync_of_the_wrong_length() {
    let mut consumer = SyncConsumer::new();
    let error = consumer.on_frame(&sync(&[5])).unwrap_err();
    assert_eq!(
        error,
        SyncError::UnexpectedLength {
            expected: 0,
            got: 1
        }
    );
    assert_eq!(error.emcy_code(), Some(0x8240));
    assert_eq!(consumer.on_frame(&sync(&[1, 2])), Err(SyncError::Length(2)));
    consumer.set_counter_overflow(5).unwrap();
    assert_eq!(
        consumer.on_frame(&sync(&[])),
        Err(SyncError::UnexpectedLength {
            expected: 1,
            got: 0
        })
    );
    assert_eq!(consumer.on_frame(&sync(&[0])), Err(SyncError::Counter(0)));
    assert_eq!(
        SyncError::UnexpectedLength {
            expected: 1,
            got: 0
        }
        .to_string(),
        "a SYNC with 0 data bytes where 1 is expected"
    );
}
