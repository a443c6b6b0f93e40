//! The reader's rules for what a second set of real EDS files showed
//! (docs/eds.md, "The rules"), one small file written for each rule in
//! `tests/data/eds-rules/`, as `candeck eds check` and the gateway show
//! them: comments after values and on lines of their own, object types
//! spelled out, `AccessType` `R`/`W` and a token that means nothing, empty
//! `ObjFlags=`, and a file that yields no object.

use std::path::Path;
use std::process::Command;

use serde_json::Value as Json;

mod common;

fn rule_file(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/eds-rules")
        .join(name)
        .display()
        .to_string()
}

/// `candeck eds check ARGS`: exit status, stdout, stderr.
fn candeck(args: &[&str]) -> (i32, String, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_candeck"))
        .args(args)
        .env_remove("CANDECK_LOG")
        .output()
        .expect("candeck runs");
    (
        output.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

/// `candeck eds check --json --dictionary` of one rule file: its exit
/// status and its JSON object.
fn check(name: &str) -> (i32, Json) {
    let path = rule_file(name);
    let (code, stdout, stderr) = candeck(&["eds", "check", "--json", "--dictionary", &path]);
    let files: Json = serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("{e}: {stderr}"));
    (code, files[0].clone())
}

/// The entry `index` sub `sub` of a file's `--dictionary`.
fn entry(file: &Json, index: u16, sub: u8) -> Option<&Json> {
    file["dictionary"]
        .as_array()?
        .iter()
        .find(|object| object["index"] == index)?["subs"]
        .as_array()?
        .iter()
        .find(|entry| entry["sub_index"] == sub)
}

/// The (line, action) of each warning.
fn warnings(file: &Json) -> Vec<(u64, String)> {
    file["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| {
            (
                w["line"].as_u64().unwrap(),
                w["action"].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

#[test]
fn a_comment_after_a_value_is_cut_where_the_value_reads_only_without_it() {
    let (code, file) = check("trailing-comments.eds");
    assert_eq!(code, 0, "{file}");
    assert_eq!(file["usable"], true);
    assert_eq!(file["objects"], 3, "{file}");
    let device_type = entry(&file, 0x1000, 0).unwrap();
    assert_eq!(device_type["data_type"], 7);
    assert_eq!(device_type["access"], "ro");
    assert_eq!(device_type["default"], "0x00000191");
    assert_eq!(file["device_type"], 0x191);
    assert_eq!(file["vendor_number"], 0x77);
    assert!(entry(&file, 0x1018, 1).is_some(), "{file}");
    // A name and a string keep their '#'.
    assert_eq!(entry(&file, 0x1018, 1).unwrap()["name"], "Vendor-ID #1");
    let string = entry(&file, 0x2000, 0).unwrap();
    assert_eq!(string["name"], "Maker #1 name");
    assert_eq!(string["default"], "Vendor #1");
    // Each comment cut is said at its line; a `;` comment is the INI one.
    let corrected = |line| (line, "corrected".to_string());
    assert_eq!(
        warnings(&file),
        [
            corrected(8),
            corrected(12),
            corrected(20),
            corrected(21),
            corrected(22),
            corrected(23),
            corrected(27),
            (32, "kept".to_string()),
        ]
    );
    assert_eq!(
        file["warnings"][2]["message"],
        "ObjectType=0x07 # VAR: '# VAR' after the value is read as a comment"
    );
    assert_eq!(file["warnings"][2]["key"], "[1000] ObjectType");
}

#[test]
fn lines_that_start_with_a_hash_are_comments_in_one_warning() {
    let (code, file) = check("comment-lines.eds");
    assert_eq!(code, 0, "{file}");
    assert_eq!(file["objects"], 2, "{file}");
    // `#DefaultValue=20` is a comment, not a second key.
    assert_eq!(entry(&file, 0x2000, 0).unwrap()["default"], "10");
    assert_eq!(warnings(&file), [(15, "kept".to_string())]);
    assert_eq!(
        file["warnings"][0]["message"],
        "a line that starts with '#' is read as a comment (CiA 306 comments start with ';'), \
         and so are the 2 more below"
    );
}

#[test]
fn spelled_out_object_types_load_with_their_objects() {
    let (code, file) = check("spelled-object-types.eds");
    assert_eq!(code, 0, "{file}");
    assert_eq!(file["objects"], 3, "{file}");
    let types: Vec<(u64, u64)> = file["dictionary"]
        .as_array()
        .unwrap()
        .iter()
        .map(|o| {
            (
                o["index"].as_u64().unwrap(),
                o["object_type"].as_u64().unwrap(),
            )
        })
        .collect();
    assert_eq!(types, [(0x1000, 7), (0x1018, 9), (0x2000, 8)]);
    // The compact array: sub 0 and two entries.
    assert!(entry(&file, 0x2000, 2).is_some(), "{file}");
    assert_eq!(entry(&file, 0x1018, 1).unwrap()["default"], "0x77");
    let lines: Vec<u64> = warnings(&file).iter().map(|(line, _)| *line).collect();
    assert_eq!(lines, [18, 25, 29, 36, 43]);
    assert_eq!(
        file["warnings"][4]["message"],
        "ObjectType=ARRAY is a name where CiA 306 writes a number; read as 0x8"
    );
}

#[test]
fn a_file_that_yields_no_object_is_not_usable_and_says_why() {
    let path = rule_file("no-object.eds");
    let (code, stdout, stderr) = candeck(&["eds", "check", &path]);
    assert_eq!(code, 1, "{stdout}");
    assert_eq!(stderr.trim(), "candeck: error: 1 of 1 files not usable");
    assert_eq!(
        stdout.lines().last().unwrap(),
        format!(
            "{path}: not usable, 3 warnings: no object could be read: object 0x1000 is listed \
             but there is no [1000] section; dropped from the list (line 12)"
        )
    );
    let (code, file) = check("no-object.eds");
    assert_eq!(code, 1);
    assert_eq!(file["usable"], false);
    assert_eq!(file["objects"], 0);
    assert_eq!(file["errors"][0]["line"], 12);
    assert!(
        file["errors"][0]["message"]
            .as_str()
            .unwrap()
            .starts_with("no object could be read: "),
        "{file}"
    );
    // Beside a usable file, only it fails.
    let (code, _, stderr) = candeck(&["eds", "check", &rule_file("comment-lines.eds"), &path]);
    assert_eq!(code, 1);
    assert_eq!(stderr.trim(), "candeck: error: 1 of 2 files not usable");
}

#[test]
fn access_types_r_and_w_are_ro_and_wo_and_a_token_that_means_nothing_refuses_its_entry() {
    let (code, file) = check("access-tokens.eds");
    assert_eq!(code, 0, "{file}");
    assert_eq!(entry(&file, 0x2001, 0).unwrap()["access"], "ro");
    assert_eq!(entry(&file, 0x2002, 0).unwrap()["access"], "wo");
    assert!(entry(&file, 0x2003, 0).is_none(), "{file}");
    assert_eq!(file["objects"], 3);
    assert_eq!(
        warnings(&file),
        [
            (29, "corrected".to_string()),
            (36, "corrected".to_string()),
            (42, "dropped".to_string()),
        ]
    );
    assert_eq!(
        file["warnings"][0]["message"],
        "AccessType=R is no access type of CiA 306; read as ro"
    );
}

#[test]
fn empty_obj_flags_are_one_warning_for_the_file() {
    let (code, file) = check("empty-objflags.eds");
    assert_eq!(code, 0, "{file}");
    assert_eq!(file["objects"], 3);
    assert_eq!(warnings(&file), [(23, "kept".to_string())]);
    assert_eq!(
        file["warnings"][0]["message"],
        "ObjFlags= is empty here and in 2 more sections; each is read as no flags"
    );
}

/// A DCF for the node described by access-tokens.eds, setting its `R`
/// entry 0x2001 (which the DCF itself, for its part, calls `rw`).
const DCF_SETTING_THE_R_ENTRY: &str = "[DeviceInfo]\nVendorNumber=0x77\nProductNumber=0x35\n\
RevisionNumber=1\n[MandatoryObjects]\nSupportedObjects=1\n1=0x1000\n\
[OptionalObjects]\nSupportedObjects=1\n1=0x2001\n\
[1000]\nParameterName=Device type\nObjectType=0x7\nDataType=0x0007\nAccessType=ro\n\
DefaultValue=0x191\nPDOMapping=0\n\
[2001]\nParameterName=Measured value\nObjectType=0x7\nDataType=0x0007\nAccessType=rw\n\
DefaultValue=0\nPDOMapping=1\nParameterValue=5\n\
[DeviceComissioning]\nNodeID=5\n";

/// The gateway: a file with no object is listed as broken, never matched;
/// a node described by the `R` file lists the entry as `ro`, and a restore
/// that would write it is refused before anything is written.
#[tokio::test]
async fn the_gateway_lists_a_file_with_no_object_as_broken_and_keeps_r_entries_read_only() {
    let dir = std::env::temp_dir().join(format!("candeck-eds-rules-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    for name in ["access-tokens.eds", "no-object.eds"] {
        std::fs::copy(rule_file(name), dir.join(name)).unwrap();
    }
    let dir_arg = dir.display().to_string();
    let (mut server, _) = common::start(&[
        "serve",
        "--bus",
        "bench=virtual:io401@5",
        "--eds-dir",
        &dir_arg,
    ]);
    let address = server.address.clone();

    let (status, body) = common::json(&address, "GET", "/api/v1/eds", None).await;
    assert_eq!(status, 200, "{body}");
    let file = |name: &str| -> Json {
        body["files"]
            .as_array()
            .unwrap()
            .iter()
            .find(|file| file["name"] == name)
            .cloned()
            .unwrap_or_else(|| panic!("{name} not in {body}"))
    };
    let broken = file("no-object.eds");
    assert_eq!(broken["usable"], false, "{broken}");
    assert_eq!(broken["nodes"], serde_json::json!([]));
    let error = broken["errors"][0]["message"].as_str().unwrap();
    assert!(
        error.contains("no object could be read: object 0x1000 is listed"),
        "{error}"
    );
    assert_eq!(broken["warnings"].as_array().unwrap().len(), 3, "{broken}");
    assert_eq!(file("access-tokens.eds")["usable"], true);

    // The I/O module at node 5, described by the R file by hand.
    let node = "/api/v1/buses/bench/nodes/5";
    let (status, body) = common::poll(&address, node, |status, _| status == 200).await;
    assert_eq!(status, 200, "{body}");
    let (status, body) = common::json(
        &address,
        "PUT",
        &format!("{node}/eds"),
        Some(r#"{"file":"access-tokens.eds"}"#),
    )
    .await;
    assert_eq!(status, 200, "{body}");

    let (status, body) = common::json(&address, "GET", &format!("{node}/od"), None).await;
    assert_eq!(status, 200, "{body}");
    let access = |index: &str| -> Option<Json> {
        body.as_array()
            .unwrap()
            .iter()
            .find(|object| object["index"] == index)
            .map(|object| object["subs"][0]["access"].clone())
    };
    assert_eq!(access("0x2001"), Some("ro".into()), "{body}");
    assert_eq!(access("0x2002"), Some("wo".into()), "{body}");
    assert_eq!(access("0x2003"), None, "{body}");

    // A write of the R entry by a restore: refused before the first write.
    let response = common::request(
        &address,
        "PUT",
        &format!("{node}/config.dcf"),
        "text/plain",
        Some(DCF_SETTING_THE_R_ENTRY),
        std::time::Duration::from_secs(20),
    )
    .await;
    assert_eq!(response.status, 400, "{}", response.body);
    let answer = response.json();
    assert_eq!(answer["error"]["code"], "invalid_dcf", "{answer}");
    assert_eq!(
        answer["error"]["message"],
        "0x2001 sub 0 (Measured value): ro in the node's dictionary, so it cannot be written"
    );
    common::terminate(&mut server).await;
    std::fs::remove_dir_all(&dir).unwrap();
}
