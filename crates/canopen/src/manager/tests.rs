use std::time::{Duration, Instant};

use std::collections::BTreeMap;

use super::*;
use crate::can::{CanId, Frame};
use crate::heartbeat::Heartbeat;

/// The manager with the supervisor of its bus, joined as the gateway
/// joins them: frames go to the supervisor, whose events drive the
/// manager; the manager's guarding goes to the supervisor, whose requests
/// go out; a confirmed write of 0x1017 is the supervisor's to follow.
/// The gateway's identification of a node is over at once
/// ([`Action::Identify`] answered `Done` within the poll) unless
/// `identifies` is off: then the test answers it.
struct Rig {
    manager: Manager,
    supervisor: Supervisor,
    identifies: bool,
    /// The write in flight per node.
    writes: BTreeMap<NodeId, (u16, u8, Vec<u8>)>,
    started: Instant,
}

impl std::ops::Deref for Rig {
    type Target = Manager;
    fn deref(&self) -> &Manager {
        &self.manager
    }
}

impl std::ops::DerefMut for Rig {
    fn deref_mut(&mut self) -> &mut Manager {
        &mut self.manager
    }
}

impl Rig {
    fn new(config: ManagerConfig, descriptions: Vec<NodeDescription>, now: Instant) -> Self {
        Self {
            supervisor: Supervisor::new(true).with_consumer_factor(config.consumer_factor),
            manager: Manager::new(config, descriptions, now),
            identifies: true,
            writes: BTreeMap::new(),
            started: now,
        }
    }

    fn pump(&mut self) {
        for event in self.supervisor.take_events() {
            self.manager.on_supervision(&event);
        }
    }

    fn node_found(&mut self, node: NodeId) {
        self.supervisor.watch(node, self.started);
        self.manager.node_found(node);
    }

    fn on_frame(&mut self, frame: &Frame, now: Instant) {
        self.supervisor.on_frame(frame, now).unwrap();
        self.pump();
    }

    fn poll(&mut self, now: Instant) -> Vec<Action> {
        let requests = self.supervisor.poll(now);
        self.pump();
        let mut actions = self.manager.poll(now);
        while self.identifies {
            let identified: Vec<NodeId> = actions
                .iter()
                .filter_map(|action| match action {
                    Action::Identify { node } => Some(*node),
                    _ => None,
                })
                .collect();
            if identified.is_empty() {
                break;
            }
            actions.retain(|action| !matches!(action, Action::Identify { .. }));
            for node in identified {
                self.manager.on_sdo(node, SdoOutcome::Done(Vec::new()), now);
            }
            actions.extend(self.manager.poll(now));
        }
        for action in &actions {
            match action {
                Action::Guard {
                    node,
                    guard_time_ms,
                    life_time_factor,
                } => self
                    .supervisor
                    .guard(*node, *guard_time_ms, *life_time_factor, now),
                Action::Unguard { node } => self.supervisor.unguard(*node, now),
                Action::Write {
                    node,
                    index,
                    sub,
                    data,
                } => {
                    self.writes.insert(*node, (*index, *sub, data.clone()));
                }
                _ => {}
            }
        }
        actions.retain(|action| !matches!(action, Action::Guard { .. } | Action::Unguard { .. }));
        actions.extend(requests.into_iter().map(Action::Send));
        // Guarding set up by this poll sends its first request at once.
        actions.extend(self.supervisor.poll(now).into_iter().map(Action::Send));
        self.pump();
        actions
    }

    fn on_sdo(&mut self, node: NodeId, outcome: SdoOutcome, now: Instant) {
        if let (Some((0x1017, 0, data)), SdoOutcome::Done(_)) =
            (self.writes.remove(&node), &outcome)
        {
            let ms = u16::from_le_bytes([data[0], data[1]]);
            self.producer_heartbeat_written(node, ms, now);
        }
        self.manager.on_sdo(node, outcome, now);
    }

    /// Someone wrote `ms` into the node's 0x1017 at `now`, and the node
    /// confirmed it.
    fn producer_heartbeat_written(&mut self, node: NodeId, ms: u16, now: Instant) {
        self.supervisor.heartbeat_written(node, ms, now);
        self.pump();
    }
}

fn id(n: u8) -> NodeId {
    NodeId::new(n).unwrap()
}

fn config() -> ManagerConfig {
    ManagerConfig {
        node_id: id(127),
        heartbeat_ms: 100,
        retry_min: Duration::from_millis(200),
        retry_max: Duration::from_millis(800),
        max_requests: 16,
        // The tests time losses at one and a half periods.
        consumer_factor: ConsumerFactor::MIN,
    }
}

fn heartbeat(node: u8, state: NmtState) -> Frame {
    Heartbeat::new(id(node), state).encode()
}

fn sdo_actions(actions: &[Action]) -> Vec<Action> {
    actions
        .iter()
        .filter(
            |action| !matches!(action, Action::Send(frame) if frame.id() == CanId::Standard(0x77F)),
        )
        .cloned()
        .collect()
}

/// Answers every request of `node` with `answer` until the boot-up ends;
/// every action seen, in order.
/// A boot-up's answers: 0x1016 sub 0 has one entry, every other read and
/// write succeeds with no data.
fn one_consumer_entry(action: &Action) -> SdoOutcome {
    match action {
        Action::Read { index: 0x1016, .. } => SdoOutcome::Done(1u32.to_le_bytes().to_vec()),
        _ => SdoOutcome::Done(Vec::new()),
    }
}

fn run_boot(
    manager: &mut Rig,
    now: Instant,
    answer: impl Fn(&Action) -> SdoOutcome,
) -> Vec<Action> {
    let mut seen = Vec::new();
    for _ in 0..100 {
        let actions = sdo_actions(&manager.poll(now));
        if actions.is_empty() {
            break;
        }
        for action in actions {
            seen.push(action.clone());
            if let Action::Read { node, .. }
            | Action::Write { node, .. }
            | Action::StopMotion { node } = &action
            {
                manager.on_sdo(*node, answer(&action), now);
            }
        }
    }
    seen
}

#[test]
fn the_manager_heartbeat_is_byte_exact_and_periodic() {
    let t0 = Instant::now();
    let mut manager = Rig::new(config(), Vec::new(), t0);
    assert_eq!(
        manager.heartbeat_now().unwrap(),
        Frame::new(CanId::Standard(0x77F), &[0x05]).unwrap()
    );
    assert!(manager.poll(t0 + Duration::from_millis(99)).is_empty());
    assert_eq!(
        manager.poll(t0 + Duration::from_millis(100)),
        vec![Action::Send(
            Frame::new(CanId::Standard(0x77F), &[0x05]).unwrap()
        )]
    );
    assert_eq!(manager.deadline(), Some(t0 + Duration::from_millis(200)));
    let silent = ManagerConfig {
        heartbeat_ms: 0,
        ..config()
    };
    let mut manager = Rig::new(silent, Vec::new(), t0);
    assert!(manager.heartbeat_now().is_none());
    assert!(manager.poll(t0 + Duration::from_secs(5)).is_empty());
}

/// Node 3's answers: its identity, and a 0x1016 of three entries, the
/// first watching node 5 (kept), the second free (takes the manager's
/// heartbeat).
fn answer_node_3(action: &Action) -> SdoOutcome {
    match action {
        Action::Read {
            index: 0x1016, sub, ..
        } => SdoOutcome::Done(
            match sub {
                0 => 3u32,
                1 => 0x0005_01F4,
                _ => 0,
            }
            .to_le_bytes()
            .to_vec(),
        ),
        Action::Read { sub: 1, .. } => SdoOutcome::Done(0x4A2u32.to_le_bytes().to_vec()),
        Action::Read { sub: 2, .. } => SdoOutcome::Done(0x1001u32.to_le_bytes().to_vec()),
        _ => SdoOutcome::Done(Vec::new()),
    }
}

#[test]
fn a_described_node_is_checked_configured_supervised_and_started_in_order() {
    let t0 = Instant::now();
    let mut description = NodeDescription::new(id(3));
    description.identity.vendor_id = Some(0x4A2);
    description.identity.product_code = Some(0x1001);
    description.heartbeat_ms = 300;
    description.config = vec![
        ConfigWrite {
            index: 0x2000,
            sub: 1,
            data: vec![7],
            label: "a.dcf: 0x2000 sub 1".into(),
        },
        ConfigWrite {
            index: 0x1800,
            sub: 5,
            data: vec![0x64, 0],
            label: "a.dcf: 0x1800 sub 5".into(),
        },
    ];
    let mut manager = Rig::new(config(), vec![description], t0);
    assert_eq!(manager.status().state, MachineState::Booting);
    manager.on_frame(&heartbeat(3, NmtState::BootUp), t0);
    let actions = run_boot(&mut manager, t0, answer_node_3);
    let n = id(3);
    assert_eq!(
        actions,
        vec![
            Action::Read {
                node: n,
                index: 0x1018,
                sub: 1
            },
            Action::Read {
                node: n,
                index: 0x1018,
                sub: 2
            },
            Action::Write {
                node: n,
                index: 0x2000,
                sub: 1,
                data: vec![7]
            },
            Action::Write {
                node: n,
                index: 0x1800,
                sub: 5,
                data: vec![0x64, 0]
            },
            Action::Write {
                node: n,
                index: 0x1017,
                sub: 0,
                data: vec![0x2C, 0x01]
            },
            // Node 127, 300 ms (3 × 100): 0x007F012C.
            Action::Read {
                node: n,
                index: 0x1016,
                sub: 0
            },
            Action::Read {
                node: n,
                index: 0x1016,
                sub: 1
            },
            Action::Read {
                node: n,
                index: 0x1016,
                sub: 2
            },
            Action::Read {
                node: n,
                index: 0x1016,
                sub: 3
            },
            Action::Write {
                node: n,
                index: 0x1016,
                sub: 2,
                data: vec![0x2C, 0x01, 0x7F, 0x00]
            },
            Action::Send(Frame::new(CanId::Standard(0x000), &[0x01, 0x03]).unwrap()),
        ]
    );
    let status = manager.status();
    let node = &status.nodes[0];
    // Started, supervised, but not ready until it says it is operational.
    assert_eq!(node.state, NodeState::Booting);
    assert_eq!(node.supervision, Supervision::Heartbeat);
    assert_eq!(node.step, Step::Start);
    manager.scan_done();
    assert_eq!(manager.status().state, MachineState::Booting);
    manager.on_frame(
        &heartbeat(3, NmtState::Operational),
        t0 + Duration::from_millis(300),
    );
    manager.poll(t0 + Duration::from_millis(300));
    assert_eq!(manager.status().state, MachineState::Ready);
    let node = manager.status().nodes[0].clone();
    assert_eq!(
        (node.state, node.step, node.nmt.as_str()),
        (NodeState::Ready, Step::Supervised, "operational")
    );
    // Lost after 1.5 periods without heartbeat: offline, machine degraded.
    manager.poll(t0 + Duration::from_millis(300 + 449));
    assert_eq!(manager.status().nodes[0].state, NodeState::Ready);
    manager.poll(t0 + Duration::from_millis(300 + 450));
    let status = manager.status();
    assert_eq!(status.nodes[0].state, NodeState::Offline);
    assert_eq!(status.state, MachineState::Down);
    assert!(
        manager
            .take_events()
            .iter()
            .any(|event| matches!(event, ManagerEvent::Lost { node, .. } if *node == n))
    );
    // Back with a boot-up: booted again by itself.
    manager.on_frame(&heartbeat(3, NmtState::BootUp), t0 + Duration::from_secs(2));
    assert_eq!(manager.status().nodes[0].state, NodeState::Booting);
    let again = run_boot(&mut manager, t0 + Duration::from_secs(2), answer_node_3);
    assert_eq!(again, actions);
    assert_eq!(manager.status().nodes[0].boots_ok, 2);
}

#[test]
fn a_wrong_identity_is_neither_configured_nor_started_nor_retried() {
    let t0 = Instant::now();
    let mut description = NodeDescription::new(id(2));
    description.identity.product_code = Some(0x1234);
    description.config = vec![ConfigWrite {
        index: 0x2000,
        sub: 0,
        data: vec![1],
        label: "x".into(),
    }];
    let mut manager = Rig::new(config(), vec![description], t0);
    manager.node_found(id(2));
    let actions = run_boot(&mut manager, t0, |_| {
        SdoOutcome::Done(0x9999u32.to_le_bytes().to_vec())
    });
    assert_eq!(
        actions,
        vec![Action::Read {
            node: id(2),
            index: 0x1018,
            sub: 2
        }]
    );
    let status = manager.status();
    assert_eq!(status.nodes[0].state, NodeState::WrongIdentity);
    let reason = status.nodes[0].reason.clone().unwrap();
    assert!(
        reason.contains("product_code") && reason.contains("0x00009999"),
        "{reason}"
    );
    assert!(manager.deadline().unwrap() <= t0 + Duration::from_millis(100));
    assert!(sdo_actions(&manager.poll(t0 + Duration::from_secs(60))).is_empty());
}

#[test]
fn a_configuration_abort_names_the_entry_and_is_retried_with_backoff() {
    let t0 = Instant::now();
    let mut description = NodeDescription::new(id(4));
    description.config = vec![ConfigWrite {
        index: 0x6060,
        sub: 0,
        data: vec![9],
        label: "lift.dcf: 0x6060 sub 0 (Modes of operation)".into(),
    }];
    let mut manager = Rig::new(config(), vec![description], t0);
    manager.node_found(id(4));
    let abort = AbortCode::from_raw(0x0609_0030);
    let aborted = |action: &Action| match action {
        // Its axes are at rest: the write is tried.
        Action::StopMotion { .. } => SdoOutcome::Done(Vec::new()),
        _ => SdoOutcome::Aborted(abort),
    };
    run_boot(&mut manager, t0, aborted);
    let node = manager.status().nodes[0].clone();
    assert_eq!(node.state, NodeState::ConfigFailed);
    assert_eq!(node.step, Step::Configuration);
    let reason = node.reason.unwrap();
    assert!(
        reason.contains("0x6060 sub 0 (Modes of operation)") && reason.contains("0x06090030"),
        "{reason}"
    );
    let retries: Vec<Duration> = manager
        .take_events()
        .into_iter()
        .filter_map(|event| match event {
            ManagerEvent::Failed { retry, .. } => retry,
            _ => None,
        })
        .collect();
    assert_eq!(retries, vec![Duration::from_millis(200)]);
    // Not before the backoff; then again, twice as late after a second failure.
    assert!(sdo_actions(&manager.poll(t0 + Duration::from_millis(199))).is_empty());
    let t1 = t0 + Duration::from_millis(200);
    run_boot(&mut manager, t1, aborted);
    let retry = manager
        .take_events()
        .into_iter()
        .find_map(|event| match event {
            ManagerEvent::Failed { retry, .. } => retry,
            _ => None,
        });
    assert_eq!(retry, Some(Duration::from_millis(400)));
}

#[test]
fn without_writable_1017_the_manager_guards_the_node() {
    let t0 = Instant::now();
    let mut description = NodeDescription::new(id(5));
    description.heartbeat_ms = 100;
    description.consume_manager_heartbeat = Some(false);
    description.start = false;
    let mut manager = Rig::new(config(), vec![description], t0);
    manager.node_found(id(5));
    let actions = run_boot(&mut manager, t0, |action| match action {
        Action::Write { index: 0x1017, .. } => {
            SdoOutcome::Aborted(AbortCode::from_raw(0x0601_0002))
        }
        _ => SdoOutcome::Done(Vec::new()),
    });
    let n = id(5);
    assert_eq!(
        actions,
        vec![
            Action::Write {
                node: n,
                index: 0x1017,
                sub: 0,
                data: vec![100, 0]
            },
            Action::Write {
                node: n,
                index: 0x100C,
                sub: 0,
                data: vec![100, 0]
            },
            Action::Write {
                node: n,
                index: 0x100D,
                sub: 0,
                data: vec![3]
            },
            // The first guarding request at once: a remote frame on 0x705.
            Action::Send(Frame::remote(CanId::Standard(0x705), 1).unwrap()),
        ]
    );
    assert_eq!(manager.status().nodes[0].supervision, Supervision::Guarding);
    // Three requests without a reply: lost.
    for ms in [100, 200] {
        manager.poll(t0 + Duration::from_millis(ms));
    }
    assert_eq!(manager.status().nodes[0].state, NodeState::Booting);
    manager.poll(t0 + Duration::from_millis(300));
    assert_eq!(manager.status().nodes[0].state, NodeState::Offline);
}

#[test]
fn a_node_that_cannot_be_supervised_says_why() {
    let t0 = Instant::now();
    let mut description = NodeDescription::new(id(6));
    description.consume_manager_heartbeat = Some(false);
    let mut manager = Rig::new(config(), vec![description], t0);
    manager.node_found(id(6));
    run_boot(&mut manager, t0, |_| {
        SdoOutcome::Aborted(AbortCode::from_raw(0x0602_0000))
    });
    let status = manager.status();
    assert_eq!(status.nodes[0].supervision, Supervision::None);
    assert!(
        status.nodes[0]
            .reason
            .as_deref()
            .unwrap()
            .contains("0x100C")
    );
    manager.scan_done();
    assert_eq!(manager.status().state, MachineState::Down);
}

#[test]
fn a_missing_mandatory_node_degrades_the_machine_once_the_scan_is_done() {
    let t0 = Instant::now();
    let mut manager = Rig::new(
        config(),
        vec![NodeDescription::new(id(1)), NodeDescription::new(id(5))],
        t0,
    );
    manager.on_frame(&heartbeat(1, NmtState::BootUp), t0);
    run_boot(&mut manager, t0, |_| SdoOutcome::Done(Vec::new()));
    manager.on_frame(&heartbeat(1, NmtState::Operational), t0);
    manager.poll(t0);
    assert_eq!(manager.status().state, MachineState::Booting);
    manager.scan_done();
    let status = manager.status();
    assert_eq!(status.state, MachineState::Degraded);
    assert_eq!(
        status.reasons,
        vec!["node 5 missing: not found on the bus".to_string()]
    );
    // An undescribed node is unexpected and left alone.
    manager.on_frame(&heartbeat(9, NmtState::PreOperational), t0);
    assert!(sdo_actions(&manager.poll(t0)).is_empty());
    let nine = manager
        .status()
        .nodes
        .into_iter()
        .find(|n| n.id == 9)
        .unwrap();
    assert_eq!(nine.state, NodeState::Unexpected);
    assert!(!nine.expected);
}

#[test]
fn without_descriptions_every_node_found_is_booted_with_the_defaults() {
    let t0 = Instant::now();
    let mut manager = Rig::new(config(), Vec::new(), t0);
    manager.node_found(id(2));
    let actions = run_boot(&mut manager, t0, |action| match action {
        Action::Write { index: 0x1016, .. } => {
            SdoOutcome::Aborted(AbortCode::from_raw(0x0602_0000))
        }
        // One entry, already the manager's (an earlier boot wrote it).
        Action::Read {
            index: 0x1016, sub, ..
        } => SdoOutcome::Done(
            if *sub == 0 { 1u32 } else { 0x007F_012C }
                .to_le_bytes()
                .to_vec(),
        ),
        _ => SdoOutcome::Done(Vec::new()),
    });
    let n = id(2);
    assert_eq!(
        actions,
        vec![
            Action::Write {
                node: n,
                index: 0x1017,
                sub: 0,
                data: vec![0xF4, 0x01]
            },
            Action::Read {
                node: n,
                index: 0x1016,
                sub: 0
            },
            Action::Read {
                node: n,
                index: 0x1016,
                sub: 1
            },
            Action::Write {
                node: n,
                index: 0x1016,
                sub: 1,
                data: vec![0x2C, 0x01, 0x7F, 0x00]
            },
            Action::Send(Frame::new(CanId::Standard(0x000), &[0x01, 0x02]).unwrap()),
        ]
    );
    manager.on_frame(&heartbeat(2, NmtState::Operational), t0);
    manager.poll(t0);
    let node = manager.status().nodes[0].clone();
    assert_eq!(
        (node.state, node.expected, node.mandatory),
        (NodeState::Ready, false, false)
    );
    manager.scan_done();
    assert_eq!(manager.status().state, MachineState::Ready);
}

#[test]
fn a_boot_up_during_a_boot_waits_for_the_answer_in_flight() {
    let t0 = Instant::now();
    let mut manager = Rig::new(config(), Vec::new(), t0);
    manager.node_found(id(1));
    let first = sdo_actions(&manager.poll(t0));
    assert_eq!(first.len(), 1);
    manager.on_frame(&heartbeat(1, NmtState::BootUp), t0);
    // Nothing new while the old request is out.
    assert!(sdo_actions(&manager.poll(t0)).is_empty());
    manager.on_sdo(id(1), SdoOutcome::Done(Vec::new()), t0);
    // The new boot-up starts from its first operation.
    assert_eq!(sdo_actions(&manager.poll(t0)), first);
}

#[test]
fn no_answer_is_missing_and_retried() {
    let t0 = Instant::now();
    let mut manager = Rig::new(config(), vec![NodeDescription::new(id(7))], t0);
    manager.node_found(id(7));
    run_boot(&mut manager, t0, |_| {
        SdoOutcome::Failed("SDO timeout".into())
    });
    let node = manager.status().nodes[0].clone();
    assert_eq!(node.state, NodeState::Missing);
    assert_eq!(node.reason.as_deref(), Some("error_control: SDO timeout"));
    assert_eq!(manager.deadline(), Some(t0 + Duration::from_millis(100)));
    manager.poll(t0 + Duration::from_millis(100));
    assert_eq!(manager.deadline(), Some(t0 + Duration::from_millis(200)));
    assert_eq!(
        sdo_actions(&manager.poll(t0 + Duration::from_millis(200))).len(),
        1
    );
}

#[test]
fn every_present_node_is_booted_again_when_the_bus_comes_back() {
    let t0 = Instant::now();
    let mut manager = Rig::new(config(), Vec::new(), t0);
    manager.node_found(id(1));
    manager.node_found(id(3));
    run_boot(&mut manager, t0, |_| SdoOutcome::Done(Vec::new()));
    manager.take_events();
    manager.bus_up(false);
    assert_eq!(manager.status().state, MachineState::Down);
    // Down: nothing is asked of the nodes.
    manager.bus_up(false);
    assert!(manager.take_events().is_empty());
    // Back: both booted again (their boot-up may have gone unheard).
    manager.bus_up(true);
    let again = run_boot(&mut manager, t0, |_| SdoOutcome::Done(Vec::new()));
    let written: Vec<NodeId> = again
        .iter()
        .filter_map(|action| match action {
            Action::Write {
                node,
                index: 0x1017,
                ..
            } => Some(*node),
            _ => None,
        })
        .collect();
    assert_eq!(written, vec![id(1), id(3)]);
    assert!(manager.status().nodes.iter().all(|node| node.boots_ok == 2));
}

#[test]
fn boot_up_requests_in_flight_are_bounded_across_the_bus() {
    let t0 = Instant::now();
    let limited = ManagerConfig {
        max_requests: 2,
        ..config()
    };
    let mut manager = Rig::new(limited, Vec::new(), t0);
    for n in 1..=5 {
        manager.node_found(id(n));
    }
    let first = sdo_actions(&manager.poll(t0));
    assert_eq!(first.len(), 2, "{first:?}");
    // Nothing more until one is answered; then one more.
    assert!(sdo_actions(&manager.poll(t0)).is_empty());
    manager.on_sdo(id(1), SdoOutcome::Done(Vec::new()), t0);
    let next = sdo_actions(&manager.poll(t0));
    assert_eq!(next.len(), 1, "{next:?}");
    // Every node gets there once the requests out are answered.
    manager.on_sdo(id(2), SdoOutcome::Done(Vec::new()), t0);
    for action in next {
        if let Action::Read { node, .. } | Action::Write { node, .. } = action {
            manager.on_sdo(node, SdoOutcome::Done(Vec::new()), t0);
        }
    }
    run_boot(&mut manager, t0, |_| SdoOutcome::Done(Vec::new()));
    for n in 1..=5 {
        manager.on_frame(&heartbeat(n, NmtState::Operational), t0);
    }
    assert!(
        manager
            .status()
            .nodes
            .iter()
            .all(|node| node.state == NodeState::Ready),
        "{:?}",
        manager.status()
    );
}

#[test]
fn a_node_that_moved_to_another_id_is_forgotten_or_missing_never_lost() {
    let t0 = Instant::now();
    let later = t0 + Duration::from_secs(10);
    let lost = |manager: &mut Manager| {
        manager
            .take_events()
            .into_iter()
            .filter(|event| matches!(event, ManagerEvent::Lost { .. }))
            .count()
    };
    // Found only (no description): forgotten.
    let mut manager = Rig::new(config(), Vec::new(), t0);
    manager.node_found(id(2));
    manager.scan_done();
    run_boot(&mut manager, t0, |_| SdoOutcome::Done(Vec::new()));
    manager.on_frame(&heartbeat(2, NmtState::Operational), t0);
    manager.poll(t0);
    assert_eq!(manager.status().nodes[0].state, NodeState::Ready);
    manager.take_events();
    manager.node_left(id(2), "moved");
    assert!(manager.status().nodes.is_empty());
    manager.poll(later);
    assert_eq!(lost(&mut manager), 0);
    assert_eq!(manager.status().state, MachineState::Ready);

    // Expected: missing again, with the reason, and booted when a device
    // answers there once more.
    let mut manager = Rig::new(config(), vec![NodeDescription::new(id(1))], t0);
    manager.on_frame(&heartbeat(1, NmtState::BootUp), t0);
    run_boot(&mut manager, t0, |_| SdoOutcome::Done(Vec::new()));
    manager.on_frame(&heartbeat(1, NmtState::Operational), t0);
    manager.poll(t0);
    manager.scan_done();
    manager.take_events();
    manager.node_left(id(1), "moved to 9");
    manager.poll(later);
    assert_eq!(lost(&mut manager), 0);
    let node = manager.status().nodes[0].clone();
    assert_eq!(
        (node.state, node.reason.as_deref()),
        (NodeState::Missing, Some("moved to 9"))
    );
    manager.node_found(id(1));
    assert!(!sdo_actions(&manager.poll(later)).is_empty());
}

#[test]
fn a_consumer_table_with_no_free_entry_is_kept_and_said() {
    let t0 = Instant::now();
    // Two entries, both watching other nodes.
    let answer = |action: &Action| match action {
        Action::Read {
            index: 0x1016, sub, ..
        } => SdoOutcome::Done(
            match sub {
                0 => 2u32,
                1 => 0x0005_01F4,
                _ => 0x0006_01F4,
            }
            .to_le_bytes()
            .to_vec(),
        ),
        _ => SdoOutcome::Done(Vec::new()),
    };
    let writes_1016 = |actions: &[Action]| {
        actions
            .iter()
            .filter(|action| matches!(action, Action::Write { index: 0x1016, .. }))
            .count()
    };
    // Where it can: booted all the same, the table left alone.
    let mut manager = Rig::new(config(), vec![NodeDescription::new(id(4))], t0);
    manager.node_found(id(4));
    let actions = run_boot(&mut manager, t0, answer);
    assert_eq!(writes_1016(&actions), 0, "{actions:?}");
    manager.on_frame(&heartbeat(4, NmtState::Operational), t0);
    assert_eq!(manager.status().nodes[0].state, NodeState::Ready);
    // Required: the boot-up fails and says why.
    let mut description = NodeDescription::new(id(4));
    description.consume_manager_heartbeat = Some(true);
    let mut manager = Rig::new(config(), vec![description], t0);
    manager.node_found(id(4));
    let actions = run_boot(&mut manager, t0, answer);
    assert_eq!(writes_1016(&actions), 0, "{actions:?}");
    let node = manager.status().nodes[0].clone();
    assert_eq!(node.state, NodeState::ConfigFailed);
    assert_eq!(
        node.reason.as_deref(),
        Some(
            "error_control: 0x1016: all 2 entries watch other nodes; none is free for the manager's heartbeat"
        )
    );
}

#[test]
fn the_supervisor_hears_error_control_frames_only_and_nothing_else_changes_the_manager() {
    // A driver skips every frame `hears` refuses, without a poll: such a
    // frame must leave the supervisor and the manager exactly as they were.
    let t0 = Instant::now();
    let mut manager = Rig::new(config(), vec![NodeDescription::new(id(1))], t0);
    manager.on_frame(&heartbeat(1, NmtState::BootUp), t0);
    let actions = sdo_actions(&manager.poll(t0));
    assert!(!actions.is_empty());
    manager.take_events();
    let (status, deadline) = (manager.status(), manager.deadline());
    let supervised = (
        manager.supervisor.deadline(),
        manager.supervisor.node(id(1)),
    );
    let mut heard = Vec::new();
    for raw in 0..0x800u16 {
        for data in [&[][..], &[0x05][..], &[0x7F, 0, 0, 0, 0, 0, 0, 0][..]] {
            let frame = Frame::new(CanId::Standard(raw), data).unwrap();
            if Supervisor::hears(&frame) {
                heard.push(raw);
                continue;
            }
            manager.on_frame(&frame, t0);
        }
    }
    heard.dedup();
    assert_eq!(heard, (0x701..=0x77F).collect::<Vec<u16>>());
    assert_eq!(manager.status(), status);
    assert_eq!(manager.deadline(), deadline);
    assert_eq!(
        (
            manager.supervisor.deadline(),
            manager.supervisor.node(id(1))
        ),
        supervised
    );
    assert!(manager.take_events().is_empty());
    // Nothing new to do either: the request in flight is still the one.
    assert!(sdo_actions(&manager.poll(t0)).is_empty());
}

/// Boots node 2 with the defaults (heartbeat 500 ms), its 0x1016 taking
/// the manager's heartbeat, and hears it operational at `now`.
fn booted_default_node(now: Instant) -> Rig {
    let mut manager = Rig::new(config(), Vec::new(), now);
    manager.node_found(id(2));
    run_boot(&mut manager, now, one_consumer_entry);
    manager.on_frame(&heartbeat(2, NmtState::Operational), now);
    manager.poll(now);
    manager.take_events();
    let node = manager.status().nodes[0].clone();
    assert_eq!(
        (node.state, node.supervision, node.heartbeat_ms),
        (NodeState::Ready, Supervision::Heartbeat, 500)
    );
    manager
}

#[test]
fn a_written_producer_heartbeat_time_is_followed_not_undone() {
    let t0 = Instant::now();
    let ms = Duration::from_millis;
    let mut manager = booted_default_node(t0);
    // 1000 ms written: the consumer waits 1.5 s from the write.
    let t1 = t0 + ms(100);
    manager.producer_heartbeat_written(id(2), 1000, t1);
    assert_eq!(manager.status().nodes[0].heartbeat_ms, 1000);
    assert_eq!(manager.description(id(2)).unwrap().heartbeat_ms, 1000);
    assert_eq!(manager.supervisor.deadline(), Some(t1 + ms(1500)));
    // The node's heartbeats one second apart: never lost, never booted again.
    for beat in 1..=5u64 {
        let at = t1 + ms(1000 * beat);
        assert!(sdo_actions(&manager.poll(at - ms(1))).is_empty());
        manager.on_frame(&heartbeat(2, NmtState::Operational), at);
    }
    manager.poll(t1 + ms(6499));
    assert_eq!(manager.take_events(), Vec::new());
    assert_eq!(manager.status().nodes[0].state, NodeState::Ready);
    assert_eq!(manager.status().nodes[0].boots, 1);
    // The manager's own write of the same value changes nothing in the
    // machine; the node answered it, so its one deadline runs from it.
    let status = manager.status();
    manager.producer_heartbeat_written(id(2), 1000, t1 + ms(6400));
    assert_eq!(manager.status(), status);
    assert_eq!(manager.supervisor.deadline(), Some(t1 + ms(6400 + 1500)));
    // 200 ms written: a silence of 300 ms is a loss.
    let t2 = t1 + ms(5200);
    manager.producer_heartbeat_written(id(2), 200, t2);
    manager.poll(t2 + ms(299));
    assert_eq!(manager.status().nodes[0].state, NodeState::Ready);
    manager.poll(t2 + ms(300));
    let node = manager.status().nodes[0].clone();
    assert_eq!(node.state, NodeState::Offline);
    assert_eq!(
        node.reason.as_deref(),
        Some("no heartbeat within 300 ms (1.5 × 200 ms)")
    );
    // Its next boot-up writes the value written last, not the old one.
    let t3 = t2 + ms(1000);
    manager.on_frame(&heartbeat(2, NmtState::BootUp), t3);
    let actions = run_boot(&mut manager, t3, one_consumer_entry);
    assert_first_writes_heartbeat_of_2(&actions, 200);
}

/// A boot-up of node 2 begins by writing `ms` into its 0x1017.
fn assert_first_writes_heartbeat_of_2(actions: &[Action], ms: u16) {
    assert_eq!(
        actions[0],
        Action::Write {
            node: id(2),
            index: 0x1017,
            sub: 0,
            data: ms.to_le_bytes().to_vec()
        }
    );
}

#[test]
fn a_producer_heartbeat_time_written_0_leaves_the_node_unsupervised_and_says_why() {
    let t0 = Instant::now();
    let ms = Duration::from_millis;
    let mut manager = booted_default_node(t0);
    manager.producer_heartbeat_written(id(2), 0, t0 + ms(10));
    let node = manager.status().nodes[0].clone();
    assert_eq!(
        (node.supervision, node.heartbeat_ms),
        (Supervision::None, 0)
    );
    assert!(
        node.reason
            .as_deref()
            .unwrap()
            .contains("0x1017 was written 0"),
        "{node:?}"
    );
    // Silence is no loss now.
    manager.poll(t0 + ms(60_000));
    assert_eq!(manager.status().nodes[0].state, NodeState::Ready);
    assert!(
        !manager
            .take_events()
            .iter()
            .any(|event| matches!(event, ManagerEvent::Lost { .. }))
    );
    // Its heartbeat on again: supervised by it again.
    let t1 = t0 + ms(60_100);
    manager.producer_heartbeat_written(id(2), 100, t1);
    let node = manager.status().nodes[0].clone();
    assert_eq!(
        (node.supervision, node.heartbeat_ms, node.reason),
        (Supervision::Heartbeat, 100, None)
    );
    manager.poll(t1 + ms(150));
    assert_eq!(manager.status().nodes[0].state, NodeState::Offline);
}

#[test]
fn a_producer_heartbeat_time_written_during_a_boot_up_is_the_one_it_writes() {
    let t0 = Instant::now();
    let mut manager = Rig::new(config(), Vec::new(), t0);
    manager.node_found(id(2));
    manager.producer_heartbeat_written(id(2), 750, t0);
    let actions = run_boot(&mut manager, t0, |_| SdoOutcome::Done(Vec::new()));
    assert_first_writes_heartbeat_of_2(&actions, 750);
    assert_eq!(manager.status().nodes[0].heartbeat_ms, 750);
}

#[test]
fn a_guarded_node_booted_again_after_its_loss_is_ready_not_lost_again() {
    let t0 = Instant::now();
    let ms = Duration::from_millis;
    let mut description = NodeDescription::new(id(5));
    description.heartbeat_ms = 100;
    description.consume_manager_heartbeat = Some(false);
    description.start = false;
    let no_1017 = |action: &Action| match action {
        Action::Write { index: 0x1017, .. } => {
            SdoOutcome::Aborted(AbortCode::from_raw(0x0601_0002))
        }
        _ => SdoOutcome::Done(Vec::new()),
    };
    let mut manager = Rig::new(config(), vec![description], t0);
    manager.node_found(id(5));
    run_boot(&mut manager, t0, no_1017);
    for at in [100, 200, 300] {
        manager.poll(t0 + ms(at));
    }
    assert_eq!(manager.status().nodes[0].state, NodeState::Offline);
    // The bus was down: booted again, guarded afresh, ready.
    manager.bus_up(false);
    manager.bus_up(true);
    let t1 = t0 + ms(1000);
    run_boot(&mut manager, t1, no_1017);
    // Its first guarding reply (toggle 0): pre-operational, as it should.
    manager.on_frame(&Frame::new(CanId::Standard(0x705), &[0x7F]).unwrap(), t1);
    let node = manager.status().nodes[0].clone();
    assert_eq!(
        (node.state, node.supervision),
        (NodeState::Ready, Supervision::Guarding),
        "{node:?}"
    );
}

/// Node 4, described with a DCF that writes 0x6060 = 1 (profile
/// position), booted and heard operational at `t0`; its 0x1016 has one
/// free entry.
fn booted_drive(t0: Instant) -> Rig {
    let mut description = NodeDescription::new(id(4));
    description.identity.vendor_id = Some(0x4A2);
    description.config = vec![ConfigWrite {
        index: 0x6060,
        sub: 0,
        data: vec![1],
        label: "drive.dcf [6060] Modes of operation".into(),
    }];
    let mut manager = Rig::new(config(), vec![description], t0);
    manager.node_found(id(4));
    let seen = run_boot(&mut manager, t0, answer_drive(500, 0));
    assert!(
        seen.iter()
            .any(|action| matches!(action, Action::Write { index: 0x6060, .. }))
    );
    manager.on_frame(&heartbeat(4, NmtState::Operational), t0);
    manager.poll(t0);
    assert_eq!(manager.status().nodes[0].state, NodeState::Ready);
    manager.take_events();
    manager
}

/// Node 4's answers: vendor 0x4A2, its 0x1017 `heartbeat`, one 0x1016
/// entry holding `consumer`.
fn answer_drive(heartbeat: u16, consumer: u32) -> impl Fn(&Action) -> SdoOutcome {
    move |action| match action {
        Action::Read {
            index: 0x1018,
            sub: 1,
            ..
        } => SdoOutcome::Done(0x4A2u32.to_le_bytes().to_vec()),
        Action::Read { index: 0x1017, .. } => SdoOutcome::Done(heartbeat.to_le_bytes().to_vec()),
        Action::Read {
            index: 0x1016,
            sub: 0,
            ..
        } => SdoOutcome::Done(vec![1]),
        Action::Read { index: 0x1016, .. } => SdoOutcome::Done(consumer.to_le_bytes().to_vec()),
        _ => SdoOutcome::Done(Vec::new()),
    }
}

/// Loses node 4 (no heartbeat for 1 s after `t0`) and hears it again,
/// operational, at the returned time.
fn lose_and_hear_again(manager: &mut Rig, t0: Instant) -> Instant {
    let t1 = t0 + Duration::from_millis(1000);
    manager.poll(t1);
    assert_eq!(manager.status().nodes[0].state, NodeState::Offline);
    manager.on_frame(&heartbeat(4, NmtState::Operational), t1);
    t1
}

#[test]
fn a_node_heard_again_after_a_short_loss_is_resynchronised_not_configured_again() {
    let t0 = Instant::now();
    let mut manager = booted_drive(t0);
    let t1 = lose_and_hear_again(&mut manager, t0);
    // As its boot-up left it: 0x1017 = 500, 0x1016 sub 1 watches the
    // manager (127, 3 × 100 ms).
    let seen = run_boot(&mut manager, t1, answer_drive(500, 0x007F_012C));
    assert_eq!(
        sdo_actions(&seen),
        vec![
            Action::Read {
                node: id(4),
                index: 0x1018,
                sub: 1
            },
            Action::Read {
                node: id(4),
                index: 0x1017,
                sub: 0
            },
            Action::Read {
                node: id(4),
                index: 0x1016,
                sub: 1
            },
        ],
        "nothing written, no NMT start (it is operational)"
    );
    let node = manager.status().nodes[0].clone();
    assert_eq!(
        (node.state, node.supervision, node.boots_ok),
        (NodeState::Ready, Supervision::Heartbeat, 1),
        "{node:?}"
    );
    let events = manager.take_events();
    assert!(
        events.contains(&ManagerEvent::Resynchronised { node: id(4) }),
        "{events:?}"
    );
}

#[test]
fn a_node_that_restarted_unheard_or_sent_its_boot_up_is_configured_again() {
    // Its 0x1017 is back to 0: it restarted while it was not heard.
    let t0 = Instant::now();
    let mut manager = booted_drive(t0);
    let t1 = lose_and_hear_again(&mut manager, t0);
    let seen = run_boot(&mut manager, t1, answer_drive(0, 0));
    assert!(
        seen.iter().any(|action| matches!(
            action,
            Action::Write {
                index: 0x6060,
                data,
                ..
            } if data == &[1]
        )),
        "{seen:?}"
    );
    assert!(manager.take_events().iter().any(|event| matches!(
        event,
        ManagerEvent::BootStarted { why, .. } if why.contains("0x1017 is 0 ms, 500 ms was written")
    )));
    assert_eq!(manager.status().nodes[0].state, NodeState::Ready);

    // A boot-up message: configured again, whatever was lost or not.
    let mut manager = booted_drive(t0);
    manager.on_frame(&heartbeat(4, NmtState::BootUp), t0);
    let seen = run_boot(&mut manager, t0, answer_drive(500, 0x007F_012C));
    assert!(
        seen.iter()
            .any(|action| matches!(action, Action::Write { index: 0x6060, .. })),
        "{seen:?}"
    );
}

#[test]
fn a_resynchronisation_without_answer_is_retried_as_one() {
    let t0 = Instant::now();
    let mut manager = booted_drive(t0);
    let t1 = lose_and_hear_again(&mut manager, t0);
    run_boot(&mut manager, t1, |_| SdoOutcome::Failed("timeout".into()));
    assert_eq!(manager.status().nodes[0].state, NodeState::Offline);
    let t2 = t1 + Duration::from_millis(200);
    manager.on_frame(&heartbeat(4, NmtState::Operational), t2);
    let seen = run_boot(&mut manager, t2, answer_drive(500, 0x007F_012C));
    assert!(
        !seen
            .iter()
            .any(|action| matches!(action, Action::Write { .. })),
        "{seen:?}"
    );
    assert_eq!(manager.status().nodes[0].state, NodeState::Ready);
}

#[test]
fn the_axes_are_stopped_before_the_configuration_writes_motion_objects() {
    let t0 = Instant::now();
    let mut description = NodeDescription::new(id(4));
    description.config = vec![
        ConfigWrite {
            index: 0x1800,
            sub: 5,
            data: vec![250, 0],
            label: "drive.dcf [1800sub5]".into(),
        },
        ConfigWrite {
            index: 0x6060,
            sub: 0,
            data: vec![1],
            label: "drive.dcf [6060]".into(),
        },
        ConfigWrite {
            index: 0x6860,
            sub: 0,
            data: vec![1],
            label: "drive.dcf [6860]".into(),
        },
    ];
    let mut manager = Rig::new(config(), vec![description], t0);
    manager.node_found(id(4));
    let seen = run_boot(&mut manager, t0, answer_drive(500, 0));
    let order: Vec<String> = seen
        .iter()
        .filter_map(|action| match action {
            Action::StopMotion { .. } => Some("stop".to_string()),
            Action::Write { index, .. } if *index == 0x1800 || *index >= 0x6000 => {
                Some(format!("{index:04X}"))
            }
            _ => None,
        })
        .collect();
    assert_eq!(order, ["1800", "stop", "6060", "6860"]);
    manager.on_frame(&heartbeat(4, NmtState::Operational), t0);
    assert_eq!(manager.status().nodes[0].state, NodeState::Ready);

    // Axes that cannot be stopped: nothing of the motion is written, and
    // it is retried.
    let mut description = NodeDescription::new(id(4));
    description.config = vec![ConfigWrite {
        index: 0x6060,
        sub: 0,
        data: vec![1],
        label: "drive.dcf [6060]".into(),
    }];
    let mut manager = Rig::new(config(), vec![description], t0);
    manager.node_found(id(4));
    let seen = run_boot(&mut manager, t0, |action| match action {
        Action::StopMotion { .. } => SdoOutcome::Failed("axis 1 did not stop".into()),
        _ => SdoOutcome::Done(Vec::new()),
    });
    assert!(
        !seen
            .iter()
            .any(|action| matches!(action, Action::Write { index: 0x6060, .. })),
        "{seen:?}"
    );
    let node = manager.status().nodes[0].clone();
    assert_eq!(node.state, NodeState::ConfigFailed, "{node:?}");
    assert_eq!(
        node.reason.as_deref(),
        Some("configuration: axis 1 did not stop")
    );
}

fn nmt_frame(command: u8, node: u8) -> Action {
    Action::Send(Frame::new(CanId::Standard(0), &[command, node]).unwrap())
}

/// Issue 32 finding 2: a node stopped by `000#0201` does no SDO (CiA 301
/// §7.3.2.2), so a boot-up that begins with a read or write cannot end.
/// The boot-up of a node that reports itself stopped begins with NMT enter
/// pre-operational (Lely's master begins with reset communication), and
/// goes on to operational.
#[test]
fn the_boot_up_of_a_stopped_node_brings_it_to_pre_operational_first() {
    let t0 = Instant::now();
    let mut manager = Rig::new(config(), Vec::new(), t0);
    manager.on_frame(&heartbeat(1, NmtState::Stopped), t0);
    let actions = sdo_actions(&manager.poll(t0));
    assert_eq!(
        actions,
        vec![
            nmt_frame(0x80, 1),
            Action::Write {
                node: id(1),
                index: 0x1017,
                sub: 0,
                data: 500u16.to_le_bytes().to_vec(),
            }
        ]
    );
    manager.on_frame(&heartbeat(1, NmtState::PreOperational), t0);
    manager.on_sdo(id(1), SdoOutcome::Done(Vec::new()), t0);
    let rest = run_boot(&mut manager, t0, one_consumer_entry);
    assert_eq!(rest.last(), Some(&nmt_frame(0x01, 1)), "{rest:?}");
    manager.on_frame(&heartbeat(1, NmtState::Operational), t0);
    manager.poll(t0);
    let node = manager.status().nodes[0].clone();
    assert_eq!(
        (node.state, node.nmt.as_str()),
        (NodeState::Ready, "operational")
    );
}

/// Issue 32 finding 2: a stopped node that does not answer is retried
/// after 200 ms, then twice as long each time (docs/network-manager.md),
/// its heartbeats meanwhile (every 100 ms) beginning no boot-up of their
/// own; each try begins with enter pre-operational.
#[test]
fn the_heartbeats_of_a_node_whose_boot_up_failed_do_not_cut_the_backoff_short() {
    let t0 = Instant::now();
    let config = ManagerConfig {
        retry_max: Duration::from_secs(10),
        ..config()
    };
    let mut manager = Rig::new(config, Vec::new(), t0);
    let mut tries = Vec::new();
    for tick in 0..=1300u64 {
        let now = t0 + Duration::from_millis(tick * 10);
        if tick % 10 == 0 {
            manager.on_frame(&heartbeat(1, NmtState::Stopped), now);
        }
        let actions = sdo_actions(&manager.poll(now));
        for (at, action) in actions.iter().enumerate() {
            if let Action::Read { node, .. } | Action::Write { node, .. } = action {
                assert!(
                    at > 0 && actions[at - 1] == nmt_frame(0x80, 1),
                    "a try without enter pre-operational first: {actions:?}"
                );
                tries.push(now);
                manager.on_sdo(*node, SdoOutcome::Failed("SDO timeout".into()), now);
            }
        }
    }
    let gaps: Vec<u128> = tries
        .windows(2)
        .map(|pair| (pair[1] - pair[0]).as_millis())
        .collect();
    assert_eq!(gaps, [200, 400, 800, 1600, 3200, 6400]);
    let node = manager.status().nodes[0].clone();
    assert_eq!(node.state, NodeState::Missing);
    assert_eq!(node.nmt, "stopped");
}

/// Issue 32 finding 11: a node that sent its boot-up message is
/// pre-operational (CiA 301 §7.3.2.1: the boot-up is sent on entering
/// it), never shown `boot_up`; and it is `ready` only once it confirmed
/// the state it should have (operational), not when the start was sent.
#[test]
fn a_booted_node_is_pre_operational_and_ready_only_once_it_says_operational() {
    let t0 = Instant::now();
    let mut manager = Rig::new(config(), Vec::new(), t0);
    manager.on_frame(&heartbeat(1, NmtState::BootUp), t0);
    let node = manager.status().nodes[0].clone();
    assert_eq!(node.nmt, "pre_operational", "{node:?}");
    let seen = run_boot(&mut manager, t0, one_consumer_entry);
    assert_eq!(seen.last(), Some(&nmt_frame(0x01, 1)));
    let node = manager.status().nodes[0].clone();
    assert_eq!(
        (node.state, node.step, node.nmt.as_str()),
        (NodeState::Booting, Step::Start, "pre_operational"),
        "the start is sent, not confirmed: {node:?}"
    );
    assert_eq!(
        node.reason.as_deref(),
        Some("the node reports pre_operational, not yet operational")
    );
    manager.on_frame(&heartbeat(1, NmtState::Operational), t0);
    manager.poll(t0);
    let node = manager.status().nodes[0].clone();
    assert_eq!(
        (node.state, node.step, node.nmt.as_str()),
        (NodeState::Ready, Step::Supervised, "operational")
    );
}

/// A node is not `ready` before the gateway knows what it is (its
/// profile, which says what a client may ask of it): its boot-up begins
/// with the gateway's identification and waits for it; a failed
/// identification is a failed step like any other, retried with the
/// back-off, the machine not `booting` meanwhile.
#[test]
fn a_node_is_ready_only_once_the_gateway_identified_it() {
    let t0 = Instant::now();
    let mut manager = Rig::new(config(), vec![NodeDescription::new(id(4))], t0);
    manager.identifies = false;
    manager.scan_done();
    manager.on_frame(&heartbeat(4, NmtState::BootUp), t0);
    let identify = vec![Action::Identify { node: id(4) }];
    assert_eq!(sdo_actions(&manager.poll(t0)), identify);
    assert!(sdo_actions(&manager.poll(t0)).is_empty(), "it waits");
    let status = manager.status();
    assert_eq!(
        (status.state, status.nodes[0].state, status.nodes[0].step),
        (MachineState::Booting, NodeState::Booting, Step::Identity),
        "{status:?}"
    );

    manager.on_sdo(id(4), SdoOutcome::Failed("0x1000: SDO timeout".into()), t0);
    manager.poll(t0);
    let status = manager.status();
    assert_eq!(status.state, MachineState::Down, "{status:?}");
    assert_eq!(status.nodes[0].state, NodeState::Missing);
    assert_eq!(
        status.nodes[0].reason.as_deref(),
        Some("identity: 0x1000: SDO timeout")
    );
    assert!(matches!(
        manager.take_events().as_slice(),
        [
            ..,
            ManagerEvent::Failed {
                step: Step::Identity,
                retry: Some(_),
                ..
            },
            _
        ]
    ));

    // The retry asks again; identified, the boot-up goes on.
    let t1 = t0 + Duration::from_millis(200);
    assert_eq!(sdo_actions(&manager.poll(t1)), identify);
    manager.on_sdo(id(4), SdoOutcome::Done(Vec::new()), t1);
    let seen = run_boot(&mut manager, t1, one_consumer_entry);
    assert_eq!(seen.last(), Some(&nmt_frame(0x01, 4)));
    manager.on_frame(&heartbeat(4, NmtState::Operational), t1);
    manager.poll(t1);
    let status = manager.status();
    assert_eq!(
        (status.state, status.nodes[0].state),
        (MachineState::Ready, NodeState::Ready),
        "{status:?}"
    );
}

/// Without a description the nodes found are the machine: it is `booting`
/// until the first scan is over (even before any node is heard: the
/// manager does not know yet what is on the bus), and while a node found
/// is on its way; a node that failed does not degrade it, and its retries
/// do not take the machine back to `booting`.
#[test]
fn without_a_description_the_machine_is_ready_once_the_scan_and_every_boot_up_are_over() {
    let t0 = Instant::now();
    let mut manager = Rig::new(config(), Vec::new(), t0);
    manager.identifies = false;
    manager.poll(t0);
    assert_eq!(manager.status().state, MachineState::Booting);
    manager.node_found(id(3));
    manager.scan_done();
    assert_eq!(
        sdo_actions(&manager.poll(t0)),
        vec![Action::Identify { node: id(3) }]
    );
    let status = manager.status();
    assert_eq!(status.state, MachineState::Booting, "{status:?}");
    assert_eq!(status.reasons, ["node 3 is booting (identity)"]);

    manager.on_sdo(id(3), SdoOutcome::Failed("SDO timeout".into()), t0);
    manager.poll(t0);
    let status = manager.status();
    assert_eq!(
        (status.state, status.nodes[0].state),
        (MachineState::Ready, NodeState::Missing),
        "{status:?}"
    );

    let t1 = t0 + Duration::from_millis(200);
    assert_eq!(
        sdo_actions(&manager.poll(t1)),
        vec![Action::Identify { node: id(3) }]
    );
    let status = manager.status();
    assert_eq!(
        (status.state, status.nodes[0].state),
        (MachineState::Ready, NodeState::Booting),
        "a retry does not take the machine back to booting: {status:?}"
    );
    manager.on_sdo(id(3), SdoOutcome::Done(Vec::new()), t1);
    run_boot(&mut manager, t1, one_consumer_entry);
    manager.on_frame(&heartbeat(3, NmtState::Operational), t1);
    manager.poll(t1);
    let status = manager.status();
    assert_eq!(
        (status.state, status.nodes[0].state),
        (MachineState::Ready, NodeState::Ready),
        "{status:?}"
    );
}
