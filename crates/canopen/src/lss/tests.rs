use std::time::{Duration, Instant};

use super::slave::LssSlaveOutput;
use super::*;
use crate::NodeId;
use crate::can::{CanId, Frame};

fn raw(id: u16, data: &[u8]) -> Frame {
    Frame::new(CanId::Standard(id), data).unwrap()
}

fn node(id: u8) -> NodeId {
    NodeId::new(id).unwrap()
}

const UMC: LssAddress = LssAddress {
    vendor_id: 0x4A2,
    product_code: 0x1001,
    revision: 0x0100_0004,
    serial: 0x101,
};

#[test]
fn command_specifiers_round_trip() {
    for raw in 0..=u8::MAX {
        assert_eq!(CommandSpecifier::from_raw(raw).raw(), raw);
    }
    assert_eq!(CommandSpecifier::from_raw(0x51), CommandSpecifier::Fastscan);
    assert_eq!(
        CommandSpecifier::from_raw(0x99),
        CommandSpecifier::Unknown(0x99)
    );
}

#[test]
fn requests_encode_byte_exact_and_decode_back() {
    let cases: Vec<(LssRequest, [u8; 8])> = vec![
        (
            LssRequest::SwitchStateGlobal(LssState::Configuration),
            [0x04, 1, 0, 0, 0, 0, 0, 0],
        ),
        (
            LssRequest::SwitchStateSelective(AddressPart::Vendor, 0x4A2),
            [0x40, 0xA2, 0x04, 0, 0, 0, 0, 0],
        ),
        (
            LssRequest::SwitchStateSelective(AddressPart::Serial, 0x1234_5678),
            [0x43, 0x78, 0x56, 0x34, 0x12, 0, 0, 0],
        ),
        (
            LssRequest::ConfigureNodeId(10),
            [0x11, 10, 0, 0, 0, 0, 0, 0],
        ),
        (
            LssRequest::ConfigureBitTiming { table: 0, index: 2 },
            [0x13, 0, 2, 0, 0, 0, 0, 0],
        ),
        (
            LssRequest::ActivateBitTiming { delay_ms: 0x1234 },
            [0x15, 0x34, 0x12, 0, 0, 0, 0, 0],
        ),
        (LssRequest::StoreConfiguration, [0x17, 0, 0, 0, 0, 0, 0, 0]),
        (
            LssRequest::IdentifyRemoteSlave(IdentifyPart::SerialHigh, 0xFFFF_FFFF),
            [0x4B, 0xFF, 0xFF, 0xFF, 0xFF, 0, 0, 0],
        ),
        (
            LssRequest::IdentifyNonConfigured,
            [0x4C, 0, 0, 0, 0, 0, 0, 0],
        ),
        (
            LssRequest::Fastscan {
                id_number: 0x0000_04A2,
                bit_checked: 5,
                sub: 1,
                next: 2,
            },
            [0x51, 0xA2, 0x04, 0, 0, 5, 1, 2],
        ),
        (
            LssRequest::Fastscan {
                id_number: 0,
                bit_checked: FASTSCAN_CONFIRM,
                sub: 0,
                next: 0,
            },
            [0x51, 0, 0, 0, 0, 0x80, 0, 0],
        ),
        (
            LssRequest::Inquire(Inquiry::Address(AddressPart::Product)),
            [0x5B, 0, 0, 0, 0, 0, 0, 0],
        ),
        (
            LssRequest::Inquire(Inquiry::NodeId),
            [0x5E, 0, 0, 0, 0, 0, 0, 0],
        ),
    ];
    for (request, bytes) in cases {
        let frame = request.encode();
        assert_eq!(frame.id(), CanId::Standard(0x7E5), "{request:?}");
        assert_eq!(frame.data(), bytes, "{request:?}");
        assert_eq!(LssRequest::decode(&frame), Ok(request));
    }
}

#[test]
fn responses_encode_byte_exact_and_decode_back() {
    let cases: Vec<(LssResponse, [u8; 8])> = vec![
        (
            LssResponse::SwitchStateSelective,
            [0x44, 0, 0, 0, 0, 0, 0, 0],
        ),
        (
            LssResponse::ConfigureNodeId(ConfigResult::error(1)),
            [0x11, 1, 0, 0, 0, 0, 0, 0],
        ),
        (
            LssResponse::StoreConfiguration(ConfigResult {
                error: 0xFF,
                specific: 7,
            }),
            [0x17, 0xFF, 7, 0, 0, 0, 0, 0],
        ),
        (LssResponse::IdentifySlave, [0x4F, 0, 0, 0, 0, 0, 0, 0]),
        (
            LssResponse::IdentifyNonConfiguredSlave,
            [0x50, 0, 0, 0, 0, 0, 0, 0],
        ),
        (
            LssResponse::Inquired(Inquiry::Address(AddressPart::Serial), 0x0102_0304),
            [0x5D, 4, 3, 2, 1, 0, 0, 0],
        ),
        (
            LssResponse::Inquired(Inquiry::NodeId, 0xFF),
            [0x5E, 0xFF, 0, 0, 0, 0, 0, 0],
        ),
    ];
    for (response, bytes) in cases {
        let frame = response.encode();
        assert_eq!(frame.id(), CanId::Standard(0x7E4), "{response:?}");
        assert_eq!(frame.data(), bytes, "{response:?}");
        assert_eq!(LssResponse::decode(&frame), Ok(response));
    }
}

#[test]
fn malformed_frames_are_errors() {
    use LssDecodeError as E;
    let cases = [
        (raw(0x7E5, &[0x04, 1, 0, 0, 0, 0, 0]), E::Length(7)),
        (raw(0x7E5, &[]), E::Length(0)),
        (raw(0x7E5, &[0x04, 2, 0, 0, 0, 0, 0, 0]), E::Mode(2)),
        (
            raw(0x7E5, &[0x99, 0, 0, 0, 0, 0, 0, 0]),
            E::UnknownCommand(0x99),
        ),
        // An answer is no request.
        (
            raw(0x7E5, &[0x44, 0, 0, 0, 0, 0, 0, 0]),
            E::UnknownCommand(0x44),
        ),
        (raw(0x7E5, &[0x51, 0, 0, 0, 0, 32, 0, 0]), E::BitChecked(32)),
        (raw(0x7E5, &[0x51, 0, 0, 0, 0, 3, 4, 0]), E::Sub(4)),
        (raw(0x7E5, &[0x51, 0, 0, 0, 0, 3, 0, 9]), E::Sub(9)),
        (raw(0x7E4, &[0x04, 0, 0, 0, 0, 0, 0, 0]), E::NotLss),
        (raw(0x7E6, &[0x04, 0, 0, 0, 0, 0, 0, 0]), E::NotLss),
    ];
    for (frame, error) in cases {
        assert_eq!(LssRequest::decode(&frame), Err(error), "{frame:?}");
    }
    let remote = Frame::remote(CanId::Standard(0x7E5), 8).unwrap();
    assert_eq!(LssRequest::decode(&remote), Err(E::NotLss));
    assert_eq!(
        LssResponse::decode(&raw(0x7E4, &[0x51, 0, 0, 0, 0, 0, 0, 0])),
        Err(E::UnknownCommand(0x51))
    );
    assert_eq!(
        LssResponse::decode(&raw(0x7E4, &[0x4F, 0, 0])),
        Err(E::Length(3))
    );
    // A slave ignores what it cannot read, and answers nothing.
    let mut slave = LssSlave::new(UMC, None);
    assert_eq!(
        slave.handle(&raw(0x7E5, &[0x51, 0, 0, 0, 0, 0x40, 0, 0])),
        LssSlaveOutput::default()
    );
}

/// Master and slaves on one simulated wire: the identical answers of
/// several slaves to one request are one frame, as on a CAN bus.
struct Wire {
    master: LssMaster,
    slaves: Vec<LssSlave>,
    now: Instant,
    events: Vec<(usize, LssSlaveEvent)>,
    requests: usize,
    /// The answers to these requests (by number, from 1) come too late:
    /// after the master's timeout, before its next request's.
    late: Vec<usize>,
}

impl Wire {
    fn new(slaves: Vec<LssSlave>) -> Self {
        Self {
            master: LssMaster::new(Duration::from_millis(10)),
            slaves,
            now: Instant::now(),
            events: Vec::new(),
            requests: 0,
            late: Vec::new(),
        }
    }

    fn run(&mut self, service: LssService) -> Result<LssOutcome, LssError> {
        let mut step = self.master.start(service, self.now);
        let mut late: Vec<Frame> = Vec::new();
        loop {
            let mut answers: Vec<Frame> = std::mem::take(&mut late);
            let mut delayed = false;
            for frame in &step.send {
                self.requests += 1;
                delayed |= self.late.contains(&self.requests);
                for (n, slave) in self.slaves.iter_mut().enumerate() {
                    let out = slave.handle(frame);
                    if let Some(event) = out.event {
                        self.events.push((n, event));
                    }
                    if let Some(reply) = out.reply
                        && !answers.contains(&reply)
                    {
                        answers.push(reply);
                    }
                }
            }
            if let Some(done) = step.done {
                return done;
            }
            if delayed {
                late = std::mem::take(&mut answers);
            }
            step = match answers.first() {
                Some(answer) => {
                    self.now += Duration::from_millis(1);
                    self.master.on_frame(answer, self.now)
                }
                None => {
                    self.now = self.master.deadline().expect("a service runs");
                    self.master.handle_timeout(self.now)
                }
            };
        }
    }
}

fn address(serial: u32) -> LssAddress {
    LssAddress { serial, ..UMC }
}

#[test]
fn fastscan_finds_one_unconfigured_slave_in_133_requests() {
    let mut wire = Wire::new(vec![LssSlave::new(address(0xDEAD_BEEF), None)]);
    let found = wire.run(LssService::Fastscan);
    assert_eq!(found, Ok(LssOutcome::Found(Some(address(0xDEAD_BEEF)))));
    assert_eq!(wire.requests, 1 + 4 * 33);
    assert_eq!(wire.slaves[0].state(), LssState::Configuration);
}

#[test]
fn fastscan_starts_over_when_an_answer_comes_too_late() {
    // Late answers to a bit, and to the request after it; then to a
    // confirmation of a part. Each time the scan starts over and finds
    // the right address.
    let slaves = || {
        vec![
            LssSlave::new(address(0x1234_5678), None),
            LssSlave::new(address(0x0F0F_0F0F), None),
        ]
    };
    let mut wire = Wire::new(slaves());
    wire.run(LssService::FastscanAll).unwrap();
    let on_time = wire.requests;
    // Request 10 asks for bit 24 of the vendor-ID (0), 40 and 41 for bits
    // 27 and 26 of the product code, 35 confirms the vendor-ID.
    for late in [vec![10], vec![40, 41], vec![35]] {
        let mut wire = Wire::new(slaves());
        wire.late = late.clone();
        let Ok(LssOutcome::FoundAll(mut found)) = wire.run(LssService::FastscanAll) else {
            panic!("Fastscan failed with late answers {late:?}");
        };
        found.sort();
        assert_eq!(
            found,
            vec![address(0x0F0F_0F0F), address(0x1234_5678)],
            "{late:?}"
        );
        assert!(wire.requests > on_time, "{late:?}: no start-over");
    }
    // A slave that answers the confirm and nothing else fails the scan
    // after the start-overs.
    let mut master = LssMaster::new(Duration::from_millis(10));
    let mut now = Instant::now();
    let mut step = master.start(LssService::Fastscan, now);
    let mut confirms = 0;
    let outcome = loop {
        if let Some(done) = step.done {
            break done;
        }
        let confirm = step.send.iter().any(|frame| {
            matches!(
                LssRequest::decode(frame),
                Ok(LssRequest::Fastscan {
                    bit_checked: FASTSCAN_CONFIRM,
                    ..
                })
            )
        });
        now = master.deadline().unwrap();
        step = if confirm {
            confirms += 1;
            master.on_frame(&LssResponse::IdentifySlave.encode(), now)
        } else {
            master.handle_timeout(now)
        };
    };
    assert_eq!(outcome, Err(LssError::Timeout(CommandSpecifier::Fastscan)));
    assert_eq!(confirms, 1 + usize::from(master::FASTSCAN_RETRIES));
}

#[test]
fn fastscan_all_finds_every_unconfigured_slave_and_leaves_them_waiting() {
    let slaves = vec![
        LssSlave::new(address(7), None),
        // A configured slave takes no part.
        LssSlave::new(address(1), Some(node(1))),
        LssSlave::new(address(0x101), None),
        LssSlave::new(LssAddress::default(), None),
        LssSlave::new(address(0xFFFF_FFFF), None),
    ];
    let mut wire = Wire::new(slaves);
    let Ok(LssOutcome::FoundAll(mut found)) = wire.run(LssService::FastscanAll) else {
        panic!("Fastscan failed");
    };
    found.sort();
    let mut expected = vec![
        address(7),
        address(0x101),
        LssAddress::default(),
        address(0xFFFF_FFFF),
    ];
    expected.sort();
    assert_eq!(found, expected);
    for slave in &wire.slaves {
        assert_eq!(slave.state(), LssState::Waiting);
    }
    assert!(wire.events.is_empty(), "{:?}", wire.events);
    // Nothing unconfigured left in configuration: a second scan finds the same.
    let Ok(LssOutcome::FoundAll(again)) = wire.run(LssService::FastscanAll) else {
        panic!("Fastscan failed");
    };
    assert_eq!(again.len(), 4);
}

#[test]
fn fastscan_without_unconfigured_slaves_finds_none() {
    let mut wire = Wire::new(vec![LssSlave::new(address(1), Some(node(1)))]);
    assert_eq!(wire.run(LssService::Fastscan), Ok(LssOutcome::Found(None)));
    assert_eq!(
        wire.run(LssService::FastscanAll),
        Ok(LssOutcome::FoundAll(vec![]))
    );
    assert!(!wire.master.is_busy());
}

#[test]
fn configuring_a_selected_slave_activates_its_node_id_on_waiting() {
    let mut wire = Wire::new(vec![
        LssSlave::new(address(5), None),
        LssSlave::new(address(6), None),
    ]);
    assert_eq!(
        wire.run(LssService::SwitchSelective(address(6))),
        Ok(LssOutcome::Selected)
    );
    assert_eq!(wire.slaves[0].state(), LssState::Waiting);
    assert_eq!(wire.slaves[1].state(), LssState::Configuration);
    assert_eq!(
        wire.run(LssService::Inquire(Inquiry::Address(AddressPart::Serial))),
        Ok(LssOutcome::Inquired(6))
    );
    assert_eq!(
        wire.run(LssService::Inquire(Inquiry::NodeId)),
        Ok(LssOutcome::Inquired(0xFF))
    );
    assert_eq!(
        wire.run(LssService::ConfigureNodeId(0)),
        Err(LssError::Refused {
            command: CommandSpecifier::ConfigureNodeId,
            result: ConfigResult::error(1)
        })
    );
    assert_eq!(
        wire.run(LssService::ConfigureNodeId(10)),
        Ok(LssOutcome::Done)
    );
    assert_eq!(
        wire.run(LssService::ConfigureBitTiming { table: 0, index: 3 }),
        Ok(LssOutcome::Done)
    );
    assert!(matches!(
        wire.run(LssService::ConfigureBitTiming { table: 1, index: 3 }),
        Err(LssError::Refused { .. })
    ));
    assert_eq!(
        wire.run(LssService::StoreConfiguration),
        Ok(LssOutcome::Done)
    );
    assert_eq!(
        wire.run(LssService::SwitchGlobal(LssState::Waiting)),
        Ok(LssOutcome::Done)
    );
    assert_eq!(
        wire.events,
        vec![
            (
                1,
                LssSlaveEvent::Store {
                    node_id: Some(node(10)),
                    bit_timing: Some(3)
                }
            ),
            (1, LssSlaveEvent::Activate(node(10))),
        ]
    );
    assert_eq!(wire.slaves[1].active(), Some(node(10)));
    assert_eq!(wire.slaves[0].active(), None);
    // Configured now: Fastscan finds only the other one.
    assert_eq!(
        wire.run(LssService::FastscanAll),
        Ok(LssOutcome::FoundAll(vec![address(5)]))
    );
}

#[test]
fn a_slave_in_waiting_ignores_configuration_and_nobody_answers() {
    let mut wire = Wire::new(vec![LssSlave::new(address(5), None)]);
    assert_eq!(
        wire.run(LssService::ConfigureNodeId(3)),
        Err(LssError::Timeout(CommandSpecifier::ConfigureNodeId))
    );
    assert_eq!(
        wire.run(LssService::SwitchSelective(address(4))),
        Err(LssError::Timeout(CommandSpecifier::SwitchSelectiveResponse))
    );
    assert_eq!(wire.slaves[0].pending(), None);
    // The master is free again after each timeout.
    assert_eq!(
        wire.run(LssService::Inquire(Inquiry::NodeId)),
        Err(LssError::Timeout(CommandSpecifier::InquireNodeId))
    );
}

#[test]
fn identify_services_say_whether_anyone_answered() {
    let mut wire = Wire::new(vec![
        LssSlave::new(address(5), Some(node(5))),
        LssSlave::new(address(9), None),
    ]);
    let identify = |low, high| LssService::IdentifyRemote {
        vendor_id: UMC.vendor_id,
        product_code: UMC.product_code,
        revision: (0, u32::MAX),
        serial: (low, high),
    };
    assert_eq!(wire.run(identify(4, 6)), Ok(LssOutcome::Identified(true)));
    assert_eq!(
        wire.run(identify(10, 20)),
        Ok(LssOutcome::Identified(false))
    );
    assert_eq!(
        wire.run(LssService::IdentifyNonConfigured),
        Ok(LssOutcome::Identified(true))
    );
    wire.slaves.remove(1);
    assert_eq!(
        wire.run(LssService::IdentifyNonConfigured),
        Ok(LssOutcome::Identified(false))
    );
}

#[test]
fn one_service_at_a_time_and_late_answers_are_ignored() {
    let mut master = LssMaster::new(Duration::from_millis(10));
    let now = Instant::now();
    let step = master.start(LssService::Inquire(Inquiry::NodeId), now);
    assert_eq!(step.send.len(), 1);
    assert_eq!(
        master.start(LssService::StoreConfiguration, now).done,
        Some(Err(LssError::Busy))
    );
    // Too early: nothing happens.
    assert_eq!(master.handle_timeout(now), LssStep::default());
    // An answer to another command is not this one's.
    let other = LssResponse::StoreConfiguration(ConfigResult::OK).encode();
    assert_eq!(master.on_frame(&other, now), LssStep::default());
    let answer = LssResponse::Inquired(Inquiry::NodeId, 4).encode();
    assert_eq!(
        master.on_frame(&answer, now).done,
        Some(Ok(LssOutcome::Inquired(4)))
    );
    assert_eq!(master.on_frame(&answer, now), LssStep::default());
    assert_eq!(master.deadline(), None);
}

#[test]
fn reset_communication_makes_the_pending_node_id_active() {
    let mut slave = LssSlave::new(address(1), Some(node(3)));
    slave.handle(&LssRequest::SwitchStateGlobal(LssState::Configuration).encode());
    let out = slave.handle(&LssRequest::ConfigureNodeId(9).encode());
    assert_eq!(
        out.reply,
        Some(LssResponse::ConfigureNodeId(ConfigResult::OK).encode())
    );
    // A configured slave keeps its active node-ID on waiting...
    let out = slave.handle(&LssRequest::SwitchStateGlobal(LssState::Waiting).encode());
    assert_eq!(out.event, None);
    assert_eq!(slave.active(), Some(node(3)));
    // ...until NMT reset communication.
    assert_eq!(slave.reset_communication(), Some(node(9)));
    slave.power_on(None);
    assert_eq!((slave.active(), slave.pending()), (None, None));
}
