//! One client's conversation with the socketcand server, without I/O: the
//! modes of linux-can/socketcand `doc/protocol.md` (NO_BUS → BCM → RAW) and
//! what each message leads to.
//!
//! BCM mode here offers what every mode shares (`send`, `sendrtr`, `fdsend`,
//! `echo`) and the switch to raw mode; the broadcast-manager jobs (`add`,
//! `subscribe`, `filter`, ...) are answered with an error naming raw mode.

use super::protocol::{Command, ParseError, Reply, Token, parse_command};
use crate::frame::Frame;

/// The protocol mode of a session.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Connected, no bus opened yet.
    NoBus,
    /// A bus is open; frames are not forwarded to the client.
    Bcm,
    /// Every frame on the bus is forwarded to the client.
    Raw,
}

/// What the server must do after a message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Action {
    /// Write this reply to the client.
    Reply(Reply),
    /// Attach the session to this channel's bus (after `open`).
    Attach(String),
    /// Put this frame on the bus.
    Send(Frame),
    /// Start forwarding the bus's frames to the client (after the `ok`).
    StartForwarding,
    /// Stop forwarding frames.
    StopForwarding,
    /// End the connection (after writing any reply before it).
    Close,
}

/// Why a message was not accepted: a client error to log (and answer, but
/// for a malformed frame command, which socketcand answers with silence).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rejection {
    pub reason: String,
}

/// A client's session. Feed it [`Token`]s; it returns [`Action`]s and, for
/// input that is wrong, a [`Rejection`] for the log (the error reply is
/// among the actions already).
#[derive(Debug)]
pub struct Session {
    mode: Mode,
    channels: Vec<String>,
}

impl Session {
    /// A session on a server that offers these channel names.
    pub fn new(channels: Vec<String>) -> Self {
        Self {
            mode: Mode::NoBus,
            channels,
        }
    }

    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The greeting a new connection gets.
    pub fn greeting() -> Reply {
        Reply::Hi
    }

    pub fn handle(&mut self, token: Token, actions: &mut Vec<Action>) -> Option<Rejection> {
        let text = match token {
            Token::Message(text) => text,
            Token::Garbage { bytes } => {
                return Some(self.reject(
                    actions,
                    format!("{bytes} bytes outside '< >'; commands look like '< send 123 1 AA >'"),
                ));
            }
            Token::Oversized { bytes } => {
                return Some(self.reject(actions, format!("command of {bytes} bytes is too long")));
            }
            Token::Truncated(text) => {
                return Some(self.reject(
                    actions,
                    format!("command '{}' was cut off by a new '<'", clip(&text)),
                ));
            }
            Token::NotAscii => {
                return Some(
                    self.reject(actions, "command has bytes that are not printable ASCII"),
                );
            }
        };
        let command = match parse_command(&text) {
            Ok(command) => command,
            Err(err) => {
                let reason = match err {
                    // socketcand's own words, which scripts may look for.
                    ParseError::UnknownCommand(_) | ParseError::Empty => {
                        format!("unknown command '{}'", clip(&text))
                    }
                    // socketcand logs a bad send and answers nothing
                    // (`state_raw.c`): python-can would read an error
                    // reply as an error frame and stop receiving.
                    other if is_frame_command(&text) => {
                        return Some(Rejection {
                            reason: other.to_string(),
                        });
                    }
                    other => other.to_string(),
                };
                return Some(self.reject(actions, reason));
            }
        };
        match (self.mode, command) {
            (_, Command::Echo) => actions.push(Action::Reply(Reply::Echo)),
            (Mode::NoBus, Command::Open(channel)) => {
                if self.channels.contains(&channel) {
                    self.mode = Mode::Bcm;
                    actions.push(Action::Attach(channel));
                    actions.push(Action::Reply(Reply::Ok));
                } else {
                    // As socketcand does: an error, then the connection ends.
                    let reason = format!(
                        "no bus '{channel}' here; this server offers {}",
                        self.channels.join(", ")
                    );
                    actions.push(Action::Reply(Reply::Error(reason.clone())));
                    actions.push(Action::Close);
                    return Some(Rejection { reason });
                }
            }
            (Mode::NoBus, _) => {
                return Some(self.reject(actions, "open a bus first: '< open CHANNEL >'"));
            }
            (_, Command::Open(_)) => {
                return Some(self.reject(actions, "a bus is already open"));
            }
            (Mode::Bcm, Command::RawMode) => {
                self.mode = Mode::Raw;
                actions.push(Action::Reply(Reply::Ok));
                actions.push(Action::StartForwarding);
            }
            (Mode::Raw, Command::RawMode) => actions.push(Action::Reply(Reply::Ok)),
            (Mode::Raw, Command::BcmMode) => {
                self.mode = Mode::Bcm;
                actions.push(Action::StopForwarding);
                actions.push(Action::Reply(Reply::Ok));
            }
            (Mode::Bcm, Command::BcmMode) => actions.push(Action::Reply(Reply::Ok)),
            (_, Command::Send(frame)) => actions.push(Action::Send(guarding_request(frame))),
            (_, Command::Unsupported(verb)) => {
                return Some(self.reject(
                    actions,
                    format!("'{verb}' is not offered by this server; use '< rawmode >'"),
                ));
            }
        }
        None
    }

    fn reject(&self, actions: &mut Vec<Action>, reason: impl Into<String>) -> Rejection {
        let reason = reason.into();
        actions.push(Action::Reply(Reply::Error(reason.clone())));
        Rejection { reason }
    }
}

/// Whether a message is one of the commands that send a frame.
fn is_frame_command(text: &str) -> bool {
    let verb = text.split_ascii_whitespace().next().unwrap_or("");
    matches!(verb, "send" | "sendrtr" | "fdsend")
}

/// python-can's socketcand interface writes a remote frame as a `send` of
/// no data (it has no form for one), so python-canopen's node guarding
/// reaches the server as zero-length data frames on 0x701–0x77F, which no
/// CANopen service uses: they are the guarding requests (remote frames,
/// CiA 301 §7.2.8.3.2.1) they were sent as.
fn guarding_request(frame: Frame) -> Frame {
    use crate::frame::{CanId, FrameKind};
    match (frame.kind(), frame.id()) {
        (FrameKind::Data, CanId::Standard(id @ 0x701..=0x77F)) if frame.data().is_empty() => {
            Frame::remote(CanId::Standard(id), 1).unwrap_or(frame)
        }
        _ => frame,
    }
}

fn clip(text: &str) -> String {
    const MAX: usize = 40;
    if text.chars().count() <= MAX {
        text.to_string()
    } else {
        let head: String = text.chars().take(MAX).collect();
        format!("{head}...")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::CanId;

    fn run(session: &mut Session, text: &str) -> (Vec<Action>, Option<Rejection>) {
        let mut actions = Vec::new();
        let rejection = session.handle(Token::Message(text.into()), &mut actions);
        (actions, rejection)
    }

    #[test]
    fn open_rawmode_send_follows_socketcand_modes() {
        let mut session = Session::new(vec!["can0".into()]);
        assert_eq!(session.mode(), Mode::NoBus);
        let (actions, _) = run(&mut session, "send 123 0");
        assert_eq!(
            actions,
            vec![Action::Reply(Reply::Error(
                "open a bus first: '< open CHANNEL >'".into()
            ))]
        );
        let (actions, rejection) = run(&mut session, "open can0");
        assert_eq!(
            actions,
            vec![Action::Attach("can0".into()), Action::Reply(Reply::Ok)]
        );
        assert!(rejection.is_none());
        assert_eq!(session.mode(), Mode::Bcm);
        // BCM mode already sends.
        let (actions, _) = run(&mut session, "send 123 1 AA");
        let frame = Frame::new(CanId::Standard(0x123), &[0xAA]).unwrap();
        assert_eq!(actions, vec![Action::Send(frame)]);
        let (actions, _) = run(&mut session, "rawmode");
        assert_eq!(
            actions,
            vec![Action::Reply(Reply::Ok), Action::StartForwarding]
        );
        assert_eq!(session.mode(), Mode::Raw);
        let (actions, _) = run(&mut session, "bcmmode");
        assert_eq!(
            actions,
            vec![Action::StopForwarding, Action::Reply(Reply::Ok)]
        );
    }

    #[test]
    fn unknown_channel_is_refused_and_closes() {
        let mut session = Session::new(vec!["can0".into()]);
        let (actions, rejection) = run(&mut session, "open vcan9");
        assert_eq!(
            actions,
            vec![
                Action::Reply(Reply::Error(
                    "no bus 'vcan9' here; this server offers can0".into()
                )),
                Action::Close
            ]
        );
        assert!(rejection.is_some());
        assert_eq!(session.mode(), Mode::NoBus);
    }

    #[test]
    fn bad_input_gets_an_error_reply_and_a_rejection() {
        let mut session = Session::new(vec!["can0".into()]);
        run(&mut session, "open can0");
        let cases = [
            (
                Token::Message("frobnicate".into()),
                "unknown command 'frobnicate'",
            ),
            (Token::Message("".into()), "unknown command ''"),
            (
                Token::Garbage { bytes: 5 },
                "5 bytes outside '< >'; commands look like '< send 123 1 AA >'",
            ),
            (
                Token::Oversized { bytes: 900 },
                "command of 900 bytes is too long",
            ),
            (
                Token::Truncated("send 1".into()),
                "command 'send 1' was cut off by a new '<'",
            ),
            (
                Token::Message("subscribe 0 0 123".into()),
                "'subscribe' is not offered by this server; use '< rawmode >'",
            ),
            (Token::Message("open can0".into()), "a bus is already open"),
        ];
        for (token, reason) in cases {
            let mut actions = Vec::new();
            let rejection = session.handle(token, &mut actions);
            assert_eq!(
                rejection,
                Some(Rejection {
                    reason: reason.into()
                })
            );
            assert_eq!(actions, vec![Action::Reply(Reply::Error(reason.into()))]);
        }
        // Still usable afterwards.
        assert_eq!(session.mode(), Mode::Bcm);
        let (actions, _) = run(&mut session, "echo");
        assert_eq!(actions, vec![Action::Reply(Reply::Echo)]);
    }

    /// linux-can/socketcand `state_raw.c`: a `send` it cannot read is
    /// logged and answered with nothing (python-can reads any `< error >`
    /// as an error frame, and its receive thread stops on one it cannot
    /// parse).
    #[test]
    fn a_malformed_send_is_logged_and_answered_with_nothing() {
        let mut session = Session::new(vec!["can0".into()]);
        run(&mut session, "open can0");
        run(&mut session, "rawmode");
        for (text, reason) in [
            ("send 123 1", "send: length says 1 data bytes but 0 follow"),
            (
                "send 123 2 AA",
                "send: length says 2 data bytes but 1 follow",
            ),
            ("send 800 0", "standard CAN identifier 0x800 is above 0x7FF"),
            ("sendrtr 123", "sendrtr: expected '< sendrtr ID DLC >'"),
        ] {
            let (actions, rejection) = run(&mut session, text);
            assert_eq!(actions, vec![], "{text}");
            assert_eq!(
                rejection,
                Some(Rejection {
                    reason: reason.into()
                }),
                "{text}"
            );
        }
        let (actions, _) = run(&mut session, "send 123 1 AA");
        assert_eq!(
            actions,
            vec![Action::Send(
                Frame::new(CanId::Standard(0x123), &[0xAA]).unwrap()
            )]
        );
    }

    /// python-can writes a remote frame as a `send` without data, so
    /// python-canopen's node guarding arrives as zero-length frames on
    /// 0x700 + node: they go on the bus as the guarding requests (remote
    /// frames, CiA 301 §7.2.8.3.2.1) they are. Other zero-length frames
    /// stay data frames.
    #[test]
    fn a_zero_length_send_on_a_guarding_id_is_the_guarding_request() {
        let mut session = Session::new(vec!["can0".into()]);
        run(&mut session, "open can0");
        run(&mut session, "rawmode");
        let (actions, _) = run(&mut session, "send 703 0");
        assert_eq!(
            actions,
            vec![Action::Send(
                Frame::remote(CanId::Standard(0x703), 1).unwrap()
            )]
        );
        for text in ["send 123 0", "send 700 0", "send 00000703 0"] {
            let (actions, _) = run(&mut session, text);
            let [Action::Send(frame)] = actions.as_slice() else {
                panic!("{text}: {actions:?}");
            };
            assert!(!frame.is_remote(), "{text}");
            assert!(frame.data().is_empty(), "{text}");
        }
    }
}
