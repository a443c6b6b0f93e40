use super::*;
use crate::behaviour::RaisedEmcy;
use crate::canopen::NodeId;
use crate::canopen::eds::Eds;
use crate::canopen::nmt::NmtState;
use crate::objects::ObjectStore;
use crate::profiles::builtin;

fn store() -> ObjectStore {
    let dictionary = Eds::parse(builtin::IO401, "io401.eds").unwrap().dictionary;
    ObjectStore::new(dictionary, NodeId::new(4).unwrap()).unwrap()
}

/// Runs an io401 from 0 to `ms` one tick at a time; its store.
fn run(store: &mut ObjectStore, io401: &mut Io401, from_ms: u64, to_ms: u64) {
    let mut raised: Vec<RaisedEmcy> = Vec::new();
    for t in from_ms..=to_ms {
        let mut io = DeviceIo::new(store, NmtState::Operational, t, &mut raised);
        if t == 0 {
            io401.reset(&mut io);
        } else {
            io401.tick(&mut io);
        }
    }
    assert!(raised.is_empty());
}

#[test]
fn the_inputs_follow_the_documented_pattern() {
    // The running light: input 1 in the first quarter second, input 5 at
    // 1 s, input 16 at 3.75 s, input 1 again at 4 s.
    assert_eq!(inputs_at(0).0, [0x01, 0x00]);
    assert_eq!(inputs_at(1_000).0, [0x10, 0x00]);
    assert_eq!(inputs_at(3_750).0, [0x00, 0x80]);
    assert_eq!(inputs_at(4_000).0, [0x01, 0x00]);
    // ai1 a sine of 10,000 over 10 s, ai2 a triangle to 20,000 over 20 s,
    // ai3 ±5,000 a second each.
    assert_eq!(inputs_at(0).1, [0, 0, 5_000]);
    assert_eq!(inputs_at(2_500).1, [10_000, 5_000, 5_000]);
    assert_eq!(inputs_at(7_500).1, [-10_000, 15_000, -5_000]);
    assert_eq!(inputs_at(10_000).1, [0, 20_000, 5_000]);
    assert_eq!(inputs_at(15_000).1[1], 10_000);
}

#[test]
fn the_store_carries_the_inputs_with_polarity_and_ai4_reads_back_ao1() {
    let mut store = store();
    let mut io401 = Io401::new();
    run(&mut store, &mut io401, 0, 1_000);
    assert_eq!(store.int(READ_INPUT_8, 1), Some(0x10));
    assert_eq!(store.int(READ_INPUT_8, 2), Some(0x00));
    assert_eq!(store.int(READ_ANALOG_INPUT_16, 3), Some(-5_000));
    // Polarity inverts a group; the output shows in ai4 at once.
    store.set_int_saturating(POLARITY_INPUT_8, 2, 0xFF);
    store.set_int_saturating(WRITE_ANALOG_OUTPUT_16, 1, -1234);
    let mut raised = Vec::new();
    let mut io = DeviceIo::new(&mut store, NmtState::Operational, 1_001, &mut raised);
    io401.written(&mut io, WRITE_ANALOG_OUTPUT_16, 1);
    assert_eq!(store.int(READ_INPUT_8, 2), Some(0xFF));
    assert_eq!(store.int(READ_ANALOG_INPUT_16, 4), Some(-1234));
    // Moments later the light has moved on.
    run(&mut store, &mut io401, 1_002, 1_260);
    assert_eq!(store.int(READ_INPUT_8, 1), Some(0x20));
}
