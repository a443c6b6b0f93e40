//! libFuzzer's entry to [`candeck_fuzz::socketcand_lines`] (what it checks is documented there).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| candeck_fuzz::socketcand_lines::run(data));
