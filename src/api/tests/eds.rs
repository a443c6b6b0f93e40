//! `GET /eds`: the catalog with every file, its warnings, and the files of
//! `--eds-dir` that were left out with all their problems, while the good
//! ones serve.

use std::sync::Arc;

use axum::http::StatusCode;
use serde_json::Value as Json;

use super::get;
use crate::api::{AppState, ServedBus, app};
use crate::gateway::profile::EdsCatalog;
use crate::gateway::registry::RegistryConfig;

const GOOD: &str = "[DeviceInfo]\nVendorNumber=0x77\nProductNumber=0x10\nRevisionNumber=1\n\
[MandatoryObjects]\nSupportedObjects=1\n1=0x1000\n\
[1000]\nParameterName=Device type\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x00020192\n";

#[tokio::test(start_paused = true)]
async fn the_catalog_lists_every_file_with_its_problems_and_the_ones_left_out() {
    let dir = std::env::temp_dir().join(format!("candeck-api-eds-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("good.eds"), GOOD).unwrap();
    // Usable, with a warning: an empty AccessType.
    let flawed = GOOD
        .replace("ProductNumber=0x10", "ProductNumber=0x11")
        .replace("AccessType=ro", "AccessType=");
    std::fs::write(dir.join("flawed.eds"), flawed).unwrap();
    // No EDS, and an EDS that names no vendor: left out, the rest serves.
    std::fs::write(dir.join("broken.eds"), "just notes\n").unwrap();
    let anonymous = GOOD
        .replace("VendorNumber=0x77\n", "")
        .replace("AccessType=ro", "AccessType=");
    std::fs::write(dir.join("anonymous.eds"), anonymous).unwrap();
    let catalog = EdsCatalog::with_dir(&dir).unwrap();
    let served = ServedBus::open(
        "bench",
        &"virtual:empty".parse().unwrap(),
        Arc::new(catalog),
        RegistryConfig::default(),
        500_000,
    )
    .await
    .unwrap();
    let app = app(AppState::new([served]));

    let (status, body) = get(&app, "/api/v1/eds").await;
    assert_eq!(status, StatusCode::OK, "{body}");
    let files = body["files"].as_array().unwrap();
    let file = |name: &str| -> &Json {
        files
            .iter()
            .find(|file| file["name"] == name)
            .unwrap_or_else(|| panic!("{name} not in {body}"))
    };
    let umc = file("umc1bds32.eds");
    assert_eq!(umc["source"], "built_in");
    assert_eq!(umc["usable"], true);
    assert_eq!(umc["vendor_id"], 0x4A2);
    assert_eq!(umc["profile"], "umc");
    assert_eq!(umc["objects"], 320);
    assert_eq!(umc["warnings"], serde_json::json!([]));

    let good = file("good.eds");
    assert_eq!(
        (
            &good["source"],
            &good["usable"],
            &good["device_type"],
            &good["profile"]
        ),
        (
            &"dir".into(),
            &true.into(),
            &0x0002_0192.into(),
            &"cia402".into()
        )
    );
    let flawed = file("flawed.eds");
    assert_eq!(flawed["usable"], true);
    assert_eq!(flawed["warnings"].as_array().unwrap().len(), 1, "{flawed}");
    assert_eq!(flawed["warnings"][0]["line"], 11);
    assert_eq!(flawed["warnings"][0]["key"], "[1000] AccessType");
    assert_eq!(flawed["warnings"][0]["action"], "defaulted");

    let broken = file("broken.eds");
    assert_eq!(broken["usable"], false);
    assert!(
        broken["errors"][0]["message"]
            .as_str()
            .unwrap()
            .contains("not an EDS"),
        "{broken}"
    );
    // Every problem of the file, not the first only.
    let anonymous = file("anonymous.eds");
    assert_eq!(anonymous["usable"], false);
    assert!(
        anonymous["errors"][0]["message"]
            .as_str()
            .unwrap()
            .contains("vendor number"),
        "{anonymous}"
    );
    let warnings: Vec<&str> = anonymous["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w["key"].as_str().unwrap_or(""))
        .collect();
    assert!(warnings.contains(&"[1000] AccessType"), "{warnings:?}");
    assert!(
        warnings.contains(&"[DeviceInfo] VendorNumber"),
        "{warnings:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
