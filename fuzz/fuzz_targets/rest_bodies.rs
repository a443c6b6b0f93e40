//! libFuzzer's entry to [`candeck_fuzz::rest_bodies`] (what it checks is documented there).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| candeck_fuzz::rest_bodies::run(data));
