//! The fuzz targets' checks (`fuzz/src/`) on every seed of `fuzz/seeds/` and,
//! when a coverage-guided run has grown one, every input of `fuzz/corpus/` and
//! every crash left in `fuzz/artifacts/`: the cheap smoke test of the fuzzing
//! that runs in the ordinary test build, with no instrumented build. The
//! coverage-guided runs themselves are `scripts/fuzz` (docs/testing.md).

#[path = "../fuzz/src/lib.rs"]
#[allow(dead_code, unreachable_pub)]
mod candeck_fuzz;

use std::path::{Path, PathBuf};

/// Every file of `fuzz/{dir}/{target}`, sorted; none when the folder is absent.
fn inputs(dir: &str, target: &str) -> Vec<PathBuf> {
    let folder = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz")
        .join(dir)
        .join(target);
    let Ok(entries) = std::fs::read_dir(&folder) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries
        .map(|entry| entry.expect("a readable folder entry").path())
        .filter(|path| path.is_file())
        .collect();
    files.sort();
    files
}

/// Runs `check` on every seed of `target` (at least one must exist) and on its
/// corpus and artifacts when present; a panic names the input.
fn replay(target: &str, check: fn(&[u8])) {
    let seeds = inputs("seeds", target);
    assert!(!seeds.is_empty(), "fuzz/seeds/{target} has no seed");
    let others = ["corpus", "artifacts"]
        .iter()
        .flat_map(|dir| inputs(dir, target));
    for path in seeds.iter().cloned().chain(others) {
        let data = std::fs::read(&path).expect("a readable input");
        let outcome = std::panic::catch_unwind(|| check(&data));
        assert!(outcome.is_ok(), "{target} fails on {}", path.display());
    }
}

#[test]
fn eds_seeds() {
    replay("eds", candeck_fuzz::eds::run);
}

#[test]
fn sdo_server_seeds() {
    replay("sdo_server", candeck_fuzz::sdo_server::run);
}

#[test]
fn sdo_client_seeds() {
    replay("sdo_client", candeck_fuzz::sdo_client::run);
}

#[test]
fn socketcand_lines_seeds() {
    replay("socketcand_lines", candeck_fuzz::socketcand_lines::run);
}

#[test]
fn rest_bodies_seeds() {
    replay("rest_bodies", candeck_fuzz::rest_bodies::run);
}
