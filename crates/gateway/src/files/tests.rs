//! The modes of what candeck keeps in its data directory (issue 19, point
//! 10): 0700 directories, 0600 files, and an older history tightened.

#![cfg(unix)]

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};

use super::*;
use crate::can::VirtualHub;
use crate::canopen::NodeId;
use crate::history::History;
use crate::recording::{Limits, Recorder};

/// A fresh directory path under the temporary directory (not made),
/// removed when dropped.
struct Scratch(PathBuf);

impl Scratch {
    fn new(name: &str) -> Self {
        let path =
            std::env::temp_dir().join(format!("candeck-files-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&path);
        Self(path)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn mode(path: &Path) -> u32 {
    std::fs::metadata(path).unwrap().permissions().mode() & 0o777
}

#[test]
fn the_data_directory_and_the_history_are_private() {
    let scratch = Scratch::new("history");
    let dir = scratch.0.join("data");
    create_private_dir(&dir).unwrap();
    assert_eq!(mode(&dir), 0o700);
    let history = History::open(&dir).unwrap();
    drop(history);
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        assert_eq!(mode(&path), 0o600, "{}", path.display());
    }
    assert_eq!(mode(&dir.join("history.sqlite3")), 0o600);
}

#[test]
fn an_older_world_readable_history_is_tightened() {
    let scratch = Scratch::new("older");
    std::fs::create_dir_all(&scratch.0).unwrap();
    drop(History::open(&scratch.0).unwrap());
    let file = scratch.0.join("history.sqlite3");
    std::fs::set_permissions(&file, std::fs::Permissions::from_mode(0o644)).unwrap();
    drop(History::open(&scratch.0).unwrap());
    assert_eq!(mode(&file), 0o600);
}

#[tokio::test(start_paused = true)]
async fn recordings_are_private() {
    let scratch = Scratch::new("recordings");
    let dir = scratch.0.join("recordings");
    let hub = VirtualHub::new("demo");
    let recorder = Recorder::new(&hub.attach(), Some(dir.clone()));
    let status = recorder.start(Limits::default()).await.unwrap();
    recorder.stop().await.unwrap();
    assert_eq!(mode(&dir), 0o700);
    assert_eq!(mode(&dir.join(status.file.unwrap())), 0o600);
}

#[test]
fn saved_values_of_virtual_devices_are_private() {
    let scratch = Scratch::new("saved");
    let path = candeck_sim::persist::saved_path(&scratch.0, "umc1bds32", NodeId::new(1).unwrap());
    let mut saved = candeck_sim::device::SavedValues::new();
    saved.insert((0x2001, 0), crate::canopen::od::Value::Unsigned8(42));
    candeck_sim::persist::write_saved(&path, &saved).unwrap();
    assert_eq!(mode(&path), 0o600);
    assert_eq!(mode(path.parent().unwrap()), 0o700);
}
