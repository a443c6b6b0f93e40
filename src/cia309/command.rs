//! A CiA 309-3 command line parsed into a typed [`Request`] (CiA 309-3
//! §5.1 "Command syntax", §6 SDO access, §7 NMT, §8 gateway management).
//!
//! Sans-I/O: [`parse`] takes one line and the connection's defaults
//! ([`Context`]) and gives a [`Line`] or a [`ParseError`] carrying the
//! internal error number CANopenNode's gateway answers with, in the order
//! it checks them (`309/CO_gateway_ascii.c`, `CO_GTWA_process`):
//!
//! ```text
//! "[" <sequence> "]" [[<net>] <node>] <command> ...   # comment
//! ```
//!
//! - the `[sequence]` token first; without it the line is a syntax error
//!   (101), answered with the previous sequence number, as CANopenNode does;
//! - up to two numbers before the command: one is the node, two are the net
//!   and the node; a node above 127 is 107, a net above 65535 is 106;
//! - the command and its keywords are case-insensitive;
//! - a node is needed by `r`, `w` (1–127) and the NMT commands (0–127, 0
//!   being every node): none given and none set is 105, out of range 107; a
//!   net that names no bus is 106;
//! - an unknown command, `set` keyword or `help` topic is 100; anything
//!   else malformed is 101.

use super::datatype::{Datatype, unsigned};
use super::reply::ErrorCode;

/// The connection's defaults, which [`parse`] resolves a request with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Context {
    /// The net used when a command names none (`set network`).
    pub default_net: u16,
    /// The node used when a command names none (`set node`).
    pub default_node: Option<u8>,
    /// The gateway's networks: 1 to `networks` (the buses in serve order).
    pub networks: u16,
}

/// One line of input.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Line {
    /// Blank or only a comment: CANopenNode answers with an empty line.
    Empty,
    Request(Request),
}

/// A well-formed command, its net and node resolved.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Request {
    pub sequence: u32,
    /// 1-based.
    pub net: u16,
    /// The node (0: every node, NMT only); `None` for commands without one.
    pub node: Option<u8>,
    pub command: Command,
}

/// What a request asks.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    /// `r[ead] <index> <subindex> [<datatype>]`: SDO upload.
    Read {
        index: u16,
        sub: u8,
        /// `None`: the reply writes the bytes as `hex`.
        datatype: Option<Datatype>,
    },
    /// `w[rite] <index> <subindex> <datatype> <value>`: SDO download.
    Write {
        index: u16,
        sub: u8,
        datatype: Datatype,
        /// The value's bytes, encoded.
        data: Vec<u8>,
        /// The value as written, for the audit log.
        text: String,
    },
    Nmt(Nmt),
    SetNetwork(u16),
    SetNode(u8),
    /// Milliseconds, 1–65535.
    SetSdoTimeout(u16),
    SetSdoBlock(bool),
    Help(HelpTopic),
}

/// The NMT commands (CiA 309-3 §7.1; CiA 301 §7.2.8.3.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Nmt {
    Start,
    Stop,
    PreOperational,
    ResetNode,
    ResetCommunication,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HelpTopic {
    Commands,
    Datatypes,
}

/// A line refused: the sequence number to answer with (`None`: the line
/// had none readable, the previous one is used) and the error number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ParseError {
    pub sequence: Option<u32>,
    pub code: ErrorCode,
}

/// The tokens of a line, comment removed.
struct Tokens<'a> {
    rest: &'a str,
}

impl<'a> Tokens<'a> {
    fn next(&mut self) -> Option<&'a str> {
        let text = self.rest.trim_start_matches([' ', '\t']);
        if text.is_empty() {
            self.rest = text;
            return None;
        }
        let end = text.find([' ', '\t']).unwrap_or(text.len());
        self.rest = &text[end..];
        Some(&text[..end])
    }

    /// Whether the line has nothing more.
    fn at_end(&self) -> bool {
        self.rest.trim_matches([' ', '\t']).is_empty()
    }

    /// The rest of the line, blanks around it removed.
    fn rest(&mut self) -> &'a str {
        let rest = self.rest.trim_matches([' ', '\t']);
        self.rest = "";
        rest
    }
}

/// The line without its end (`\n`, optional `\r`) and its comment: from
/// the first `#` outside double quotes (a `vs` value may hold one).
fn strip(line: &str) -> &str {
    let line = line.trim_end_matches(['\n', '\r']);
    let mut quoted = false;
    for (at, c) in line.char_indices() {
        match c {
            '"' => quoted = !quoted,
            '#' if !quoted => return &line[..at],
            _ => {}
        }
    }
    line
}

/// Parses one line of input (its end of line, `\r\n` or `\n`, optional).
pub fn parse(line: &str, context: &Context) -> Result<Line, ParseError> {
    let mut tokens = Tokens { rest: strip(line) };
    let Some(first) = tokens.next() else {
        return Ok(Line::Empty);
    };
    let syntax = |sequence| ParseError {
        sequence,
        code: ErrorCode::Syntax,
    };
    // CANopenNode refuses a line that is only its sequence before reading
    // the number: the previous sequence answers.
    if tokens.at_end() {
        return Err(syntax(None));
    }
    let sequence = first
        .strip_prefix('[')
        .and_then(|rest| rest.strip_suffix(']'))
        .and_then(|number| unsigned(number, u32::MAX.into()).ok())
        .ok_or(syntax(None))? as u32;
    let fail = |code| ParseError {
        sequence: Some(sequence),
        code,
    };
    let syntax = fail(ErrorCode::Syntax);

    // [[<net>] <node>] <command>
    let mut numbers = Vec::new();
    let command = loop {
        let token = tokens.next().ok_or(syntax)?;
        if !token.starts_with(|c: char| c.is_ascii_digit()) {
            break token;
        }
        if numbers.len() == 2 || tokens.at_end() {
            return Err(syntax);
        }
        numbers.push(unsigned(token, u32::MAX.into()).map_err(|_| syntax)?);
    };
    let (net, node) = match numbers.as_slice() {
        [] => (None, None),
        [node] if *node > 127 => return Err(fail(ErrorCode::UnsupportedNode)),
        [node] => (None, Some(*node as u8)),
        [net, _] if *net > 0xFFFF => return Err(fail(ErrorCode::UnsupportedNet)),
        [_, node] if *node > 127 => return Err(fail(ErrorCode::UnsupportedNode)),
        [net, node] => (Some(*net as u16), Some(*node as u8)),
        _ => return Err(syntax),
    };
    let net = net.unwrap_or(context.default_net);
    let node = node.or(context.default_node);
    let check_net = || {
        if net == 0 || net > context.networks {
            Err(fail(ErrorCode::UnsupportedNet))
        } else {
            Ok(net)
        }
    };
    let check_node = |min: u8| match node {
        None => Err(fail(ErrorCode::NoDefaultNode)),
        Some(id) if id < min || id > 127 => Err(fail(ErrorCode::UnsupportedNode)),
        Some(id) => check_net().map(|net| (net, id)),
    };
    let request = |net, node, command| {
        Ok(Line::Request(Request {
            sequence,
            net,
            node,
            command,
        }))
    };

    match command.to_ascii_lowercase().as_str() {
        "set" => {
            let keyword = tokens.next().ok_or(syntax)?.to_ascii_lowercase();
            let value = |tokens: &mut Tokens, min: u64, max: u64| {
                let token = tokens.next().ok_or(syntax)?;
                if !tokens.at_end() {
                    return Err(syntax);
                }
                match unsigned(token, max) {
                    Ok(value) if value >= min => Ok(value),
                    _ => Err(syntax),
                }
            };
            match keyword.as_str() {
                "network" => {
                    let value = value(&mut tokens, 1, context.networks.into())?;
                    request(net, None, Command::SetNetwork(value as u16))
                }
                "node" => {
                    let net = check_net()?;
                    let value = value(&mut tokens, 1, 127)?;
                    request(net, None, Command::SetNode(value as u8))
                }
                "sdo_timeout" => {
                    let net = check_net()?;
                    let value = value(&mut tokens, 1, 0xFFFF)?;
                    request(net, None, Command::SetSdoTimeout(value as u16))
                }
                "sdo_block" => {
                    let net = check_net()?;
                    let value = value(&mut tokens, 0, 1)?;
                    request(net, None, Command::SetSdoBlock(value == 1))
                }
                _ => Err(fail(ErrorCode::RequestNotSupported)),
            }
        }
        "r" | "read" => {
            let (net, node) = check_node(1)?;
            let index = tokens.next().ok_or(syntax)?;
            let index = unsigned(index, 0xFFFF).map_err(|_| syntax)? as u16;
            let sub = tokens.next().ok_or(syntax)?;
            let sub = unsigned(sub, 0xFF).map_err(|_| syntax)? as u8;
            let datatype = match tokens.next() {
                None => None,
                Some(token) => {
                    if !tokens.at_end() {
                        return Err(syntax);
                    }
                    Some(Datatype::from_mnemonic(token).ok_or(syntax)?)
                }
            };
            request(
                net,
                Some(node),
                Command::Read {
                    index,
                    sub,
                    datatype,
                },
            )
        }
        "w" | "write" => {
            let (net, node) = check_node(1)?;
            let index = tokens.next().ok_or(syntax)?;
            let index = unsigned(index, 0xFFFF).map_err(|_| syntax)? as u16;
            let sub = tokens.next().ok_or(syntax)?;
            let sub = unsigned(sub, 0xFF).map_err(|_| syntax)? as u8;
            let datatype = tokens.next().ok_or(syntax)?;
            let datatype = Datatype::from_mnemonic(datatype).ok_or(syntax)?;
            let text = if datatype.takes_rest_of_line() {
                tokens.rest()
            } else {
                let token = tokens.next().ok_or(syntax)?;
                if !tokens.at_end() {
                    return Err(syntax);
                }
                token
            };
            let data = datatype.encode(text).map_err(|_| syntax)?;
            // CANopenNode refuses an empty value (size 0): an SDO download
            // of nothing is no write.
            if data.is_empty() {
                return Err(syntax);
            }
            request(
                net,
                Some(node),
                Command::Write {
                    index,
                    sub,
                    datatype,
                    data,
                    text: text.to_string(),
                },
            )
        }
        word @ ("start" | "stop" | "preop" | "preoperational") => {
            let (net, node) = check_node(0)?;
            if !tokens.at_end() {
                return Err(syntax);
            }
            let nmt = match word {
                "start" => Nmt::Start,
                "stop" => Nmt::Stop,
                _ => Nmt::PreOperational,
            };
            request(net, Some(node), Command::Nmt(nmt))
        }
        "reset" => {
            let (net, node) = check_node(0)?;
            let what = tokens.next().ok_or(syntax)?.to_ascii_lowercase();
            if !tokens.at_end() {
                return Err(syntax);
            }
            let nmt = match what.as_str() {
                "node" => Nmt::ResetNode,
                "comm" | "communication" => Nmt::ResetCommunication,
                _ => return Err(syntax),
            };
            request(net, Some(node), Command::Nmt(nmt))
        }
        "help" => {
            let topic = match tokens.next() {
                None => HelpTopic::Commands,
                Some(topic) => {
                    if !tokens.at_end() {
                        return Err(syntax);
                    }
                    match topic.to_ascii_lowercase().as_str() {
                        "datatype" => HelpTopic::Datatypes,
                        // No LSS master here: its help would list commands
                        // that answer 100.
                        "lss" => return Err(fail(ErrorCode::RequestNotSupported)),
                        _ => return Err(syntax),
                    }
                }
            };
            request(net, None, Command::Help(topic))
        }
        _ => Err(fail(ErrorCode::RequestNotSupported)),
    }
}

/// What a line asks to change, read from its command word alone: for the
/// audit log of lines [`parse`] refuses (a malformed SDO write is still
/// someone trying to write). `None` for reads, settings, help, and lines
/// without a command word.
pub fn attempted_change(line: &str) -> Option<Change> {
    let mut tokens = Tokens { rest: strip(line) };
    let mut word = tokens.next()?;
    if word.starts_with('[') {
        word = tokens.next()?;
    }
    // Up to two numbers (net, node) before the command.
    for _ in 0..2 {
        if word.starts_with(|c: char| c.is_ascii_digit()) {
            word = tokens.next()?;
        }
    }
    match word.to_ascii_lowercase().as_str() {
        "w" | "write" => Some(Change::Write),
        "start" | "stop" | "preop" | "preoperational" | "reset" => Some(Change::Nmt),
        _ => None,
    }
}

/// What kind of change a line asks for ([`attempted_change`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Change {
    Write,
    Nmt,
}

impl Change {
    /// As the audit log names it.
    pub fn what(self) -> &'static str {
        match self {
            Self::Write => "SDO write",
            Self::Nmt => "NMT command",
        }
    }
}

#[cfg(test)]
mod tests {
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
}
