//! A node that answers SDO requests from an [`ObjectStore`] over a [`Bus`]:
//! the SDO server of [`crate::canopen::sdo`] driven by frames and tokio's
//! clock. The full device core (NMT, heartbeat, PDOs, EMCY) is built on it.

use std::sync::{Arc, Mutex};

use crate::can::{Bus, FrameReceiver, RecvError};
use crate::canopen::sdo::{SdoServer, ServerConfig};

use super::objects::ObjectStore;

/// Serves SDO for `store` until the bus closes. The store stays shared so
/// that the device (or a test) changes values while clients read them.
///
/// The node listens from the moment this is called, not from the first
/// poll of the returned future, so a request sent right after spawning it is
/// not lost.
pub fn serve_sdo(
    bus: Bus,
    store: Arc<Mutex<ObjectStore>>,
    config: ServerConfig,
) -> impl Future<Output = ()> + Send {
    let frames = bus.subscribe();
    serve(bus, frames, store, config)
}

async fn serve(
    bus: Bus,
    mut frames: FrameReceiver,
    store: Arc<Mutex<ObjectStore>>,
    config: ServerConfig,
) {
    let node = lock(&store).node();
    let mut server = SdoServer::new(node, config);
    loop {
        let deadline = server.deadline().map(tokio::time::Instant::from_std);
        let replies = tokio::select! {
            received = frames.recv() => match received {
                Ok(frame) => {
                    let now = tokio::time::Instant::now().into_std();
                    server.handle_frame(&frame.frame, now, &mut *lock(&store))
                }
                // Requests lost in an overrun end as a client timeout, as on a real bus.
                Err(RecvError::Lagged(_)) => continue,
                Err(RecvError::Closed) => return,
            },
            _ = sleep_until(deadline) => server.handle_timeout(tokio::time::Instant::now().into_std()),
        };
        for reply in replies {
            if let Err(err) = bus.send(reply).await {
                tracing::debug!("sdo node {node}: reply not sent: {err}");
            }
        }
    }
}

fn lock(store: &Mutex<ObjectStore>) -> std::sync::MutexGuard<'_, ObjectStore> {
    store
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

async fn sleep_until(deadline: Option<tokio::time::Instant>) {
    match deadline {
        Some(deadline) => tokio::time::sleep_until(deadline).await,
        None => std::future::pending().await,
    }
}
