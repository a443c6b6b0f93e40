//! The OpenAPI schemas of the bodies whose Rust type is the gateway's: a
//! move, an axis's status, a stop's attempts, a logger, a role, an LED
//! strip's preview.
//!
//! The gateway knows no HTTP and no OpenAPI (issue 29): its types derive
//! serde only, and the handlers send and take them as they are, so that
//! REST, Sparkplug and the stream put the same JSON on the wire. What the
//! document says of that JSON is here, in the REST door: each type below
//! mirrors the gateway type of the same name field by field (the same serde
//! attributes, which utoipa reads for names, tags and what is required),
//! derives only [`utoipa::ToSchema`], and is named in the handlers'
//! `#[utoipa::path]`s (`body = schema::AxisStatus`) and in the door's own
//! bodies (`#[schema(value_type = schema::StopAttempt)]`). Its doc comments
//! are the descriptions the document shows.
//!
//! A mirror can drift from its gateway type; the tests of this module
//! serialize representative gateway values (every variant, every field)
//! and check each against its schema in the served document: no field the
//! schema lacks, none it requires missing, each of its type, and every
//! property and enum value of every mirror met at least once. A field added
//! to a gateway type fails them (its value built in the tests no longer
//! compiles, then its key is unknown to the schema) until its mirror has it.

pub mod access;
pub mod drive;
pub mod logger;
pub mod safe_stop;
pub mod step_test;
pub mod uioled;

#[cfg(test)]
mod tests;

pub use access::Role;
pub use drive::{AxisLimits, AxisStatus, AxisUnits, MoveMode, MoveRequest, TargetState};
pub use logger::{ChannelInfo, ChannelRequest, LoggerRequest, LoggerState, LoggerStatus, Source};
pub use safe_stop::{StopAttempt, StopMethod, StopOutcome};
pub use step_test::{LoopGains, SampleSource, Sampling, StepLoop, StepTestRequest, StepTestResult};
pub use uioled::{Color, Preview, PreviewSegment};
