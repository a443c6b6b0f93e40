//! `candeck eds check` as a user and a script meet it: every warning with
//! file:line, one summary line per file, exit status 0 when every file is
//! usable and 1 otherwise, `--strict` failing on warnings too, `--json`.

use std::path::{Path, PathBuf};
use std::process::Command;

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

fn repo(path: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(path)
        .display()
        .to_string()
}

/// A folder of its own in the temp dir with `files` written into it.
fn files(test: &str, files: &[(&str, &str)]) -> (PathBuf, Vec<String>) {
    let dir = std::env::temp_dir().join(format!("candeck-eds-check-{test}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let paths = files
        .iter()
        .map(|(name, text)| {
            let path = dir.join(name);
            std::fs::write(&path, text).unwrap();
            path.display().to_string()
        })
        .collect();
    (dir, paths)
}

const FLAWED: &str = "[DeviceInfo]\nVendorNumber=0x4A2\nProductNumber=7\n\
[MandatoryObjects]\nSupportedObjects=2\n1=0x1000\n2=0x1018\n\
[1000]\nParameterName=Device type\nDataType=0x0007\nAccessType=\nDefaultValue=0x00020191\n";

#[test]
fn warnings_name_file_and_line_and_each_file_gets_a_summary() {
    let own = repo("eds/umc1bds32.eds");
    let (dir, paths) = files("summary", &[("flawed.eds", FLAWED)]);
    let (code, stdout, stderr) = candeck(&["eds", "check", &own, &paths[0]]);
    assert_eq!(code, 0, "{stdout}{stderr}");
    assert!(stderr.is_empty(), "{stderr}");
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(
        lines[0],
        format!(
            "{own}: ok: EDS, 321 objects, 889 sub-entries, vendor 0x000004A2 (UniSwarm SASU), \
             product 0x00001001 (UMC1BDS32), revision 0x01000004, device type 0x00000192"
        )
    );
    let flawed = &paths[0];
    assert_eq!(
        lines[1..],
        [
            format!(
                "{flawed}:7: object 0x1018 is listed but there is no [1018] section; dropped from the list [dropped]"
            ),
            format!("{flawed}:11: AccessType is empty; read as rw [defaulted]"),
            format!(
                "{flawed}: usable, 2 warnings: EDS, 1 objects, 1 sub-entries, vendor 0x000004A2, product 0x00000007, revision none, device type 0x00020191"
            ),
        ]
    );
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_file_that_is_no_eds_fails_the_check_and_strict_fails_on_warnings() {
    let (dir, paths) = files(
        "status",
        &[("flawed.eds", FLAWED), ("notes.eds", "just some notes\n")],
    );
    let (code, stdout, stderr) = candeck(&["eds", "check", &paths[0]]);
    assert_eq!(code, 0, "{stdout}{stderr}");
    let (code, stdout, stderr) = candeck(&["eds", "check", "--strict", &paths[0]]);
    assert_eq!(code, 1, "{stdout}");
    assert_eq!(
        stderr.trim(),
        "candeck: error: 1 of 1 files not usable or with warnings (--strict)"
    );
    let (code, stdout, stderr) = candeck(&["eds", "check", &paths[0], &paths[1]]);
    assert_eq!(code, 1, "{stdout}");
    assert!(
        stdout.contains(&format!(
            "{}:1: no sections: this is not an EDS or DCF\n",
            paths[1]
        )),
        "{stdout}"
    );
    assert!(
        stdout.ends_with(&format!("{}: refused: not an EDS or DCF\n", paths[1])),
        "{stdout}"
    );
    assert_eq!(stderr.trim(), "candeck: error: 1 of 2 files not usable");
    // A file that cannot be opened is not usable either.
    let missing = dir.join("missing.eds").display().to_string();
    let (code, stdout, _) = candeck(&["eds", "check", &missing]);
    assert_eq!(code, 1);
    assert!(stdout.contains("refused"), "{stdout}");
    // No file at all is a usage error.
    let (code, _, stderr) = candeck(&["eds", "check"]);
    assert_eq!(code, 2, "{stderr}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn json_for_scripts() {
    let (dir, paths) = files(
        "json",
        &[("flawed.eds", FLAWED), ("binary.eds", "[FileInfo]\n\0\0\0")],
    );
    let (code, stdout, _) = candeck(&[
        "eds",
        "check",
        "--json",
        "--dictionary",
        &paths[0],
        &paths[1],
    ]);
    assert_eq!(code, 1);
    let files: serde_json::Value = serde_json::from_str(&stdout).expect("JSON");
    let flawed = &files[0];
    assert_eq!(flawed["file"], paths[0].as_str());
    assert_eq!(flawed["usable"], true);
    assert_eq!(flawed["objects"], 1);
    assert_eq!(flawed["vendor_number"], 0x4A2);
    assert_eq!(flawed["device_type"], 0x0002_0191);
    assert_eq!(flawed["warnings"][1]["line"], 11);
    assert_eq!(flawed["warnings"][1]["key"], "[1000] AccessType");
    assert_eq!(flawed["warnings"][1]["action"], "defaulted");
    let entry = &flawed["dictionary"][0]["subs"][0];
    assert_eq!(flawed["dictionary"][0]["index"], 0x1000);
    assert_eq!(entry["data_type"], 7);
    assert_eq!(entry["access"], "rw");
    assert_eq!(entry["default"], "0x00020191");
    let binary = &files[1];
    assert_eq!(binary["usable"], false);
    assert_eq!(binary["errors"][0]["line"], 2);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn the_whole_corpus_is_usable() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/eds-corpus");
    let mut args = vec!["eds".to_string(), "check".to_string()];
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path
            .extension()
            .is_some_and(|ext| ext == "eds" || ext == "dcf")
        {
            args.push(path.display().to_string());
        }
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (code, stdout, stderr) = candeck(&args);
    assert_eq!(code, 0, "{stderr}");
    let summaries = stdout
        .lines()
        .filter(|line| line.contains(": ok: ") || line.contains(": usable, "))
        .count();
    assert_eq!(summaries, args.len() - 2, "{stdout}");
}
