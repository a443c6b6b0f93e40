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
mod tests;
