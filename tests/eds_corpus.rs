//! The corpus of real EDS and DCF files (`tests/data/eds-corpus/`, sources
//! and licences in its SOURCES.md): every file loads with the tolerant
//! reader (warnings allowed, no error), and what it read writes back to text
//! that reads to the same device description.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use candeck::canopen::eds::{Eds, read_eds_file};

fn corpus() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/eds-corpus");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("the corpus folder")
        .map(|entry| entry.expect("a folder entry").path())
        .filter(|path| {
            path.extension()
                .and_then(|ext| ext.to_str())
                .is_some_and(|ext| {
                    ext.eq_ignore_ascii_case("eds") || ext.eq_ignore_ascii_case("dcf")
                })
        })
        .collect();
    files.sort();
    files
}

#[test]
fn every_corpus_file_loads_and_reads_back_the_same() {
    let files = corpus();
    assert!(files.len() >= 60, "{} files", files.len());
    let mut vendors = BTreeSet::new();
    let mut refused = Vec::new();
    for path in &files {
        let eds = match read_eds_file(path) {
            Ok(eds) => eds,
            Err(error) => {
                refused.push(error.to_string());
                continue;
            }
        };
        assert!(!eds.dictionary.is_empty(), "{}: no objects", path.display());
        for warning in &eds.warnings {
            assert!(warning.line > 0, "{warning}");
            assert!(
                warning
                    .file
                    .ends_with(&*path.file_name().unwrap().to_string_lossy())
            );
        }
        if let Some(vendor) = eds
            .device_info
            .vendor_name
            .clone()
            .filter(|v| !v.is_empty())
        {
            vendors.insert(vendor);
        }
        let written = eds.write();
        let again = Eds::parse(&written, "again.eds")
            .unwrap_or_else(|error| panic!("{}: {error}", path.display()));
        assert_eq!(again, eds, "{} does not read back", path.display());
    }
    assert!(refused.is_empty(), "{refused:#?}");
    assert!(vendors.len() >= 6, "{vendors:?}");
}

/// Files of the corpus with the defect classes the reader tolerates: each
/// loads, with a warning of its class at the line where the file has it.
#[test]
fn the_corpus_has_the_defect_classes_and_each_is_a_warning() {
    let classes = [
        // UniSwarm's umckin1.eds (imitated): an empty AccessType.
        ("synthetic/uniswarm-umckin1-like.eds", "AccessType is empty"),
        // Faulhaber: "ö" of a code page.
        (
            "KITmedical+kacanopen_old__eds_Faulhaber_605.3150.51-V-EK-2-60.eds",
            "read as Windows-1252",
        ),
        // Faulhaber: INTEGER8 limits 0x00..0xFF, which is 0..-1.
        (
            "KITmedical+kacanopen_old__eds_Faulhaber_605.3150.51-V-EK-2-60.eds",
            "is above HighLimit",
        ),
        // CANopenNode's editor: a DOMAIN DefaultValue that is no hex bytes.
        (
            "CANopenNode+CANopenNode__example_IO.eds",
            "a DOMAIN value is hex bytes",
        ),
        (
            "samsamfire+gocanopen__pkg_od_base.eds",
            "a DOMAIN value is hex bytes",
        ),
        // UniSwarm's uio44.eds (imitated): an object listed without a
        // section, a manufacturer's data type, an empty AccessType, a DOMAIN
        // default, all reported together.
        ("synthetic/uniswarm-uio44-like.eds", "there is no"),
        ("synthetic/uniswarm-uio44-like.eds", "read as DOMAIN"),
        ("synthetic/uniswarm-uio44-like.eds", "AccessType is empty"),
        (
            "synthetic/uniswarm-uio44-like.eds",
            "a DOMAIN value is hex bytes",
        ),
        // No [MandatoryObjects] (UniSwarm's custom.eds, imitated).
        (
            "synthetic/uniswarm-custom-like.eds",
            "no [MandatoryObjects]",
        ),
        // The revision as text (UniSwarm's umc1bds32_v1.0.2.eds, imitated).
        (
            "synthetic/uniswarm-revision-text.eds",
            "RevisionNumber=1.0.2 is not a number",
        ),
        // A default above its limit (UniSwarm's uio8ad_v1.0.1.eds, imitated).
        (
            "synthetic/uniswarm-uio8ad-like.eds",
            "is above the high limit",
        ),
        // A negative unsigned default (UniSwarm's uio1led.eds, imitated).
        (
            "synthetic/uniswarm-uio1led-like.eds",
            "is read as 0xFFFFFFFF",
        ),
        // No product number (Technosoft iPOS), no identity at all (SCHUNK,
        // Pilz), imitated.
        (
            "synthetic/technosoft-ipos-like.eds",
            "matches no device by identity",
        ),
        (
            "synthetic/schunk-pilz-like.dcf",
            "matches no device by identity",
        ),
        // C literal suffixes and negative unsigned defaults.
        ("heig-vd-iai+canopen-stack__od.eds", "is read as"),
    ];
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/eds-corpus");
    for (file, class) in classes {
        let eds = read_eds_file(dir.join(file)).unwrap_or_else(|error| panic!("{error}"));
        assert!(
            eds.warnings.iter().any(|w| w.message.contains(class)),
            "{file}: no '{class}' in {:#?}",
            eds.warnings
        );
    }
}

/// The synthetic files that stand for the files whose licence keeps them
/// out of the repository (SOURCES.md): each loads, says whose defect class
/// it imitates, and is listed in SOURCES.md.
#[test]
fn every_synthetic_file_loads_and_names_the_source_it_imitates() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/eds-corpus/synthetic");
    let sources = std::fs::read_to_string(dir.join("../SOURCES.md")).unwrap();
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .collect();
    files.sort();
    assert!(files.len() >= 8, "{files:?}");
    for path in files {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with("; Synthetic"), "{name}");
        assert!(text.contains("imitates"), "{name}");
        assert!(
            sources.contains(&format!("`synthetic/{name}`")),
            "{name} not in SOURCES.md"
        );
        let eds = read_eds_file(&path).unwrap_or_else(|error| panic!("{error}"));
        assert!(!eds.warnings.is_empty(), "{name} shows no defect");
        let again = Eds::parse(&eds.write(), "again.eds").unwrap();
        assert_eq!(again, eds, "{name} does not read back");
    }
}
