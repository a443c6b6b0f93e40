//! The replies and event notifications of CiA 309-3 (§5.3 "Response
//! syntax", §5.4 error codes, §9 event notifications), byte for byte as
//! CANopenNode's gateway writes them (`309/CO_gateway_ascii.c`, built with
//! `CO_CONFIG_GTW_ASCII_ERROR_DESC`, as its Linux `canopend` is):
//!
//! ```text
//! [<sequence>] OK\r\n
//! [<sequence>] <value>\r\n
//! [<sequence>] ERROR:<internal error number> #<description>\r\n
//! [<sequence>] ERROR:0x<SDO abort code, 8 hex digits> #<description>\r\n
//! \r\n                                  (a blank or comment-only line)
//! ```
//!
//! Event notifications are unsolicited lines that never start with `[`
//! (CiA 309-3 §9): `<net> <node> BOOT_UP`, `<net> <node> EMCY <code>
//! <register> <manufacturer bytes>`, `<net> <node> ERROR:<202|203>
//! #<description>` for a heartbeat started or lost. CANopenNode's gateway
//! has no such lines (it keeps them in its `log`); these follow the forms
//! of CiA 309-3.

use crate::canopen::sdo::AbortCode;

/// An internal error number of CiA 309-3 (§5.4), with CANopenNode's text.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorCode {
    /// 100
    RequestNotSupported,
    /// 101
    Syntax,
    /// 102
    InternalState,
    /// 103
    TimeOut,
    /// 104
    NoDefaultNet,
    /// 105
    NoDefaultNode,
    /// 106
    UnsupportedNet,
    /// 107
    UnsupportedNode,
    /// 202 (event)
    HeartbeatStarted,
    /// 203 (event)
    HeartbeatLost,
    /// 204
    WrongNmtState,
    /// 205 (event)
    BootUp,
}

impl ErrorCode {
    pub fn number(self) -> u16 {
        match self {
            Self::RequestNotSupported => 100,
            Self::Syntax => 101,
            Self::InternalState => 102,
            Self::TimeOut => 103,
            Self::NoDefaultNet => 104,
            Self::NoDefaultNode => 105,
            Self::UnsupportedNet => 106,
            Self::UnsupportedNode => 107,
            Self::HeartbeatStarted => 202,
            Self::HeartbeatLost => 203,
            Self::WrongNmtState => 204,
            Self::BootUp => 205,
        }
    }

    pub fn description(self) -> &'static str {
        match self {
            Self::RequestNotSupported => "Request not supported.",
            Self::Syntax => "Syntax error.",
            Self::InternalState => "Request not processed due to internal state.",
            Self::TimeOut => "Time-out.",
            Self::NoDefaultNet => "No default net set.",
            Self::NoDefaultNode => "No default node set.",
            Self::UnsupportedNet => "Unsupported net.",
            Self::UnsupportedNode => "Unsupported node.",
            Self::HeartbeatStarted => "Heartbeat started.",
            Self::HeartbeatLost => "Heartbeat lost.",
            Self::WrongNmtState => "Wrong NMT state.",
            Self::BootUp => "Boot-up.",
        }
    }
}

/// CANopenNode's one-line description of an SDO abort code; `-` for codes
/// it has none for.
pub fn abort_description(code: u32) -> &'static str {
    match code {
        0x0000_0000 => "No abort.",
        0x0503_0000 => "Toggle bit not altered.",
        0x0504_0000 => "SDO protocol timed out.",
        0x0504_0001 => "Command specifier not valid or unknown.",
        0x0504_0002 => "Invalid block size in block mode.",
        0x0504_0003 => "Invalid sequence number in block mode.",
        0x0504_0004 => "CRC error (block mode only).",
        0x0504_0005 => "Out of memory.",
        0x0601_0000 => "Unsupported access to an object.",
        0x0601_0001 => "Attempt to read a write only object.",
        0x0601_0002 => "Attempt to write a read only object.",
        0x0602_0000 => "Object does not exist.",
        0x0604_0041 => "Object cannot be mapped to the PDO.",
        0x0604_0042 => "Number and length of object to be mapped exceeds PDO length.",
        0x0604_0043 => "General parameter incompatibility reasons.",
        0x0604_0047 => "General internal incompatibility in device.",
        0x0606_0000 => "Access failed due to hardware error.",
        0x0607_0010 => "Data type does not match, length of service parameter does not match.",
        0x0607_0012 => "Data type does not match, length of service parameter too high.",
        0x0607_0013 => "Data type does not match, length of service parameter too short.",
        0x0609_0011 => "Sub index does not exist.",
        0x0609_0030 => "Invalid value for parameter (download only).",
        0x0609_0031 => "Value range of parameter written too high.",
        0x0609_0032 => "Value range of parameter written too low.",
        0x0609_0036 => "Maximum value is less than minimum value.",
        0x060A_0023 => "Resource not available: SDO connection.",
        0x0800_0000 => "General error.",
        0x0800_0020 => "Data cannot be transferred or stored to application.",
        0x0800_0021 => {
            "Data cannot be transferred or stored to application because of local control."
        }
        0x0800_0022 => {
            "Data cannot be transferred or stored to application because of present device state."
        }
        0x0800_0023 => "Object dictionary not present or dynamic generation fails.",
        0x0800_0024 => "No data available.",
        _ => "-",
    }
}

/// A reply to one line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reply {
    /// To a blank or comment-only line.
    Empty,
    Ok(u32),
    /// A value read, already written in its type's form.
    Value(u32, String),
    Error(u32, ErrorCode),
    Abort(u32, AbortCode),
    /// `help`: a text of its own, not prefixed by the sequence.
    Help(&'static str),
}

impl Reply {
    /// The bytes sent, `\r\n` included.
    pub fn to_wire(&self) -> String {
        match self {
            Self::Empty => "\r\n".to_string(),
            Self::Ok(sequence) => format!("[{sequence}] OK\r\n"),
            Self::Value(sequence, value) => format!("[{sequence}] {value}\r\n"),
            Self::Error(sequence, code) => format!(
                "[{sequence}] ERROR:{} #{}\r\n",
                code.number(),
                code.description()
            ),
            Self::Abort(sequence, code) => format!(
                "[{sequence}] ERROR:0x{:08X} #{}\r\n",
                code.raw(),
                abort_description(code.raw())
            ),
            Self::Help(text) => (*text).to_string(),
        }
    }
}

/// An event notification (CiA 309-3 §9), unsolicited.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    BootUp {
        net: u16,
        node: u8,
    },
    Emcy {
        net: u16,
        node: u8,
        code: u16,
        register: u8,
        manufacturer: [u8; 5],
    },
    HeartbeatStarted {
        net: u16,
        node: u8,
    },
    HeartbeatLost {
        net: u16,
        node: u8,
    },
}

impl Event {
    pub fn to_wire(&self) -> String {
        match self {
            Self::BootUp { net, node } => format!("{net} {node} BOOT_UP\r\n"),
            Self::Emcy {
                net,
                node,
                code,
                register,
                manufacturer,
            } => format!(
                "{net} {node} EMCY 0x{code:04X} 0x{register:02X} {}\r\n",
                super::datatype::hex_text(manufacturer)
            ),
            Self::HeartbeatStarted { net, node } => {
                let code = ErrorCode::HeartbeatStarted;
                format!(
                    "{net} {node} ERROR:{} #{}\r\n",
                    code.number(),
                    code.description()
                )
            }
            Self::HeartbeatLost { net, node } => {
                let code = ErrorCode::HeartbeatLost;
                format!(
                    "{net} {node} ERROR:{} #{}\r\n",
                    code.number(),
                    code.description()
                )
            }
        }
    }
}

/// `help`: in CANopenNode's layout (a leading `\n`, lines ended by `\n`,
/// the last by `\r\n`), listing the commands this gateway has.
pub const HELP: &str = "\nCommand strings start with '\"[\"<sequence>\"]\"' followed by:\n\
[[<net>] <node>] r[ead] <index> <subindex> [<datatype>]        # SDO upload.\n\
[[<net>] <node>] w[rite] <index> <subindex> <datatype> <value> # SDO download.\n\
\n\
[[<net>] <node>] start                   # NMT Start node.\n\
[[<net>] <node>] stop                    # NMT Stop node.\n\
[[<net>] <node>] preop[erational]        # NMT Set node to pre-operational.\n\
[[<net>] <node>] reset node              # NMT Reset node.\n\
[[<net>] <node>] reset comm[unication]   # NMT Reset communication.\n\
\n\
[<net>] set network <value>              # Set default net.\n\
[<net>] set node <value>                 # Set default node.\n\
[<net>] set sdo_timeout <value>          # Configure SDO client time-out in ms.\n\
[<net>] set sdo_block <0|1>              # Enable/disable SDO block transfer.\n\
\n\
help [datatype]                          # Print this or datatype help.\n\
\n\
Response:\n\
\"[\"<sequence>\"]\" OK | <value> |\n\
                 ERROR:<SDO-abort-code> | ERROR:<internal-error-code>\n\
\n\
Events (unsolicited, without sequence):\n\
<net> <node> BOOT_UP | EMCY <code> <register> <manufacturer bytes> |\n\
             ERROR:202 (heartbeat started) | ERROR:203 (heartbeat lost)\n\
\n\
* Every command must be terminated with <CR><LF> ('\\r\\n'). characters. Same\n\
  is response. <CR> is optional in command.\n\
* Comments started with '#' are ignored. They may be on the beginning of the\n\
  line or after the command string.\n\
* 'sdo_timeout' is in milliseconds, the gateway's SDO time-out by default.\n\
  Block transfer is disabled by default.\n\
* <net> is the gateway's bus in the order they are served, 1 the first; 1 by\n\
  default.\n\
* If '<net>' or '<node>' is not specified within commands, then value defined\n\
  by 'set network' or 'set node' command is used.\r\n";

/// `help datatype`, CANopenNode's text.
pub const HELP_DATATYPES: &str = "\nDatatypes:\n\
b                  # Boolean.\n\
i8, i16, i32, i64  # Signed integers.\n\
u8, u16, u32, u64  # Unsigned integers.\n\
x8, x16, x32, x64  # Unsigned integers, displayed as hexadecimal, non-standard.\n\
r32, r64           # Real numbers.\n\
vs                 # Visible string (between double quotes if multi-word).\n\
os, us             # Octet, unicode string, (mime-base64 (RFC2045) based, line).\n\
d                  # domain (mime-base64 (RFC2045) based, one line).\n\
hex                # Hexagonal data, optionally space separated, non-standard.\r\n";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replies_are_byte_exact() {
        assert_eq!(Reply::Empty.to_wire(), "\r\n");
        assert_eq!(Reply::Ok(1).to_wire(), "[1] OK\r\n");
        assert_eq!(
            Reply::Value(2, "\"UMC\"".into()).to_wire(),
            "[2] \"UMC\"\r\n"
        );
        assert_eq!(
            Reply::Error(3, ErrorCode::RequestNotSupported).to_wire(),
            "[3] ERROR:100 #Request not supported.\r\n"
        );
        assert_eq!(
            Reply::Error(4, ErrorCode::Syntax).to_wire(),
            "[4] ERROR:101 #Syntax error.\r\n"
        );
        assert_eq!(
            Reply::Error(5, ErrorCode::NoDefaultNode).to_wire(),
            "[5] ERROR:105 #No default node set.\r\n"
        );
        assert_eq!(
            Reply::Abort(6, AbortCode::from_raw(0x0602_0000)).to_wire(),
            "[6] ERROR:0x06020000 #Object does not exist.\r\n"
        );
        assert_eq!(
            Reply::Abort(7, AbortCode::from_raw(0x0504_0000)).to_wire(),
            "[7] ERROR:0x05040000 #SDO protocol timed out.\r\n"
        );
        assert_eq!(
            Reply::Abort(8, AbortCode::from_raw(0x1234_5678)).to_wire(),
            "[8] ERROR:0x12345678 #-\r\n"
        );
        assert_eq!(
            Reply::Error(4294967295, ErrorCode::WrongNmtState).to_wire(),
            "[4294967295] ERROR:204 #Wrong NMT state.\r\n"
        );
    }

    #[test]
    fn every_internal_error_has_its_number_and_text() {
        let all = [
            (ErrorCode::RequestNotSupported, 100),
            (ErrorCode::Syntax, 101),
            (ErrorCode::InternalState, 102),
            (ErrorCode::TimeOut, 103),
            (ErrorCode::NoDefaultNet, 104),
            (ErrorCode::NoDefaultNode, 105),
            (ErrorCode::UnsupportedNet, 106),
            (ErrorCode::UnsupportedNode, 107),
            (ErrorCode::HeartbeatStarted, 202),
            (ErrorCode::HeartbeatLost, 203),
            (ErrorCode::WrongNmtState, 204),
            (ErrorCode::BootUp, 205),
        ];
        for (code, number) in all {
            assert_eq!(code.number(), number);
            assert!(code.description().ends_with('.'));
        }
    }

    #[test]
    fn events_are_lines_without_sequence() {
        assert_eq!(
            Event::BootUp { net: 1, node: 3 }.to_wire(),
            "1 3 BOOT_UP\r\n"
        );
        assert_eq!(
            Event::Emcy {
                net: 1,
                node: 1,
                code: 0x4210,
                register: 0x09,
                manufacturer: [1, 2, 3, 4, 5]
            }
            .to_wire(),
            "1 1 EMCY 0x4210 0x09 01 02 03 04 05\r\n"
        );
        assert_eq!(
            Event::HeartbeatLost { net: 2, node: 5 }.to_wire(),
            "2 5 ERROR:203 #Heartbeat lost.\r\n"
        );
        assert_eq!(
            Event::HeartbeatStarted { net: 2, node: 5 }.to_wire(),
            "2 5 ERROR:202 #Heartbeat started.\r\n"
        );
    }

    #[test]
    fn help_texts_have_canopennode_framing() {
        for text in [HELP, HELP_DATATYPES] {
            assert!(text.starts_with('\n'));
            assert!(text.ends_with(".\r\n"));
            // One \r only: the one that ends the reply.
            assert_eq!(text.matches('\r').count(), 1);
        }
    }
}
