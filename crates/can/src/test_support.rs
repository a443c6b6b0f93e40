//! Helpers shared by the unit tests.

/// Cases per property test: `default` in the normal test suite, or
/// `CANDECK_FUZZ_CASES` for a long fuzzing run (see `docs/testing.md`, "Fuzzing").
pub fn fuzz_cases(default: u32) -> u32 {
    std::env::var("CANDECK_FUZZ_CASES")
        .ok()
        .and_then(|cases| cases.parse().ok())
        .unwrap_or(default)
}
