//! The counters of the Sparkplug B edge node (the adapter in
//! `crate::sparkplug`), kept on the gateway service so that `/metrics`
//! shows them without knowing the adapter.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// What the edge node did since the start; all zero when it is off.
#[derive(Debug, Default)]
pub struct EdgeNodeStats {
    /// Whether an edge node runs (`mqtt_url` given).
    pub enabled: AtomicBool,
    /// Whether it is connected to the broker now.
    pub connected: AtomicBool,
    /// Whether it publishes now (connected, and the primary host, if
    /// any, online).
    pub publishing: AtomicBool,
    /// Connections made to the broker.
    pub connects: AtomicU64,
    /// Messages published (births, deaths, data, historical).
    pub messages: AtomicU64,
    /// Metrics in those messages.
    pub metrics: AtomicU64,
    /// Data messages queued for store and forward, now.
    pub queued: AtomicU64,
    /// Historical messages sent from the queue.
    pub historical: AtomicU64,
    /// Messages dropped from the full queue (the oldest first).
    pub dropped: AtomicU64,
    /// Decoded TPDO frames the edge node fell too far behind to report
    /// one by one (their devices' newest values were reported instead).
    pub lost_changes: AtomicU64,
    /// Commands (NCMD/DCMD metrics) received.
    pub commands: AtomicU64,
    /// Of those, refused (role, rate limit, checks) or failed.
    pub commands_failed: AtomicU64,
}

impl EdgeNodeStats {
    pub fn add(counter: &AtomicU64, n: u64) {
        counter.fetch_add(n, Ordering::Relaxed);
    }

    pub fn get(counter: &AtomicU64) -> u64 {
        counter.load(Ordering::Relaxed)
    }
}
