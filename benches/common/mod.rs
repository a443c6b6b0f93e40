//! What the benchmarks share: how long each level runs, from the command
//! line (`cargo bench --bench NAME -- --seconds N --warmup N`).

use std::time::Duration;

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
