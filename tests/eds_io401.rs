//! The EDS written for the virtual io401 (`eds/io401.eds`) passes
//! `candeck eds check --strict`: no warning, usable, a CiA 401 device type
//! with the identity the virtual device reports.

use std::process::Command;

#[test]
fn the_io401_eds_passes_eds_check_strict() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/eds/io401.eds");
    let output = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(["eds", "check", "--strict", "--json", path])
        .env_remove("CANDECK_LOG")
        .output()
        .expect("candeck runs");
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert_eq!(output.status.code(), Some(0), "{stdout}");
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let file = &report[0];
    assert_eq!(file["usable"], true);
    assert_eq!(file["warnings"], serde_json::json!([]));
    assert_eq!(file["errors"], serde_json::json!([]));
    assert_eq!(file["device_type"], 0x000F_0191);
    assert_eq!(file["product_number"], 0x401);
}
