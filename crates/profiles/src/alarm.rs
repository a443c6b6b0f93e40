//! What an alarm means on each product: its severity, its text and the
//! help an operator reads, in plain words naming the objects and values to
//! look at (the dashboard links every `0xNNNN` it finds to the node's
//! object of that index).
//!
//! The table is written from what candeck knows of each product: the
//! UMC's axis areas and error objects ([`crate::umc`]), the JMC's alarm
//! EMCYs and its error register bits ([`crate::jmc::emcy`]), the CiA 402
//! fault of the statusword (bit 3) and error code 0x603F, and CiA 301's
//! EMCY error code classes (§7.2.7.1, Table 21).
//!
//! Severities follow what stops the machine: `critical` when nothing on
//! the bus can be trusted any more (bus off, a drive's heartbeat lost);
//! `high` when an axis or a node is out of operation; `medium` when
//! something needs a look but the machine runs (a halted lease, a program
//! that did not download, a communication warning); `low` for notices.

use std::fmt;

/// How urgent an alarm is (ISA-18.2 priorities, four levels).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Severity {
    Low,
    Medium,
    High,
    Critical,
}

impl Severity {
    /// Every severity, the most urgent first.
    pub const ALL: [Self; 4] = [Self::Critical, Self::High, Self::Medium, Self::Low];

    pub fn name(self) -> &'static str {
        match self {
            Self::Critical => "critical",
            Self::High => "high",
            Self::Medium => "medium",
            Self::Low => "low",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL
            .into_iter()
            .find(|severity| severity.name() == name)
    }

    /// Whether an active alarm of this severity keeps the machine out of
    /// `ready`.
    pub fn stops_machine(self) -> bool {
        self >= Self::High
    }
}

impl fmt::Display for Severity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The product an alarm's node is, as far as the table tells them apart.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Product {
    /// UniSwarm UMC motion controller (axis areas 0x800 apart).
    Umc,
    /// JMC CANopen stepper drive.
    Jmc,
    /// Any other CiA 402 drive.
    Drive,
    /// Anything else (I/O modules, LED controllers, unknown devices).
    Other,
}

impl Product {
    fn is_drive(self) -> bool {
        matches!(self, Self::Umc | Self::Jmc | Self::Drive)
    }
}

/// What raised an alarm.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AlarmKind {
    /// A CiA 402 axis in the state Fault (statusword 0x6041 bit 3).
    AxisFault,
    /// An emergency message with this error code (CiA 301 §7.2.7).
    Emcy(u16),
    /// A node without heartbeat that stopped answering.
    NodeOffline,
    /// A node of the machine description that was never found.
    NodeMissing,
    /// A node whose identity (0x1018) is not the described one.
    WrongIdentity,
    /// A node whose configuration download failed at boot-up.
    ConfigFailed,
    /// A node's heartbeat stopped (1.5 producer periods without one).
    HeartbeatLost,
    /// A guarded node stopped answering node guarding.
    GuardingLost,
    /// The CAN controller left the bus.
    BusOff,
    /// The CAN controller is error passive.
    ErrorPassive,
    /// An axis was halted because the client holding its motion lease
    /// went away.
    LeaseHalted,
    /// A program download (CiA 302-3) failed.
    ProgramFailed,
}

impl AlarmKind {
    /// The kind's name in the API (`emcy` for every EMCY code).
    pub fn name(self) -> &'static str {
        match self {
            Self::AxisFault => "axis_fault",
            Self::Emcy(_) => "emcy",
            Self::NodeOffline => "node_offline",
            Self::NodeMissing => "node_missing",
            Self::WrongIdentity => "wrong_identity",
            Self::ConfigFailed => "config_failed",
            Self::HeartbeatLost => "heartbeat_lost",
            Self::GuardingLost => "guarding_lost",
            Self::BusOff => "bus_off",
            Self::ErrorPassive => "error_passive",
            Self::LeaseHalted => "lease_halted",
            Self::ProgramFailed => "program_failed",
        }
    }

    /// The kind a name and (for `emcy`) a code make; `None` for a name
    /// that is no kind.
    pub fn from_name(name: &str, code: Option<u16>) -> Option<Self> {
        Some(match name {
            "axis_fault" => Self::AxisFault,
            "emcy" => Self::Emcy(code?),
            "node_offline" => Self::NodeOffline,
            "node_missing" => Self::NodeMissing,
            "wrong_identity" => Self::WrongIdentity,
            "config_failed" => Self::ConfigFailed,
            "heartbeat_lost" => Self::HeartbeatLost,
            "guarding_lost" => Self::GuardingLost,
            "bus_off" => Self::BusOff,
            "error_passive" => Self::ErrorPassive,
            "lease_halted" => Self::LeaseHalted,
            "program_failed" => Self::ProgramFailed,
            _ => return None,
        })
    }
}

/// What the table says of one alarm.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AlarmText {
    pub severity: Severity,
    /// One line: what happened.
    pub text: String,
    /// What to look at, in plain words, naming objects and values.
    pub help: String,
}

/// The severity, text and help of `kind` on `product`; `axis` (1-based)
/// where the alarm names one, `emcy_text` the EMCY code's text (CiA 301's
/// or CiA 402's wording).
pub fn describe(product: Product, kind: AlarmKind, axis: Option<u8>, emcy_text: &str) -> AlarmText {
    let on_axis = axis.map(|n| format!(" (axis {n})")).unwrap_or_default();
    match kind {
        AlarmKind::AxisFault => AlarmText {
            severity: Severity::High,
            text: format!("Drive fault{on_axis}"),
            help: format!(
                "The axis is in the CiA 402 state Fault (statusword {} bit 3). {} \
                 Remove the cause, then reset the fault (controlword {} bit 7) and enable the axis again.",
                object(product, axis, 0x6041),
                error_code_help(product, axis),
                object(product, axis, 0x6040),
            ),
        },
        AlarmKind::Emcy(code) => emcy(product, code, axis, &on_axis, emcy_text),
        AlarmKind::NodeOffline => AlarmText {
            severity: Severity::High,
            text: "Node offline: it no longer answers".to_string(),
            help: "The node has no heartbeat (0x1017 is 0) and did not answer a scan. Check its \
                   power, its CAN cable and termination, and that its node-ID and bit rate are \
                   the bus's; give it a heartbeat (0x1017) so that a loss is seen at once."
                .to_string(),
        },
        AlarmKind::NodeMissing => AlarmText {
            severity: Severity::High,
            text: "Node missing: described in the machine but not found".to_string(),
            help: "The first scan did not find the node of the machine description. Check that \
                   the device is powered and connected, and its node-ID (UniSwarm: 0x2040 sub 1) \
                   and bit rate (0x2040 sub 2)."
                .to_string(),
        },
        AlarmKind::WrongIdentity => AlarmText {
            severity: Severity::High,
            text: "Wrong device: its identity is not the described one".to_string(),
            help: "The node's identity object 0x1018 (sub 1 vendor, sub 2 product code, sub 3 \
                   revision) differs from the machine description. Fit the described device, or \
                   correct the description's identity."
                .to_string(),
        },
        AlarmKind::ConfigFailed => AlarmText {
            severity: Severity::High,
            text: "Configuration download failed".to_string(),
            help: "A write of the node's configuration (its DCF or description) was refused or \
                   not answered during boot-up: the machine's reasons name the object and the \
                   SDO abort code. Check the value against the device's EDS, then boot the node \
                   again."
                .to_string(),
        },
        AlarmKind::HeartbeatLost => AlarmText {
            severity: if product.is_drive() {
                Severity::Critical
            } else {
                Severity::High
            },
            text: "Heartbeat lost".to_string(),
            help: "No heartbeat within 1.5 producer periods (0x1017). Check the node's power and \
                   CAN wiring; a drive that loses the bus reacts as its 0x6007 (abort connection \
                   option code) says."
                .to_string(),
        },
        AlarmKind::GuardingLost => AlarmText {
            severity: if product.is_drive() {
                Severity::Critical
            } else {
                Severity::High
            },
            text: "Node guarding lost".to_string(),
            help: "The node did not answer node guarding within its life time (0x100C guard \
                   time × 0x100D life time factor). Check its power and CAN wiring."
                .to_string(),
        },
        AlarmKind::BusOff => AlarmText {
            severity: Severity::Critical,
            text: "CAN bus off".to_string(),
            help: "The gateway's CAN controller left the bus after too many transmit errors: no \
                   node can be reached. Check the termination (120 Ω at both ends), the wiring, \
                   and that every node uses the same bit rate."
                .to_string(),
        },
        AlarmKind::ErrorPassive => AlarmText {
            severity: Severity::Medium,
            text: "CAN bus error passive".to_string(),
            help: "The CAN controller's error counters reached 128: frames still flow but the \
                   bus is unhealthy. Check the termination, cable length and the bit rate; the \
                   bus's counters show the transmit and receive error counters."
                .to_string(),
        },
        AlarmKind::LeaseHalted => AlarmText {
            severity: Severity::Medium,
            text: format!("Motion halted: its client went away{on_axis}"),
            help: "The client holding the axis's motion lease stopped renewing it, so the \
                   gateway halted the axis (controlword 0x6040 bit 8). Check the client's \
                   connection; the audit log names the lease's holder."
                .to_string(),
        },
        AlarmKind::ProgramFailed => AlarmText {
            severity: Severity::Medium,
            text: "Program download failed".to_string(),
            help: "A program download (CiA 302-3: 0x1F51 program control, 0x1F50 program data, \
                   0x1F56 program software identification) failed: the audit log names the step \
                   and the answer. The node may be left without a running program; download it \
                   again."
                .to_string(),
        },
    }
}

/// An EMCY: its class's severity (CiA 301 Table 21), the product's own
/// words where it has them.
fn emcy(product: Product, code: u16, axis: Option<u8>, on_axis: &str, text: &str) -> AlarmText {
    let severity = emcy_severity(product, code);
    let class = match code >> 12 {
        0x1 => "a generic error",
        0x2 => "a current error",
        0x3 => "a voltage error",
        0x4 => "a temperature error",
        0x5 => "a device hardware error",
        0x6 => "a device software error",
        0x7 => "an error of an additional module",
        0x8 => "a monitoring error",
        0x9 => "an external error",
        0xF => "a device specific error",
        _ => "an error",
    };
    let mut help = format!(
        "EMCY 0x{code:04X} is {class}. Read the error register 0x1001 and the error history \
         0x1003 (pre-defined error field, newest first)."
    );
    if product.is_drive() {
        help.push(' ');
        help.push_str(&error_code_help(product, axis));
    }
    if let Some(more) = emcy_product_help(product, code, axis) {
        help.push(' ');
        help.push_str(&more);
    }
    AlarmText {
        severity,
        text: format!("EMCY 0x{code:04X}: {text}{on_axis}"),
        help,
    }
}

/// The severity of an EMCY code on `product`.
pub fn emcy_severity(product: Product, code: u16) -> Severity {
    match code >> 8 {
        // Life guard or heartbeat error, seen by the device itself.
        0x81 if code & 0xFFF0 == 0x8130 => Severity::High,
        // CAN overrun, error passive, recovered from bus off, PDO lengths.
        0x81 | 0x82 => Severity::Medium,
        // Positioning control (following error) on a drive.
        0x86 if product.is_drive() => Severity::High,
        _ => match code >> 12 {
            0x2..=0x5 | 0x9 => Severity::High,
            0x1 | 0x6 | 0x7 | 0x8 => Severity::Medium,
            0xF if code >> 8 == 0xF0 => Severity::Low,
            _ => Severity::Medium,
        },
    }
}

/// What the product's own objects say of an EMCY's cause.
fn emcy_product_help(product: Product, code: u16, axis: Option<u8>) -> Option<String> {
    match (product, code >> 12) {
        (Product::Umc, 0x2) => Some(format!(
            "On the UMC: motor status {} sub 6 bit 0 (over-current) and the currents {}.",
            object(product, axis, 0x4006),
            object(product, axis, 0x2802),
        )),
        (Product::Umc, 0x3) => Some(
            "On the UMC: the board voltage 0x2000 sub 1 (0.01 V) against the under- and \
             over-voltage thresholds 0x2041 sub 1 and sub 2."
                .to_string(),
        ),
        (Product::Umc, 0x4) => Some(format!(
            "On the UMC: motor status {} sub 6 bit 2 (driver over-temperature), the driver \
             temperature 0x2801 and the CPU temperature 0x2020.",
            object(product, axis, 0x4006),
        )),
        (Product::Umc, 0x8) if code & 0xFF00 == 0x8600 => Some(format!(
            "On the UMC: motion error {} sub 1 (bit 0 board, bit 1 motor, bit 7 position \
             controller) and the position loop's status {}.",
            object(product, axis, 0x4000),
            object(product, axis, 0x4060),
        )),
        (Product::Jmc, 0x2) => Some("On the JMC: 0x1001 bit 1 (current).".to_string()),
        (Product::Jmc, 0x3) => Some("On the JMC: 0x1001 bit 2 (voltage).".to_string()),
        (Product::Jmc, 0x4) => Some("On the JMC: 0x1001 bit 3 (temperature).".to_string()),
        (Product::Jmc, 0x8) if code == crate::jmc::emcy::FOLLOWING_ERROR => Some(
            "On the JMC: over position, 0x1001 bit 5 and statusword 0x6041 bit 13 in position \
             mode; check the load, the acceleration 0x6083 and the following error window \
             0x6065."
                .to_string(),
        ),
        _ => None,
    }
}

/// Where the axis's CiA 402 error code is, in words.
fn error_code_help(product: Product, axis: Option<u8>) -> String {
    format!(
        "Read the error code {} (CiA 402: 0x2xxx current, 0x3xxx voltage, 0x4xxx temperature, \
         0x5xxx hardware, 0x86xx positioning, such as 0x8611 following error).",
        object(product, axis, 0x603F)
    )
}

/// The axis's copy of an axis-1 object: on the UMC, shifted by its axis
/// area; elsewhere the index itself.
fn object(product: Product, axis: Option<u8>, index: u16) -> String {
    let shifted = match (product, axis) {
        (Product::Umc, Some(axis)) => crate::umc::axis_index(axis, index).unwrap_or(index),
        _ => index,
    };
    format!("0x{shifted:04X}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn emcy_classes_have_the_severities_of_the_table() {
        let cases = [
            (Product::Umc, 0x2310, Severity::High),
            (Product::Jmc, 0x3210, Severity::High),
            (Product::Other, 0x4210, Severity::High),
            (Product::Other, 0x5000, Severity::High),
            (Product::Other, 0x6100, Severity::Medium),
            (Product::Other, 0x8110, Severity::Medium),
            (Product::Other, 0x8120, Severity::Medium),
            (Product::Other, 0x8130, Severity::High),
            (Product::Jmc, 0x8611, Severity::High),
            (Product::Other, 0x8611, Severity::Medium),
            (Product::Other, 0x9000, Severity::High),
            (Product::Other, 0xF000, Severity::Low),
            (Product::Umc, 0xFF00, Severity::Medium),
            (Product::Other, 0x1000, Severity::Medium),
        ];
        for (product, code, severity) in cases {
            assert_eq!(
                emcy_severity(product, code),
                severity,
                "{product:?} 0x{code:04X}"
            );
        }
    }

    #[test]
    fn a_umc_axis_help_names_that_axis_objects() {
        let text = describe(Product::Umc, AlarmKind::AxisFault, Some(2), "");
        assert_eq!(text.text, "Drive fault (axis 2)");
        assert!(text.help.contains("0x6841"), "{}", text.help);
        assert!(text.help.contains("0x683F"), "{}", text.help);
        let text = describe(
            Product::Umc,
            AlarmKind::Emcy(0x8611),
            Some(2),
            "Following error",
        );
        assert_eq!(text.text, "EMCY 0x8611: Following error (axis 2)");
        assert!(text.help.contains("0x4200"), "{}", text.help);
        assert!(text.help.contains("0x683F"), "{}", text.help);
    }

    #[test]
    fn heartbeat_loss_of_a_drive_is_critical_of_an_io_module_high() {
        let drive = describe(Product::Jmc, AlarmKind::HeartbeatLost, None, "");
        let other = describe(Product::Other, AlarmKind::HeartbeatLost, None, "");
        assert_eq!(drive.severity, Severity::Critical);
        assert_eq!(other.severity, Severity::High);
    }

    #[test]
    fn kinds_and_severities_read_back_from_their_names() {
        for severity in Severity::ALL {
            assert_eq!(Severity::from_name(severity.name()), Some(severity));
        }
        assert!(Severity::High.stops_machine() && !Severity::Medium.stops_machine());
        let kinds = [
            AlarmKind::AxisFault,
            AlarmKind::Emcy(0x2310),
            AlarmKind::NodeOffline,
            AlarmKind::NodeMissing,
            AlarmKind::WrongIdentity,
            AlarmKind::ConfigFailed,
            AlarmKind::HeartbeatLost,
            AlarmKind::GuardingLost,
            AlarmKind::BusOff,
            AlarmKind::ErrorPassive,
            AlarmKind::LeaseHalted,
            AlarmKind::ProgramFailed,
        ];
        for kind in kinds {
            assert_eq!(AlarmKind::from_name(kind.name(), Some(0x2310)), Some(kind));
        }
        assert_eq!(AlarmKind::from_name("emcy", None), None);
    }
}
