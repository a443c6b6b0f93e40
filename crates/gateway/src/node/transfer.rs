//! A node operation's transfers, run in a task of their own: a caller that
//! goes away (a client hanging up drops its request) never cuts a sequence
//! of transfers half way (a PDO between invalidation and validation, a
//! restore between two entries), nor the audit row that says how it ended.

use std::future::Future;

use crate::GatewayError;
use crate::audit::AuditRow;

/// Runs `transfers` to its end, whatever becomes of the caller's future.
pub(super) async fn spawned<T, Fut>(transfers: Fut) -> Result<T, GatewayError>
where
    T: Send + 'static,
    Fut: Future<Output = Result<T, GatewayError>> + Send + 'static,
{
    tokio::spawn(transfers)
        .await
        .map_err(|err| GatewayError::Internal(format!("SDO task: {err}")))?
}

/// [`spawned`], and `row` finished with the outcome in the same task.
pub(super) use crate::audit::spawn_audited as audited;

/// An operation refused before its transfers: `row` says why.
pub(super) async fn refused<T>(row: AuditRow, error: GatewayError) -> Result<T, GatewayError> {
    let result = Err(error);
    row.finish(&result).await;
    result
}
