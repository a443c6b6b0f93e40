//! INI sections to an [`Eds`]: the file and device information, the object
//! lists and the object descriptions of CiA 306 (§4.6.3.2, with compact
//! storage), and the DCF additions.
//!
//! The reader is tolerant (docs/eds.md, "Reading EDS files"): every deviation
//! that a sensible reading survives is a warning naming the line, the key and
//! what was done ([`Action`]), and the rest of the file loads. Only a file
//! that is no EDS at all (no CiA 306 section) is refused. What is right in a
//! file is read exactly as before: a tolerated defect never changes an entry
//! that has none.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use super::ini::{self, Entry, Ini, Section};
use super::{Action, DeviceCommissioning, DeviceInfo, Eds, EdsError, EdsWarning, FileInfo};
use crate::od::{
    AccessType, DataType, Object, ObjectDictionary, ObjectType, SubObject, Value, snippet,
};

/// The three object lists of CiA 306; together they name every object.
const LISTS: [&str; 3] = ["MandatoryObjects", "OptionalObjects", "ManufacturerObjects"];

/// The keys of `[DeviceInfo]` (lower case) whose values are numbers, and
/// the `BaudRate_<kbit>` flags besides.
const DEVICE_INFO_NUMBERS: [&str; 12] = [
    "vendornumber",
    "productnumber",
    "revisionnumber",
    "simplebootupmaster",
    "simplebootupslave",
    "groupmessaging",
    "lss_supported",
    "granularity",
    "dynamicchannelssupported",
    "compactpdo",
    "nrofrxpdo",
    "nroftxpdo",
];

/// What `$NODEID` stands for while an EDS, which has no node, is checked:
/// the smallest node id, so `$NODEID+0x180` is checked as 0x181.
const CHECK_NODE: u8 = 1;

/// The name CiA 306 gives sub-index 0 of a `CompactSubObj` array.
const COMPACT_SUB0_NAME: &str = "NrOfObjects";

/// The access type of an entry whose `AccessType` is missing or empty:
/// the device decides with an SDO abort what it does not allow, whereas a
/// guessed `ro` would forbid writes the device takes. (A token that is
/// written but means nothing refuses the entry instead: it may stand for
/// a restriction, and `rw` would lift it.)
const DEFAULT_ACCESS: AccessType = AccessType::Rw;

/// The object types whose names some files write where CiA 306 writes the
/// number (`ObjectType=VAR`).
const NAMED_OBJECT_TYPES: [ObjectType; 7] = [
    ObjectType::Null,
    ObjectType::Domain,
    ObjectType::DefType,
    ObjectType::DefStruct,
    ObjectType::Var,
    ObjectType::Array,
    ObjectType::Record,
];

pub(super) fn read(text: &str, file: &str) -> Result<Eds, EdsError> {
    if let Some(at) = text.find('\0') {
        let line = text[..at].matches('\n').count() + 1;
        return Err(EdsError {
            file: file.to_string(),
            line,
            message: "NUL bytes: this is a binary file, not an EDS or DCF".into(),
        });
    }
    let (ini, ini_warnings) = ini::parse(text);
    let mut reader = Reader {
        file,
        ini: &ini,
        warnings: Vec::new(),
        empty_obj_flags: Vec::new(),
    };
    for warning in ini_warnings {
        let action = if warning.dropped {
            Action::Dropped
        } else {
            Action::Kept
        };
        reader.warn(warning.line, warning.key, action, warning.message);
    }
    let mut eds = reader.eds()?;
    let mut warnings = reader.warnings;
    // In file order; warnings of one line in the order they were found.
    warnings.sort_by_key(|warning| warning.line);
    eds.warnings = warnings;
    Ok(eds)
}

/// What a section name says it is.
enum Kind {
    Object(u16),
    Sub(u16, u8),
    /// `[xxxxName]`: names of `CompactSubObj` sub-objects.
    Names(u16),
    /// `[xxxxValue]`: DCF values of `CompactSubObj` sub-objects.
    Values(u16),
    /// `[xxxxDenotation]`: DCF denotations of `CompactSubObj` sub-objects.
    Denotations(u16),
    Other,
}

/// Hex digits read as a number of at most `max_digits` significant digits.
enum Hex {
    Invalid,
    TooLarge,
    Value(u32),
}

fn hex_number(digits: &str, max_digits: usize) -> Hex {
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Hex::Invalid;
    }
    let significant = digits.trim_start_matches('0');
    if significant.len() > max_digits {
        return Hex::TooLarge;
    }
    match u32::from_str_radix(significant, 16) {
        Ok(value) => Hex::Value(value),
        // Only zeros.
        Err(_) => Hex::Value(0),
    }
}

fn classify(name: &str) -> Result<Kind, String> {
    let folded = name.to_ascii_lowercase();
    let index = |digits: &str| -> Result<Option<u16>, String> {
        match hex_number(digits, 4) {
            Hex::Invalid => Ok(None),
            Hex::Value(index) => Ok(Some(index as u16)),
            Hex::TooLarge => Err(format!("index 0x{} is over 0xFFFF", snippet(digits))),
        }
    };
    for (suffix, kind) in [
        ("name", Kind::Names as fn(u16) -> Kind),
        ("value", Kind::Values),
        ("denotation", Kind::Denotations),
        ("objectlinks", |_| Kind::Other),
    ] {
        if let Some(prefix) = folded.strip_suffix(suffix)
            && let Some(index) = index(prefix)?
        {
            return Ok(kind(index));
        }
    }
    if let Some((prefix, sub)) = folded.split_once("sub")
        && let Some(index) = index(prefix)?
    {
        return match hex_number(sub, 2) {
            Hex::Invalid => Err(format!("[{}] is no sub-object section", snippet(name))),
            Hex::Value(sub) => Ok(Kind::Sub(index, sub as u8)),
            Hex::TooLarge => Err(format!("sub-index 0x{} is over 255 (0xFF)", snippet(sub))),
        };
    }
    Ok(match index(&folded)? {
        Some(index) => Kind::Object(index),
        None => Kind::Other,
    })
}

/// The object sections of the file, sorted out by index.
#[derive(Default)]
struct Layout<'a> {
    objects: BTreeMap<u16, &'a Section>,
    subs: BTreeMap<u16, BTreeMap<u8, &'a Section>>,
    names: HashMap<u16, &'a Section>,
    values: HashMap<u16, &'a Section>,
    denotations: HashMap<u16, &'a Section>,
}

struct Reader<'a> {
    file: &'a str,
    ini: &'a Ini,
    warnings: Vec<EdsWarning>,
    /// The `ObjFlags=` lines with no value, as (line, `[section] ObjFlags`):
    /// one warning says them all.
    empty_obj_flags: Vec<(usize, String)>,
}

/// `[section] key`, the key of a warning.
fn key_of(section: &Section, key: &str) -> String {
    format!("[{}] {key}", section.name)
}

/// `[section]`, the key of a warning about a whole section.
fn section_key(section: &Section) -> String {
    format!("[{}]", section.name)
}

impl<'a> Reader<'a> {
    fn error(&self, line: usize, message: impl Into<String>) -> EdsError {
        EdsError {
            file: self.file.to_string(),
            line,
            message: message.into(),
        }
    }

    fn warn(
        &mut self,
        line: usize,
        key: impl Into<String>,
        action: Action,
        message: impl Into<String>,
    ) {
        self.warnings.push(EdsWarning {
            file: self.file.to_string(),
            line,
            key: key.into(),
            action,
            message: message.into(),
        });
    }

    /// The line warnings about something missing point at: the end of the file.
    fn end_line(&self) -> usize {
        self.ini.lines.max(1)
    }

    /// The value of an entry whose value is a number or a token (not a
    /// name or a string): as written, unless it does not `read` as written
    /// but does without a `#` comment after white space
    /// (`ObjectType=0x07 # VAR`); then without it, with a warning. A value
    /// that reads as written keeps its `#`, and so does every name and
    /// string (`ParameterName=Heartbeat #1`, `DefaultValue=Vendor #1`).
    fn uncommented<'e>(
        &mut self,
        section: &Section,
        entry: &'e Entry,
        reads: impl Fn(&str) -> bool,
    ) -> &'e str {
        let value = entry.value.as_str();
        if let Some((before, comment)) = hash_comment(value)
            && !reads(value)
            && reads(before)
        {
            self.warn(
                entry.line,
                key_of(section, &entry.key),
                Action::Corrected,
                format!(
                    "{}={}: '{}' after the value is read as a comment",
                    entry.key,
                    snippet(value),
                    snippet(comment)
                ),
            );
            return before;
        }
        value
    }

    /// A number of `data_type` (an unsigned type) from an entry (see
    /// [`Reader::uncommented`] for a comment after it), or a warning naming
    /// the key and `then` (what is done instead).
    fn number(
        &mut self,
        section: &Section,
        entry: &Entry,
        data_type: DataType,
        action: Action,
        then: &str,
    ) -> Option<u64> {
        let text = self.uncommented(section, entry, |text| {
            parse_unsigned(text, data_type).is_ok()
        });
        self.number_of(section, entry, text, data_type, action, then)
    }

    /// [`Reader::number`] of `text`, the value of `entry`.
    fn number_of(
        &mut self,
        section: &Section,
        entry: &Entry,
        text: &str,
        data_type: DataType,
        action: Action,
        then: &str,
    ) -> Option<u64> {
        match parse_unsigned(text, data_type) {
            Ok(value) => Some(value),
            Err(message) => {
                self.warn(
                    entry.line,
                    key_of(section, &entry.key),
                    action,
                    format!("{}: {message}; {then}", entry.key),
                );
                None
            }
        }
    }

    /// The `ObjFlags` of a section; an empty `ObjFlags=` is no flags, said
    /// once for the whole file (it is as if the key were not there).
    fn obj_flags(&mut self, section: &Section) -> Option<u32> {
        let entry = section.get("ObjFlags")?;
        if entry.value.is_empty() {
            let key = key_of(section, &entry.key);
            if !self
                .empty_obj_flags
                .iter()
                .any(|(line, _)| *line == entry.line)
            {
                self.empty_obj_flags.push((entry.line, key));
            }
            return None;
        }
        self.number(
            section,
            entry,
            DataType::Unsigned32,
            Action::Dropped,
            "dropped",
        )
        .map(|v| v as u32)
    }

    /// True when the file has a section CiA 306 defines.
    fn has_cia306_section(&self) -> bool {
        self.ini.sections.iter().any(|section| {
            [
                "FileInfo",
                "DeviceInfo",
                "DeviceComissioning",
                "DeviceCommissioning",
            ]
            .into_iter()
            .chain(LISTS)
            .any(|name| section.name.eq_ignore_ascii_case(name))
                || matches!(classify(&section.name), Ok(Kind::Object(_) | Kind::Sub(..)))
        })
    }

    fn eds(&mut self) -> Result<Eds, EdsError> {
        if self.ini.sections.is_empty() {
            return Err(self.error(self.end_line(), "no sections: this is not an EDS or DCF"));
        }
        if !self.has_cia306_section() {
            return Err(self.error(
                self.end_line(),
                "no section of CiA 306 ([FileInfo], [DeviceInfo], an object list or an object): \
                 this is not an EDS or DCF",
            ));
        }
        let file_info = self.file_info();
        let mut device_info = self.device_info();
        let dummy_usage = self.dummy_usage();
        let comments = self.comments();
        let commissioning = self.commissioning();
        let dictionary = self.dictionary();
        self.identity(&mut device_info, &dictionary);
        if let Some((line, key)) = self.empty_obj_flags.first().cloned() {
            let count = self.empty_obj_flags.len();
            let message = match count {
                1 => "ObjFlags= is empty; read as no flags".to_string(),
                _ => format!(
                    "ObjFlags= is empty here and in {} more sections; each is read as no flags",
                    count - 1
                ),
            };
            self.warn(line, key, Action::Kept, message);
        }
        Ok(Eds {
            file_info,
            device_info,
            dummy_usage,
            comments,
            dictionary,
            commissioning,
            warnings: Vec::new(),
        })
    }

    fn file_info(&mut self) -> FileInfo {
        let mut info = FileInfo::default();
        let Some(section) = self.ini.section("FileInfo") else {
            return info;
        };
        for entry in &section.entries {
            let value = Some(entry.value.clone());
            match entry.key.to_ascii_lowercase().as_str() {
                "filename" => info.file_name = value,
                "fileversion" => info.file_version = value,
                "filerevision" => info.file_revision = value,
                "edsversion" => info.eds_version = value,
                "description" => info.description = value,
                "creationtime" => info.creation_time = value,
                "creationdate" => info.creation_date = value,
                "createdby" => info.created_by = value,
                "modificationtime" => info.modification_time = value,
                "modificationdate" => info.modification_date = value,
                "modifiedby" => info.modified_by = value,
                _ => info.other.push((entry.key.clone(), entry.value.clone())),
            }
        }
        info
    }

    fn device_info(&mut self) -> DeviceInfo {
        let mut info = DeviceInfo::default();
        let Some(section) = self.ini.section("DeviceInfo") else {
            self.warn(
                self.end_line(),
                "[DeviceInfo]",
                Action::Defaulted,
                "no [DeviceInfo] section; the identity is taken from object 0x1018",
            );
            return info;
        };
        for entry in &section.entries {
            let key = entry.key.to_ascii_lowercase();
            let text =
                if DEVICE_INFO_NUMBERS.contains(&key.as_str()) || key.starts_with("baudrate_") {
                    self.uncommented(section, entry, |text| {
                        parse_unsigned(text, DataType::Unsigned32).is_ok()
                    })
                } else {
                    entry.value.as_str()
                };
            let unsigned = |data_type| parse_unsigned(text, data_type).ok();
            let flag = || parse_flag(text);
            // Each arm says whether the value could be read.
            let read = match key.as_str() {
                "vendorname" => {
                    info.vendor_name = Some(entry.value.clone());
                    true
                }
                "productname" => {
                    info.product_name = Some(entry.value.clone());
                    true
                }
                "ordercode" => {
                    info.order_code = Some(entry.value.clone());
                    true
                }
                "vendornumber" => {
                    info.vendor_number = unsigned(DataType::Unsigned32).map(|v| v as u32);
                    info.vendor_number.is_some()
                }
                "productnumber" => {
                    info.product_number = unsigned(DataType::Unsigned32).map(|v| v as u32);
                    info.product_number.is_some()
                }
                "revisionnumber" => {
                    info.revision_number = unsigned(DataType::Unsigned32).map(|v| v as u32);
                    info.revision_number.is_some()
                }
                "simplebootupmaster" => {
                    info.simple_boot_up_master = flag();
                    info.simple_boot_up_master.is_some()
                }
                "simplebootupslave" => {
                    info.simple_boot_up_slave = flag();
                    info.simple_boot_up_slave.is_some()
                }
                "groupmessaging" => {
                    info.group_messaging = flag();
                    info.group_messaging.is_some()
                }
                "lss_supported" => {
                    info.lss_supported = flag();
                    info.lss_supported.is_some()
                }
                "granularity" => {
                    info.granularity = unsigned(DataType::Unsigned8).map(|v| v as u8);
                    info.granularity.is_some()
                }
                "dynamicchannelssupported" => {
                    info.dynamic_channels_supported =
                        unsigned(DataType::Unsigned8).map(|v| v as u8);
                    info.dynamic_channels_supported.is_some()
                }
                "compactpdo" => {
                    info.compact_pdo = unsigned(DataType::Unsigned8).map(|v| v as u8);
                    info.compact_pdo.is_some()
                }
                "nrofrxpdo" => {
                    info.nr_of_rx_pdo = unsigned(DataType::Unsigned16).map(|v| v as u16);
                    info.nr_of_rx_pdo.is_some()
                }
                "nroftxpdo" => {
                    info.nr_of_tx_pdo = unsigned(DataType::Unsigned16).map(|v| v as u16);
                    info.nr_of_tx_pdo.is_some()
                }
                baud if baud.starts_with("baudrate_") => {
                    let rate = baud["baudrate_".len()..].parse::<u32>().ok();
                    match (rate, flag()) {
                        (Some(rate), Some(supported)) => {
                            if supported {
                                info.baud_rates.insert(rate);
                            }
                            true
                        }
                        _ => false,
                    }
                }
                _ => {
                    info.other.push((entry.key.clone(), entry.value.clone()));
                    true
                }
            };
            // The identity numbers are warned about with object 0x1018.
            let identity = matches!(
                key.as_str(),
                "vendornumber" | "productnumber" | "revisionnumber"
            );
            if !read && identity {
                info.other.push((entry.key.clone(), entry.value.clone()));
            } else if !read {
                self.warn(
                    entry.line,
                    key_of(section, &entry.key),
                    Action::Kept,
                    format!(
                        "{}={} is not a number; kept as text",
                        entry.key,
                        snippet(&entry.value)
                    ),
                );
                info.other.push((entry.key.clone(), entry.value.clone()));
            }
        }
        info
    }

    /// Vendor, product and revision numbers that `[DeviceInfo]` lacks (or
    /// writes as no number) from the defaults of object 0x1018, which
    /// describe the same device; what neither has is said, because such a
    /// file matches no device by identity.
    fn identity(&mut self, info: &mut DeviceInfo, dictionary: &ObjectDictionary) {
        let device_info = self.ini.section("DeviceInfo");
        let line = device_info.map_or(self.end_line(), |section| section.line);
        for (sub, key) in [
            (1, "VendorNumber"),
            (2, "ProductNumber"),
            (3, "RevisionNumber"),
        ] {
            let field = match sub {
                1 => &mut info.vendor_number,
                2 => &mut info.product_number,
                _ => &mut info.revision_number,
            };
            if field.is_some() {
                continue;
            }
            let written = device_info.and_then(|section| section.get(key));
            let at = written.map_or(line, |entry| entry.line);
            let default = dictionary
                .sub(0x1018, sub)
                .and_then(|entry| entry.default_value(None).ok().flatten())
                .and_then(|value| value.as_i128())
                .and_then(|value| u32::try_from(value).ok());
            let what = match written {
                Some(entry) => format!("{key}={} is not a number", snippet(&entry.value)),
                None => format!("no {key} in [DeviceInfo]"),
            };
            match default {
                Some(value) => {
                    *field = Some(value);
                    // The text is replaced, not kept beside the number.
                    info.other
                        .retain(|(other, _)| !other.eq_ignore_ascii_case(key));
                    self.warn(
                        at,
                        format!("[DeviceInfo] {key}"),
                        Action::Defaulted,
                        format!("{what}; the default of 0x1018 sub {sub} (0x{value:08X}) is used"),
                    );
                }
                None if sub < 3 && written.is_none() => self.warn(
                    at,
                    format!("[DeviceInfo] {key}"),
                    Action::Kept,
                    format!(
                        "{what} nor a 0x1018 sub {sub} default: the file matches no device by \
                         identity (assign it to a node by hand)"
                    ),
                ),
                None if sub < 3 => self.warn(
                    at,
                    format!("[DeviceInfo] {key}"),
                    Action::Kept,
                    format!(
                        "{what}; kept as text: the file matches no device by identity (assign \
                         it to a node by hand)"
                    ),
                ),
                // A revision is no part of matching.
                None if written.is_some() => self.warn(
                    at,
                    format!("[DeviceInfo] {key}"),
                    Action::Kept,
                    format!("{what}; kept as text"),
                ),
                None => {}
            }
        }
    }

    fn dummy_usage(&mut self) -> BTreeSet<u16> {
        let mut usage = BTreeSet::new();
        let Some(section) = self.ini.section("DummyUsage") else {
            return usage;
        };
        for entry in &section.entries {
            let folded = entry.key.to_ascii_lowercase();
            let index = match folded
                .strip_prefix("dummy")
                .map(|digits| hex_number(digits, 4))
            {
                Some(Hex::Value(index)) => Some(index),
                _ => None,
            };
            let text = self.uncommented(section, entry, |text| parse_flag(text).is_some());
            match (index, parse_flag(text)) {
                (Some(index), Some(used)) => {
                    if used {
                        usage.insert(index as u16);
                    }
                }
                _ => self.warn(
                    entry.line,
                    key_of(section, &entry.key),
                    Action::Dropped,
                    format!(
                        "{}={} is no DummyXXXX=0|1; ignored",
                        snippet(&entry.key),
                        snippet(&entry.value)
                    ),
                ),
            }
        }
        usage
    }

    fn comments(&mut self) -> Vec<String> {
        let Some(section) = self.ini.section("Comments") else {
            return Vec::new();
        };
        let reads = |text: &str| parse_unsigned(text, DataType::Unsigned16).is_ok();
        let count = section
            .get("Lines")
            .map(|entry| self.uncommented(section, entry, reads))
            .and_then(|text| parse_unsigned(text, DataType::Unsigned16).ok())
            // A count beyond the entries there are is a lie; never loop on it.
            .filter(|&count| count as usize <= section.entries.len());
        let Some(count) = count else {
            self.warn(
                section.line,
                "[Comments] Lines",
                Action::Dropped,
                "[Comments] has no usable Lines=; comments dropped",
            );
            return Vec::new();
        };
        (1..=count)
            .map(|n| match section.get(&format!("Line{n}")) {
                Some(entry) => entry.value.clone(),
                None => {
                    self.warn(
                        section.line,
                        format!("[Comments] Line{n}"),
                        Action::Defaulted,
                        format!("[Comments] has no Line{n}; an empty line"),
                    );
                    String::new()
                }
            })
            .collect()
    }

    fn commissioning(&mut self) -> Option<DeviceCommissioning> {
        let section = match (
            self.ini.section("DeviceComissioning"),
            self.ini.section("DeviceCommissioning"),
        ) {
            (Some(section), Some(other)) => {
                self.warn(
                    other.line,
                    section_key(other),
                    Action::Dropped,
                    "both [DeviceComissioning] and [DeviceCommissioning]; the first counts",
                );
                section
            }
            (Some(section), None) | (None, Some(section)) => section,
            (None, None) => return None,
        };
        let mut commissioning = DeviceCommissioning::default();
        let dropped = Action::Dropped;
        for entry in &section.entries {
            let mut number = |data_type| self.number(section, entry, data_type, dropped, "dropped");
            match entry.key.to_ascii_lowercase().as_str() {
                "nodeid" => {
                    commissioning.node_id = number(DataType::Unsigned8).map(|v| v as u8);
                }
                "nodename" => commissioning.node_name = Some(entry.value.clone()),
                "baudrate" => {
                    commissioning.baudrate = number(DataType::Unsigned32).map(|v| v as u32);
                }
                "netnumber" => {
                    commissioning.net_number = number(DataType::Unsigned32).map(|v| v as u32);
                }
                "networkname" => commissioning.network_name = Some(entry.value.clone()),
                "canopenmanager" => {
                    commissioning.canopen_manager = number(DataType::Boolean).map(|v| v != 0);
                }
                "lss_serialnumber" => {
                    commissioning.lss_serial_number =
                        number(DataType::Unsigned32).map(|v| v as u32);
                }
                _ => commissioning
                    .other
                    .push((entry.key.clone(), entry.value.clone())),
            }
        }
        Some(commissioning)
    }

    fn layout(&mut self) -> Layout<'a> {
        let ini: &'a Ini = self.ini;
        let mut layout = Layout::default();
        for section in &ini.sections {
            let kind = match classify(&section.name) {
                Ok(kind) => kind,
                Err(message) => {
                    self.warn(
                        section.line,
                        section_key(section),
                        Action::Dropped,
                        format!("{message}; section dropped"),
                    );
                    continue;
                }
            };
            let first = match kind {
                Kind::Object(index) => layout.objects.get(&index),
                Kind::Sub(index, sub) => layout.subs.get(&index).and_then(|subs| subs.get(&sub)),
                Kind::Names(index) => layout.names.get(&index),
                Kind::Values(index) => layout.values.get(&index),
                Kind::Denotations(index) => layout.denotations.get(&index),
                Kind::Other => None,
            };
            if let Some(first) = first {
                let message = format!(
                    "[{}] repeats [{}] of line {}; the first counts",
                    section.name, first.name, first.line
                );
                self.warn(section.line, section_key(section), Action::Dropped, message);
                continue;
            }
            match kind {
                Kind::Object(index) => {
                    layout.objects.insert(index, section);
                }
                Kind::Sub(index, sub) => {
                    layout.subs.entry(index).or_default().insert(sub, section);
                }
                Kind::Names(index) => {
                    layout.names.insert(index, section);
                }
                Kind::Values(index) => {
                    layout.values.insert(index, section);
                }
                Kind::Denotations(index) => {
                    layout.denotations.insert(index, section);
                }
                Kind::Other => {}
            }
        }
        layout
    }

    /// The indexes the object lists name, with the line that names each.
    /// An object listed without a section is dropped from the list.
    fn lists(&mut self, layout: &Layout) -> BTreeMap<u16, usize> {
        let mut listed = BTreeMap::new();
        for list in LISTS {
            let Some(section) = self.ini.section(list) else {
                if list == "MandatoryObjects" {
                    self.warn(
                        self.end_line(),
                        "[MandatoryObjects]",
                        Action::Kept,
                        "no [MandatoryObjects] section; the objects are read from their sections",
                    );
                }
                continue;
            };
            let count = match section.get("SupportedObjects") {
                Some(entry) => self.number(
                    section,
                    entry,
                    DataType::Unsigned16,
                    Action::Dropped,
                    "every numbered entry is read",
                ),
                None => {
                    self.warn(
                        section.line,
                        key_of(section, "SupportedObjects"),
                        Action::Defaulted,
                        format!("[{list}] has no SupportedObjects; every numbered entry is read"),
                    );
                    None
                }
            };
            let mut numbered = 0u64;
            for entry in &section.entries {
                let Ok(n) = entry.key.parse::<u64>() else {
                    continue;
                };
                if n == 0 || count.is_some_and(|count| n > count) {
                    let limit = count.map_or(String::new(), |count| {
                        format!(" beyond SupportedObjects={count}")
                    });
                    self.warn(
                        entry.line,
                        key_of(section, &entry.key),
                        Action::Dropped,
                        format!("{}= is{limit}; ignored", entry.key),
                    );
                    continue;
                }
                numbered += 1;
                let Some(index) = self.number(
                    section,
                    entry,
                    DataType::Unsigned16,
                    Action::Dropped,
                    "dropped from the list",
                ) else {
                    continue;
                };
                let index = index as u16;
                if !layout.objects.contains_key(&index) {
                    self.warn(
                        entry.line,
                        key_of(section, &entry.key),
                        Action::Dropped,
                        format!(
                            "object 0x{index:04X} is listed but there is no [{index:04X}] section; \
                             dropped from the list"
                        ),
                    );
                    continue;
                }
                if let Some(first) = listed.insert(index, entry.line) {
                    self.warn(
                        entry.line,
                        key_of(section, &entry.key),
                        Action::Kept,
                        format!("object 0x{index:04X} is listed twice (first at line {first})"),
                    );
                }
            }
            if let Some(count) = count.filter(|&count| count != numbered)
                && let Some(entry) = section.get("SupportedObjects")
            {
                self.warn(
                    entry.line,
                    key_of(section, "SupportedObjects"),
                    Action::Kept,
                    format!("SupportedObjects={count} but [{list}] has {numbered} numbered entries; those there are count"),
                );
            }
        }
        listed
    }

    fn dictionary(&mut self) -> ObjectDictionary {
        let layout = self.layout();
        let listed = self.lists(&layout);
        let mut dictionary = ObjectDictionary::new();
        for (&index, section) in &layout.objects {
            if !listed.contains_key(&index) {
                self.warn(
                    section.line,
                    section_key(section),
                    Action::Kept,
                    format!("object 0x{index:04X} is in no object list; read anyway"),
                );
            }
            if let Some(object) = self.object(index, section, &layout) {
                dictionary.insert(object);
            }
        }
        for (index, subs) in &layout.subs {
            if !layout.objects.contains_key(index)
                && let Some(section) = subs.values().next()
            {
                self.warn(
                    section.line,
                    section_key(section),
                    Action::Dropped,
                    format!("sub-objects of 0x{index:04X}, which has no section; ignored"),
                );
            }
        }
        dictionary
    }

    /// The `ObjectType` of a section, `None` (with a warning) when it is no
    /// object type: the section is dropped then, as it is not known what
    /// it describes.
    fn object_type(&mut self, section: &Section) -> Option<ObjectType> {
        let Some(entry) = section.get("ObjectType") else {
            // CiA 306 §4.6.3.2: a missing ObjectType means VAR.
            return Some(ObjectType::Var);
        };
        let text = self.uncommented(section, entry, |text| {
            parse_unsigned(text, DataType::Unsigned8).is_ok() || object_type_named(text).is_some()
        });
        if let Some(object_type) = object_type_named(text) {
            self.warn(
                entry.line,
                key_of(section, &entry.key),
                Action::Corrected,
                format!(
                    "ObjectType={} is a name where CiA 306 writes a number; read as 0x{:X}",
                    snippet(text),
                    object_type.raw()
                ),
            );
            return Some(object_type);
        }
        let raw = self.number_of(
            section,
            entry,
            text,
            DataType::Unsigned8,
            Action::Dropped,
            "section dropped",
        )?;
        let object_type = ObjectType::from_raw(raw as u8);
        if let ObjectType::Unknown(raw) = object_type {
            self.warn(
                entry.line,
                key_of(section, &entry.key),
                Action::Dropped,
                format!("ObjectType 0x{raw:X} is unknown; section dropped"),
            );
            return None;
        }
        Some(object_type)
    }

    /// The `ParameterName`, or a name made of `fallback` when there is none.
    fn name(&mut self, section: &Section, fallback: String) -> String {
        match section.get("ParameterName") {
            Some(entry) if !entry.value.is_empty() => entry.value.clone(),
            _ => {
                let message = format!(
                    "[{}] has no ParameterName; named '{fallback}'",
                    section.name
                );
                self.warn(
                    section.line,
                    key_of(section, "ParameterName"),
                    Action::Defaulted,
                    message,
                );
                fallback
            }
        }
    }

    /// The `ParameterName`, or `fallback` without a warning.
    fn name_or(&self, section: &Section, fallback: String) -> String {
        match section.get("ParameterName") {
            Some(entry) if !entry.value.is_empty() => entry.value.clone(),
            _ => fallback,
        }
    }

    fn object(&mut self, index: u16, section: &Section, layout: &Layout) -> Option<Object> {
        let object_type = self.object_type(section)?;
        let name = self.name(section, format!("Object 0x{index:04X}"));
        let mut object = Object::new(index, name, object_type);
        let subs = layout.subs.get(&index);
        if !object_type.has_sub_objects() {
            if let Some(sub) = subs.and_then(|subs| subs.values().next()) {
                self.warn(
                    sub.line,
                    section_key(sub),
                    Action::Dropped,
                    format!(
                        "0x{index:04X} is a {object_type} and has no sub-objects; sections ignored"
                    ),
                );
            }
            if object_type != ObjectType::Null {
                // A VAR or DOMAIN without a readable type is no entry.
                let name = object.name.clone();
                object.insert_sub(self.sub_object(section, 0, object_type, Some(&name))?);
            }
            return Some(object);
        }
        object.obj_flags = self.obj_flags(section);
        let compact = match section.get("CompactSubObj") {
            Some(entry) => self
                .number(
                    section,
                    entry,
                    DataType::Unsigned8,
                    Action::Dropped,
                    "read as 0",
                )
                .map_or(0, |v| v as u8),
            None => 0,
        };
        let sub_number = match section.get("SubNumber") {
            Some(entry) => self
                .number(
                    section,
                    entry,
                    DataType::Unsigned16,
                    Action::Dropped,
                    "ignored",
                )
                .map(|number| (number, entry.line)),
            None => None,
        };
        match subs {
            Some(subs) => {
                if compact > 0 {
                    self.warn(
                        section.line,
                        key_of(section, "CompactSubObj"),
                        Action::Dropped,
                        "both CompactSubObj and sub-object sections; the sections count",
                    );
                }
                if let Some((number, line)) =
                    sub_number.filter(|&(number, _)| number != subs.len() as u64)
                {
                    self.warn(
                        line,
                        key_of(section, "SubNumber"),
                        Action::Kept,
                        format!(
                            "SubNumber={number} but there are {} sub-object sections",
                            subs.len()
                        ),
                    );
                }
                for (&sub_index, sub_section) in subs {
                    let Some(sub_type) = self.object_type(sub_section) else {
                        continue;
                    };
                    if let Some(sub) = self.sub_object(sub_section, sub_index, sub_type, None) {
                        object.insert_sub(sub);
                    }
                }
            }
            None if compact > 0 => {
                for sub in self.compact_subs(index, section, compact, layout) {
                    object.insert_sub(sub);
                }
            }
            None => self.warn(
                section.line,
                section_key(section),
                Action::Kept,
                format!(
                    "{object_type} 0x{index:04X} has neither [{index:04X}subN] sections nor \
                     CompactSubObj; kept with no sub-objects"
                ),
            ),
        }
        Some(object)
    }

    /// The sub-objects of a `CompactSubObj` array (CiA 306 compact storage): sub 0
    /// the count, subs 1 to n as the object section describes them, named
    /// `<object name><n>` unless `[xxxxName]` names them, with values from
    /// `[xxxxValue]` and denotations from `[xxxxDenotation]`.
    fn compact_subs(
        &mut self,
        index: u16,
        section: &Section,
        count: u8,
        layout: &Layout,
    ) -> Vec<SubObject> {
        let name = self.name_or(section, format!("Object 0x{index:04X}"));
        let Some(mut template) = self.sub_object(section, 1, ObjectType::Var, Some(&name)) else {
            return Vec::new();
        };
        template.denotation = None;
        let mut sub0 = SubObject::new(0, COMPACT_SUB0_NAME, DataType::Unsigned8, AccessType::Ro);
        sub0.default = Some(count.to_string());
        let mut subs = vec![sub0];
        let names = layout.names.get(&index);
        let values = layout.values.get(&index);
        let denotations = layout.denotations.get(&index);
        for n in 1..=count {
            let key = n.to_string();
            let mut sub = template.clone();
            sub.sub_index = n;
            sub.name = match names.and_then(|names| names.get(&key)) {
                Some(entry) => entry.value.clone(),
                None => format!("{}{n}", template.name),
            };
            if let Some((values, entry)) =
                values.and_then(|values| values.get(&key).map(|entry| (values, entry)))
            {
                sub.parameter_value = self.value_text(values, entry, sub.data_type);
            }
            if let Some(entry) = denotations.and_then(|denotations| denotations.get(&key)) {
                sub.denotation = Some(entry.value.clone());
            }
            subs.push(sub);
        }
        for extra in [names, values, denotations].into_iter().flatten() {
            for entry in &extra.entries {
                if entry
                    .key
                    .parse::<u64>()
                    .is_ok_and(|n| n == 0 || n > u64::from(count))
                {
                    self.warn(
                        entry.line,
                        key_of(extra, &entry.key),
                        Action::Dropped,
                        format!("{}= is beyond CompactSubObj={count}; ignored", entry.key),
                    );
                }
            }
        }
        subs
    }

    /// A value text, checked against the type (with `$NODEID` standing for
    /// node 1); `None` when empty. What does not read as written is read
    /// the way its writer meant where that is clear (a C literal suffix, a
    /// negative number in an unsigned type) and dropped otherwise.
    fn value_text(
        &mut self,
        section: &Section,
        entry: &Entry,
        data_type: DataType,
    ) -> Option<String> {
        if entry.value.is_empty() {
            return None;
        }
        let text = self.uncommented(section, entry, |text| {
            Value::parse_text_with_node(data_type, text, Some(CHECK_NODE)).is_ok()
                || corrected_number(data_type, text).is_some()
        });
        let error = match Value::parse_text_with_node(data_type, text, Some(CHECK_NODE)) {
            Ok(_) => return Some(text.to_string()),
            Err(error) => error,
        };
        let key = key_of(section, &entry.key);
        let shown = snippet(text);
        if let Some(corrected) = corrected_number(data_type, text) {
            self.warn(
                entry.line,
                key,
                Action::Corrected,
                format!("{}={shown} is read as {corrected} ({data_type})", entry.key),
            );
            return Some(corrected);
        }
        let message = if data_type == DataType::Domain {
            format!(
                "{}={shown}: a DOMAIN value is hex bytes; dropped (no value)",
                entry.key
            )
        } else {
            format!("{}: {error}; dropped", entry.key)
        };
        self.warn(entry.line, key, Action::Dropped, message);
        None
    }

    fn data_type(&mut self, section: &Section, object_type: ObjectType) -> Option<DataType> {
        let Some(entry) = section.get("DataType") else {
            // CiA 306 §4.6.3.2: a DOMAIN object needs no DataType.
            if object_type == ObjectType::Domain {
                return Some(DataType::Domain);
            }
            self.warn(
                section.line,
                key_of(section, "DataType"),
                Action::Dropped,
                format!(
                    "[{}] has no DataType: the entry cannot be read or written; dropped",
                    section.name
                ),
            );
            return None;
        };
        let raw = self.number(
            section,
            entry,
            DataType::Unsigned16,
            Action::Dropped,
            "the entry cannot be read or written; dropped",
        )? as u16;
        let data_type = DataType::from_raw(raw);
        if data_type.is_known() {
            return Some(data_type);
        }
        self.warn(
            entry.line,
            key_of(section, &entry.key),
            Action::Corrected,
            format!(
                "DataType 0x{raw:04X} is no basic type of CiA 301 (a manufacturer's or a \
                 structure's); read as DOMAIN (raw bytes)"
            ),
        );
        Some(DataType::Domain)
    }

    fn sub_object(
        &mut self,
        section: &Section,
        sub_index: u8,
        object_type: ObjectType,
        parent_name: Option<&str>,
    ) -> Option<SubObject> {
        let data_type = self.data_type(section, object_type)?;
        // The entry of a VAR or a compact array is named by the object's
        // section, whose missing name has been warned about.
        let name = match parent_name {
            Some(parent) => self.name_or(section, parent.to_string()),
            None => self.name(section, format!("Sub-index {sub_index}")),
        };
        let access = match section.get("AccessType") {
            Some(entry) => {
                let text = self.uncommented(section, entry, |text| access_token(text).is_some());
                match access_token(text) {
                    Some((access, true)) => access,
                    Some((access, false)) => {
                        self.warn(
                            entry.line,
                            key_of(section, &entry.key),
                            Action::Corrected,
                            format!(
                                "AccessType={} is no access type of CiA 306; read as {access}",
                                snippet(text)
                            ),
                        );
                        access
                    }
                    None if text.trim().is_empty() => {
                        self.warn(
                            entry.line,
                            key_of(section, &entry.key),
                            Action::Defaulted,
                            format!("AccessType is empty; read as {DEFAULT_ACCESS}"),
                        );
                        DEFAULT_ACCESS
                    }
                    None => {
                        // `rw` could make writable what the device's maker
                        // meant to be read-only.
                        self.warn(
                            entry.line,
                            key_of(section, &entry.key),
                            Action::Dropped,
                            format!(
                                "AccessType={} is no access type (ro, wo, rw, rwr, rww, const): \
                                 what the entry allows is not known; [{}] dropped",
                                snippet(text),
                                section.name
                            ),
                        );
                        return None;
                    }
                }
            }
            None if data_type == DataType::Domain => AccessType::Rw,
            None => {
                self.warn(
                    section.line,
                    key_of(section, "AccessType"),
                    Action::Defaulted,
                    format!(
                        "[{}] has no AccessType; read as {DEFAULT_ACCESS}",
                        section.name
                    ),
                );
                DEFAULT_ACCESS
            }
        };
        let mut sub = SubObject::new(sub_index, name, data_type, access);
        if let Some(entry) = section.get("PDOMapping") {
            sub.pdo_mappable = self
                .number(
                    section,
                    entry,
                    DataType::Unsigned8,
                    Action::Defaulted,
                    "read as 0 (not mappable)",
                )
                .is_some_and(|v| v != 0);
        }
        sub.obj_flags = self.obj_flags(section);
        let mut text = |key: &str| {
            section
                .get(key)
                .and_then(|entry| self.value_text(section, entry, data_type))
        };
        sub.default = text("DefaultValue");
        sub.low = text("LowLimit");
        sub.high = text("HighLimit");
        sub.parameter_value = text("ParameterValue");
        sub.denotation = section.get("Denotation").map(|entry| entry.value.clone());
        self.check_limits(section, &mut sub);
        Some(sub)
    }

    /// Limits that contradict each other are dropped (no value could pass
    /// both, so they say nothing about the device); a default outside the
    /// limits is kept with a warning, as the device would refuse it.
    fn check_limits(&mut self, section: &Section, sub: &mut SubObject) {
        let check = crate::NodeId::new(CHECK_NODE).ok();
        let (Ok(low), Ok(high)) = (sub.low_value(check), sub.high_value(check)) else {
            return;
        };
        if let (Some(low), Some(high)) = (&low, &high)
            && low.check_limits(None, Some(high)).is_err()
        {
            let message = format!(
                "[{}]: LowLimit {low} is above HighLimit {high}; both dropped",
                section.name
            );
            let line = section
                .get("LowLimit")
                .map_or(section.line, |entry| entry.line);
            self.warn(line, key_of(section, "LowLimit"), Action::Dropped, message);
            sub.low = None;
            sub.high = None;
            return;
        }
        if let Ok(Some(default)) = sub.default_value(check)
            && let Err(error) = default.check_limits(low.as_ref(), high.as_ref())
        {
            let line = section
                .get("DefaultValue")
                .map_or(section.line, |entry| entry.line);
            self.warn(
                line,
                key_of(section, "DefaultValue"),
                Action::Kept,
                format!("[{}]: DefaultValue {error}", section.name),
            );
        }
    }
}

/// A value's text before a `#` comment (a `#` after white space, not at
/// the start), trimmed, and the comment; `None` when there is none.
fn hash_comment(value: &str) -> Option<(&str, &str)> {
    let bytes = value.as_bytes();
    let at =
        (1..bytes.len()).find(|&i| bytes[i] == b'#' && matches!(bytes[i - 1], b' ' | b'\t'))?;
    Some((value[..at].trim(), value[at..].trim()))
}

/// The object type an `ObjectType` names (`VAR`, `record`, ...), if it
/// names one.
fn object_type_named(text: &str) -> Option<ObjectType> {
    NAMED_OBJECT_TYPES
        .into_iter()
        .find(|object_type| object_type.name().eq_ignore_ascii_case(text.trim()))
}

/// An `AccessType` token: a CiA 306 one (any case), with `true`; or `R` or
/// `W`, which some tools write for `ro` and `wo`, with `false`.
fn access_token(text: &str) -> Option<(AccessType, bool)> {
    if let Ok(access) = text.parse::<AccessType>() {
        return Some((access, true));
    }
    match text.trim() {
        "R" | "r" => Some((AccessType::Ro, false)),
        "W" | "w" => Some((AccessType::Wo, false)),
        _ => None,
    }
}

/// The warning that says why a file that read yields no object: the first
/// that dropped an object, a sub-object or an entry of an object list.
pub(super) fn no_object_reason(warnings: &[EdsWarning]) -> Option<&EdsWarning> {
    warnings.iter().find(|warning| {
        let section = warning
            .key
            .strip_prefix('[')
            .and_then(|key| key.split_once(']'))
            .map(|(section, _)| section);
        warning.action == Action::Dropped
            && section.is_some_and(|section| {
                LISTS.iter().any(|list| list.eq_ignore_ascii_case(section))
                    || matches!(classify(section), Ok(Kind::Object(_) | Kind::Sub(..)))
            })
    })
}

/// A number's value text as its writer meant it, as text that reads: a C
/// literal suffix dropped (`0x1234567890ABCDEFLL`, `100U`, `1.5f`), a negative
/// number in an unsigned type as its two's complement (`-1` in an UNSIGNED32
/// is 0xFFFFFFFF, as C compilers and the tools built with them have it).
fn corrected_number(data_type: DataType, text: &str) -> Option<String> {
    let reads = |text: &str| Value::parse_text_with_node(data_type, text, Some(CHECK_NODE)).is_ok();
    let trimmed = text.trim();
    if data_type.is_real() {
        // `1.0f`: a C float literal.
        let unsuffixed = trimmed.strip_suffix(['f', 'F'])?;
        return reads(unsuffixed).then(|| unsuffixed.to_string());
    }
    if !data_type.is_integer() || data_type == DataType::Boolean {
        return None;
    }
    let unsuffixed = trimmed.trim_end_matches(['u', 'U', 'l', 'L']);
    let digits_left = unsuffixed
        .chars()
        .last()
        .is_some_and(|c| c.is_ascii_hexdigit());
    let candidate = if unsuffixed.len() < trimmed.len() && digits_left {
        unsuffixed
    } else {
        trimmed
    };
    if candidate != trimmed && reads(candidate) {
        return Some(candidate.to_string());
    }
    let bits = data_type.bits()?;
    if data_type.is_signed() || !candidate.starts_with('-') {
        return None;
    }
    let negative = Value::parse_text_with_node(DataType::Integer64, candidate, None)
        .ok()?
        .as_i128()?;
    let modulus = 1i128 << bits;
    if negative >= 0 || negative < -(modulus / 2) {
        return None;
    }
    let text = format!("0x{:X}", negative + modulus);
    reads(&text).then_some(text)
}

/// An unsigned number (or BOOLEAN) in any CiA 306 form, within `data_type`.
fn parse_unsigned(text: &str, data_type: DataType) -> Result<u64, String> {
    let value = Value::parse_text(data_type, text, None).map_err(|error| error.to_string())?;
    value
        .as_i128()
        .and_then(|v| u64::try_from(v).ok())
        .ok_or_else(|| format!("'{}' is not an unsigned number", snippet(text)))
}

/// 0 or 1 (or false/true), as `[DeviceInfo]` writes its yes/no keys.
fn parse_flag(text: &str) -> Option<bool> {
    parse_unsigned(text, DataType::Boolean).ok().map(|v| v != 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn section_names_say_what_they_hold() {
        let kind = |name: &str| match classify(name) {
            Ok(Kind::Object(index)) => format!("object {index:04X}"),
            Ok(Kind::Sub(index, sub)) => format!("sub {index:04X}/{sub}"),
            Ok(Kind::Names(index)) => format!("names {index:04X}"),
            Ok(Kind::Values(index)) => format!("values {index:04X}"),
            Ok(Kind::Denotations(index)) => format!("denotations {index:04X}"),
            Ok(Kind::Other) => "other".into(),
            Err(message) => message,
        };
        assert_eq!(kind("1000"), "object 1000");
        assert_eq!(kind("a0"), "object 00A0");
        assert_eq!(kind("01A00"), "object 1A00");
        assert_eq!(kind("1018sub1"), "sub 1018/1");
        assert_eq!(kind("1A00SUBA"), "sub 1A00/10");
        assert_eq!(kind("2000subFF"), "sub 2000/255");
        assert_eq!(kind("2000sub0FF"), "sub 2000/255");
        assert_eq!(kind("2000Name"), "names 2000");
        assert_eq!(kind("2000value"), "values 2000");
        assert_eq!(kind("2000Denotation"), "denotations 2000");
        assert_eq!(kind("2000ObjectLinks"), "other");
        assert_eq!(kind("FileInfo"), "other");
        assert_eq!(kind("DeviceComissioning"), "other");
        assert_eq!(kind("Name"), "other");
        assert_eq!(kind("1018sub100"), "sub-index 0x100 is over 255 (0xFF)");
        assert_eq!(kind("1018sub"), "[1018sub] is no sub-object section");
        assert_eq!(kind("1018subx"), "[1018subx] is no sub-object section");
        assert_eq!(kind("12345"), "index 0x12345 is over 0xFFFF");
        assert_eq!(kind("12345sub1"), "index 0x12345 is over 0xFFFF");
    }
}
