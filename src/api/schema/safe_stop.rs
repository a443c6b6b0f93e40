//! The schemas of `crate::gateway::safe_stop`'s report of a stop.

use utoipa::ToSchema;

/// How a stop was tried.
#[derive(Debug, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum StopMethod {
    /// Controlword bit 8 (halt), the rest of the controlword kept.
    Halt,
    /// The quick stop command in the axis's controlword.
    QuickStop,
    /// NMT stop of the whole node.
    NmtStop,
}

/// What came of one [`StopMethod`].
#[derive(Debug, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum StopOutcome {
    /// The drive showed it: the statusword out of operation enabled after a
    /// quick stop; the controlword written and the axis read back after a
    /// halt.
    Confirmed,
    /// Sent, but not confirmed: the controlword was written and the
    /// statusword did not show the stop in time; an NMT stop is never
    /// confirmed.
    Sent,
    /// The node did not answer in time.
    Timeout,
    /// The node refused the transfer (`detail` has the abort code).
    SdoAbort,
    /// The node broke the SDO protocol.
    SdoProtocolError,
    /// The bus could not carry the frame.
    BusDown,
    /// Not tried: the node did not answer an earlier axis's transfer.
    Skipped,
    /// Anything else (`detail` says what).
    Failed,
}

/// One step of a stop.
#[derive(Debug, ToSchema)]
pub struct StopAttempt {
    #[schema(example = "quick_stop")]
    pub method: StopMethod,
    #[schema(example = "confirmed")]
    pub outcome: StopOutcome,
    /// What the drive showed or why the step failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(example = "statusword 0x0007: quick_stop_active")]
    pub detail: Option<String>,
}
