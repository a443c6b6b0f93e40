//! The schema of `crate::gateway::access`'s roles.

use utoipa::ToSchema;

/// What a token may do; each role may do what the ones before it may.
#[derive(Debug, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Reads and the stream.
    Viewer,
    /// Motion, LEDs, NMT, object writes.
    Operator,
    /// PDO configuration, store/restore, DCF restore, raw frames,
    /// recording, `/sim`, SYNC.
    Admin,
}
