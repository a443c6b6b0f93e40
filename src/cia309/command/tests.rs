use super::*;

const CONTEXT: Context = Context {
    default_net: 1,
    default_node: None,
    networks: 2,
};

fn ok(line: &str) -> Request {
    match parse(line, &CONTEXT) {
        Ok(Line::Request(request)) => request,
        other => panic!("{line:?}: {other:?}"),
    }
}

fn err(line: &str) -> (Option<u32>, u16) {
    match parse(line, &CONTEXT) {
        Err(error) => (error.sequence, error.code.number()),
        other => panic!("{line:?}: {other:?}"),
    }
}

#[test]
fn blank_and_comment_lines_are_empty() {
    for line in ["", "\r\n", "   \n", "# a comment\r\n", "  # indented"] {
        assert_eq!(parse(line, &CONTEXT), Ok(Line::Empty), "{line:?}");
    }
}

#[test]
fn a_read_with_net_node_and_type() {
    let request = ok("[7] 2 3 r 0x1017 0 u16\r\n");
    assert_eq!(request.sequence, 7);
    assert_eq!(request.net, 2);
    assert_eq!(request.node, Some(3));
    assert_eq!(
        request.command,
        Command::Read {
            index: 0x1017,
            sub: 0,
            datatype: Some(Datatype::U16)
        }
    );
    let request = ok("[0x10] 4 READ 4119 0x0 # comment");
    assert_eq!(request.sequence, 16);
    assert_eq!(request.net, 1);
    assert_eq!(
        request.command,
        Command::Read {
            index: 0x1017,
            sub: 0,
            datatype: None
        }
    );
}

#[test]
fn a_write_of_each_shape() {
    let request = ok("[1] 1 w 0x1017 0 u16 1000\n");
    assert_eq!(
        request.command,
        Command::Write {
            index: 0x1017,
            sub: 0,
            datatype: Datatype::U16,
            data: vec![0xE8, 0x03],
            text: "1000".into()
        }
    );
    let request = ok("[2] 3 write 0x2000 1 vs \"two # words\" # comment");
    let Command::Write { data, .. } = request.command else {
        panic!()
    };
    assert_eq!(data, b"two # words");
    let request = ok("[3] 3 w 0x2000 1 hex 01 02 ff");
    let Command::Write { data, .. } = request.command else {
        panic!()
    };
    assert_eq!(data, vec![1, 2, 0xFF]);
}

#[test]
fn the_default_node_is_used_when_none_is_given() {
    let context = Context {
        default_node: Some(5),
        ..CONTEXT
    };
    let Ok(Line::Request(request)) = parse("[1] start", &context) else {
        panic!()
    };
    assert_eq!(request.node, Some(5));
    assert_eq!(request.command, Command::Nmt(Nmt::Start));
}

#[test]
fn nmt_commands() {
    assert_eq!(ok("[1] 0 start").node, Some(0));
    assert_eq!(ok("[1] 2 stop").command, Command::Nmt(Nmt::Stop));
    assert_eq!(ok("[1] 2 preop").command, Command::Nmt(Nmt::PreOperational));
    assert_eq!(
        ok("[1] 2 preoperational").command,
        Command::Nmt(Nmt::PreOperational)
    );
    assert_eq!(ok("[1] 2 reset node").command, Command::Nmt(Nmt::ResetNode));
    assert_eq!(
        ok("[1] 2 RESET Comm").command,
        Command::Nmt(Nmt::ResetCommunication)
    );
    assert_eq!(
        ok("[1] 2 reset communication").command,
        Command::Nmt(Nmt::ResetCommunication)
    );
}

#[test]
fn set_commands() {
    assert_eq!(ok("[1] set network 2").command, Command::SetNetwork(2));
    assert_eq!(ok("[1] set node 127").command, Command::SetNode(127));
    assert_eq!(
        ok("[1] set sdo_timeout 50").command,
        Command::SetSdoTimeout(50)
    );
    assert_eq!(
        ok("[1] set sdo_block 1").command,
        Command::SetSdoBlock(true)
    );
    assert_eq!(ok("[1] help").command, Command::Help(HelpTopic::Commands));
    assert_eq!(
        ok("[1] help datatype").command,
        Command::Help(HelpTopic::Datatypes)
    );
}

#[test]
fn errors_carry_canopennode_numbers() {
    // No sequence, or a bad one: the previous sequence answers.
    assert_eq!(err("r 0x1000 0"), (None, 101));
    assert_eq!(err("[1]"), (None, 101));
    assert_eq!(err("[x] 1 r 0x1000 0"), (None, 101));
    assert_eq!(err("1 r 0x1000 0"), (None, 101));
    // Unknown command, keyword, topic.
    assert_eq!(err("[2] 1 frobnicate"), (Some(2), 100));
    assert_eq!(err("[2] set speed 1"), (Some(2), 100));
    assert_eq!(err("[2] led"), (Some(2), 100));
    assert_eq!(err("[2] help lss"), (Some(2), 100));
    assert_eq!(err("[2] help me"), (Some(2), 101));
    // Net and node.
    assert_eq!(err("[3] r 0x1000 0"), (Some(3), 105));
    assert_eq!(err("[3] 128 r 0x1000 0"), (Some(3), 107));
    assert_eq!(err("[3] 0 r 0x1000 0"), (Some(3), 107));
    assert_eq!(err("[3] 70000 1 r 0x1000 0"), (Some(3), 106));
    assert_eq!(err("[3] 3 1 r 0x1000 0"), (Some(3), 106));
    assert_eq!(err("[3] 1 1 1 r 0x1000 0"), (Some(3), 101));
    assert_eq!(err("[3] 1"), (Some(3), 101));
    // Syntax.
    assert_eq!(err("[4] 1 r"), (Some(4), 101));
    assert_eq!(err("[4] 1 r 0x10000 0"), (Some(4), 101));
    assert_eq!(err("[4] 1 r 0x1000 256"), (Some(4), 101));
    assert_eq!(err("[4] 1 r 0x1000 0 u24"), (Some(4), 101));
    assert_eq!(err("[4] 1 r 0x1000 0 u8 extra"), (Some(4), 101));
    assert_eq!(err("[4] 1 w 0x1017 0 u16"), (Some(4), 101));
    assert_eq!(err("[4] 1 w 0x1017 0 u16 70000"), (Some(4), 101));
    assert_eq!(err("[4] 1 w 0x1017 0 u16 1 2"), (Some(4), 101));
    assert_eq!(err("[4] 1 w 0x1017 0 bogus 1"), (Some(4), 101));
    assert_eq!(err("[4] 1 w 0x2000 0 vs \"open"), (Some(4), 101));
    assert_eq!(err("[4] 1 w 0x2000 0 d"), (Some(4), 101));
    assert_eq!(err("[4] 1 start now"), (Some(4), 101));
    assert_eq!(err("[4] 1 reset everything"), (Some(4), 101));
    assert_eq!(err("[4] set node 0"), (Some(4), 101));
    assert_eq!(err("[4] set node 128"), (Some(4), 101));
    assert_eq!(err("[4] set network 3"), (Some(4), 101));
    assert_eq!(err("[4] set sdo_timeout 0"), (Some(4), 101));
    assert_eq!(err("[4] set sdo_block 2"), (Some(4), 101));
    assert_eq!(err("[4] set"), (Some(4), 101));
}

#[test]
fn refused_lines_are_known_by_their_command_word() {
    let change = |line| attempted_change(line);
    assert_eq!(change("[4] 1 w 0x1017 0 u16 70000"), Some(Change::Write));
    assert_eq!(
        change("[4] 1 2 WRITE 0x1017 0 bogus 1"),
        Some(Change::Write)
    );
    assert_eq!(change("[4] 300 w 0x1017 0 u16 1"), Some(Change::Write));
    assert_eq!(change("1 w 0x1017 0 u16 1"), Some(Change::Write));
    assert_eq!(change("[4] 1 start now"), Some(Change::Nmt));
    assert_eq!(change("[4] reset everything"), Some(Change::Nmt));
    assert_eq!(change("[4] 1 r 0x1000 0 u24"), None);
    assert_eq!(change("[4] set node 0"), None);
    assert_eq!(change("[4] # w 0x1017"), None);
    assert_eq!(change(""), None);
}
