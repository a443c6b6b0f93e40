//! socketcand (the text protocol of a socketcand daemon, as candeck speaks it
//! as client and server): arbitrary bytes, cut into arbitrary pieces, through
//! the framer and both line parsers. Nothing may panic, the framer's buffer
//! stays bounded, and what the parsers accept writes back to text that parses
//! to the same thing.

use candeck::can::socketcand::protocol::{
    Command, Framer, ServerMessage, Token, parse_command, parse_server_message, write_command,
    write_send,
};

/// The framer's message limit here: small, so that oversized runs happen.
const MAX_MESSAGE: usize = 64;

/// One input: what the fuzz target and the seed replay run.
pub fn run(data: &[u8]) {
    // The first byte chooses the piece size, the rest is the stream.
    let Some((&piece, stream)) = data.split_first() else {
        return;
    };
    let piece = usize::from(piece).max(1);
    let mut framer = Framer::new(MAX_MESSAGE);
    let mut tokens = Vec::new();
    for chunk in stream.chunks(piece) {
        framer.push(chunk, &mut tokens);
        assert!(
            framer.pending() <= MAX_MESSAGE,
            "framer holds {} bytes",
            framer.pending()
        );
    }
    for token in tokens {
        let (Token::Message(text) | Token::Truncated(text)) = token else {
            continue;
        };
        if let Ok(command) = parse_command(&text) {
            round_trip(&command);
        }
        let _: Option<ServerMessage> = parse_server_message(&text).ok();
    }
}

/// A command candeck accepted, written as candeck writes it, reads back the same.
fn round_trip(command: &Command) {
    let mut out = Vec::new();
    match command {
        // Only the verb is kept, as the server only names it in its error.
        Command::Unsupported(_) => return,
        Command::Send(frame) => {
            if write_send(&mut out, frame).is_err() {
                return;
            }
        }
        _ => write_command(&mut out, command),
    }
    let mut framer = Framer::new(usize::MAX);
    let mut tokens = Vec::new();
    framer.push(&out, &mut tokens);
    match tokens.as_slice() {
        [Token::Message(text)] => assert_eq!(parse_command(text).as_ref(), Ok(command), "{text:?}"),
        other => panic!(
            "{command:?} wrote {:?} as {other:?}",
            String::from_utf8_lossy(&out)
        ),
    }
}
