//! The virtual JMC drive against its manual, driven through its store as
//! the device core drives it: writes checked and stored, then `written`;
//! one `tick` per millisecond.

use super::*;
use crate::behaviour::RaisedEmcy;
use crate::canopen::NodeId;
use crate::canopen::eds::Eds;
use crate::canopen::nmt::NmtState;
use crate::canopen::od::Value;
use crate::canopen::sdo::ObjectAccess;
use crate::profiles::builtin::JMC_STEPPER;
use crate::profiles::jmc::{SW_CCW_LIMIT, SW_CW_LIMIT, SW_ORIGIN_SWITCH};

/// A drive at node 3 with its dictionary, and a clock.
struct Bench {
    store: ObjectStore,
    jmc: Jmc,
    ms: u64,
    raised: Vec<RaisedEmcy>,
}

impl Bench {
    fn new() -> Self {
        Self::with(Jmc::new())
    }

    fn with(jmc: Jmc) -> Self {
        let dictionary = Eds::parse(JMC_STEPPER, "jmc_stepper.eds")
            .unwrap()
            .dictionary;
        let store = ObjectStore::new(dictionary, NodeId::new(3).unwrap()).unwrap();
        let mut bench = Bench {
            store,
            jmc,
            ms: 0,
            raised: Vec::new(),
        };
        bench.call(|jmc, io| jmc.reset(io));
        bench
    }

    fn call<R>(&mut self, f: impl FnOnce(&mut Jmc, &mut DeviceIo<'_>) -> R) -> R {
        let mut io = DeviceIo::new(
            &mut self.store,
            NmtState::Operational,
            self.ms,
            &mut self.raised,
        );
        f(&mut self.jmc, &mut io)
    }

    /// An SDO download of `data`, checked as the device core checks it.
    fn download(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        self.jmc
            .check_write(&self.store, index, sub, Some(data.len()))?;
        self.store.check_write(index, sub, Some(data.len()))?;
        self.jmc.check_value(&self.store, index, sub, data)?;
        self.store.write(index, sub, data)?;
        self.call(|jmc, io| jmc.written(io, index, sub));
        Ok(())
    }

    /// A download at the object's own size.
    fn set(&mut self, index: u16, sub: u8, value: i64) {
        let data_type = self.store.dictionary().sub(index, sub).unwrap().data_type;
        let value = Value::from_i128(data_type, i128::from(value)).unwrap();
        self.download(index, sub, &value.to_bytes())
            .unwrap_or_else(|abort| panic!("0x{index:04X}sub{sub}: {abort}"));
    }

    fn controlword(&mut self, word: u16) {
        self.set(0x6040, 0, i64::from(word));
    }

    fn get(&self, index: u16, sub: u8) -> i64 {
        self.store.get(index, sub).unwrap().as_i128().unwrap() as i64
    }

    fn statusword(&self) -> u16 {
        self.get(0x6041, 0) as u16
    }

    fn position(&self) -> i64 {
        self.get(0x6064, 0)
    }

    fn velocity(&self) -> i64 {
        self.get(0x606C, 0)
    }

    fn tick(&mut self) {
        self.ms += 1;
        self.call(|jmc, io| jmc.tick(io));
    }

    fn run(&mut self, ms: u64) {
        for _ in 0..ms {
            self.tick();
        }
    }

    /// Ticks until `done`, at most `limit` ms; the ms it took.
    fn run_until(&mut self, limit: u64, mut done: impl FnMut(&Bench) -> bool) -> u64 {
        for ms in 1..=limit {
            self.tick();
            if done(self) {
                return ms;
            }
        }
        panic!(
            "not done after {limit} ms: statusword 0x{:04X}, position {}, velocity {}",
            self.statusword(),
            self.position(),
            self.velocity()
        );
    }

    fn run_until_standing(&mut self, limit: u64) -> u64 {
        self.run_until(limit, |bench| {
            bench.jmc.axis.velocity == 0.0 && !bench.jmc.busy()
        })
    }

    /// The manual's "Power the motor": shutdown, switch on, enable.
    fn enable(&mut self, last: u16) {
        self.controlword(0x06);
        self.controlword(0x07);
        self.controlword(last);
    }

    /// Position mode with the routine's parameters: `speed` 0.1 rps,
    /// 100 rps/s ramps.
    fn position_mode(&mut self, speed: i64) {
        self.enable(0x0F);
        self.set(0x6060, 0, 1);
        self.set(0x6081, 0, speed);
        self.set(0x6083, 0, 1000);
        self.set(0x6084, 0, 1000);
    }
}

const SW_STATE: u16 = 0x006F;

#[test]
fn boots_in_switch_on_disabled_with_the_manuals_defaults() {
    let bench = Bench::new();
    // Switch on disabled (bit 6), power stage present (bit 4), no switch on.
    assert_eq!(bench.statusword(), 0x0050);
    assert_eq!(bench.get(0x6061, 0), 0);
    assert_eq!((bench.position(), bench.velocity()), (0, 0));
    // Heartbeat 1000 ms and the default PDOs of the manual.
    assert_eq!(bench.get(0x1017, 0), 1000);
    let mapping = |index: u16| -> Vec<i64> {
        (1..=bench.get(index, 0) as u8)
            .map(|sub| bench.get(index, sub))
            .collect()
    };
    assert_eq!(mapping(0x1600), [0x6081_0020, 0x6083_0010, 0x6084_0010]);
    assert_eq!(mapping(0x1601), [0x607C_0020, 0x6099_0220]);
    assert_eq!(mapping(0x1602), [0x6099_0120, 0x609A_0010, 0x609A_0010]);
    assert_eq!(
        mapping(0x1603),
        [0x6060_0008, 0x6098_0008, 0x607A_0020, 0x6040_0010]
    );
    assert_eq!(mapping(0x1A00), [0x6041_0010, 0x6064_0020]);
    assert_eq!(mapping(0x1A01), [0x606C_0020]);
    for n in 0..4u16 {
        assert_eq!(bench.get(0x1400 + n, 1), 0x203 + 0x100 * i64::from(n));
        assert_eq!(bench.get(0x1400 + n, 2), 254);
        assert_eq!(bench.get(0x1800 + n, 1), 0x183 + 0x100 * i64::from(n));
        assert_eq!(bench.get(0x1800 + n, 2), 1);
    }
}

#[test]
fn the_routines_state_walk_and_the_jmc_bits_of_the_statusword() {
    let mut bench = Bench::new();
    bench.controlword(0x06);
    assert_eq!(bench.statusword(), 0x0031, "ready to switch on");
    bench.controlword(0x07);
    assert_eq!(bench.statusword(), 0x0033, "switched on");
    bench.controlword(0x0F);
    assert_eq!(bench.statusword(), 0x0037, "operation enabled");
    // Bit 9 is "motor running", never CiA 402's "remote".
    bench.run(10);
    assert_eq!(bench.statusword() & SW_RUNNING, 0);
    bench.controlword(0x010F);
    assert_eq!(bench.statusword(), 0x0137, "bit 8: halted");
    // Quick stop (bit 2 low): stopped at once, then switch on disabled.
    bench.controlword(0x000B);
    bench.run(1);
    assert_eq!(bench.statusword() & SW_STATE, 0x0040);
    bench.enable(0x0F);
    assert_eq!(bench.statusword() & SW_STATE, 0x0027);
}

#[test]
fn a_four_byte_value_for_a_two_byte_object_gets_the_drives_abort() {
    let mut bench = Bench::new();
    for index in [0x6083, 0x6084, 0x6085, 0x609A, 0x605A, 0x605D, 0x1017] {
        assert_eq!(
            bench.download(index, 0, &[0xE8, 0x03, 0, 0]),
            Err(AbortCode::InvalidValue),
            "0x{index:04X}"
        );
        assert_eq!(bench.download(index, 0, &[0xE8, 0x03]), Ok(()));
    }
    assert_eq!(bench.get(0x6083, 0), 1000);
    // Other lengths keep CiA 301's answers.
    assert_eq!(
        bench.download(0x6081, 0, &[0x0A, 0]),
        Err(AbortCode::LengthTooLow)
    );
    assert_eq!(
        bench.download(0x6060, 0, &[1, 0]),
        Err(AbortCode::LengthTooHigh)
    );
    assert_eq!(
        bench.download(0x6041, 0, &[0, 0, 0, 0]),
        Err(AbortCode::ReadOnlyObject)
    );
    assert_eq!(bench.download(0x6081, 0, &[0x0A, 0, 0, 0]), Ok(()));
}

#[test]
fn modes_1_3_6_are_taken_and_shown_in_0x6061() {
    let mut bench = Bench::new();
    for mode in [1i8, 3, 6, 0] {
        assert_eq!(bench.download(0x6060, 0, &[mode as u8]), Ok(()));
        assert_eq!(bench.get(0x6061, 0), i64::from(mode));
    }
    for refused in [2i8, 4, 7, -1] {
        assert_eq!(
            bench.download(0x6060, 0, &[refused as u8]),
            Err(AbortCode::InvalidValue),
            "mode {refused}"
        );
    }
}

#[test]
fn position_mode_single_point_as_the_routine() {
    let mut bench = Bench::new();
    bench.position_mode(10);
    assert_eq!(bench.statusword(), 0x0437, "at rest on its target");
    bench.set(0x607A, 0, 200_000);
    bench.controlword(0x1F);
    assert_eq!(
        bench.statusword() & (SW_MODE_12 | SW_TARGET_REACHED),
        SW_MODE_12
    );
    bench.controlword(0x0F);
    assert_eq!(bench.statusword() & SW_MODE_12, 0, "flag cleared");
    bench.run(100);
    assert_eq!(bench.velocity(), 10, "1 rps in 0.1 rps");
    assert_eq!(bench.statusword(), 0x0237, "running, target not reached");
    // 10 000 steps/s: 200 000 steps in 20 s and a ramp.
    let ms = 100 + bench.run_until(30_000, |b| b.statusword() & SW_TARGET_REACHED != 0);
    assert!((20_005..=20_020).contains(&ms), "{ms} ms");
    assert_eq!((bench.position(), bench.velocity()), (200_000, 0));
    assert_eq!(bench.statusword(), 0x0437);
    // Absolute again: back to 1000.
    bench.set(0x607A, 0, 1_000);
    bench.controlword(0x1F);
    bench.controlword(0x0F);
    bench.run_until_standing(30_000);
    assert_eq!(bench.position(), 1_000);
}

#[test]
fn bit_12_refuses_a_new_point_until_bit_4_went_low() {
    let mut bench = Bench::new();
    bench.position_mode(100);
    bench.set(0x607A, 0, 5_000);
    bench.controlword(0x1F);
    // Bit 4 stays high: a second set point is not sampled.
    bench.set(0x607A, 0, 9_000);
    bench.controlword(0x1F);
    bench.run_until_standing(5_000);
    assert_eq!(bench.position(), 5_000);
    assert_ne!(bench.statusword() & SW_MODE_12, 0);
    bench.controlword(0x0F);
    assert_eq!(bench.statusword() & SW_MODE_12, 0);
}

#[test]
fn relative_set_points_add_to_the_previous_target() {
    let mut bench = Bench::new();
    bench.position_mode(100);
    for expected in [3_000, 6_000, 9_000] {
        bench.set(0x607A, 0, 3_000);
        bench.controlword(0x5F);
        bench.controlword(0x4F);
        bench.run_until_standing(5_000);
        assert_eq!(bench.position(), expected);
    }
    bench.set(0x607A, 0, -10_000);
    bench.controlword(0x5F);
    bench.controlword(0x4F);
    bench.run_until_standing(5_000);
    assert_eq!(bench.position(), -1_000);
}

/// The manual's multi-point routines: 200 000 steps at 5 rps, then 600 000
/// more at 10 rps, relative; `flags` adds bits 5 and 9 to 0x4F / 0x5F. The
/// second point is given 1 s into the first. Returns the shaft's speeds
/// (steps/s) from then on, tick by tick.
fn multi_point(flags: u16) -> (Bench, Vec<f64>) {
    let mut bench = Bench::new();
    bench.position_mode(50);
    bench.set(0x607A, 0, 200_000);
    bench.controlword(0x5F | flags);
    bench.controlword(0x4F | flags);
    bench.run(1_000);
    bench.set(0x6081, 0, 100);
    bench.set(0x607A, 0, 600_000);
    bench.controlword(0x5F | flags);
    bench.controlword(0x4F | flags);
    let mut speeds = Vec::new();
    bench.run_until(60_000, |b| {
        speeds.push(b.jmc.machine_velocity());
        b.statusword() & SW_TARGET_REACHED != 0
    });
    assert_eq!(bench.position(), 800_000, "the sum of the two points");
    (bench, speeds)
}

#[test]
fn multi_point_stopping_between_the_points() {
    let (bench, speeds) = multi_point(0);
    // Stopped at 200 000 (4 s at 5 rps, 3 s after the second point came),
    // braking over its last 50 ms; then on at 10 rps.
    let stop = speeds.iter().position(|&v| v == 0.0).unwrap();
    assert!((3_040..=3_060).contains(&stop), "{stop}");
    assert!(speeds[..stop - 50].iter().all(|&v| v == 50_000.0));
    assert!(speeds[stop..].contains(&100_000.0));
    assert_eq!(bench.statusword() & SW_MODE_12, 0);
}

#[test]
fn multi_point_without_stopping() {
    let (_, speeds) = multi_point(CW_NO_STOP);
    // Never below 5 rps before the final braking; 5 rps up to the first
    // point, then up to 10 rps.
    let end = speeds.len() - 130;
    assert!(speeds[..end].iter().all(|&v| v >= 50_000.0));
    let faster = speeds.iter().position(|&v| v > 50_000.0).unwrap();
    assert!((3_015..=3_035).contains(&faster), "{faster}");
    assert!(speeds[faster + 50..end].iter().all(|&v| v == 100_000.0));
}

#[test]
fn multi_point_changing_at_once() {
    let (_, speeds) = multi_point(CW_NO_STOP | CW_AT_ONCE);
    // The second point's speed is taken at once (a 50 ms ramp), long
    // before the first point would have been reached.
    let odd = speeds[50..speeds.len() - 130]
        .iter()
        .position(|&v| v != 100_000.0);
    assert_eq!(odd, None, "{:?}", odd.map(|i| &speeds[i + 40..i + 60]));
    // 750 000 steps left at 10 rps.
    assert!((7_560..=7_600).contains(&speeds.len()), "{}", speeds.len());
}

const CW_NO_STOP: u16 = 1 << 9;
const CW_AT_ONCE: u16 = 1 << 5;

#[test]
fn a_set_point_waits_while_bit_12_is_set_by_the_waiting_one() {
    let mut bench = Bench::new();
    bench.position_mode(50);
    bench.set(0x607A, 0, 20_000);
    bench.controlword(0x5F);
    bench.controlword(0x4F);
    bench.set(0x607A, 0, 20_000);
    bench.controlword(0x5F);
    bench.controlword(0x4F);
    // The second waits: bit 12 stays set until it runs.
    assert_ne!(bench.statusword() & SW_MODE_12, 0);
    bench.set(0x607A, 0, 50_000);
    bench.controlword(0x5F);
    bench.controlword(0x4F);
    bench.run_until_standing(10_000);
    assert_eq!(bench.position(), 40_000, "the third was refused");
    assert_eq!(bench.statusword() & SW_MODE_12, 0);
}

#[test]
fn halt_bit_8_stops_on_the_deceleration_and_resumes() {
    let mut bench = Bench::new();
    bench.position_mode(100);
    bench.set(0x607A, 0, 100_000);
    bench.controlword(0x1F);
    bench.controlword(0x0F);
    bench.run(500);
    assert_eq!(bench.velocity(), 100);
    bench.controlword(0x010F);
    // 10 rps at 100 rps/s: 100 ms.
    let ms = bench.run_until(1_000, |b| b.velocity() == 0);
    assert!((99..=101).contains(&ms), "{ms}");
    bench.run(1);
    let halted = bench.position();
    assert!(halted < 100_000);
    // Bits 8 and 10 (halted, speed 0), not running.
    assert_eq!(bench.statusword(), 0x0537);
    bench.run(200);
    assert_eq!(bench.position(), halted);
    bench.controlword(0x0F);
    bench.run_until(5_000, |b| b.statusword() & SW_TARGET_REACHED != 0);
    assert_eq!(bench.position(), 100_000);
}

#[test]
fn halt_code_2_uses_the_quick_stop_deceleration() {
    let mut bench = Bench::new();
    bench.set(0x605D, 0, 2);
    bench.set(0x6085, 0, 10_000);
    bench.position_mode(100);
    bench.set(0x607A, 0, 100_000);
    bench.controlword(0x1F);
    bench.run(300);
    bench.controlword(0x011F);
    let ms = bench.run_until(1_000, |b| b.velocity() == 0);
    assert!((9..=11).contains(&ms), "{ms}");
}

#[test]
fn velocity_mode_as_the_routine_in_tenths_of_rps() {
    let mut bench = Bench::new();
    bench.enable(0x010F);
    bench.set(0x6060, 0, 3);
    bench.set(0x6081, 0, 10);
    bench.set(0x6083, 0, 1000);
    bench.set(0x6084, 0, 1000);
    bench.run(50);
    assert_eq!(bench.velocity(), 0, "halted");
    assert_eq!(bench.statusword(), 0x1537, "halted, speed 0");
    bench.controlword(0x0F);
    // 1 rps at 100 rps/s: 10 ms.
    let ms = bench.run_until(100, |b| b.statusword() & SW_TARGET_REACHED != 0);
    assert_eq!(ms, 10);
    assert_eq!(bench.velocity(), 10);
    assert_eq!(bench.statusword(), 0x0637, "running at the target speed");
    // 10 000 steps per second.
    let start = bench.position();
    bench.run(1_000);
    assert_eq!(bench.position() - start, 10_000);
    bench.set(0x6081, 0, 100);
    assert_eq!(bench.statusword() & SW_TARGET_REACHED, 0);
    let ms = bench.run_until(200, |b| b.statusword() & SW_TARGET_REACHED != 0);
    assert_eq!(ms, 90);
    assert_eq!(bench.velocity(), 100);
    bench.controlword(0x010F);
    let ms = bench.run_until(200, |b| b.velocity() == 0);
    assert_eq!(ms, 100);
    bench.run(1);
    assert_eq!(bench.statusword(), 0x1537);
    // Negative: the other way.
    bench.set(0x6081, 0, -20);
    bench.controlword(0x0F);
    bench.run(100);
    assert_eq!(bench.velocity(), -20);
    let before = bench.position();
    bench.run(500);
    assert_eq!(bench.position() - before, -10_000);
}

#[test]
fn velocity_mode_bit_13_while_the_maximum_acceleration_limits_the_ramp() {
    let mut bench = Bench::new();
    bench.enable(0x0F);
    bench.set(0x6060, 0, 3);
    bench.set(0x6083, 0, 1000);
    bench.set(0x60C5, 0, 100);
    bench.set(0x6081, 0, 10);
    bench.run(1);
    assert_ne!(bench.statusword() & SW_MODE_13, 0);
    // 1 rps at 10 rps/s instead of 100: 100 ms.
    let ms = bench.run_until(200, |b| b.jmc.machine_velocity() == 10_000.0);
    assert_eq!(ms, 99);
    bench.run(1);
    assert_eq!(bench.statusword() & SW_MODE_13, 0);
}

#[test]
fn limit_switches_stop_a_run_into_them_and_show_in_bits_14_and_15() {
    let mut bench = Bench::new();
    bench.jmc.set_switches(LimitSwitches {
        cw_limit: Some(-5_000),
        ccw_limit: Some(5_000),
        origin: Some((-100, 100)),
    });
    bench.run(1);
    assert_eq!(bench.statusword() & SW_ORIGIN_SWITCH, SW_ORIGIN_SWITCH);
    bench.enable(0x0F);
    bench.set(0x6060, 0, 3);
    bench.set(0x6081, 0, -10);
    bench.run_until(2_000, |b| b.statusword() & SW_CW_LIMIT != 0);
    bench.run(10);
    assert_eq!((bench.position(), bench.velocity()), (-5_000, 0));
    assert_eq!(bench.statusword() & SW_ORIGIN_SWITCH, 0);
    // Away from it is free.
    bench.set(0x6081, 0, 10);
    bench.run_until(2_000, |b| b.statusword() & SW_CCW_LIMIT != 0);
    bench.run(10);
    assert_eq!(bench.position(), 5_000);
    // A set point beyond the switch is abandoned at the switch.
    bench.set(0x6060, 0, 1);
    bench.set(0x607A, 0, -20_000);
    bench.controlword(0x1F);
    bench.controlword(0x0F);
    bench.run_until_standing(10_000);
    assert_eq!(bench.position(), -5_000);
    assert_eq!(bench.statusword() & SW_TARGET_REACHED, 0);
}

/// The switches of the homing tests, in machine steps: the shaft starts at
/// 0 between the origin cam (left) and the CCW switch.
const HOMING_SWITCHES: LimitSwitches = LimitSwitches {
    cw_limit: Some(-30_000),
    ccw_limit: Some(30_000),
    origin: Some((-10_000, -8_000)),
};

/// Homes with `method` (10 rps search, 0.5 rps slow, 100 rps/s) and home
/// offset `offset`; returns the machine position where the counter's 0
/// ended.
fn home(method: i64, offset: i64, switches: LimitSwitches) -> Bench {
    let mut bench = Bench::new();
    bench.jmc.set_switches(switches);
    bench.enable(0x0F);
    bench.set(0x6060, 0, 6);
    bench.set(0x6098, 0, method);
    bench.set(0x609A, 0, 1000);
    bench.set(0x6099, 1, 100);
    bench.set(0x6099, 2, 5);
    bench.set(0x607C, 0, offset);
    bench.run(5);
    bench.controlword(0x1F);
    bench.run_until(60_000, |b| {
        b.statusword() & (SW_MODE_12 | SW_MODE_13) != 0 && b.velocity() == 0
    });
    bench
}

#[test]
fn homing_methods_0_to_12_against_the_switches_with_the_home_offset() {
    // (method, home offset, where the zero ends on the machine).
    let cases: [(i64, i64, f64); 13] = [
        (0, 2_500, 0.0),
        // 1, 2: onto the limit switch; the offset is not theirs.
        (1, 2_500, -30_000.0),
        (2, 2_500, 30_000.0),
        // 3: left onto the origin cam's right edge; 4: right, turned back by
        // the CCW switch, onto the same edge from the right.
        (3, 2_500, -8_000.0),
        (4, 2_500, -8_000.0),
        // 5, 6: the limit switch's edge, approached slowly.
        (5, 2_500, -30_000.0),
        (6, 2_500, 30_000.0),
        // 7: left fast through the cam, back slowly onto its right edge;
        // 8: right, turned back by the CCW switch, last approach rightwards
        // onto the left edge.
        (7, 2_500, -8_000.0),
        (8, 2_500, -10_000.0),
        // 9–12: as 5–8, then the offset, either sign.
        (9, 2_500, -27_500.0),
        (10, -2_500, 27_500.0),
        (11, 2_500, -5_500.0),
        (12, -2_500, -12_500.0),
    ];
    for (method, offset, zero) in cases {
        let bench = home(method, offset, HOMING_SWITCHES);
        let at = format!("method {method}");
        assert_eq!(bench.jmc.machine_position(), zero, "{at}");
        assert_eq!((bench.position(), bench.velocity()), (0, 0), "{at}");
        let status = bench.statusword();
        assert_eq!(
            status & (SW_TARGET_REACHED | SW_MODE_12 | SW_MODE_13 | SW_HALTED),
            SW_TARGET_REACHED | SW_MODE_12,
            "{at}: 0x{status:04X}"
        );
        assert_eq!(status & SW_STATE, 0x0027, "{at}");
        let on_switch = match method {
            1 | 5 => SW_CW_LIMIT,
            2 | 6 => SW_CCW_LIMIT,
            3 | 4 | 7 | 8 => SW_ORIGIN_SWITCH,
            _ => 0,
        };
        assert_eq!(
            status & (SW_CW_LIMIT | SW_CCW_LIMIT | SW_ORIGIN_SWITCH),
            on_switch,
            "{at}"
        );
    }
}

#[test]
fn homing_speeds_are_capped_by_method() {
    // 10 rps asked: 1–4 run at 5 rps at most, 5–12 at 10.
    let mut bench = Bench::new();
    bench.jmc.set_switches(HOMING_SWITCHES);
    bench.enable(0x0F);
    bench.set(0x6060, 0, 6);
    bench.set(0x6098, 0, 2);
    bench.set(0x6099, 1, 100);
    bench.controlword(0x1F);
    bench.run(100);
    assert_eq!(bench.velocity(), 50);
    let mut bench = Bench::new();
    bench.enable(0x0F);
    bench.set(0x6060, 0, 6);
    bench.set(0x6098, 0, 6);
    bench.set(0x6099, 1, 300);
    bench.controlword(0x1F);
    bench.run(100);
    assert_eq!(bench.velocity(), 200, "1200 r/min");
}

#[test]
fn homing_without_an_origin_switch_fails_with_bit_13() {
    let switches = LimitSwitches {
        origin: None,
        ..HOMING_SWITCHES
    };
    for method in [3, 4, 7, 8, 11, 12] {
        let bench = home(method, 0, switches);
        let status = bench.statusword();
        assert_eq!(
            status & (SW_MODE_12 | SW_MODE_13 | SW_TARGET_REACHED),
            SW_MODE_13,
            "method {method}: 0x{status:04X}"
        );
    }
}

#[test]
fn halt_stops_homing_unfinished() {
    let mut bench = Bench::new();
    bench.jmc.set_switches(HOMING_SWITCHES);
    bench.enable(0x0F);
    bench.set(0x6060, 0, 6);
    bench.set(0x6098, 0, 1);
    bench.set(0x6099, 1, 10);
    bench.controlword(0x1F);
    bench.run(1_000);
    bench.controlword(0x011F);
    bench.run_until_standing(1_000);
    let status = bench.statusword();
    assert_eq!(
        status & (SW_MODE_12 | SW_MODE_13 | SW_TARGET_REACHED | SW_HALTED),
        SW_TARGET_REACHED | SW_HALTED,
        "0x{status:04X}"
    );
    assert!(bench.position() < -9_000);
    // Released and started again: it completes.
    bench.controlword(0x0F);
    bench.controlword(0x1F);
    bench.run_until(10_000, |b| b.statusword() & SW_MODE_12 != 0);
    assert_eq!(bench.jmc.machine_position(), -30_000.0);
}

#[test]
fn alarms_raise_their_emcy_and_need_a_fault_reset() {
    let mut bench = Bench::new();
    bench.enable(0x0F);
    bench.set(0x6060, 0, 3);
    bench.set(0x6081, 0, 50);
    bench.run(100);
    bench
        .call(|jmc, io| jmc.inject_fault(io, Fault::OverCurrent))
        .unwrap();
    assert_eq!(
        bench.raised,
        [RaisedEmcy {
            code: 0x2310,
            manufacturer: [0; 5]
        }]
    );
    assert_eq!(bench.get(0x1001, 0), 0x03);
    // Fault, the motor current cut.
    assert_eq!(bench.statusword() & 0x004F, 0x0008);
    bench.run(1);
    assert_eq!(bench.velocity(), 0);
    // A reset while the condition lasts changes nothing.
    bench.controlword(0x80);
    assert_eq!(bench.statusword() & 0x004F, 0x0008);
    bench
        .call(|jmc, io| jmc.clear_fault(io, Fault::OverCurrent))
        .unwrap();
    assert_eq!(bench.get(0x1001, 0), 0x03, "latched until reset");
    bench.controlword(0x00);
    bench.controlword(0x80);
    assert_eq!(bench.statusword() & SW_STATE, 0x0040);
    assert_eq!(bench.get(0x1001, 0), 0);
    assert_eq!(bench.raised.last().unwrap().code, 0x0000);
    assert_eq!(
        bench.call(|jmc, io| jmc.inject_fault(io, Fault::HeartbeatLoss)),
        Err(FaultError::NotApplicable {
            product: "jmc",
            fault: Fault::HeartbeatLoss
        })
    );
}

#[test]
fn each_alarm_has_its_register_bit_and_code() {
    for (fault, register, code) in [
        (Fault::OverCurrent, 0x03, 0x2310),
        (Fault::UnderVoltage, 0x05, 0x3220),
        (Fault::OverTemperature, 0x09, 0x4210),
        (Fault::FollowingError, 0x21, 0x8611),
    ] {
        let mut bench = Bench::new();
        bench.set(0x6060, 0, 1);
        bench.call(|jmc, io| jmc.inject_fault(io, fault)).unwrap();
        assert_eq!(bench.get(0x1001, 0), register, "{fault}");
        assert_eq!(bench.raised[0].code, code, "{fault}");
        let status = bench.statusword();
        // Under-voltage takes bit 4; following error is position mode's
        // "over position", bit 13.
        assert_eq!(
            status & SW_VOLTAGE_ENABLED == 0,
            fault == Fault::UnderVoltage
        );
        assert_eq!(status & SW_MODE_13 != 0, fault == Fault::FollowingError);
    }
}

#[test]
fn reset_node_zeroes_the_counter_not_the_machine() {
    let mut bench = Bench::new();
    bench.position_mode(100);
    bench.set(0x607A, 0, 12_345);
    bench.controlword(0x1F);
    bench.run_until_standing(5_000);
    assert_eq!(bench.position(), 12_345);
    bench.call(|jmc, io| jmc.reset(io));
    assert_eq!(bench.position(), 0);
    assert_eq!(bench.jmc.machine_position(), 12_345.0);
    assert_eq!(bench.statusword() & SW_STATE, 0x0040);
}

#[test]
fn an_idle_drive_does_nothing_in_its_tick() {
    let mut bench = Bench::new();
    bench.position_mode(100);
    bench.run(10);
    assert!(!bench.jmc.busy());
    // Values the drive would rewrite if its tick published anything.
    bench
        .store
        .set(0x6041, 0, Value::Unsigned16(0xBEEF))
        .unwrap();
    bench.store.set(0x6064, 0, Value::Integer32(-77)).unwrap();
    bench.run(1_000);
    assert_eq!((bench.statusword(), bench.position()), (0xBEEF, -77));
    // Work to do: it publishes again.
    bench.set(0x607A, 0, 1_000);
    bench.controlword(0x1F);
    bench.run(1);
    assert!(bench.jmc.busy());
    assert_eq!(bench.statusword() & SW_STATE, 0x0027);
    assert!(bench.position() > 0);
}

#[test]
fn moved_switches_show_at_the_next_tick_and_follow_the_counter() {
    let mut bench = Bench::new();
    bench.run(10);
    bench.jmc.set_switches(LimitSwitches {
        cw_limit: Some(0),
        ..LimitSwitches::default()
    });
    bench.run(1);
    assert_eq!(bench.statusword() & SW_CW_LIMIT, SW_CW_LIMIT);
    // After homing the counter's 0 is elsewhere on the machine.
    let bench = home(2, 0, HOMING_SWITCHES);
    assert_eq!(bench.jmc.counter_zero(), 30_000.0);
    assert_eq!(
        bench.jmc.counter_zero() + bench.position() as f64,
        bench.jmc.machine_position()
    );
}

#[test]
fn steps_per_revolution_scale_every_speed() {
    let mut jmc = Jmc::new();
    jmc.set_steps_per_revolution(4_000);
    jmc.set_steps_per_revolution(0);
    assert_eq!(jmc.steps_per_revolution(), 4_000);
    let mut bench = Bench::with(jmc);
    bench.enable(0x0F);
    bench.set(0x6060, 0, 3);
    bench.set(0x6081, 0, 10);
    bench.run(1_000);
    // 1 rps of 4000 steps, no ramp (0x6083 = 0).
    assert_eq!(bench.position(), 4_000);
    assert_eq!(bench.velocity(), 10);
}
