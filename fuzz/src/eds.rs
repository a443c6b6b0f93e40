//! EDS/DCF reader (CiA 306): arbitrary bytes as a file. Nothing may panic,
//! and a file the reader accepts writes back to text that reads to the same
//! dictionary (what `PUT .../config.dcf` and the EDS catalog rely on).

use candeck::canopen::eds::Eds;

/// One input: what the fuzz target and the seed replay run.
pub fn run(data: &[u8]) {
    if let Ok(eds) = Eds::parse_bytes(data, "fuzz.eds") {
        let written = eds.write();
        let again = Eds::parse(&written, "again.eds")
            .unwrap_or_else(|error| panic!("what we wrote does not read back: {error}\n{written}"));
        assert_eq!(
            again, eds,
            "the written file reads to another dictionary:\n{written}"
        );
    }
}
