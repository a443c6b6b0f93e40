//! The browse tree of namespace `urn:candeck`, sans I/O: what each node id
//! stands for, and the methods with their arguments as the gateway's typed
//! requests (docs/opcua.md, "Address space").
//!
//! Node ids are strings, the browse path from the `candeck` object:
//! `candeck/Nodes/demo/3/Axes/1/Position`. A method's id is its path too,
//! so that a call names its target by itself:
//!
//! ```text
//! Objects/candeck
//!   StopAll()
//!   Machine/{State, Reasons, ActiveAlarms, UnacknowledgedAlarms, HighestSeverity}
//!     Acknowledge(AlarmId, Comment)
//!   Buses/{bus}/{State, Load, RxFrames, TxFrames, ErrorFrames, RxOverruns, TxErrors}
//!     Scan(), Sync(PeriodMs)
//!   Nodes/{bus}/{id}/{NmtState, Online, Profile}
//!     Identification/{Manufacturer, Model, SerialNumber, HardwareRevision,
//!                     SoftwareRevision, DeviceRevision, VendorId, ProductCode}
//!     Nmt(Command), Store(Area), Restore(Area, Source)
//!     Dictionary/{index}sub{sub} (e.g. 0x1017sub0)
//!     Axes/{n}/{State, Mode, Statusword, Position, Velocity, Torque,
//!               FaultCode, FaultText, TargetReached}
//!       SetState(Target), Move(Mode, Target, Velocity, Acceleration,
//!       Deceleration, Relative), Halt(), QuickStop(), FaultReset(),
//!       StepTest(Request), TakeLease(), RenewLease(LeaseId),
//!       ReleaseLease(LeaseId)
//! ```

use crate::canopen::nmt::NmtCommand;
use crate::gateway::{GatewayError, MoveRequest, ParameterArea, RestoreSource, TargetState};

/// The namespace of every node candeck adds.
pub const NAMESPACE: &str = "urn:candeck";
/// The id of the top object, under `Objects`.
pub const ROOT: &str = "candeck";

/// A bus node: `{bus}/{id}`.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodePath {
    pub bus: String,
    pub node: u8,
}

impl NodePath {
    pub fn id(&self) -> String {
        format!("{ROOT}/Nodes/{}/{}", self.bus, self.node)
    }

    pub fn child(&self, name: &str) -> String {
        format!("{}/{name}", self.id())
    }

    /// The object of axis `axis`.
    pub fn axis(&self, axis: u8) -> String {
        format!("{}/Axes/{axis}", self.id())
    }

    /// The variable of object `index` sub `sub` in `Dictionary`.
    pub fn object(&self, index: u16, sub: u8) -> String {
        format!("{}/Dictionary/{}", self.id(), object_name(index, sub))
    }
}

/// A dictionary variable's browse name: `0x1017sub0`.
pub fn object_name(index: u16, sub: u8) -> String {
    format!("0x{index:04X}sub{sub}")
}

/// A bus's object.
pub fn bus_id(bus: &str) -> String {
    format!("{ROOT}/Buses/{bus}")
}

/// What a node id of the namespace stands for, where something acts on
/// it: a method to call, or a dictionary variable to read or write. The
/// other variables are values the server keeps, fed from the gateway.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Target {
    StopAll,
    /// `Machine/Acknowledge`: the gateway's alarm acknowledge.
    Acknowledge,
    Scan {
        bus: String,
    },
    Sync {
        bus: String,
    },
    Nmt(NodePath),
    Store(NodePath),
    Restore(NodePath),
    Axis {
        node: NodePath,
        axis: u8,
        method: AxisMethod,
    },
    Object {
        node: NodePath,
        index: u16,
        sub: u8,
    },
}

/// The methods of an axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AxisMethod {
    SetState,
    Move,
    Halt,
    QuickStop,
    FaultReset,
    StepTest,
    /// The session's lease on the axis, handed to the client: its id and
    /// period, to renew or release it explicitly (or over REST).
    TakeLease,
    RenewLease,
    ReleaseLease,
}

impl AxisMethod {
    pub const ALL: [Self; 9] = [
        Self::SetState,
        Self::Move,
        Self::Halt,
        Self::QuickStop,
        Self::FaultReset,
        Self::StepTest,
        Self::TakeLease,
        Self::RenewLease,
        Self::ReleaseLease,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::SetState => "SetState",
            Self::Move => "Move",
            Self::Halt => "Halt",
            Self::QuickStop => "QuickStop",
            Self::FaultReset => "FaultReset",
            Self::StepTest => "StepTest",
            Self::TakeLease => "TakeLease",
            Self::RenewLease => "RenewLease",
            Self::ReleaseLease => "ReleaseLease",
        }
    }
}

impl Target {
    /// The target of node id `id` (its string), if it is one.
    pub fn parse(id: &str) -> Option<Self> {
        let rest = id.strip_prefix(ROOT)?.strip_prefix('/')?;
        let parts: Vec<&str> = rest.split('/').collect();
        let node = |bus: &str, node: &str| {
            Some(NodePath {
                bus: bus.to_string(),
                node: node.parse().ok().filter(|id| (1..=127).contains(id))?,
            })
        };
        Some(match parts.as_slice() {
            ["StopAll"] => Self::StopAll,
            ["Machine", "Acknowledge"] => Self::Acknowledge,
            ["Buses", bus, "Scan"] => Self::Scan {
                bus: bus.to_string(),
            },
            ["Buses", bus, "Sync"] => Self::Sync {
                bus: bus.to_string(),
            },
            ["Nodes", bus, id, "Nmt"] => Self::Nmt(node(bus, id)?),
            ["Nodes", bus, id, "Store"] => Self::Store(node(bus, id)?),
            ["Nodes", bus, id, "Restore"] => Self::Restore(node(bus, id)?),
            ["Nodes", bus, id, "Axes", axis, method] => Self::Axis {
                node: node(bus, id)?,
                axis: axis.parse().ok().filter(|axis| *axis > 0)?,
                method: AxisMethod::ALL
                    .into_iter()
                    .find(|known| known.name() == *method)?,
            },
            ["Nodes", bus, id, "Dictionary", object] => {
                let (index, sub) = object.strip_prefix("0x")?.split_once("sub")?;
                Self::Object {
                    node: node(bus, id)?,
                    index: u16::from_str_radix(index, 16).ok()?,
                    sub: sub.parse().ok()?,
                }
            }
            _ => return None,
        })
    }
}

/// The axis whose value variable (or engineering units) `id` is:
/// `candeck/Nodes/{bus}/{id}/Axes/{n}/{value}[/EngineeringUnits]`.
pub fn axis_value(id: &str) -> Option<(NodePath, u8)> {
    let rest = id.strip_prefix(ROOT)?.strip_prefix("/Nodes/")?;
    let parts: Vec<&str> = rest.split('/').collect();
    let (bus, node, axis, value) = match parts.as_slice() {
        [bus, node, "Axes", axis, value] | [bus, node, "Axes", axis, value, _] => {
            (bus, node, axis, value)
        }
        _ => return None,
    };
    if AxisMethod::ALL.iter().any(|method| method.name() == *value) {
        return None;
    }
    Some((
        NodePath {
            bus: bus.to_string(),
            node: node.parse().ok().filter(|id| (1..=127).contains(id))?,
        },
        axis.parse().ok().filter(|axis| *axis > 0)?,
    ))
}

/// `Nmt`'s `Command`: the words of REST's NMT route.
pub fn nmt_command(text: &str) -> Result<NmtCommand, GatewayError> {
    Ok(match text.trim() {
        "start" => NmtCommand::Start,
        "stop" => NmtCommand::Stop,
        "pre_operational" => NmtCommand::EnterPreOperational,
        "reset_node" => NmtCommand::ResetNode,
        "reset_communication" => NmtCommand::ResetCommunication,
        other => {
            return Err(GatewayError::InvalidRequest(format!(
                "'{other}' is no NMT command: start, stop, pre_operational, reset_node or \
                 reset_communication"
            )));
        }
    })
}

/// `Store`'s and `Restore`'s `Area`, as REST's `what`.
pub fn parameter_area(text: &str) -> Result<ParameterArea, GatewayError> {
    Ok(match text.trim() {
        "all" => ParameterArea::All,
        "communication" => ParameterArea::Communication,
        "application" => ParameterArea::Application,
        "manufacturer" => ParameterArea::Manufacturer,
        other => {
            return Err(GatewayError::InvalidRequest(format!(
                "'{other}' is no parameter area: all, communication, application or manufacturer"
            )));
        }
    })
}

/// `Restore`'s `Source`: `factory` (also the empty string) or `saved`.
pub fn restore_source(text: &str) -> Result<RestoreSource, GatewayError> {
    match text.trim() {
        "" | "factory" => Ok(RestoreSource::Factory),
        "saved" => Ok(RestoreSource::Saved),
        other => Err(GatewayError::InvalidRequest(format!(
            "'{other}' is no restore source: factory or saved"
        ))),
    }
}

/// `SetState`'s `Target`: the targets of REST's state route.
pub fn target_state(text: &str) -> Result<TargetState, GatewayError> {
    serde_json::from_value(serde_json::Value::String(text.trim().to_string())).map_err(|_| {
        GatewayError::InvalidRequest(format!(
            "'{text}' is no drive state to command: operation_enabled, switched_on, \
             ready_to_switch_on, switch_on_disabled or quick_stop_active"
        ))
    })
}

/// `Move`'s arguments as a move: `Target` is the mode's set-point (a
/// position, a velocity, a torque in per mille, a duty cycle), in device
/// units; `Velocity`, `Acceleration` and `Deceleration` are the profile's
/// (0: the drive's own), `Relative` for the position modes. Interpolated
/// position and homing take more than one number: REST has them.
pub fn move_request(
    mode: &str,
    target: f64,
    velocity: f64,
    acceleration: f64,
    deceleration: f64,
    relative: bool,
) -> Result<MoveRequest, GatewayError> {
    let optional = |value: f64, name: &str| -> Result<Option<i64>, GatewayError> {
        if value == 0.0 {
            return Ok(None);
        }
        whole(value, name, i64::MIN as f64, i64::MAX as f64).map(Some)
    };
    let request = match mode.trim() {
        "profile_position" => MoveRequest::ProfilePosition {
            target: whole(target, "Target", i32::MIN.into(), i32::MAX.into())? as i32,
            relative,
            immediate: true,
            velocity: optional(velocity, "Velocity")?,
            acceleration: optional(acceleration, "Acceleration")?,
            deceleration: optional(deceleration, "Deceleration")?,
        },
        "velocity" => MoveRequest::Velocity {
            velocity: whole(target, "Target", i32::MIN.into(), i32::MAX.into())? as i32,
            acceleration: optional(acceleration, "Acceleration")?,
            deceleration: optional(deceleration, "Deceleration")?,
        },
        "torque" => MoveRequest::Torque {
            torque: whole(target, "Target", i16::MIN.into(), i16::MAX.into())? as i16,
            slope: optional(acceleration, "Acceleration")?,
        },
        "duty_cycle" => MoveRequest::DutyCycle {
            duty: whole(target, "Target", i16::MIN.into(), i16::MAX.into())? as i16,
            slope: optional(acceleration, "Acceleration")?,
        },
        "continuous_position" => MoveRequest::ContinuousPosition {
            target: whole(target, "Target", i32::MIN.into(), i32::MAX.into())? as i32,
            relative,
        },
        other => {
            return Err(GatewayError::InvalidRequest(format!(
                "'{other}' is no mode Move takes: profile_position, velocity, torque, duty_cycle \
                 or continuous_position (interpolated position and homing: REST)"
            )));
        }
    };
    Ok(request)
}

/// A device value given as a Double: whole, within `min..=max`.
fn whole(value: f64, name: &str, min: f64, max: f64) -> Result<i64, GatewayError> {
    if !value.is_finite() || value.fract() != 0.0 {
        return Err(GatewayError::InvalidValue(format!(
            "{name} {value} is no whole number of device units"
        )));
    }
    if value < min || value > max {
        return Err(GatewayError::ValueOutOfRange(format!(
            "{name} {value} is outside {min} to {max}"
        )));
    }
    Ok(value as i64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node() -> NodePath {
        NodePath {
            bus: "demo".into(),
            node: 3,
        }
    }

    #[test]
    fn method_and_dictionary_ids_name_their_target() {
        assert_eq!(Target::parse("candeck/StopAll"), Some(Target::StopAll));
        assert_eq!(
            Target::parse("candeck/Machine/Acknowledge"),
            Some(Target::Acknowledge)
        );
        assert_eq!(
            Target::parse(&format!("{}/Scan", bus_id("line"))),
            Some(Target::Scan { bus: "line".into() })
        );
        assert_eq!(
            Target::parse(&node().child("Nmt")),
            Some(Target::Nmt(node()))
        );
        assert_eq!(
            Target::parse(&format!("{}/Move", node().axis(2))),
            Some(Target::Axis {
                node: node(),
                axis: 2,
                method: AxisMethod::Move
            })
        );
        for method in AxisMethod::ALL {
            let id = format!("{}/{}", node().axis(1), method.name());
            assert!(
                matches!(Target::parse(&id), Some(Target::Axis { method: m, .. }) if m == method),
                "{id}"
            );
        }
        assert_eq!(
            Target::parse(&node().object(0x1017, 0)),
            Some(Target::Object {
                node: node(),
                index: 0x1017,
                sub: 0
            })
        );
        assert_eq!(
            node().object(0x6064, 0),
            "candeck/Nodes/demo/3/Dictionary/0x6064sub0"
        );
        // Values are no targets; nor are nodes out of CANopen's range.
        assert_eq!(Target::parse(&format!("{}/Position", node().axis(1))), None);
        assert_eq!(Target::parse("candeck/Nodes/demo/128/Nmt"), None);
        assert_eq!(Target::parse("candeck/Nodes/demo/3/Axes/0/Move"), None);
        assert_eq!(Target::parse("other/StopAll"), None);
    }

    #[test]
    fn axis_values_name_their_axis() {
        let position = format!("{}/Position", node().axis(2));
        assert_eq!(axis_value(&position), Some((node(), 2)));
        assert_eq!(
            axis_value(&format!("{position}/EngineeringUnits")),
            Some((node(), 2))
        );
        assert_eq!(axis_value(&format!("{}/Move", node().axis(2))), None);
        assert_eq!(axis_value(&node().child("NmtState")), None);
    }

    #[test]
    fn move_arguments_become_the_modes_request() {
        assert_eq!(
            move_request("profile_position", 65536.0, 100.0, 0.0, 0.0, true).unwrap(),
            MoveRequest::ProfilePosition {
                target: 65536,
                relative: true,
                immediate: true,
                velocity: Some(100),
                acceleration: None,
                deceleration: None,
            }
        );
        assert_eq!(
            move_request("velocity", -500.0, 0.0, 2000.0, 0.0, false).unwrap(),
            MoveRequest::Velocity {
                velocity: -500,
                acceleration: Some(2000),
                deceleration: None,
            }
        );
        let err = move_request("torque", 40000.0, 0.0, 0.0, 0.0, false).unwrap_err();
        assert_eq!(err.code(), "value_out_of_range", "{err}");
        let err = move_request("velocity", 1.5, 0.0, 0.0, 0.0, false).unwrap_err();
        assert_eq!(err.code(), "invalid_value", "{err}");
        let err = move_request("homing", 1.0, 0.0, 0.0, 0.0, false).unwrap_err();
        assert_eq!(err.code(), "invalid_request", "{err}");
    }

    #[test]
    fn words_of_the_other_methods_are_rests() {
        assert_eq!(nmt_command("start").unwrap(), NmtCommand::Start);
        assert_eq!(nmt_command("reset_node").unwrap(), NmtCommand::ResetNode);
        assert!(nmt_command("go").is_err());
        assert_eq!(parameter_area("all").unwrap(), ParameterArea::All);
        assert!(parameter_area("everything").is_err());
        assert_eq!(restore_source("").unwrap(), RestoreSource::Factory);
        assert_eq!(restore_source("saved").unwrap(), RestoreSource::Saved);
        assert_eq!(
            target_state("operation_enabled").unwrap(),
            TargetState::OperationEnabled
        );
        assert!(target_state("flying").is_err());
    }
}
