//! Byte-exact tests of the socketcand codec, malformed input included.

use proptest::prelude::*;

use super::*;
use crate::frame::FD_LENGTHS;

fn tokens(input: &[u8]) -> Vec<Token> {
    let mut framer = Framer::default();
    let mut out = Vec::new();
    framer.push(input, &mut out);
    out
}

fn msg(text: &str) -> Token {
    Token::Message(text.into())
}

fn std_frame(id: u16, data: &[u8]) -> Frame {
    Frame::new(CanId::Standard(id), data).unwrap()
}

#[test]
fn framer_cuts_messages_without_separators() {
    assert_eq!(
        tokens(b"< hi >< open can0 ><rawmode>"),
        vec![msg("hi"), msg("open can0"), msg("rawmode")]
    );
    // White space and newlines between messages are not garbage.
    assert_eq!(
        tokens(b"  < echo >\r\n\t< echo >\n"),
        vec![msg("echo"), msg("echo")]
    );
}

#[test]
fn framer_joins_messages_split_across_reads() {
    let mut framer = Framer::default();
    let mut out = Vec::new();
    for chunk in [&b"< se"[..], b"nd 12", b"3 1 A", b"A >< ec", b"ho >"] {
        framer.push(chunk, &mut out);
    }
    assert_eq!(out, vec![msg("send 123 1 AA"), msg("echo")]);
    assert_eq!(framer.pending(), 0);
}

#[test]
fn framer_reports_garbage_once_per_run() {
    assert_eq!(
        tokens(b"hello world\n< echo >junk"),
        vec![
            Token::Garbage { bytes: 12 },
            msg("echo"),
            Token::Garbage { bytes: 4 }
        ]
    );
    // A stray '>' outside a message is garbage too.
    assert_eq!(
        tokens(b"> <echo>"),
        vec![Token::Garbage { bytes: 2 }, msg("echo")]
    );
}

#[test]
fn framer_reports_a_message_cut_by_a_new_open_bracket() {
    assert_eq!(
        tokens(b"< send 123 <echo>"),
        vec![Token::Truncated("send 123".into()), msg("echo")]
    );
}

#[test]
fn framer_skips_oversized_messages_with_bounded_memory() {
    let mut framer = Framer::new(16);
    let mut out = Vec::new();
    let mut input = b"< ".to_vec();
    input.extend(std::iter::repeat_n(b'A', 10_000));
    input.extend_from_slice(b" >< echo >");
    framer.push(&input, &mut out);
    assert_eq!(out, vec![Token::Oversized { bytes: 10_004 }, msg("echo")]);
    assert!(framer.pending() <= 16);
}

#[test]
fn framer_skips_messages_with_non_ascii_bytes() {
    assert_eq!(
        tokens(b"< send \xff\x00 ><echo>"),
        vec![Token::NotAscii, msg("echo")]
    );
}

#[test]
fn framer_keeps_an_unfinished_message_for_the_next_read() {
    let mut framer = Framer::default();
    let mut out = Vec::new();
    framer.push(b"< send 123", &mut out);
    assert!(out.is_empty());
    assert_eq!(framer.pending(), " send 123".len());
}

#[test]
fn commands_parse_as_socketcand_reads_them() {
    let cases: Vec<(&str, Command)> = vec![
        ("open can0", Command::Open("can0".into())),
        ("rawmode", Command::RawMode),
        ("bcmmode", Command::BcmMode),
        ("echo", Command::Echo),
        ("send 123 0", Command::Send(std_frame(0x123, &[]))),
        (
            "send 7FF 8 1 2 3 4 5 6 7 ff",
            Command::Send(std_frame(0x7FF, &[1, 2, 3, 4, 5, 6, 7, 0xFF])),
        ),
        // Eight digits: extended, whatever the value.
        (
            "send 1AAAAAAA 2 1 F1",
            Command::Send(Frame::new(CanId::Extended(0x1AAA_AAAA), &[1, 0xF1]).unwrap()),
        ),
        (
            "send 00000123 1 0",
            Command::Send(Frame::new(CanId::Extended(0x123), &[0]).unwrap()),
        ),
        // python-can writes lower-case bytes without padding.
        (
            "send 601 2 2f a",
            Command::Send(std_frame(0x601, &[0x2F, 0x0A])),
        ),
        (
            "sendrtr 701 1",
            Command::Send(Frame::remote(CanId::Standard(0x701), 1).unwrap()),
        ),
        (
            "fdsend 123 01 12 0 1 2 3 4 5 6 7 8 9 A B",
            Command::Send(
                Frame::fd(
                    CanId::Standard(0x123),
                    &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 0xA, 0xB],
                    FdFlags::from_raw(1),
                )
                .unwrap(),
            ),
        ),
        (
            "subscribe 0 0 123",
            Command::Unsupported("subscribe".into()),
        ),
    ];
    for (text, expected) in cases {
        assert_eq!(parse_command(text), Ok(expected), "{text}");
    }
}

#[test]
fn malformed_commands_say_what_is_wrong() {
    let cases = [
        ("", "empty message"),
        ("frobnicate 1 2", "unknown command 'frobnicate'"),
        ("open", "open: expected '< open CHANNEL >'"),
        ("open a b", "open: expected '< open CHANNEL >'"),
        (
            "open abcdefghijklmnopq",
            "open: channel names have at most 16 characters",
        ),
        ("rawmode now", "mode: 'rawmode' takes no arguments"),
        ("send", "send: expected '< send ID LEN B0 B1 ... >'"),
        ("send 123", "send: expected '< send ID LEN B0 B1 ... >'"),
        ("send xyz 0", "send: identifier 'xyz' is not hex"),
        (
            "send 123456789 0",
            "send: identifier '123456789' is not 1 to 8 hex digits",
        ),
        ("send 800 0", "standard CAN identifier 0x800 is above 0x7FF"),
        (
            "send 20000000 0",
            "extended CAN identifier 0x20000000 is above 0x1FFFFFFF",
        ),
        (
            "send 123 9 1 2 3 4 5 6 7 8 9",
            "send: length '9' is not 0 to 8",
        ),
        ("send 123 -1", "send: length '-1' is not 0 to 8"),
        (
            "send 123 2 1",
            "send: length says 2 data bytes but 1 follow",
        ),
        (
            "send 123 1 1 2",
            "send: length says 1 data bytes but 2 follow",
        ),
        (
            "send 123 1 100",
            "send: data byte '100' is not 1 or 2 hex digits",
        ),
        ("send 123 1 zz", "send: data byte 'zz' is not hex"),
        ("sendrtr 123", "sendrtr: expected '< sendrtr ID DLC >'"),
        ("sendrtr 123 9", "sendrtr: length '9' is not 0 to 8"),
        (
            "fdsend 123 0 10 0 0 0 0 0 0 0 0 0 0",
            "a CAN FD frame carries 0-8, 12, 16, 20, 24, 32, 48 or 64 data bytes, not 10",
        ),
        ("fdsend 123 0 65", "fdsend: length '65' is not 0 to 64"),
    ];
    for (text, expected) in cases {
        let err = parse_command(text).expect_err(text);
        assert_eq!(err.to_string(), expected, "{text}");
    }
}

#[test]
fn frames_are_written_byte_for_byte_as_socketcand_does() {
    let ts = Timestamp(1_436_509_052_249_713);
    let cases = [
        (
            std_frame(0x123, &[0x11, 0x22, 0x33, 0x44]),
            "< frame 123 1436509052.249713 11223344 >",
        ),
        // No data: two spaces, exactly as socketcand's sprintf sequence gives.
        (std_frame(0x5, &[]), "< frame 005 1436509052.249713  >"),
        (
            Frame::new(CanId::Extended(0x1ABCDEF), &[0xFF; 8]).unwrap(),
            "< frame 01ABCDEF 1436509052.249713 FFFFFFFFFFFFFFFF >",
        ),
        // A remote frame: python-can's parser (split into at most four
        // fields, the third the data) reads a frame without data, with no
        // warning; candeck reads `rtr DLC`.
        (
            Frame::remote(CanId::Standard(0x701), 1).unwrap(),
            "< frame 701 1436509052.249713  rtr 1 >",
        ),
        (
            Frame::fd(CanId::Standard(0x10), &[1, 2], FdFlags::from_raw(3)).unwrap(),
            "< fdframe 010 03 1436509052.249713 0102 >",
        ),
        (
            Frame::error(0x40, [0; 8]).unwrap(),
            "< error 040 1436509052.249713 >",
        ),
    ];
    for (frame, expected) in cases {
        let mut out = Vec::new();
        write_frame(&mut out, &frame, ts);
        assert_eq!(String::from_utf8(out).unwrap(), expected);
    }
    let mut out = Vec::new();
    write_frame(&mut out, &std_frame(1, &[]), Timestamp(7));
    assert_eq!(out, b"< frame 001 0.000007  >");
}

#[test]
fn send_commands_are_written_as_socketcand_reads_them() {
    let cases = [
        (std_frame(0x123, &[]), "< send 123 0 >"),
        (
            std_frame(0x601, &[0x40, 0x00, 0x10, 0x00]),
            "< send 601 4 40 00 10 00 >",
        ),
        (
            Frame::new(CanId::Extended(0x1AAA_AAAA), &[1, 0xF1]).unwrap(),
            "< send 1AAAAAAA 2 01 F1 >",
        ),
        (
            Frame::remote(CanId::Standard(0x701), 0).unwrap(),
            "< sendrtr 701 0 >",
        ),
        (
            Frame::fd(CanId::Standard(0x1), &[0xAB; 12], FdFlags::from_raw(1)).unwrap(),
            "< fdsend 001 01 12 AB AB AB AB AB AB AB AB AB AB AB AB >",
        ),
    ];
    for (frame, expected) in cases {
        let mut out = Vec::new();
        write_send(&mut out, &frame).unwrap();
        assert_eq!(String::from_utf8(out).unwrap(), expected);
    }
    let mut out = Vec::new();
    assert_eq!(
        write_send(&mut out, &Frame::error(1, [0; 8]).unwrap()),
        Err(CannotSendErrorFrame)
    );
    assert!(out.is_empty());
}

#[test]
fn replies_are_written_exactly_and_error_text_is_made_safe() {
    assert_eq!(Reply::Hi.to_string(), "< hi >");
    assert_eq!(Reply::Ok.to_string(), "< ok >");
    assert_eq!(Reply::Echo.to_string(), "< echo >");
    assert_eq!(
        Reply::Error("unknown command".into()).to_string(),
        "< error unknown command >"
    );
    assert_eq!(
        Reply::Error("bad <x> \n é".into()).to_string(),
        "< error bad 'x' ? ? >"
    );
}

#[test]
fn server_messages_parse_both_data_spellings() {
    let ts = Timestamp(23_424_242);
    let cases = [
        ("hi", ServerMessage::Hi),
        ("ok", ServerMessage::Ok),
        ("echo", ServerMessage::Echo),
        (
            "frame 123 23.424242 11223344",
            ServerMessage::Frame(std_frame(0x123, &[0x11, 0x22, 0x33, 0x44]), ts),
        ),
        // The protocol document's example spells data with spaces.
        (
            "frame 123 23.424242 11 22 33 44",
            ServerMessage::Frame(std_frame(0x123, &[0x11, 0x22, 0x33, 0x44]), ts),
        ),
        (
            "frame 123 23.424242",
            ServerMessage::Frame(std_frame(0x123, &[]), ts),
        ),
        (
            "frame 00000123 23.424242 FF",
            ServerMessage::Frame(Frame::new(CanId::Extended(0x123), &[0xFF]).unwrap(), ts),
        ),
        // Fewer fractional digits are read as a decimal fraction.
        (
            "frame 123 23.5 00",
            ServerMessage::Frame(std_frame(0x123, &[0]), Timestamp(23_500_000)),
        ),
        (
            "rtr 701 23.424242 1",
            ServerMessage::Frame(Frame::remote(CanId::Standard(0x701), 1).unwrap(), ts),
        ),
        (
            "fdframe 010 01 23.424242 0102",
            ServerMessage::Frame(
                Frame::fd(CanId::Standard(0x10), &[1, 2], FdFlags::from_raw(1)).unwrap(),
                ts,
            ),
        ),
        (
            "error 040 23.424242",
            ServerMessage::Frame(Frame::error(0x40, [0; 8]).unwrap(), ts),
        ),
        (
            "error unknown command",
            ServerMessage::Error("unknown command".into()),
        ),
        ("stat 1 2 3 4", ServerMessage::Other("stat 1 2 3 4".into())),
    ];
    for (text, expected) in cases {
        assert_eq!(parse_server_message(text), Ok(expected), "{text}");
    }
}

#[test]
fn malformed_server_messages_are_errors() {
    let cases = [
        "",
        "frame",
        "frame 123",
        "frame xyz 1.0 00",
        "frame 123 1 00",
        "frame 123 1.1234567 00",
        "frame 123 .5 00",
        "frame 123 1.0 0",
        "frame 123 1.0 GG",
        "frame 123 1.0 112233445566778899",
        "frame 123456789 1.0 00",
        "rtr 123 1.0",
        "rtr 123 1.0 9",
        "fdframe 123 1.0 00",
        "fdframe 123 00 1.0 0011223344556677889900",
        "frame 123 99999999999999999.0 00",
    ];
    for text in cases {
        assert!(parse_server_message(text).is_err(), "{text} parsed");
    }
}

fn arb_id() -> impl Strategy<Value = CanId> {
    prop_oneof![
        (0u32..=0x7FF).prop_map(|id| CanId::Standard(id as u16)),
        (0u32..=0x1FFF_FFFF).prop_map(CanId::Extended),
    ]
}

fn arb_frame() -> impl Strategy<Value = Frame> {
    prop_oneof![
        (arb_id(), prop::collection::vec(any::<u8>(), 0..=8))
            .prop_map(|(id, data)| Frame::new(id, &data).unwrap()),
        (arb_id(), 0u8..=8).prop_map(|(id, dlc)| Frame::remote(id, dlc).unwrap()),
        (
            arb_id(),
            prop::sample::select(FD_LENGTHS.to_vec()),
            any::<u8>(),
            any::<u8>()
        )
            .prop_map(|(id, len, fill, flags)| {
                Frame::fd(id, &vec![fill; len], FdFlags::from_raw(flags)).unwrap()
            }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(crate::test_support::fuzz_cases(2000)))]

    /// Whatever arrives, in whatever pieces, the framer and both parsers
    /// return and memory stays bounded.
    #[test]
    fn never_panics_on_any_bytes(input in prop::collection::vec(any::<u8>(), 0..2048), cut in 0usize..2048) {
        let mut framer = Framer::new(64);
        let mut out = Vec::new();
        let cut = cut.min(input.len());
        framer.push(&input[..cut], &mut out);
        framer.push(&input[cut..], &mut out);
        prop_assert!(framer.pending() <= 64);
        for token in out {
            if let Token::Message(text) = token {
                let _ = parse_command(&text);
                let _ = parse_server_message(&text);
            }
        }
    }

    /// Text made of the protocol's own words, shuffled, hits the parsers'
    /// deeper branches.
    #[test]
    fn never_panics_on_protocol_shaped_text(
        words in prop::collection::vec(
            prop_oneof![
                Just("send".to_string()), Just("fdsend".to_string()), Just("sendrtr".to_string()),
                Just("frame".to_string()), Just("fdframe".to_string()), Just("rtr".to_string()),
                Just("error".to_string()), Just("open".to_string()),
                "[0-9A-Fa-f]{0,10}", "[0-9]{0,12}\\.[0-9]{0,8}", "-?[0-9]{1,4}",
            ],
            0..20,
        )
    ) {
        let text = words.join(" ");
        let _ = parse_command(&text);
        let _ = parse_server_message(&text);
    }

    /// What the server writes, a client reads back unchanged.
    #[test]
    fn written_frames_read_back(frame in arb_frame(), micros in 0u64..4_000_000_000_000_000) {
        let ts = Timestamp(micros);
        let mut out = Vec::new();
        write_frame(&mut out, &frame, ts);
        let toks = tokens(&out);
        prop_assert_eq!(toks.len(), 1);
        let Token::Message(text) = &toks[0] else { panic!("not a message: {toks:?}") };
        prop_assert_eq!(parse_server_message(text), Ok(ServerMessage::Frame(frame, ts)));
    }

    /// What a client writes, the server reads back unchanged.
    #[test]
    fn written_sends_read_back(frame in arb_frame()) {
        let mut out = Vec::new();
        write_send(&mut out, &frame).unwrap();
        let toks = tokens(&out);
        let Token::Message(text) = &toks[0] else { panic!("not a message: {toks:?}") };
        prop_assert_eq!(parse_command(text), Ok(Command::Send(frame)));
    }
}

/// A remote frame as the server writes it reads back as the remote frame
/// (candeck's client), and so does the older `< rtr >` line.
#[test]
fn remote_frames_read_back_as_remote_frames() {
    let ts = Timestamp(1_436_509_052_249_713);
    let frame = Frame::remote(CanId::Standard(0x703), 1).unwrap();
    let mut out = Vec::new();
    write_frame(&mut out, &frame, ts);
    let text = String::from_utf8(out).unwrap();
    let inner = text.trim_start_matches('<').trim_end_matches('>').trim();
    assert_eq!(
        parse_server_message(inner),
        Ok(ServerMessage::Frame(frame, ts))
    );
    assert_eq!(
        parse_server_message("rtr 703 1436509052.249713 1"),
        Ok(ServerMessage::Frame(frame, ts))
    );
}
