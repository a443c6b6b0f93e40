//! The optional peers of the tests and benchmarks: the Python peers
//! (python-can, python-canopen) in the `.venv` that `scripts/test` makes, and
//! Debian's `mosquitto`. One rule for all of them: a peer that is there is
//! used; one that is missing is skipped, said on stderr as `skipped: WHO:
//! REASON`, unless `CANDECK_REQUIRE_PEERS` is set (`scripts/test` and
//! `scripts/bench` set it), which makes a missing peer a failure, so that CI
//! never skips them.
//!
//! libtest cannot mark a test skipped at run time (rust-lang/rust#68007): a
//! skipped test returns early and is counted as passed, so the line on
//! stderr is what tells. It is written to the process's stderr itself, not
//! through `eprintln!`, which the test harness captures for passing tests.
//!
//! Included by path by `tests/python_peers.rs` and `benches/common/mod.rs`
//! (not by `tests/common/mod.rs`: `benches/stream_fanout.rs` includes that
//! one too, and a file is one module of a crate).

#![allow(dead_code)] // Each test or benchmark uses part of it.

use std::ffi::OsStr;
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// The variable that turns a missing peer from a skip into a failure.
pub(crate) const REQUIRE: &str = "CANDECK_REQUIRE_PEERS";

/// What to do about one peer.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum Decision {
    /// It is there: use it.
    Run(PathBuf),
    /// It is missing and not required: say so and go on without it.
    Skip(String),
    /// It is missing and required: fail with this message.
    Fail(String),
}

/// Whether the value of a yes-or-no variable (`CANDECK_REQUIRE_PEERS`,
/// `CANDECK_BENCH_SMOKE`) says yes: set, and neither empty nor `0`.
pub(crate) fn flag(value: Option<&OsStr>) -> bool {
    value.is_some_and(|value| !value.is_empty() && value != OsStr::new("0"))
}

/// The decision for a peer found (its path) or missing (why).
pub(crate) fn decide(found: Result<PathBuf, String>, required: bool) -> Decision {
    match found {
        Ok(path) => Decision::Run(path),
        Err(reason) if required => Decision::Fail(format!(
            "{reason}; {REQUIRE} is set, so a missing peer is a failure (scripts/test installs them)"
        )),
        Err(reason) => Decision::Skip(reason),
    }
}

/// Where the Python with the peers is: `CANDECK_PYTHON` when it is set (the
/// caller said where; it is used as it is), otherwise `venv_python` (the
/// checkout's `.venv/bin/python`) when it exists.
pub(crate) fn python_location(
    candeck_python: Option<&OsStr>,
    venv_python: &Path,
) -> Result<PathBuf, String> {
    match candeck_python {
        Some(python) if !python.is_empty() => Ok(PathBuf::from(python)),
        _ if venv_python.exists() => Ok(venv_python.to_path_buf()),
        _ => Err(format!(
            "no Python peers: CANDECK_PYTHON is not set and {} is missing (scripts/test makes it: python-can and python-canopen in .venv)",
            venv_python.display()
        )),
    }
}

/// Where Debian's `mosquitto` is, among `candidates`.
pub(crate) fn mosquitto_location(candidates: &[&Path]) -> Result<PathBuf, String> {
    candidates
        .iter()
        .find(|path| path.exists())
        .map(|path| path.to_path_buf())
        .ok_or_else(|| {
            "no mosquitto (Debian: apt-get install mosquitto; scripts/test installs it)".to_string()
        })
}

/// Applies [`decide`] with the environment's `CANDECK_REQUIRE_PEERS` for
/// `who` (a test's name, a benchmark's row): the path, `None` after the
/// skip line on stderr, or a panic.
fn apply(who: &str, found: Result<PathBuf, String>) -> Option<PathBuf> {
    match decide(found, flag(std::env::var_os(REQUIRE).as_deref())) {
        Decision::Run(path) => Some(path),
        Decision::Skip(reason) => {
            // Past the test harness's capture, so that every run shows it.
            let _ = writeln!(std::io::stderr(), "skipped: {who}: {reason}");
            None
        }
        Decision::Fail(message) => panic!("{who}: {message}"),
    }
}

/// The Python interpreter with python-can and python-canopen, for `who`;
/// `None` when it is skipped (said on stderr).
pub(crate) fn python(who: &str) -> Option<PathBuf> {
    let venv = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python");
    apply(
        who,
        python_location(std::env::var_os("CANDECK_PYTHON").as_deref(), &venv),
    )
}

/// Debian's `mosquitto`, for `who`; `None` when it is skipped (said on
/// stderr).
pub(crate) fn mosquitto(who: &str) -> Option<PathBuf> {
    apply(
        who,
        mosquitto_location(&[
            Path::new("/usr/sbin/mosquitto"),
            Path::new("/usr/bin/mosquitto"),
        ]),
    )
}
