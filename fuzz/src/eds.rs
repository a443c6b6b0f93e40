//! EDS/DCF reader (CiA 306): arbitrary bytes as a file, against the tolerant
//! reader. Nothing may panic; what is refused is refused with a line inside
//! the file; every warning names a line inside the file; and a file the
//! reader accepts writes back to text that reads to the same description
//! (what `PUT .../config.dcf` and the EDS catalog rely on).
//!
//! Seeds: candeck's own files, and real files of the corpus
//! (`corpus-*`, sources in tests/data/eds-corpus/SOURCES.md) with the
//! defects the reader tolerates.

use candeck::canopen::eds::Eds;

/// One input: what the fuzz target and the seed replay run.
pub fn run(data: &[u8]) {
    // Lines as the reader counts them (CR LF, LF or a lone CR), plus one for
    // warnings about what is missing at the end.
    let lines = data.iter().filter(|&&b| b == b'\n' || b == b'\r').count() + 1;
    match Eds::parse_bytes(data, "fuzz.eds") {
        Err(error) => assert!(error.line <= lines, "{error}: beyond {lines} lines"),
        Ok(eds) => {
            for warning in &eds.warnings {
                assert!(
                    (1..=lines).contains(&warning.line),
                    "{warning}: beyond {lines} lines"
                );
            }
            let written = eds.write();
            let again = Eds::parse(&written, "again.eds").unwrap_or_else(|error| {
                panic!("what we wrote does not read back: {error}\n{written}")
            });
            assert_eq!(
                again, eds,
                "the written file reads to another dictionary:\n{written}"
            );
        }
    }
}
