//! The programming routines at the end of the JMC CANopen manual
//! ("Appendix – Programming routine": RPDO and TPDO configuration, position
//! mode single and multi-point, velocity mode, homing mode), replayed frame
//! by frame against the virtual drive at node 3 as the manual has it
//! (0x603 / 0x583), each frame transcribed with its comment. Every SDO
//! download must get its confirmation (or the abort the drive gives), the
//! CiA 402 steps the statuswords of the manual's table, and the motion what
//! the routine commands.

use std::time::Duration;

use candeck::can::{Bus, CanId, Frame, FrameReceiver, VirtualHub};
use candeck::canopen::NodeId;
use candeck::canopen::od::Value;
use candeck::sim::jmc::{Jmc, LimitSwitches};
use candeck::sim::products::Product;
use candeck::sim::rack::Rack;

/// One frame of a routine: identifier, data, and the manual's comment.
struct Step {
    id: u16,
    data: &'static [u8],
    comment: &'static str,
}

const fn step(id: u16, data: &'static [u8], comment: &'static str) -> Step {
    Step { id, data, comment }
}

/// "1. RPDO Configuration: Configure node 3's index 1402h to receive PDOs
/// for each synchronization message, and Configure control word 6040h and
/// destination 607Ah."
const RPDO_CONFIGURATION: &[Step] = &[
    step(
        0x603,
        &[0x23, 0x02, 0x14, 0x01, 0x03, 0x02, 0x00, 0x00],
        "1402:1 COB-ID 0x203",
    ),
    step(
        0x603,
        &[0x2F, 0x02, 0x14, 0x02, 0x01, 0x00, 0x00, 0x00],
        "1402:2 every SYNC",
    ),
    step(
        0x603,
        &[0x2F, 0x02, 0x16, 0x00, 0x00, 0x00, 0x00, 0x00],
        "1602:0 no entries",
    ),
    step(
        0x603,
        &[0x23, 0x02, 0x16, 0x01, 0x10, 0x00, 0x40, 0x60],
        "1602:1 6040 16 bits",
    ),
    step(
        0x603,
        &[0x23, 0x02, 0x16, 0x02, 0x20, 0x00, 0x7A, 0x60],
        "1602:2 607A 32 bits",
    ),
    step(
        0x603,
        &[0x2F, 0x02, 0x16, 0x00, 0x02, 0x00, 0x00, 0x00],
        "1602:0 two entries",
    ),
];

/// "2. TPDO Configuration: Configure TPDO to send data on every SYNC cycle
/// and map Status Word 6041h and Actual Location 6064h as follows."
const TPDO_CONFIGURATION: &[Step] = &[
    step(
        0x603,
        &[0x23, 0x01, 0x18, 0x01, 0x83, 0x01, 0x00, 0x00],
        "1801:1 COB-ID 0x183",
    ),
    step(
        0x603,
        &[0x2F, 0x01, 0x18, 0x02, 0x01, 0x00, 0x00, 0x00],
        "1801:2 every SYNC",
    ),
    step(
        0x603,
        &[0x2F, 0x01, 0x1A, 0x00, 0x00, 0x00, 0x00, 0x00],
        "1A01:0 no entries",
    ),
    step(
        0x603,
        &[0x23, 0x01, 0x1A, 0x01, 0x10, 0x00, 0x41, 0x60],
        "1A01:1 6041 16 bits",
    ),
    step(
        0x603,
        &[0x23, 0x01, 0x1A, 0x02, 0x20, 0x00, 0x64, 0x60],
        "1A01:2 6064 32 bits",
    ),
    step(
        0x603,
        &[0x2F, 0x01, 0x1A, 0x00, 0x02, 0x00, 0x00, 0x00],
        "1A01:0 two entries",
    ),
];

/// "CIA301 state the pre-operation state to switch to the operating state".
const START: Step = step(
    0x000,
    &[0x01, 0x03],
    "the pre-operation state to switch to the operating state",
);

/// "CIA402 state Power the motor", with the statusword each step gives
/// (the manual's table: initialized device, device operation, device
/// enable; bit 4 the power stage).
const POWER_THE_MOTOR: &[(Step, u16)] = &[
    (
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x06, 0x00, 0x00, 0x00],
            "Shutdown",
        ),
        0x0031,
    ),
    (
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x07, 0x00, 0x00, 0x00],
            "Switched on",
        ),
        0x0033,
    ),
    (
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x0F, 0x00, 0x00, 0x00],
            "Operation Enabled",
        ),
        0x0037,
    ),
];

const SET_POSITION_MODE: &[Step] = &[
    step(
        0x603,
        &[0x2F, 0x60, 0x60, 0x00, 0x01, 0x00, 0x00, 0x00],
        "Set the position mode",
    ),
    step(
        0x603,
        &[0x23, 0x81, 0x60, 0x00, 0x0A, 0x00, 0x00, 0x00],
        "Set the speed of running 1 rps",
    ),
    step(
        0x603,
        &[0x2B, 0x83, 0x60, 0x00, 0xE8, 0x03, 0x00, 0x00],
        "Set acceleration100 rps/s",
    ),
    step(
        0x603,
        &[0x2B, 0x84, 0x60, 0x00, 0xE8, 0x03, 0x00, 0x00],
        "Set deceleration100 rps/s",
    ),
];

/// "Single point motion".
const SINGLE_POINT: &[Step] = &[
    step(
        0x603,
        &[0x23, 0x7A, 0x60, 0x00, 0x40, 0x0D, 0x03, 0x00],
        "Set target position 200000steps",
    ),
    step(
        0x603,
        &[0x2B, 0x40, 0x60, 0x00, 0x1F, 0x00, 0x00, 0x00],
        "Sampling new position",
    ),
    step(
        0x603,
        &[0x2B, 0x40, 0x60, 0x00, 0x0F, 0x00, 0x00, 0x00],
        "Clear the flag",
    ),
];

/// "Multi-point motion, need to stay between two points": the first point,
/// then the second (given while the first runs).
const MULTI_POINT_STAY: [&[Step]; 2] = [
    &[
        step(
            0x603,
            &[0x23, 0x81, 0x60, 0x00, 0x32, 0x00, 0x00, 0x00],
            "Set the speed of running 5 rps",
        ),
        step(
            0x603,
            &[0x23, 0x7A, 0x60, 0x00, 0x40, 0x0D, 0x03, 0x00],
            "Set target position 200000 steps",
        ),
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x5F, 0x00, 0x00, 0x00],
            "Sampling new position",
        ),
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x4F, 0x00, 0x00, 0x00],
            "Clear the flag",
        ),
    ],
    &[
        step(
            0x603,
            &[0x23, 0x81, 0x60, 0x00, 0x64, 0x00, 0x00, 0x00],
            "The speed of setting second segments is 10 rps",
        ),
        step(
            0x603,
            &[0x23, 0x7A, 0x60, 0x00, 0xC0, 0x27, 0x09, 0x00],
            "Set target position 600000 steps",
        ),
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x5F, 0x00, 0x00, 0x00],
            "Sampling new position",
        ),
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x4F, 0x00, 0x00, 0x00],
            "Clear the flag",
        ),
    ],
];

/// "Multi-point motion, no need to stay between two points".
const MULTI_POINT_NO_STAY: [&[Step]; 2] = [
    &[
        step(
            0x603,
            &[0x23, 0x81, 0x60, 0x00, 0x32, 0x00, 0x00, 0x00],
            "Set the speed of running 5 rps",
        ),
        step(
            0x603,
            &[0x23, 0x7A, 0x60, 0x00, 0x40, 0x0D, 0x03, 0x00],
            "Set target position 200000 steps",
        ),
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x5F, 0x02, 0x00, 0x00],
            "Sampling new position",
        ),
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x4F, 0x02, 0x00, 0x00],
            "Clear the flag",
        ),
    ],
    &[
        step(
            0x603,
            &[0x23, 0x81, 0x60, 0x00, 0x64, 0x00, 0x00, 0x00],
            "Set the speed of running 10 rps",
        ),
        step(
            0x603,
            &[0x23, 0x7A, 0x60, 0x00, 0xC0, 0x27, 0x09, 0x00],
            "Set target position 600000 steps",
        ),
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x5F, 0x02, 0x00, 0x00],
            "Sampling new position",
        ),
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x4F, 0x02, 0x00, 0x00],
            "Clear the flag",
        ),
    ],
];

/// "Multi-point motion, which directly changes the speed of operation".
const MULTI_POINT_AT_ONCE: [&[Step]; 2] = [
    &[
        step(
            0x603,
            &[0x23, 0x81, 0x60, 0x00, 0x32, 0x00, 0x00, 0x00],
            "Set the speed of running 5 rps",
        ),
        step(
            0x603,
            &[0x23, 0x7A, 0x60, 0x00, 0x40, 0x0D, 0x03, 0x00],
            "Set target position 200000 steps",
        ),
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x7F, 0x02, 0x00, 0x00],
            "Sampling new position",
        ),
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x6F, 0x02, 0x00, 0x00],
            "Clear the flag",
        ),
    ],
    &[
        step(
            0x603,
            &[0x23, 0x81, 0x60, 0x00, 0x64, 0x00, 0x00, 0x00],
            "The speed of setting second segments is 10 rps",
        ),
        step(
            0x603,
            &[0x23, 0x7A, 0x60, 0x00, 0xC0, 0x27, 0x09, 0x00],
            "Set target position 600000 steps",
        ),
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x7F, 0x02, 0x00, 0x00],
            "Sampling new position",
        ),
        step(
            0x603,
            &[0x2B, 0x40, 0x60, 0x00, 0x6F, 0x02, 0x00, 0x00],
            "Clear the flag",
        ),
    ],
];

/// "4. Velocity mode", after the start and the state walk (whose last
/// step, "Operation Enabled; Motion Halted", is 0x010F).
const VELOCITY_MODE: &[Step] = &[
    step(
        0x603,
        &[0x2F, 0x60, 0x60, 0x00, 0x03, 0x00, 0x00, 0x00],
        "Set the velocity mode",
    ),
    step(
        0x603,
        &[0x23, 0x81, 0x60, 0x00, 0x0A, 0x00, 0x00, 0x00],
        "Set the speed of running 1 rps",
    ),
    step(
        0x603,
        &[0x2B, 0x83, 0x60, 0x00, 0xE8, 0x03, 0x00, 0x00],
        "Set acceleration100 rps/s",
    ),
    step(
        0x603,
        &[0x2B, 0x84, 0x60, 0x00, 0xE8, 0x03, 0x00, 0x00],
        "Set deceleration 100 rps/s",
    ),
];
const VELOCITY_HALTED: Step = step(
    0x603,
    &[0x2B, 0x40, 0x60, 0x00, 0x0F, 0x01, 0x00, 0x00],
    "Operation Enabled; Motion Halted",
);
const VELOCITY_START: Step = step(
    0x603,
    &[0x2B, 0x40, 0x60, 0x00, 0x0F, 0x00, 0x00, 0x00],
    "Start operation",
);
const VELOCITY_CHANGE: Step = step(
    0x603,
    &[0x23, 0x81, 0x60, 0x00, 0x64, 0x00, 0x00, 0x00],
    "Change the speed of running 10 rps",
);
/// The manual's comment says "Start operation", but 0x010F is the halt:
/// "Write 0x010F to the control word to stop the motor."
const VELOCITY_STOP: Step = step(
    0x603,
    &[0x2B, 0x40, 0x60, 0x00, 0x0F, 0x01, 0x00, 0x00],
    "Start operation",
);

/// "5. Homing mode", after the start and the state walk.
const HOMING_MODE: &[Step] = &[
    step(
        0x603,
        &[0x2F, 0x60, 0x60, 0x00, 0x06, 0x00, 0x00, 0x00],
        "Set homing mode",
    ),
    step(
        0x603,
        &[0x2F, 0x98, 0x60, 0x00, 0x01, 0x00, 0x00, 0x00],
        "Select homing method 1",
    ),
    step(
        0x603,
        &[0x2B, 0x9A, 0x60, 0x00, 0xE8, 0x03, 0x00, 0x00],
        "Set homing acceleration 100rps/s",
    ),
    step(
        0x603,
        &[0x23, 0x99, 0x60, 0x01, 0x0A, 0x00, 0x00, 0x00],
        "Set homing speed 1rps",
    ),
    step(
        0x603,
        &[0x23, 0x99, 0x60, 0x02, 0x05, 0x00, 0x00, 0x00],
        "Set speed of finding homing origin 0.5rps",
    ),
];
const HOMING_START: Step = step(
    0x603,
    &[0x2B, 0x40, 0x60, 0x00, 0x1F, 0x00, 0x00, 0x00],
    "Start homing",
);
const HOMING_STOP: Step = step(
    0x603,
    &[0x2B, 0x40, 0x60, 0x00, 0x1F, 0x01, 0x00, 0x00],
    "stop homing",
);

fn node() -> NodeId {
    NodeId::new(3).unwrap()
}

/// A master and a JMC drive at node 3 that has booted.
struct Bench {
    master: Bus,
    frames: FrameReceiver,
    rack: Rack,
}

impl Bench {
    async fn new() -> Bench {
        let hub = VirtualHub::new("test");
        let master = hub.attach();
        let mut frames = master.subscribe();
        let rack = Rack::new(hub.clone());
        rack.add(Product::Jmc, node()).unwrap();
        let boot = frames.recv().await.unwrap().frame;
        assert_eq!(
            (boot.id(), boot.data()),
            (CanId::Standard(0x703), &[0u8][..])
        );
        Bench {
            master,
            frames,
            rack,
        }
    }

    /// Sends `step` and returns the SDO reply (0x583) within 100 ms, if any.
    async fn send(&mut self, step: &Step) -> Option<Vec<u8>> {
        let frame = Frame::new(CanId::Standard(step.id), step.data).unwrap();
        self.master.send(frame).await.unwrap();
        let until = tokio::time::Instant::now() + Duration::from_millis(100);
        loop {
            match tokio::time::timeout_at(until, self.frames.recv()).await {
                Ok(Ok(reply)) if reply.frame.id() == CanId::Standard(0x583) => {
                    return Some(reply.frame.data().to_vec());
                }
                Ok(Ok(_)) => {}
                Ok(Err(error)) => panic!("{error}"),
                Err(_) => return None,
            }
        }
    }

    /// Sends an SDO download of the routine and checks its confirmation:
    /// 0x60 and the index and sub-index it wrote.
    async fn confirmed(&mut self, step: &Step) {
        let reply = self.send(step).await;
        let mut expected = vec![0x60, step.data[1], step.data[2], step.data[3], 0, 0, 0, 0];
        if step.id != 0x603 {
            expected.clear();
        }
        assert_eq!(
            reply.unwrap_or_default(),
            expected,
            "'{}' ({:03X} {:02X?})",
            step.comment,
            step.id,
            step.data
        );
    }

    async fn all_confirmed(&mut self, steps: &[Step]) {
        for step in steps {
            self.confirmed(step).await;
        }
    }

    /// NMT start (no reply) and the state walk, each step's statusword
    /// read back over SDO; `last` replaces the walk's last controlword.
    async fn start_and_power(&mut self, last: Option<(&Step, u16)>) {
        assert_eq!(self.send(&START).await, None, "{}", START.comment);
        for (index, (step, statusword)) in POWER_THE_MOTOR.iter().enumerate() {
            let (step, statusword) = match last {
                Some(last) if index == POWER_THE_MOTOR.len() - 1 => last,
                _ => (step, *statusword),
            };
            self.confirmed(step).await;
            assert_eq!(
                self.statusword().await,
                statusword,
                "after '{}'",
                step.comment
            );
        }
    }

    /// 0x6041 read over SDO, as a master reads it.
    async fn statusword(&mut self) -> u16 {
        let upload = Step {
            id: 0x603,
            data: &[0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0],
            comment: "read the statusword",
        };
        let reply = self.send(&upload).await.expect("no reply to the upload");
        assert_eq!(reply[..4], [0x4B, 0x41, 0x60, 0x00], "{reply:02X?}");
        u16::from_le_bytes([reply[4], reply[5]])
    }

    fn peek(&self, index: u16) -> i64 {
        self.peek_sub(index, 0)
    }

    fn peek_sub(&self, index: u16, sub: u8) -> i64 {
        self.rack
            .with_device(node(), |core| core.store().get(index, sub).cloned())
            .unwrap()
            .and_then(|value: Value| value.as_i128())
            .unwrap() as i64
    }

    fn position(&self) -> i64 {
        self.peek(0x6064)
    }

    fn velocity(&self) -> i64 {
        self.peek(0x606C)
    }

    fn machine_position(&self) -> f64 {
        self.rack
            .with_device(node(), |core| {
                core.behaviour_mut::<Jmc>().unwrap().machine_position()
            })
            .unwrap()
    }

    /// Lets the simulation run `ms` milliseconds.
    async fn run(&mut self, ms: u64) {
        tokio::time::sleep(Duration::from_millis(ms)).await;
    }

    /// Runs 10 ms at a time until `done`; the ms it took.
    async fn run_until(&mut self, limit_ms: u64, mut done: impl FnMut(&Bench) -> bool) -> u64 {
        let mut ms = 0;
        while !done(self) {
            assert!(ms < limit_ms, "not done after {limit_ms} ms");
            self.run(10).await;
            ms += 10;
        }
        ms
    }
}

#[tokio::test(start_paused = true)]
async fn boot_up_and_the_1000_ms_heartbeat() {
    let mut bench = Bench::new().await;
    let mut heartbeats = Vec::new();
    let until = tokio::time::Instant::now() + Duration::from_millis(3_500);
    while let Ok(Ok(frame)) = tokio::time::timeout_at(until, bench.frames.recv()).await {
        if frame.frame.id() == CanId::Standard(0x703) {
            heartbeats.push((tokio::time::Instant::now(), frame.frame.data().to_vec()));
        }
    }
    // Pre-operational (0x7F) once a second.
    assert_eq!(heartbeats.len(), 3, "{heartbeats:?}");
    assert!(heartbeats.iter().all(|(_, data)| data == &[0x7F]));
    for pair in heartbeats.windows(2) {
        assert_eq!(pair[1].0 - pair[0].0, Duration::from_millis(1_000));
    }
    assert_eq!(bench.send(&START).await, None);
    let until = tokio::time::Instant::now() + Duration::from_millis(1_100);
    let mut operational = Vec::new();
    while let Ok(Ok(frame)) = tokio::time::timeout_at(until, bench.frames.recv()).await {
        if frame.frame.id() == CanId::Standard(0x703) {
            operational.push(frame.frame.data().to_vec());
        }
    }
    assert_eq!(operational, [vec![0x05]]);
}

#[tokio::test(start_paused = true)]
async fn position_mode_single_and_multi_point() {
    let mut bench = Bench::new().await;
    bench.start_and_power(None).await;
    bench.all_confirmed(SET_POSITION_MODE).await;
    assert_eq!(bench.peek(0x6061), 1, "mode display: position");
    // At rest on its target.
    assert_eq!(bench.statusword().await, 0x0437);

    // Single point: 200 000 steps at 1 rps (10 000 steps/s): 20 s.
    bench.confirmed(&SINGLE_POINT[0]).await;
    bench.confirmed(&SINGLE_POINT[1]).await;
    // Bit 12, set point taken; bit 10 cleared.
    assert_eq!(bench.statusword().await & 0x1400, 0x1000);
    bench.confirmed(&SINGLE_POINT[2]).await;
    bench.run(1_000).await;
    assert_eq!(bench.velocity(), 10);
    // Running (bit 9), flag cleared, not there yet.
    assert_eq!(bench.statusword().await, 0x0237);
    let ms = bench.run_until(30_000, |b| b.position() == 200_000).await;
    assert!((18_900..=19_100).contains(&ms), "{ms} ms");
    bench.run(10).await;
    assert_eq!(bench.velocity(), 0);
    assert_eq!(bench.statusword().await, 0x0437, "target reached");

    // Multi-point, each relative (bit 6): 200 000 more at 5 rps, then
    // 600 000 more at 10 rps; the second given while the first runs.
    let mut start = bench.position();
    for (routine, stays) in [
        (MULTI_POINT_STAY, true),
        (MULTI_POINT_NO_STAY, false),
        (MULTI_POINT_AT_ONCE, false),
    ] {
        bench.all_confirmed(routine[0]).await;
        bench.run(500).await;
        assert_eq!(bench.velocity(), 50, "5 rps");
        bench.all_confirmed(routine[1]).await;
        let mut stopped_between = false;
        let mut passed_first_at = None;
        bench
            .run_until(20_000, |b| {
                let travelled = b.position() - start;
                if b.velocity() == 0 && travelled < 800_000 {
                    stopped_between = true;
                }
                if travelled >= 200_000 && passed_first_at.is_none() {
                    passed_first_at = Some(b.velocity());
                }
                travelled == 800_000
            })
            .await;
        assert_eq!(stopped_between, stays, "{}", routine[1][0].comment);
        let at_first = passed_first_at.unwrap();
        if routine[1][2].data[4] & 0x20 != 0 {
            // Bit 5: the second point's 10 rps from the moment it came.
            assert_eq!(at_first, 100);
        } else if !stays {
            // Bit 9: through the first point at its own 5 rps.
            assert!((50..=60).contains(&at_first), "{at_first}");
        }
        bench.run(200).await;
        assert_eq!(bench.velocity(), 0);
        assert_eq!(bench.statusword().await, 0x0437);
        start = bench.position();
    }
    assert_eq!(bench.position(), 200_000 + 3 * 800_000);
}

#[tokio::test(start_paused = true)]
async fn velocity_mode() {
    let mut bench = Bench::new().await;
    // The walk ends halted: bit 8.
    bench
        .start_and_power(Some((&VELOCITY_HALTED, 0x0137)))
        .await;
    bench.all_confirmed(VELOCITY_MODE).await;
    bench.run(100).await;
    assert_eq!(bench.velocity(), 0);
    // Halted, speed 0 (bits 8, 10), speed 0 (bit 12).
    assert_eq!(bench.statusword().await, 0x1537);

    bench.confirmed(&VELOCITY_START).await;
    bench.run(50).await;
    assert_eq!(bench.velocity(), 10, "1 rps");
    // Running at the target speed: bits 9 and 10.
    assert_eq!(bench.statusword().await, 0x0637);
    let position = bench.position();
    bench.run(1_000).await;
    // 10 000 steps/s (the 1 ms ticks and the 10 ms reads may be a tick apart).
    let travelled = bench.position() - position;
    assert!(
        (9_990..=10_010).contains(&travelled),
        "{travelled} steps in 1 s"
    );

    bench.confirmed(&VELOCITY_CHANGE).await;
    // 1 → 10 rps at 100 rps/s: 90 ms.
    bench.run(50).await;
    assert!(
        (50..=60).contains(&bench.velocity()),
        "{}",
        bench.velocity()
    );
    bench.run(50).await;
    assert_eq!(bench.velocity(), 100, "10 rps");

    bench.confirmed(&VELOCITY_STOP).await;
    bench.run(150).await;
    assert_eq!(bench.velocity(), 0);
    assert_eq!(bench.statusword().await, 0x1537, "halted, stopped");
}

#[tokio::test(start_paused = true)]
async fn homing_mode_method_1() {
    let mut bench = Bench::new().await;
    let switches = bench
        .rack
        .with_device(node(), |core| {
            core.behaviour_mut::<Jmc>().unwrap().switches()
        })
        .unwrap();
    assert_eq!(switches, LimitSwitches::default());
    let cw_limit = switches.cw_limit.unwrap() as f64;
    bench.start_and_power(None).await;
    bench.all_confirmed(HOMING_MODE).await;
    assert_eq!(bench.peek(0x6061), 6, "mode display: homing");

    bench.confirmed(&HOMING_START).await;
    bench.run(500).await;
    // Left (towards the CW switch) at 1 rps, homing under way.
    assert_eq!(bench.velocity(), -10);
    assert_eq!(bench.statusword().await & 0x3600, 0x0200);
    // The CW switch is 100 000 steps left: 10 s at 1 rps.
    let ms = bench
        .run_until(20_000, |b| b.peek(0x6041) & 0x1000 != 0)
        .await;
    assert!((9_400..=9_600).contains(&ms), "{ms} ms");
    assert_eq!(bench.machine_position(), cw_limit);
    assert_eq!((bench.position(), bench.velocity()), (0, 0));
    // Homing done (12), home reached (10), on the CW switch (14).
    assert_eq!(bench.statusword().await, 0x5437);

    // "stop homing": halted.
    bench.confirmed(&HOMING_STOP).await;
    assert_eq!(bench.statusword().await, 0x5537);
}

#[tokio::test(start_paused = true)]
async fn homing_mode_stopped_on_the_way() {
    let mut bench = Bench::new().await;
    bench.start_and_power(None).await;
    bench.all_confirmed(HOMING_MODE).await;
    bench.confirmed(&HOMING_START).await;
    bench.run(2_000).await;
    bench.confirmed(&HOMING_STOP).await;
    bench.run(100).await;
    assert_eq!(bench.velocity(), 0);
    // Halted, speed 0; homing not done, no error.
    assert_eq!(bench.statusword().await & 0x3700, 0x0500);
    assert!(bench.machine_position() > -100_000.0);
}

/// "4. Velocity mode" verbatim, ending on 0x010F (halt), then "5. Homing
/// mode" verbatim: its walk (Shutdown 0x06, Switched on 0x07, Operation
/// Enabled 0x0F) leaves operation enabled, which drops the halt (the
/// manual's controlword table: bit 8 "1—>0: normal operation"; CiA 402: the
/// halt is a function of operation enabled), so the statusword's bit 8
/// ("1: Motor halt") is clear after the walk and "Start homing" starts.
#[tokio::test(start_paused = true)]
async fn homing_after_the_velocity_routine_is_not_halted() {
    let mut bench = Bench::new().await;
    bench
        .start_and_power(Some((&VELOCITY_HALTED, 0x0137)))
        .await;
    bench.all_confirmed(VELOCITY_MODE).await;
    bench.confirmed(&VELOCITY_START).await;
    bench.run(200).await;
    bench.confirmed(&VELOCITY_CHANGE).await;
    bench.run(200).await;
    bench.confirmed(&VELOCITY_STOP).await;
    bench.run(200).await;
    assert_eq!(bench.statusword().await, 0x1537, "halted, stopped");

    // Routine 5 from its first line: NMT start again, then the walk (the
    // velocity mode's bits 10 and 12 stay until "Set homing mode").
    assert_eq!(bench.send(&START).await, None, "{}", START.comment);
    for (step, _) in POWER_THE_MOTOR {
        bench.confirmed(step).await;
        let statusword = bench.statusword().await;
        assert_eq!(statusword & 0x0100, 0, "bit 8 after '{}'", step.comment);
    }
    bench.all_confirmed(HOMING_MODE).await;
    bench.confirmed(&HOMING_START).await;
    bench.run(500).await;
    assert_eq!(bench.velocity(), -10, "homing at 1 rps");
    assert_eq!(
        bench.statusword().await & 0x3700,
        0x0200,
        "running, not halted"
    );
}

/// The PDO routines re-map PDOs that are in use without setting bit 31 of
/// their COB-IDs first, which CiA 301 refuses; the drive takes them (the
/// manual's 0x1600 section: "If you need to remap the sub-index first set to
/// 0"), and so does the virtual one: every frame is confirmed.
#[tokio::test(start_paused = true)]
async fn pdo_configuration_routines() {
    let mut bench = Bench::new().await;
    bench.all_confirmed(RPDO_CONFIGURATION).await;
    bench.all_confirmed(TPDO_CONFIGURATION).await;
    assert_eq!(bench.peek_sub(0x1402, 1), 0x203);
    assert_eq!(bench.peek_sub(0x1801, 1), 0x183);
    assert_eq!(bench.peek_sub(0x1602, 0), 2);
    assert_eq!(bench.peek_sub(0x1602, 1), 0x6040_0010);
    assert_eq!(bench.peek_sub(0x1602, 2), 0x607A_0020);
    assert_eq!(bench.peek_sub(0x1A01, 1), 0x6041_0010);
    assert_eq!(bench.peek_sub(0x1A01, 2), 0x6064_0020);
    // In operational the re-mapped RPDO takes the controlword and target
    // at the next SYNC, and the re-mapped TPDO goes out on every SYNC
    // beside TPDO1 (both on 0x183 now, as the routine leaves them).
    assert_eq!(bench.send(&START).await, None);
    let rpdo = Frame::new(CanId::Standard(0x203), &[0x06, 0x00, 0x10, 0x27, 0, 0]).unwrap();
    bench.master.send(rpdo).await.unwrap();
    bench.run(5).await;
    assert_eq!(bench.peek(0x607A), 0, "an RPDO of type 1 waits for SYNC");
    let sync = Frame::new(CanId::Standard(0x080), &[]).unwrap();
    bench.master.send(sync).await.unwrap();
    bench.run(5).await;
    assert_eq!(bench.peek(0x607A), 10_000);
    assert_eq!(bench.peek(0x6040), 0x0006);
    // What the first SYNC sent was sampled before the RPDO was applied.
    while let Ok(Some(_)) = bench.frames.try_recv() {}
    bench.master.send(sync).await.unwrap();
    let mut tpdos = Vec::new();
    let until = tokio::time::Instant::now() + Duration::from_millis(10);
    while let Ok(Ok(received)) = tokio::time::timeout_at(until, bench.frames.recv()).await {
        if received.frame.id() == CanId::Standard(0x183) {
            tpdos.push(received.frame.data().to_vec());
        }
    }
    // Statusword "ready to switch on" (0x0031) and position 0, twice.
    assert_eq!(tpdos, vec![vec![0x31, 0x00, 0, 0, 0, 0]; 2]);
    // The transmission types were taken (1, every SYNC: the default).
    assert_eq!(bench.peek_sub(0x1402, 2), 1);
    assert_eq!(bench.peek_sub(0x1801, 2), 1);
}
