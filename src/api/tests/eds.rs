//! `GET /eds`: the catalog with every file, its warnings, and the files of
//! `--eds-dir` that were left out with all their problems, while the good
//! ones serve.

use crate::emulator::RackOf;
use std::sync::Arc;

use axum::http::StatusCode;
use serde_json::Value as Json;

use super::get;
use crate::api::{AppState, app};
use crate::gateway::EdsCatalog;
use crate::gateway::RegistryConfig;

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
    // No EDS: left out, the rest serves; an EDS that names no vendor.
    std::fs::write(dir.join("broken.eds"), "just notes\n").unwrap();
    let anonymous = GOOD
        .replace("VendorNumber=0x77\n", "")
        .replace("AccessType=ro", "AccessType=");
    std::fs::write(dir.join("anonymous.eds"), anonymous).unwrap();
    let catalog = EdsCatalog::with_dir(&dir).unwrap();
    let served = crate::emulator::open_bus(
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
    // The names of its [DeviceInfo], for the catalog to show.
    assert_eq!(
        (&umc["vendor_name"], &umc["product_name"]),
        (&"UniSwarm SASU".into(), &"UMC1BDS32".into())
    );
    assert_eq!(umc["profile"], "umc");
    assert_eq!(umc["objects"], 321);
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
    assert_eq!(broken["product_name"], Json::Null);
    assert!(
        broken["errors"][0]["message"]
            .as_str()
            .unwrap()
            .contains("not an EDS"),
        "{broken}"
    );
    // Every problem of the file, not the first only. A file that names no
    // vendor joins the catalog, to be assigned to nodes by hand.
    let anonymous = file("anonymous.eds");
    assert_eq!(anonymous["usable"], true);
    assert_eq!(anonymous["matches_by_identity"], false);
    assert_eq!(anonymous["errors"], serde_json::json!([]));
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

/// A synthetic file of the corpus that names no product (as Technosoft's
/// iPOS files): a CiA 402 drive with a manufacturer parameter, 0x2076
/// "Jerk time".
const IPOS_LIKE: &str =
    include_str!("../../../tests/data/eds-corpus/synthetic/technosoft-ipos-like.eds");

async fn send(
    app: &axum::Router,
    method: axum::http::Method,
    uri: &str,
    body: Option<&str>,
) -> (StatusCode, Json) {
    let (status, text, _) = super::support::raw_call(
        app,
        method,
        uri,
        "application/json",
        body.map(str::to_string),
    )
    .await;
    let json = if text.is_empty() {
        Json::Null
    } else {
        serde_json::from_str(&text).unwrap_or_else(|err| panic!("{uri}: {err}: {text}"))
    };
    (status, json)
}

async fn upload(app: &axum::Router, name: &str, text: &str) -> (StatusCode, Json) {
    let (status, body, _) = super::support::raw_call(
        app,
        axum::http::Method::POST,
        &format!("/api/v1/eds?name={name}"),
        "text/plain",
        Some(text.to_string()),
    )
    .await;
    (status, serde_json::from_str(&body).unwrap())
}

fn listed<'a>(list: &'a Json, name: &str) -> Option<&'a Json> {
    list["files"]
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f["name"] == name)
}

#[tokio::test(start_paused = true)]
async fn an_upload_is_validated_kept_0600_listed_as_uploaded_and_deleted() {
    use axum::http::Method;
    let dir = std::env::temp_dir().join(format!("candeck-api-eds-up-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let catalog = EdsCatalog::builtin()
        .unwrap()
        .with_uploads(dir.join("eds"))
        .unwrap();
    let served = crate::emulator::open_bus(
        "bench",
        &"virtual:empty".parse().unwrap(),
        Arc::new(catalog),
        RegistryConfig::default(),
        500_000,
    )
    .await
    .unwrap();
    let app = app(AppState::new([served]));

    // Usable with a warning: kept, the warning in the answer.
    let (status, body) = upload(&app, "ipos.eds", IPOS_LIKE).await;
    assert_eq!(status, StatusCode::CREATED, "{body}");
    assert_eq!(body["source"], "uploaded");
    assert_eq!(body["matches_by_identity"], false);
    assert_eq!(body["profile"], "cia402");
    assert_eq!(body["warnings"].as_array().unwrap().len(), 1, "{body}");
    let kept = dir.join("eds/ipos.eds");
    assert_eq!(std::fs::read_to_string(&kept).unwrap(), IPOS_LIKE);
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&kept).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
    }
    let (_, list) = get(&app, "/api/v1/eds").await;
    assert_eq!(list["uploads_kept_in"], "data_dir");
    assert_eq!(listed(&list, "ipos.eds").unwrap()["source"], "uploaded");

    // No EDS at all: refused with its problem, nothing kept.
    let (status, body) = upload(&app, "notes.eds", "just notes\n").await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert_eq!(body["error"]["code"], "invalid_eds");
    assert!(!dir.join("eds/notes.eds").exists());
    // A name taken, a name that is no file name.
    let (status, body) = upload(&app, "ipos.eds", IPOS_LIKE).await;
    assert_eq!(
        (status, &body["error"]["code"]),
        (StatusCode::CONFLICT, &"eds_conflict".into())
    );
    let (status, body) = upload(&app, "umc1bds32.eds", IPOS_LIKE).await;
    assert_eq!(
        (status, &body["error"]["code"]),
        (StatusCode::CONFLICT, &"eds_conflict".into())
    );
    for bad in ["..%2Fx.eds", ".hidden.eds", "x.txt", "a%20b.eds"] {
        let (status, body) = upload(&app, bad, IPOS_LIKE).await;
        assert_eq!(
            (status, &body["error"]["code"]),
            (StatusCode::BAD_REQUEST, &"invalid_request".into()),
            "{bad}"
        );
    }

    // No name at all.
    let (status, body, _) = super::support::raw_call(
        &app,
        Method::POST,
        "/api/v1/eds",
        "text/plain",
        Some(IPOS_LIKE.to_string()),
    )
    .await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert!(body.contains("invalid_request"), "{body}");

    // Only uploaded files are deleted.
    let response = send(&app, Method::DELETE, "/api/v1/eds/umc1bds32.eds", None).await;
    assert_eq!(response.0, StatusCode::CONFLICT, "{}", response.1);
    let response = send(&app, Method::DELETE, "/api/v1/eds/nothing.eds", None).await;
    assert_eq!(response.1["error"]["code"], "unknown_eds");
    let response = send(&app, Method::DELETE, "/api/v1/eds/ipos.eds", None).await;
    assert_eq!(response.0, StatusCode::NO_CONTENT, "{}", response.1);
    assert!(!kept.exists());
    let (_, list) = get(&app, "/api/v1/eds").await;
    assert!(listed(&list, "ipos.eds").is_none());

    // Audited, with the file's name.
    let (_, audit) = get(&app, "/api/v1/events?kind=audit&limit=100").await;
    let entries: Vec<(String, Option<String>, u64)> = audit
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["operation"].as_str().unwrap().to_string(),
                e["item"].as_str().map(str::to_string),
                e["status"].as_u64().unwrap(),
            )
        })
        .collect();
    assert!(
        entries.contains(&("upload eds".into(), Some("ipos.eds".into()), 201)),
        "{entries:?}"
    );
    assert!(
        entries.contains(&("delete eds".into(), Some("ipos.eds".into()), 204)),
        "{entries:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[tokio::test(start_paused = true)]
async fn without_a_data_dir_uploads_are_kept_in_memory() {
    let (app, _) = super::support::demo().await;
    let (status, body) = upload(&app, "ipos.eds", IPOS_LIKE).await;
    assert_eq!(status, StatusCode::CREATED, "{body}");
    let (_, list) = get(&app, "/api/v1/eds").await;
    assert_eq!(list["uploads_kept_in"], "memory");
    assert_eq!(listed(&list, "ipos.eds").unwrap()["source"], "uploaded");
}

/// The demo bus and, at node 6, a device built from the iPOS-like file: it
/// answers the file's objects, and names no product to be matched by.
async fn demo_with_anonymous_drive() -> (axum::Router, AppState) {
    let served = super::support::open("demo", "virtual:demo").await;
    let dictionary = crate::canopen::eds::Eds::parse(IPOS_LIKE, "ipos.eds")
        .unwrap()
        .dictionary;
    let device =
        crate::sim::device::DeviceCore::new(dictionary, crate::canopen::NodeId::new(6).unwrap())
            .unwrap();
    served.rack().unwrap().add_device(device).unwrap();
    let nodes = served.scan().await.unwrap();
    assert_eq!(nodes.len(), 4, "{nodes:?}");
    let state = AppState::new([served]);
    (app(state.clone()), state)
}

#[tokio::test(start_paused = true)]
async fn a_node_whose_eds_names_no_product_is_assigned_then_read_and_written_by_name() {
    use axum::http::Method;
    let (app, state) = demo_with_anonymous_drive().await;
    let (status, body) = upload(&app, "ipos.eds", IPOS_LIKE).await;
    assert_eq!(status, StatusCode::CREATED, "{body}");
    // Nothing describes node 6: its names are unknown.
    let (_, node) = get(&app, "/api/v1/buses/demo/nodes/6").await;
    assert_eq!(
        (&node["eds"], &node["profile"]),
        (&Json::Null, &"cia402".into()),
        "{node}"
    );
    let response = get(&app, "/api/v1/buses/demo/nodes/6/od/Jerk%20time/0").await;
    assert_eq!(response.0, StatusCode::NOT_FOUND, "{}", response.1);

    let (status, node) = send(
        &app,
        Method::PUT,
        "/api/v1/buses/demo/nodes/6/eds",
        Some(r#"{"file":"ipos.eds"}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{node}");
    assert_eq!(
        (&node["eds"], &node["eds_assigned"], &node["profile"]),
        (&"ipos.eds".into(), &true.into(), &"cia402".into())
    );
    let (status, read) = get(&app, "/api/v1/buses/demo/nodes/6/od/Jerk%20time/0").await;
    assert_eq!(status, StatusCode::OK, "{read}");
    assert_eq!(read["value"], 100, "{read}");
    let (status, written) = send(
        &app,
        Method::PUT,
        "/api/v1/buses/demo/nodes/6/od/Jerk%20time/0",
        Some(r#"{"value": 250}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{written}");
    let (_, read) = get(&app, "/api/v1/buses/demo/nodes/6/od/0x2076/0").await;
    assert_eq!(read["value"], 250, "{read}");
    let (_, listing) = get(&app, "/api/v1/buses/demo/nodes/6/od?q=jerk").await;
    assert_eq!(listing.as_array().map(Vec::len), Some(1), "{listing}");

    // The catalog says who uses the file, and keeps it while assigned.
    let (_, list) = get(&app, "/api/v1/eds").await;
    assert_eq!(
        listed(&list, "ipos.eds").unwrap()["nodes"],
        serde_json::json!([{"bus": "demo", "node": 6, "assigned": true}])
    );
    let response = send(&app, Method::DELETE, "/api/v1/eds/ipos.eds", None).await;
    assert_eq!(
        response.1["error"]["code"], "eds_conflict",
        "{}",
        response.1
    );
    // Unknown files and buses.
    let response = send(
        &app,
        Method::PUT,
        "/api/v1/buses/demo/nodes/6/eds",
        Some(r#"{"file":"nothing.eds"}"#),
    )
    .await;
    assert_eq!(response.1["error"]["code"], "unknown_eds");

    // The assignment holds through a boot-up of the node.
    let (status, body) = send(
        &app,
        Method::POST,
        "/api/v1/buses/demo/nodes/6/nmt",
        Some(r#"{"command":"reset_node"}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{body}");
    tokio::time::sleep(std::time::Duration::from_secs(2)).await;
    state.gateway.bus("demo").unwrap().settle().await;
    let (_, node) = get(&app, "/api/v1/buses/demo/nodes/6").await;
    assert_eq!(
        (
            &node["eds"],
            &node["eds_assigned"],
            &node["identification"]["state"]
        ),
        (&"ipos.eds".into(), &true.into(), &"done".into()),
        "{node}"
    );

    // A node id not heard yet takes the file when it is.
    let (status, nothing) = send(
        &app,
        Method::PUT,
        "/api/v1/buses/demo/nodes/7/eds",
        Some(r#"{"file":"ipos.eds"}"#),
    )
    .await;
    assert_eq!((status, &nothing), (StatusCode::OK, &Json::Null));
    let dictionary = crate::canopen::eds::Eds::parse(IPOS_LIKE, "ipos.eds")
        .unwrap()
        .dictionary;
    let device =
        crate::sim::device::DeviceCore::new(dictionary, crate::canopen::NodeId::new(7).unwrap())
            .unwrap();
    let served = &state.gateway.bus("demo").unwrap();
    served.rack().unwrap().add_device(device).unwrap();
    served.scan().await.unwrap();
    let (_, node) = get(&app, "/api/v1/buses/demo/nodes/7").await;
    assert_eq!(
        (&node["eds"], &node["eds_assigned"]),
        (&"ipos.eds".into(), &true.into()),
        "{node}"
    );
    let (_, read) = get(&app, "/api/v1/buses/demo/nodes/7/od/Jerk%20time/0").await;
    assert_eq!(read["value"], 100, "{read}");
    send(&app, Method::DELETE, "/api/v1/buses/demo/nodes/7/eds", None).await;

    // Back to matching by identity: nothing describes it again.
    let (status, node) = send(&app, Method::DELETE, "/api/v1/buses/demo/nodes/6/eds", None).await;
    assert_eq!(status, StatusCode::OK, "{node}");
    assert_eq!(
        (&node["eds"], &node["eds_assigned"]),
        (&Json::Null, &false.into())
    );
    let response = send(&app, Method::DELETE, "/api/v1/eds/ipos.eds", None).await;
    assert_eq!(response.0, StatusCode::NO_CONTENT, "{}", response.1);
}

/// Generic CiA 402: a drive described by a file that is no UniSwarm or JMC
/// one gets the drive REST by its device type. The virtual UMC1BD90
/// answers CiA 402 (0x6040/0x6041 at axis 1), so assigning the iPOS-like
/// file to it makes it a generic drive that is enabled through 0x6040.
#[tokio::test(start_paused = true)]
async fn a_drive_assigned_a_non_uniswarm_402_eds_lists_its_axis_and_is_enabled() {
    use axum::http::Method;
    let served = super::support::open("bench", "virtual:empty").await;
    served
        .rack()
        .unwrap()
        .add(
            crate::sim::products::Product::Umc1bd90,
            crate::canopen::NodeId::new(1).unwrap(),
        )
        .unwrap();
    served.scan().await.unwrap();
    let app = app(AppState::new([served]));
    let (status, body) = upload(&app, "ipos.eds", IPOS_LIKE).await;
    assert_eq!(status, StatusCode::CREATED, "{body}");
    let (status, node) = send(
        &app,
        Method::PUT,
        "/api/v1/buses/bench/nodes/1/eds",
        Some(r#"{"file":"ipos.eds"}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{node}");
    assert_eq!(node["profile"], "cia402", "{node}");
    let (status, axes) = get(&app, "/api/v1/buses/bench/nodes/1/axes").await;
    assert_eq!(status, StatusCode::OK, "{axes}");
    assert_eq!(axes.as_array().map(Vec::len), Some(1), "{axes}");
    let (status, axis) = send(
        &app,
        Method::POST,
        "/api/v1/buses/bench/nodes/1/axes/1/state",
        Some(r#"{"target":"operation_enabled"}"#),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{axis}");
    let (_, statusword) = get(&app, "/api/v1/buses/bench/nodes/1/od/Statusword/0").await;
    assert_eq!(
        statusword["value"].as_u64().unwrap() & 0x6F,
        0x27,
        "operation enabled: {statusword}"
    );
}

/// Issue 30, finding 7: the uploaded files are held to a quota of files
/// and of bytes; an upload beyond is refused (409 `eds_quota`, naming the
/// key), nothing kept, and a delete makes room again.
#[tokio::test(start_paused = true)]
async fn uploads_beyond_the_quota_of_files_or_bytes_are_refused() {
    let (app, state) = super::support::demo().await;
    let catalog = state.gateway.eds_catalog().unwrap();
    let size = IPOS_LIKE.len() as u64;
    catalog.set_quota(crate::gateway::EdsQuota {
        max_files: 2,
        max_bytes: 10 * size,
    });
    for name in ["a.eds", "b.eds"] {
        let (status, body) = upload(&app, name, IPOS_LIKE).await;
        assert_eq!(status, StatusCode::CREATED, "{name}: {body}");
    }
    let (status, body) = upload(&app, "c.eds", IPOS_LIKE).await;
    assert_eq!(status, StatusCode::CONFLICT, "{body}");
    assert_eq!(body["error"]["code"], "eds_quota", "{body}");
    assert!(
        body["error"]["message"]
            .as_str()
            .unwrap()
            .contains("eds_max_files 2"),
        "{body}"
    );
    let (_, list) = get(&app, "/api/v1/eds").await;
    assert!(listed(&list, "c.eds").is_none(), "{list}");
    let (status, body) = send(&app, axum::http::Method::DELETE, "/api/v1/eds/a.eds", None).await;
    assert_eq!(status, StatusCode::NO_CONTENT, "{body}");
    let (status, body) = upload(&app, "c.eds", IPOS_LIKE).await;
    assert_eq!(status, StatusCode::CREATED, "{body}");
    assert_eq!(catalog.uploaded(), (2, 2 * size));

    // The bytes: room for two and a half files.
    catalog.set_quota(crate::gateway::EdsQuota {
        max_files: 100,
        max_bytes: 2 * size + size / 2,
    });
    let (status, body) = upload(&app, "d.eds", IPOS_LIKE).await;
    assert_eq!(status, StatusCode::CONFLICT, "{body}");
    assert!(
        body["error"]["message"]
            .as_str()
            .unwrap()
            .contains("eds_max_mb"),
        "{body}"
    );
    assert_eq!(catalog.uploaded(), (2, 2 * size));
}
