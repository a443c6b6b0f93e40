//! INI sections to an [`Eds`]: the file and device information, the object
//! lists and the object descriptions of CiA 306 (§4.6.3.2, with compact
//! storage), and the DCF additions.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use super::ini::{self, Entry, Ini, Section};
use super::{DeviceCommissioning, DeviceInfo, Eds, EdsError, EdsWarning, FileInfo};
use crate::canopen::od::{
    AccessType, DataType, Object, ObjectDictionary, ObjectType, SubObject, Value, snippet,
};

/// The three object lists of CiA 306; together they name every object.
const LISTS: [&str; 3] = ["MandatoryObjects", "OptionalObjects", "ManufacturerObjects"];

/// What `$NODEID` stands for while an EDS, which has no node, is checked:
/// the smallest node id, so `$NODEID+0x180` is checked as 0x181.
const CHECK_NODE: u8 = 1;

/// The name CiA 306 gives sub-index 0 of a `CompactSubObj` array.
const COMPACT_SUB0_NAME: &str = "NrOfObjects";

pub(super) fn read(text: &str, file: &str) -> Result<(Eds, Vec<EdsWarning>), EdsError> {
    let ini = ini::parse(text).map_err(|error| EdsError {
        file: file.to_string(),
        line: error.line,
        message: error.message,
    })?;
    let mut reader = Reader {
        file,
        ini: &ini,
        warnings: Vec::new(),
    };
    let eds = reader.eds()?;
    Ok((eds, reader.warnings))
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
}

impl<'a> Reader<'a> {
    fn error(&self, line: usize, message: impl Into<String>) -> EdsError {
        EdsError {
            file: self.file.to_string(),
            line,
            message: message.into(),
        }
    }

    fn warn(&mut self, line: usize, message: impl Into<String>) {
        self.warnings.push(EdsWarning {
            file: self.file.to_string(),
            line,
            message: message.into(),
        });
    }

    /// The line errors about something missing point at: the end of the file.
    fn end_line(&self) -> usize {
        self.ini.lines.max(1)
    }

    /// A number of `data_type` (an unsigned type) from an entry; an error
    /// naming the key otherwise.
    fn number(&self, entry: &Entry, data_type: DataType) -> Result<u64, EdsError> {
        parse_unsigned(&entry.value, data_type)
            .map_err(|message| self.error(entry.line, format!("{}: {message}", entry.key)))
    }

    fn required<'s>(&self, section: &'s Section, key: &str) -> Result<&'s Entry, EdsError> {
        section
            .get(key)
            .ok_or_else(|| self.error(section.line, format!("[{}] has no {key}", section.name)))
    }

    fn eds(&mut self) -> Result<Eds, EdsError> {
        if self.ini.sections.is_empty() {
            return Err(self.error(self.end_line(), "no sections: this is not an EDS or DCF"));
        }
        let file_info = self.file_info();
        let device_info = self.device_info();
        let dummy_usage = self.dummy_usage();
        let comments = self.comments();
        let commissioning = self.commissioning()?;
        let dictionary = self.dictionary()?;
        Ok(Eds {
            file_info,
            device_info,
            dummy_usage,
            comments,
            dictionary,
            commissioning,
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
            self.warn(self.end_line(), "no [DeviceInfo] section");
            return info;
        };
        for entry in &section.entries {
            let key = entry.key.to_ascii_lowercase();
            let unsigned = |data_type| parse_unsigned(&entry.value, data_type).ok();
            let flag = || parse_flag(&entry.value);
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
            if !read {
                self.warn(
                    entry.line,
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
            match (index, parse_flag(&entry.value)) {
                (Some(index), Some(used)) => {
                    if used {
                        usage.insert(index as u16);
                    }
                }
                _ => self.warn(
                    entry.line,
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
        let count = section
            .get("Lines")
            .and_then(|entry| parse_unsigned(&entry.value, DataType::Unsigned16).ok())
            // A count beyond the entries there are is a lie; never loop on it.
            .filter(|&count| count as usize <= section.entries.len());
        let Some(count) = count else {
            self.warn(
                section.line,
                "[Comments] has no usable Lines=; comments dropped",
            );
            return Vec::new();
        };
        (1..=count)
            .map(|n| match section.get(&format!("Line{n}")) {
                Some(entry) => entry.value.clone(),
                None => {
                    self.warn(section.line, format!("[Comments] has no Line{n}"));
                    String::new()
                }
            })
            .collect()
    }

    fn commissioning(&mut self) -> Result<Option<DeviceCommissioning>, EdsError> {
        let section = match (
            self.ini.section("DeviceComissioning"),
            self.ini.section("DeviceCommissioning"),
        ) {
            (Some(section), Some(other)) => {
                self.warn(
                    other.line,
                    "both [DeviceComissioning] and [DeviceCommissioning]; the first counts",
                );
                section
            }
            (Some(section), None) | (None, Some(section)) => section,
            (None, None) => return Ok(None),
        };
        let mut commissioning = DeviceCommissioning::default();
        for entry in &section.entries {
            match entry.key.to_ascii_lowercase().as_str() {
                "nodeid" => {
                    commissioning.node_id = Some(self.number(entry, DataType::Unsigned8)? as u8)
                }
                "nodename" => commissioning.node_name = Some(entry.value.clone()),
                "baudrate" => {
                    commissioning.baudrate = Some(self.number(entry, DataType::Unsigned32)? as u32)
                }
                "netnumber" => {
                    commissioning.net_number =
                        Some(self.number(entry, DataType::Unsigned32)? as u32)
                }
                "networkname" => commissioning.network_name = Some(entry.value.clone()),
                "canopenmanager" => {
                    commissioning.canopen_manager =
                        Some(self.number(entry, DataType::Boolean)? != 0)
                }
                "lss_serialnumber" => {
                    commissioning.lss_serial_number =
                        Some(self.number(entry, DataType::Unsigned32)? as u32)
                }
                _ => commissioning
                    .other
                    .push((entry.key.clone(), entry.value.clone())),
            }
        }
        Ok(Some(commissioning))
    }

    fn layout(&self) -> Result<Layout<'a>, EdsError> {
        let ini: &'a Ini = self.ini;
        let mut layout = Layout::default();
        for section in &ini.sections {
            let kind =
                classify(&section.name).map_err(|message| self.error(section.line, message))?;
            let first = match kind {
                Kind::Object(index) => layout.objects.insert(index, section),
                Kind::Sub(index, sub) => layout.subs.entry(index).or_default().insert(sub, section),
                Kind::Names(index) => layout.names.insert(index, section),
                Kind::Values(index) => layout.values.insert(index, section),
                Kind::Denotations(index) => layout.denotations.insert(index, section),
                Kind::Other => None,
            };
            if let Some(first) = first {
                return Err(self.error(
                    section.line,
                    format!(
                        "[{}] repeats [{}] of line {}",
                        section.name, first.name, first.line
                    ),
                ));
            }
        }
        Ok(layout)
    }

    /// The indexes the object lists name, with the line that names each.
    fn lists(&mut self, layout: &Layout) -> Result<BTreeMap<u16, usize>, EdsError> {
        let mut listed = BTreeMap::new();
        for list in LISTS {
            let Some(section) = self.ini.section(list) else {
                if list == "MandatoryObjects" {
                    return Err(self.error(self.end_line(), "no [MandatoryObjects] section"));
                }
                continue;
            };
            let count_entry = self.required(section, "SupportedObjects")?;
            let count = self.number(count_entry, DataType::Unsigned16)?;
            // Never loop on a count beyond the entries there are.
            if count as usize >= section.entries.len() {
                return Err(self.error(
                    count_entry.line,
                    format!(
                        "SupportedObjects={count} but [{list}] lists only {} objects",
                        section.entries.len() - 1
                    ),
                ));
            }
            for n in 1..=count {
                let entry = section.get(&n.to_string()).ok_or_else(|| {
                    self.error(
                        section.line,
                        format!("SupportedObjects={count} but [{list}] has no {n}="),
                    )
                })?;
                let index = self.number(entry, DataType::Unsigned16)? as u16;
                if !layout.objects.contains_key(&index) {
                    return Err(self.error(
                        entry.line,
                        format!(
                            "object 0x{index:04X} is listed but there is no [{index:04X}] section"
                        ),
                    ));
                }
                if let Some(first) = listed.insert(index, entry.line) {
                    self.warn(
                        entry.line,
                        format!("object 0x{index:04X} is listed twice (first at line {first})"),
                    );
                }
            }
            for entry in &section.entries {
                let beyond = entry.key.parse::<u64>().is_ok_and(|n| n == 0 || n > count);
                if beyond {
                    self.warn(
                        entry.line,
                        format!("{}= is beyond SupportedObjects={count}; ignored", entry.key),
                    );
                }
            }
        }
        Ok(listed)
    }

    fn dictionary(&mut self) -> Result<ObjectDictionary, EdsError> {
        let layout = self.layout()?;
        let listed = self.lists(&layout)?;
        let mut dictionary = ObjectDictionary::new();
        for (&index, section) in &layout.objects {
            if !listed.contains_key(&index) {
                self.warn(
                    section.line,
                    format!("object 0x{index:04X} is in no object list; read anyway"),
                );
            }
            let object = self.object(index, section, &layout)?;
            dictionary.insert(object);
        }
        for (index, subs) in &layout.subs {
            if !layout.objects.contains_key(index) {
                let line = subs.values().next().map_or(0, |section| section.line);
                self.warn(
                    line,
                    format!("sub-objects of 0x{index:04X}, which has no section; ignored"),
                );
            }
        }
        Ok(dictionary)
    }

    fn object_type(&self, section: &Section) -> Result<ObjectType, EdsError> {
        let Some(entry) = section.get("ObjectType") else {
            // CiA 306 §4.6.3.2: a missing ObjectType means VAR.
            return Ok(ObjectType::Var);
        };
        let object_type = ObjectType::from_raw(self.number(entry, DataType::Unsigned8)? as u8);
        if let ObjectType::Unknown(raw) = object_type {
            return Err(self.error(entry.line, format!("ObjectType 0x{raw:X} is unknown")));
        }
        Ok(object_type)
    }

    fn object(
        &mut self,
        index: u16,
        section: &Section,
        layout: &Layout,
    ) -> Result<Object, EdsError> {
        let name = self.required(section, "ParameterName")?.value.clone();
        let object_type = self.object_type(section)?;
        let mut object = Object::new(index, name, object_type);
        let subs = layout.subs.get(&index);
        if !object_type.has_sub_objects() {
            if let Some(subs) = subs {
                let line = subs.values().next().map_or(section.line, |sub| sub.line);
                self.warn(
                    line,
                    format!(
                        "0x{index:04X} is a {object_type} and has no sub-objects; sections ignored"
                    ),
                );
            }
            if object_type != ObjectType::Null {
                object.insert_sub(self.sub_object(section, 0, object_type)?);
            }
            return Ok(object);
        }
        if let Some(entry) = section.get("ObjFlags") {
            object.obj_flags = Some(self.number(entry, DataType::Unsigned32)? as u32);
        }
        let compact = match section.get("CompactSubObj") {
            Some(entry) => self.number(entry, DataType::Unsigned8)? as u8,
            None => 0,
        };
        let sub_number = match section.get("SubNumber") {
            Some(entry) => Some((self.number(entry, DataType::Unsigned16)?, entry.line)),
            None => None,
        };
        match subs {
            Some(subs) => {
                if compact > 0 {
                    self.warn(
                        section.line,
                        "both CompactSubObj and sub-object sections; the sections count",
                    );
                }
                if let Some((number, line)) =
                    sub_number.filter(|&(number, _)| number != subs.len() as u64)
                {
                    self.warn(
                        line,
                        format!(
                            "SubNumber={number} but there are {} sub-object sections",
                            subs.len()
                        ),
                    );
                }
                for (&sub_index, sub_section) in subs {
                    let sub_type = self.object_type(sub_section)?;
                    object.insert_sub(self.sub_object(sub_section, sub_index, sub_type)?);
                }
            }
            None if compact > 0 => {
                for sub in self.compact_subs(index, section, compact, layout)? {
                    object.insert_sub(sub);
                }
            }
            None if sub_number.is_some() => {
                self.warn(section.line, format!("0x{index:04X} has no sub-objects"));
            }
            None => {
                return Err(self.error(
                    section.line,
                    format!(
                        "{object_type} 0x{index:04X} has neither [{index:04X}subN] sections nor CompactSubObj"
                    ),
                ));
            }
        }
        Ok(object)
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
    ) -> Result<Vec<SubObject>, EdsError> {
        let mut template = self.sub_object(section, 1, ObjectType::Var)?;
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
            if let Some(entry) = values.and_then(|values| values.get(&key)) {
                sub.parameter_value = self.value_text(entry, sub.data_type)?;
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
                        format!("{}= is beyond CompactSubObj={count}; ignored", entry.key),
                    );
                }
            }
        }
        Ok(subs)
    }

    /// A value text, checked against the type (with `$NODEID` standing for
    /// node 1); `None` when empty.
    fn value_text(&self, entry: &Entry, data_type: DataType) -> Result<Option<String>, EdsError> {
        if entry.value.is_empty() {
            return Ok(None);
        }
        Value::parse_text_with_node(data_type, &entry.value, Some(CHECK_NODE))
            .map_err(|error| self.error(entry.line, format!("{}: {error}", entry.key)))?;
        Ok(Some(entry.value.clone()))
    }

    fn sub_object(
        &mut self,
        section: &Section,
        sub_index: u8,
        object_type: ObjectType,
    ) -> Result<SubObject, EdsError> {
        let name = self.required(section, "ParameterName")?.value.clone();
        let data_type = match section.get("DataType") {
            Some(entry) => {
                let raw = self.number(entry, DataType::Unsigned16)? as u16;
                let data_type = DataType::from_raw(raw);
                if !data_type.is_known() {
                    return Err(self.error(entry.line, format!("DataType 0x{raw:04X} is unknown")));
                }
                data_type
            }
            // CiA 306 §4.6.3.2: a DOMAIN object needs no DataType.
            None if object_type == ObjectType::Domain => DataType::Domain,
            None => {
                return Err(self.error(section.line, format!("[{}] has no DataType", section.name)));
            }
        };
        let access = match section.get("AccessType") {
            Some(entry) => entry
                .value
                .parse::<AccessType>()
                .map_err(|error| self.error(entry.line, error.to_string()))?,
            None if data_type == DataType::Domain => AccessType::Rw,
            None => {
                return Err(self.error(
                    section.line,
                    format!("[{}] has no AccessType", section.name),
                ));
            }
        };
        let mut sub = SubObject::new(sub_index, name, data_type, access);
        if let Some(entry) = section.get("PDOMapping") {
            sub.pdo_mappable = self.number(entry, DataType::Unsigned8)? != 0;
        }
        if let Some(entry) = section.get("ObjFlags") {
            sub.obj_flags = Some(self.number(entry, DataType::Unsigned32)? as u32);
        }
        let text = |key: &str| {
            section
                .get(key)
                .map(|entry| self.value_text(entry, data_type))
                .transpose()
        };
        sub.default = text("DefaultValue")?.flatten();
        sub.low = text("LowLimit")?.flatten();
        sub.high = text("HighLimit")?.flatten();
        sub.parameter_value = text("ParameterValue")?.flatten();
        sub.denotation = section.get("Denotation").map(|entry| entry.value.clone());
        self.check_limits(section, &sub);
        Ok(sub)
    }

    /// Warns about limits that contradict each other or the default, as the
    /// device would refuse its own default.
    fn check_limits(&mut self, section: &Section, sub: &SubObject) {
        let check = crate::canopen::NodeId::new(CHECK_NODE).ok();
        let (Ok(low), Ok(high)) = (sub.low_value(check), sub.high_value(check)) else {
            return;
        };
        if let (Some(low), Some(high)) = (&low, &high)
            && low.check_limits(None, Some(high)).is_err()
        {
            let message = format!(
                "[{}]: LowLimit {low} is above HighLimit {high}",
                section.name
            );
            self.warn(section.line, message);
            return;
        }
        if let Ok(Some(default)) = sub.default_value(check)
            && let Err(error) = default.check_limits(low.as_ref(), high.as_ref())
        {
            self.warn(
                section.line,
                format!("[{}]: DefaultValue {error}", section.name),
            );
        }
    }
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
