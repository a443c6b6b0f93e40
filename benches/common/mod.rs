//! What the benchmarks share: how long each level runs, from the command
//! line (`cargo bench --bench NAME -- --seconds N --warmup N`); the smoke
//! run (`CANDECK_BENCH_SMOKE`); the optional peers ([`peers`], the tests'
//! rule); and ending in failure when requests failed.

#![allow(dead_code)] // Each benchmark uses part of it.

#[path = "../../tests/common/peers.rs"]
pub(crate) mod peers;
pub(crate) mod process;

use std::time::Duration;

/// The variable of the smoke run: every benchmark cut to about a second with
/// minimal sizes, to show that it still runs to its end (`scripts/test`
/// runs them so, in the debug test build). Its figures mean nothing.
pub(crate) const SMOKE: &str = "CANDECK_BENCH_SMOKE";

/// Whether this is a smoke run: `CANDECK_BENCH_SMOKE` set, neither empty
/// nor `0`.
pub(crate) fn smoke() -> bool {
    peers::flag(std::env::var_os(SMOKE).as_deref())
}

/// `normal`, or `smoke` in a smoke run: the default of a size or a time.
pub(crate) fn pick<T>(normal: T, smoke: T) -> T {
    if self::smoke() { smoke } else { normal }
}

/// Says on stdout, first, that this is a smoke run.
pub(crate) fn announce_smoke(bench: &str) {
    if smoke() {
        println!("{bench}: smoke run ({SMOKE} is set): minimal sizes, the figures mean nothing");
    }
}

/// Ends the process with status 1 after printing each failure, when there
/// are any: a benchmark whose requests failed has no figures to report.
pub(crate) fn exit_on_failures(bench: &str, failures: &[String]) {
    if failures.is_empty() {
        return;
    }
    for failure in failures {
        eprintln!("{bench}: FAIL: {failure}");
    }
    std::process::exit(1);
}

#[derive(Clone, Copy)]
pub(crate) struct Options {
    pub warmup: Duration,
    pub measure: Duration,
}

impl Options {
    /// `--seconds N` (measured) and `--warmup N` over the defaults given;
    /// `cargo bench` passes `--bench`, and anything else is ignored too.
    pub(crate) fn from_args(warmup: Duration, measure: Duration) -> Self {
        let mut options = Self { warmup, measure };
        let args: Vec<String> = std::env::args().collect();
        let mut i = 1;
        while i < args.len() {
            let value = args.get(i + 1).and_then(|v| v.parse::<f64>().ok());
            match (args[i].as_str(), value) {
                ("--seconds", Some(v)) => options.measure = Duration::from_secs_f64(v),
                ("--warmup", Some(v)) => options.warmup = Duration::from_secs_f64(v),
                _ => {
                    i += 1;
                    continue;
                }
            }
            i += 2;
        }
        options
    }
}
