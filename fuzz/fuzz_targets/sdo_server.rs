//! libFuzzer's entry to [`candeck_fuzz::sdo_server`] (what it checks is documented there).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| candeck_fuzz::sdo_server::run(data));
