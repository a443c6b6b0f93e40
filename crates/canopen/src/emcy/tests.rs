use super::*;

fn node(id: u8) -> NodeId {
    NodeId::new(id).unwrap()
}

fn us(us: u64) -> Duration {
    Duration::from_micros(us)
}

fn frame(id: u16, data: &[u8]) -> Frame {
    Frame::new(CanId::Standard(id), data).unwrap()
}

#[test]
fn emcy_frames_encode_byte_exact() {
    let emcy = Emcy {
        code: 0x4310,
        register: ErrorRegister::from_raw(0x09),
        manufacturer: [0x01, 0x02, 0x03, 0x04, 0x05],
    };
    assert_eq!(emcy.to_bytes(), [0x10, 0x43, 0x09, 1, 2, 3, 4, 5]);
    assert_eq!(emcy.encode(node(1)).to_string(), "081#1043090102030405");
    assert_eq!(
        Emcy::error_reset(ErrorRegister::NONE)
            .encode(node(0x7F))
            .to_string(),
        "0FF#0000000000000000"
    );
    assert_eq!(
        Emcy::new(0x8130, ErrorRegister::NONE.with(ErrorBit::Communication))
            .encode_on(CanId::Standard(0x0A0))
            .to_string(),
        "0A0#3081100000000000"
    );
}

#[test]
fn emcy_frames_decode_and_reject_malformed_ones() {
    let (from, emcy) = Emcy::decode(&frame(0x085, &[0x10, 0x43, 0x09, 1, 2, 3, 4, 5])).unwrap();
    assert_eq!(from, node(5));
    assert_eq!(emcy.code, 0x4310);
    assert_eq!(emcy.register.raw(), 0x09);
    assert_eq!(emcy.manufacturer, [1, 2, 3, 4, 5]);
    assert!(!emcy.is_reset());
    assert_eq!(
        Emcy::decode(&frame(0x085, &[0x10, 0x43, 0x09])),
        Err(EmcyError::Length(3))
    );
    assert_eq!(Emcy::decode(&frame(0x085, &[])), Err(EmcyError::Length(0)));
    // SYNC, not node 0's EMCY.
    assert_eq!(
        Emcy::decode(&frame(0x080, &[0; 8])),
        Err(EmcyError::NotEmcy(CanId::Standard(0x080)))
    );
    assert_eq!(
        Emcy::decode(&frame(0x185, &[0; 8])),
        Err(EmcyError::NotEmcy(CanId::Standard(0x185)))
    );
    assert_eq!(
        Emcy::decode(&Frame::remote(CanId::Standard(0x085), 8).unwrap()),
        Err(EmcyError::Remote)
    );
    assert_eq!(Emcy::from_bytes(&[0; 9]), Err(EmcyError::Length(9)));
}

#[test]
fn code_0000_is_an_error_reset() {
    let (_, emcy) = Emcy::decode(&frame(0x081, &[0, 0, 0, 0, 0, 0, 0, 0])).unwrap();
    assert!(emcy.is_reset());
    assert_eq!(emcy.text(), "Error reset or no error");
    assert!(Emcy::new(0x0001, ErrorRegister::NONE).is_reset());
    assert!(!Emcy::new(0x1000, ErrorRegister::NONE).is_reset());
}

#[test]
fn error_register_bits_are_named() {
    let register = ErrorRegister::from_raw(0x89);
    assert!(register.contains(ErrorBit::Generic));
    assert!(register.contains(ErrorBit::Temperature));
    assert!(!register.contains(ErrorBit::Current));
    assert_eq!(register.names(), ["generic", "temperature", "manufacturer"]);
    assert_eq!(
        register.to_string(),
        "0x89 (generic, temperature, manufacturer)"
    );
    assert_eq!(ErrorRegister::NONE.to_string(), "0x00");
    let masks: Vec<u8> = ErrorBit::ALL.iter().map(|bit| bit.mask()).collect();
    assert_eq!(masks, [0x01, 0x02, 0x04, 0x08, 0x10, 0x20, 0x40, 0x80]);
    assert_eq!(
        ErrorRegister::NONE
            .with(ErrorBit::Voltage)
            .with(ErrorBit::Generic)
            .without(ErrorBit::Generic)
            .raw(),
        0x04
    );
    assert_eq!(
        ErrorBit::Communication.text(),
        "Communication error (overrun, error state)"
    );
    assert_eq!(ErrorBit::DeviceProfile.name(), "device_profile");
}

#[test]
fn an_emcy_displays_its_text() {
    let emcy = Emcy::new(0x4310, ErrorRegister::from_raw(0x09));
    assert_eq!(
        emcy.to_string(),
        "0x4310 Excess temperature drive, register 0x09 (generic, temperature)"
    );
}

#[test]
fn the_error_field_keeps_the_newest_first_and_bounded() {
    let mut history = ErrorHistory::new(3);
    assert_eq!(history.read(0), Ok(0));
    assert_eq!(
        history.read(1),
        Err(ErrorHistoryError::NoData { sub: 1, count: 0 })
    );
    history.push(0x1000, 0);
    history.push(0x2310, 0x0007);
    assert_eq!(history.read(0), Ok(2));
    assert_eq!(history.read(1), Ok(0x0007_2310));
    assert_eq!(history.read(2), Ok(0x0000_1000));
    history.push(0x3210, 0);
    history.push(0x4310, 0);
    // The oldest (0x1000) fell out.
    assert_eq!(history.count(), 3);
    assert_eq!(
        history.iter().collect::<Vec<_>>(),
        [0x4310, 0x3210, 0x0007_2310]
    );
    assert_eq!(history.read(4), Err(ErrorHistoryError::NoSubIndex(4)));
    assert_eq!(ErrorHistoryError::NoSubIndex(4).abort_code(), 0x0609_0011);
    assert_eq!(
        ErrorHistoryError::NoData { sub: 1, count: 0 }.abort_code(),
        0x0800_0024
    );
}

#[test]
fn writing_0_to_sub_0_clears_the_error_field() {
    let mut history = ErrorHistory::new(5);
    history.push(0x1000, 0);
    assert_eq!(history.write(0, 3), Err(ErrorHistoryError::NotZero(3)));
    assert_eq!(ErrorHistoryError::NotZero(3).abort_code(), 0x0609_0030);
    assert_eq!(history.write(1, 0), Err(ErrorHistoryError::ReadOnly(1)));
    assert_eq!(ErrorHistoryError::ReadOnly(1).abort_code(), 0x0601_0002);
    assert_eq!(history.write(6, 0), Err(ErrorHistoryError::NoSubIndex(6)));
    assert_eq!(history.count(), 1);
    assert_eq!(history.write(0, 0), Ok(()));
    assert!(history.is_empty());
    assert_eq!(ErrorHistory::new(0).capacity(), 1);
    assert_eq!(ErrorHistory::new(255).capacity(), 254);
}

#[test]
fn the_producer_sends_at_once_without_inhibit_time() {
    let t0 = Instant::now();
    let mut producer = EmcyProducer::new(node(3), 8);
    assert_eq!(producer.deadline(), None);
    assert_eq!(producer.poll(t0), None);
    producer.raise(Emcy::new(0x8130, ErrorRegister::from_raw(0x11)), t0);
    producer.raise(Emcy::new(0x3210, ErrorRegister::from_raw(0x15)), t0);
    assert_eq!(producer.deadline(), Some(t0));
    assert_eq!(
        producer.poll(t0).unwrap().to_string(),
        "083#3081110000000000"
    );
    assert_eq!(
        producer.poll(t0).unwrap().to_string(),
        "083#1032150000000000"
    );
    assert_eq!(producer.poll(t0), None);
    assert_eq!(
        producer.history().iter().collect::<Vec<_>>(),
        [0x3210, 0x8130]
    );
    producer.reset(ErrorRegister::NONE, t0);
    assert_eq!(
        producer.poll(t0).unwrap().to_string(),
        "083#0000000000000000"
    );
    // The reset is not an error: the field is unchanged.
    assert_eq!(producer.history().count(), 2);
}

#[test]
fn the_inhibit_time_spaces_emcys_out() {
    let t0 = Instant::now();
    let mut producer = EmcyProducer::new(node(3), 8);
    producer.set_inhibit_time_100us(100);
    assert_eq!(producer.inhibit_time(), us(10_000));
    producer.raise(Emcy::new(0x2310, ErrorRegister::from_raw(0x03)), t0);
    producer.raise(
        Emcy::new(0x3210, ErrorRegister::from_raw(0x07)),
        t0 + us(1_000),
    );
    producer.raise(
        Emcy::new(0x4310, ErrorRegister::from_raw(0x0F)),
        t0 + us(2_000),
    );
    let first = producer.poll(t0 + us(2_000)).unwrap();
    assert_eq!(first.data()[..2], [0x10, 0x23]);
    assert_eq!(producer.poll(t0 + us(2_000)), None);
    assert_eq!(producer.deadline(), Some(t0 + us(12_000)));
    assert_eq!(producer.poll(t0 + us(11_999)), None);
    let second = producer.poll(t0 + us(12_000)).unwrap();
    assert_eq!(second.data()[..2], [0x10, 0x32]);
    assert_eq!(producer.deadline(), Some(t0 + us(22_000)));
    let third = producer.poll(t0 + us(30_000)).unwrap();
    assert_eq!(third.data()[..2], [0x10, 0x43]);
    assert_eq!(producer.pending(), 0);
    // Long after the last one, a new EMCY goes at once.
    producer.raise(
        Emcy::new(0x1000, ErrorRegister::from_raw(0x01)),
        t0 + us(50_000),
    );
    assert_eq!(producer.deadline(), Some(t0 + us(50_000)));
    assert!(producer.poll(t0 + us(50_000)).is_some());
}

#[test]
fn a_full_queue_drops_the_newest() {
    let t0 = Instant::now();
    let mut producer = EmcyProducer::new(node(3), 4);
    producer.set_inhibit_time_100us(10);
    for code in 0..(QUEUE_LEN as u16 + 3) {
        producer.raise(Emcy::new(0x1000 + code, ErrorRegister::NONE), t0);
    }
    assert_eq!(producer.pending(), QUEUE_LEN);
    assert_eq!(producer.dropped(), 3);
    assert_eq!(producer.poll(t0).unwrap().data()[..2], [0x00, 0x10]);
    // 0x1003 still records every error that occurred, newest first.
    assert_eq!(producer.history().read(1), Ok(0x1012));
}
