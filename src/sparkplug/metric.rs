//! Typed metric values (Sparkplug 3.0 §6.4.16, "DataType Values") and how
//! CANopen values map onto them.
//!
//! The protobuf carries integers up to 32 bits in `int_value` (a `uint32`:
//! the signed types as their two's complement, sign-extended to 32 bits),
//! 64-bit ones and `DateTime` in `long_value` (§6.4.17).

use super::proto::DataType;
use super::proto::payload::{Metric, metric};
use crate::canopen::od::Value;

/// A metric's value with its Sparkplug type.
#[derive(Debug, Clone, PartialEq)]
pub enum MetricValue {
    Int8(i8),
    Int16(i16),
    Int32(i32),
    Int64(i64),
    UInt8(u8),
    UInt16(u16),
    UInt32(u32),
    UInt64(u64),
    Float(f32),
    Double(f64),
    Boolean(bool),
    String(String),
    Bytes(Vec<u8>),
    /// Milliseconds since 1970 (UTC).
    DateTime(u64),
    /// No value yet, of this type (`is_null`).
    Null(DataType),
}

impl MetricValue {
    pub fn datatype(&self) -> DataType {
        match self {
            Self::Int8(_) => DataType::Int8,
            Self::Int16(_) => DataType::Int16,
            Self::Int32(_) => DataType::Int32,
            Self::Int64(_) => DataType::Int64,
            Self::UInt8(_) => DataType::UInt8,
            Self::UInt16(_) => DataType::UInt16,
            Self::UInt32(_) => DataType::UInt32,
            Self::UInt64(_) => DataType::UInt64,
            Self::Float(_) => DataType::Float,
            Self::Double(_) => DataType::Double,
            Self::Boolean(_) => DataType::Boolean,
            Self::String(_) => DataType::String,
            Self::Bytes(_) => DataType::Bytes,
            Self::DateTime(_) => DataType::DateTime,
            Self::Null(datatype) => *datatype,
        }
    }

    /// The value as a number, for deadbands; `None` for text, bytes and
    /// null.
    pub fn as_f64(&self) -> Option<f64> {
        Some(match *self {
            Self::Int8(v) => v.into(),
            Self::Int16(v) => v.into(),
            Self::Int32(v) => v.into(),
            Self::Int64(v) => v as f64,
            Self::UInt8(v) => v.into(),
            Self::UInt16(v) => v.into(),
            Self::UInt32(v) => v.into(),
            Self::UInt64(v) => v as f64,
            Self::Float(v) => v.into(),
            Self::Double(v) => v,
            Self::Boolean(v) => u8::from(v).into(),
            Self::DateTime(v) => v as f64,
            _ => return None,
        })
    }

    /// A CANopen value as its nearest Sparkplug type: the integers of 24,
    /// 40, 48 and 56 bits widened, the strings as `String`, octet strings
    /// and domains as `Bytes`, times of day as bytes (their wire form).
    pub fn from_canopen(value: &Value) -> Self {
        match value {
            Value::Boolean(v) => Self::Boolean(*v),
            Value::Integer8(v) => Self::Int8(*v),
            Value::Integer16(v) => Self::Int16(*v),
            Value::Integer24(v) | Value::Integer32(v) => Self::Int32(*v),
            Value::Integer40(v)
            | Value::Integer48(v)
            | Value::Integer56(v)
            | Value::Integer64(v) => Self::Int64(*v),
            Value::Unsigned8(v) => Self::UInt8(*v),
            Value::Unsigned16(v) => Self::UInt16(*v),
            Value::Unsigned24(v) | Value::Unsigned32(v) => Self::UInt32(*v),
            Value::Unsigned40(v)
            | Value::Unsigned48(v)
            | Value::Unsigned56(v)
            | Value::Unsigned64(v) => Self::UInt64(*v),
            Value::Real32(v) => Self::Float(*v),
            Value::Real64(v) => Self::Double(*v),
            Value::VisibleString(v) | Value::UnicodeString(v) => Self::String(v.clone()),
            Value::OctetString(v) | Value::Domain(v) => Self::Bytes(v.clone()),
            other @ (Value::TimeOfDay(_) | Value::TimeDifference(_)) => {
                Self::Bytes(other.to_bytes())
            }
        }
    }

    /// The value as JSON (what the gateway's checks of a write take).
    pub fn to_json(&self) -> serde_json::Value {
        use serde_json::json;
        match self {
            Self::Int8(v) => json!(v),
            Self::Int16(v) => json!(v),
            Self::Int32(v) => json!(v),
            Self::Int64(v) => json!(v),
            Self::UInt8(v) => json!(v),
            Self::UInt16(v) => json!(v),
            Self::UInt32(v) => json!(v),
            Self::UInt64(v) => json!(v),
            Self::Float(v) => json!(v),
            Self::Double(v) => json!(v),
            Self::Boolean(v) => json!(v),
            Self::String(v) => json!(v),
            Self::Bytes(v) => json!(v),
            Self::DateTime(v) => json!(v),
            Self::Null(_) => serde_json::Value::Null,
        }
    }

    /// Fills in a protobuf metric's `datatype`, value and `is_null`.
    pub fn fill(&self, metric: &mut Metric) {
        metric.datatype = Some(self.datatype() as u32);
        metric.value = match self {
            // Two's complement, sign-extended to 32 bits (§6.4.17).
            Self::Int8(v) => Some(metric::Value::IntValue(i32::from(*v) as u32)),
            Self::Int16(v) => Some(metric::Value::IntValue(i32::from(*v) as u32)),
            Self::Int32(v) => Some(metric::Value::IntValue(*v as u32)),
            Self::Int64(v) => Some(metric::Value::LongValue(*v as u64)),
            Self::UInt8(v) => Some(metric::Value::IntValue((*v).into())),
            Self::UInt16(v) => Some(metric::Value::IntValue((*v).into())),
            Self::UInt32(v) => Some(metric::Value::IntValue(*v)),
            Self::UInt64(v) | Self::DateTime(v) => Some(metric::Value::LongValue(*v)),
            Self::Float(v) => Some(metric::Value::FloatValue(*v)),
            Self::Double(v) => Some(metric::Value::DoubleValue(*v)),
            Self::Boolean(v) => Some(metric::Value::BooleanValue(*v)),
            Self::String(v) => Some(metric::Value::StringValue(v.clone())),
            Self::Bytes(v) => Some(metric::Value::BytesValue(v.clone())),
            Self::Null(_) => None,
        };
        metric.is_null = matches!(self, Self::Null(_)).then_some(true);
    }

    /// A received metric's value, typed by its `datatype` (a command's
    /// metric need not carry it: the edge node gives it the type its birth
    /// said first); `None` for a type candeck does not take.
    pub fn from_metric(metric: &Metric) -> Option<Self> {
        let datatype = DataType::try_from(i32::try_from(metric.datatype?).ok()?).ok()?;
        if metric.is_null == Some(true) {
            return Some(Self::Null(datatype));
        }
        let value = metric.value.as_ref()?;
        Some(match (datatype, value) {
            (DataType::Int8, metric::Value::IntValue(v)) => Self::Int8(*v as i32 as i8),
            (DataType::Int16, metric::Value::IntValue(v)) => Self::Int16(*v as i32 as i16),
            (DataType::Int32, metric::Value::IntValue(v)) => Self::Int32(*v as i32),
            (DataType::Int64, metric::Value::LongValue(v)) => Self::Int64(*v as i64),
            (DataType::UInt8, metric::Value::IntValue(v)) => Self::UInt8(u8::try_from(*v).ok()?),
            (DataType::UInt16, metric::Value::IntValue(v)) => Self::UInt16(u16::try_from(*v).ok()?),
            (DataType::UInt32, metric::Value::IntValue(v)) => Self::UInt32(*v),
            // Some hosts send a UInt32 in long_value.
            (DataType::UInt32, metric::Value::LongValue(v)) => {
                Self::UInt32(u32::try_from(*v).ok()?)
            }
            (DataType::UInt64, metric::Value::LongValue(v)) => Self::UInt64(*v),
            (DataType::DateTime, metric::Value::LongValue(v)) => Self::DateTime(*v),
            (DataType::Float, metric::Value::FloatValue(v)) => Self::Float(*v),
            (DataType::Double, metric::Value::DoubleValue(v)) => Self::Double(*v),
            (DataType::Boolean, metric::Value::BooleanValue(v)) => Self::Boolean(*v),
            (DataType::String | DataType::Text, metric::Value::StringValue(v)) => {
                Self::String(v.clone())
            }
            (DataType::Bytes, metric::Value::BytesValue(v)) => Self::Bytes(v.clone()),
            _ => return None,
        })
    }
}

/// A metric as the gateway reports it: its name, value, and when it was
/// measured (milliseconds since 1970).
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    pub name: String,
    pub value: MetricValue,
    pub timestamp: u64,
    /// A host may write it (a command metric): its birth says so
    /// ([`READ_ONLY`] false).
    pub writable: bool,
}

/// The metric property a birth gives every metric: whether a host may
/// write it. Ignition's MQTT Engine takes a metric's properties as the
/// tag's properties, and `readOnly` is Ignition's tag property for it.
pub const READ_ONLY: &str = "readOnly";

impl Sample {
    pub fn new(name: impl Into<String>, value: MetricValue, timestamp: u64) -> Self {
        Self {
            name: name.into(),
            value,
            timestamp,
            writable: false,
        }
    }

    /// The same, a host may write it (a command metric).
    pub fn writable(mut self) -> Self {
        self.writable = true;
        self
    }
}
