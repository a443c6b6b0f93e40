use super::*;
use crate::VirtualHub;

fn frame(id: u32, data: &[u8]) -> Frame {
    Frame::new(CanId::standard(id).unwrap(), data).unwrap()
}

#[tokio::test]
async fn a_reader_of_one_identifier_gets_its_frames_alone_in_order_and_never_lags_behind_others() {
    let hub = VirtualHub::new("test");
    let device = hub.attach();
    let client = hub.attach();
    let mut answers = client.subscribe_id(CanId::standard(0x585).unwrap());
    let mut again = client.subscribe_id(CanId::standard(0x585).unwrap());
    let mut other = client.subscribe_id(CanId::standard(0x586).unwrap());
    // Far more frames of other identifiers than a whole-bus reader holds.
    for i in 0..3 * DEFAULT_RX_QUEUE as u32 {
        device.send(frame(0x185, &[i as u8])).await.unwrap();
        if i % 1000 == 0 {
            device
                .send(frame(0x585, &[(i / 1000) as u8]))
                .await
                .unwrap();
        }
    }
    // The client's own frames of that identifier are not heard.
    client.send(frame(0x585, &[0xFF])).await.unwrap();
    for rx in [&mut answers, &mut again] {
        for n in 0..25u8 {
            let got = rx.recv().await.unwrap();
            assert_eq!(
                (got.frame, got.direction),
                (frame(0x585, &[n]), Direction::Rx)
            );
        }
        assert_eq!(rx.try_recv().unwrap(), None);
    }
    assert_eq!(other.try_recv().unwrap(), None);
    assert_eq!(client.counters().rx_overruns, 0);
}

#[tokio::test]
async fn a_reader_of_one_identifier_that_falls_behind_loses_the_oldest_and_is_told() {
    let hub = VirtualHub::new("test");
    let device = hub.attach();
    let client = hub.attach();
    let mut answers = client.subscribe_id(CanId::standard(0x585).unwrap());
    for i in 0..ID_RX_QUEUE as u32 + 10 {
        device.send(frame(0x585, &i.to_le_bytes())).await.unwrap();
    }
    assert_eq!(answers.recv().await, Err(RecvError::Lagged(10)));
    assert_eq!(
        answers.recv().await.unwrap().frame,
        frame(0x585, &10u32.to_le_bytes())
    );
    assert_eq!(client.counters().rx_overruns, 10);
}

#[tokio::test]
async fn a_driver_backed_bus_hands_one_identifier_to_its_readers() {
    let (parts, driver) = driver_channels(
        "can0",
        "socketcand:x",
        BusKind::Socketcand,
        BusStatus::up(),
        false,
    );
    let bus = attach_driver(parts, tokio::spawn(async {}));
    let mut answers = bus.subscribe_id(CanId::standard(0x581).unwrap());
    let mut all = bus.subscribe();
    assert_eq!(driver.receivers(), 2);
    for id in [0x181, 0x581, 0x701, 0x581] {
        driver.received(frame(id, &[id as u8]), Timestamp::now());
    }
    for _ in 0..2 {
        assert_eq!(answers.recv().await.unwrap().frame, frame(0x581, &[0x81]));
    }
    assert_eq!(answers.try_recv().unwrap(), None);
    let mut heard = Vec::new();
    while let Some(got) = all.try_recv().unwrap() {
        heard.push(got.frame.id());
    }
    assert_eq!(heard.len(), 4);
    // A reader gone, its channel goes with the next subscription.
    drop(answers);
    let _other = bus.subscribe_id(CanId::standard(0x582).unwrap());
    assert_eq!(driver.receivers(), 2);
}
