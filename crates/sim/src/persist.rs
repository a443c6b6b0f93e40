//! Saved parameters on disk (`--data-dir`): what a virtual device saved with
//! 0x1010 survives a restart of candeck, as a real device's flash survives a
//! power cycle.
//!
//! One JSON file per device, `DIR/devices/PRODUCT-NODE.json`: a list of
//! `{"index": "0x2001", "sub": 0, "data_type": "u8", "value": 42}`, written to
//! a temporary file and renamed, so a crash never leaves half a file. An
//! unconfigured LSS device (`PRODUCT@lss`) keeps its values in
//! `DIR/devices/PRODUCT-lss-SERIAL.json`. What LSS store configuration kept
//! (CiA 305 §6.4.5) is next to it, in `….lss.json`:
//! `{"node_id": 10, "bit_timing": null}` (`null` node-ID: unconfigured).
//! A program image downloaded to 0x1F50 (CiA 302-3, [`super::program`]) is
//! next to it too, byte for byte, in `….program.bin`.

use std::path::{Path, PathBuf};

use serde_json::{Value as Json, json};

use crate::canopen::NodeId;
use crate::canopen::od::{DataType, Value, format_index, parse_index};

use super::device::{LssStored, SavedValues};

/// A saved-values file that cannot be read or written.
#[derive(Debug, thiserror::Error)]
pub enum PersistError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {problem}")]
    Invalid { path: PathBuf, problem: String },
}

/// Where the saved values of `product` at `node` live under `dir`.
pub fn saved_path(dir: &Path, product: &str, node: NodeId) -> PathBuf {
    dir.join("devices").join(format!("{product}-{node}.json"))
}

/// Where the saved values of the unconfigured LSS device of `product` with
/// serial number `serial` live under `dir`.
pub fn saved_path_lss(dir: &Path, product: &str, serial: u32) -> PathBuf {
    dir.join("devices")
        .join(format!("{product}-lss-{serial}.json"))
}

/// Where what LSS stored is kept, next to the saved values in `saved`.
pub fn lss_path(saved: &Path) -> PathBuf {
    saved.with_extension("lss.json")
}

/// Where a device's program image is kept, next to the saved values in
/// `saved`.
pub fn program_path(saved: &Path) -> PathBuf {
    saved.with_extension("program.bin")
}

/// The program image kept at `path`; `None` when there is none.
pub fn read_program(path: &Path) -> Result<Option<Vec<u8>>, PersistError> {
    match std::fs::read(path) {
        Ok(image) => Ok(Some(image)),
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(source) => Err(PersistError::Read {
            path: path.to_path_buf(),
            source,
        }),
    }
}

/// Keeps `image` at `path`; `None` (a cleared program) removes the file.
pub fn write_program(path: &Path, image: Option<&[u8]>) -> Result<(), PersistError> {
    match image {
        Some(image) => write_private(path, image),
        None => match std::fs::remove_file(path) {
            Err(err) if err.kind() != std::io::ErrorKind::NotFound => Err(PersistError::Write {
                path: path.to_path_buf(),
                source: err,
            }),
            _ => Ok(()),
        },
    }
}

/// What LSS stored, from `path`; `None` when nothing was stored.
pub fn read_lss(path: &Path) -> Result<Option<LssStored>, PersistError> {
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => {
            return Err(PersistError::Read {
                path: path.to_path_buf(),
                source,
            });
        }
    };
    let invalid = |problem: &str| PersistError::Invalid {
        path: path.to_path_buf(),
        problem: problem.to_string(),
    };
    let json: Json = serde_json::from_str(&text).map_err(|_| invalid("not JSON"))?;
    let node_id = match json.get("node_id") {
        None | Some(Json::Null) => None,
        Some(value) => Some(
            value
                .as_u64()
                .and_then(|raw| u8::try_from(raw).ok())
                .and_then(|raw| NodeId::new(raw).ok())
                .ok_or_else(|| invalid("node_id is not 1 to 127 or null"))?,
        ),
    };
    let bit_timing = match json.get("bit_timing") {
        None | Some(Json::Null) => None,
        Some(value) => Some(
            value
                .as_u64()
                .and_then(|raw| u8::try_from(raw).ok())
                .ok_or_else(|| invalid("bit_timing is not 0 to 255 or null"))?,
        ),
    };
    Ok(Some(LssStored {
        node_id,
        bit_timing,
    }))
}

/// Writes what LSS stored to `path` (next to the saved values).
pub fn write_lss(path: &Path, stored: &LssStored) -> Result<(), PersistError> {
    let text = json!({
        "node_id": stored.node_id.map(NodeId::get),
        "bit_timing": stored.bit_timing,
    })
    .to_string();
    write_private(path, &text)
}

/// The values saved in `path`; none when the file does not exist yet.
pub fn read_saved(path: &Path) -> Result<SavedValues, PersistError> {
    let text = match std::fs::read_to_string(path) {
        Ok(text) => text,
        Err(err) if err.kind() == std::io::ErrorKind::NotFound => return Ok(SavedValues::new()),
        Err(source) => {
            return Err(PersistError::Read {
                path: path.to_path_buf(),
                source,
            });
        }
    };
    let invalid = |problem: String| PersistError::Invalid {
        path: path.to_path_buf(),
        problem,
    };
    let entries: Vec<Json> =
        serde_json::from_str(&text).map_err(|err| invalid(format!("not a JSON list: {err}")))?;
    let mut saved = SavedValues::new();
    for (n, entry) in entries.iter().enumerate() {
        let field = |name: &str| {
            entry
                .get(name)
                .ok_or_else(|| invalid(format!("entry {n} has no '{name}'")))
        };
        let index = field("index")?
            .as_str()
            .and_then(parse_index)
            .ok_or_else(|| invalid(format!("entry {n}: index is not like \"0x2001\"")))?;
        let sub = field("sub")?
            .as_u64()
            .and_then(|sub| u8::try_from(sub).ok())
            .ok_or_else(|| invalid(format!("entry {n}: sub is not 0 to 255")))?;
        let data_type: DataType = field("data_type")?
            .as_str()
            .and_then(|name| name.parse().ok())
            .ok_or_else(|| invalid(format!("entry {n}: unknown data_type")))?;
        let value = Value::from_json(data_type, field("value")?)
            .map_err(|err| invalid(format!("entry {n}: {err}")))?;
        saved.insert((index, sub), value);
    }
    Ok(saved)
}

/// Writes `saved` to `path`, creating its directory.
pub fn write_saved(path: &Path, saved: &SavedValues) -> Result<(), PersistError> {
    let entries: Vec<Json> = saved
        .iter()
        .map(|((index, sub), value)| {
            json!({
                "index": format_index(*index),
                "sub": sub,
                "data_type": value.data_type().short_name(),
                "value": value.to_json(),
            })
        })
        .collect();
    let text = serde_json::to_string_pretty(&entries).unwrap_or_else(|_| "[]".to_string());
    write_private(path, &text)
}

/// Writes `text` to `path` by a temporary file, only the user reading it.
fn write_private(path: &Path, text: impl AsRef<[u8]>) -> Result<(), PersistError> {
    let write_error = |source| PersistError::Write {
        path: path.to_path_buf(),
        source,
    };
    if let Some(dir) = path.parent() {
        // In the gateway's data directory: only its user reads it (0700
        // and 0600, as the gateway's own files).
        let mut builder = std::fs::DirBuilder::new();
        builder.recursive(true);
        #[cfg(unix)]
        {
            use std::os::unix::fs::DirBuilderExt;
            builder.mode(0o700);
        }
        builder.create(dir).map_err(write_error)?;
    }
    let mut temporary = path.as_os_str().to_owned();
    temporary.push(".tmp");
    let temporary = PathBuf::from(temporary);
    let mut options = std::fs::OpenOptions::new();
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(0o600);
    }
    let mut file = options
        .write(true)
        .create(true)
        .truncate(true)
        .open(&temporary)
        .map_err(write_error)?;
    std::io::Write::write_all(&mut file, text.as_ref()).map_err(write_error)?;
    drop(file);
    std::fs::rename(&temporary, path).map_err(write_error)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("candeck-persist-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    #[test]
    fn saved_values_round_trip_through_the_file() {
        let dir = scratch("round-trip");
        let path = saved_path(&dir, "umc1bds32", NodeId::new(1).unwrap());
        assert!(path.ends_with("devices/umc1bds32-1.json"));
        assert_eq!(read_saved(&path).unwrap(), SavedValues::new());
        let mut saved = SavedValues::new();
        saved.insert((0x2001, 0), Value::Unsigned8(42));
        saved.insert((0x2004, 0), Value::Integer64(-5_000_000_000));
        saved.insert((0x2000, 0), Value::VisibleString("kept".into()));
        saved.insert((0x2005, 0), Value::Real32(1.5));
        write_saved(&path, &saved).unwrap();
        assert_eq!(read_saved(&path).unwrap(), saved);
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn a_damaged_file_is_an_error_naming_it() {
        let dir = scratch("damaged");
        let path = saved_path(&dir, "jmc", NodeId::new(2).unwrap());
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        for (text, problem) in [
            ("not json", "not a JSON list"),
            (r#"[{"sub": 0}]"#, "entry 0 has no 'index'"),
            (
                r#"[{"index": "0x2001", "sub": 300, "data_type": "u8", "value": 1}]"#,
                "sub is not 0 to 255",
            ),
            (
                r#"[{"index": "0x2001", "sub": 0, "data_type": "u8", "value": 300}]"#,
                "entry 0:",
            ),
        ] {
            std::fs::write(&path, text).unwrap();
            let err = read_saved(&path).unwrap_err().to_string();
            assert!(err.starts_with(&path.display().to_string()), "{err}");
            assert!(err.contains(problem), "{err}");
        }
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn lss_stored_round_trips_next_to_the_saved_values() {
        let dir = scratch("lss");
        let saved = saved_path_lss(&dir, "uio1led", 0x101);
        assert!(saved.ends_with("devices/uio1led-lss-257.json"));
        let path = lss_path(&saved);
        assert!(path.ends_with("devices/uio1led-lss-257.lss.json"));
        assert_eq!(read_lss(&path).unwrap(), None);
        for stored in [
            LssStored {
                node_id: NodeId::new(10).ok(),
                bit_timing: Some(2),
            },
            LssStored::default(),
        ] {
            write_saved(&saved, &SavedValues::new()).unwrap();
            write_lss(&path, &stored).unwrap();
            assert_eq!(read_lss(&path).unwrap(), Some(stored));
        }
        std::fs::write(&path, r#"{"node_id": 200}"#).unwrap();
        let err = read_lss(&path).unwrap_err().to_string();
        assert!(err.contains("node_id is not 1 to 127"), "{err}");
        let _ = std::fs::remove_dir_all(dir);
    }
}
