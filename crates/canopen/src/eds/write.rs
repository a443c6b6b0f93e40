//! An [`Eds`] back to CiA 306 text, in the order of the standard's examples:
//! file and device information, the three object lists each followed by its
//! objects, and for a DCF the commissioning section last.

use std::fmt::Display;

use super::{DeviceInfo, Eds, FileInfo};
use crate::od::{Object, SubObject};

/// CR LF, as the vendors' files and the Windows tools that read them have it.
const EOL: &str = "\r\n";

/// The bit rates CiA 306 gives a `BaudRate_` key, in kbit/s.
const STANDARD_BAUD_RATES: [u32; 8] = [10, 20, 50, 125, 250, 500, 800, 1000];

/// The objects every device has (CiA 301), listed in
/// `[MandatoryObjects]`.
const MANDATORY: [u16; 3] = [0x1000, 0x1001, 0x1018];

#[derive(Default)]
struct Out(String);

impl Out {
    fn section(&mut self, name: &str) {
        if !self.0.is_empty() {
            self.0.push_str(EOL);
        }
        self.0.push('[');
        self.0.push_str(name);
        self.0.push(']');
        self.0.push_str(EOL);
    }

    /// One `key=value` line. A line break cannot be written in an INI value;
    /// it becomes a space.
    fn key(&mut self, key: &str, value: impl Display) {
        let line = format!("{key}={value}").replace(['\r', '\n'], " ");
        self.0.push_str(&line);
        self.0.push_str(EOL);
    }

    fn text(&mut self, key: &str, value: &Option<String>) {
        if let Some(value) = value {
            self.key(key, value);
        }
    }

    fn number(&mut self, key: &str, value: Option<impl Display>) {
        if let Some(value) = value {
            self.key(key, value);
        }
    }

    fn hex(&mut self, key: &str, value: Option<u32>) {
        if let Some(value) = value {
            self.key(key, format_args!("0x{value:X}"));
        }
    }

    fn flag(&mut self, key: &str, value: Option<bool>) {
        self.number(key, value.map(u8::from));
    }

    fn other(&mut self, other: &[(String, String)]) {
        for (key, value) in other {
            self.key(key, value);
        }
    }
}

pub(super) fn write(eds: &Eds) -> String {
    let mut out = Out::default();
    file_info(&mut out, &eds.file_info);
    device_info(&mut out, &eds.device_info);

    out.section("DummyUsage");
    let standard = 1..=7u16;
    for index in standard.clone() {
        out.key(
            &format!("Dummy{index:04X}"),
            u8::from(eds.dummy_usage.contains(&index)),
        );
    }
    for index in eds
        .dummy_usage
        .iter()
        .filter(|index| !standard.contains(index))
    {
        out.key(&format!("Dummy{index:04X}"), 1);
    }

    if !eds.comments.is_empty() {
        out.section("Comments");
        out.key("Lines", eds.comments.len());
        for (n, line) in eds.comments.iter().enumerate() {
            out.key(&format!("Line{}", n + 1), line);
        }
    }

    let objects = &eds.dictionary.objects;
    let mandatory: Vec<&Object> = objects
        .values()
        .filter(|o| MANDATORY.contains(&o.index))
        .collect();
    let manufacturer: Vec<&Object> = objects
        .values()
        .filter(|o| (0x2000..=0x5FFF).contains(&o.index))
        .collect();
    let optional: Vec<&Object> = objects
        .values()
        .filter(|o| !MANDATORY.contains(&o.index) && !(0x2000..=0x5FFF).contains(&o.index))
        .collect();
    for (list, members) in [
        ("MandatoryObjects", mandatory),
        ("OptionalObjects", optional),
        ("ManufacturerObjects", manufacturer),
    ] {
        out.section(list);
        out.key("SupportedObjects", members.len());
        for (n, object) in members.iter().enumerate() {
            out.key(&(n + 1).to_string(), format_args!("0x{:04X}", object.index));
        }
        for object in members {
            write_object(&mut out, object);
        }
    }

    if let Some(commissioning) = &eds.commissioning {
        out.section("DeviceComissioning");
        out.number("NodeID", commissioning.node_id);
        out.text("NodeName", &commissioning.node_name);
        out.number("Baudrate", commissioning.baudrate);
        out.number("NetNumber", commissioning.net_number);
        out.text("NetworkName", &commissioning.network_name);
        out.flag("CANopenManager", commissioning.canopen_manager);
        out.hex("LSS_SerialNumber", commissioning.lss_serial_number);
        out.other(&commissioning.other);
    }
    out.0
}

fn file_info(out: &mut Out, info: &FileInfo) {
    out.section("FileInfo");
    out.text("FileName", &info.file_name);
    out.text("FileVersion", &info.file_version);
    out.text("FileRevision", &info.file_revision);
    out.text("EDSVersion", &info.eds_version);
    out.text("Description", &info.description);
    out.text("CreationTime", &info.creation_time);
    out.text("CreationDate", &info.creation_date);
    out.text("CreatedBy", &info.created_by);
    out.text("ModificationTime", &info.modification_time);
    out.text("ModificationDate", &info.modification_date);
    out.text("ModifiedBy", &info.modified_by);
    out.other(&info.other);
}

fn device_info(out: &mut Out, info: &DeviceInfo) {
    out.section("DeviceInfo");
    out.text("VendorName", &info.vendor_name);
    out.hex("VendorNumber", info.vendor_number);
    out.text("ProductName", &info.product_name);
    out.hex("ProductNumber", info.product_number);
    out.hex("RevisionNumber", info.revision_number);
    out.text("OrderCode", &info.order_code);
    let extra_rates = info
        .baud_rates
        .iter()
        .filter(|rate| !STANDARD_BAUD_RATES.contains(rate));
    for rate in STANDARD_BAUD_RATES.iter().chain(extra_rates) {
        let key = format!("BaudRate_{rate}");
        // A BaudRate_ value that could not be read is in `other`, as written;
        // a second line with the same key would make the file ambiguous.
        if !info
            .other
            .iter()
            .any(|(other, _)| other.eq_ignore_ascii_case(&key))
        {
            out.key(&key, u8::from(info.baud_rates.contains(rate)));
        }
    }
    out.flag("SimpleBootUpMaster", info.simple_boot_up_master);
    out.flag("SimpleBootUpSlave", info.simple_boot_up_slave);
    out.number("Granularity", info.granularity);
    out.number("DynamicChannelsSupported", info.dynamic_channels_supported);
    out.number("CompactPDO", info.compact_pdo);
    out.flag("GroupMessaging", info.group_messaging);
    out.number("NrOfRXPDO", info.nr_of_rx_pdo);
    out.number("NrOfTXPDO", info.nr_of_tx_pdo);
    out.flag("LSS_Supported", info.lss_supported);
    out.other(&info.other);
}

/// An object section, and for an ARRAY or RECORD one section per
/// sub-object. A VAR's entry is its sub-object 0, written into the object's
/// own section under the object's name.
fn write_object(out: &mut Out, object: &Object) {
    out.section(&format!("{:04X}", object.index));
    out.key("ParameterName", &object.name);
    out.key(
        "ObjectType",
        format_args!("0x{:X}", object.object_type.raw()),
    );
    if object.object_type.has_sub_objects() {
        out.hex("ObjFlags", object.obj_flags);
        out.key("SubNumber", format_args!("0x{:X}", object.subs.len()));
        for sub in object.subs.values() {
            out.section(&format!("{:04X}sub{:X}", object.index, sub.sub_index));
            out.key("ParameterName", &sub.name);
            out.key("ObjectType", "0x7");
            entry(out, sub);
        }
    } else if let Some(sub) = object.subs.get(&0) {
        entry(out, sub);
    }
}

fn entry(out: &mut Out, sub: &SubObject) {
    out.key("DataType", format_args!("0x{:04X}", sub.data_type.raw()));
    out.key("AccessType", sub.access);
    out.text("DefaultValue", &sub.default);
    out.key("PDOMapping", u8::from(sub.pdo_mappable));
    out.text("LowLimit", &sub.low);
    out.text("HighLimit", &sub.high);
    out.hex("ObjFlags", sub.obj_flags);
    out.text("ParameterValue", &sub.parameter_value);
    out.text("Denotation", &sub.denotation);
}
