use super::*;
use socketcan_rs::{CanDataFrame, CanErrorFrame, CanRemoteFrame};

fn std_id(raw: u32) -> CanId {
    CanId::standard(raw).unwrap()
}

fn ext_id(raw: u32) -> CanId {
    CanId::extended(raw).unwrap()
}

/// The `can_id` word, length and data bytes of a classic frame.
fn classic_raw(frame: &CanAnyFrame) -> (u32, u8, [u8; 8]) {
    let raw = match frame {
        CanAnyFrame::Normal(f) => *f.as_ref(),
        CanAnyFrame::Remote(f) => *f.as_ref(),
        CanAnyFrame::Error(f) => *f.as_ref(),
        CanAnyFrame::Fd(_) => panic!("expected a classic frame, got {frame:?}"),
    };
    (raw.can_id, raw.can_dlc, raw.data)
}

fn round_trip(frame: Frame) -> CanAnyFrame {
    let raw = to_socketcan(&frame);
    assert_eq!(from_socketcan(&raw), Ok(frame), "{frame} via {raw:X}");
    raw
}

#[test]
fn data_frames_convert_with_identifiers_at_their_limits() {
    let cases = [
        (std_id(0), 0x0000_0000),
        (std_id(0x7FF), 0x0000_07FF),
        (ext_id(0), 0x8000_0000),
        (ext_id(0x7FF), 0x8000_07FF),
        (ext_id(0x1FFF_FFFF), 0x9FFF_FFFF),
    ];
    for (id, word) in cases {
        let raw = round_trip(Frame::new(id, &[0xA5]).unwrap());
        assert!(matches!(raw, CanAnyFrame::Normal(_)));
        assert_eq!(classic_raw(&raw), (word, 1, [0xA5, 0, 0, 0, 0, 0, 0, 0]));
    }
}

#[test]
fn data_frames_convert_with_zero_to_eight_bytes() {
    for len in 0..=8usize {
        let data: Vec<u8> = (1..=len as u8).collect();
        let raw = round_trip(Frame::new(std_id(0x123), &data).unwrap());
        let mut expected = [0u8; 8];
        expected[..len].copy_from_slice(&data);
        assert_eq!(classic_raw(&raw), (0x123, len as u8, expected));
    }
}

#[test]
fn remote_frames_keep_their_dlc_and_rtr_flag() {
    for dlc in 0..=8u8 {
        let raw = round_trip(Frame::remote(std_id(0x701), dlc).unwrap());
        assert!(matches!(raw, CanAnyFrame::Remote(_)));
        assert_eq!(classic_raw(&raw), (0x4000_0701, dlc, [0; 8]));
    }
    let raw = round_trip(Frame::remote(ext_id(0x1FFF_FFFF), 4).unwrap());
    assert_eq!(classic_raw(&raw), (0xDFFF_FFFF, 4, [0; 8]));
    let parsed = CanRemoteFrame::new_remote(socketcan_rs::StandardId::MAX, 8).unwrap();
    assert_eq!(
        from_socketcan(&CanAnyFrame::Remote(parsed)),
        Frame::remote(std_id(0x7FF), 8)
    );
}

#[test]
fn fd_frames_keep_flags_and_sixty_four_bytes() {
    let data: Vec<u8> = (0..64).collect();
    let flag_cases = [
        (false, false, 0x04),
        (true, false, 0x05),
        (false, true, 0x06),
        (true, true, 0x07),
    ];
    for (brs, esi, raw_flags) in flag_cases {
        let frame = Frame::fd(ext_id(0x1FFF_FFFF), &data, FdFlags { brs, esi }).unwrap();
        let raw = round_trip(frame);
        let CanAnyFrame::Fd(fd) = raw else {
            panic!("expected an FD frame, got {raw:?}");
        };
        let inner = fd.as_ref();
        assert_eq!(
            (inner.can_id, inner.len, inner.flags),
            (0x9FFF_FFFF, 64, raw_flags)
        );
        assert_eq!(&inner.data[..], &data[..]);
    }
    let short = round_trip(Frame::fd(std_id(0x7FF), &[1, 2, 3], FdFlags::default()).unwrap());
    let CanAnyFrame::Fd(fd) = short else {
        panic!("expected an FD frame");
    };
    assert_eq!((fd.as_ref().can_id, fd.as_ref().len), (0x7FF, 3));
    assert_eq!(&fd.as_ref().data[..4], &[1, 2, 3, 0]);
    for len in super::super::frame::FD_LENGTHS {
        round_trip(Frame::fd(std_id(1), &vec![0xEE; len], FdFlags::default()).unwrap());
    }
}

#[test]
fn error_frames_carry_class_bits_under_the_error_flag() {
    let details = [1, 0x10, 0, 0, 0, 0, 0x7F, 0x80];
    let raw = round_trip(Frame::error(0x004, details).unwrap());
    assert!(matches!(raw, CanAnyFrame::Error(_)));
    assert_eq!(classic_raw(&raw), (0x2000_0004, 8, details));
    let raw = round_trip(Frame::error(0x1FFF_FFFF, [0xFF; 8]).unwrap());
    assert_eq!(classic_raw(&raw), (0x3FFF_FFFF, 8, [0xFF; 8]));

    // As the kernel delivers it: fewer than eight bytes are padded.
    let kernel = CanErrorFrame::new_error(CAN_ERR_BUSOFF, &[]).unwrap();
    assert_eq!(
        from_socketcan(&CanAnyFrame::Error(kernel)),
        Frame::error(0x40, [0; 8])
    );
}

#[test]
fn frames_built_by_the_crate_convert_to_ours() {
    let data = CanDataFrame::new(socketcan_rs::ExtendedId::new(0x123).unwrap(), &[9, 8]).unwrap();
    assert_eq!(
        from_socketcan(&CanAnyFrame::Normal(data)),
        Frame::new(ext_id(0x123), &[9, 8])
    );
    let fd = CanFdFrame::with_flags(
        socketcan_rs::StandardId::new(0x10).unwrap(),
        &[1; 10],
        socketcan_rs::id::FdFlags::BRS,
    )
    .unwrap();
    // The crate pads 10 bytes to the next FD length, 12.
    let mut padded = [1u8; 12];
    padded[10..].fill(0);
    assert_eq!(
        from_socketcan(&CanAnyFrame::Fd(fd)),
        Frame::fd(
            std_id(0x10),
            &padded,
            FdFlags {
                brs: true,
                esi: false
            }
        )
    );
}

fn crtl(status: u8) -> Frame {
    Frame::error(CAN_ERR_CRTL, [0, status, 0, 0, 0, 0, 0, 0]).unwrap()
}

fn change(frame: &Frame, current: BusState) -> Option<(BusState, String)> {
    bus_state_after_error(frame, current).map(|s| (s.state, s.reason.unwrap_or_default()))
}

#[test]
fn error_class_constants_match_linux_can_error_h() {
    assert_eq!(CAN_ERR_CRTL, 0x04);
    assert_eq!(CAN_ERR_BUSOFF, 0x40);
    assert_eq!(CAN_ERR_RESTARTED, 0x100);
    assert_eq!(ControllerProblems::RX_WARNING.bits(), 0x04);
    assert_eq!(ControllerProblems::TX_WARNING.bits(), 0x08);
    assert_eq!(ControllerProblems::RX_PASSIVE.bits(), 0x10);
    assert_eq!(ControllerProblems::TX_PASSIVE.bits(), 0x20);
    assert_eq!(ControllerProblems::ACTIVE.bits(), 0x40);
}

#[test]
fn bus_off_is_reported_from_any_connected_state() {
    let frame = Frame::error(CAN_ERR_BUSOFF, [0; 8]).unwrap();
    for current in [BusState::Up, BusState::ErrorPassive] {
        let (state, reason) = change(&frame, current).unwrap();
        assert_eq!(state, BusState::BusOff);
        assert_eq!(reason, "controller is bus-off (too many transmit errors)");
    }
    assert_eq!(change(&frame, BusState::BusOff), None);
}

#[test]
fn a_restart_brings_a_bus_off_controller_back_up() {
    let frame = Frame::error(CAN_ERR_RESTARTED, [0; 8]).unwrap();
    assert_eq!(
        change(&frame, BusState::BusOff),
        Some((BusState::Up, "controller restarted after bus-off".into()))
    );
    assert_eq!(change(&frame, BusState::Up), None);
}

#[test]
fn passive_bits_make_the_bus_error_passive_naming_the_direction() {
    let cases = [
        (0x20, "controller is error passive (transmit errors)"),
        (0x10, "controller is error passive (receive errors)"),
        (
            0x30,
            "controller is error passive (transmit and receive errors)",
        ),
        // Passive outranks a warning bit in the same frame.
        (0x28, "controller is error passive (transmit errors)"),
    ];
    for (status, reason) in cases {
        for current in [BusState::Up, BusState::BusOff] {
            assert_eq!(
                change(&crtl(status), current),
                Some((BusState::ErrorPassive, reason.into())),
                "status 0x{status:02X} from {current:?}"
            );
        }
        assert_eq!(change(&crtl(status), BusState::ErrorPassive), None);
    }
}

#[test]
fn active_and_warning_bits_mean_error_active() {
    assert_eq!(
        change(&crtl(0x40), BusState::ErrorPassive),
        Some((BusState::Up, "controller is error active again".into()))
    );
    assert_eq!(
        change(&crtl(0x40), BusState::BusOff),
        Some((BusState::Up, "controller is error active again".into()))
    );
    let warnings = [
        (
            0x08,
            "controller is error active at warning level (transmit errors)",
        ),
        (
            0x04,
            "controller is error active at warning level (receive errors)",
        ),
        (
            0x0C,
            "controller is error active at warning level (transmit and receive errors)",
        ),
    ];
    for (status, reason) in warnings {
        assert_eq!(
            change(&crtl(status), BusState::ErrorPassive),
            Some((BusState::Up, reason.into()))
        );
        // Already error active: nothing changes.
        assert_eq!(change(&crtl(status), BusState::Up), None);
    }
}

#[test]
fn frames_that_say_nothing_about_the_state_change_nothing() {
    // Overflow bits only, and CAN_ERR_CRTL_UNSPEC.
    assert_eq!(change(&crtl(0x01), BusState::Up), None);
    assert_eq!(change(&crtl(0x02), BusState::ErrorPassive), None);
    assert_eq!(change(&crtl(0x00), BusState::BusOff), None);
    // Lost arbitration, protocol violation, no ACK, bus error.
    for class in [0x02, 0x08, 0x20, 0x80] {
        let frame = Frame::error(class, [0xFF; 8]).unwrap();
        assert_eq!(change(&frame, BusState::Up), None, "class 0x{class:X}");
    }
    let data = Frame::new(std_id(0x40), &[0, 0x20]).unwrap();
    assert_eq!(change(&data, BusState::Up), None);
}

#[test]
fn bus_off_outranks_everything_in_the_same_frame() {
    let frame = Frame::error(
        CAN_ERR_BUSOFF | CAN_ERR_RESTARTED | CAN_ERR_CRTL,
        [0, 0x40, 0, 0, 0, 0, 0, 0],
    )
    .unwrap();
    assert_eq!(
        change(&frame, BusState::Up).map(|(state, _)| state),
        Some(BusState::BusOff)
    );
}

#[test]
fn a_down_bus_is_not_revived_by_error_frames() {
    for frame in [
        Frame::error(CAN_ERR_RESTARTED, [0; 8]).unwrap(),
        Frame::error(CAN_ERR_BUSOFF, [0; 8]).unwrap(),
        crtl(0x40),
        crtl(0x20),
    ] {
        assert_eq!(change(&frame, BusState::Down), None, "{frame}");
    }
}

/// An error frame as the kernel hands it over: `struct can_frame` with
/// `CAN_ERR_FLAG | class` in can_id and the eight detail bytes.
fn kernel_error(class: u32, data: [u8; 8]) -> Frame {
    let raw = CanErrorFrame::new_error(class, &data).unwrap();
    from_socketcan(&CanAnyFrame::Error(raw)).unwrap()
}

#[test]
fn error_passive_with_counters_is_read_byte_for_byte() {
    // CAN_ERR_CRTL | CAN_ERR_CNT, data[1] CAN_ERR_CRTL_TX_PASSIVE, data[6]
    // TEC 136, data[7] REC 5: what mcp251xfd and flexcan send.
    let frame = kernel_error(0x204, [0, 0x20, 0, 0, 0, 0, 136, 5]);
    let report = error_frame_report(&frame, BusState::Up);
    assert_eq!(
        report.status,
        Some(BusStatus::new(
            BusState::ErrorPassive,
            "controller is error passive (transmit errors)"
        ))
    );
    assert_eq!(report.counters, Some(ErrorCounters { tec: 136, rec: 5 }));
    // RX passive: REC 128 in data[7].
    let frame = kernel_error(0x204, [0, 0x10, 0, 0, 0, 0, 0, 128]);
    let report = error_frame_report(&frame, BusState::Up);
    assert_eq!(report.status.map(|s| s.state), Some(BusState::ErrorPassive));
    assert_eq!(report.counters, Some(ErrorCounters { tec: 0, rec: 128 }));
}

#[test]
fn bus_off_and_restart_are_read_with_the_counters_they_carry() {
    // CAN_ERR_BUSOFF | CAN_ERR_CNT: TEC 255 is what a byte can say of 256+.
    let frame = kernel_error(0x240, [0, 0, 0, 0, 0, 0, 255, 0]);
    let report = error_frame_report(&frame, BusState::ErrorPassive);
    assert_eq!(report.status.map(|s| s.state), Some(BusState::BusOff));
    assert_eq!(report.counters, Some(ErrorCounters { tec: 255, rec: 0 }));
    // CAN_ERR_BUSOFF alone (older drivers): the state, no counters.
    let report = error_frame_report(&kernel_error(0x40, [0; 8]), BusState::Up);
    assert_eq!(report.status.map(|s| s.state), Some(BusState::BusOff));
    assert_eq!(report.counters, None);
    // CAN_ERR_RESTARTED: back up, the controller's counters start at 0.
    let report = error_frame_report(&kernel_error(0x100, [0; 8]), BusState::BusOff);
    assert_eq!(report.status.map(|s| s.state), Some(BusState::Up));
    assert_eq!(report.counters, Some(ErrorCounters { tec: 0, rec: 0 }));
    // Back to error active (CAN_ERR_CRTL_ACTIVE) with counters.
    let frame = kernel_error(0x204, [0, 0x40, 0, 0, 0, 0, 90, 3]);
    let report = error_frame_report(&frame, BusState::ErrorPassive);
    assert_eq!(report.status.map(|s| s.state), Some(BusState::Up));
    assert_eq!(report.counters, Some(ErrorCounters { tec: 90, rec: 3 }));
}

#[test]
fn protocol_errors_and_data_frames_report_nothing_about_the_controller() {
    // CAN_ERR_PROT | CAN_ERR_BUSERROR, a stuff error: what the virtual hub
    // sends the others when a node's frame meets a bit error.
    let frame = kernel_error(0x88, [0, 0, 0x04, 0, 0, 0, 0, 0]);
    assert_eq!(
        error_frame_report(&frame, BusState::Up),
        ErrorFrameReport::default()
    );
    assert_eq!(frame, crate::hub::bit_error_frame());
    let data = Frame::new(std_id(0x204), &[0, 0x20, 0, 0, 0, 0, 136, 5]).unwrap();
    assert_eq!(
        error_frame_report(&data, BusState::Up),
        ErrorFrameReport::default()
    );
    assert_eq!(CAN_ERR_CNT, 0x200);
}
