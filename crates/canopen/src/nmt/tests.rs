use super::*;

fn node(id: u8) -> NodeId {
    NodeId::new(id).unwrap()
}

fn nmt(data: &[u8]) -> Frame {
    Frame::new(CanId::Standard(0), data).unwrap()
}

#[test]
fn command_codes_and_names() {
    let table = [
        (NmtCommand::Start, 0x01, "start"),
        (NmtCommand::Stop, 0x02, "stop"),
        (NmtCommand::EnterPreOperational, 0x80, "pre_operational"),
        (NmtCommand::ResetNode, 0x81, "reset_node"),
        (NmtCommand::ResetCommunication, 0x82, "reset_communication"),
    ];
    for (command, raw, name) in table {
        assert_eq!(command.raw(), raw);
        assert_eq!(NmtCommand::from_raw(raw), command);
        assert_eq!(command.name(), name);
        assert_eq!(name.parse::<NmtCommand>(), Ok(command));
        assert_eq!(command.to_string(), name);
    }
    assert_eq!(NmtCommand::from_raw(0x03), NmtCommand::Unknown(0x03));
    assert_eq!(NmtCommand::Unknown(0x03).raw(), 0x03);
    assert_eq!(NmtCommand::Unknown(0x03).to_string(), "unknown (0x03)");
    // The command line spells them with hyphens.
    assert_eq!(
        "reset-communication".parse::<NmtCommand>(),
        Ok(NmtCommand::ResetCommunication)
    );
    assert_eq!(
        "Pre-Operational".parse::<NmtCommand>(),
        Ok(NmtCommand::EnterPreOperational)
    );
    assert!("unknown".parse::<NmtCommand>().is_err());
    assert!("go".parse::<NmtCommand>().unwrap_err().contains("'go'"));
}

#[test]
fn states_and_their_heartbeat_bytes() {
    let table = [
        (NmtState::BootUp, 0x00, "boot_up"),
        (NmtState::Stopped, 0x04, "stopped"),
        (NmtState::Operational, 0x05, "operational"),
        (NmtState::PreOperational, 0x7F, "pre_operational"),
    ];
    for (state, raw, name) in table {
        assert_eq!(state.raw(), raw);
        assert_eq!(NmtState::from_raw(raw), state);
        assert_eq!(state.name(), name);
    }
    assert_eq!(NmtState::from_raw(0x50), NmtState::Unknown(0x50));
    assert_eq!(NmtState::Unknown(0x50).raw(), 0x50);
    assert_eq!(NmtState::Unknown(0x50).name(), "unknown");
    for raw in 0..=u8::MAX {
        assert_eq!(NmtState::from_raw(raw).raw(), raw);
        assert_eq!(NmtCommand::from_raw(raw).raw(), raw);
    }
}

#[test]
fn command_targets_are_the_states_of_figure_48() {
    assert_eq!(
        NmtCommand::Start.target_state(),
        Some(NmtState::Operational)
    );
    assert_eq!(NmtCommand::Stop.target_state(), Some(NmtState::Stopped));
    assert_eq!(
        NmtCommand::EnterPreOperational.target_state(),
        Some(NmtState::PreOperational)
    );
    assert_eq!(NmtCommand::ResetNode.target_state(), Some(NmtState::BootUp));
    assert_eq!(
        NmtCommand::ResetCommunication.target_state(),
        Some(NmtState::BootUp)
    );
    assert_eq!(NmtCommand::Unknown(9).target_state(), None);
}

#[test]
fn services_allowed_per_state_follow_figure_3_9() {
    use NmtService::*;
    let services = [
        Pdo,
        Sdo,
        Sync,
        Emcy,
        Time,
        NodeGuarding,
        Heartbeat,
        BootUp,
        Nmt,
    ];
    let allowed = |state: NmtState| -> Vec<NmtService> {
        services
            .into_iter()
            .filter(|&service| state.allows(service))
            .collect()
    };
    assert_eq!(
        allowed(NmtState::PreOperational),
        [Sdo, Sync, Emcy, Time, NodeGuarding, Heartbeat, Nmt]
    );
    assert_eq!(
        allowed(NmtState::Operational),
        [Pdo, Sdo, Sync, Emcy, Time, NodeGuarding, Heartbeat, Nmt]
    );
    assert_eq!(allowed(NmtState::Stopped), [NodeGuarding, Heartbeat, Nmt]);
    assert_eq!(allowed(NmtState::BootUp), [BootUp]);
    assert_eq!(allowed(NmtState::Unknown(0x50)), []);
}

#[test]
fn nmt_frames_encode_byte_exact() {
    let start_5 = NmtMessage::new(NmtCommand::Start, NmtTarget::Node(node(5))).encode();
    assert_eq!(start_5.to_string(), "000#0105");
    let reset_all = NmtMessage::new(NmtCommand::ResetNode, NmtTarget::All).encode();
    assert_eq!(reset_all.to_string(), "000#8100");
    let pre_127 = NmtMessage::new(NmtCommand::EnterPreOperational, NmtTarget::Node(node(127)));
    assert_eq!(pre_127.encode().to_string(), "000#807F");
    assert_eq!(NmtMessage::decode(&pre_127.encode()), Ok(pre_127));
    assert_eq!(boot_up_frame(node(0x22)).to_string(), "722#00");
}

#[test]
fn nmt_frames_decode_and_reject_malformed_ones() {
    assert_eq!(
        NmtMessage::decode(&nmt(&[0x02, 0x00])),
        Ok(NmtMessage::new(NmtCommand::Stop, NmtTarget::All))
    );
    assert_eq!(
        NmtMessage::decode(&nmt(&[0x82, 0x0A])),
        Ok(NmtMessage::new(
            NmtCommand::ResetCommunication,
            NmtTarget::Node(node(10))
        ))
    );
    assert_eq!(
        NmtMessage::decode(&nmt(&[0x42, 0x01])),
        Ok(NmtMessage::new(
            NmtCommand::Unknown(0x42),
            NmtTarget::Node(node(1))
        ))
    );
    assert_eq!(NmtMessage::decode(&nmt(&[0x01])), Err(NmtError::Length(1)));
    assert_eq!(NmtMessage::decode(&nmt(&[])), Err(NmtError::Length(0)));
    assert_eq!(
        NmtMessage::decode(&nmt(&[0x01, 0x05, 0x00])),
        Err(NmtError::Length(3))
    );
    assert_eq!(
        NmtMessage::decode(&nmt(&[0x01, 0x80])),
        Err(NmtError::NodeId(0x80))
    );
    assert_eq!(
        NmtMessage::decode(&Frame::remote(CanId::Standard(0), 2).unwrap()),
        Err(NmtError::Remote)
    );
    let elsewhere = Frame::new(CanId::Standard(0x001), &[1, 5]).unwrap();
    assert_eq!(
        NmtMessage::decode(&elsewhere),
        Err(NmtError::NotNmt(CanId::Standard(1)))
    );
    let extended = Frame::new(CanId::Extended(0), &[1, 5]).unwrap();
    assert_eq!(
        NmtMessage::decode(&extended),
        Err(NmtError::NotNmt(CanId::Extended(0)))
    );
    assert_eq!(
        NmtError::Length(3).to_string(),
        "an NMT command has 2 data bytes, not 3"
    );
}

#[test]
fn a_slave_boots_into_pre_operational_and_follows_commands() {
    let mut slave = NmtSlave::new(node(5));
    assert_eq!(slave.state(), NmtState::BootUp);
    assert!(slave.allows(NmtService::BootUp));
    // Not on the network yet: commands are ignored while initialising.
    assert_eq!(slave.on_frame(&nmt(&[0x01, 0x05])), Ok(None));
    assert_eq!(slave.boot_up().to_string(), "705#00");
    assert_eq!(slave.state(), NmtState::PreOperational);
    assert!(!slave.allows(NmtService::Pdo));

    assert_eq!(
        slave.on_frame(&nmt(&[0x01, 0x05])),
        Ok(Some(NmtEvent::StateChanged {
            from: NmtState::PreOperational,
            to: NmtState::Operational
        }))
    );
    assert!(slave.allows(NmtService::Pdo));
    // Again: already operational, nothing changes.
    assert_eq!(slave.on_frame(&nmt(&[0x01, 0x00])), Ok(None));
    // Another node's command.
    assert_eq!(slave.on_frame(&nmt(&[0x02, 0x06])), Ok(None));
    assert_eq!(
        slave.on_frame(&nmt(&[0x02, 0x00])),
        Ok(Some(NmtEvent::StateChanged {
            from: NmtState::Operational,
            to: NmtState::Stopped
        }))
    );
    assert!(!slave.allows(NmtService::Sdo));
    assert!(slave.allows(NmtService::Heartbeat));
    // Stopped straight to operational is allowed.
    assert_eq!(
        slave.on_frame(&nmt(&[0x01, 0x05])),
        Ok(Some(NmtEvent::StateChanged {
            from: NmtState::Stopped,
            to: NmtState::Operational
        }))
    );
    assert_eq!(
        slave.on_frame(&nmt(&[0x80, 0x05])),
        Ok(Some(NmtEvent::StateChanged {
            from: NmtState::Operational,
            to: NmtState::PreOperational
        }))
    );
    // Unknown commands change nothing.
    assert_eq!(slave.on_frame(&nmt(&[0x03, 0x05])), Ok(None));
    assert_eq!(slave.state(), NmtState::PreOperational);
}

#[test]
fn resets_are_reported_and_end_in_a_new_boot_up() {
    let mut slave = NmtSlave::new(node(5));
    let _ = slave.boot_up();
    let _ = slave.on_frame(&nmt(&[0x01, 0x00]));
    assert_eq!(
        slave.on_frame(&nmt(&[0x82, 0x05])),
        Ok(Some(NmtEvent::ResetCommunication))
    );
    assert_eq!(slave.state(), NmtState::BootUp);
    assert!(!slave.allows(NmtService::Sdo));
    assert_eq!(slave.boot_up().to_string(), "705#00");
    assert_eq!(slave.state(), NmtState::PreOperational);

    let _ = slave.on_frame(&nmt(&[0x02, 0x00]));
    // A reset is obeyed in stopped too.
    assert_eq!(
        slave.on_frame(&nmt(&[0x81, 0x00])),
        Ok(Some(NmtEvent::ResetNode))
    );
    assert_eq!(slave.state(), NmtState::BootUp);
}

#[test]
fn a_slave_reports_malformed_nmt_frames_and_passes_others() {
    let mut slave = NmtSlave::new(node(5));
    let _ = slave.boot_up();
    assert_eq!(slave.on_frame(&nmt(&[0x01])), Err(NmtError::Length(1)));
    assert_eq!(slave.state(), NmtState::PreOperational);
    let sdo = Frame::new(CanId::Standard(0x605), &[0x40, 0, 0x10, 0, 0, 0, 0, 0]).unwrap();
    assert_eq!(slave.on_frame(&sdo), Ok(None));
}
