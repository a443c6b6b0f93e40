//! `candeck serve --eds-dir` with a broken file beside good ones: the
//! gateway starts, serves the good ones and lists the broken one with all
//! its problems in `GET /api/v1/eds`.

mod common;

#[tokio::test]
async fn a_broken_file_in_the_eds_dir_does_not_stop_serve() {
    let dir = std::env::temp_dir().join(format!("candeck-eds-dir-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    // A file of the corpus with several problems, usable (the synthetic
    // imitation of UniSwarm's uio44.eds), and one that is no EDS.
    let corpus = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/eds-corpus/synthetic/uniswarm-uio44-like.eds");
    std::fs::copy(&corpus, dir.join("uio44.eds")).unwrap();
    std::fs::write(dir.join("broken.eds"), [0u8, 159, 146, 150]).unwrap();
    let dir_arg = dir.display().to_string();
    let (mut server, _) = common::start(&[
        "serve",
        "--bus",
        "bench=virtual:empty",
        "--eds-dir",
        &dir_arg,
    ]);
    let (status, body) = common::json(&server.address, "GET", "/api/v1/eds", None).await;
    assert_eq!(status, 200, "{body}");
    let files = body["files"].as_array().unwrap();
    let file = |name: &str| {
        files
            .iter()
            .find(|file| file["name"] == name)
            .unwrap_or_else(|| panic!("{name} not in {body}"))
    };
    let uio44 = file("uio44.eds");
    assert_eq!(uio44["usable"], true, "{uio44}");
    assert_eq!(uio44["vendor_id"], 0x4A2);
    let warnings = uio44["warnings"].as_array().unwrap();
    assert!(warnings.len() >= 6, "{warnings:?}");
    let broken = file("broken.eds");
    assert_eq!(broken["usable"], false);
    assert!(
        broken["errors"][0]["message"]
            .as_str()
            .unwrap()
            .contains("binary"),
        "{broken}"
    );
    // The gateway serves.
    let (status, _) = common::json(&server.address, "GET", "/api/v1/buses", None).await;
    assert_eq!(status, 200);
    common::terminate(&mut server).await;
    std::fs::remove_dir_all(&dir).unwrap();
}
