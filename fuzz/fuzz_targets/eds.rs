//! libFuzzer's entry to [`candeck_fuzz::eds`] (what it checks is documented there).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| candeck_fuzz::eds::run(data));
