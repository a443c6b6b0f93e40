//! A node operation's transfers, run in a task of their own: a caller that
//! goes away (a client hanging up drops its request) never cuts a sequence
//! of transfers half way (a PDO between invalidation and validation, a
//! restore between two entries).

use std::future::Future;

use crate::GatewayError;

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
