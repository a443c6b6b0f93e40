//! Electronic data sheets and device configuration files (CiA 306): the INI
//! files that describe a device's object dictionary (EDS) and, with
//! `ParameterValue`s and `[DeviceComissioning]`, one configured device (DCF).
//!
//! The reader is our own (see `ini`), because vendor files are not the INI
//! that generic crates expect, and because every problem of a file must be
//! reported as `file:line: what is wrong, what was done` rather than as a
//! panic or a silently missing object. It takes what vendor files do:
//! case-insensitive names, CR LF, `$NODEID+0x180` defaults, quoted string
//! defaults, sub-sections with gaps, `CompactSubObj` arrays with their
//! `[xxxxName]` / `[xxxxValue]` sections, versions like `1.0.2` and dates in
//! either order (kept as text), Windows code pages. It is as tolerant as the
//! tools engineers use: a deviation from CiA 306 that a sensible reading
//! survives is an [`EdsWarning`] that says what was kept, corrected,
//! defaulted or dropped, and the rest of the file loads; only what is not an
//! EDS at all (no CiA 306 section, a binary file) is an [`EdsError`]. The
//! rules, one per defect class, are in docs/eds.md.
//!
//! # Layout
//!
//! - [`Eds`], [`read_eds_file`]: the whole file: [`FileInfo`], [`DeviceInfo`],
//!   dummy usage, comments, the [`ObjectDictionary`] and, in a DCF, the
//!   [`DeviceCommissioning`].
//! - [`compare()`]: our dictionary of a product against the vendor's.
//! - `ini`: the INI dialect of CiA 306.
//! - `read`: INI sections to an [`Eds`].
//! - `write`: an [`Eds`] back to text that reads back the same.

mod compare;
pub use compare::{Difference, compare};
mod ini;
mod read;
mod write;

#[cfg(test)]
mod tests;

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::path::Path;

use crate::NodeId;
use crate::od::{DictionaryError, ObjectDictionary, Value};

/// An EDS or DCF file, read or to be written.
#[derive(Debug, Clone, Default)]
pub struct Eds {
    pub file_info: FileInfo,
    pub device_info: DeviceInfo,
    /// `[DummyUsage]`: the data type indexes (0x0001–0x0007) the device
    /// accepts as dummy entries in RPDO mappings.
    pub dummy_usage: BTreeSet<u16>,
    /// `[Comments]`, one string per line.
    pub comments: Vec<String>,
    pub dictionary: ObjectDictionary,
    /// `[DeviceComissioning]` (CiA 306 spells it with one m): present in a
    /// DCF only.
    pub commissioning: Option<DeviceCommissioning>,
    /// What the reader got past, in line order (empty for an `Eds` that was
    /// built rather than read). Not part of equality: two reads of the same
    /// device from differently flawed files are the same `Eds`.
    pub warnings: Vec<EdsWarning>,
}

impl PartialEq for Eds {
    fn eq(&self, other: &Self) -> bool {
        // Destructured, so that a new field is not forgotten here.
        let Eds {
            file_info,
            device_info,
            dummy_usage,
            comments,
            dictionary,
            commissioning,
            warnings: _,
        } = self;
        *file_info == other.file_info
            && *device_info == other.device_info
            && *dummy_usage == other.dummy_usage
            && *comments == other.comments
            && *dictionary == other.dictionary
            && *commissioning == other.commissioning
    }
}

impl Eq for Eds {}

/// `[FileInfo]`, every value as written: vendors write
/// dates as MM-DD-YYYY or DD-MM-YYYY and versions as `1` or `1.0.2`, and
/// nothing here depends on them.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct FileInfo {
    pub file_name: Option<String>,
    pub file_version: Option<String>,
    pub file_revision: Option<String>,
    pub eds_version: Option<String>,
    pub description: Option<String>,
    pub creation_time: Option<String>,
    pub creation_date: Option<String>,
    pub created_by: Option<String>,
    pub modification_time: Option<String>,
    pub modification_date: Option<String>,
    pub modified_by: Option<String>,
    /// Keys CiA 306 does not define, in file order, so that writing keeps them.
    pub other: Vec<(String, String)>,
}

/// `[DeviceInfo]`. A value that is not a number where one
/// is expected stays in `other` as written (with a warning), because the
/// identity that counts is the device's own object 0x1018.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct DeviceInfo {
    pub vendor_name: Option<String>,
    pub vendor_number: Option<u32>,
    pub product_name: Option<String>,
    pub product_number: Option<u32>,
    pub revision_number: Option<u32>,
    pub order_code: Option<String>,
    /// The supported bit rates in kbit/s, from the `BaudRate_<kbit>=1` keys.
    pub baud_rates: BTreeSet<u32>,
    pub simple_boot_up_master: Option<bool>,
    pub simple_boot_up_slave: Option<bool>,
    /// The smallest unit of PDO mapping, in bits (8: byte-aligned mapping only).
    pub granularity: Option<u8>,
    pub dynamic_channels_supported: Option<u8>,
    pub group_messaging: Option<bool>,
    pub nr_of_rx_pdo: Option<u16>,
    pub nr_of_tx_pdo: Option<u16>,
    pub lss_supported: Option<bool>,
    pub compact_pdo: Option<u8>,
    /// Keys CiA 306 does not define and values that could not be read, in
    /// file order.
    pub other: Vec<(String, String)>,
}

/// `[DeviceComissioning]` of a DCF: where the configured
/// device sits on which network.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct DeviceCommissioning {
    /// As written; 1–127 for a usable node (see [`DeviceCommissioning::node`]).
    pub node_id: Option<u8>,
    pub node_name: Option<String>,
    /// In kbit/s.
    pub baudrate: Option<u32>,
    pub net_number: Option<u32>,
    pub network_name: Option<String>,
    pub canopen_manager: Option<bool>,
    pub lss_serial_number: Option<u32>,
    pub other: Vec<(String, String)>,
}

impl DeviceCommissioning {
    /// The node id, if it is one (templates write 0 or 255 for "not set").
    pub fn node(&self) -> Option<NodeId> {
        self.node_id.and_then(|id| NodeId::new(id).ok())
    }
}

/// A file that cannot be read at all (it could not be opened, or it is not
/// an EDS: empty, no CiA 306 section, binary): which file, which line (0
/// when the file itself could not be opened), and what is wrong.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EdsError {
    pub file: String,
    pub line: usize,
    pub message: String,
}

impl fmt::Display for EdsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            0 => write!(f, "{}: {}", self.file, self.message),
            line => write!(f, "{}:{line}: {}", self.file, self.message),
        }
    }
}

impl std::error::Error for EdsError {}

/// The largest EDS or DCF read from disk: CiA 306 files are kilobytes, the
/// largest vendors ship a few MiB.
pub const MAX_FILE_BYTES: u64 = 16 * 1024 * 1024;

/// Whether `path` is a file an EDS or DCF may be read from: a regular file
/// (not `/dev/zero`, not a FIFO that would block the reader) of at most
/// [`MAX_FILE_BYTES`] (issue 30, finding 7: `dcf = "/dev/zero"` read 4 GB
/// at start); its size.
pub fn check_file(path: &Path) -> std::io::Result<u64> {
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            "not a regular file (an EDS or DCF is one)",
        ));
    }
    if meta.len() > MAX_FILE_BYTES {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!(
                "{} bytes, more than the {MAX_FILE_BYTES} an EDS or DCF may have",
                meta.len()
            ),
        ));
    }
    Ok(meta.len())
}

/// The bytes of an EDS or DCF file checked by [`check_file`], read up to
/// [`MAX_FILE_BYTES`] whatever its size says (a file that grows meanwhile).
pub fn read_bounded(path: &Path) -> std::io::Result<Vec<u8>> {
    use std::io::Read as _;
    check_file(path)?;
    let mut bytes = Vec::new();
    std::fs::File::open(path)?
        .take(MAX_FILE_BYTES + 1)
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("more than the {MAX_FILE_BYTES} bytes an EDS or DCF may have"),
        ));
    }
    Ok(bytes)
}

/// Reads an EDS or DCF from disk, within [`read_bounded`]'s bound; errors
/// name the file by `path`.
pub fn read_eds_file(path: impl AsRef<Path>) -> Result<Eds, EdsError> {
    let path = path.as_ref();
    let file = path.display().to_string();
    let bytes = read_bounded(path).map_err(|error| EdsError {
        file: file.clone(),
        line: 0,
        message: error.to_string(),
    })?;
    Eds::parse_bytes(&bytes, &file)
}

/// A deviation from CiA 306 that the reader got past: an object section that
/// no list names, a `SubNumber` that does not count the sub-sections, a
/// `[DeviceInfo]` number that is not one, an empty `AccessType`...
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct EdsWarning {
    pub file: String,
    pub line: usize,
    /// What it is about: `[section] Key`, `[section]`, or empty for a line
    /// that is neither.
    pub key: String,
    /// What the reader did.
    pub action: Action,
    /// What is wrong and what was done, in words.
    pub message: String,
}

/// What the reader did about a deviation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Action {
    /// Read as written (the warning is information).
    Kept,
    /// Read the way its writer evidently meant (a C literal suffix dropped,
    /// `-1` in an unsigned type, an unknown data type as DOMAIN).
    Corrected,
    /// Missing or unreadable, and replaced by a default that is said.
    Defaulted,
    /// Left out: the rest of the file does not depend on it.
    Dropped,
}

impl Action {
    pub fn as_str(self) -> &'static str {
        match self {
            Action::Kept => "kept",
            Action::Corrected => "corrected",
            Action::Defaulted => "defaulted",
            Action::Dropped => "dropped",
        }
    }
}

impl fmt::Display for Action {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl fmt::Display for EdsWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}: {}", self.file, self.line, self.message)
    }
}

/// The characters of Windows-1252 for the bytes 0x80 to 0x9F; `None` for
/// the five it leaves undefined.
const WINDOWS_1252_HIGH: [Option<char>; 32] = [
    Some('\u{20AC}'),
    None,
    Some('\u{201A}'),
    Some('\u{0192}'),
    Some('\u{201E}'),
    Some('\u{2026}'),
    Some('\u{2020}'),
    Some('\u{2021}'),
    Some('\u{02C6}'),
    Some('\u{2030}'),
    Some('\u{0160}'),
    Some('\u{2039}'),
    Some('\u{0152}'),
    None,
    Some('\u{017D}'),
    None,
    None,
    Some('\u{2018}'),
    Some('\u{2019}'),
    Some('\u{201C}'),
    Some('\u{201D}'),
    Some('\u{2022}'),
    Some('\u{2013}'),
    Some('\u{2014}'),
    Some('\u{02DC}'),
    Some('\u{2122}'),
    Some('\u{0161}'),
    Some('\u{203A}'),
    Some('\u{0153}'),
    None,
    Some('\u{017E}'),
    Some('\u{0178}'),
];

/// `bytes` as Windows-1252, `None` if one is a byte it does not define.
/// (0xA0 to 0xFF are Latin-1's.)
fn decode_windows_1252(bytes: &[u8]) -> Option<String> {
    bytes
        .iter()
        .map(|&b| match b {
            0x80..=0x9F => WINDOWS_1252_HIGH[usize::from(b - 0x80)],
            _ => Some(char::from(b)),
        })
        .collect()
}

impl Eds {
    /// An EDS for `dictionary`, with nothing else filled in.
    pub fn new(dictionary: ObjectDictionary) -> Self {
        Eds {
            dictionary,
            ..Eds::default()
        }
    }

    /// The entries of a DCF that carry a `ParameterValue`, as (index, sub,
    /// value with `$NODEID` resolved for `node`, name), in the order the
    /// file lists their sections (CiA 302-2 downloads a configuration in
    /// file order, unlike [`Eds::dictionary`], which is by index). An
    /// entry whose value does not read is an error naming it.
    pub fn parameter_values_in_file_order(
        text: &str,
        file: &str,
        node: NodeId,
    ) -> Result<Vec<(u16, u8, crate::od::Value, String)>, String> {
        let dcf = Eds::parse(text, file).map_err(|error| error.to_string())?;
        let (ini, _) = ini::parse(text.strip_prefix('\u{FEFF}').unwrap_or(text));
        let mut seen = std::collections::BTreeSet::new();
        let mut out = Vec::new();
        for section in &ini.sections {
            let name = section.name.trim();
            let (index, sub) = match name.to_ascii_lowercase().split_once("sub") {
                Some((index, sub)) => (
                    u16::from_str_radix(index, 16).ok(),
                    u8::from_str_radix(sub, 16).ok(),
                ),
                None => (u16::from_str_radix(name, 16).ok(), Some(0)),
            };
            let (Some(index), Some(sub)) = (index, sub) else {
                continue;
            };
            let Some(entry) = dcf.dictionary.sub(index, sub) else {
                if section.get("ParameterValue").is_some() {
                    return Err(format!(
                        "{file}:{}: [{name}] has a ParameterValue, but is no entry of the file's dictionary (see `candeck eds check`)",
                        section.line
                    ));
                }
                continue;
            };
            if entry.parameter_value.is_none() || !seen.insert((index, sub)) {
                continue;
            }
            let label = format!("{file}: 0x{index:04X} sub {sub} ({})", entry.name);
            let value = entry
                .parameter_value(Some(node))
                .map_err(|error| format!("{label}: {error}"))?
                .ok_or_else(|| format!("{label}: no value"))?;
            out.push((index, sub, value, label));
        }
        Ok(out)
    }

    /// Reads an EDS or DCF. `file` names it in errors and warnings; the
    /// warnings are in [`Eds::warnings`].
    pub fn parse(text: &str, file: &str) -> Result<Eds, EdsError> {
        read::read(text, file)
    }

    /// [`Eds::parse`], also returning a copy of its warnings.
    pub fn parse_with_warnings(text: &str, file: &str) -> Result<(Eds, Vec<EdsWarning>), EdsError> {
        let eds = read::read(text, file)?;
        let warnings = eds.warnings.clone();
        Ok((eds, warnings))
    }

    /// Reads a file's bytes: UTF-8, else Windows-1252 when every byte is a
    /// printable character of it, else Latin-1 (each byte one character):
    /// what vendors' Windows tools write. A file that is not UTF-8 gets a
    /// warning at the line of its first such byte.
    pub fn parse_bytes(bytes: &[u8], file: &str) -> Result<Eds, EdsError> {
        let (text, first_line, encoding) = match std::str::from_utf8(bytes) {
            Ok(text) => return Eds::parse(text, file),
            Err(error) => {
                let line = bytes[..error.valid_up_to()]
                    .iter()
                    .filter(|&&b| b == b'\n')
                    .count()
                    + 1;
                match decode_windows_1252(bytes) {
                    Some(text) => (text, line, "Windows-1252"),
                    None => (
                        bytes.iter().map(|&b| char::from(b)).collect(),
                        line,
                        "Latin-1",
                    ),
                }
            }
        };
        let mut eds = Eds::parse(&text, file)?;
        let warning = EdsWarning {
            file: file.to_string(),
            line: first_line,
            key: String::new(),
            action: Action::Kept,
            message: format!("not UTF-8: the file is read as {encoding}"),
        };
        let at = eds.warnings.partition_point(|w| w.line <= first_line);
        eds.warnings.insert(at, warning);
        Ok(eds)
    }

    /// The file as text (CR LF line ends, as CiA 306 tools expect). With
    /// `ParameterValue`s or a [`DeviceCommissioning`] it is a DCF.
    /// [`Eds::parse`] reads it back to an equal [`Eds`]; `CompactSubObj`
    /// arrays come out with explicit sub-sections.
    pub fn write(&self) -> String {
        write::write(self)
    }

    /// Why a file that read is still not usable, `None` when it is: it
    /// yields no object (every object section, or every object its lists
    /// name, was dropped, or it has none), so a node described by it would
    /// show nothing. The error names `file` and the line of the first
    /// reason, the first warning that dropped an object or a listed one.
    pub fn why_unusable(&self, file: &str) -> Option<EdsError> {
        if !self.dictionary.is_empty() {
            return None;
        }
        let (line, reason) = match read::no_object_reason(&self.warnings) {
            Some(warning) => (warning.line, warning.message.as_str()),
            None => (0, "the file has no object section ([1000], [1018], ...)"),
        };
        Some(EdsError {
            file: file.to_string(),
            line,
            message: format!("no object could be read: {reason}"),
        })
    }

    /// True when this is a DCF: a configured device rather than a type.
    pub fn is_dcf(&self) -> bool {
        self.commissioning.is_some()
    }

    /// The node id of a DCF.
    pub fn node_id(&self) -> Option<NodeId> {
        self.commissioning
            .as_ref()
            .and_then(DeviceCommissioning::node)
    }

    /// A DCF of this device: `commissioning`, and `values` (by index and
    /// sub-index) as `ParameterValue`s, typically the current values read
    /// from the device for a backup. Fails if a value is for an entry the
    /// dictionary does not have, or of the wrong type.
    pub fn to_dcf(
        &self,
        commissioning: DeviceCommissioning,
        values: &BTreeMap<(u16, u8), Value>,
    ) -> Result<Eds, DictionaryError> {
        let mut dcf = self.clone();
        for (&(index, sub), value) in values {
            dcf.dictionary.set_parameter_value(index, sub, value)?;
        }
        dcf.commissioning = Some(commissioning);
        Ok(dcf)
    }
}
